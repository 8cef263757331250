"""Checks before a coordinated-motion sequence is sent, and what streaming it needs.

Every refusal is a :class:`galil.errors.LimitError` that names the segment (in its message)
and, where the path gets there, the sample and time (``sample``, ``time``) at which the
predicted profile would reach the problem.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from galil.codes import tc_text
from galil.errors import InvalidArgument, LimitError
from galil.models import INT32_MAX, ModelSpec
from galil.predict.checks import check_soft_limits, quantise_accel, quantise_speed, resolve_model
from galil.predict.engine import plan_position
from galil.predict.path import Arc, LinearInterp, PathSegment, path_kind
from galil.predict.smoothing import quantise_it
from galil.predict.vector import VectorProfile, vector

__all__ = [
    "QuantisedVector",
    "axis_rates",
    "check_vector",
    "quantise_vector",
    "segment_deadlines",
]

FloatArray = npt.NDArray[np.float64]
Int64Array = npt.NDArray[np.int64]


@dataclass(frozen=True)
class QuantisedVector:
    """VS, VA, VD and VT as the controller stores them (``None`` where none was given)."""

    speed: float | None
    accel: float | None
    decel: float | None
    smoothing: float | None
    sample_period: float
    model: ModelSpec


def quantise_vector(
    model: str | ModelSpec = "DMC-4040",
    *,
    speed: float | None = None,
    accel: float | None = None,
    decel: float | None = None,
    smoothing: float | None = None,
    tm: float | None = None,
) -> QuantisedVector:
    """Quantise VS like SP (down to its resolution), VA/VD like AC/DC, VT like IT.

    Ranges come from the model: VS up to :attr:`ModelSpec.vs_max` (``sp_max`` when unset),
    VA/VD up to :attr:`ModelSpec.va_max` (``ac_max`` when unset). Their steps (and VA/VD's
    minimum) follow ``tm`` as SP's and AC's do (an assumption: docs/decisions/0025,
    "Predictions at any TM").

    Raises:
        LimitError: a value outside the model's range (``name`` VS, VA, VD or VT).
    """
    spec = resolve_model(model)
    ts = spec.sample_period if tm is None else spec.sample_period_for(tm)
    vs_spec = replace(spec, sp_max=spec.vs_max if spec.vs_max is not None else spec.sp_max)
    va_spec = replace(spec, ac_max=spec.va_max if spec.va_max is not None else spec.ac_max)
    vs = None
    if speed is not None:
        vs = quantise_speed(speed, vs_spec, name="VS", tm=tm)
        if vs <= 0:
            step = spec.speed_resolution(tm)
            raise LimitError(
                f"VS {speed!r} counts/s is below the smallest step {step:.6g}",
                name="VS",
                value=speed,
                limit=step,
                model=spec.name,
            )
    vt = None
    if smoothing is not None:
        try:
            vt = quantise_it(smoothing)
        except InvalidArgument as exc:
            raise LimitError(
                str(exc).replace("IT", "VT"),
                name="VT",
                value=smoothing,
                limit=spec.it_range[0],
                model=spec.name,
            ) from None
    return QuantisedVector(
        speed=vs,
        accel=None if accel is None else quantise_accel(accel, va_spec, name="VA", tm=tm),
        decel=None if decel is None else quantise_accel(decel, va_spec, name="VD", tm=tm),
        smoothing=vt,
        sample_period=ts,
        model=spec,
    )


def _reach(total: float, v: float, a: float, d: float, x: float) -> int:
    """First sample at which a plan over ``total`` counts (per-sample units) reaches ``x``."""
    plan = plan_position(0.0, 0.0, float(total), v, a, d)
    t0, p0, v0, acc = plan.tables()
    for i, seg in enumerate(plan.segments):
        travel = seg.duration * (seg.velocity + 0.5 * seg.accel * seg.duration)
        if x <= p0[i] + travel:
            dx = max(0.0, x - p0[i])
            root = math.sqrt(max(0.0, v0[i] * v0[i] + 2.0 * acc[i] * dx))
            tau = 2.0 * dx / (v0[i] + root) if v0[i] + root > 0 else 0.0
            return math.ceil(t0[i] + tau - 1e-9)
    return math.ceil(plan.duration - 1e-9)


@dataclass(frozen=True)
class _Static:
    """What the checks before planning need: per-segment lengths and where they start."""

    lengths: list[float]
    starts: list[float]
    total: float
    v: float
    a: float
    d: float
    ts: float
    model: str

    def refuse(self, i: int, text: str, *, name: str, value: float, limit: float) -> LimitError:
        k = _reach(self.total, self.v, self.a, self.d, self.starts[i])
        return LimitError(
            f"segment {i}: {text} (the path would reach it at t={k * self.ts:.6g} s, sample {k})",
            name=name,
            value=value,
            limit=limit,
            time=k * self.ts,
            sample=k,
            model=self.model,
        )


def _static_for(segs: Sequence[PathSegment], q: QuantisedVector) -> _Static:
    """Segment lengths and starts along the path, and the plan's units, for the checks."""
    for seg in segs:
        path_kind(seg)  # refuses anything that is not a segment
    lengths = [float(seg.length) for seg in segs]
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]]).tolist()
    ts = q.sample_period
    assert q.speed is not None
    assert q.accel is not None
    assert q.decel is not None
    return _Static(
        lengths=lengths,
        starts=[float(x) for x in starts],
        total=float(round(math.fsum(lengths))),
        v=q.speed * ts,
        a=q.accel * ts * ts,
        d=q.decel * ts * ts,
        ts=ts,
        model=q.model.name,
    )


def _static_checks(
    segs: Sequence[PathSegment], st: _Static, spec: ModelSpec, streaming: bool
) -> None:
    kind = path_kind(segs[0])
    for i, seg in enumerate(segs):
        if path_kind(seg) != kind:
            raise st.refuse(i, f"TC 33 {tc_text(33)}", name="TC 33", value=i, limit=0)
        if isinstance(seg, LinearInterp):
            big = max(abs(c) for c in seg.increments)
            if big > spec.li_max:
                raise st.refuse(
                    i,
                    f"LI increment {big} is beyond ±{spec.li_max}",
                    name="LI",
                    value=big,
                    limit=spec.li_max,
                )
            if len(seg.increments) > len(spec.axes):
                raise st.refuse(
                    i,
                    f"LI over {len(seg.increments)} axes; {spec.name} has {len(spec.axes)}",
                    name="LM axes",
                    value=len(seg.increments),
                    limit=len(spec.axes),
                )
        if isinstance(seg, Arc):
            _arc_checks(i, seg, st, spec)
        if st.lengths[i] < spec.vector_segment_min:
            raise st.refuse(
                i,
                f"length {st.lengths[i]:.6g} counts: TC 30 {tc_text(30)}",
                name="TC 30",
                value=st.lengths[i],
                limit=spec.vector_segment_min,
            )
        if st.starts[i] + st.lengths[i] > spec.vector_distance_max:
            raise st.refuse(
                i,
                f"the path passes {spec.vector_distance_max} counts: TC 31 {tc_text(31)}",
                name="TC 31",
                value=st.starts[i] + st.lengths[i],
                limit=spec.vector_distance_max,
            )
    if not streaming and len(segs) > spec.vector_buffer:
        i = spec.vector_buffer
        raise st.refuse(
            i,
            f"{len(segs)} segments do not fit the {spec.vector_buffer}-segment buffer"
            f" (TC 32 {tc_text(32)}); stream them instead",
            name="segment buffer",
            value=len(segs),
            limit=spec.vector_buffer,
        )


def _arc_checks(i: int, arc: Arc, st: _Static, spec: ModelSpec) -> None:
    lo, hi = spec.cr_radius
    if not lo <= arc.radius <= hi:
        raise st.refuse(
            i,
            f"CR radius {arc.radius:g} is outside {lo:g}..{hi:g}",
            name="CR radius",
            value=arc.radius,
            limit=hi if arc.radius > hi else lo,
        )
    for label, angle in (("start angle", arc.start), ("sweep", arc.sweep)):
        if abs(angle) > spec.cr_angle_max:
            raise st.refuse(
                i,
                f"CR {label} {angle:g} is beyond ±{spec.cr_angle_max:g} degrees",
                name="CR angle",
                value=angle,
                limit=spec.cr_angle_max,
            )
    if abs(arc.radius * arc.sweep) > spec.cr_arc_max:
        raise st.refuse(
            i,
            f"CR radius × sweep {arc.radius * arc.sweep:.6g} is beyond ±{spec.cr_arc_max:g}",
            name="CR arc",
            value=arc.radius * arc.sweep,
            limit=spec.cr_arc_max,
        )


def axis_rates(profile: VectorProfile) -> tuple[FloatArray, FloatArray]:
    """Each axis's speed and acceleration along the planned path, sample by sample.

    The vector speed and acceleration resolve onto each axis through the path's direction:
    ``v_axis = v·t`` and ``a_axis = a·t + (v²/r)·n`` (``t`` the unit tangent, ``n`` the unit
    normal towards an arc's centre). ``v`` is the profiler speed before VT smoothing (which
    only lowers the peaks), ``a`` its change to the next sample.

    Returns:
        ``(velocity, acceleration)``, each ``(axes, N + 1)``, counts/s and counts/s², signed.
    """
    lay = profile.layout
    idx = profile.segment
    v = profile.speed
    a = np.zeros_like(v)
    a[:-1] = np.diff(v) / profile.sample_period
    delta = lay.end[idx] - lay.start[idx]
    norm = np.linalg.norm(delta, axis=1)
    tangent = delta / np.where(norm > 0, norm, 1.0)[:, None]
    normal = np.zeros_like(tangent)
    on_arc = lay.arc[idx]
    if on_arc.any():
        k = idx[on_arc]
        counts = lay.counts[k].astype(np.float64)
        u = np.clip((profile.path[on_arc] - lay.bounds[k]) / np.maximum(counts, 1.0), 0, 1)
        phi = np.radians(lay.theta0[k] + u * lay.sweep[k])
        turn = np.sign(lay.sweep[k])
        tangent[on_arc, 0] = -turn * np.sin(phi)
        tangent[on_arc, 1] = turn * np.cos(phi)
        normal[on_arc, 0] = -np.cos(phi) / lay.radius[k]
        normal[on_arc, 1] = -np.sin(phi) / lay.radius[k]
    vel = (v[:, None] * tangent).T
    acc = (a[:, None] * tangent + (v * v)[:, None] * normal).T
    return np.ascontiguousarray(vel), np.ascontiguousarray(acc)


def _per_axis(
    value: float | Sequence[float | None] | None, n: int, default: float | None
) -> list[float | None]:
    if value is None or isinstance(value, (int, float)):
        return [default if value is None else float(value)] * n
    out = [None if v is None else float(v) for v in value]
    if len(out) != n:
        raise InvalidArgument(f"expected {n} per-axis values, got {len(out)}")
    return out


def _names(axes: Sequence[str] | str | None, n: int) -> list[str]:
    if axes is None:
        return [str(i) for i in range(n)]
    names = list(axes)
    if len(names) != n:
        raise InvalidArgument(f"expected {n} axis names, got {len(names)}")
    return names


def _rate_error(
    profile: VectorProfile, seg: int, k: int, axis: str, what: str, value: float, limit: float
) -> LimitError:
    unit = "counts/s" if what == "speed" else "counts/s²"
    return LimitError(
        f"segment {seg}: axis {axis} {what} {value:.6g} {unit} at t={profile.t[k]:.6g} s"
        f" (sample {k}) is beyond its limit {limit:g}",
        name=f"axis {what}",
        value=value,
        limit=limit,
        time=float(profile.t[k]),
        sample=k,
        axis=axis,
    )


def _rate_checks(
    profile: VectorProfile,
    names: list[str],
    speed_limits: list[float | None],
    accel_limits: list[float | None],
) -> None:
    vel, acc = axis_rates(profile)
    for what, values, limits in (("speed", vel, speed_limits), ("acceleration", acc, accel_limits)):
        for i, limit in enumerate(limits):
            if limit is None:
                continue
            over = np.flatnonzero(np.abs(values[i]) > limit * (1 + 1e-9))
            if over.size:
                k = int(over[0])
                value = float(abs(values[i][k]))
                raise _rate_error(profile, int(profile.segment[k]), k, names[i], what, value, limit)
    _short_segment_checks(profile, names, speed_limits, accel_limits)


def _arc_extremes(theta0: float, sweep: float) -> tuple[FloatArray, FloatArray]:
    """Largest |component| per axis of an arc's unit tangent and unit normal."""
    lo, hi = sorted((theta0, theta0 + sweep))
    quarters = np.arange(math.ceil(lo / 90.0), math.floor(hi / 90.0) + 1) * 90.0
    phi = np.radians(np.concatenate([np.linspace(lo, hi, 65), quarters]))
    c, s = np.abs(np.cos(phi)).max(), np.abs(np.sin(phi)).max()
    return np.array([s, c]), np.array([c, s])


def _short_segment_checks(
    profile: VectorProfile,
    names: list[str],
    speed_limits: list[float | None],
    accel_limits: list[float | None],
) -> None:
    """Segments the path crosses in a sample or two: bound them over the samples around them.

    The per-sample check sees only the samples; a short arc crossed between two samples would
    escape it. Here each such segment's largest tangent and normal components are combined
    with the speed and acceleration of the samples on either side (a conservative bound).
    """
    lay = profile.layout
    v = profile.speed
    a = np.zeros_like(v)
    a[:-1] = np.abs(np.diff(v)) / profile.sample_period
    for i in range(len(lay)):
        k0 = max(0, int(np.searchsorted(profile.path, lay.bounds[i], side="right")) - 1)
        k1 = min(profile.samples, int(np.searchsorted(profile.path, lay.bounds[i + 1])))
        if k1 - k0 > 3:
            continue  # samples inside the segment: the per-sample check covered it
        ks = np.arange(k0, k1 + 1)
        if lay.arc[i]:
            t_max, n_max = _arc_extremes(float(lay.theta0[i]), float(lay.sweep[i]))
            curvature = 1.0 / float(lay.radius[i])
        else:
            d = lay.end[i] - lay.start[i]
            norm = float(np.linalg.norm(d))
            t_max = np.abs(d) / norm if norm > 0 else np.zeros_like(d)
            n_max, curvature = np.zeros_like(d), 0.0
        for j, name in enumerate(names):
            speeds = v[ks] * t_max[j]
            accels = a[ks] * t_max[j] + v[ks] ** 2 * curvature * n_max[j]
            for what, values, limit in (
                ("speed", speeds, speed_limits[j]),
                ("acceleration", accels, accel_limits[j]),
            ):
                if limit is None:
                    continue
                over = np.flatnonzero(values > limit * (1 + 1e-9))
                if over.size:
                    k = int(ks[over[0]])
                    value = float(values[over[0]])
                    raise _rate_error(profile, i, k, name, what, value, limit)


def _limit_checks(
    profile: VectorProfile,
    names: list[str],
    forward: list[float | None],
    backward: list[float | None],
) -> None:
    for i in range(profile.axes):
        try:
            check_soft_limits(
                profile.axis(i), forward_limit=forward[i], backward_limit=backward[i], axis=names[i]
            )
        except LimitError as exc:
            k = exc.sample if exc.sample is not None else 0
            raise LimitError(
                f"segment {int(profile.segment[k])}: {exc}",
                name=exc.name,
                value=exc.value,
                limit=exc.limit,
                time=exc.time,
                sample=exc.sample,
                axis=exc.axis,
                model=exc.model,
            ) from None


def check_vector(
    segments: Sequence[PathSegment],
    speed: float,
    accel: float,
    decel: float,
    *,
    model: str | ModelSpec = "DMC-4040",
    start: Sequence[int] | None = None,
    smoothing: float = 1.0,
    tm: float | None = None,
    forward_limits: float | Sequence[float | None] | None = None,
    backward_limits: float | Sequence[float | None] | None = None,
    speed_limits: float | Sequence[float | None] | None = None,
    accel_limits: float | Sequence[float | None] | None = None,
    streaming: bool = False,
    axes: Sequence[str] | str | None = None,
) -> VectorProfile:
    """Every check before a sequence is sent; return its predicted profile.

    In order: VS/VA/VD/VT against the model (quantised); segment kinds (TC 33), LI and CR
    ranges, segment length (TC 30), total distance (TC 31), buffer depth (unless
    ``streaming``); then, on the predicted profile, each axis's speed and acceleration along
    the path (default limits: the model's SP and AC maxima) and each axis's soft limits
    (FL/BL, outward motion only) and 32-bit position range over the whole path.

    Args:
        segments, speed, accel, decel, start, smoothing: as :func:`galil.predict.vector`.
        model: model name or spec. tm: TM in µs (default: the model's default).
        forward_limits, backward_limits: FL and BL per axis (or one value for all), counts.
        speed_limits, accel_limits: per-axis maxima (counts/s, counts/s²).
        streaming: the host streams segments into the buffer as slots free up (no depth
            limit here; see :func:`segment_deadlines`).
        axes: axis names for the messages (default ``"0"``, ``"1"``, ...).

    Raises:
        LimitError: the first check that fails, naming the segment and the sample.
        InvalidArgument: malformed arguments.
    """
    spec = resolve_model(model)
    q = quantise_vector(spec, speed=speed, accel=accel, decel=decel, smoothing=smoothing, tm=tm)
    assert q.speed is not None
    assert q.accel is not None
    assert q.decel is not None
    segs = tuple(segments)
    if not segs:
        raise InvalidArgument("a vector sequence needs at least one segment")
    st = _static_for(segs, q)
    n = len(segs[0].increments) if isinstance(segs[0], LinearInterp) else 2
    names = _names(axes, n)
    fast = (_per_axis(speed_limits, n, spec.sp_max), _per_axis(accel_limits, n, spec.ac_max))
    fl, bl = _per_axis(forward_limits, n, None), _per_axis(backward_limits, n, None)
    _static_checks(segs, st, spec, streaming)
    profile = vector(
        segs, q.speed, q.accel, q.decel, start=start, smoothing=smoothing, model=spec, tm=tm
    )
    _coordinate_checks(profile)
    _rate_checks(profile, names, *fast)
    _limit_checks(profile, names, fl, bl)
    return profile


def _coordinate_checks(profile: VectorProfile) -> None:
    """VP coordinates are 32-bit integers relative to the sequence origin."""
    ends = profile.layout.end
    bad = np.flatnonzero(np.any(np.abs(ends) > INT32_MAX, axis=1))
    if bad.size:
        i = int(bad[0])
        first, _ = profile.samples_of(i)
        raise LimitError(
            f"segment {i} ends {ends[i].tolist()} counts from the sequence start, beyond the"
            " 32-bit range of VP/LI coordinates",
            name="VP range",
            value=float(np.abs(ends[i]).max()),
            limit=INT32_MAX,
            time=first * profile.sample_period,
            sample=first,
        )


def segment_deadlines(profile: VectorProfile) -> Int64Array:
    """Latest sample by which each segment must be in the buffer for the prediction to hold.

    Without ``VE``/``LE`` the controller plans to stop at the end of the segments it has, so
    segment ``i`` must arrive before that plan would start to slow down for the end of
    segment ``i - 1``: while ``s + v²/(2·VD) < bounds[i]`` (``s`` the path position, ``v``
    the speed along the path). A segment added after the engine has committed that many
    samples re-plans from the same state as the full plan (to within a count of rounding).
    Segment 0 must be there at ``BGS`` (deadline 0). Exact to about one sample.
    """
    lay = profile.layout
    decel = profile.speed_settings[2]
    reach = profile.path + 0.5 + profile.speed**2 / (2.0 * decel)
    out = np.zeros(len(lay), dtype=np.int64)
    for i in range(1, len(lay)):
        late = np.flatnonzero(reach >= lay.bounds[i])
        first_late = int(late[0]) if late.size else profile.samples
        out[i] = max(0, first_late - 1)
    return out
