"""Coordinated motion: vector mode (``VM VP CR VE``), linear interpolation (``LM LI LE``).

Each coordinate system (plane ``S`` or ``T``, picked with ``CA``) queues segments in a buffer
and runs one profile along the whole path at ``VS``/``VA``/``VD`` once ``BG S`` is given. The
profile is the predictor's :class:`~galil.predict.vector.VectorProfiler`: this room holds no
motion math. While a sequence runs, its axes belong to it: their profilers are
:class:`~galil.sim.driven.DrivenProfiler`\\ s fed by one :class:`PlaneFeed`, so ``BG`` on them
is refused (TC 21), ``ST`` or a soft limit on any of them stops the whole sequence at ``VD``
(stop code 4, or 2/3 for a limit), ``AB`` stops it at once (7), and each reports stop code 100
while it runs and 101 once it completes. Where the manuals are silent (assumptions):

- ``VP`` takes absolute coordinates from the sequence start (the controller zeroes them at
  ``BG S``); ``LI`` takes one increment per axis, fields by axis position like ``PR``;
- ``VS``/``VA``/``VD`` are kept per plane (``VS n`` for the selected one, ``VSS=n``,
  ``VS s,t``); a change during a sequence applies to the next one;
- on models without ``VT`` the sequence is smoothed with the ``IT`` of its first axis;
- a segment into a full buffer is refused (TC 32), as are ``VP``/``CR`` mixed with ``LI``
  (TC 33), a segment shorter than the model's minimum (TC 30), a path beyond two billion
  counts (TC 31), ``VM``/``LM``/``CS`` during a sequence (TC 29) and ``BG S`` without segments
  (TC 24); per-segment speeds (``VP x,y < n``) are not simulated (TC 6);
- ``BG S`` is refused (TC 22) when an axis's first motion along the queued segments heads
  into its active limit switch (one ``LD`` leaves on) or on past a soft limit it is beyond,
  as an independent ``BG`` is (the reference says so of soft limits only: decision 0050).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import CommandError, InvalidArgument
from galil.predict.path import Arc, Line, LinearInterp, PathSegment
from galil.predict.vector import VectorProfiler
from galil.predict.vector_checks import quantise_vector
from galil.sim.driven import DrivenProfiler, drive
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.motion import Motion
from galil.sim.servo import Axis

__all__ = ["PlaneFeed", "Vector"]

Int64Array = npt.NDArray[np.int64]
#: The coordinate systems, one letter each (a tuple: "" and "ST" are no plane).
_PLANES = ("S", "T")


class PlaneFeed:
    """The running sequence of one plane, shared by the driven profilers of its axes.

    The first axis to step a chunk advances the sequence; the others read the same samples.

    Attributes:
        eng: the sequence.
        plane: ``"S"`` or ``"T"``.
    """

    mode = "vector"

    def __init__(self, eng: VectorProfiler, plane: str) -> None:
        self.eng = eng
        self.plane = plane
        # Samples advanced and not yet taken by every axis: one row per axis, then the path
        # position (what an axis geared to the plane, GA S, follows).
        self._buf: Int64Array = np.empty((eng.axes + 1, 0), np.int64)
        self._taken = [0] * eng.axes
        self._limit: int | None = None  # the stop code of a limit that stopped it

    def _fill(self, upto: int) -> None:
        have = int(self._buf.shape[1])
        if upto > have:
            s, pos = self.eng.advance_path(upto - have)
            more = np.vstack([pos, s[None, :]])
            self._buf = np.concatenate([self._buf, more], axis=1) if have else more

    def distance(self, n: int) -> Int64Array:
        """The path position of the next ``n`` samples, for an axis that steps before the
        plane's own axes (a gear follower): they then take the same samples."""
        t = min(self._taken)
        self._fill(t + n)
        out: Int64Array = self._buf[-1, t : t + n].copy()
        return out

    def take(self, index: int, n: int) -> Int64Array:
        t = self._taken[index]
        self._fill(t + n)
        out: Int64Array = self._buf[index, t : t + n].copy()
        self._taken[index] = t + n
        drop = min(self._taken)
        if drop:
            self._buf = self._buf[:, drop:]
            self._taken = [x - drop for x in self._taken]
        return out

    def peek(self, index: int, n: int) -> Int64Array:
        t = self._taken[index]
        have = int(self._buf.shape[1])
        if t + n <= have:
            out: Int64Array = self._buf[index, t : t + n].copy()
            return out
        more = self.eng.preview(t + n - have)
        out = np.concatenate([self._buf[index, t:], more[index]])
        return out

    def remaining(self, index: int) -> int | None:
        pending = int(self._buf.shape[1]) - self._taken[index]
        eng = self.eng
        if not eng.moving:
            return pending
        end = eng.end_sample
        return None if end is None else max(0, end - eng.sample) + pending

    def moving(self, index: int) -> bool:
        return self.remaining(index) != 0

    def stop_code(self, index: int) -> int:
        code = self.eng.stop_code
        if code == 4 and self._limit is not None:
            return self._limit
        return 100 if code is None else code

    def stop(self, code: int) -> None:
        if self.eng.moving and code != 4 and self._limit is None:
            self._limit = code
        self.eng.stop()

    def abort(self) -> None:
        self.eng.abort()


@dataclass
class Plane:
    """One coordinate system: its mode, axes, vector parameters and sequence."""

    letter: str
    kind: str | None = None  # "vector" after VM, "linear" after LM
    axes: str = ""
    vs: float = 25000.0
    va: float = 256000.0
    vd: float = 256000.0
    vt: float = 1.0
    eng: VectorProfiler | None = None  # the sequence being queued, or the last one run
    running: bool = False  # BG S was given and the sequence has not been seen to end
    starts: int = 0  # sequences begun (AV measures from the start of the present one)


class Vector(Room):
    """The coordinate systems S and T: their buffers, sequences and parameters."""

    requires = (Motion,)

    def reset(self) -> None:
        self.planes = {p: Plane(p) for p in _PLANES}
        self.selected = "S"

    def burn(self, name: str) -> object | None:
        # The BN table: VS VA VD (not VT), of each coordinate system.
        if name != "BN":
            return None
        return {p.letter: (p.vs, p.va, p.vd) for p in self.planes.values()}

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, dict)
        for letter, (vs, va, vd) in saved.items():
            plane = self.planes[letter]
            plane.vs, plane.va, plane.vd = vs, va, vd

    # ---- the sequence of a plane -------------------------------------------------------
    def feed(self, plane: Plane) -> PlaneFeed | None:
        """The feed of ``plane``'s running sequence, found through its axes."""
        if not plane.axes:
            return None
        prof = self.machine.servo.axes[plane.axes[0]].m.profiler
        src = prof.source if isinstance(prof, DrivenProfiler) else None
        if isinstance(src, PlaneFeed) and src.plane == plane.letter:
            return src
        return None

    def engine(self, plane: Plane) -> VectorProfiler | None:
        """The sequence of ``plane``: the running one, else the one queued or last run."""
        if plane.running:
            self._refresh(plane)  # a sequence may end in a command (ST at rest), not a step
        return plane.eng

    def busy(self, plane: Plane) -> bool:
        """``_BGS``: some axis of ``plane`` is driven by its sequence (read from the axes)."""
        for c in plane.axes:
            prof = self.machine.servo.axes[c].m.profiler
            if isinstance(prof, DrivenProfiler) and prof.driven:
                src = prof.source
                if isinstance(src, PlaneFeed) and src.plane == plane.letter:
                    return True
        return False

    def _refs(self, plane: Plane) -> list[int]:
        return [self.machine.servo.axes[c].m.reference for c in plane.axes]

    def _queueing(self, plane: Plane) -> VectorProfiler:
        """The sequence new segments go to (a new one once the last has finished)."""
        if plane.kind is None:
            raise Refused(28, "no VM or LM for this coordinate system")
        eng = self.engine(plane)
        if eng is None or (eng.stop_code is not None and not eng.moving):
            spec = self.machine.spec
            eng = VectorProfiler(
                len(plane.axes),
                sample_period=self.machine.servo.ts,
                position=self._refs(plane),
                buffer=spec.vector_buffer,
                angle_resolution=spec.cr_angle_resolution,
            )
            plane.eng = eng
        return eng

    def _add(self, plane: Plane, segment: PathSegment) -> str:
        eng = self._queueing(plane)
        spec = self.machine.spec
        if segment.length < spec.vector_segment_min:
            raise Refused(30, "segment too short")
        if eng.length + segment.length > spec.vector_distance_max:
            raise Refused(31, "sequence longer than two billion counts")
        try:
            eng.add(segment)
        except CommandError as e:
            raise Refused(e.code or 6, e.text) from None
        except InvalidArgument as e:
            raise Refused(6, str(e)) from None
        return ""

    def _plane(self, text: str) -> Plane:
        t = text.strip()
        if not t:
            return self.planes[self.selected]
        if t not in _PLANES:
            raise Refused(28, "S or T")
        return self.planes[t]

    # ---- hooks -------------------------------------------------------------------------
    def after_step(self) -> None:
        for plane in self.planes.values():
            if plane.running:
                self._refresh(plane)

    def _refresh(self, plane: Plane) -> None:
        """Take the running sequence from the axes (a snapshot may have replaced it), and
        note when it has ended."""
        found = self.feed(plane)
        if found is not None:
            plane.eng = found.eng
        if found is None or not self.busy(plane):
            plane.running = False

    def abort(self) -> None:
        for plane in self.planes.values():
            if plane.running:
                self._refresh(plane)
                plane.running = False

    # ---- setting up --------------------------------------------------------------------
    @handler("CA")
    def ca(self, args: str) -> str:
        a = args.strip()
        if a == "?":
            return self.machine.interp.num(_PLANES.index(self.selected), "1.0") + "\r\n"
        if a not in _PLANES:
            # One plane, S or T ("CA S", "CS S|T": galil-wave2-facts.md §6 [P:EPICS, QCODES]);
            # a bare CA or "CA ST" names none: refused with TC 28 "S operand not valid"
            # (galil-protocol.md §1.2) as a bad plane is [U: the code for a missing one].
            raise Refused(28, "CA takes S or T")
        self.selected = a
        return ""

    def _mode(self, kind: str, args: str) -> str:
        plane = self.planes[self.selected]
        a = args.replace(" ", "").replace(",", "")
        if a == "?":
            eng = self.engine(plane)
            free = self.machine.spec.vector_buffer if eng is None else eng.free_slots
            return self.machine.interp.num(free, "10.0") + "\r\n"
        letters = [self.machine.interp.axis(c).letter for c in a]
        if len(set(letters)) != len(letters) or not letters:
            raise Refused(6, "axes must be distinct")
        if kind == "vector" and len(letters) != 2:
            raise Refused(6, "VM takes two axes")
        self.engine(plane)
        if plane.running:
            raise Refused(29, "sequence running")
        plane.kind, plane.axes, plane.eng = kind, "".join(letters), None
        return ""

    @handler("VM")
    def vm(self, args: str) -> str:
        return self._mode("vector", args)

    @handler("LM")
    def lm(self, args: str) -> str:
        return self._mode("linear", args)

    @handler("CS")
    def cs(self, args: str) -> str:
        plane = self._plane(args)
        self.engine(plane)
        if plane.running:
            raise Refused(29, "sequence running")
        plane.eng = None
        return ""

    # ---- segments ----------------------------------------------------------------------
    def _numbers(self, args: str, count: int) -> list[float]:
        if "<" in args or ">" in args:
            raise Refused(6, "per-segment speeds are not simulated")
        fields = split_fields(args)
        if len(fields) != count or not all(f.strip() for f in fields):
            raise Refused(50, "not enough fields")
        return [self.machine.interp.evaluate(f) for f in fields]

    @handler("VP")
    def vp(self, args: str) -> str:
        plane = self.planes[self.selected]
        x, y = self._numbers(args, 2)
        if plane.kind == "linear":
            raise Refused(33, "VP in LM mode")
        if not (x.is_integer() and y.is_integer()) or max(abs(x), abs(y)) > 2**31 - 1:
            raise Refused(6, "VP coordinates are 32-bit counts")
        eng = self._queueing(plane)
        ax, ay = (math.floor(v + 0.5) for v in eng.end_point)
        return self._add(plane, Line(int(x) - ax, int(y) - ay))

    @handler("CR")
    def cr(self, args: str) -> str:
        plane = self.planes[self.selected]
        r, theta, delta = self._numbers(args, 3)
        if plane.kind == "linear":
            raise Refused(33, "CR in LM mode")
        spec = self.machine.spec
        lo, hi = spec.cr_radius
        amax = spec.cr_angle_max
        if not lo <= r <= hi or abs(theta) > amax or abs(delta) > amax or delta == 0:
            raise Refused(6, "CR out of range")
        if abs(r * delta) > spec.cr_arc_max:
            raise Refused(6, "CR out of range")
        try:
            arc = Arc(r, theta, delta)
        except InvalidArgument:
            raise Refused(6, "CR out of range") from None
        return self._add(plane, arc)

    @handler("LI")
    def li(self, fields: str) -> str:
        plane = self.planes[self.selected]
        if "<" in fields or ">" in fields:
            raise Refused(6, "per-segment speeds are not simulated")
        if plane.kind == "vector":
            raise Refused(33, "LI in VM mode")
        given = self.machine.interp.axis_fields(fields)
        values = {ax.letter: self.machine.interp.evaluate(t) for ax, t in given}
        li_max = self.machine.spec.li_max
        for letter, v in values.items():
            if not v.is_integer() or abs(v) > li_max:
                raise Refused(6, "LI out of range")
            if v and letter not in plane.axes:
                raise Refused(6, "LI on an axis not in LM")
        if plane.kind is None:
            raise Refused(28, "no LM")
        incs = tuple(int(values.get(c, 0)) for c in plane.axes)
        return self._add(plane, LinearInterp(incs))

    def _end(self) -> str:
        plane = self.planes[self.selected]
        eng = self._queueing(plane)
        eng.end()
        return ""

    @handler("VE")
    def ve(self, args: str) -> str:
        return self._end()

    @handler("LE")
    def le(self, args: str) -> str:
        return self._end()

    # ---- vector parameters -------------------------------------------------------------
    def _parameter(self, args: str, name: str) -> str:
        """``VS n`` (selected plane), ``VSS=n``, ``VS s,t``, ``VS ?``, ``VSS=?``."""
        a = args.strip()
        assigns: list[tuple[Plane, str]]
        if "=" in a:
            left, _, right = a.partition("=")
            assigns = [(self._plane(left), right.strip())]
        else:
            fields = split_fields(a)
            if len(fields) > 2:
                raise Refused(4, "S and T only")
            if len(fields) == 1:
                assigns = [(self.planes[self.selected], fields[0].strip())]
            else:
                assigns = [
                    (self.planes[p], f.strip()) for p, f in zip(_PLANES, fields, strict=True)
                ]
        out = []
        values: list[tuple[Plane, float]] = []  # (checked all before any is set)
        for plane, text in assigns:
            if text == "?":
                out.append(self.machine.interp.num(getattr(plane, name), "10.0"))
            elif text:
                value = self._quantised(name, self.machine.interp.evaluate(text))
                # DMC-4103 command reference: VD "Not Valid while in motion" (VS, VA are).
                if name == "vd" and self.busy(plane):
                    raise Refused(7, "VD while the sequence runs")
                values.append((plane, value))
        for plane, value in values:
            setattr(plane, name, value)
        return ",".join(out) + "\r\n" if out else ""

    def _quantised(self, name: str, value: float) -> float:
        spec = self.machine.spec
        key = {"vs": "speed", "va": "accel", "vd": "decel", "vt": "smoothing"}[name]
        try:
            q = quantise_vector(spec, **{key: value}, tm=self.machine.servo.tm)
        except InvalidArgument:  # LimitError included
            raise Refused(6, f"{name.upper()} out of range") from None
        got = getattr(q, key)
        assert got is not None
        return float(got)

    @handler("VS", equals=True)
    def vs(self, args: str) -> str:
        return self._parameter(args, "vs")

    @handler("VA", equals=True)
    def va(self, args: str) -> str:
        return self._parameter(args, "va")

    @handler("VD", equals=True)
    def vd(self, args: str) -> str:
        return self._parameter(args, "vd")

    @handler("VT", equals=True)
    def vt(self, args: str) -> str:
        if not self.machine.spec.vt:
            raise Refused(1, "no VT on this model")
        return self._parameter(args, "vt")

    # ---- running -----------------------------------------------------------------------
    @handler("BG", Args.PLANES_AND_AXES)
    def begin(self, letters: list[str]) -> str:
        """``BG S``, ``BG ST``, and planes with axes (``BG SA``; the BG entry: "Any
        combination of Axes, Vector Planes, and Virtual Axes may be mixed to begin
        motion"): every plane and axis is checked before any starts, then all start on this
        sample. An axis named beside a plane it belongs to is refused as ``BG S;BG A``
        would refuse it (TC 21, "Begin not valid while running")."""
        chosen = [self.planes[c] for c in letters if c in self.planes]
        named = "".join(c for c in letters if c not in self.planes)
        axes = self.machine.interp.axis_list(named) if named else []
        for plane in chosen:
            self._check_begin(plane)
        if any(ax.letter in plane.axes for ax in axes for plane in chosen):
            raise Refused(21, "an axis named beside its plane")
        motion = self.machine.room(Motion)
        plans = motion.plan_begin(axes)
        for plane in chosen:
            self._begin(plane)
        motion.begin(plans)
        return ""

    def _check_begin(self, plane: Plane) -> None:
        eng = self.engine(plane)
        if plane.running or self.busy(plane):
            raise Refused(21, "sequence running")
        if plane.kind is None or eng is None or eng.segments == 0 or eng.moving:
            raise Refused(24, "no sequence")
        if eng.stop_code is not None:
            raise Refused(24, "no sequence: it has run")  # a finished one needs new segments
        for c in plane.axes:
            ax = self.machine.servo.axes[c]
            if ax.contour:
                raise Refused(18, "axis is contouring")
            if not ax.m.motor_on:
                raise Refused(20, "motor off")
            if ax.m.moving:
                raise Refused(21, "axis moving")
        # An axis whose first motion heads into its active switch (LD leaves it on) or on
        # past a soft limit it is beyond: TC 22, as an independent BG (decision 0050).
        limits = self.machine.room(Limits)
        for c, direction in zip(plane.axes, eng.first_directions(), strict=True):
            if direction:
                limits.check_start(self.machine.servo.axes[c], direction)

    def _begin(self, plane: Plane) -> None:
        eng = self.engine(plane)
        assert eng is not None
        spec = self.machine.spec
        motion = self.machine.room(Motion)
        smoothing = plane.vt if spec.vt else motion.axes[plane.axes[0]].it
        try:
            eng.begin(plane.vs, plane.va, plane.vd, smoothing, position=self._refs(plane))
        except CommandError as e:
            raise Refused(e.code or 6, e.text) from None
        feed = PlaneFeed(eng, plane.letter)
        for i, c in enumerate(plane.axes):
            ax: Axis = self.machine.servo.axes[c]
            ax.limit_stop = False
            ax.m.profiler = drive(ax.m.profiler, feed, i)
        plane.eng = eng
        plane.running = True
        plane.starts += 1

    @handler("ST", Args.PLANES_AND_AXES)
    def stop(self, letters: list[str]) -> str:
        """``ST S``, ``ST ST``, and planes with axes (``ST SCD``: the ST entry's example "Stop
        coordinate plane S, as well as axes C and D"; its mask runs A .. ABCDEFGHMNST): the
        planes, then the axes, as ``ST S;ST CD`` on one line, on this sample (decision
        0048)."""
        named = "".join(c for c in letters if c not in self.planes)
        axes = self.machine.interp.axis_list(named) if named else []
        for p in (c for c in letters if c in self.planes):
            plane = self.planes[p]
            found = self.feed(plane) if plane.running else None
            if found is not None:
                found.stop(4)
                for c in plane.axes:
                    prof = self.machine.servo.axes[c].m.profiler
                    if isinstance(prof, DrivenProfiler) and prof.driven:
                        prof.sync()
        if axes:
            self.machine.room(Motion).st(axes)
        return ""

    # ---- the data record ---------------------------------------------------------------
    def record_block(self, p: str) -> tuple[int, int, int, int]:
        """Plane ``p``'s block of the data record: segment count (``_CSp``), move status,
        distance travelled (``_AVp``), buffer space (``_LMp``) (gclib ``GDataRecord4000``
        ``s_plane_*``, galil-wave2-facts.md lines 55 and 131). The status word: b15 move in
        progress (``_BGp``), b5 slewing, b4 stopping (ST or a limit), b3 final deceleration
        (galil-protocol.md section 4, "Coordinated plane status"; DMC-4123 user manual p.55).
        The count is a 16-bit field: [U] a longer sequence's count is kept modulo 65536."""
        plane = self.planes[p]
        eng = self.engine(plane)
        if eng is None:
            return 0, 0, 0, self.machine.spec.vector_buffer
        status = 0
        if self.busy(plane):
            status = 0x8000
            status |= 0x0020 if eng.slewing else 0
            status |= 0x0010 if eng.stopping else 0
            status |= 0x0008 if eng.final_decel else 0
        return eng.segments_completed & 0xFFFF, status, eng.distance, max(0, eng.free_slots)

    # ---- operands ----------------------------------------------------------------------
    @operand("BG", kind=OperandKind.PLANE)
    def moving(self, p: str) -> float:
        return 1.0 if self.busy(self.planes[p]) else 0.0

    @operand("CS", kind=OperandKind.PLANE)
    def completed(self, p: str) -> float:
        eng = self.engine(self.planes[p])
        return 0.0 if eng is None else float(eng.segments_completed)

    @operand("LM", kind=OperandKind.PLANE)
    def free_slots(self, p: str) -> float:
        eng = self.engine(self.planes[p])
        return float(self.machine.spec.vector_buffer if eng is None else eng.free_slots)

    @operand("AV", kind=OperandKind.PLANE)
    def distance(self, p: str) -> float:
        eng = self.engine(self.planes[p])
        return 0.0 if eng is None else float(eng.distance)

    @operand("VS", kind=OperandKind.PLANE)
    def speed(self, p: str) -> float:
        return self.planes[p].vs

    @operand("VA", kind=OperandKind.PLANE)
    def accel(self, p: str) -> float:
        return self.planes[p].va

    @operand("VD", kind=OperandKind.PLANE)
    def decel(self, p: str) -> float:
        return self.planes[p].vd

    @operand("VT", kind=OperandKind.PLANE)
    def smoothing(self, p: str) -> float:
        return self.planes[p].vt

    @operand("LM")
    def selected_free_slots(self) -> float:
        return self.free_slots(self.selected)

    @operand("CS")
    def selected_completed(self) -> float:
        return self.completed(self.selected)

    @operand("AV")
    def selected_distance(self) -> float:
        return self.distance(self.selected)
