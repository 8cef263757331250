"""Position moves (PR/PA then BG), changes in motion, and speed schedules.

Every function here drives :class:`~galil.predict.engine.AxisProfiler`, the engine the
simulator runs, so a prediction is the simulator's (and, as far as the model goes, the
controller's) reference sample for sample.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument, LimitError, ScheduleError
from galil.models import ModelSpec
from galil.predict.counts import check_position_range, whole_counts
from galil.predict.engine import (
    AxisProfiler,
    KinematicPlan,
    PlanSamples,
    plan_from_rest,
    plan_position,
)
from galil.predict.profile import Profile
from galil.predict.quantities import no_quantity, period_seconds, seconds
from galil.predict.smoothing import END_LOOKAHEAD

__all__ = [
    "SCHEDULE_MAX_SAMPLES",
    "Abort",
    "Event",
    "Increment",
    "MovePlan",
    "ScheduleError",
    "SetAccel",
    "SetDecel",
    "SetSpeed",
    "SpeedSchedule",
    "Stop",
    "move",
    "plan_move",
    "run",
    "run_profile",
    "sample_of_event",
    "speed_schedule",
]

# Samples previewed at a time while waiting for a speed schedule's trigger.
_SCHEDULE_STEP = 4096
#: Longest prediction, in samples (about 13.6 hours at 1024 Hz), so a mistake cannot hang.
MAX_SAMPLES = 50_000_000

Int64Array = npt.NDArray[np.int64]


def _event_time(event: object, kind: str) -> None:
    """An event's ``time`` given as a time Quantity, in seconds (the dataclass is frozen).

    Raises:
        InvalidArgument: a Quantity that is not a time.
    """
    time = getattr(event, "time")  # noqa: B009 (the events share no base class to type it)
    if not isinstance(time, (int, float)):
        object.__setattr__(event, "time", seconds(time, f"{kind} time"))


def _plain_settings(speed: object, accel: object, decel: object, smoothing: object) -> None:
    """Refuse a Quantity for SP (JG), AC, DC or IT: the predictor has no scale.

    Raises:
        InvalidArgument: naming the argument.
    """
    no_quantity(speed, "speed", "counts/s")
    no_quantity(accel, "accel", "counts/s²")
    no_quantity(decel, "decel", "counts/s²")
    no_quantity(smoothing, "smoothing", "IT (a fraction, 1/256 .. 1)", counts=False)


@dataclass(frozen=True)
class SetSpeed:
    """SP (position move) or JG (jog) at ``time`` seconds from the start, counts/s."""

    time: float
    speed: float

    def __post_init__(self) -> None:
        _event_time(self, "SetSpeed")
        no_quantity(self.speed, "SetSpeed speed", "counts/s")


@dataclass(frozen=True)
class SetAccel:
    """AC at ``time`` seconds, counts/s²."""

    time: float
    accel: float

    def __post_init__(self) -> None:
        _event_time(self, "SetAccel")
        no_quantity(self.accel, "SetAccel accel", "counts/s²")


@dataclass(frozen=True)
class SetDecel:
    """DC at ``time`` seconds, counts/s²: in a jog, or while a stop (ST) ramps down, the ramp
    re-plans at the new rate; in a position move the controller refuses it (TC 7)."""

    time: float
    decel: float

    def __post_init__(self) -> None:
        _event_time(self, "SetDecel")
        no_quantity(self.decel, "SetDecel decel", "counts/s²")


@dataclass(frozen=True)
class Increment:
    """IP ``distance`` counts at ``time`` seconds."""

    time: float
    distance: int

    def __post_init__(self) -> None:
        _event_time(self, "Increment")
        no_quantity(self.distance, "Increment distance", "counts")


@dataclass(frozen=True)
class Stop:
    """ST at ``time`` seconds."""

    time: float

    def __post_init__(self) -> None:
        _event_time(self, "Stop")


@dataclass(frozen=True)
class Abort:
    """AB at ``time`` seconds: the profiler stops at once where it is (stop code 7). An AB
    that arrives once the motion is over changes nothing; events after it are ignored."""

    time: float

    def __post_init__(self) -> None:
        _event_time(self, "Abort")


Event = SetSpeed | SetAccel | SetDecel | Increment | Stop | Abort


@dataclass(frozen=True)
class MovePlan:
    """A position move planned but not sampled (the cheap part of :func:`move`).

    Attributes:
        distance: counts (signed).
        duration: seconds, ``samples * sample_period``.
        samples: N, the sample at which the profiler issues the target.
        exact_duration: the continuous (closed-form) duration, seconds.
        peak_speed: counts/s.
        shape: ``"trapezoid"``, ``"triangle"`` or ``"none"``.
        accel_time, cruise_time, decel_time: phase lengths in seconds (closed form).
    """

    distance: int
    duration: float
    samples: int
    exact_duration: float
    peak_speed: float
    shape: str
    accel_time: float
    cruise_time: float
    decel_time: float


def _validate(speed: float, accel: float, decel: float, sample_period: float) -> None:
    isfinite = math.isfinite
    if (
        isfinite(speed)
        and speed > 0
        and isfinite(accel)
        and accel > 0
        and isfinite(decel)
        and decel > 0
        and isfinite(sample_period)
        and sample_period > 0
    ):
        return  # (the usual case: the loop below, without it)
    for name, value in (("speed", speed), ("accel", accel), ("decel", decel)):
        if not (math.isfinite(value) and value > 0):
            raise InvalidArgument(f"{name} must be a positive number, got {value!r}")
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise InvalidArgument(f"sample_period must be positive, got {sample_period!r}")


def plan_move(
    distance: int,
    speed: float,
    accel: float,
    decel: float,
    *,
    sample_period: float = 1 / 1024,
) -> MovePlan:
    """Plan a PR move from rest without sampling it: duration, peak speed and shape.

    Raises:
        InvalidArgument: a non-positive speed, accel, decel or sample period; a distance that
            is not a whole number of counts (:func:`move`).
        LimitError: a distance outside the 32-bit range ``PR`` takes.
    """
    distance = _distance(distance)
    _plain_settings(speed, accel, decel, None)
    sample_period = period_seconds(sample_period)
    _validate(speed, accel, decel, sample_period)
    ts = sample_period
    plan = plan_position(0.0, 0.0, float(distance), speed * ts, accel * ts * ts, decel * ts * ts)
    return _move_plan(distance, plan, ts)


def _distance(distance: object, start: object = 0, model: str | None = None) -> int:
    """A move's distance as whole counts, its ``PR`` and its target (``start + distance``)
    inside the controller's 32-bit range.

    Raises:
        InvalidArgument: not a whole number of counts (``10.7``, ``"1000"``, ``True``).
        LimitError: the distance or the target outside -2147483648 .. 2147483647.
    """
    d = whole_counts(distance, "distance")
    check_position_range("PR", d, "PR", model=model)
    if start != 0:
        target = whole_counts(start, "start") + d
        check_position_range("PA", target, "the target (start + distance)", model=model)
    return d


def _move_plan(distance: int, plan: KinematicPlan, ts: float) -> MovePlan:
    phases = [0.0, 0.0, 0.0]
    for seg in plan.segments:
        if seg.accel == 0:
            phases[1] += seg.duration
        elif (seg.accel > 0) == (distance > 0):
            phases[0] += seg.duration
        else:
            phases[2] += seg.duration
    samples = max(0, math.ceil(plan.duration - 1e-9))
    return MovePlan(
        distance=distance,
        duration=samples * ts,
        samples=samples,
        exact_duration=plan.duration * ts,
        peak_speed=plan.peak / ts,
        shape=plan.shape,
        accel_time=phases[0] * ts,
        cruise_time=phases[1] * ts,
        decel_time=phases[2] * ts,
    )


def _resolve(
    speed: float,
    accel: float,
    decel: float,
    smoothing: float | None,
    sample_period: float,
    model: str | ModelSpec | None,
    *,
    jog: bool = False,
) -> tuple[float, float, float, float, float]:
    """SP/AC/DC/IT/Ts as the engine takes them (quantised for ``model``; IT ``None`` is 1)."""
    if smoothing is None:
        smoothing = 1.0
    if model is None:
        return speed, accel, decel, smoothing, sample_period
    from galil.predict.checks import quantise

    q = quantise(model, speed=speed, accel=accel, decel=decel, smoothing=smoothing, jog=jog)
    assert q.speed is not None
    assert q.accel is not None
    assert q.decel is not None
    assert q.smoothing is not None
    return q.speed, q.accel, q.decel, q.smoothing, q.sample_period


def _model_name(model: str | ModelSpec | None) -> str | None:
    return model.name if isinstance(model, ModelSpec) else model


def sample_of_event(time: float, ts: float) -> int:
    """The sample an event at ``time`` seconds applies at (``round(time / ts)``).

    Raises:
        InvalidArgument: a time that is not a finite number >= 0.
    """
    if not (math.isfinite(time) and time >= 0):
        raise InvalidArgument(f"event time must be >= 0, got {time!r}")
    return round(time / ts)


#: A run of more samples than this keeps none of them: its profile knows its ends, length,
#: bounds and peak, and computes the samples again only when they are first read
#: (:meth:`Profile.planned`). A jog stopped after a day costs no more memory than one stopped
#: after a minute (about 34 min at 1024 Hz; the whole arrays cost about 40 bytes a sample).
KEEP_SAMPLES = 1 << 21

#: The engine is stepped at most this many samples at a time (the memory of one step).
_PIECE = 1 << 18


@dataclass
class _Run:
    """What a driven engine produced: the samples (while it keeps them), how many, their
    bounds and last values, and the peak |velocity| (counts/s).

    ``keep``: once more samples than this were run, the arrays are dropped and only the
    summary is kept (``None``: keep them all)."""

    r: list[Int64Array]
    ref: list[Int64Array]
    peak: float
    keep: int | None = None
    n: int = 0
    low: int = 0
    high: int = 0
    last: int = 0
    dropped: bool = False

    def add(self, r: Int64Array, ref: Int64Array) -> None:
        self.n += ref.size
        self.last = int(ref[-1])
        if self.dropped:
            self.low = min(self.low, int(ref.min()))
            self.high = max(self.high, int(ref.max()))
            return
        self.r.append(r)
        self.ref.append(ref)
        if self.keep is not None and self.n > self.keep:
            self.low = min(int(a.min()) for a in self.ref)
            self.high = max(int(a.max()) for a in self.ref)
            self.r.clear()
            self.ref.clear()
            self.dropped = True

    def arrays(self) -> tuple[Int64Array, Int64Array]:
        """The profiler positions and the references of the samples run (all kept)."""
        assert not self.dropped
        empty = np.empty(0, np.int64)
        r = np.concatenate(self.r) if self.r else empty
        ref = np.concatenate(self.ref) if self.ref else empty
        return r, ref


def _advance(eng: AxisProfiler, n: int, run: _Run) -> None:
    while n > 0:
        piece = min(n, _PIECE)
        if eng.moving:
            v = eng.preview_velocity(piece)
            if v.size:
                run.peak = max(run.peak, float(np.max(np.abs(v))))
        r, ref = eng.advance_both(piece)
        run.add(r, ref)
        n -= piece


def run(
    eng: AxisProfiler,
    events: Sequence[Event],
    *,
    speed: float,
    accel: float,
    decel: float,
    until: int | None = None,
) -> tuple[Int64Array, Int64Array, float]:
    """Drive ``eng`` through timed events, then until ``until`` or until motion completes.

    Each event is applied at sample ``round(time / sample_period)`` and takes effect from the
    next sample, as a command does on the controller.

    Returns:
        ``(r, reference, peak_speed)``: samples 1.. of the profiler position and of the
        reference, and the largest |profiler velocity| seen (counts/s).

    Raises:
        CommandError: the controller would refuse an event (e.g. TC 16 for a wrong-sign IP).
        InvalidArgument: the motion does not complete within ``MAX_SAMPLES`` of its last
            event.
    """
    out = _Run([], [], 0.0)
    drive(eng, events, speed=speed, accel=accel, decel=decel, until=until, out=out)
    r, ref = out.arrays()
    return r, ref, out.peak


def drive(
    eng: AxisProfiler,
    events: Sequence[Event],
    *,
    speed: float,
    accel: float,
    decel: float,
    until: int | None,
    out: _Run,
) -> None:
    """:func:`run`, adding what the engine produces to ``out``."""
    ts = eng.sample_period
    out.peak = max(out.peak, abs(eng.velocity))
    sp, ac, dc = speed, accel, decel
    base = eng.sample
    for ev in sorted(events, key=lambda e: e.time):
        k = base + sample_of_event(ev.time, ts)
        if isinstance(ev, Abort):
            _run_down(eng, out, until=k)  # (no further than the motion's end)
            if eng.moving:
                eng.abort()
            break
        _advance(eng, k - eng.sample, out)
        if isinstance(ev, SetSpeed):
            sp = abs(ev.speed) if eng.mode != "jog" else ev.speed
            eng.set_speed(ev.speed)
        elif isinstance(ev, SetAccel):
            ac = ev.accel
            eng.set_accel(ev.accel)
        elif isinstance(ev, SetDecel):
            eng.set_decel(ev.decel)
            dc = ev.decel
        elif isinstance(ev, Increment):
            eng.increment(ev.distance, abs(sp), ac, dc)
        else:
            eng.stop()
    if until is not None:
        _advance(eng, base + until - eng.sample, out)
        return
    _run_down(eng, out)


def _run_down(eng: AxisProfiler, out: _Run, *, until: int | None = None) -> None:
    """Step ``eng`` until its motion is over, or (``until``) to that sample at most.

    Raises:
        InvalidArgument: with no ``until``, the motion does not complete within
            ``MAX_SAMPLES`` (counted from here, the last event: a jog may run for days before
            its ST).
    """
    step = 1024
    last = eng.sample
    while eng.moving and (until is None or eng.sample < until):
        if until is None and eng.sample - last > MAX_SAMPLES:
            raise InvalidArgument(f"motion does not complete within {MAX_SAMPLES} samples")
        end = eng.end_sample
        # An unknown end is at least END_LOOKAHEAD samples away (a smoothed move ending
        # later, or a jog): stepping that far cannot pass it. A plan that has already
        # ended is complete on the next sample.
        n = step if end is None else max(1, end - eng.sample)
        _advance(eng, n if until is None else min(n, until - eng.sample), out)
        step = min(step * 2, END_LOOKAHEAD)


#: Drives a fresh engine (:func:`drive`, once or more) into a :class:`_Run`.
Driver = Callable[[AxisProfiler, _Run], None]


class _Rerun:
    """The samples of a long run, computed again when they are first read: the source of a
    :meth:`Profile.planned` whose summary (ends, length, bounds) the first run measured.

    ``fresh()`` builds the engine as it was before the first run; ``go`` drives it as then
    (the engine is deterministic: the same samples again)."""

    def __init__(
        self, fresh: Callable[[], AxisProfiler], go: Driver, summary: _Run, start: int
    ) -> None:
        self._fresh = fresh
        self._go = go
        self.start = start
        self.end = summary.last
        self.samples = summary.n
        self.bounds = (min(start, summary.low), max(start, summary.high))
        self._r: Int64Array | None = None

    def __call__(self) -> Int64Array:
        eng = self._fresh()
        out = _Run([], [], 0.0)
        self._go(eng, out)
        r, ref = out.arrays()
        head = np.array([self.start], np.int64)
        self._r = np.concatenate([head, r])
        return np.concatenate([head, ref])

    def profiler(self) -> Int64Array:
        """The profiler positions ``r`` (before smoothing), sample 0 included."""
        if self._r is None:
            self()
        assert self._r is not None
        return self._r


def run_profile(
    fresh: Callable[[], AxisProfiler],
    go: Driver,
    *,
    start: int,
    shape: Callable[[str, AxisProfiler], str],
    start_velocity: float = 0.0,
) -> Profile:
    """The profile of a fresh engine driven by ``go``, from sample 0 (``start``).

    A run of more than :data:`KEEP_SAMPLES` samples keeps none: its profile computes them
    again when they are first read. ``shape(begun, eng)`` names the profile from the shape
    of the plan the engine began with and the engine once driven.
    """
    eng = fresh()
    begun = "" if eng.plan is None else eng.plan.shape
    out = _Run([], [], 0.0, keep=KEEP_SAMPLES)
    go(eng, out)
    name = shape(begun, eng)
    peak = max(out.peak, abs(start_velocity))
    if out.dropped:
        source = _Rerun(fresh, go, out, start)
        return Profile.planned(
            source,
            sample_period=eng.sample_period,
            shape=name,
            peak_speed=peak,
            stop_code=eng.stop_code,
            profiler=source.profiler,
            start_velocity=start_velocity,
        )
    r, ref = out.arrays()
    head = np.array([start], np.int64)
    return Profile.from_samples(
        np.concatenate([head, ref]),
        profiler=np.concatenate([head, r]),
        sample_period=eng.sample_period,
        start_velocity=start_velocity,
        shape=name,
        peak_speed=peak,
        stop_code=eng.stop_code,
    )


def move(
    distance: int,
    speed: float,
    accel: float,
    decel: float,
    *,
    sample_period: float = 1 / 1024,
    smoothing: float | None = 1.0,
    start: int = 0,
    events: Sequence[Event] = (),
    model: str | ModelSpec | None = None,
) -> Profile:
    """Predict a PR move of ``distance`` counts (PA: pass ``target - start``).

    Args:
        distance: counts, signed.
        speed: SP, counts/s.
        accel: AC, counts/s².
        decel: DC, counts/s².
        sample_period: seconds per servo sample (``TM/1_024_000``).
        smoothing: IT (1 or ``None`` = none).
        start: position at sample 0.
        events: changes in motion (:class:`SetSpeed`, :class:`SetAccel`, :class:`Increment`,
            :class:`Stop`, :class:`Abort`; :class:`SetDecel` only after a stop) at given
            times.
        model: when given, SP/AC/DC/IT are first quantised as that model stores them (and
            range-checked), and its sample period is used.

    Returns:
        The :class:`Profile` from sample 0 (``start``) to the sample where the move completes.

    A distance or start that is not a whole number of counts (``10.7``; a whole float such
    as ``1000.0`` is taken) is refused, as are a string or a bool: the controller moves whole
    counts (an axis with a scale rounds its units to them first). The distance and the target
    must lie in the 32-bit range the controller's ``PR`` and ``PA`` take, with a model or
    without.

    Raises:
        InvalidArgument: bad arguments. LimitError: out of the model's range (with ``model``),
        or a distance or target outside the 32-bit range.
        CommandError: an event the controller would refuse.
    """
    start = whole_counts(start, "start")
    distance = _distance(distance, start, _model_name(model))
    _plain_settings(speed, accel, decel, smoothing)
    sample_period = period_seconds(sample_period)
    _validate(speed, accel, decel, sample_period)
    if model is not None or smoothing is None:  # (else _resolve returns them as they are)
        speed, accel, decel, smoothing, sample_period = _resolve(
            speed, accel, decel, smoothing, sample_period, model
        )
    if not events and smoothing == 1.0:
        # The usual case: one plan from rest, unsmoothed, evaluated at samples 0..N in one go
        # (sample 0 is the start) as the engine evaluates it, without stepping an engine, and
        # only when the profile's arrays are first read (Profile.planned).
        ts = sample_period
        v = speed * ts
        if v <= 0:
            raise InvalidArgument(f"speed must be > 0, got {speed!r}")
        x0 = float(start)
        target = float(start + distance)
        plan = plan_from_rest(x0, target, v, accel * ts * ts, decel * ts * ts)
        return Profile.planned(
            PlanSamples.of(plan),
            sample_period=ts,
            shape=plan.shape,
            peak_speed=plan.peak / ts,
            stop_code=1,
        )
    return _run_move(
        start,
        start + distance,
        speed,
        accel,
        decel,
        smoothing,
        sample_period,
        events,
    )


def _run_move(
    start: int,
    target: int,
    speed: float,
    accel: float,
    decel: float,
    smoothing: float,
    sample_period: float,
    events: Sequence[Event],
) -> Profile:
    """:func:`move` on the engine (changes in motion, or IT smoothing)."""

    def fresh() -> AxisProfiler:
        eng = AxisProfiler(sample_period=sample_period, position=start)
        eng.begin_move(target, speed, accel, decel, smoothing)
        return eng

    def go(eng: AxisProfiler, out: _Run) -> None:
        drive(eng, events, speed=speed, accel=accel, decel=decel, until=None, out=out)

    def shape(begun: str, eng: AxisProfiler) -> str:
        if not events:
            return begun
        return "stopped" if eng.stop_code == 4 else "changed"

    return run_profile(fresh, go, start=start, shape=shape)


#: The most samples a speed schedule is predicted in (2.3 h at 1024 Hz; about 300 MB).
SCHEDULE_MAX_SAMPLES = 1 << 23


def _schedule_seconds(
    total: int, triggers: Sequence[int], speeds: Sequence[float], accel: float, decel: float
) -> float:
    """An upper bound of a schedule's duration: each stretch at the slower of the speeds it
    joins, plus the first ramp up and the last ramp down."""
    edges = [0, *triggers, total]
    seconds = speeds[0] / accel + speeds[-1] / decel
    for i in range(len(speeds)):
        slowest = speeds[i] if i == 0 else min(speeds[i - 1], speeds[i])
        seconds += (edges[i + 1] - edges[i]) / slowest
    return seconds


def _schedule_points(
    distance: int,
    initial_speed: float,
    changes: Sequence[tuple[float, float]],
    accel: float,
    decel: float,
) -> tuple[list[int], list[float], list[float]]:
    """Check each change point; return the triggers, the speeds and where each ramp ends.

    Raises:
        ScheduleError: a change before the previous ramp ends, or no room to stop.
        InvalidArgument: malformed points.
    """
    total = abs(int(distance))
    if total == 0:
        raise InvalidArgument("a speed schedule needs a non-zero distance")
    speeds = [float(initial_speed)]
    ramp_end = initial_speed**2 / (2 * accel)
    ramp_ends = [ramp_end]
    triggers: list[int] = []
    prev_at = 0.0
    for i, (at, sp) in enumerate(changes):
        if not (math.isfinite(sp) and sp > 0):
            raise InvalidArgument(f"change {i}: speed must be positive, got {sp!r}")
        if not (math.isfinite(at) and prev_at < at < total):
            raise InvalidArgument(
                f"change {i}: trigger distance {at!r} must lie in ({prev_at:g}, {total})"
            )
        if at < ramp_end:
            earliest = math.ceil(ramp_end)
            raise ScheduleError(
                f"change {i} at {at:g} counts comes before the previous ramp ends at"
                f" {ramp_end:.6g} counts; the earliest valid trigger is {earliest}",
                index=i,
                earliest=earliest,
                value=at,
            )
        rate = accel if sp > speeds[-1] else decel
        ramp_end = at + abs(sp**2 - speeds[-1] ** 2) / (2 * rate)
        ramp_ends.append(ramp_end)
        speeds.append(float(sp))
        triggers.append(math.ceil(at))
        prev_at = at
    _room_to_stop(ramp_end, speeds[-1], decel, total, len(triggers))
    return triggers, speeds, ramp_ends


def _room_to_stop(ramp_end: float, speed: float, decel: float, total: int, index: int) -> None:
    need = ramp_end + speed**2 / (2 * decel)
    if need > total:
        raise ScheduleError(
            f"the final deceleration from {speed:g} counts/s needs the move to be at least"
            f" {need:.6g} counts long, not {total}",
            index=index,
            earliest=math.ceil(need),
            value=total,
        )


def _predict_schedule(
    distance: int,
    triggers: Sequence[int],
    speeds: Sequence[float],
    accel: float,
    decel: float,
    sample_period: float,
    start: int,
    smoothing: float | None,
) -> Profile:
    """Run the schedule on the engine: AD watches r (before smoothing), SP from the next sample."""
    sign = 1 if distance > 0 else -1
    eng = AxisProfiler(sample_period=sample_period, position=int(start))
    eng.begin_move(int(start) + int(distance), speeds[0], accel, decel, smoothing)
    out = _Run([], [], 0.0)
    for trig, sp in zip(triggers, speeds[1:], strict=True):
        while True:
            end = eng.end_sample
            n = max(1, (end - eng.sample) if end is not None else _SCHEDULE_STEP)
            r = eng.preview_profile(n)
            hit = np.flatnonzero(sign * (r - int(start)) >= trig)
            if hit.size:
                _advance(eng, int(hit[0]) + 1, out)
                break
            _advance(eng, n, out)
        eng.set_speed(sp)
    drive(eng, (), speed=speeds[-1], accel=accel, decel=decel, until=None, out=out)
    return Profile.from_samples(
        np.concatenate([[int(start)], *out.ref]),
        profiler=np.concatenate([[int(start)], *out.r]),
        sample_period=sample_period,
        shape="schedule",
        peak_speed=out.peak,
        stop_code=eng.stop_code,
    )


@dataclass(frozen=True)
class SpeedSchedule:
    """A move that changes speed at given distances, validated and predicted.

    Attributes:
        distance: total move, counts (signed).
        triggers: distances from the start (counts, positive) at which each speed change is
            commanded: the axis layer arms ``AD`` trippoints with these.
        speeds: the initial speed followed by each new speed, counts/s.
        ramp_ends: distance from the start at which each ramp (initial acceleration, then one
            per change) finishes, closed form.
        profile: the predicted :class:`Profile`.
    """

    distance: int
    triggers: tuple[int, ...]
    speeds: tuple[float, ...]
    ramp_ends: tuple[float, ...]
    profile: Profile


def speed_schedule(
    distance: int,
    initial_speed: float,
    changes: Sequence[tuple[float, float]],
    accel: float,
    decel: float,
    *,
    sample_period: float = 1 / 1024,
    start: int = 0,
    smoothing: float | None = 1.0,
) -> SpeedSchedule:
    """Validate and predict a move that changes speed at given distances from its start.

    The Galil counterpart of a "distance to change" schedule: PR ``distance`` at
    ``initial_speed``; at each ``(at, speed)`` (``at`` counts from the start, increasing) an
    ``AD`` trippoint then ``SP speed``. A change is valid only if the previous ramp has finished
    when its trigger is reached; the last ramp must also leave room for the final deceleration.
    Speed rises at ``accel`` and falls at ``decel``. ``smoothing`` is IT (1 or ``None``: none).

    Raises:
        ScheduleError: a change point that is not valid, with the earliest valid one.
        InvalidArgument: malformed arguments; a distance or start that is not a whole number of
            counts (as :func:`move`).
        LimitError: a schedule longer than :data:`SCHEDULE_MAX_SAMPLES` samples; a distance
            or target outside the 32-bit range.
    """
    start = whole_counts(start, "start")
    distance = _distance(distance, start)
    _plain_settings(initial_speed, accel, decel, smoothing)
    sample_period = period_seconds(sample_period)
    _validate(initial_speed, accel, decel, sample_period)
    triggers, speeds, ramp_ends = _schedule_points(distance, initial_speed, changes, accel, decel)
    longest = _schedule_seconds(abs(int(distance)), triggers, speeds, accel, decel)
    if longest / sample_period > SCHEDULE_MAX_SAMPLES:
        # Every sample is predicted up front (8 bytes each in several arrays): refuse what
        # would take gigabytes rather than run out of memory.
        raise LimitError(
            f"a speed schedule of up to {longest:.6g} s is more than the"
            f" {SCHEDULE_MAX_SAMPLES} samples it can be predicted in; split the move",
            name="samples",
            value=math.ceil(longest / sample_period),
            limit=SCHEDULE_MAX_SAMPLES,
        )
    profile = _predict_schedule(
        distance, triggers, speeds, accel, decel, sample_period, start, smoothing
    )
    return SpeedSchedule(
        distance=int(distance),
        triggers=tuple(triggers),
        speeds=tuple(speeds),
        ramp_ends=tuple(ramp_ends),
        profile=profile,
    )
