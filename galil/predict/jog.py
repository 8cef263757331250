"""Jog (JG then BG): ramps between speeds, speed changes at given times, ST."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import cast

from galil.errors import InvalidArgument
from galil.models import ModelSpec
from galil.predict.counts import whole_counts
from galil.predict.engine import AxisProfiler
from galil.predict.move import (
    Abort,
    Event,
    SetSpeed,
    Stop,
    _plain_settings,
    _resolve,
    _Run,
    drive,
    run_profile,
    sample_of_event,
)
from galil.predict.profile import Profile
from galil.predict.quantities import no_quantity, period_seconds, seconds

__all__ = ["jog"]


def jog(
    speed: float,
    accel: float,
    decel: float,
    *,
    changes: Sequence[tuple[float, float]] = (),
    stop_at: float | None = None,
    duration: float | None = None,
    events: Sequence[Event] = (),
    sample_period: float = 1 / 1024,
    smoothing: float | None = 1.0,
    start: int = 0,
    initial_speed: float = 0.0,
    model: str | ModelSpec | None = None,
) -> Profile:
    """Predict a jog at the signed ``speed`` (counts/s).

    |v| grows at ``accel`` and shrinks at ``decel``; a change of sign passes through zero.

    Args:
        speed: JG, counts/s (signed).
        accel: AC, counts/s².
        decel: DC, counts/s².
        changes: ``(time, new_speed)`` pairs: JG in motion at ``time`` seconds.
        stop_at: ST at this time (seconds): the profile ends when the axis has stopped.
        duration: predict this many seconds. Without ``stop_at`` or ``duration`` the
            prediction runs until the last ramp has reached its speed.
        events: further changes in motion (:class:`~galil.predict.move.SetAccel`,
            :class:`~galil.predict.move.SetDecel`, :class:`~galil.predict.move.Increment`,
            :class:`~galil.predict.move.Abort` ...).
        sample_period: seconds per sample.
        smoothing: IT (1 or ``None``: none).
        start: position at sample 0.
        initial_speed: velocity at sample 0 (counts/s): the axis is already jogging, and
            ``speed`` is a JG change in motion.
        model: quantise JG/AC/DC/IT as this model stores them first.

    Raises:
        InvalidArgument: bad arguments (a ``start`` that is not a whole number of counts too).
        CommandError: an event the controller would refuse.
    """
    start = whole_counts(start, "start")
    _plain_settings(speed, accel, decel, smoothing)
    no_quantity(initial_speed, "initial_speed", "counts/s")
    sample_period = period_seconds(sample_period)
    stop_at = cast("float | None", seconds(stop_at, "stop_at"))
    duration = cast("float | None", seconds(duration, "duration"))
    _validate_jog(speed, accel, decel)
    speed, accel, decel, smoothing, sample_period = _resolve(
        speed, accel, decel, smoothing, sample_period, model, jog=True
    )
    ts = sample_period
    all_events = _jog_events(changes, events, stop_at)

    def fresh() -> AxisProfiler:
        eng = AxisProfiler(sample_period=ts, position=start)
        if initial_speed:
            eng.resume_jog(initial_speed, speed, accel, decel, smoothing)
        else:
            eng.begin_jog(speed, accel, decel, smoothing)
        return eng

    until = None if duration is None else sample_of_event(duration, ts)
    # (stop_at is a Stop among the events)
    settle = until is None and not any(isinstance(e, (Stop, Abort)) for e in all_events)

    def go(eng: AxisProfiler, out: _Run) -> None:
        if settle:
            _run_until_settled(eng, all_events, speed, accel, decel, smoothing, out)
        else:
            drive(eng, all_events, speed=speed, accel=accel, decel=decel, until=until, out=out)

    return run_profile(
        fresh, go, start=start, shape=lambda begun, eng: "jog", start_velocity=initial_speed
    )


def _validate_jog(speed: float, accel: float, decel: float) -> None:
    for name, value in (("accel", accel), ("decel", decel)):
        if not (math.isfinite(value) and value > 0):
            raise InvalidArgument(f"{name} must be a positive number, got {value!r}")
    if not math.isfinite(speed):
        raise InvalidArgument(f"speed must be finite, got {speed!r}")


def _jog_events(
    changes: Sequence[tuple[float, float]], events: Sequence[Event], stop_at: float | None
) -> list[Event]:
    out: list[Event] = [SetSpeed(t, s) for t, s in changes]
    out.extend(events)
    if stop_at is not None:
        out.append(Stop(stop_at))
    return out


def _run_until_settled(
    eng: AxisProfiler,
    events: Sequence[Event],
    speed: float,
    accel: float,
    decel: float,
    smoothing: float,
    out: _Run,
) -> None:
    """No end given: run past the last event until the last ramp (and smoothing) settles."""
    ts = eng.sample_period
    last = max((sample_of_event(e.time, ts) for e in events), default=0)
    drive(eng, events, speed=speed, accel=accel, decel=decel, until=last, out=out)
    plan = eng.plan
    extra = 0
    if plan is not None:
        ramp = sum(s.duration for s in plan.segments if math.isfinite(s.duration))
        extra = max(0, math.ceil(ramp - 1e-9) - (eng.sample - last))
    if smoothing < 1.0:
        extra += math.ceil(8 / smoothing)
    drive(eng, (), speed=speed, accel=accel, decel=decel, until=extra, out=out)
