"""Path segments of coordinated motion, in counts, and where each sample of a path lies.

Two kinds of sequence exist on the controller and never mix in one sequence (TC 33):

- vector mode (``VM`` then ``VP``/``CR``, ``VE``): straight :class:`Line` segments and circular
  :class:`Arc` segments in one plane of two axes;
- linear interpolation (``LM`` then ``LI``, ``LE``): :class:`LinearInterp` segments, straight
  lines over one to eight axes given as increments per axis.

A path is laid out (:class:`PathLayout`, :class:`VectorPath`) in sequence coordinates: the
controller makes the position at the start of a sequence its origin. How the firmware splits
the path onto the axes is not documented; the rules below are assumptions (ADR 0009) that a
controller log may overturn:

- Each segment gets a whole number of counts of path, ``n_i``, such that the running sum is the
  ideal cumulative length rounded half up (the contour rule of ``profiler-model.md``), so the
  whole path is ``round(total length)`` counts and no rounding accumulates.
- The profiler advances an integer path position ``s`` (:mod:`galil.predict.vector`). Sample
  ``j`` of ``n_i`` in segment ``i`` is the fraction ``u = j/n_i`` of the way along it: lines
  linearly, arcs at angle ``θ + u·Δθ`` on the circle. Each axis is that ideal point rounded to
  the nearest count, halves up (``floor(x + 0.5)``, the engine's rule). At ``u = 1`` the axis
  takes the segment's end point exactly.
- A line ends at the previous end point rounded to whole counts plus ``(dx, dy)``: what the
  absolute integer coordinates of ``VP`` can express. Arcs start where the previous segment
  ended (ideal, maybe fractional); CR angles are rounded to 1/256 degree; an arc through a
  whole number of turns ends exactly on its start, and arcs whose angles are multiples of 90
  degrees end exactly on their ideal (integer, for integer radii) end points.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument

__all__ = [
    "ANGLE_RESOLUTION",
    "Arc",
    "Line",
    "LinearInterp",
    "PathLayout",
    "PathSegment",
    "VectorPath",
    "first_directions",
    "path_kind",
]

#: CR angles are stored in steps of 1/256 degree (DMC user manuals, vector mode appendix).
ANGLE_RESOLUTION = 1 / 256
#: Most axes an LM sequence can interpolate.
MAX_AXES = 8

FloatArray = npt.NDArray[np.float64]
Int64Array = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def _whole(name: str, value: object) -> int:
    """An integer count, accepting numpy integers and integral floats."""
    if isinstance(value, bool):
        raise InvalidArgument(f"{name} must be a whole number of counts, got {value!r}")
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    raise InvalidArgument(f"{name} must be a whole number of counts, got {value!r}")


def _finite(name: str, value: object) -> float:
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise InvalidArgument(f"{name} must be finite, got {value!r}")
    return x


@dataclass(frozen=True)
class Line:
    """A straight vector segment (``VP``): relative end point, counts, in the VM plane.

    Attributes:
        dx, dy: end point relative to where the previous segment ended (rounded to whole
            counts; see the module notes), first and second axis of the plane.
    """

    dx: int
    dy: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "dx", _whole("dx", self.dx))
        object.__setattr__(self, "dy", _whole("dy", self.dy))

    @property
    def length(self) -> float:
        """Length in counts."""
        return math.hypot(self.dx, self.dy)


@dataclass(frozen=True)
class Arc:
    """A circular vector segment (``CR r,θ,Δθ``), counts and degrees.

    Attributes:
        radius: counts (> 0).
        start: angle of the start point seen from the centre, degrees; 0 is the first axis's
            positive direction, 90 the second's.
        sweep: angle travelled, degrees; positive is counter-clockwise, as ``CR``.
    """

    radius: float
    start: float
    sweep: float

    def __post_init__(self) -> None:
        radius = _finite("radius", self.radius)
        if radius <= 0:
            raise InvalidArgument(f"arc radius must be > 0 counts, got {self.radius!r}")
        sweep = _finite("sweep", self.sweep)
        if sweep == 0:
            raise InvalidArgument("arc sweep must not be 0 degrees")
        object.__setattr__(self, "radius", radius)
        object.__setattr__(self, "start", _finite("start angle", self.start))
        object.__setattr__(self, "sweep", sweep)

    @property
    def length(self) -> float:
        """Arc length in counts (before the angles are rounded to the controller's step)."""
        return self.radius * abs(math.radians(self.sweep))


@dataclass(frozen=True)
class LinearInterp:
    """A linear-interpolation segment (``LI``): an increment per axis of the LM sequence.

    Attributes:
        increments: counts per axis, in the order of the ``LM`` axes (1 to 8 axes).
    """

    increments: tuple[int, ...]

    def __post_init__(self) -> None:
        raw: object = self.increments
        if isinstance(raw, (str, bytes)) or not hasattr(raw, "__iter__"):
            raise InvalidArgument(f"increments must be a sequence of counts, got {raw!r}")
        inc = tuple(_whole(f"increment {i}", v) for i, v in enumerate(raw))
        if not 1 <= len(inc) <= MAX_AXES:
            raise InvalidArgument(f"LI takes 1 to {MAX_AXES} axes, got {len(inc)}")
        object.__setattr__(self, "increments", inc)

    @property
    def length(self) -> float:
        """Length in counts."""
        return math.sqrt(math.fsum(float(c) * c for c in self.increments))


PathSegment = Line | Arc | LinearInterp


def path_kind(segment: PathSegment) -> str:
    """``"vector"`` for VP/CR segments (VM), ``"linear"`` for LI segments (LM).

    Raises:
        InvalidArgument: not a path segment.
    """
    if isinstance(segment, (Line, Arc)):
        return "vector"
    if isinstance(segment, LinearInterp):
        return "linear"
    raise InvalidArgument(f"not a path segment (Line, Arc or LinearInterp): {segment!r}")


def quantise_angle(degrees: float, resolution: float = ANGLE_RESOLUTION) -> float:
    """An angle as CR stores it: the nearest multiple of ``resolution`` (halves up)."""
    return math.floor(degrees / resolution + 0.5) * resolution


def _cos_sin(degrees: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90 degrees."""
    rest = math.fmod(degrees, 360.0)
    if rest % 90.0 == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(rest // 90.0) % 4]
    rad = math.radians(rest)
    return math.cos(rad), math.sin(rad)


def first_directions(
    segments: Iterable[PathSegment], axes: int, angle_resolution: float = ANGLE_RESOLUTION
) -> tuple[int, ...]:
    """The direction (+1, -1, or 0 for none) each axis of a path first moves in: the sign of
    its component in the first segment that moves it (a line's or an ``LI``'s; a line of
    ``dx = 0`` never changes the axis by a whole count). An arc moves both its axes: along
    its tangent at the start (``CR`` angles rounded as the controller stores them), or, where
    the tangent's component is 0 (a start angle a multiple of 90 degrees), the way the circle
    bends. What a switch or a soft limit active at ``BG S`` meets first (decision 0050)."""
    out = [0] * axes
    for seg in segments:
        if all(out):
            break
        if isinstance(seg, Arc):
            c, s = _cos_sin(quantise_angle(seg.start, angle_resolution))
            turn = 1.0 if quantise_angle(seg.sweep, angle_resolution) > 0 else -1.0
            # d/du (cos, sin)(θ + u·turn) at u = 0: turn·(-sin, cos); where 0, the second
            # derivative -(cos, sin) says which way the axis leaves its extreme.
            step: Sequence[float] = (-turn * s or -c, turn * c or -s)
        elif isinstance(seg, LinearInterp):
            step = seg.increments
        else:
            step = (seg.dx, seg.dy)
        for i, v in enumerate(step[:axes]):
            if not out[i] and v:
                out[i] = 1 if v > 0 else -1
    return tuple(out)


def _round_half_up(x: float) -> int:
    return math.floor(x + 0.5)


def _resized(old: Any, shape: tuple[int, ...], dtype: type = np.float64) -> Any:
    """A zeroed array of ``shape`` holding ``old``'s rows at its start."""
    new: Any = np.zeros(shape, dtype=dtype)
    if old is not None:
        new[: old.shape[0]] = old
    return new


@dataclass(frozen=True)
class _Arrays:
    """The per-segment tables of a layout (views, or frozen copies in a VectorPath)."""

    start: FloatArray  # (m, axes) ideal start point, sequence coordinates
    end: FloatArray  # (m, axes) ideal end point
    counts: Int64Array  # (m,) whole counts of path per segment
    bounds: Int64Array  # (m + 1,) cumulative counts, bounds[0] == 0
    arc: BoolArray  # (m,)
    centre: FloatArray  # (m, 2) arc centres (0 for lines)
    radius: FloatArray  # (m,)
    theta0: FloatArray  # (m,) quantised start angle, degrees
    sweep: FloatArray  # (m,) quantised sweep, degrees


def _segment_index(a: _Arrays, s: Int64Array) -> Int64Array:
    """Segment of each path position: a position on a boundary ends the earlier segment."""
    m = a.counts.size
    idx: Int64Array = np.searchsorted(a.bounds[1:], s, side="left").astype(np.int64)
    np.minimum(idx, m - 1, out=idx)
    return idx


def _project(a: _Arrays, s: Int64Array) -> Int64Array:
    """Whole-count offsets from the sequence origin, shape ``(axes, len(s))``."""
    idx = _segment_index(a, s)
    j = s - a.bounds[idx]
    n = a.counts[idx]
    done = j >= n  # the segment's end point (also every zero-length segment)
    nf = np.where(done, 1, n).astype(np.float64)
    jf = np.where(done, 1, j).astype(np.float64)
    first = a.start[idx]
    last = a.end[idx]
    # j*(E - A) is exact for integer end points (below 2**53), the division correctly rounded,
    # so a point exactly half-way between counts rounds up as the engine's positions do.
    x = first + (jf[:, None] * (last - first)) / nf[:, None]
    on_arc = a.arc[idx] & ~done
    if on_arc.any():
        k = idx[on_arc]
        phi = np.radians(a.theta0[k] + (jf[on_arc] / nf[on_arc]) * a.sweep[k])
        x[on_arc, 0] = a.centre[k, 0] + a.radius[k] * np.cos(phi)
        x[on_arc, 1] = a.centre[k, 1] + a.radius[k] * np.sin(phi)
    x[done] = last[done]
    x += 0.5
    out: Int64Array = np.floor(x).astype(np.int64).T.copy()
    return out


@dataclass(frozen=True, eq=False)
class VectorPath:
    """A laid-out path: the per-segment geometry the profile was projected with.

    Attributes:
        kind: ``"vector"`` (VP/CR in a VM plane) or ``"linear"`` (LI in an LM sequence).
        axes: axes the path moves (2 for vector mode).
        segments: the segments, as given.
        start, end: ideal start and end point of each segment, counts from the sequence
            origin, shape ``(m, axes)``. A line's end point is integer (its ``VP`` coordinates).
        lengths: ideal length of each segment, counts (after CR angles are rounded).
        counts: whole counts of path given to each segment (their sum is :attr:`length`).
        bounds: cumulative ``counts``, ``m + 1`` values from 0.
        arc, centre, radius, theta0, sweep: arc geometry (degrees; zeros for lines).
    """

    kind: str
    axes: int
    segments: tuple[PathSegment, ...]
    start: FloatArray
    end: FloatArray
    lengths: FloatArray
    counts: Int64Array
    bounds: Int64Array
    arc: BoolArray
    centre: FloatArray
    radius: FloatArray
    theta0: FloatArray
    sweep: FloatArray
    _tables: _Arrays = field(init=False, repr=False)

    def __post_init__(self) -> None:
        arrays = (self.start, self.end, self.lengths, self.counts, self.bounds, self.arc)
        for arr in (*arrays, self.centre, self.radius, self.theta0, self.sweep):
            arr.setflags(write=False)
        tables = _Arrays(
            self.start,
            self.end,
            self.counts,
            self.bounds,
            self.arc,
            self.centre,
            self.radius,
            self.theta0,
            self.sweep,
        )
        object.__setattr__(self, "_tables", tables)

    @property
    def length(self) -> int:
        """Whole counts of path: the distance the vector profile covers."""
        return int(self.bounds[-1])

    @property
    def ideal_length(self) -> float:
        """Sum of the ideal segment lengths, counts."""
        return math.fsum(self.lengths.tolist())

    def __len__(self) -> int:
        return int(self.counts.size)

    def project(self, s: npt.ArrayLike) -> Int64Array:
        """Whole-count offsets from the origin of path positions ``s``: ``(axes, len(s))``."""
        return _project(self._tables, np.asarray(s, dtype=np.int64).ravel())

    def segment_of(self, s: npt.ArrayLike) -> Int64Array:
        """Index of the segment each path position ``s`` lies in (a boundary ends a segment)."""
        return _segment_index(self._tables, np.asarray(s, dtype=np.int64).ravel())


class PathLayout:
    """A path laid out segment by segment, as the controller's buffer receives them.

    Args:
        axes: axes of the sequence (2 for vector mode).
        angle_resolution: CR angle step, degrees.
    """

    def __init__(self, axes: int, *, angle_resolution: float = ANGLE_RESOLUTION) -> None:
        if not 1 <= int(axes) <= MAX_AXES:
            raise InvalidArgument(f"a path has 1 to {MAX_AXES} axes, got {axes!r}")
        if not (math.isfinite(angle_resolution) and angle_resolution > 0):
            raise InvalidArgument(f"angle resolution must be > 0, got {angle_resolution!r}")
        self.axes = int(axes)
        self.angle_resolution = float(angle_resolution)
        self.kind: str | None = None
        self.size = 0
        self._segments: list[PathSegment] = []
        self._cum = 0.0  # ideal cumulative length
        self._point = np.zeros(self.axes)  # ideal end of the path so far
        self._anchor = np.zeros(self.axes)  # that end rounded to whole counts
        self._cap = 0
        self._grow(16)

    def __deepcopy__(self, memo: dict[int, object]) -> PathLayout:
        # A simulator snapshots its sequences often: copy the tables (numpy copies) and share
        # the segments, which are frozen.
        new = copy.copy(self)
        for name in ("_start", "_end", "_centre", "_len", "_radius", "_theta0", "_sweep"):
            setattr(new, name, getattr(self, name).copy())
        for name in ("_counts", "_bounds", "_arc", "_point", "_anchor"):
            setattr(new, name, getattr(self, name).copy())
        new._segments = list(self._segments)
        return new

    def _grow(self, cap: int) -> None:
        """Give the per-segment tables room for ``cap`` segments (keeping what is there)."""
        ax = self.axes
        self._start: FloatArray = _resized(getattr(self, "_start", None), (cap, ax))
        self._end: FloatArray = _resized(getattr(self, "_end", None), (cap, ax))
        self._centre: FloatArray = _resized(getattr(self, "_centre", None), (cap, 2))
        self._len: FloatArray = _resized(getattr(self, "_len", None), (cap,))
        self._radius: FloatArray = _resized(getattr(self, "_radius", None), (cap,))
        self._theta0: FloatArray = _resized(getattr(self, "_theta0", None), (cap,))
        self._sweep: FloatArray = _resized(getattr(self, "_sweep", None), (cap,))
        self._counts: Int64Array = _resized(getattr(self, "_counts", None), (cap,), np.int64)
        self._bounds: Int64Array = _resized(getattr(self, "_bounds", None), (cap + 1,), np.int64)
        self._arc: BoolArray = _resized(getattr(self, "_arc", None), (cap,), np.bool_)
        self._cap = cap

    @property
    def length(self) -> int:
        """Whole counts of path laid out so far."""
        return int(self._bounds[self.size])

    @property
    def end_point(self) -> tuple[float, ...]:
        """Ideal end of the path so far, counts from the origin."""
        return tuple(float(v) for v in self._point)

    def append(self, segment: PathSegment) -> int:
        """Lay out one more segment; return the whole counts of path it adds.

        Raises:
            InvalidArgument: a segment of the other kind (TC 33's case: the caller reports
                it) or with the wrong number of axes.
        """
        kind = path_kind(segment)
        if self.kind is not None and kind != self.kind:
            raise InvalidArgument(f"cannot mix {kind} and {self.kind} segments in one sequence")
        if kind == "vector" and self.axes != 2:
            raise InvalidArgument(f"VP/CR segments need a 2-axis plane, not {self.axes} axes")
        if isinstance(segment, LinearInterp) and len(segment.increments) != self.axes:
            raise InvalidArgument(
                f"LI segment has {len(segment.increments)} increments for {self.axes} axes"
            )
        if self.size == self._cap:
            self._grow(2 * self._cap)
        i = self.size
        start = self._point.copy()
        if isinstance(segment, Arc):
            end, length = self._lay_arc(i, segment, start)
        else:
            step = (
                segment.increments
                if isinstance(segment, LinearInterp)
                else (
                    segment.dx,
                    segment.dy,
                )
            )
            end = self._anchor + np.asarray(step, dtype=np.float64)
            length = math.sqrt(math.fsum(float(v) ** 2 for v in (end - start)))
        self._start[i] = start
        self._end[i] = end
        self._len[i] = length
        self._cum += length
        bound = _round_half_up(self._cum)
        self._counts[i] = bound - self._bounds[i]
        self._bounds[i + 1] = bound
        self._point = end
        self._anchor = np.floor(end + 0.5)
        self._segments.append(segment)
        self.kind = kind
        self.size += 1
        return int(self._counts[i])

    def _lay_arc(self, i: int, arc: Arc, start: FloatArray) -> tuple[FloatArray, float]:
        theta = quantise_angle(arc.start, self.angle_resolution)
        sweep = quantise_angle(arc.sweep, self.angle_resolution)
        if sweep == 0:
            raise InvalidArgument(
                f"arc sweep {arc.sweep!r} rounds to 0 at {self.angle_resolution:g} degree steps"
            )
        r = arc.radius
        c0, s0 = _cos_sin(theta)
        centre = start - r * np.array([c0, s0])
        if math.fmod(sweep, 360.0) == 0.0:
            end = start.copy()  # whole turns close exactly
        else:
            c1, s1 = _cos_sin(theta + sweep)
            end = centre + r * np.array([c1, s1])
        self._arc[i] = True
        self._centre[i] = centre
        self._radius[i] = r
        self._theta0[i] = theta
        self._sweep[i] = sweep
        return end, r * abs(math.radians(sweep))

    def _tables(self) -> _Arrays:
        m = self.size
        return _Arrays(
            self._start[:m],
            self._end[:m],
            self._counts[:m],
            self._bounds[: m + 1],
            self._arc[:m],
            self._centre[:m],
            self._radius[:m],
            self._theta0[:m],
            self._sweep[:m],
        )

    def project(self, s: Int64Array) -> Int64Array:
        """Whole-count offsets from the origin for path positions ``s``: ``(axes, len(s))``."""
        if self.size == 0:
            return np.zeros((self.axes, s.size), dtype=np.int64)
        return _project(self._tables(), s)

    def segment_of(self, s: int) -> int:
        """Index of the segment the path position ``s`` lies in (0 when empty)."""
        if self.size == 0:
            return 0
        return int(_segment_index(self._tables(), np.array([s], dtype=np.int64))[0])

    def first_directions(self) -> tuple[int, ...]:
        """The direction each axis first moves in along the path laid out so far
        (:func:`first_directions`)."""
        return first_directions(self._segments, self.axes, self.angle_resolution)

    def completed(self, s: int) -> int:
        """Segments whose end the path position ``s`` has reached."""
        return int(np.searchsorted(self._bounds[1 : self.size + 1], s, side="right"))

    def snapshot(self) -> VectorPath:
        """A frozen copy of the layout."""
        if self.kind is None:
            raise InvalidArgument("an empty path has no layout")
        t = self._tables()
        return VectorPath(
            kind=self.kind,
            axes=self.axes,
            segments=tuple(self._segments),
            start=t.start.copy(),
            end=t.end.copy(),
            lengths=self._len[: self.size].copy(),
            counts=t.counts.copy(),
            bounds=t.bounds.copy(),
            arc=t.arc.copy(),
            centre=t.centre.copy(),
            radius=t.radius.copy(),
            theta0=t.theta0.copy(),
            sweep=t.sweep.copy(),
        )
