"""The one motion engine: a sample-stepping model of one axis of the controller's profiler.

:class:`AxisProfiler` is driven by the predictor (with a schedule of events) and by the
simulator's servo loop. Both get identical reference positions for identical calls at identical
samples, however they chunk :meth:`AxisProfiler.advance`.

Inside, time is counted in samples and distance in counts. A kinematic plan (position move,
jog, stop ramp) is a list of constant-acceleration segments anchored at the sample where the
command was given; the position at any sample is a closed form, evaluated with numpy for whole
chunks at once. The position is kept at 1/65536 count, as the controller does, and ``r[k]`` is
that rounded to the nearest count. See ``shared/reference/profiler-model.md``.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from galil.codes import tc_text
from galil.errors import CommandError, InvalidArgument
from galil.predict.contour_queue import ContourQueue
from galil.predict.smoothing import IT_MAX, IT_STORED_MIN, SmoothCache

__all__ = [
    "FRACTION",
    "AxisProfiler",
    "KinematicPlan",
    "PlanSamples",
    "Segment",
    "final_decel",
    "plan_from_rest",
    "plan_jog",
    "plan_position",
    "plan_stop",
    "ramping",
    "sample_plan",
    "slewing",
]

_new = object.__new__

#: The controller carries position with 16 fractional bits.
FRACTION = 65536
# Slack, in counts, when deciding whether the present stopping distance fits the remaining
# distance: re-plans start from a position quantised to 1/65536 count.
_EPS = 1e-4


Int64Array = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


def _refuse(code: int, command: str) -> CommandError:
    return CommandError(code, tc_text(code), command)


class Segment(NamedTuple):
    """One phase of constant acceleration, in samples and counts (signed).

    A named tuple (immutable, and several times cheaper to build than a frozen dataclass:
    a move is planned in a few microseconds).
    """

    duration: float
    velocity: float
    accel: float


@dataclass(frozen=True)
class KinematicPlan:
    """A piecewise-quadratic trajectory from a start state, in samples and counts.

    Attributes:
        x0: start position (counts, may be fractional).
        segments: consecutive constant-acceleration phases; the last one of a jog is open-ended
            (``duration == inf``).
        x_end: exact end position (the target of a position move).
        duration: closed-form duration in samples (``inf`` for a jog).
        peak: largest |velocity| reached, counts/sample.
        shape: ``"trapezoid"``, ``"triangle"``, ``"none"`` (already there), ``"jog"``,
            ``"stop"``.
    """

    x0: float
    segments: tuple[Segment, ...]
    x_end: float
    duration: float
    peak: float
    shape: str

    def tables(self) -> tuple[list[float], list[float], list[float], list[float]]:
        """Return segment start times, start positions, start velocities and accelerations."""
        if not self.segments:
            return [0.0], [self.x0], [0.0], [0.0]
        t0: list[float] = []
        p0: list[float] = []
        v0: list[float] = []
        a: list[float] = []
        t = 0.0
        x = self.x0
        for s in self.segments:
            t0.append(t)
            p0.append(x)
            v0.append(s.velocity)
            a.append(s.accel)
            if math.isfinite(s.duration):
                x = x + s.duration * (s.velocity + 0.5 * s.accel * s.duration)
                t += s.duration
        return t0, p0, v0, a


def _ramp(v_from: float, v_to: float, rate: float) -> Segment:
    """A segment changing velocity from ``v_from`` to ``v_to`` at ``rate`` (> 0)."""
    dv = v_to - v_from
    return Segment(abs(dv) / rate, v_from, math.copysign(rate, dv))


def _travel(x0: float, segs: list[Segment]) -> float:
    """Position after running ``segs`` from ``x0``."""
    for seg in segs:
        x0 += seg.duration * (seg.velocity + 0.5 * seg.accel * seg.duration)
    return x0


def plan_position(
    x0: float, v0: float, target: float, v: float, a: float, d: float
) -> KinematicPlan:
    """Plan a position move from the state (``x0``, ``v0``) to ``target``.

    Args:
        x0: present position, counts.
        v0: present velocity, counts/sample (signed).
        target: end position, counts.
            ``x0`` and ``target`` are on the engine's grid of 1/65536 count (a whole count
            for a target), so a distance left is 0 or at least that: the final ramp of a
            state already stopping is then at most a few times ``d``.
        v: slew speed, counts/sample (> 0).
        a: acceleration, counts/sample² (> 0).
        d: deceleration, counts/sample² (> 0).

    Speed grows at ``a`` and shrinks at ``d``. A state moving away from the target first
    decelerates to rest (the engine refuses that case for IP; it only arises numerically).
    """
    segs: list[Segment] = []
    peak = abs(v0)
    dist = target - x0
    s = 1.0 if dist > 0 or (dist == 0 and v0 >= 0) else -1.0
    dd = s * dist
    u0 = s * v0
    shape = "none"
    if u0 < 0:
        # Moving away: come to rest at d, then start over towards the target.
        segs.append(_ramp(s * u0, 0.0, d))
        dd += u0 * u0 / (2 * d)
        u0 = 0.0
    stop_dist = u0 * u0 / (2 * d)
    if stop_dist > dd + _EPS:
        # Cannot stop in time: overshoot, then come back.
        segs.append(_ramp(s * u0, 0.0, d))
        back = plan_position(_travel(x0, segs), 0.0, target, v, a, d)
        segs.extend(back.segments)
        total = sum(x.duration for x in segs)
        peak = max(peak, back.peak)
        return KinematicPlan(x0, tuple(segs), float(target), total, peak, "overshoot")
    if stop_dist >= dd:
        # Already on the final ramp (within rounding): finish at exactly the rate that lands.
        if dd > 0 and u0 > 0:
            segs.append(Segment(2 * dd / u0, s * u0, -s * u0 * u0 / (2 * dd)))
        shape = "triangle" if u0 > 0 else "none"
    elif u0 > v:
        # Slower slew than the present speed: shrink at d, cruise, stop.
        d1 = (u0 * u0 - v * v) / (2 * d)
        segs.append(_ramp(s * u0, s * v, d))
        cruise = dd - d1 - v * v / (2 * d)
        if cruise > 0:
            segs.append(Segment(cruise / v, s * v, 0.0))
        segs.append(_ramp(s * v, 0.0, d))
        shape = "trapezoid"
    else:
        up, shape = _accelerate_cruise_stop(segs, s, u0, dd, v, a, d)
        peak = max(peak, up)
    total = sum(x.duration for x in segs)
    return KinematicPlan(x0, tuple(segs), float(target), total, peak, shape)


def _accelerate_cruise_stop(
    segs: list[Segment], s: float, u0: float, dd: float, v: float, a: float, d: float
) -> tuple[float, str]:
    """Append the ramp up (at ``a``), the cruise and the ramp down (at ``d``) of a move of
    ``dd`` counts in direction ``s`` from speed ``u0``; return the peak speed and the shape."""
    up_sq = (2 * dd * a * d + u0 * u0 * d) / (a + d)
    if up_sq >= v * v:
        up, shape = v, "trapezoid"
    else:
        up, shape = max(math.sqrt(up_sq), u0), "triangle"
    d1 = (up * up - u0 * u0) / (2 * a)
    d3 = up * up / (2 * d)
    if up > u0:
        segs.append(_ramp(s * u0, s * up, a))
    cruise = dd - d1 - d3
    if cruise > 0 and up > 0:
        segs.append(Segment(cruise / up, s * up, 0.0))
    if up > 0:
        segs.append(_ramp(s * up, 0.0, d))
    return up, shape


def plan_from_rest(x0: float, target: float, v: float, a: float, d: float) -> KinematicPlan:
    """``plan_position(x0, 0.0, target, v, a, d)``: a move from rest, the predictor's usual
    case (a hot path). The same operations in the same order, without the branches a start
    from rest never takes (moving away, overshoot, slowing from above ``v``) nor the calls."""
    dist = target - x0
    s = 1.0 if dist > 0 or dist == 0 else -1.0
    dd = s * dist
    u0 = s * 0.0
    stop_dist = u0 * u0 / (2 * d)
    if stop_dist > dd + _EPS or stop_dist >= dd or u0 > v:  # (never from rest but dd == 0)
        return plan_position(x0, 0.0, target, v, a, d)
    # _accelerate_cruise_stop, its _ramp()s written out
    up_sq = (2 * dd * a * d + u0 * u0 * d) / (a + d)
    if up_sq >= v * v:
        up, shape = v, "trapezoid"
    else:
        up, shape = max(math.sqrt(up_sq), u0), "triangle"
    d1 = (up * up - u0 * u0) / (2 * a)
    d3 = up * up / (2 * d)
    segs: list[Segment] = []
    if up > u0:
        dv = s * up - s * u0
        segs.append(Segment(abs(dv) / a, s * u0, math.copysign(a, dv)))
    cruise = dd - d1 - d3
    if cruise > 0 and up > 0:
        segs.append(Segment(cruise / up, s * up, 0.0))
    if up > 0:
        dv = 0.0 - s * up
        segs.append(Segment(abs(dv) / d, s * up, math.copysign(d, dv)))
    total = sum(x.duration for x in segs)
    plan = _new(KinematicPlan)  # (a frozen dataclass built without its __init__'s setattrs)
    plan.__dict__.update(
        x0=x0,
        segments=tuple(segs),
        x_end=float(target),
        duration=total,
        peak=max(0.0, up),
        shape=shape,
    )
    return plan


def plan_jog(x0: float, v0: float, speed: float, a: float, d: float) -> KinematicPlan:
    """Plan a jog from (``x0``, ``v0``) towards the signed ``speed`` (all per sample).

    |v| grows at ``a`` and shrinks at ``d``; a sign change passes through zero.
    """
    segs: list[Segment] = []
    v = v0
    if v != 0 and (speed == 0 or (speed > 0) != (v > 0)):
        segs.append(_ramp(v, 0.0, d))
        v = 0.0
    if speed != v:
        segs.append(_ramp(v, speed, a if abs(speed) > abs(v) else d))
    segs.append(Segment(math.inf, speed, 0.0))
    return KinematicPlan(x0, tuple(segs), math.inf, math.inf, max(abs(v0), abs(speed)), "jog")


def sample_plan(plan: KinematicPlan) -> Int64Array:
    """Whole-count positions of a finite plan begun at sample 0, at samples 0 .. its end.

    What :meth:`AxisProfiler.preview_from` gives for a plan in force from sample 0 (the same
    evaluation), without building a profiler: a prediction of a whole move in one call.

    Raises:
        InvalidArgument: the plan has no end (a jog).
    """
    act = _Active(plan, 0)
    if act.end_sample is None:
        raise InvalidArgument("a plan without an end (a jog) cannot be sampled whole")
    return _round_fixed(act.fixed(0, act.end_sample + 1))


@dataclass(frozen=True)
class PlanSamples:
    """A position move planned from rest at sample 0, sampled (:func:`sample_plan`) only
    when called: the source of a :meth:`Profile.planned <galil.predict.Profile.planned>`.

    Attributes:
        plan: a finite plan from rest (``plan_position`` with ``v0 = 0``).
        start: the position at sample 0.
        end: the position from the plan's last sample on.
        samples: that last sample.
    """

    plan: KinematicPlan
    start: int
    end: int
    samples: int

    @classmethod
    def of(cls, plan: KinematicPlan) -> PlanSamples:
        """The start, end and length of ``plan`` (no sampling).

        Raises:
            InvalidArgument: the plan has no end (a jog).
        """
        # What _Active(plan, 0) would give, without its tables (planning pays for them):
        # its end_sample and end_value, and its first segment's constant term p_fixed[0].
        if not math.isfinite(plan.duration):
            raise InvalidArgument("a plan without an end (a jog) cannot be sampled whole")
        end = max(0, math.ceil(plan.duration - 1e-9))
        end_value = (math.floor(plan.x_end * FRACTION + 0.5) + FRACTION // 2) >> 16
        # Sample 0 evaluates to the first segment's constant term (the plan's start), rounded
        # as fixed() rounds it (dt = 0 makes the other terms exact zeros); a plan of no length
        # is at its end.
        first = (
            end_value if end == 0 else (math.floor(plan.x0 * FRACTION + 0.5) + FRACTION // 2) >> 16
        )
        new = _new(cls)  # (frozen: built without its __init__'s setattrs, a hot path)
        new.__dict__.update(plan=plan, start=first, end=end_value, samples=end)
        return new

    @property
    def bounds(self) -> tuple[int, int]:
        """Every sample lies within one count of the ends: from rest, the plan's position never
        decreases (increases, for a negative move) on its way to the target, and the floating
        point of the evaluation can move a rounded sample by one count at most."""
        return min(self.start, self.end) - 1, max(self.start, self.end) + 1

    def __call__(self) -> Int64Array:
        return sample_plan(self.plan)

    def window(self, start: int, n: int) -> Int64Array:
        """The positions at samples ``start .. start+n-1``: those :meth:`__call__` gives."""
        return _round_fixed(_Active(self.plan, 0).fixed(start, n))

    def ends(self) -> Callable[[int], int]:
        """A function of a sample giving its position (as :meth:`window` does), one sample at
        a time and cheaply."""
        act = _Active(self.plan, 0)
        return lambda k: act.rounded(k, 1)[0]


def plan_stop(x0: float, v0: float, d: float) -> KinematicPlan:
    """Plan a ramp to rest at ``d`` from (``x0``, ``v0``); it ends where it comes to rest."""
    if v0 == 0:
        return KinematicPlan(x0, (), x0, 0.0, 0.0, "stop")
    seg = _ramp(v0, 0.0, d)
    x_end = x0 + seg.duration * (seg.velocity + 0.5 * seg.accel * seg.duration)
    return KinematicPlan(x0, (seg,), x_end, seg.duration, abs(v0), "stop")


# Chunks up to this many samples are evaluated with Python floats (same IEEE operations as
# numpy, element by element): below it numpy's fixed cost per call is the larger one.
_SCALAR_MAX = 48
# Chunks up to this many samples that span several segments gather each sample's
# coefficients and evaluate them in one pass (fewer numpy calls, 32 bytes a sample more).
_GATHER_MAX = 4096


def _round_fixed(xq: Int64Array) -> Int64Array:
    """Fixed-point position to the nearest whole count (in place: ``xq`` is consumed)."""
    xq += FRACTION // 2
    np.right_shift(xq, 16, out=xq)
    return xq


class _Active:
    """A kinematic plan placed in time: anchored at sample ``k0``.

    Coefficients are kept as Python floats: numpy applies the same IEEE double operations
    element by element, so the scalar path (:meth:`state`) and the vector path
    (:meth:`fixed`) give bit-identical positions.
    """

    __slots__ = (
        "a",
        "end_sample",
        "end_value",
        "h_fixed",
        "k0",
        "p0",
        "p_fixed",
        "plan",
        "t0",
        "v0",
        "v_fixed",
    )

    def __init__(self, plan: KinematicPlan, k0: int) -> None:
        self.plan = plan
        self.k0 = k0
        self.t0, self.p0, self.v0, self.a = plan.tables()
        self._scale()
        self.end_sample: int | None = None
        self.end_value = 0
        if math.isfinite(plan.duration):
            self.end_sample = k0 + max(0, math.ceil(plan.duration - 1e-9))
            xq = math.floor(plan.x_end * FRACTION + 0.5)
            self.end_value = (xq + FRACTION // 2) >> 16

    def _scale(self) -> None:
        self.p_fixed = [p * FRACTION + 0.5 for p in self.p0]
        self.v_fixed = [v * FRACTION for v in self.v0]
        self.h_fixed = [a * (FRACTION / 2) for a in self.a]

    def shift(self, n: int) -> None:
        """Step the whole plan by ``n`` counts (IP while jogging)."""
        self.p0 = [p + n for p in self.p0]
        self._scale()
        self.end_value += n

    def fixed(self, start: int, n: int) -> Int64Array:
        """Fixed-point (1/65536) positions at the absolute samples ``start .. start+n-1``."""
        out = np.empty(n, np.int64)
        first = start - self.k0
        end = n if self.end_sample is None else min(n, max(0, self.end_sample - start))
        counts = self._counts(first, end)
        if len(counts) > 1 and end <= _GATHER_MAX:
            # A short chunk over several segments (a whole move predicted at once): each
            # sample's coefficients gathered, then one pass, as numpy's fixed cost per call is
            # the larger one here. The operations per element are those of the loop below.
            coef = np.repeat(self._table(), counts, axis=1)
            dt = np.arange(first, first + end, dtype=np.float64)
            dt -= coef[0]
            x = coef[1] * dt
            x += coef[2]
            x *= dt
            x += coef[3]
            np.floor(x, out=x)
            out[:end] = x
        else:
            lo = 0
            for i, count in enumerate(counts):
                if not count:
                    continue
                hi = lo + count
                # Horner form, already scaled to 1/65536 count (and offset by half for rounding).
                dt = np.arange(first + lo, first + hi, dtype=np.float64)
                dt -= self.t0[i]
                x = self.h_fixed[i] * dt
                x += self.v_fixed[i]
                x *= dt
                x += self.p_fixed[i]
                np.floor(x, out=x)
                out[lo:hi] = x
                lo = hi
        if end < n:
            out[end:] = self.end_value * FRACTION
        return out

    def _counts(self, first: int, end: int) -> list[int]:
        """How many of the samples ``first .. first+end-1`` (plan time) fall in each segment."""
        t0 = self.t0
        out = []
        lo = 0
        for i in range(1, len(t0)):
            # Sample tau belongs to segment i-1 while tau < t0[i] (tau is an integer).
            hi = min(end, max(0, math.ceil(t0[i]) - first))
            out.append(hi - lo)
            lo = hi
        out.append(end - lo)
        return out

    def _table(self) -> FloatArray:
        """Rows t0, h, v, p: the coefficients of :meth:`fixed`, one column per segment."""
        table: FloatArray = np.array([self.t0, self.h_fixed, self.v_fixed, self.p_fixed])
        return table

    def rounded(self, start: int, n: int) -> list[int]:
        """Whole-count positions at ``start .. start+n-1``: :meth:`fixed` then rounding.

        The scalar path for short chunks (a host polling every few milliseconds): numpy's
        fixed cost per call dwarfs a few samples of arithmetic. The operations are those of
        :meth:`fixed` and :func:`_round_fixed`, in the same order, on the same IEEE doubles
        (an int minus a float is the int converted exactly, then subtracted), so the values
        are identical.
        """
        return self.step_values(start, n)[0]

    def step_values(self, start: int, n: int) -> tuple[list[int], float]:
        """:meth:`rounded`, and the velocity at the last of those samples (as :meth:`state`)."""
        k = start - self.k0
        stop = k + n
        end = self.end_sample
        floor = math.floor
        half = FRACTION // 2
        t0 = self.t0
        last = len(t0) - 1
        if k < stop and t0[last] <= k and (end is None or stop <= end - self.k0):
            # Every sample in the last segment, none past the end (a jog's cruise polled):
            # what the loop below does for that one segment.
            h, v, t, p = self.h_fixed[last], self.v_fixed[last], t0[last], self.p_fixed[last]
            if h == 0.0:
                values = [(floor(v * (tau - t) + p) + half) >> 16 for tau in range(k, stop)]
            else:
                values = [
                    (floor((h * (dt := tau - t) + v) * dt + p) + half) >> 16
                    for tau in range(k, stop)
                ]
            return values, self.v0[last] + self.a[last] * (float(stop - 1) - t)
        run = stop if end is None else max(k, min(stop, end - self.k0))
        out: list[int] = []
        i = self._segment(float(k)) if k < run else last
        velocity = 0.0
        while k < run:
            # Sample tau belongs to segment i while tau < t0[i+1] (tau is an integer).
            hi = run if i == last else min(run, max(k, math.ceil(t0[i + 1])))
            if hi > k:
                h, v, t, p = self.h_fixed[i], self.v_fixed[i], t0[i], self.p_fixed[i]
                if h == 0.0:
                    # Cruise: h * dt is a zero and adding it to v gives v back, bit for bit.
                    out += [(floor(v * (tau - t) + p) + half) >> 16 for tau in range(k, hi)]
                else:
                    out += [
                        (floor((h * (dt := tau - t) + v) * dt + p) + half) >> 16
                        for tau in range(k, hi)
                    ]
                if hi == stop:
                    velocity = self.v0[i] + self.a[i] * (float(stop - 1) - t)
                k = hi
            i += 1
        if k < stop:
            out += [self.end_value] * (stop - k)
        return out, velocity

    def _segment(self, tau: float) -> int:
        i = len(self.t0) - 1
        while i > 0 and self.t0[i] > tau:
            i -= 1
        return i

    def velocities(self, start: int, n: int) -> FloatArray:
        """Plan velocity (counts/sample) at the absolute samples ``start .. start+n-1``."""
        tau = np.arange(start - self.k0, start - self.k0 + n, dtype=np.float64)
        t0 = np.array(self.t0)
        idx = np.searchsorted(t0, tau, side="right") - 1
        v: FloatArray = np.array(self.v0)[idx] + np.array(self.a)[idx] * (tau - t0[idx])
        if self.end_sample is not None:
            v[tau >= self.end_sample - self.k0] = 0.0
        return v

    def ramp(self, k: int) -> tuple[float, float]:
        """Velocity (counts/sample) and acceleration (counts/sample²) at sample k: those of
        the segment sample k falls in (0 and 0 from the plan's end on)."""
        if self.end_sample is not None and k >= self.end_sample:
            return 0.0, 0.0
        tau = float(k - self.k0)
        i = self._segment(tau)
        return self.v0[i] + self.a[i] * (tau - self.t0[i]), self.a[i]

    def state(self, k: int) -> tuple[float, float]:
        """Position (counts, quantised to 1/65536) and velocity (counts/sample) at sample k."""
        if self.end_sample is not None and k >= self.end_sample:
            return float(self.end_value), 0.0
        tau = float(k - self.k0)
        i = self._segment(tau)
        dt = tau - self.t0[i]
        # the same operations, in the same order, as fixed()
        x = self.h_fixed[i] * dt
        x += self.v_fixed[i]
        x *= dt
        x += self.p_fixed[i]
        return math.floor(x) / FRACTION, self.v0[i] + self.a[i] * dt


def _per_sample(ts: float, speed: float, accel: float, decel: float) -> tuple[float, float, float]:
    """Speed, AC and DC (per second) in counts per sample (``ts`` seconds), checked."""
    for name, value in (("speed", speed), ("accel", accel), ("decel", decel)):
        if not math.isfinite(value):
            raise InvalidArgument(f"{name} must be finite, got {value!r}")
    if accel <= 0 or decel <= 0:
        raise InvalidArgument(f"accel and decel must be > 0, got {accel!r}, {decel!r}")
    return speed * ts, accel * ts * ts, decel * ts * ts


def _checked_smoothing(smoothing: float | None) -> float:
    """IT as the engine filters with it (``None``: 1, none)."""
    if smoothing is None:
        return 1.0
    if not (IT_STORED_MIN <= smoothing <= IT_MAX):
        raise InvalidArgument(
            f"smoothing (IT) must be in [{IT_STORED_MIN}, {IT_MAX}], got {smoothing!r}"
        )
    # IT 0.004 is held as 1/256 (read back as 0.0039): the smallest step filters with it.
    return max(float(smoothing), 1 / 256)


class AxisProfiler:
    """The profiler of one axis, stepped sample by sample (see the interface in ADR 0001).

    Commands take effect from the next sample; refusals raise :class:`CommandError` with the
    controller's TC code. Speeds and accelerations (counts/s, counts/s²) must already be
    quantised as the controller stores them (:func:`galil.predict.quantise`).

    Attributes:
        sample: samples committed so far.
        position: ``r[k]``, the profiler reference (before smoothing), counts.
        reference: ``y[k]`` rounded, the reference after IT smoothing (what ``_RP`` reports).
        velocity: the profiler's velocity at the last sample, counts/s (signed).
        moving: ``_BG``; True until the profile and its smoothing tail are complete.
        mode: ``"idle"``, ``"position"``, ``"jog"`` or ``"contour"``.
        target: ``_PA`` of the position move (the last target otherwise).
        stop_code: 0 running, 1 done, 2/3 limits, 4 ST, 7 AB, 50/51 contour running/stopped.
        smoothing: IT in use.
    """

    def __init__(self, *, sample_period: float = 1 / 1024, position: int = 0) -> None:
        if not (sample_period > 0 and math.isfinite(sample_period)):
            raise InvalidArgument(f"sample period must be positive, got {sample_period!r}")
        self.sample_period = float(sample_period)
        self.sample = 0
        self.position = int(position)
        self.reference = int(position)
        self.velocity = 0.0
        self.moving = False
        self.mode = "idle"
        self.target = int(position)
        self.stop_code = 1
        self.smoothing = 1.0
        self._y = float(position)
        self._active: _Active | None = None
        self._stopping = False
        self._end_code = 1
        self._v = 0.0  # slew / jog speed, counts/sample (jog: signed)
        self._a = 0.0
        self._d = 0.0
        self._sc = SmoothCache(0)  # r and y of the plan in force, when smoothed
        self._cq = ContourQueue(int(position))

    def __deepcopy__(self, memo: dict[int, object]) -> AxisProfiler:
        # A simulator snapshots its axes often. Plans, their tables and the smoothing cache's
        # arrays are replaced, never changed in place, so the copy shares them; the holders
        # (an IP shifts the plan, stepping refills the cache) and the contour queue (appended
        # to) are copied.
        new = copy.copy(self)
        if self._active is not None:
            new._active = copy.copy(self._active)
        new._sc = copy.copy(self._sc)
        new._cq = copy.deepcopy(self._cq, memo)
        return new

    # ---- helpers -----------------------------------------------------------------------
    def _state(self) -> tuple[float, float]:
        if self._active is None:
            return float(self.position), 0.0
        return self._active.state(self.sample)

    def _set_plan(self, plan: KinematicPlan, *, stopping: bool = False, code: int = 1) -> None:
        self._active = _Active(plan, self.sample)
        self._stopping = stopping
        self._end_code = code
        self._invalidate()
        self.moving = True
        # While a forced stop ramps down, _SC already reports why (4 for ST, 2/3 for limits).
        self.stop_code = code if stopping else 0
        self.velocity = self._state()[1] / self.sample_period

    def _invalidate(self) -> None:
        self._sc = SmoothCache(self.sample)

    # ---- commands ----------------------------------------------------------------------
    def begin_move(
        self,
        target: int,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float | None = 1.0,
    ) -> None:
        """PR/PA then BG: a trapezoid or triangle to ``target`` (counts).

        ``smoothing`` is IT; ``None`` is the default, 1 (none).

        Raises:
            CommandError: TC 21 while moving.
        """
        if self.moving:
            raise _refuse(21, "BG")
        it = _checked_smoothing(smoothing)
        v, a, d = _per_sample(self.sample_period, abs(speed), accel, decel)
        if v <= 0:
            raise InvalidArgument(f"speed must be > 0, got {speed!r}")
        self.smoothing = it
        self._v, self._a, self._d = v, a, d
        self.mode = "position"
        self.target = int(target)
        self._set_plan(plan_position(float(self.position), 0.0, float(target), v, a, d))

    def begin_jog(
        self, speed: float, accel: float, decel: float, smoothing: float | None = 1.0
    ) -> None:
        """JG then BG: ramp to the signed ``speed`` and keep going (IT ``None``: 1).

        Raises:
            CommandError: TC 21 while moving.
        """
        if self.moving:
            raise _refuse(21, "BG")
        it = _checked_smoothing(smoothing)
        v, a, d = _per_sample(self.sample_period, speed, accel, decel)
        self.smoothing = it
        self._v, self._a, self._d = v, a, d
        self.mode = "jog"
        self._set_plan(plan_jog(float(self.position), 0.0, v, a, d))

    def resume_jog(
        self,
        velocity: float,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float | None = 1.0,
    ) -> None:
        """Start as if already jogging at ``velocity`` (counts/s), then JG ``speed``.

        For predictions that begin in the middle of a jog (a JG change sent while jogging).
        """
        if self.moving:
            raise _refuse(21, "BG")
        it = _checked_smoothing(smoothing)
        v, a, d = _per_sample(self.sample_period, speed, accel, decel)
        if not math.isfinite(velocity):
            raise InvalidArgument(f"velocity must be finite, got {velocity!r}")
        self.smoothing = it
        self._v, self._a, self._d = v, a, d
        self.mode = "jog"
        self._set_plan(plan_jog(float(self.position), velocity * self.sample_period, v, a, d))

    def set_speed(self, speed: float) -> None:
        """SP (position move) or JG (jog) while moving: re-plan from the present state.

        Ignored while idle, while contouring and during a forced deceleration (ST, limits).
        """
        if not math.isfinite(speed):
            raise InvalidArgument(f"speed must be finite, got {speed!r}")
        if not self.moving or self._stopping or self.mode not in ("position", "jog"):
            return
        x, v0 = self._state()
        if self.mode == "jog":
            self._v = speed * self.sample_period
            self._set_plan(plan_jog(x, v0, self._v, self._a, self._d))
        else:
            if speed == 0:
                raise InvalidArgument("speed of a position move must be > 0")
            self._v = abs(speed) * self.sample_period
            self._set_plan(plan_position(x, v0, float(self.target), self._v, self._a, self._d))

    def set_accel(self, accel: float) -> None:
        """AC while moving: re-plan from the present state (ignored when it has no effect)."""
        if not (math.isfinite(accel) and accel > 0):
            raise InvalidArgument(f"accel must be > 0, got {accel!r}")
        self._a = accel * self.sample_period**2
        if not self.moving or self._stopping or self.mode not in ("position", "jog"):
            return
        x, v0 = self._state()
        if self.mode == "jog":
            self._set_plan(plan_jog(x, v0, self._v, self._a, self._d))
        else:
            self._set_plan(plan_position(x, v0, float(self.target), self._v, self._a, self._d))

    @property
    def takes_decel(self) -> bool:
        """Whether DC may change now: at rest, in a jog, or while ST or a limit ramps down
        (not in a position move nor while contouring: TC 7)."""
        return not self.moving or self._stopping or self.mode == "jog"

    def set_decel(self, decel: float) -> None:
        """DC: a jog or a forced stop's ramp re-plans from the present state at the new rate
        (as AC does); at rest it is kept. CommandError TC 7 unless :attr:`takes_decel`."""
        if not (math.isfinite(decel) and decel > 0):
            raise InvalidArgument(f"decel must be > 0, got {decel!r}")
        if not self.takes_decel:
            raise _refuse(7, "DC")
        self._d = decel * self.sample_period**2
        if self._stopping:
            x, v0 = self._state()
            self._set_plan(plan_stop(x, v0, self._d), stopping=True, code=self._end_code)
        elif self.moving:
            x, v0 = self._state()
            self._set_plan(plan_jog(x, v0, self._v, self._a, self._d))

    def increment(
        self,
        n: int,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float | None = None,
    ) -> None:
        """IP n: retarget a position move, step a jog, or start a move of ``n`` when idle.

        Raises:
            CommandError: TC 16 for a wrong-sign IP during a position move or any IP during a
                forced deceleration; TC 18 while contouring.
        """
        n = int(n)
        if self.mode == "contour":
            raise _refuse(18, "IP")
        if not self.moving:
            it = self.smoothing if smoothing is None else smoothing
            self.begin_move(self.position + n, speed, accel, decel, it)
            return
        if self._stopping:
            raise _refuse(16, "IP")
        if n == 0:
            return
        if self.mode == "jog":
            assert self._active is not None
            self._active.shift(n)
            self._invalidate()
            return
        x, v0 = self._state()
        direction = self.target - x if v0 == 0 else v0
        if direction != 0 and (n > 0) != (direction > 0):
            raise _refuse(16, "IP")
        v, a, d = _per_sample(self.sample_period, abs(speed), accel, decel)
        if v > 0:
            self._v = v
        self._a, self._d = a, d
        self.target += n
        self._set_plan(plan_position(x, v0, float(self.target), self._v, self._a, self._d))

    def stop(self) -> None:
        """ST: ramp to rest at DC (stop code 4); in contour mode stop at once (code 51)."""
        self._forced_stop(4)

    def limit_stop(self, code: int) -> None:
        """A limit switch or soft limit: ramp to rest at DC with stop code ``code`` (2 or 3)."""
        self._forced_stop(int(code))

    def _forced_stop(self, code: int) -> None:
        if not self.moving:
            return
        if self.mode == "contour":
            self._finish_contour(51 if code == 4 else code)
        elif not self._stopping:
            x, v0 = self._state()
            self._set_plan(plan_stop(x, v0, self._d), stopping=True, code=code)
        elif self.stop_code == 0:  # a homing's own ramp down (it runs on): ST or a limit ends it
            self.stop_code = self._end_code = code

    def abort(self) -> None:
        """AB: stop at once where the reference is now (stop code 7); smoothing is dropped."""
        self._cq = ContourQueue(self.reference)
        self._active = None
        self._stopping = False
        self._invalidate()
        self.position = self.reference
        self._y = float(self.reference)
        self.velocity = 0.0
        self.moving = False
        self.mode = "idle"
        self.stop_code = 7

    def halt(self, code: int) -> None:
        """Stop at once where the reference is now, ending with stop code ``code``.

        The second stage of HM stops this way at the home switch's edge; ``AB`` is the same
        stop with code 7 (:meth:`abort`).
        """
        self.abort()
        self.stop_code = int(code)

    # ---- contour -----------------------------------------------------------------------
    def begin_contour(self) -> None:
        """CM: enter contour mode; an empty queue holds position.

        Raises:
            CommandError: TC 7 while another motion is running.
        """
        if self.moving:
            if self.mode == "contour":
                return
            raise _refuse(7, "CM")
        self.mode = "contour"
        self.moving = True
        self.stop_code = 50
        self._invalidate()
        self._cq = ContourQueue(self.position)

    def add_segment(self, increment: int, n: int) -> None:
        """CD ``increment`` over ``2**n`` samples (DT n), queued behind earlier segments.

        Raises:
            CommandError: TC 8 outside contour mode, TC 6 for DT outside 1..8.
        """
        if self.mode != "contour" or self._cq.ending:
            raise _refuse(8, "CD")
        if not 1 <= int(n) <= 8:
            raise _refuse(6, "DT")
        self._cq.add(increment, n)

    def end_contour(self) -> None:
        """CD 0=0: leave contour mode once the queued segments have run."""
        if self.mode != "contour":
            return
        self._cq.ending = True
        if self.queued_segments == 0:
            self._finish_contour(51)

    @property
    def queued_segments(self) -> int:
        """Contour segments not yet finished (including the one running)."""
        return self._cq.queued

    def _finish_contour(self, code: int) -> None:
        self._cq = ContourQueue(self.position)
        self.mode = "idle"
        self.moving = False
        self.stop_code = code
        self.velocity = 0.0
        self._y = float(self.position)
        self.reference = self.position

    # ---- stepping ----------------------------------------------------------------------
    def _raw(self, start: int, n: int) -> Int64Array:
        """Unsmoothed reference for absolute samples ``start .. start+n-1``."""
        if self._active is None:
            return np.full(n, self.position, np.int64)
        if n <= _SCALAR_MAX:
            return np.array(self._active.rounded(start, n), np.int64)
        return _round_fixed(self._active.fixed(start, n))

    def _fill(self, n: int) -> None:
        """Extend the smoothing cache, one page at a time, to cover n samples from now."""
        act = self._active
        assert act is not None
        sc = self._sc
        sc.fill(
            self._raw, self.sample, n, self._y, self.smoothing, act.end_sample, float(act.end_value)
        )

    def _window(self, n: int) -> tuple[Int64Array, Int64Array, FloatArray | None]:
        if self.mode == "contour":
            r = self._cq.window(n)[0]
            return r, r, None
        if self._active is None or self.smoothing >= 1.0:
            r = self._raw(self.sample + 1, n)
            return r, r, None  # fresh arrays: no copy needed
        sc = self._sc
        if sc.k + sc.r.size < self.sample + n:
            self._fill(n)
            sc = self._sc
        off = self.sample - sc.k
        r = sc.r[off : off + n]
        y = sc.y[off : off + n]
        return r, np.floor(y + 0.5).astype(np.int64), y

    def preview(self, n: int) -> Int64Array:
        """The next ``n`` reference values (after smoothing), without committing them."""
        out: Int64Array = self._window(self._count(n))[1].copy()
        return out

    def preview_from(self, start: int, n: int) -> Int64Array:
        """Unsmoothed positions of the present plan at samples ``start .. start+n-1``.

        For the predictor: one evaluation of a whole move, sample 0 included. Samples before
        the present one are what the plan gave there (when it was in force).
        """
        if self.mode == "contour":
            raise InvalidArgument("preview_from() is for kinematic plans, not contour mode")
        return self._raw(int(start), self._count(n))

    def preview_profile(self, n: int) -> Int64Array:
        """The next ``n`` profiler positions ``r`` (before smoothing: what AD/AR watch)."""
        out: Int64Array = self._window(self._count(n))[0].copy()
        return out

    def advance(self, n: int) -> Int64Array:
        """Commit the next ``n`` samples and return their reference values (int64)."""
        return self.advance_both(n)[1]

    def advance_both(self, n: int) -> tuple[Int64Array, Int64Array]:
        """Commit ``n`` samples; return the profiler positions ``r`` and the references.

        Without smoothing (IT = 1, or contour mode) both are the same array.
        """
        n = self._count(n)
        if n == 0:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        if self.mode == "contour":
            r = self._cq.step(n)
            self.sample += n
            self.position = self.reference = int(r[-1])
            self._y = float(self.position)
            self.velocity = self._cq.rate / self.sample_period
            if self._cq.ending and self.queued_segments == 0:
                self._finish_contour(51)
            return r, r
        r, ref, y = self._window(n)
        if y is not None:  # slices of the smoothing cache: hand out copies
            r, ref = r.copy(), ref.copy()
        else:
            ref = r
        self.sample += n
        self.position = int(r[-1])
        self.reference = int(ref[-1])
        self._y = float(y[-1]) if y is not None else float(self.position)
        if self._active is not None:
            self.velocity = self._active.state(self.sample)[1] / self.sample_period
            end = self._sc.end if self.smoothing < 1.0 else self._active.end_sample
            if end is not None and self.sample >= end:
                self._finish()
        return r, ref

    def advance_values(self, n: int) -> list[int]:
        """:meth:`advance` as a list of ints; cheap for short chunks (a servo loop's steps)."""
        act = self._active
        if (
            act is None
            or self.smoothing < 1.0
            or self.mode == "contour"
            or type(n) is not int
            or not 0 < n <= _SCALAR_MAX
        ):
            if act is None and self.mode != "contour" and type(n) is int and n > 0:
                # Idle: the reference holds still (what advance_both does, without arrays).
                self.sample += n
                self.reference = self.position
                self._y = float(self.position)
                return [self.position] * n
            values: list[int] = self.advance(n).tolist()
            return values
        # The commit of advance_both() for a plan without smoothing, on Python ints.
        out, velocity = act.step_values(self.sample + 1, n)
        self.sample += n
        self.position = self.reference = out[-1]
        self._y = float(out[-1])
        self.velocity = velocity / self.sample_period
        end = act.end_sample
        if end is not None and self.sample >= end:
            self._finish()
        return out

    def _finish(self) -> None:
        assert self._active is not None
        self.position = self._active.end_value
        self.reference = self.position
        self._y = float(self.position)
        self._active = None
        self._invalidate()
        self.moving = False
        self.mode = "idle"
        self.velocity = 0.0
        self.stop_code = self._end_code
        self._stopping = False

    @staticmethod
    def _count(n: int) -> int:
        n = int(n)
        if n < 0:
            raise InvalidArgument(f"sample count must be >= 0, got {n}")
        return n

    # ---- introspection (predictor use) -----------------------------------------------
    def preview_velocity(self, n: int) -> FloatArray:
        """Profiler velocity (counts/s, before rounding) over the next ``n`` samples."""
        n = self._count(n)
        if self.mode == "contour" or self._active is None:  # (contour: each sample's segment)
            rates = self._cq.rates(n) if self.mode == "contour" else np.zeros(n)
            return rates / self.sample_period
        out: FloatArray = self._active.velocities(self.sample + 1, n) / self.sample_period
        return out

    @property
    def end_sample(self) -> int | None:
        """Sample at which the present plan ends, when known (``None`` for a jog).

        With IT smoothing this is the first sample from which the filtered reference stays on
        the target (``_BG`` falls there), known once the profile ends within
        :data:`~galil.predict.smoothing.END_LOOKAHEAD` samples (``None`` before).
        """
        act = self._active
        if act is None:
            return self.sample if not self.moving else None
        if self.smoothing >= 1.0 or act.end_sample is None:
            return act.end_sample
        if self._sc.end is not None:
            return self._sc.end
        return self._sc.find_end(
            self._raw, self.sample, self._y, self.smoothing, act.end_sample, float(act.end_value)
        )

    @property
    def plan(self) -> KinematicPlan | None:
        """The kinematic plan in force (``None`` when idle or contouring)."""
        return None if self._active is None else self._active.plan


def ramping(prof: AxisProfiler) -> bool:
    """Whether ``prof`` changes speed towards its slew speed at its present sample.

    The slew speed is SP in a position move (signed towards the target) and the signed JG
    speed in a jog. True while a ramp approaches it, from below or from above (after a lower
    SP or JG); false at rest, at the slew speed, while the speed moves away from it (a
    triangle's ramp down), during ST or a limit's stop and in contour mode. What ``AS`` waits
    out; the profile before IT smoothing.
    """
    act = prof._active
    if act is None or prof._stopping or prof.mode not in ("position", "jog"):
        return False
    v, a = act.ramp(prof.sample)
    slew = prof._v
    if prof.mode == "position":
        x = act.state(prof.sample)[0]
        slew = math.copysign(slew, prof.target - x if prof.target != x else v)
    return a * (slew - v) > 0


def slewing(prof: AxisProfiler) -> bool:
    """Whether ``prof`` runs at a constant, non-zero speed at its present sample: a position
    move's cruise at SP, a jog at its JG speed. The data record's axis status bit 5 "Motion
    is slewing" (galil-protocol.md section 4; DMC-2x00 user manual p.68); the profile before
    IT smoothing; false while contouring and during ST or a limit's stop."""
    act = prof._active
    if act is None or prof._stopping or prof.mode not in ("position", "jog"):
        return False
    v, a = act.ramp(prof.sample)
    return a == 0.0 and v != 0.0


def final_decel(prof: AxisProfiler) -> bool:
    """Whether ``prof`` is in the ramp that brings its motion to rest: the last phase of a
    position move's profile, or the ramp of ST or a limit's stop. The data record's axis
    status bit 3 "Motion is making final decel." (galil-protocol.md section 4; DMC-2x00 user
    manual p.68). [U] The manuals do not say whether a stop's ramp counts as the final
    deceleration: here it does (bit 4, "stopping", says why it stops)."""
    act = prof._active
    if act is None or act.end_sample is None or prof.mode not in ("position", "jog"):
        return False
    k = prof.sample
    if k >= act.end_sample or act._segment(float(k - act.k0)) != len(act.t0) - 1:
        return False
    v, a = act.ramp(k)
    return v * a < 0.0
