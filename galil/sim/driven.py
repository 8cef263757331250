"""Axes whose reference comes from elsewhere: a vector plane's sequence, or a gear master.

An axis of the servo loop steps its :class:`~galil.predict.engine.AxisProfiler`. While a room
couples the axis to something else (the coordinated-motion room to a vector sequence, the
gearing room to a master), the axis's profiler is a :class:`DrivenProfiler`: an
``AxisProfiler`` that takes its reference positions from a :class:`Source` for as long as it is
driven, and behaves as a plain profiler again afterwards. The motion math stays in the
predictor (the vector sequence is :class:`~galil.predict.vector.VectorProfiler`, gearing is
:class:`~galil.predict.gearing.GearFollower`); nothing here computes a position.

Several axes may share one source (the two axes of a plane). The servo loop copies its axes
with one memo (:meth:`~galil.sim.servo.Servo._snapshot`), so a shared source stays shared in
a snapshot, and a room reaches a running source through its axes, never through a reference
of its own (a restored snapshot replaces it).
"""

from __future__ import annotations

import copy
from typing import Protocol

import numpy as np
import numpy.typing as npt

from galil.codes import tc_text
from galil.errors import CommandError
from galil.predict.engine import AxisProfiler

__all__ = ["DrivenProfiler", "Source", "drive"]

Int64Array = npt.NDArray[np.int64]


class Source(Protocol):
    """What drives one or more axes, each known to it by an index."""

    mode: str  # the profiler mode of a driven axis ("vector", "gear")

    def take(self, index: int, n: int) -> Int64Array:
        """Commit the next ``n`` reference positions of axis ``index``."""
        ...

    def peek(self, index: int, n: int) -> Int64Array:
        """The next ``n`` reference positions of axis ``index``, without committing them."""
        ...

    def remaining(self, index: int) -> int | None:
        """Samples until axis ``index`` is released (0: now), ``None`` while unknown."""
        ...

    def moving(self, index: int) -> bool:
        """Whether axis ``index`` counts as in motion (``_BG``) while driven."""
        ...

    def stop_code(self, index: int) -> int:
        """The stop code of axis ``index`` (while driven, and once released)."""
        ...

    def stop(self, code: int) -> None:
        """``ST`` (code 4) or a limit (2, 3) on an axis it drives."""
        ...

    def abort(self) -> None:
        """``AB``: stop at once."""
        ...


def _refuse(code: int, command: str) -> CommandError:
    return CommandError(code, tc_text(code), command)


class DrivenProfiler(AxisProfiler):
    """An axis profiler that a :class:`Source` may drive (see the module notes).

    Attributes:
        source: what drives the axis (``None`` when it runs its own profiles); it stays set
            after the axis is released, so a room can still read the sequence's last state.
        index: the axis's index in the source.
        driven: whether the source drives the axis now.
    """

    def __init__(self, *, sample_period: float = 1 / 1024, position: int = 0) -> None:
        super().__init__(sample_period=sample_period, position=position)
        self.source: Source | None = None
        self.index = 0
        self.driven = False

    def __deepcopy__(self, memo: dict[int, object]) -> DrivenProfiler:
        new = super().__deepcopy__(memo)
        assert isinstance(new, DrivenProfiler)
        new.source = copy.deepcopy(self.source, memo)
        return new

    def attach(self, source: Source, index: int) -> None:
        """Let ``source`` drive this axis from the next sample on (the axis must be idle)."""
        self.source = source
        self.index = index
        self.driven = True
        self.mode = source.mode
        self.moving = source.moving(index)
        self.stop_code = source.stop_code(index)
        self.velocity = 0.0

    def detach(self, code: int) -> None:
        """Stop being driven now, where the axis is, with stop code ``code``."""
        if self.driven:
            self.driven = False
            self.mode = "idle"
            self.moving = False
            self.velocity = 0.0
            self.stop_code = int(code)
            self.target = self.position

    def _release(self) -> None:
        assert self.source is not None
        self.driven = False
        self.mode = "idle"
        self.moving = False
        self.velocity = 0.0
        self.stop_code = self.source.stop_code(self.index)
        self.target = self.position

    # ---- stepping ----------------------------------------------------------------------
    def advance_both(self, n: int) -> tuple[Int64Array, Int64Array]:
        if not self.driven:
            return super().advance_both(n)
        source = self.source
        assert source is not None
        n = self._count(n)
        if n == 0:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        before = self.position
        r = source.take(self.index, n)
        self.sample += n
        last = int(r[-1])
        prev = int(r[-2]) if n > 1 else before
        self.velocity = (last - prev) / self.sample_period
        self.position = self.reference = last
        self._y = float(last)
        self.sync()
        return r, r

    def sync(self) -> None:
        """Take the source's state (in motion, stop code); released once it is done."""
        source = self.source
        assert source is not None
        self.moving = source.moving(self.index)
        self.stop_code = source.stop_code(self.index)
        if source.remaining(self.index) == 0:
            self._release()

    def advance_values(self, n: int) -> list[int]:
        if not self.driven:
            return super().advance_values(n)
        values: list[int] = self.advance_both(n)[1].tolist()
        return values

    def preview(self, n: int) -> Int64Array:
        if not self.driven:
            return super().preview(n)
        assert self.source is not None
        return self.source.peek(self.index, self._count(n))

    def preview_profile(self, n: int) -> Int64Array:
        return self.preview(n) if self.driven else super().preview_profile(n)

    def preview_velocity(self, n: int) -> npt.NDArray[np.float64]:
        if not self.driven:
            return super().preview_velocity(n)
        r = self.preview(n).astype(np.float64)
        out: npt.NDArray[np.float64] = np.diff(r, prepend=float(self.position))
        return out / self.sample_period

    @property
    def end_sample(self) -> int | None:
        if not self.driven:
            return super().end_sample
        assert self.source is not None
        left = self.source.remaining(self.index)
        return None if left is None else self.sample + left

    # ---- commands --------------------------------------------------------------------
    def stop(self) -> None:
        if self.driven:
            assert self.source is not None
            self.source.stop(4)
            self.sync()
            return
        super().stop()

    def limit_stop(self, code: int) -> None:
        if self.driven:
            assert self.source is not None
            self.source.stop(int(code))
            self.sync()
            return
        super().limit_stop(code)

    def abort(self) -> None:
        if self.driven:
            assert self.source is not None
            self.source.abort()
            self.driven = False
        super().abort()

    def _busy(self, command: str) -> None:
        if self.driven:
            assert self.source is not None
            # TC 29 in a sequence; a geared axis's own moves (the controller superimposes
            # them) are not simulated: TC 141, "feature not supported".
            raise _refuse(29 if self.source.mode == "vector" else 141, command)

    def begin_move(
        self,
        target: int,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float | None = 1.0,
    ) -> None:
        self._busy("BG")
        super().begin_move(target, speed, accel, decel, smoothing)

    def begin_jog(
        self, speed: float, accel: float, decel: float, smoothing: float | None = 1.0
    ) -> None:
        self._busy("BG")
        super().begin_jog(speed, accel, decel, smoothing)

    def increment(
        self,
        n: int,
        speed: float,
        accel: float,
        decel: float,
        smoothing: float | None = None,
    ) -> None:
        self._busy("IP")
        super().increment(n, speed, accel, decel, smoothing)

    def begin_contour(self) -> None:
        self._busy("CM")
        super().begin_contour()

    def set_speed(self, speed: float) -> None:
        if not self.driven:
            super().set_speed(speed)

    def set_accel(self, accel: float) -> None:
        if not self.driven:
            super().set_accel(accel)


def drive(old: AxisProfiler, source: Source, index: int) -> DrivenProfiler:
    """A :class:`DrivenProfiler` in the state of the idle profiler ``old``, driven by
    ``source``; the caller puts it in the axis (``ax.m.profiler = drive(...)``)."""
    if isinstance(old, DrivenProfiler):
        new = old
    else:
        new = DrivenProfiler(sample_period=old.sample_period, position=old.position)
        new.sample = old.sample
        new.smoothing = old.smoothing
    new.attach(source, index)
    return new
