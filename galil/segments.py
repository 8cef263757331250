"""Paths in user units: :class:`Line` and :class:`Arc` segments, their conversion to the
predictor's counts, and :class:`VectorPlan`, a predicted sequence shown in those units.

A segment's components go through each axis's scale (``Scale``: counts per unit, offset,
sign). A :class:`Line` may move each axis in its own unit; an :class:`Arc` needs the same
counts per unit on both axes of its plane (otherwise the circle would be an ellipse in counts),
and a reversed axis (``sign=-1``) mirrors it: its start angle reflects and its turn reverses.

Rounding, so that nothing accumulates: a line ends at the rounded ideal end of the path so far
(the controller's ``VP`` takes absolute whole counts); an arc starts where the controller's
path is, with its radius to 1/10000 count (four decimals on the wire) and its angles to the
controller's CR step (1/256 degree).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import numpy.typing as npt

from galil import predict
from galil.errors import InvalidArgument, decimal_hint, missing_extra
from galil.predict.counts import whole_counts
from galil.predict.path import PathLayout, quantise_angle
from galil.predict.profile import shown_position
from galil.units import (
    Amount,
    QuantityLike,
    Scale,
    angle_in_degrees,
    counts_or_plain,
    is_quantity,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "Arc",
    "Display",
    "Line",
    "PathAxis",
    "PathInCounts",
    "Segment",
    "VectorPlan",
    "describe_scales",
    "show",
    "to_counts",
]

FloatArray = npt.NDArray[np.float64]

Display = Callable[[predict.Profile], predict.Profile]
"""Shows a profile in an axis's user unit (arrays stay in counts)."""


# --------------------------------------------------------------------------- user segments


def _finite(value: object, what: str) -> None:
    if is_quantity(value):
        magnitude = getattr(value, "magnitude", None)
        if isinstance(magnitude, numbers.Real) and math.isfinite(float(magnitude)):
            return
    elif (
        not isinstance(value, bool)
        and isinstance(value, numbers.Real)
        and math.isfinite(float(value))
    ):
        return
    hint = decimal_hint(getattr(value, "magnitude", value))
    raise InvalidArgument(f"{what} must be a finite number or a pint Quantity, got {value!r}{hint}")


class Segment:
    """A segment of a path in user units: a :class:`Line` or an :class:`Arc`."""

    __slots__ = ()


@dataclass(frozen=True, init=False)
class Line(Segment):
    """A straight segment: how far each axis of the path moves, relative to where the
    previous segment ended, in each axis's user units (counts on an axis without a scale).

    ``Line(dx, dy)`` in a plane of two axes (``VP``), ``Line(dx, dy, dz, ...)`` for linear
    interpolation on more axes (``LI``).
    """

    deltas: tuple[Amount, ...]

    def __init__(self, *deltas: Amount) -> None:
        if not deltas:
            raise InvalidArgument("a Line needs the move of each axis, e.g. Line(10 * mm, 0)")
        for i, d in enumerate(deltas):
            _finite(d, f"Line component {i}")
        object.__setattr__(self, "deltas", tuple(deltas))

    @property
    def dx(self) -> Amount:
        """The first axis's move."""
        return self.deltas[0]

    @property
    def dy(self) -> Amount | None:
        """The second axis's move (``None`` on a one-axis line)."""
        return self.deltas[1] if len(self.deltas) > 1 else None


@dataclass(frozen=True)
class Arc(Segment):
    """A circular segment in the plane of two axes (``CR``), starting where the path is.

    Attributes:
        radius: a positive length in the axes' user unit (counts on axes without a scale);
            both axes need the same counts per unit, or the circle would be an ellipse.
        start: the angle of the start point seen from the centre: degrees (a number) or a pint
            angle; 0 is the first axis's positive direction, 90 the second's.
        sweep: the angle travelled, degrees or a pint angle; positive is counter-clockwise.
    """

    radius: Amount
    start: Amount
    sweep: Amount

    def __post_init__(self) -> None:
        _finite(self.radius, "Arc radius")
        radius: Any = getattr(self.radius, "magnitude", self.radius)  # (checked finite above)
        if not radius > 0:
            raise InvalidArgument(f"Arc radius must be positive, got {self.radius!r}")
        if _degrees(self.sweep, "Arc sweep") == 0:
            raise InvalidArgument("Arc sweep must not be 0")
        _degrees(self.start, "Arc start")


def _degrees(value: object, what: str) -> float:
    """An angle in degrees: a number is degrees, a Quantity must be an angle (one only the
    user's own registry defines is refused as every unit is: :func:`angle_in_degrees`)."""
    _finite(value, what)
    return angle_in_degrees(value, what)


@dataclass(frozen=True)
class PathAxis:
    """An axis of a path as the controller gives it: its letter, scale and display."""

    letter: str
    scale: Scale | None = None
    display: Display | None = None


# --------------------------------------------------------------------------- conversion


@dataclass(frozen=True)
class PathInCounts:
    """A path in the predictor's counts, ready to check and send.

    Attributes:
        kind: ``"vector"`` (VM/VP/CR) or ``"linear"`` (LM/LI).
        letters: the axes, in the order of the segments' components.
        segments: the counts-level segments.
        per_unit: counts per user unit common to every axis (1 for counts), or ``None`` when
            the axes' scales differ (speeds along the path are then in counts).
        unit: the unit of :attr:`per_unit` (``"counts"`` without scales).
    """

    kind: str
    letters: str
    segments: tuple[predict.PathSegment, ...]
    per_unit: float | None
    unit: str


def _common_scale(axes: Sequence[PathAxis]) -> tuple[float, str] | None:
    """(counts per unit, unit) shared by every axis, or ``None`` when their scales differ."""
    scales = [a.scale for a in axes]
    if all(s is None for s in scales):
        return 1.0, "counts"
    if any(s is None for s in scales):
        return None
    first = scales[0]
    assert first is not None
    one = 1.0 * first.unit
    k = abs(first.distance_to_counts(one))
    for s in scales[1:]:
        assert s is not None
        try:
            other = abs(s.distance_to_counts(one))
        except InvalidArgument:
            return None  # a rotary and a linear axis
        if not math.isclose(other, k, rel_tol=1e-12):
            return None
    return k, f"{first.unit:~}"


def describe_scales(axes: Sequence[PathAxis]) -> str:
    """The axes' scales in words, for messages (``"A 2000 1 / mm, B in counts"``)."""
    parts = []
    for a in axes:
        if a.scale is None:
            parts.append(f"{a.letter} in counts")
        else:
            parts.append(f"{a.letter} {a.scale.counts_per:~}")
    return ", ".join(parts)


def _distance(axis: PathAxis, value: object, what: str) -> float:
    if not is_quantity(value) and value == 0 and not isinstance(value, bool):
        return 0.0  # no move needs no unit: Line(10 * mm, 0)
    if axis.scale is not None:
        return axis.scale.distance_to_counts(cast("QuantityLike", value), what)
    return counts_or_plain(value, what, axis.letter)


def _arc_in_counts(i: int, arc: Arc, axes: Sequence[PathAxis], resolution: float) -> predict.Arc:
    common = _common_scale(axes)
    if common is None:
        raise InvalidArgument(
            f"segment {i}: an Arc needs the same counts per unit on both axes"
            f" ({describe_scales(axes)}): with different scales the circle would be an ellipse"
            " in counts"
        )
    theta = _degrees(arc.start, f"segment {i} start")
    sweep = _degrees(arc.sweep, f"segment {i} sweep")
    sx = 1 if axes[0].scale is None else axes[0].scale.sign
    sy = 1 if axes[1].scale is None else axes[1].scale.sign
    # (a reversed first axis gives the radius negative counts: a length is a magnitude)
    radius = sx * _distance(axes[0], arc.radius, f"segment {i} radius")
    # A reversed axis mirrors the circle: the start angle reflects and the turn reverses.
    if sx < 0 and sy < 0:
        theta += 180.0
    elif sx < 0:
        theta, sweep = 180.0 - theta, -sweep
    elif sy < 0:
        theta, sweep = -theta, -sweep
    theta = math.fmod(theta, 360.0)
    sweep_q = quantise_angle(sweep, resolution)
    if sweep_q == 0:
        raise InvalidArgument(f"segment {i}: the sweep rounds to 0 at {resolution:g} degree steps")
    return predict.Arc(round(radius, 4), quantise_angle(theta, resolution), sweep_q)


def _kind(segments: Sequence[Segment], n: int, mode: str | None) -> str:
    if mode not in (None, "vector", "linear"):
        raise InvalidArgument(f"mode is 'vector' (VM) or 'linear' (LM), not {mode!r}")
    has_arc = any(isinstance(s, Arc) for s in segments)
    kind = mode or ("vector" if n == 2 else "linear")
    if has_arc and (kind != "vector" or n != 2):
        raise InvalidArgument("Arc segments need vector mode on two axes (VM)")
    if kind == "vector" and n != 2:
        raise InvalidArgument(f"vector mode (VM) takes two axes, got {n}")
    return kind


def to_counts(
    segments: Sequence[Segment],
    axes: Sequence[PathAxis],
    *,
    mode: str | None = None,
    angle_resolution: float = 1 / 256,
) -> PathInCounts:
    """Turn a path in user units into the predictor's segments in counts.

    Args:
        segments: :class:`Line` and :class:`Arc` segments.
        axes: the path's axes, in the order of the segments' components.
        mode: ``"vector"`` (VM: lines and arcs on two axes), ``"linear"`` (LM: lines on one to
            eight axes), or ``None``: vector on two axes, linear otherwise.
        angle_resolution: the controller's CR angle step, degrees.

    Raises:
        InvalidArgument: no segments, a segment that is not a Line or Arc, a Line with the
            wrong number of components, wrong units, or an Arc on axes whose scales differ.
    """
    if isinstance(segments, (str, bytes, Mapping)) or not isinstance(segments, Iterable):
        raise InvalidArgument(
            f"segments must be a list of galil.Line and galil.Arc, not {segments!r:.60}"
        )
    segs = list(segments)
    if not segs:
        raise InvalidArgument("a path needs at least one segment")
    letters = "".join(a.letter for a in axes)
    if not letters or len(set(letters)) != len(letters):
        raise InvalidArgument(f"a path needs distinct axes, got {letters!r}")
    for i, seg in enumerate(segs):
        if not isinstance(seg, (Line, Arc)):
            raise InvalidArgument(f"segment {i} is not a galil.Line or galil.Arc: {seg!r}")
        if isinstance(seg, Line) and len(seg.deltas) != len(axes):
            raise InvalidArgument(
                f"segment {i}: a Line with {len(seg.deltas)} components on {len(axes)} axes"
            )
    kind = _kind(segs, len(axes), mode)
    common = _common_scale(axes)
    out = (
        _vector_segments(segs, axes, angle_resolution)
        if kind == "vector"
        else _linear_segments(segs, axes)
    )
    per_unit, unit = common if common is not None else (None, "counts")
    return PathInCounts(kind, letters, tuple(out), per_unit, unit)


#: What a Line on an axis without a scale says when given a fraction of a count.
_WHOLE_HINT = (
    " (an axis without a scale takes whole counts; with a scale, a length in its unit is"
    " rounded to the nearest count)"
)


def _line_counts(i: int, line: Line, axes: Sequence[PathAxis]) -> list[float]:
    """A Line's moves in counts: whole on an axis without a scale, whose values are counts
    (a fraction of one refused, decision 0092); in a scale's unit they round along the path."""
    out: list[float] = []
    for a, d in zip(axes, line.deltas, strict=True):
        what = f"segment {i} on {a.letter}"
        counts = _distance(a, d, what)
        out.append(counts if a.scale is not None else whole_counts(counts, what, _WHOLE_HINT))
    return out


def _vector_segments(
    segs: Sequence[Segment], axes: Sequence[PathAxis], resolution: float
) -> list[predict.PathSegment]:
    layout = PathLayout(2, angle_resolution=resolution)
    ideal = np.zeros(2)  # where the user's path is, counts (unrounded)
    out: list[predict.PathSegment] = []
    for i, seg in enumerate(segs):
        piece: predict.PathSegment
        if isinstance(seg, Arc):
            piece = _arc_in_counts(i, seg, axes, resolution)
        else:
            assert isinstance(seg, Line)
            ideal = ideal + np.array(_line_counts(i, seg, axes))
            anchor = np.floor(np.array(layout.end_point) + 0.5)
            step = np.floor(ideal + 0.5) - anchor
            piece = predict.Line(int(step[0]), int(step[1]))
        layout.append(piece)
        if isinstance(seg, Arc):
            ideal = np.array(layout.end_point)
        out.append(piece)
    return out


def _linear_segments(
    segs: Sequence[Segment], axes: Sequence[PathAxis]
) -> list[predict.PathSegment]:
    ideal = np.zeros(len(axes))
    done = np.zeros(len(axes))
    out: list[predict.PathSegment] = []
    for i, seg in enumerate(segs):
        assert isinstance(seg, Line)
        ideal = ideal + np.array(_line_counts(i, seg, axes))
        ends = np.floor(ideal + 0.5)
        out.append(predict.LinearInterp(tuple(int(v) for v in ends - done)))
        done = ends
    return out


# --------------------------------------------------------------------------- the plan


@dataclass(frozen=True, eq=False)
class VectorPlan:
    """A predicted sequence, shown in the axes' user units.

    Attributes:
        axes: the axes, in the order of the path's components.
        counts: the prediction in counts (:class:`~galil.predict.VectorProfile`).
        profiles: each axis's profile (displayed in its unit where it has a scale).
        unit: the unit of :attr:`path` and :attr:`speed` (``"counts"`` when the axes have
            no common scale).
        per_unit: counts per :attr:`unit`.
    """

    axes: str
    counts: predict.VectorProfile
    profiles: dict[str, predict.Profile]
    unit: str
    per_unit: float

    @property
    def duration(self) -> float:
        """Seconds from ``BG S`` until the sequence completes."""
        return self.counts.duration

    @property
    def t(self) -> FloatArray:
        """Sample times, seconds."""
        return self.counts.t

    @property
    def sample_period(self) -> float:
        """Seconds per sample."""
        return self.counts.sample_period

    @property
    def speed(self) -> FloatArray:
        """The speed along the path at each sample, :attr:`unit` per second."""
        out: FloatArray = self.counts.speed / self.per_unit
        return out

    @property
    def path(self) -> FloatArray:
        """The distance travelled along the path at each sample, in :attr:`unit`."""
        out: FloatArray = self.counts.path / self.per_unit
        return out

    def _profile(self, axis: str) -> predict.Profile:
        try:
            return self.profiles[axis]
        except (KeyError, TypeError):  # TypeError: an unhashable key
            raise KeyError(
                f"{axis!r:.40} is not an axis of the path; its axes: {', '.join(self.profiles)}"
            ) from None

    def position(self, axis: str) -> FloatArray:
        """An axis's reference position at each sample, in its user unit (counts without).

        Raises:
            KeyError: ``axis`` is not one of the path's axes.
        """
        p = self._profile(axis)
        out = shown_position(p.display, p.position.astype(np.float64))
        return np.asarray(out, dtype=np.float64)

    def unit_of(self, axis: str) -> str:
        """The unit :meth:`position` gives ``axis`` in (``KeyError`` as :meth:`position`)."""
        d = self._profile(axis).display
        return "counts" if d is None else d[2]

    def plot(self, *, title: str | None = None) -> Figure:
        """The path (first two axes) and the speed along it; returns the Figure.

        matplotlib is imported here, not at import time.
        """
        try:
            from matplotlib.figure import Figure
        except ImportError as exc:
            raise missing_extra(exc, "VectorPlan.plot()") from exc

        fig = Figure(figsize=(10, 4.5), layout="constrained")
        ax_xy, ax_v = fig.subplots(1, 2)
        a = self.axes[0]
        if len(self.axes) >= 2:
            b = self.axes[1]
            ax_xy.plot(self.position(a), self.position(b))
            ax_xy.set_aspect("equal", adjustable="datalim")
            ax_xy.set_xlabel(f"{a} ({self.unit_of(a)})")
            ax_xy.set_ylabel(f"{b} ({self.unit_of(b)})")
        else:
            ax_xy.plot(self.t, self.position(a))
            ax_xy.set_xlabel("time (s)")
            ax_xy.set_ylabel(f"{a} ({self.unit_of(a)})")
        ax_v.plot(self.t, self.speed)
        ax_v.set_xlabel("time (s)")
        ax_v.set_ylabel(f"speed along the path ({self.unit}/s)")
        for ax in (ax_xy, ax_v):
            ax.grid(True, alpha=0.3)
        segments = len(self.counts.layout)
        fig.suptitle(title or f"{self.axes}: {segments} segments, {self.duration:.4g} s")
        return fig

    def __repr__(self) -> str:
        length = self.counts.length / self.per_unit
        peak = self.counts.peak_speed / self.per_unit
        return (
            f"VectorPlan({self.axes}, {self.counts.layout.kind},"
            f" segments={len(self.counts.layout)},"
            f" length={length:.6g} {self.unit}, duration={self.duration:.6g} s,"
            f" peak speed={peak:.6g} {self.unit}/s)"
        )


def show(
    profile: predict.VectorProfile,
    axes: Sequence[PathAxis],
    path: PathInCounts,
) -> VectorPlan:
    """A counts-level prediction as a :class:`VectorPlan` in the axes' units."""
    profiles: dict[str, predict.Profile] = {}
    for i, a in enumerate(axes):
        p = profile.axis(i)
        profiles[a.letter] = p if a.display is None else a.display(p)
    per_unit = path.per_unit if path.per_unit is not None else 1.0
    return VectorPlan(path.letters, profile, profiles, path.unit, per_unit)
