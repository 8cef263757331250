"""Coordinated motion: the vector profile along a path, projected onto its axes.

The controller runs one profile along the whole path of a sequence (``VM``/``VP``/``CR`` or
``LM``/``LI``): a trapezoid or triangle over the total path length at VS, VA and VD, with the
segments joined without stopping. Here that profile is the single-axis engine's: an
:class:`~galil.predict.engine.AxisProfiler` moves an integer path position ``s`` from 0 to the
path length exactly as it would move one axis (fractional position kept at 1/65536 count,
rounded half up), VT smoothing is its IT smoothing, ``ST`` its stop at VD, and a segment queued
during motion is an ``IP`` of the path: a re-plan from the present state towards the new end of
the path. Each sample's ``s`` is then projected onto the axes (:mod:`galil.predict.path`).

Without ``VE``/``LE`` the profile still plans to stop at the end of the segments it has: when
the host streams too slowly the motion slows down and waits, and the sequence stays running.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from galil.codes import tc_text
from galil.errors import CommandError, InvalidArgument, LimitError, missing_extra
from galil.models import ModelSpec
from galil.predict.engine import AxisProfiler, final_decel, ramping, slewing
from galil.predict.path import (
    ANGLE_RESOLUTION,
    Arc,
    LinearInterp,
    PathLayout,
    PathSegment,
    VectorPath,
    path_kind,
)
from galil.predict.profile import Profile
from galil.predict.quantities import no_quantity, period_seconds

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["SequenceEvent", "VectorProfile", "VectorProfiler", "replay", "vector"]

#: Longest prediction, in samples (about 13.6 hours at 1024 Hz), as for single-axis moves.
MAX_SAMPLES = 50_000_000

FloatArray = npt.NDArray[np.float64]
Int64Array = npt.NDArray[np.int64]

#: Stop codes of a vector sequence (``_SC`` of its axes).
RUNNING = 100
COMPLETED = 101


def _refuse(code: int, command: str) -> CommandError:
    return CommandError(code, tc_text(code), command)


def _command_of(segment: PathSegment) -> str:
    if isinstance(segment, LinearInterp):
        return "LI"
    return "CR" if isinstance(segment, Arc) else "VP"


class VectorProfiler:
    """The profiler of one coordinated-motion plane (S), stepped sample by sample.

    The simulator drives it from its servo loop; :func:`vector` drives it for a prediction. The
    same calls at the same samples give identical positions however :meth:`advance` is
    chunked. Speeds and accelerations must already be quantised as the controller stores them
    (:func:`galil.predict.quantise_vector`).

    Args:
        axes: axes of the plane (2 for VM; 1 to 8 for LM).
        sample_period: seconds per servo sample.
        position: axis positions at the start, counts (default zeros).
        buffer: segments the controller's buffer holds (:attr:`ModelSpec.vector_buffer`).
        angle_resolution: CR angle step, degrees.

    Attributes:
        sample: samples committed so far.
        position: per-axis reference at the last committed sample, counts.
        moving: ``_BGS``: a sequence was begun and has not completed or been stopped; a
            sequence without ``VE``/``LE`` stays moving, at rest, once its segments run out.
        stop_code: ``None`` before any sequence; 100 running, 101 completed, 4 ST, 7 AB.
    """

    def __init__(
        self,
        axes: int = 2,
        *,
        sample_period: float = 1 / 1024,
        position: Sequence[int] | None = None,
        buffer: int = 511,
        angle_resolution: float = ANGLE_RESOLUTION,
    ) -> None:
        if not (math.isfinite(sample_period) and sample_period > 0):
            raise InvalidArgument(f"sample period must be positive, got {sample_period!r}")
        if int(buffer) < 1:
            raise InvalidArgument(f"segment buffer must hold at least 1 segment, got {buffer!r}")
        layout = PathLayout(axes, angle_resolution=angle_resolution)  # 1 to 8 axes
        self.axes = layout.axes
        self.sample_period = float(sample_period)
        self.buffer = int(buffer)
        self.angle_resolution = float(angle_resolution)
        pos = (0,) * self.axes if position is None else tuple(int(p) for p in position)
        if len(pos) != self.axes:
            raise InvalidArgument(f"position has {len(pos)} values for {self.axes} axes")
        self.position: tuple[int, ...] = pos
        self.sample = 0
        self.moving = False
        self.stop_code: int | None = None
        self._layout = layout
        self._origin = np.array(pos, dtype=np.int64)
        self._path = AxisProfiler(sample_period=self.sample_period)
        self._begun = False
        self._ended = False
        self._stopping = False
        self._done = 0
        self._motion: tuple[float, float, float] = (0.0, 0.0, 0.0)

    # ---- read-outs ---------------------------------------------------------------------
    @property
    def distance(self) -> int:
        """Path travelled in this sequence (``_AVS``), counts."""
        return self._path.reference

    @property
    def velocity(self) -> float:
        """Speed along the path at the last sample (profiler, before rounding), counts/s."""
        return self._path.velocity

    @property
    def ramping(self) -> bool:
        """Whether the path speed changes towards VS at the present sample (see
        :func:`galil.predict.engine.ramping`): what ``AS S`` waits out."""
        return self.moving and ramping(self._path)

    @property
    def slewing(self) -> bool:
        """Whether the path runs at a constant speed now (:func:`~galil.predict.engine.slewing`):
        the plane status bit 5 of the data record."""
        return self.moving and slewing(self._path)

    @property
    def stopping(self) -> bool:
        """Whether ``ST`` or a limit is bringing the sequence to rest (plane status bit 4)."""
        return self.moving and self._stopping

    @property
    def final_decel(self) -> bool:
        """Whether the path is in the ramp to its end or to a stop
        (:func:`~galil.predict.engine.final_decel`): plane status bit 3."""
        return self.moving and final_decel(self._path)

    @property
    def length(self) -> int:
        """Whole counts of path queued in this sequence so far."""
        return self._layout.length

    @property
    def segments(self) -> int:
        """Segments given in this sequence so far."""
        return self._layout.size

    @property
    def segments_completed(self) -> int:
        """Segments whose end the path has reached (``_CSS``)."""
        return self._done

    @property
    def free_slots(self) -> int:
        """Free places in the segment buffer (``_LMS``); a slot frees when its segment ends."""
        return self.buffer - (self._layout.size - self._done)

    @property
    def segment(self) -> int:
        """Index of the segment the path is in (the last one once complete; 0 when empty)."""
        if self._layout.size == 0:
            return 0
        return self._layout.segment_of(self._path.reference)

    @property
    def ended(self) -> bool:
        """``VE``/``LE`` was given: no more segments in this sequence."""
        return self._ended

    @property
    def end_point(self) -> tuple[float, ...]:
        """Ideal end of the path queued so far, counts from the sequence origin (a ``VP``'s
        absolute coordinates minus this, from its whole-count anchor, give its ``Line``)."""
        return self._layout.end_point

    @property
    def kind(self) -> str | None:
        """``"vector"`` (VP/CR), ``"linear"`` (LI), or ``None`` before the first segment."""
        return self._layout.kind

    @property
    def end_sample(self) -> int | None:
        """Sample at which the sequence completes, when known.

        ``None`` while more segments may come (no ``VE``/``LE``) or while smoothing has not
        yet settled far enough ahead to know it.
        """
        if not self.moving:
            return self.sample
        if not (self._ended or self._stopping):
            return None
        return self._path.end_sample

    def first_directions(self) -> tuple[int, ...]:
        """The direction (+1, -1, 0) each axis first moves in along the segments queued so
        far (:func:`~galil.predict.path.first_directions`): what ``BG S`` checks the limit
        switches and soft limits against."""
        return self._layout.first_directions()

    def path(self) -> VectorPath:
        """The path of this sequence laid out so far.

        Raises:
            InvalidArgument: no segment yet.
        """
        return self._layout.snapshot()

    # ---- commands ----------------------------------------------------------------------
    def add(self, segment: PathSegment) -> None:
        """Queue a segment (``VP``, ``CR`` or ``LI``), before ``BGS`` or during the sequence.

        A segment given after a sequence has finished starts a new one from where the axes
        are. During motion the profile is re-planned towards the new end of the path.

        Raises:
            CommandError: TC 33 for LI in a VP/CR sequence or the reverse, TC 32 when the
                buffer is full.
            InvalidArgument: wrong number of axes, or a segment after ``VE``/``LE`` or during
                a stop.
        """
        kind = path_kind(segment)
        if self._begun and not self.moving:
            self._new_sequence()
        if self._layout.kind is not None and kind != self._layout.kind:
            raise _refuse(33, _command_of(segment))
        if self._ended:
            raise InvalidArgument("the sequence was ended (VE/LE); no more segments")
        if self._stopping:
            raise InvalidArgument("the sequence is stopping (ST); no more segments")
        if self.free_slots <= 0:
            raise _refuse(32, _command_of(segment))
        n = self._layout.append(segment)
        if self.moving and n > 0:
            speed, accel, decel = self._motion
            self._path.increment(n, speed, accel, decel)

    def extend(self, segments: Iterable[PathSegment]) -> None:
        """:meth:`add` each segment in turn."""
        for seg in segments:
            self.add(seg)

    def end(self) -> None:
        """``VE``/``LE``: the sequence ends with the segments given so far."""
        self._ended = True
        self._settle()

    def begin(
        self,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float = 1.0,
        *,
        position: Sequence[int] | None = None,
    ) -> None:
        """``BGS``: start the sequence at VS ``speed``, VA ``accel``, VD ``decel`` (VT).

        Args:
            speed: VS, counts/s. accel: VA, counts/s². decel: VD, counts/s².
            smoothing: VT (IT on models without VT), 1 for none.
            position: where the axes are now (the sequence origin), if they moved since.

        Raises:
            CommandError: TC 21 while the sequence runs, TC 24 with no segment queued.
        """
        if self.moving:
            raise _refuse(21, "BG")
        if self._begun:
            self._new_sequence()
        if self._layout.size == 0:
            raise _refuse(24, "BG")
        if position is not None:
            self.set_position(position)
        if not (math.isfinite(speed) and speed > 0):
            raise InvalidArgument(f"vector speed must be > 0, got {speed!r}")
        self._path.begin_move(self.length, speed, accel, decel, smoothing)
        self._motion = (float(speed), float(accel), float(decel))
        self._begun = True
        self.moving = True
        self.stop_code = RUNNING
        self._settle()

    def set_position(self, position: Sequence[int]) -> None:
        """Tell an idle plane where its axes are (they moved independently, or DP).

        Raises:
            InvalidArgument: while the sequence runs, or the wrong number of values.
        """
        if self.moving:
            raise InvalidArgument("cannot move the origin of a running sequence")
        pos = tuple(int(p) for p in position)
        if len(pos) != self.axes:
            raise InvalidArgument(f"position has {len(pos)} values for {self.axes} axes")
        self.position = pos
        self._origin = (
            np.array(pos, dtype=np.int64)
            - self._layout.project(np.array([self._path.reference], dtype=np.int64))[:, 0]
        )

    def stop(self) -> None:
        """``ST``: decelerate along the path at VD; the sequence ends where it comes to rest."""
        if not self.moving or self._stopping:
            return
        self._stopping = True
        self.stop_code = 4
        self._path.stop()
        self._settle()

    def abort(self) -> None:
        """``AB``: stop at once where the reference is now (stop code 7)."""
        if not self.moving:
            return
        self._path.abort()
        self._finish(7)

    def clear(self) -> None:
        """``CS``: forget the segments of an idle plane; the next segment starts afresh.

        Raises:
            InvalidArgument: while the sequence runs.
        """
        if self.moving:
            raise InvalidArgument("cannot clear the sequence while it runs")
        self._new_sequence()

    def _new_sequence(self) -> None:
        self._layout = PathLayout(self.axes, angle_resolution=self.angle_resolution)
        self._origin = np.array(self.position, dtype=np.int64)
        self._path = AxisProfiler(sample_period=self.sample_period)
        self._begun = self._ended = self._stopping = False
        self._done = 0

    def _finish(self, code: int) -> None:
        self.moving = False
        self.stop_code = code
        self._stopping = False

    def _settle(self) -> None:
        """Bring the sequence state up to date after the path engine changed or stepped."""
        path = self._path
        s = path.reference
        self._done = self._layout.completed(s)
        end = path.end_sample
        if not self.moving or (path.moving and (end is None or end > path.sample)):
            return
        if self._stopping:
            self._finish(4)
        elif self._ended and s == self.length:
            self._finish(COMPLETED)

    # ---- stepping ----------------------------------------------------------------------
    def preview(self, n: int) -> Int64Array:
        """The axis references of the next ``n`` samples, without committing them."""
        ahead = copy.copy(self)  # advancing reads the layout, never changes it
        ahead._path = copy.deepcopy(self._path)
        return ahead.advance(n)

    def preview_speed(self, n: int) -> FloatArray:
        """Profiler speed along the path over the next ``n`` samples, counts/s."""
        return self._path.preview_velocity(n)

    def advance(self, n: int) -> Int64Array:
        """Commit the next ``n`` samples; return the axis references, shape ``(axes, n)``."""
        return self.advance_path(n)[1]

    def advance_path(self, n: int) -> tuple[Int64Array, Int64Array]:
        """Commit ``n`` samples; return the path positions ``s`` and the axis references."""
        n = int(n)
        if n < 0:
            raise InvalidArgument(f"sample count must be >= 0, got {n}")
        if not self.moving:
            self.sample += n
            s = np.full(n, self._path.reference, dtype=np.int64)
            held = np.repeat(np.array(self.position, dtype=np.int64)[:, None], n, axis=1)
            return s, held
        s = self._path.advance(n)
        pos = self._layout.project(s)
        pos += self._origin[:, None]
        self.sample += n
        if n:
            self.position = tuple(int(v) for v in pos[:, -1])
        self._settle()
        return s, pos


@dataclass(frozen=True, eq=False)
class VectorProfile:
    """A predicted coordinated-motion sequence, one value per servo sample (k = 0..N).

    Attributes:
        t: sample times, seconds.
        position: per-axis reference, counts, shape ``(axes, N + 1)`` (int64).
        path: position along the path (``_AVS``), whole counts, after VT smoothing.
        speed: the profiler's speed along the path (before rounding and smoothing), counts/s.
        segment: index of the segment each sample is in (a sample on a boundary ends the
            earlier segment).
        duration: ``N * sample_period``.
        sample_period: seconds per sample.
        layout: the laid-out path (:class:`~galil.predict.path.VectorPath`).
        shape: ``"trapezoid"`` or ``"triangle"`` (of the whole path), or ``"none"``.
        peak_speed: largest profiler speed along the path, counts/s.
        speed_settings: ``(VS, VA, VD, VT)`` used (after quantisation when a model was given).
        stop_code: 101 (completed).
    """

    t: FloatArray
    position: Int64Array
    path: Int64Array
    speed: FloatArray
    segment: Int64Array
    duration: float
    sample_period: float
    layout: VectorPath
    shape: str
    peak_speed: float
    speed_settings: tuple[float, float, float, float]
    stop_code: int = COMPLETED

    def __post_init__(self) -> None:
        for arr in (self.t, self.position, self.path, self.speed, self.segment):
            arr.setflags(write=False)

    @property
    def samples(self) -> int:
        """N, the index of the last sample."""
        return int(self.t.size - 1)

    @property
    def axes(self) -> int:
        """Number of axes."""
        return int(self.position.shape[0])

    @property
    def length(self) -> int:
        """Whole counts of path."""
        return self.layout.length

    @property
    def start(self) -> tuple[int, ...]:
        """Axis positions at sample 0."""
        return tuple(int(v) for v in self.position[:, 0])

    @property
    def end(self) -> tuple[int, ...]:
        """Axis positions at the last sample."""
        return tuple(int(v) for v in self.position[:, -1])

    def axis(self, i: int) -> Profile:
        """Axis ``i`` as a single-axis :class:`Profile` (for plots and soft-limit checks)."""
        if not 0 <= i < self.axes:
            raise InvalidArgument(f"axis index {i} is outside 0..{self.axes - 1}")
        pos = self.position[i]
        vel = np.abs(np.diff(pos)) / self.sample_period if pos.size > 1 else np.zeros(1)
        return Profile.from_samples(
            pos,
            sample_period=self.sample_period,
            shape="vector",
            peak_speed=float(vel.max()) if vel.size else 0.0,
            stop_code=self.stop_code,
        )

    def samples_of(self, index: int) -> tuple[int, int]:
        """First and last sample that lie in segment ``index`` (``(-1, -1)`` if none)."""
        hit = np.flatnonzero(self.segment == index)
        if hit.size == 0:
            return -1, -1
        return int(hit[0]), int(hit[-1])

    def plot(self, *, title: str | None = None) -> Figure:
        """Plot the path of the first two axes and the speed along the path; return the Figure.

        matplotlib is imported here, not at import time.
        """
        try:
            from matplotlib.figure import Figure
        except ImportError as exc:
            raise missing_extra(exc, "VectorProfile.plot()") from exc

        fig = Figure(figsize=(10, 4.5), layout="constrained")
        ax_xy, ax_v = fig.subplots(1, 2)
        if self.axes >= 2:
            ax_xy.plot(self.position[0], self.position[1])
            ax_xy.set_aspect("equal", adjustable="datalim")
            ax_xy.set_xlabel("axis 0 (counts)")
            ax_xy.set_ylabel("axis 1 (counts)")
        else:
            ax_xy.plot(self.t, self.position[0])
            ax_xy.set_xlabel("time (s)")
            ax_xy.set_ylabel("axis 0 (counts)")
        ax_v.plot(self.t, self.speed)
        ax_v.set_xlabel("time (s)")
        ax_v.set_ylabel("speed along the path (counts/s)")
        for ax in (ax_xy, ax_v):
            ax.grid(True, alpha=0.3)
        fig.suptitle(title or f"{len(self.layout)} segments, {self.duration:.4g} s")
        return fig

    def _repr_pretty_(self, p: Any, cycle: bool) -> None:
        p.text("VectorProfile(...)" if cycle else repr(self))

    def __repr__(self) -> str:
        return (
            f"VectorProfile({self.layout.kind}, segments={len(self.layout)}, axes={self.axes},"
            f" length={self.length}, duration={self.duration:.6g}, start={self.start},"
            f" end={self.end}, peak_speed={self.peak_speed:.6g})"
        )


def _mixing_error(segments: Sequence[PathSegment]) -> LimitError | None:
    kind = path_kind(segments[0])
    for i, seg in enumerate(segments):
        if path_kind(seg) != kind:
            return LimitError(
                f"segment {i} ({_command_of(seg)}) cannot follow {kind} segments in one"
                f" sequence: TC 33 {tc_text(33)}",
                name="TC 33",
                value=i,
                limit=None,
                sample=None,
            )
    return None


def _axes_of(segments: Sequence[PathSegment]) -> int:
    first = segments[0]
    if isinstance(first, LinearInterp):
        return len(first.increments)
    return 2


def _resolve(
    speed: float,
    accel: float,
    decel: float,
    smoothing: float,
    sample_period: float,
    model: str | ModelSpec | None,
    tm: float | None,
) -> tuple[float, float, float, float, float, float]:
    """(VS, VA, VD, VT, sample period, CR angle step), quantised when a model is given."""
    for name, value in (("speed", speed), ("accel", accel), ("decel", decel)):
        no_quantity(value, f"vector {name}", "counts/s" if name == "speed" else "counts/s²")
    no_quantity(smoothing, "smoothing", "VT (a fraction, 1/256 .. 1)", counts=False)
    sample_period = period_seconds(sample_period)
    for name, value in (("speed", speed), ("accel", accel), ("decel", decel)):
        if not (math.isfinite(value) and value > 0):
            raise InvalidArgument(f"vector {name} must be a positive number, got {value!r}")
    if model is None:
        return speed, accel, decel, smoothing, sample_period, ANGLE_RESOLUTION
    from galil.predict.vector_checks import quantise_vector

    q = quantise_vector(model, speed=speed, accel=accel, decel=decel, smoothing=smoothing, tm=tm)
    assert q.speed is not None
    assert q.accel is not None
    assert q.decel is not None
    assert q.smoothing is not None
    spec = q.model
    return q.speed, q.accel, q.decel, q.smoothing, q.sample_period, spec.cr_angle_resolution


def vector(
    segments: Sequence[PathSegment],
    speed: float,
    accel: float,
    decel: float,
    *,
    sample_period: float = 1 / 1024,
    start: Sequence[int] | None = None,
    smoothing: float = 1.0,
    model: str | ModelSpec | None = None,
    tm: float | None = None,
) -> VectorProfile:
    """Predict a coordinated-motion sequence: VP/CR segments (VM) or LI segments (LM).

    Args:
        segments: :class:`~galil.predict.path.Line` and :class:`~galil.predict.path.Arc`
            segments, or :class:`~galil.predict.path.LinearInterp` segments (not both).
        speed: VS, counts/s along the path.
        accel: VA, counts/s². decel: VD, counts/s².
        sample_period: seconds per servo sample.
        start: axis positions at sample 0 (default zeros); the sequence origin.
        smoothing: VT (IT on models without VT), 1 for none.
        model: when given, VS/VA/VD/VT are quantised as that model stores them (and
            range-checked), CR angles use its step, and its sample period is used.
        tm: with ``model``, TM in µs (default: the model's default).

    Returns:
        The :class:`VectorProfile` from sample 0 to the sample where the sequence completes
        (``VE``/``LE`` given with the last segment).

    Raises:
        InvalidArgument: bad arguments; LimitError: mixed segment kinds (TC 33) or, with
            ``model``, values outside its range. See :func:`check_vector` for the full checks.
    """
    segs = tuple(segments)
    if not segs:
        raise InvalidArgument("a vector sequence needs at least one segment")
    mixed = _mixing_error(segs)
    if mixed is not None:
        raise mixed
    speed, accel, decel, smoothing, ts, angle = _resolve(
        speed, accel, decel, smoothing, sample_period, model, tm
    )
    if not (math.isfinite(ts) and ts > 0):
        raise InvalidArgument(f"sample_period must be positive, got {ts!r}")
    eng = VectorProfiler(
        _axes_of(segs), sample_period=ts, position=start, buffer=len(segs), angle_resolution=angle
    )
    eng.extend(segs)
    eng.end()
    eng.begin(speed, accel, decel, smoothing)
    return _predict(eng, (speed, accel, decel, smoothing))


_Parts = tuple[list[Int64Array], list[Int64Array], list[FloatArray]]


def _predict(
    eng: VectorProfiler,
    settings: tuple[float, float, float, float],
    first: Int64Array | None = None,
    before: _Parts | None = None,
    shape: str | None = None,
) -> VectorProfile:
    """Step a begun, ended (or stopping) sequence to its end and collect its profile.

    ``first`` (the axes at sample 0) and ``before`` (chunks already stepped since) are given
    when the sequence was stepped by :func:`replay` first.
    """
    ts = eng.sample_period
    plan = eng._path.plan
    if first is None:
        first = np.array(eng.position, dtype=np.int64)[:, None]
    s_parts, p_parts, v_parts = before if before is not None else ([], [], [])
    more = _run(eng)
    s_parts, p_parts, v_parts = s_parts + more[0], p_parts + more[1], v_parts + more[2]
    layout = eng.path()
    s = np.concatenate([np.zeros(1, np.int64), *s_parts])
    pos = np.concatenate([first, *p_parts], axis=1)
    v = np.concatenate([np.zeros(1), *v_parts])
    if shape is None:
        assert plan is not None
        shape = plan.shape
    return VectorProfile(
        t=np.arange(s.size, dtype=np.float64) * ts,
        position=pos,
        path=s,
        speed=v,
        segment=layout.segment_of(s),
        duration=(s.size - 1) * ts,
        sample_period=ts,
        layout=layout,
        shape=shape,
        peak_speed=float(np.abs(v).max()) if plan is None or before else plan.peak / ts,
        speed_settings=settings,
        stop_code=eng.stop_code if eng.stop_code is not None else COMPLETED,
    )


@dataclass(frozen=True)
class SequenceEvent:
    """What the host sent during a sequence, at a sample counted from its ``BGS``.

    Attributes:
        sample: samples after the ``BGS`` sample (the ``MG TIME`` of the line, minus that of
            the ``BGS`` line).
        kind: ``"add"`` (segments), ``"end"`` (``VE``/``LE``), ``"stop"`` (``ST``) or
            ``"abort"`` (``AB``).
        segments: the segments of an ``"add"``.
    """

    sample: int
    kind: str
    segments: tuple[PathSegment, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in ("add", "end", "stop", "abort"):
            raise InvalidArgument(f"event kind is add, end, stop or abort, not {self.kind!r}")


def _apply(eng: VectorProfiler, event: SequenceEvent) -> None:
    if event.kind == "add":
        eng.extend(event.segments)
    elif event.kind == "end":
        eng.end()
    elif event.kind == "stop":
        eng.stop()
    else:
        eng.abort()


def replay(
    segments: Sequence[PathSegment],
    speed: float,
    accel: float,
    decel: float,
    *,
    events: Iterable[SequenceEvent] = (),
    ended: bool = True,
    sample_period: float = 1 / 1024,
    start: Sequence[int] | None = None,
    smoothing: float = 1.0,
    angle_resolution: float = ANGLE_RESOLUTION,
) -> VectorProfile:
    """Predict a sequence from what was sent when: segments queued before ``BGS``, then
    segments, ``VE``/``LE``, ``ST`` or ``AB`` at known samples (a streamed path, a stop).

    Values must already be quantised (:func:`galil.predict.quantise_vector`). A sequence that
    is neither ended nor stopped after the last event is predicted as if ``VE``/``LE``
    followed it: it stops at the end of its segments.

    Args:
        segments: the segments queued before ``BGS`` (at least one).
        speed, accel, decel, smoothing, sample_period, start: as :func:`vector`.
        events: what came after ``BGS``, by sample.
        ended: ``VE``/``LE`` was sent before ``BGS``.
        angle_resolution: CR angle step, degrees.

    Raises:
        InvalidArgument: no segments, a bad event; CommandError: what the controller would
            refuse (TC 33 mixing segment kinds).
    """
    segs = tuple(segments)
    if not segs:
        raise InvalidArgument("a vector sequence needs at least one segment")
    eng = VectorProfiler(
        _axes_of(segs),
        sample_period=sample_period,
        position=start,
        buffer=1 << 40,
        angle_resolution=angle_resolution,
    )
    eng.extend(segs)
    if ended:
        eng.end()
    eng.begin(speed, accel, decel, smoothing)
    settings = (float(speed), float(accel), float(decel), float(smoothing))
    first = np.array(eng.position, dtype=np.int64)[:, None]
    parts: _Parts = ([], [], [])
    shape: str | None = None
    for event in sorted(events, key=lambda e: e.sample):
        if not eng.moving:
            break
        if event.sample > eng.sample:
            _collect(eng, event.sample - eng.sample, parts)
        _apply(eng, event)
        if event.kind != "end":
            shape = "stopped" if event.kind in ("stop", "abort") else (shape or "changed")
    if eng.moving and not eng.ended and eng.stop_code != 4:
        eng.end()
    return _predict(eng, settings, first, parts, shape)


def _collect(eng: VectorProfiler, n: int, parts: _Parts) -> None:
    """Step ``n`` samples of a running sequence into ``parts``."""
    parts[2].append(eng.preview_speed(n))
    s, pos = eng.advance_path(n)
    parts[0].append(s)
    parts[1].append(pos)


def _run(eng: VectorProfiler) -> tuple[list[Int64Array], list[Int64Array], list[FloatArray]]:
    """Step ``eng`` to the end of its sequence; the path, axis and speed chunks."""
    s_parts: list[Int64Array] = []
    p_parts: list[Int64Array] = []
    v_parts: list[FloatArray] = []
    step = 1024
    while eng.moving:
        if eng.sample > MAX_SAMPLES:
            raise InvalidArgument(f"the sequence does not complete within {MAX_SAMPLES} samples")
        end = eng.end_sample
        if end is None:
            eng._path.preview(step)  # lets smoothing find where it settles
            end = eng.end_sample
        n = end - eng.sample if end is not None and end > eng.sample else step
        v_parts.append(eng.preview_speed(n))
        s, pos = eng.advance_path(n)
        s_parts.append(s)
        p_parts.append(pos)
        step = min(step * 2, 1 << 20)
    return s_parts, p_parts, v_parts
