"""Electronic gearing: ``GA`` (the master of each follower) and ``GR`` (the ratio).

``GR`` with a non-zero ratio engages a follower on the master ``GA`` named for it, ``GR 0``
disengages it; a new ratio while geared carries on from where the follower is. The follower's
reference is the predictor's :class:`~galil.predict.gearing.GearFollower` fed with the master's
positions, sample by sample (this room holds no motion math). A master is an axis's encoder
(``A``), its commanded position (``CA``), its auxiliary encoder (``DA``, equal to the encoder
here) or the path of a coordinate system (``S``, ``T``: the distance travelled along its
sequences, which only grows).

Assumptions where the manuals are silent: a geared follower reports ``_BG`` 1, so ``BG`` on it
is refused (TC 21) rather than superimposed on the gearing (the controller superimposes; the
simulator does not); ``ST``, a limit or ``AB`` on a follower disengages it where it is (stop
code 4, 2/3 or 7), as the manuals say of ``ST`` and limits outside gantry mode (``GM`` is not
simulated); ``GR 0`` leaves stop code 1; an axis cannot be a follower and a master at once
(TC 46).
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.predict.gearing import GearFollower, quantise_ratio
from galil.sim.driven import DrivenProfiler, drive
from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.vector import Vector
from galil.sim.servo import Axis

__all__ = ["GearFeed", "Gearing"]

Int64Array = npt.NDArray[np.int64]
Fields = list[tuple[Axis, str]]
_MASTER = re.compile(r"([CD]?)([A-Z])")


@dataclass
class PathMaster:
    """The distance along a plane's sequences, as a master (``GA S``): it only grows."""

    plane: str
    total: int = 0  # distance counted so far
    last: int = 0  # the plane's _AV when last read


class GearFeed:
    """Drives one follower: its :class:`GearFollower`, and ``read(n, feed)``, the master's
    next ``n`` positions (read before the master steps: followers step first)."""

    mode = "gear"

    def __init__(
        self,
        follower: GearFollower,
        read: Callable[[int, GearFeed], Int64Array],
        path: PathMaster | None = None,
    ) -> None:
        self.follower = follower
        self.read = read  # a plain function: a snapshot shares it (see driven.py)
        self.path = path
        self.off = False
        self.code = 0

    def take(self, index: int, n: int) -> Int64Array:
        if self.off:
            return np.full(n, self.follower.position, dtype=np.int64)
        return self.follower.follow(self.read(n, self))

    def peek(self, index: int, n: int) -> Int64Array:
        if self.off:
            return np.full(n, self.follower.position, dtype=np.int64)
        ahead = copy.deepcopy(self)
        return ahead.follower.follow(ahead.read(n, ahead))

    def remaining(self, index: int) -> int | None:
        return 0 if self.off else None

    def moving(self, index: int) -> bool:
        return not self.off

    def stop_code(self, index: int) -> int:
        return self.code

    def stop(self, code: int) -> None:
        self.off, self.code = True, code

    def abort(self) -> None:
        self.off, self.code = True, 7


class Gearing(Room):
    """GA and GR: which axis follows which, at what ratio."""

    requires = (Vector,)

    def reset(self) -> None:
        self.masters: dict[str, str] = {}  # follower letter -> master (GA): "A", "CA", "S"
        self.ratios: dict[str, float] = {}  # follower letter -> ratio, while geared

    def burn(self, name: str) -> object | None:
        # The BN table lists GA and GR: the masters, and the ratios of the axes geared now.
        self.after_step()
        return (dict(self.masters), dict(self.ratios)) if name == "BN" else None

    def restore(self, name: str, saved: object) -> None:
        """A burned ratio gears its axis again at power-on (the axes are at rest, at 0)."""
        assert isinstance(saved, tuple)
        self.masters, ratios = saved
        for c, ratio in ratios.items():
            self._apply(self.machine.servo.axes[c], ratio)
        self.machine.servo.step_first(list(self.ratios))

    # ---- where the master's positions come from ----------------------------------------
    def _reader(self, spec: str) -> Callable[[int, GearFeed], Int64Array]:
        servo = self.machine.servo
        if spec in ("S", "T"):
            vector = self.machine.room(Vector)
            return lambda n, feed: _path_positions(vector, feed, n)
        kind, letter = spec[:-1], spec[-1]
        if kind == "C":
            return lambda n, feed: servo.axes[letter].m.profiler.preview(n)
        return lambda n, feed: servo.axes[letter].m.preview_encoder(n)

    def _master_now(self, spec: str) -> int:
        if spec in ("S", "T"):
            return _distance(self.machine.room(Vector), spec)
        m = self.machine.servo.axes[spec[-1]].m
        return m.reference if spec[:-1] == "C" else m.encoder

    # ---- engaging ------------------------------------------------------------------------
    def geared(self, ax: Axis) -> GearFeed | None:
        """The feed gearing ``ax`` now, if any (read from the axis)."""
        prof = ax.m.profiler
        if isinstance(prof, DrivenProfiler) and prof.driven and isinstance(prof.source, GearFeed):
            return prof.source
        return None

    def _engage(self, ax: Axis, ratio: float) -> None:
        spec = self.masters[ax.letter]
        res = self.machine.spec.gr_resolution
        now = self._master_now(spec)
        follower = GearFollower(ratio, master=now, position=ax.m.reference, resolution=res)
        path = PathMaster(spec, now, now) if spec in ("S", "T") else None
        ax.limit_stop = False
        feed = GearFeed(follower, self._reader(spec), path)
        ax.m.profiler = drive(ax.m.profiler, feed, 0)

    def after_step(self) -> None:
        # A follower that ST, a limit or AB disengaged (or DP or SH reseated) follows no more.
        if not self.ratios:
            return  # none geared (at every step: nothing to look at)
        gone = [c for c in self.ratios if self.geared(self.machine.servo.axes[c]) is None]
        for c in gone:
            del self.ratios[c]
        if gone:
            self.machine.servo.step_first(list(self.ratios))

    def abort(self) -> None:
        self.after_step()

    # ---- commands --------------------------------------------------------------------
    @handler("GA", Args.VALUES)
    def ga(self, fields: Fields) -> str:
        sets: list[tuple[Axis, str]] = []
        for ax, text in fields:
            t = text.strip().upper()
            if t == "?":
                raise Refused(51, "GA cannot be interrogated")
            if t in ("S", "T"):
                sets.append((ax, t))
                continue
            m = _MASTER.fullmatch(t)
            if m is None:
                raise Refused(4, f"not a master: {text!r}")
            letter = self.machine.interp.axis(m.group(2)).letter
            if letter == ax.letter:
                raise Refused(46, "an axis cannot follow itself")
            sets.append((ax, m.group(1) + letter))
        for ax, spec in sets:
            self.masters[ax.letter] = spec
        return ""

    @handler("GR", Args.VALUES)
    def gr(self, fields: Fields) -> str:
        i = self.machine.interp
        self.after_step()  # (a follower ST or AB released since the last sample is no more)
        queries = [ax for ax, t in fields if t.strip() == "?"]
        changes: list[tuple[Axis, float]] = []
        for ax, text in fields:
            if text.strip() == "?":
                continue
            try:
                ratio = quantise_ratio(i.evaluate(text), self.machine.spec)
            except InvalidArgument:
                raise Refused(6, "GR out of range") from None
            self._check(ax, ratio)
            changes.append((ax, ratio))
        for ax, ratio in changes:
            self._apply(ax, ratio)
        self.machine.servo.step_first(list(self.ratios))
        if not queries:
            return ""
        return ",".join(i.num(self.ratios.get(ax.letter, 0.0), "3.4") for ax in queries) + "\r\n"

    @operand("GR", kind=OperandKind.AXIS)
    def ratio(self, ax: Axis) -> float:
        """``_GRm``: "Operand holds the value last set by the command" (DMC-4103 reference);
        0 once ``ST``, a limit or ``AB`` turned the gearing off, as ``GR ?`` (assumption)."""
        self.after_step()
        return self.ratios.get(ax.letter, 0.0)

    def _check(self, ax: Axis, ratio: float) -> None:
        if ratio == 0 or self.geared(ax) is not None:
            return
        spec = self.masters.get(ax.letter)
        if spec is None:
            raise Refused(6, "no master (GA) for this axis")
        if ax.m.moving or ax.contour:
            raise Refused(7, "the follower is moving")
        leads = any(self.masters[c][-1] == ax.letter for c in self.ratios)
        if spec[-1] in self.ratios or leads:
            raise Refused(46, "gear axis both master and follower")

    def _apply(self, ax: Axis, ratio: float) -> None:
        feed = self.geared(ax)
        if ratio == 0:
            prof = ax.m.profiler
            if feed is not None and isinstance(prof, DrivenProfiler):
                prof.detach(1)
            self.ratios.pop(ax.letter, None)
        elif feed is not None:
            feed.follower.set_ratio(ratio)
            self.ratios[ax.letter] = ratio
        else:
            self._engage(ax, ratio)
            self.ratios[ax.letter] = ratio


def _distance(vector: Vector, plane: str) -> int:
    eng = vector.engine(vector.planes[plane])
    return 0 if eng is None else eng.distance


def _path_positions(vector: Vector, feed: GearFeed, n: int) -> Int64Array:
    path = feed.path
    assert path is not None
    plane = vector.planes[path.plane]
    plane_feed = vector.feed(plane) if plane.running else None
    if plane_feed is None or not vector.busy(plane):
        return np.full(n, path.total, dtype=np.int64)
    s = plane_feed.distance(n)
    # A new sequence starts again from 0: count what it travels on top of the total.
    prev = np.concatenate(([path.last], s[:-1]))
    step = np.where(s >= prev, s - prev, s)
    out: Int64Array = path.total + np.cumsum(step)
    path.total, path.last = int(out[-1]), int(s[-1])
    return out
