"""Homing (HM, FE, FI) as phases of the one motion engine, shared by predictor and simulator.

:class:`HomingSequence` drives an :class:`~galil.predict.engine.AxisProfiler` through the
phases of a homing command. It does no stepping itself: whoever owns the profiler steps it and
tells the sequence when a phase's condition (:meth:`HomingSequence.watch`, a :class:`Crossing`
of a switch edge or an index pulse) turned true, and when a phase's motion has ended. The
simulator's homing room does that in its servo loop, with the motor's position; :func:`homing`
does it here, on the reference position, to predict the whole sequence. With the simulator's
servo lag at 0 the two agree sample for sample.

The phases (``shared/reference/galil-wave2-facts.md`` section 2; decision 0015):

- ``HM``, stage 1: jog at SP towards the home switch's edge (direction from the home input
  and CN field 2), decelerate at DC once the input changes. Stage 2: back at HV until the input
  changes back, stop at once there (Optima HM text). Stage 3 (servo motors): forward at HV to
  the next index pulse, latch it, decelerate, return to it at HV; it becomes position 0. A
  stepper ends after stage 2, with position 0 at the edge. Stop code 10.
- ``FE``: jog at SP towards the edge, decelerate at DC once the input changes; no position is
  defined. Stop code 9.
- ``FI``: jog at JG (its sign is the direction) to the next index pulse, latch, decelerate,
  return at HV, position 0 at the index (EPICS: the 4xxx "latches the index and returns").
  Stop code 10.

Steppers: ``KS`` smooths the step pulses *after* the profiler (a filter with a time constant of
about 3·KS samples, DMC-2x00 manual); the reference (``RP``) predicted here is the profiler's
output, before KS. :func:`stepper_output` gives the smoothed step position under that model; its
exact form on current firmware is an assumption.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.predict.counts import whole_counts
from galil.predict.engine import AxisProfiler
from galil.predict.move import Event, SetAccel, sample_of_event
from galil.predict.profile import Profile
from galil.predict.quantities import period_seconds
from galil.predict.smoothing import smooth

__all__ = [
    "Crossing",
    "HomeSwitch",
    "HomingParams",
    "HomingPrediction",
    "HomingSequence",
    "homing",
    "stepper_output",
]

#: Stop codes at the end of each command.
END_CODE = {"HM": 10, "FE": 9, "FI": 10}
#: Longest sequence the predictor follows before it gives up (samples).
MAX_SAMPLES = 20_000_000
_CHUNK = 4096


@dataclass(frozen=True)
class Crossing:
    """A condition on the position: true once ``(p - threshold) * direction >= 0``."""

    threshold: int
    direction: int

    def hit(self, position: int) -> bool:
        """Whether ``position`` is at or beyond the threshold."""
        return (position - self.threshold) * self.direction >= 0

    def first(self, positions: npt.NDArray[np.int64]) -> int | None:
        """Index of the first position that hits, if any."""
        hits = np.flatnonzero((positions - self.threshold) * self.direction >= 0)
        return int(hits[0]) if hits.size else None


def _whole_counts(value: object, name: str) -> int:
    """``value`` as an ``int``: an integer (numpy's too) or a whole, finite float; a bool,
    NaN, a fraction of a count or anything else is refused, naming ``name``."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, (float, np.floating)) and math.isfinite(value) and value.is_integer():
        return int(value)
    raise InvalidArgument(f"{name} must be a whole number of counts, not {value!r:.60}")


@dataclass(frozen=True)
class HomeSwitch:
    """Where an axis's home switch edge and index pulses are, in one frame of counts.

    Every field is a whole number of counts (numpy integers and whole floats are taken, and
    kept as ``int``); anything else is an :class:`~galil.errors.InvalidArgument` at
    construction.

    Attributes:
        edge: the position where the home switch changes state.
        side: -1 when the switch is tripped (its input low) below ``edge``, +1 at and above.
        index_period: counts between index pulses (the encoder's counts per turn).
        index_offset: the position of one index pulse (the others every ``index_period``).
    """

    edge: int
    side: int = -1
    index_period: int = 4000
    index_offset: int = 0

    def __post_init__(self) -> None:
        for name in ("edge", "index_period", "index_offset"):
            object.__setattr__(self, name, _whole_counts(getattr(self, name), name))
        side = self.side
        if (
            isinstance(side, bool)
            or not isinstance(side, (int, float, np.integer, np.floating))
            or side not in (-1, 1)
        ):
            raise InvalidArgument(f"side is -1 or 1, not {side!r:.60}")
        object.__setattr__(self, "side", int(side))
        if self.index_period <= 0:
            raise InvalidArgument(f"index_period must be > 0, not {self.index_period!r}")

    def on_flag(self, position: int) -> bool:
        """Whether the home switch is tripped at ``position``."""
        return position < self.edge if self.side < 0 else position >= self.edge

    def level(self, position: int) -> int:
        """The home input (``_HM``): 0 while tripped, 1 otherwise."""
        return 0 if self.on_flag(position) else 1

    def leaving(self, position: int) -> Crossing:
        """The crossing where the switch state first differs from the one at ``position``."""
        now = self.on_flag(position)
        below = self.side < 0
        # Tripped below the edge: leaving it means reaching the edge going up, and so on.
        if now == below:
            return Crossing(self.edge, 1)
        return Crossing(self.edge - 1, -1)

    def next_index(self, position: int, direction: int) -> Crossing:
        """The first index pulse strictly beyond ``position`` in ``direction``."""
        p, off = self.index_period, self.index_offset
        k = (position - off) // p
        if direction > 0:
            return Crossing(off + (k + 1) * p, 1)
        below = off + k * p
        return Crossing(below if below < position else below - p, -1)

    def shifted(self, by: int) -> HomeSwitch:
        """The same switch in a frame shifted by ``by`` counts (positions + by)."""
        offset = (self.index_offset + by) % self.index_period
        return HomeSwitch(self.edge + by, self.side, self.index_period, offset)


@dataclass(frozen=True)
class HomingParams:
    """The axis's settings a homing command uses (counts/s, counts/s², as quantised).

    Attributes:
        speed: SP (stage 1 of HM, and FE).
        accel, decel: AC and DC.
        home_speed: HV (stages 2 and 3 of HM, FI's return).
        jog_speed: JG (FI's speed and direction).
        home_direction: CN field 2 (-1: drive in reverse while the home input is high).
        stepper: HM ends after stage 2 (no index on a stepper).
    """

    speed: float
    accel: float
    decel: float
    home_speed: float
    jog_speed: float = 0.0
    home_direction: int = -1
    stepper: bool = False


class HomingSequence:
    """One HM, FE or FI in progress on ``profiler`` (see the module docstring).

    Args:
        kind: ``"HM"``, ``"FE"`` or ``"FI"``.
        profiler: the axis's engine (idle).
        params: the settings in force at ``BG``.
        switch: the switch and index positions, in the caller's frame.
        origin: the caller's frame minus the profiler's (the simulator's fixed frame is the
            encoder plus an origin; 0 when both are the same).

    Attributes:
        prof: the engine it drives; a caller that replaces the axis's engine object (the
            simulator restores snapshots while it bisects a step) sets it again.
        stage: 1, 2, 3 (to the index), 4 (back to it); 0 once done.
        zero_at: where, in the profiler's frame, the position to define as 0 is (set when
            the sequence ends with a defined position).
    """

    def __init__(
        self,
        kind: str,
        profiler: AxisProfiler,
        params: HomingParams,
        switch: HomeSwitch,
        origin: int = 0,
    ) -> None:
        if kind not in END_CODE:
            raise InvalidArgument(f"kind is HM, FE or FI, not {kind!r}")
        self.kind = kind
        self.prof = profiler
        self.params = params
        self.switch = switch
        self.origin = origin
        self.stage = 0
        self.zero_at: int | None = None
        self._watch: Crossing | None = None
        self._latched = 0
        self._direction = 1
        self._tripped = False  # the switch at the start of the phase that waits for it

    @property
    def code(self) -> int:
        """The stop code the sequence ends with."""
        return END_CODE[self.kind]

    @property
    def done(self) -> bool:
        """Whether the sequence has ended (normally or not)."""
        return self.stage == 0

    def direction(self, position: int) -> int:
        """Stage 1's (and FE's) direction at ``position`` (caller's frame); FI's from JG."""
        if self.kind == "FI":
            return 1 if self.params.jog_speed > 0 else -1
        high = self.switch.level(position) == 1
        forward_when_high = self.params.home_direction > 0
        return 1 if high == forward_when_high else -1

    def start(self, position: int) -> None:
        """Begin stage 1 at ``position`` (the caller's frame)."""
        p = self.params
        d = self._direction = self.direction(position)
        self.stage = 1
        if self.kind == "FI":
            self._watch = self.switch.next_index(position, d)
            self._latched = self._watch.threshold - self.origin
            self.stage = 3
            self.prof.begin_jog(p.jog_speed, p.accel, p.decel)
            return
        self._tripped = self.switch.on_flag(position)
        self._watch = self.switch.leaving(position)
        self.prof.begin_jog(d * p.speed, p.accel, p.decel)

    def watch(self) -> Crossing | None:
        """The condition the present phase waits for (``None``: it ends with its motion)."""
        return self._watch

    def rewire(self, switch: HomeSwitch, position: int) -> None:
        """The home input follows ``switch`` from now on: it changed otherwise than by the
        motion (the simulator's test hook held the switch, released it or moved it), with the
        axis at ``position`` (caller's frame). A phase waiting for the input to change sees it
        changed at ``position`` if it differs now from what it was when the phase began (its
        watch is met there), and otherwise waits for the new switch's edge. The index pulses
        of a phase that looks for one are kept (the pulse it latched is where it returns).
        """
        self.switch = switch
        if self.stage not in (1, 2) or self._watch is None:
            return
        if switch.on_flag(position) != self._tripped:
            self._watch = Crossing(position, 1)  # (met at once)
        else:
            self._watch = switch.leaving(position)

    def fire(self, position: int) -> None:
        """The watched condition turned true at the last sample (``position``: caller's frame).

        Nothing more happens once an ``ST`` or a limit ramps the axis down (its stop code
        shows): the sequence ends with that ramp (:meth:`settle`), whatever it passes on the
        way (the home switch's edge, an index pulse).
        """
        self._watch = None
        prof = self.prof
        if prof.moving and prof.stop_code != 0:  # (ST's or a limit's ramp: its code shows)
            return
        if self.stage == 1:
            self._decelerate()
        elif self.stage == 2:
            prof.halt(self.code)
            if self.params.stepper:
                self._finish(prof.position)
            else:
                self._index_phase(position)
        elif self.stage == 3:
            self._decelerate()  # the index crossed is the one _index_phase latched

    def settle(self) -> None:
        """The present phase's motion ended (the profiler is idle): go on, or end."""
        prof = self.prof
        expected = 1 if self.stage == 4 else self.code
        if prof.stop_code != expected or prof.moving or self._watch is not None:
            self.stage = 0  # ST, AB or a limit ended it: the sequence is over
            return
        p = self.params
        if self.stage == 1:
            if self.kind == "FE":
                self.stage = 0
                return
            self.stage = 2
            self._tripped = self.switch.on_flag(prof.position + self.origin)
            self._watch = self.switch.leaving(prof.position + self.origin)
            prof.begin_jog(-self._direction * p.home_speed, p.accel, p.decel)
        elif self.stage == 3:
            self.stage = 4
            if prof.position == self._latched:
                self._finish(self._latched)
                return
            prof.begin_move(self._latched, p.home_speed, p.accel, p.decel)
        elif self.stage == 4:
            self._finish(self._latched)

    # ---- helpers -----------------------------------------------------------------------
    def _decelerate(self) -> None:
        prof = self.prof
        prof.limit_stop(self.code)
        if self.kind != "FE":
            prof.stop_code = 0  # still running: _SC reads 0 until the last phase ends

    def _index_phase(self, position: int) -> None:
        p = self.params
        self.stage = 3
        cross = self.switch.next_index(position, 1)  # forward to the index (Optima HM text)
        self._watch = cross
        self._latched = cross.threshold - self.origin
        self.prof.begin_jog(p.home_speed, p.accel, p.decel)

    def _finish(self, zero: int) -> None:
        self.zero_at = zero
        self.prof.stop_code = self.code
        self.stage = 0


@dataclass(frozen=True)
class HomingPrediction:
    """A predicted homing sequence.

    Attributes:
        profile: the reference positions, in the frame the sequence ends with (0 at the index
            after HM or FI; unchanged after FE).
        zero_at: where position 0 is in the frame at the start (``None`` after FE).
        stop_code: 10 after HM/FI, 9 after FE.
    """

    profile: Profile
    zero_at: int | None
    stop_code: int


def homing(
    kind: str,
    params: HomingParams,
    switch: HomeSwitch,
    *,
    start: int = 0,
    sample_period: float = 1 / 1024,
    max_samples: int = MAX_SAMPLES,
    events: Sequence[Event] = (),
) -> HomingPrediction:
    """Predict HM, FE or FI from ``start`` with the switch and index positions of ``switch``.

    ``events``: ``AC`` changes while the sequence runs (:class:`~galil.predict.SetAccel`, at
    their time from ``BG``). As on the simulator, each re-plans the phase in progress from the
    next sample (the engine's ``set_accel``; not a deceleration already begun), and the later
    phases start with the settings in force at ``BG`` (:class:`HomingSequence`).

    Raises:
        InvalidArgument: the sequence does not end within ``max_samples`` (the switch is not
            in the direction of travel, a speed is 0 ...); an event other than ``AC``, or at a
            time before ``BG``.
    """
    start, (ts, changes) = whole_counts(start, "start"), _accel_changes(events, sample_period)
    prof = AxisProfiler(sample_period=ts, position=start)
    seq = HomingSequence(kind, prof, params, switch)
    chunks: list[npt.NDArray[np.int64]] = [np.array([start], np.int64)]
    seq.start(start)
    run = 0
    while not seq.done:
        while changes and changes[-1][0] <= prof.sample:
            prof.set_accel(changes.pop()[1])
        # (no step goes past the next change: it takes effect from the sample after it)
        room = changes[-1][0] - prof.sample if changes else _CHUNK
        cross = seq.watch()
        if cross is None:
            end = prof.end_sample
            n = max(1, min((end - prof.sample) if end is not None else _CHUNK, room))
            chunks.append(prof.advance(n))
            run += n
            if not prof.moving:
                seq.settle()
        else:
            ahead = prof.preview(min(_CHUNK, room))
            k = cross.first(ahead)
            if k is None:
                chunks.append(prof.advance(len(ahead)))
                run += len(ahead)
                if not prof.moving:  # stopped before reaching the switch
                    raise InvalidArgument(f"{kind} never reaches its switch or index")
            else:
                chunks.append(prof.advance(k + 1))
                run += k + 1
                seq.fire(int(chunks[-1][-1]))
                if not prof.moving:
                    continue
        if run > max_samples:
            raise InvalidArgument(
                f"{kind} does not end within {max_samples} samples: is the switch in the "
                "direction of travel and every speed above 0?"
            )
    positions = np.concatenate(chunks)
    zero = seq.zero_at
    if zero is not None:
        positions = positions - zero
    profile = Profile.from_samples(
        positions,
        sample_period=ts,
        shape=kind,
        peak_speed=float(max(params.speed, params.home_speed, abs(params.jog_speed))),
        stop_code=seq.code,
    )
    return HomingPrediction(profile, zero, seq.code)


def _accel_changes(
    events: Sequence[Event], sample_period: float
) -> tuple[float, list[tuple[int, float]]]:
    """The sample period in seconds (a time Quantity too), and ``(sample, AC)`` of each
    change, the latest first (the predictor pops from the end)."""
    sample_period = period_seconds(sample_period)
    changes: list[tuple[int, float]] = []
    for ev in events:
        if not isinstance(ev, SetAccel):
            raise InvalidArgument(
                f"a homing prediction follows AC changes only, not {type(ev).__name__}"
            )
        changes.append((sample_of_event(ev.time, sample_period), ev.accel))
    changes.sort(key=lambda c: c[0])  # (stable: of two at one sample, the later wins)
    return sample_period, changes[::-1]


def stepper_output(
    positions: npt.ArrayLike, ks: float, *, start: float | None = None
) -> npt.NDArray[np.float64]:
    """The step position a stepper's KS filter makes of the profiler's ``positions``.

    Model (an assumption): a single-pole filter with a time constant of ``3 * ks`` samples
    (DMC-2x00 manual: "3·KS samples"), the same recursion as IT smoothing.

    Raises:
        InvalidArgument: ``ks`` outside 0.25 .. 64.
    """
    if not (isinstance(ks, (int, float)) and 0.25 <= ks <= 64):
        raise InvalidArgument(f"KS must be in 0.25 .. 64, not {ks!r}")
    r = np.asarray(positions, dtype=np.float64)
    alpha = -math.expm1(-1.0 / (3.0 * ks))
    y0 = float(r[0]) if start is None else float(start)
    return smooth(r, alpha, y0)
