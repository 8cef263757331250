"""Checks before anything is sent: quantised values, model ranges, soft limits, the motion a
path implies (speed and acceleration), contour streams.

Every failure is a :class:`galil.errors.LimitError` that names the value, the limit it crosses,
and, where it applies, the time and sample at which the predicted path crosses it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument, LimitError
from galil.models import ETHERNET_BYTES_PER_S, ModelSpec, get_model
from galil.predict.engine import PlanSamples
from galil.predict.profile import Int64Array, Profile, finite_number
from galil.predict.smoothing import quantise_it

__all__ = [
    "ETHERNET_BYTES_PER_S",
    "Checked",
    "MotionReport",
    "Quantised",
    "StreamReport",
    "check",
    "check_contour",
    "check_motion",
    "check_parameter",
    "check_profile_motion",
    "check_soft_limits",
    "contour_bytes",
    "quantise",
    "quantise_accel",
    "quantise_limits",
    "quantise_speed",
    "quantise_value",
    "resolve_model",
]

FloatArray = npt.NDArray[np.float64]

_POSITION_MAX = 2**31 - 1
_POSITION_MIN = -(2**31)


def resolve_model(model: str | ModelSpec) -> ModelSpec:
    """Accept a model name or a :class:`ModelSpec`."""
    return model if isinstance(model, ModelSpec) else get_model(model)


#: Half the last of the four decimals a number has on the wire, plus half the last bit of the
#: 32.16 fixed point the controller holds it in: a value this close below a step is that step
#: written at four decimals (``SP ?`` answers 4/3 * 83494 = 111325.3333... as
#: ``111325.3333``; at TM 19875 the step 1038.79245... is held as 1038.792449... and printed
#: ``1038.7924``, 5.3e-5 short), and reads back as the step itself.
_WIRE_HALF_DIGIT = (0.5e-4 + 0.5 / 65536) * (1 + 1e-9)


def _steps(value: float, step: float, ceiling: float) -> float:
    """The largest multiple of ``step`` not above ``value`` (>= 0) nor ``ceiling`` (the
    model's maximum); whole numbers as ``int``.

    A multiple already (a value read back) stays itself, whatever the division rounds to,
    and so does one written at four decimals just short of it (:data:`_WIRE_HALF_DIGIT`).
    """
    n = math.floor(value / step)
    top = min(value + _WIRE_HALF_DIGIT, ceiling)
    if (n + 1) * step <= top:
        n += 1
    elif n * step > top:
        n -= 1
    out = n * step
    return int(out) if float(out).is_integer() else float(out)


def quantise_accel(
    value: float,
    model: str | ModelSpec = "DMC-4040",
    *,
    name: str = "AC",
    tm: float | None = None,
) -> float:
    """AC or DC as the controller stores it: rounded down to its resolution, at least one step.

    The step and the minimum are the model's at ``tm`` µs (default: its power-on TM):
    1024 counts/s² at TM 1000, 4096 at TM 500 (:meth:`ModelSpec.accel_resolution`). Whole
    values come back as ``int``.

    Raises:
        LimitError: not positive, not finite, or above the model's maximum.
    """
    spec = resolve_model(model)
    if not math.isfinite(value) or value <= 0:
        raise LimitError(
            f"{name} must be a positive number, got {value!r}",
            name=name,
            value=value,
            limit=spec.accel_min(tm),
            model=spec.name,
        )
    if value > spec.ac_max:
        raise LimitError(
            f"{name} {value:g} counts/s² is above the {spec.name} maximum {spec.ac_max}",
            name=name,
            value=value,
            limit=spec.ac_max,
            model=spec.name,
        )
    low = spec.accel_min(tm)
    stored = _steps(value, spec.accel_resolution(tm), spec.ac_max)
    return stored if stored >= low else (int(low) if low.is_integer() else low)


def quantise_speed(
    value: float,
    model: str | ModelSpec = "DMC-4040",
    *,
    name: str = "SP",
    signed: bool = False,
    tm: float | None = None,
) -> float:
    """SP (or JG with ``signed=True``) as stored: magnitude rounded down to the resolution.

    The resolution is the model's at ``tm`` µs (default: its power-on TM): 2 counts/s at
    TM 1000, 8 at TM 250 (:meth:`ModelSpec.speed_resolution`). Whole values come back as
    ``int``.

    Raises:
        LimitError: not finite, negative SP, or above the model's maximum.
    """
    spec = resolve_model(model)
    if not math.isfinite(value) or (value < 0 and not signed):
        raise LimitError(
            f"{name} must be a non-negative number, got {value!r}",
            name=name,
            value=value,
            limit=0,
            model=spec.name,
        )
    if abs(value) > spec.sp_max:
        raise LimitError(
            f"{name} {value:g} counts/s is above the {spec.name} maximum {spec.sp_max}",
            name=name,
            value=value,
            limit=spec.sp_max,
            model=spec.name,
        )
    stored = _steps(abs(value), spec.speed_resolution(tm), spec.sp_max)
    return -stored if value < 0 and stored else stored


@dataclass(frozen=True)
class Quantised:
    """The values the controller will actually use (``None`` where none was given)."""

    speed: float | None
    accel: float | None
    decel: float | None
    smoothing: float | None
    sample_period: float


_COMMANDS = ("SP", "JG", "AC", "DC", "IT", "HV")


def quantise_value(
    command: str, value: float, model: str | ModelSpec = "DMC-4040", *, tm: float | None = None
) -> float:
    """One value as the controller stores it: ``command`` is SP, JG, AC, DC, IT or HV (the
    homing speed: SP's range and step).

    ``tm`` (µs; default the model's power-on TM) sets the step of SP/JG/HV and AC/DC.

    Raises:
        LimitError: outside the model's range. InvalidArgument: unknown command.
    """
    cmd = command.upper()
    if cmd in ("SP", "JG", "HV"):
        return float(quantise_speed(value, model, name=cmd, signed=cmd == "JG", tm=tm))
    if cmd in ("AC", "DC"):
        return float(quantise_accel(value, model, name=cmd, tm=tm))
    if cmd == "IT":
        q = quantise(model, smoothing=value).smoothing
        assert q is not None
        return q
    raise InvalidArgument(f"cannot quantise {command!r}; known: {', '.join(_COMMANDS)}")


def check_parameter(
    command: str,
    value: float,
    model: str | ModelSpec = "DMC-4040",
    *,
    axis: str | None = None,
    tm: float | None = None,
) -> float:
    """Quantise and range-check one SP/JG/AC/DC/IT/HV value (the LimitError names the axis)."""
    if not isinstance(command, str):
        raise InvalidArgument(f"cannot quantise {command!r:.60}; known: {', '.join(_COMMANDS)}")
    value = finite_number(value, command)
    try:
        return quantise_value(command, value, model, tm=tm)
    except LimitError as exc:
        exc.axis = axis
        raise


def quantise_limits(model: str | ModelSpec = "DMC-4040") -> dict[str, tuple[float, float]]:
    """The model's range for each quantised command, after quantisation."""
    spec = resolve_model(model)
    return {
        "SP": (0.0, float(spec.sp_max)),
        "JG": (-float(spec.sp_max), float(spec.sp_max)),
        "AC": (float(spec.ac_min), float(spec.ac_max)),
        "DC": (float(spec.ac_min), float(spec.ac_max)),
        "IT": (1 / 256, 1.0),
        "HV": (0.0, float(spec.sp_max)),
    }


def quantise(
    model: str | ModelSpec = "DMC-4040",
    *,
    speed: float | None = None,
    accel: float | None = None,
    decel: float | None = None,
    smoothing: float | None = None,
    jog: bool = False,
    tm: float | None = None,
) -> Quantised:
    """Quantise SP/JG, AC, DC and IT as ``model`` stores them; check them against its ranges.

    One value at a time: :func:`quantise_value` (or :func:`check_parameter`).

    Args:
        model: model name or spec.
        speed: SP (or JG when ``jog``; then the sign is kept), counts/s.
        accel: AC, counts/s².
        decel: DC, counts/s².
        smoothing: IT.
        jog: ``speed`` is a signed jog speed.
        tm: TM in µs (default: the model's default), sets ``sample_period`` and the steps of
            SP/JG and AC/DC.

    Raises:
        LimitError: a value outside the model's range.
    """
    spec = resolve_model(model)
    ts = spec.sample_period if tm is None else spec.sample_period_for(tm)
    sp = None
    if speed is not None:
        sp = quantise_speed(speed, spec, name="JG" if jog else "SP", signed=jog, tm=tm)
    it = None
    if smoothing is not None:
        try:
            it = quantise_it(smoothing)
        except InvalidArgument as exc:
            raise LimitError(
                str(exc), name="IT", value=smoothing, limit=spec.it_range[0], model=spec.name
            ) from None
    return Quantised(
        speed=sp,
        accel=None if accel is None else quantise_accel(accel, spec, name="AC", tm=tm),
        decel=None if decel is None else quantise_accel(decel, spec, name="DC", tm=tm),
        smoothing=it,
        sample_period=ts,
    )


def check_soft_limits(
    profile: Profile,
    *,
    forward_limit: float | None = None,
    backward_limit: float | None = None,
    axis: str | None = None,
) -> None:
    """Check the whole predicted path, not just its end, against FL and BL.

    Like the controller, only motion *outwards* beyond a limit is refused: an axis that starts
    past FL may move back towards (and inside) it.

    Raises:
        LimitError: at the first sample beyond a limit (``name`` is ``"FL"`` or ``"BL"``).
    """

    def inside(low: int, high: int) -> bool:
        return (
            (forward_limit is None or high <= forward_limit)
            and (backward_limit is None or low >= backward_limit)
            and low >= _POSITION_MIN
            and high <= _POSITION_MAX
        )

    # Quick look first: nothing can be beyond a limit when the whole path lies inside every
    # one of them; the usual case, and cheap (a planned profile knows bounds unsampled).
    if inside(*profile.bounds()):
        return
    hit = next(
        (
            (offset + first[0], int(pos[first[0]]), first[1], first[2])
            for offset, pos, prev in _stretches(profile, inside)
            if (first := _first_beyond(pos, prev, forward_limit, backward_limit)) is not None
        ),
        None,
    )
    if hit is None:
        return
    k, value, name, limit = hit
    t = k * profile.sample_period
    where = f" on axis {axis}" if axis else ""
    raise LimitError(
        f"the path{where} reaches {value} counts at t={t:.6g} s (sample {k}), beyond"
        f" {name} {limit:g}; the move ends at {profile.end}",
        name=name,
        value=value,
        limit=limit,
        time=t,
        sample=k,
        axis=axis,
    )


#: Samples of a long planned move looked at together (:func:`_stretches`).
_STRETCH = 1 << 16


def _stretches(
    profile: Profile, inside: Callable[[int, int], bool]
) -> Iterator[tuple[int, Int64Array, Int64Array]]:
    """``(first sample, positions, each one's previous position)`` of the parts of
    ``profile`` that may leave the limits (``inside(low, high)`` says a part within
    ``low .. high`` cannot), in order.

    A move planned from rest (:class:`~galil.predict.engine.PlanSamples`) is evaluated part by
    part, and only where a part's ends come within a count of a limit (its samples lie within
    one count of its ends, as the whole move's do): a move of hours ending at a limit is
    checked without its samples (28 h ends at 2**31 - 1 at the default speed). Any other
    profile is one part.
    """
    source = profile._source()
    if not isinstance(source, PlanSamples):
        pos = profile.position
        yield 0, pos, np.concatenate((pos[:1], pos[:-1]))
        return
    ends = source.ends()
    for first in range(0, source.samples + 1, _STRETCH):
        last = min(first + _STRETCH, source.samples + 1) - 1
        a, b = ends(first), ends(last)
        if inside(min(a, b) - 1, max(a, b) + 1):
            continue
        lead = max(first - 1, 0)
        values = source.window(lead, last + 1 - lead)
        pos = values[first - lead :]
        yield first, pos, values[: pos.size] if first else np.concatenate((pos[:1], pos[:-1]))


def _first_beyond(
    pos: Int64Array, prev: Int64Array, forward_limit: float | None, backward_limit: float | None
) -> tuple[int, str, float] | None:
    """The first of ``pos`` beyond a limit, moving outwards: ``(index, name, limit)``."""
    checks: list[tuple[str, float, npt.NDArray[np.bool_]]] = []
    if forward_limit is not None:
        checks.append(("FL", forward_limit, (pos > forward_limit) & (pos > prev)))
    if backward_limit is not None:
        checks.append(("BL", backward_limit, (pos < backward_limit) & (pos < prev)))
    checks.append(("position range", _POSITION_MAX, pos > _POSITION_MAX))
    checks.append(("position range", _POSITION_MIN, pos < _POSITION_MIN))
    first: tuple[int, str, float] | None = None
    for name, limit, over in checks:
        hit = np.flatnonzero(over)
        if hit.size and (first is None or int(hit[0]) < first[0]):
            first = (int(hit[0]), name, limit)
    return first


@dataclass(frozen=True)
class MotionReport:
    """The motion a path implies, per axis (what :func:`check_motion` compared).

    Attributes:
        peak_speed: largest |velocity| of any segment, counts/s.
        peak_accel: largest |change of velocity| between neighbouring segments (and from the
            start velocity, and to rest at the end when the path stops), counts/s².
    """

    peak_speed: tuple[float, ...]
    peak_accel: tuple[float, ...]


Limit = float | Sequence[float | None] | None


def _per_axis(limit: Limit, default: float, k: int, name: str) -> FloatArray:
    """A limit for each of ``k`` axes: one value for all, or one per axis (``None``: default)."""
    if limit is None or isinstance(limit, (int, float)):
        values: list[float | None] = [limit] * k
    else:
        values = list(limit)
        if len(values) != k:
            raise InvalidArgument(f"{name} needs one value per axis ({k}), got {len(values)}")
    out = np.array([default if v is None else float(v) for v in values])
    if not np.all(out > 0):
        raise InvalidArgument(f"{name} must be positive, got {values!r}")
    return out


def _motion_arrays(
    increments: npt.ArrayLike | None, positions: npt.ArrayLike | None, samples: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Increments as (segments, axes) floats and the samples of each segment."""
    if (increments is None) == (positions is None):
        raise InvalidArgument("give either increments or positions")
    if positions is not None:
        pos = np.asarray(positions, dtype=np.float64)
        inc = np.diff(pos, axis=0)
    else:
        inc = np.asarray(increments, dtype=np.float64)
    if inc.ndim == 1:
        inc = inc[:, None]
    if inc.ndim != 2:
        raise InvalidArgument(f"a path must be 1-D or (segments, axes), got shape {inc.shape}")
    if not np.all(np.isfinite(inc)):
        raise InvalidArgument("a path must be finite")
    n = np.broadcast_to(np.asarray(samples, dtype=np.float64), inc.shape[:1])
    if not np.all(n > 0):
        raise InvalidArgument("every segment must last at least one sample")
    return inc, n


def check_motion(
    increments: npt.ArrayLike | None = None,
    *,
    positions: npt.ArrayLike | None = None,
    samples: int | npt.ArrayLike = 1,
    model: str | ModelSpec = "DMC-4040",
    sample_period: float | None = None,
    speed_limit: Limit = None,
    accel_limit: Limit = None,
    axes: str | Sequence[str] | None = None,
    start_velocity: float | Sequence[float] = 0.0,
    stops: bool = True,
    rounding: float = 0.0,
) -> MotionReport:
    """Check the speed and acceleration a path implies, per axis, before it is sent.

    The path is a sequence of segments, each moving every axis linearly by its increment over
    its samples (contour segments: ``2**DT`` samples; a sampled profile: one sample each).
    Segment i's velocity is ``increment / (samples * Ts)``; the acceleration is the change of
    velocity between neighbouring segments over the time between their midpoints, from
    ``start_velocity`` at the start of the path (rest by default) and, when ``stops``, to rest
    at its end (one constant acceleration over a first segment from rest gives exactly that
    acceleration).

    Args:
        increments: per-segment increments, shape (segments,) or (segments, axes), counts.
        positions: or the positions at segment boundaries, the start first (one row more).
        samples: samples in each segment (one value, or one per segment).
        model: the model whose ``sp_max`` and ``ac_max`` are the default limits.
        sample_period: seconds per sample (default: the model's).
        speed_limit: counts/s: one for all axes, one per axis (``None`` entries: the model's).
        accel_limit: counts/s², likewise.
        axes: axis names for the errors (a string gives one letter per axis).
        start_velocity: counts/s per axis at the start of the path.
        stops: the path ends at rest (a contour, a move); False for a jog still running.
        rounding: counts each position may be off by (0.5 for rounded per-sample positions):
            widens each limit by what that much rounding can add, so rounding alone never
            fails a check.

    Returns:
        The peak speed and acceleration of each axis.

    Raises:
        LimitError: ``name`` ``"speed"`` or ``"acceleration"`` at the first segment (in time)
            where an axis crosses its limit, with ``value``, ``limit``, ``sample`` (where the
            segment starts; for an acceleration, where the velocity changes), ``time``,
            ``axis`` and the segment in the message.
        InvalidArgument: a malformed path or limit.
    """
    spec = resolve_model(model)
    ts = spec.sample_period if sample_period is None else float(sample_period)
    inc, n = _motion_arrays(increments, positions, samples)
    m, k = inc.shape
    if m == 0:
        return MotionReport((0.0,) * k, (0.0,) * k)
    names, v_max, a_max, v0 = _motion_limits(
        spec, k, axes, speed_limit, accel_limit, start_velocity
    )
    vel, acc, slack, acc_slack, starts = _kinematics(inc, n, ts, v0, stops, rounding)
    tol = 1 + 1e-9
    fast = np.abs(vel) > (v_max[None, :] + slack[:, None]) * tol
    hard = np.abs(acc) > (a_max[None, :] + acc_slack[:, None]) * tol
    # acceleration row j changes the velocity at the start of segment j (row m: the end)
    first = _first_violation(fast, hard)
    if first is not None:
        kind, row, axis = first
        given = speed_limit if kind == "speed" else accel_limit
        _refuse_motion(kind, row, axis, (vel, acc, v_max, a_max, starts), ts, names, spec, given)
    return MotionReport(
        peak_speed=tuple(float(x) for x in np.abs(vel).max(axis=0, initial=0.0)),
        peak_accel=tuple(float(x) for x in np.abs(acc).max(axis=0, initial=0.0)),
    )


def _motion_limits(
    spec: ModelSpec,
    k: int,
    axes: str | Sequence[str] | None,
    speed_limit: Limit,
    accel_limit: Limit,
    start_velocity: float | Sequence[float],
) -> tuple[list[str | None], FloatArray, FloatArray, FloatArray]:
    """Axis names, speed and acceleration limits and start velocities, one per axis."""
    names: list[str | None] = [None] * k if axes is None else list(axes)
    if len(names) != k:
        raise InvalidArgument(f"axes names {len(names)} axes, the path has {k}")
    v_max = _per_axis(speed_limit, float(spec.sp_max), k, "speed_limit")
    a_max = _per_axis(accel_limit, float(spec.ac_max), k, "accel_limit")
    v0 = np.broadcast_to(np.asarray(start_velocity, dtype=np.float64), (k,))
    return names, v_max, a_max, v0


def _kinematics(
    inc: FloatArray,
    n: FloatArray,
    ts: float,
    v0: FloatArray,
    stops: bool,
    rounding: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Segment velocities, the accelerations between them, their rounding slack, and where
    each segment starts (the last entry: the total)."""
    k = inc.shape[1]
    starts = np.concatenate(([0.0], np.cumsum(n)))  # sample where each segment starts; total
    vel = inc / (n * ts)[:, None]
    slack = 2 * rounding / (n * ts)  # velocity error from rounding, per segment
    knots_t = np.concatenate(([0.0], starts[:-1] + n / 2, starts[-1:] if stops else []))
    knots_v = np.vstack([v0, vel, np.zeros((1, k))] if stops else [v0, vel])
    knots_s = np.concatenate(([0.0], slack, [0.0] if stops else []))
    dt = np.diff(knots_t) * ts
    acc = np.diff(knots_v, axis=0) / dt[:, None]
    acc_slack = (knots_s[:-1] + knots_s[1:]) / dt
    return vel, acc, slack, acc_slack, starts


def _first_violation(
    fast: npt.NDArray[np.bool_], hard: npt.NDArray[np.bool_]
) -> tuple[str, int, int] | None:
    """The earliest (row, axis) over limit: speed rows are segments, acceleration rows the
    changes at segment starts; at the same start the acceleration comes first."""
    best: tuple[int, int, str, int] | None = None
    for kind, mask, order in (("speed", fast, 1), ("acceleration", hard, 0)):
        rows, cols = np.nonzero(mask)
        if rows.size:
            key = (int(rows[0]), order, kind, int(cols[0]))
            if best is None or key[:2] < best[:2]:
                best = key
    return None if best is None else (best[2], best[0], best[3])


def _refuse_motion(
    kind: str,
    row: int,
    axis: int,
    arrays: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
    ts: float,
    names: Sequence[str | None],
    spec: ModelSpec,
    given: Limit,
) -> None:
    """Raise the LimitError for ``kind`` at ``row`` (a segment, or a change of speed)."""
    vel, acc, v_max, a_max, starts = arrays
    m = vel.shape[0]
    sample = int(starts[row])
    t = sample * ts
    name = names[axis]
    on = f" on axis {name}" if name else ""
    if kind == "speed":
        value, limit, unit = float(vel[row, axis]), float(v_max[axis]), "counts/s"
        where = f"segment {row} (samples {sample}..{int(starts[row + 1])})"
    else:
        value, limit, unit = float(acc[row, axis]), float(a_max[axis]), "counts/s²"
        if row == 0:
            where = f"the start into segment 0 (sample {sample})"
        elif row == m:
            where = f"the stop after segment {m - 1} (sample {sample})"
        else:
            where = f"segment {row - 1} -> {row} (sample {sample})"
    own = given is not None and (isinstance(given, (int, float)) or list(given)[axis] is not None)
    source = "the limit given" if own else f"the {spec.name} maximum"
    raise LimitError(
        f"the path{on} needs {kind} {abs(value):.6g} {unit} at {where}, t={t:.6g} s;"
        f" {source} is {limit:.6g} {unit}",
        name=kind,
        value=abs(value),
        limit=limit,
        time=t,
        sample=sample,
        axis=name,
        model=spec.name,
        segment=min(row, m - 1),
    )


def check_profile_motion(
    profile: Profile,
    *,
    model: str | ModelSpec = "DMC-4040",
    speed_limit: float | None = None,
    accel_limit: float | None = None,
    axis: str | None = None,
) -> MotionReport:
    """:func:`check_motion` over a predicted profile (a jog, a move), sample by sample.

    The positions are whole counts, so each limit is widened by what half a count of
    rounding per sample can add. A profile still moving at its end (a jog without a stop,
    stop code 0) is not required to stop.
    """
    return check_motion(
        positions=profile.position,
        model=model,
        sample_period=profile.sample_period,
        speed_limit=speed_limit,
        accel_limit=accel_limit,
        axes=None if axis is None else [axis],
        start_velocity=float(profile.velocity[0]),
        stops=profile.stop_code != 0,
        rounding=0.5,
    )


@dataclass(frozen=True)
class StreamReport:
    """How a contour stream fares on a link.

    Attributes:
        link_rate: bytes/s assumed for the link (after the utilisation margin).
        needed_rate: average bytes/s the segments need.
        bytes_total: bytes to send.
        min_slack: smallest margin, seconds, between a segment's arrival and its start,
            over every segment but the first (which starts as it arrives: the stream's time
            begins there); ``inf`` for a single segment.
        buffer_depth: contour segments the controller can hold.
    """

    link_rate: float
    needed_rate: float
    bytes_total: int
    min_slack: float
    buffer_depth: int


def contour_bytes(increments: npt.ArrayLike, dt: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Bytes on the wire per segment for one axis: ``CD c`` (``CD c=n`` when DT changes) + CR."""
    c = np.asarray(increments, dtype=np.int64)
    n = np.broadcast_to(np.asarray(dt, dtype=np.int64), c.shape)
    digits = np.where(c == 0, 1, np.floor(np.log10(np.maximum(np.abs(c), 1))).astype(np.int64) + 1)
    out = 3 + digits + (c < 0) + 1  # "CD " + digits + sign + CR
    changes = np.ones(c.shape, dtype=bool)
    changes[1:] = n[1:] != n[:-1]
    out = out + np.where(changes, 2, 0)  # "=n"
    result: npt.NDArray[np.int64] = out.astype(np.int64)
    return result


def check_contour(
    increments: npt.ArrayLike,
    dt: int | Sequence[int],
    *,
    model: str | ModelSpec = "DMC-4040",
    baud: float | None = None,
    link_rate: float | None = None,
    ethernet: bool = False,
    buffer_depth: int | None = None,
    bytes_per_segment: int | Sequence[int] | None = None,
    utilisation: float = 0.8,
    preload: bool = False,
    sample_period: float | None = None,
    axis: str | None = None,
    speed_limit: float | None = None,
    accel_limit: float | None = None,
) -> StreamReport | None:
    """Check contour segments against the model's CD/DT ranges, the motion they imply and,
    given a link, the stream.

    The motion: each segment's speed against ``speed_limit`` (default the model's SP
    maximum) and the change of speed between segments, from rest at the start and to rest at
    the end, against ``accel_limit`` (default the model's AC maximum); see
    :func:`check_motion`.

    The stream model: the host sends segments back to back at ``utilisation`` x the link's byte
    rate (a serial port at B baud moves B/10 bytes/s), never more than ``buffer_depth`` ahead;
    contour motion starts when the first segment arrives (or, with ``preload``, the first
    ``buffer_depth``); every segment must arrive before the previous one ends.

    Returns:
        A :class:`StreamReport` when a link was given, else ``None``.

    Raises:
        LimitError: ``"CD"`` or ``"DT"`` out of range (``sample`` is the segment's first sample),
            ``"speed"`` or ``"acceleration"`` over its limit (see :func:`check_motion`),
            ``"link byte rate"`` when the average need exceeds the link, ``"contour stream"``
            when the buffer would run dry (``time``/``sample`` where it does).
    """
    spec = resolve_model(model)
    ts = spec.sample_period if sample_period is None else sample_period
    c = np.asarray(increments, dtype=np.int64).ravel()
    n = _dt_exponents(dt, c.shape, spec, axis)
    lengths = np.left_shift(np.int64(1), np.clip(n, 0, 62))
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]) if c.size else np.zeros(0, np.int64)
    _check_segment_ranges(c, n, starts, spec, ts, axis)
    check_motion(
        c,
        samples=lengths,
        model=spec,
        sample_period=ts,
        speed_limit=speed_limit,
        accel_limit=accel_limit,
        axes=None if axis is None else [axis],
    )
    raw_rate = _link_rate(baud, link_rate, ethernet, utilisation)
    if raw_rate is None:
        return None
    depth = spec.contour_buffer if buffer_depth is None else int(buffer_depth)
    if depth < 1:
        raise InvalidArgument(f"buffer depth must be >= 1, got {depth}")
    b = (
        contour_bytes(c, n)
        if bytes_per_segment is None
        else np.broadcast_to(np.asarray(bytes_per_segment, dtype=np.int64), c.shape)
    )
    return _check_stream(
        b, lengths * ts, starts, (raw_rate, utilisation, depth, preload), ts, axis, spec
    )


def _dt_exponents(
    dt: int | Sequence[int], shape: tuple[int, ...], spec: ModelSpec, axis: str | None
) -> npt.NDArray[np.int64]:
    """DT per segment (one for all, or one each) as int64 exponents; their range is checked
    with the segments'.

    Raises:
        LimitError: an int no int64 holds (10**400).
    """
    try:
        return np.broadcast_to(np.asarray(dt, dtype=np.int64), shape)
    except OverflowError:
        low, high = spec.dt_range
        raise LimitError(
            f"DT {dt!r:.40} is outside {low}..{high}", name="DT", axis=axis, model=spec.name
        ) from None


def _link_rate(
    baud: float | None, link_rate: float | None, ethernet: bool, utilisation: float
) -> float | None:
    """Bytes per second of the link given (``None``: no link, no stream check)."""
    if baud is None and link_rate is None and not ethernet:
        return None
    if not 0 < utilisation <= 1:
        raise InvalidArgument(f"utilisation must be in (0, 1], got {utilisation!r}")
    if link_rate is not None:
        raw_rate = float(link_rate)
    elif baud is not None:
        raw_rate = float(baud) / 10.0
    else:
        raw_rate = ETHERNET_BYTES_PER_S
    if not raw_rate > 0:
        raise InvalidArgument(f"link rate must be positive, got {raw_rate!r}")
    return raw_rate


def _check_segment_ranges(
    c: npt.NDArray[np.int64],
    n: npt.NDArray[np.int64],
    starts: npt.NDArray[np.int64],
    spec: ModelSpec,
    ts: float,
    axis: str | None,
) -> None:
    """DT and CD of every segment within the model's ranges."""
    lo, hi = spec.dt_range
    bad = np.flatnonzero((n < lo) | (n > hi))
    if bad.size:
        i = int(bad[0])
        raise LimitError(
            f"DT {int(n[i])} of segment {i} is outside {lo}..{hi} on {spec.name}",
            name="DT",
            value=int(n[i]),
            limit=hi if n[i] > hi else lo,
            time=float(starts[i] * ts),
            sample=int(starts[i]),
            axis=axis,
            model=spec.name,
            segment=i,
        )
    # Not np.abs: the most negative int64 has no positive counterpart and stays negative.
    cd_lo, cd_hi = spec.cd_range
    bad = np.flatnonzero((c > cd_hi) | (c < cd_lo))
    if bad.size:
        i = int(bad[0])
        raise LimitError(
            f"CD {int(c[i])}{'' if axis is None else f' on {axis}'} (segment {i},"
            f" t={starts[i] * ts:.6g} s) is outside"
            f" {cd_lo}..{cd_hi} on {spec.name}",
            name="CD",
            value=int(c[i]),
            limit=cd_hi if c[i] > cd_hi else cd_lo,
            time=float(starts[i] * ts),
            sample=int(starts[i]),
            axis=axis,
            model=spec.name,
            segment=i,
        )


def _check_stream(
    b: npt.NDArray[np.int64],
    durations: FloatArray,
    starts: npt.NDArray[np.int64],
    link: tuple[float, float, int, bool],
    ts: float,
    axis: str | None,
    spec: ModelSpec,
) -> StreamReport:
    """Segments of ``b`` bytes sent back to back: does each arrive before it is needed?"""
    raw_rate, utilisation, depth, preload = link
    rate = raw_rate * utilisation
    total_bytes = int(b.sum())
    if b.size == 0:
        return StreamReport(rate, 0.0, 0, math.inf, depth)
    total_time = float(durations.sum())
    needed = total_bytes / total_time
    if needed > rate:
        raise LimitError(
            f"contour needs {needed:.6g} bytes/s on average but the link gives {rate:.6g}"
            f" ({utilisation:.0%} of {raw_rate:.6g} bytes/s)",
            name="link byte rate",
            value=needed,
            limit=rate,
            axis=axis,
            model=spec.name,
        )
    sent = np.cumsum(b) / rate  # completion times if sent back to back from t = 0
    first = min(depth, b.size) - 1 if preload else 0
    s0 = float(sent[first])
    seg_start = s0 + np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    # Segment i may be sent once segment i - depth has left the buffer (started).
    gate = np.zeros(b.size)
    if b.size > depth:
        gate[depth:] = seg_start[: b.size - depth]
    prev = np.concatenate([[0.0], sent[:-1]])
    arrive = sent + np.maximum.accumulate(gate - prev)
    slack = seg_start - arrive
    late = np.flatnonzero(slack < -1e-12)
    if late.size:
        i = int(late[0])
        k = int(starts[i])
        raise LimitError(
            f"contour buffer runs dry: segment {i} arrives at {arrive[i]:.6g} s but is needed at"
            f" {seg_start[i]:.6g} s (link {rate:.6g} bytes/s, {int(b[i])} bytes for"
            f" {durations[i] * 1e3:.4g} ms)",
            name="contour stream",
            value=float(arrive[i]),
            limit=float(seg_start[i]),
            time=k * ts,
            sample=k,
            axis=axis,
            model=spec.name,
            segment=i,
        )
    margin = float(slack[1:].min()) if slack.size > 1 else math.inf
    return StreamReport(rate, needed, total_bytes, margin, depth)


def _check_profile(
    profile: Profile,
    spec: ModelSpec,
    forward_limit: float | None,
    backward_limit: float | None,
    axis: str | None,
    speed_limit: float | None,
    accel_limit: float | None,
) -> None:
    """A predicted profile against the soft limits, the model's peak speed and its motion."""
    check_soft_limits(
        profile, forward_limit=forward_limit, backward_limit=backward_limit, axis=axis
    )
    if profile.peak_speed > spec.sp_max:
        k = int(np.argmax(np.abs(profile.velocity)))
        raise LimitError(
            f"peak speed {profile.peak_speed:g} counts/s is above the {spec.name} maximum",
            name="speed",
            value=profile.peak_speed,
            limit=spec.sp_max,
            time=float(profile.t[k]),
            sample=k,
            axis=axis,
            model=spec.name,
        )
    check_profile_motion(
        profile, model=spec, speed_limit=speed_limit, accel_limit=accel_limit, axis=axis
    )


@dataclass(frozen=True)
class Checked:
    """Result of :func:`check`: the values the controller will use, and the stream report."""

    quantised: Quantised
    stream: StreamReport | None


def check(
    profile: Profile | None = None,
    *,
    model: str | ModelSpec = "DMC-4040",
    speed: float | None = None,
    accel: float | None = None,
    decel: float | None = None,
    smoothing: float | None = None,
    jog: bool = False,
    forward_limit: float | None = None,
    backward_limit: float | None = None,
    increments: npt.ArrayLike | None = None,
    dt: int | Sequence[int] | None = None,
    baud: float | None = None,
    link_rate: float | None = None,
    ethernet: bool = False,
    buffer_depth: int | None = None,
    axis: str | None = None,
    tm: float | None = None,
    speed_limit: float | None = None,
    accel_limit: float | None = None,
) -> Checked:
    """All pre-send checks in one call (the axis layer's entry point).

    Quantises and range-checks SP/JG, AC, DC and IT for ``model``; checks a predicted
    ``profile`` against the soft limits FL/BL over its whole path and the speed and
    acceleration it implies (:func:`check_profile_motion`: an IP step while jogging is an
    acceleration); checks contour ``increments``/``dt`` against CD/DT ranges, the motion they
    imply and, given a link, the streaming feasibility. ``speed_limit`` (counts/s) and
    ``accel_limit`` (counts/s²) replace the model's maxima for this axis.

    Raises:
        LimitError: the first check that fails, naming the value, the limit and where.
    """
    spec = resolve_model(model)
    q: Quantised = quantise(
        spec, speed=speed, accel=accel, decel=decel, smoothing=smoothing, jog=jog, tm=tm
    )
    if profile is not None:
        _check_profile(profile, spec, forward_limit, backward_limit, axis, speed_limit, accel_limit)
    stream = None
    if increments is not None:
        if dt is None:
            raise InvalidArgument("contour increments need dt")
        stream = check_contour(
            increments,
            dt,
            model=spec,
            baud=baud,
            link_rate=link_rate,
            ethernet=ethernet,
            buffer_depth=buffer_depth,
            sample_period=q.sample_period,
            axis=axis,
            speed_limit=speed_limit,
            accel_limit=accel_limit,
        )
    return Checked(quantised=q, stream=stream)
