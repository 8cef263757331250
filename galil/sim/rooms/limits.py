"""Limits: soft limits (``FL``/``BL``), limit switches and the switch status (``TS``).

Soft limits act on the reference position (``RP``) and stop at DC, like a limit switch, and
only motion *outwards* is stopped, so an axis beyond a limit can always be moved back (decision
0003). A step of the servo loop ends where the previewed path first crosses a limit outwards.
``_LFx``/``_LRx`` are 1 while the switch is inactive, as the TS bits are. Switches are set by a
test hook (:meth:`Limits.set_switch`); the home input reads high.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.models import INT32_MAX, INT32_MIN
from galil.sim.interpreter import int32
from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.servo import Axis

__all__ = ["Limits"]


@dataclass
class _AxisLimits:
    fl: int = INT32_MAX
    bl: int = INT32_MIN
    forward: bool = False  # forward limit switch active
    reverse: bool = False


class Limits(Room):
    """Soft limits, limit switches and what stops an axis at them."""

    def reset(self) -> None:
        self.axes = {letter: _AxisLimits() for letter in self.machine.spec.axes}
        self._switched = False  # any switch active: the service hook has work
        self._soft = False  # any soft limit set: the horizon hook has work

    # ---- used by other rooms -----------------------------------------------------------
    def check_start(self, ax: Axis, direction: float) -> None:
        """Refuse a start towards an active switch or beyond a soft limit.

        Raises:
            Refused: TC 22.
        """
        s = self.axes[ax.letter]
        ref = ax.m.reference
        if direction > 0 and (s.forward or ref > s.fl):
            raise Refused(22, "forward limit")
        if direction < 0 and (s.reverse or ref < s.bl):
            raise Refused(22, "reverse limit")

    def switch_bits(self, ax: Axis) -> int:
        """Home input high, and the limit bits (set while the switch is inactive)."""
        s = self.axes[ax.letter]
        return 0x02 | (0 if s.forward else 0x08) | (0 if s.reverse else 0x04)

    def set_switch(self, letter: str, which: str, active: bool) -> None:
        """Set a limit switch; an active one stops motion towards it (SC 2/3).

        Raises:
            InvalidArgument: ``which`` is not ``"forward"`` or ``"reverse"``.
        """
        if which not in ("forward", "reverse"):
            raise InvalidArgument(f"which must be 'forward' or 'reverse', not {which!r}")
        s = self.axes[letter]
        if which == "forward":
            s.forward = bool(active)
        else:
            s.reverse = bool(active)
        self._switched = any(a.forward or a.reverse for a in self.axes.values())
        self._check_switch(self.machine.servo.axes[letter])

    # ---- servo-loop hooks --------------------------------------------------------------
    def horizon(self, k: int) -> int:
        if not self._soft:
            return k
        for ax in self.machine.servo.axes.values():
            s = self.axes[ax.letter]
            if (
                (s.fl < INT32_MAX or s.bl > INT32_MIN)
                and ax.m.moving
                and not ax.limit_stop
                and not ax.contour
            ):
                prof = ax.m.profiler
                k = min(k, self._crossing(s, prof.reference, prof.preview(k)))
        return k

    @staticmethod
    def _crossing(s: _AxisLimits, now: int, refs: npt.NDArray[np.int64]) -> int:
        """Samples until the path is beyond a soft limit moving outwards (large if never).

        ``now`` is the reference before the first sample of ``refs``.
        """
        r = np.asarray(refs)
        prev = np.concatenate(([now], r[:-1]))
        beyond = ((r > s.fl) & (r > prev)) | ((r < s.bl) & (r < prev))
        hits = np.flatnonzero(beyond)
        return int(hits[0]) + 1 if hits.size else r.size + 1

    def after_step(self) -> None:
        for ax in self.machine.servo.axes.values():
            prof = ax.m.profiler
            if not prof.moving or ax.limit_stop or ax.contour:
                continue
            s = self.axes[ax.letter]
            v = prof.velocity
            if v > 0 and prof.reference > s.fl:
                ax.limit_stop = True
                prof.limit_stop(2)
            elif v < 0 and prof.reference < s.bl:
                ax.limit_stop = True
                prof.limit_stop(3)

    def service(self) -> None:
        if self._switched:
            for ax in self.machine.servo.axes.values():
                self._check_switch(ax)

    def _check_switch(self, ax: Axis) -> None:
        s = self.axes[ax.letter]
        if not (s.forward or s.reverse):
            return
        m = ax.m
        if not m.moving or ax.limit_stop or ax.contour:
            return
        v = m.profiler.velocity
        if s.forward and v > 0:
            ax.limit_stop = True
            m.profiler.limit_stop(2)
        elif s.reverse and v < 0:
            ax.limit_stop = True
            m.profiler.limit_stop(3)

    # ---- commands and operands ---------------------------------------------------------
    @handler("FL", Args.VALUES)
    def fl(self, fields: list[tuple[Axis, str]]) -> str:
        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].fl = int(v)
            self._soft_limits_changed()

        i = self.machine.interp
        return i.parameters(fields, self.forward_limit, lambda ax, v: int32(v), apply, i.pnum)

    @handler("BL", Args.VALUES)
    def bl(self, fields: list[tuple[Axis, str]]) -> str:
        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].bl = int(v)
            self._soft_limits_changed()

        i = self.machine.interp
        return i.parameters(fields, self.reverse_limit, lambda ax, v: int32(v), apply, i.pnum)

    def _soft_limits_changed(self) -> None:
        self._soft = any(a.fl < INT32_MAX or a.bl > INT32_MIN for a in self.axes.values())

    @handler("TS", Args.AXES)
    def ts(self, axes: list[Axis]) -> str:
        i = self.machine.interp
        return i.report(axes, self.status_byte, lambda v: i.num(v, "3.0"))

    @operand("FL", kind=OperandKind.AXIS)
    def forward_limit(self, ax: Axis) -> float:
        return self.axes[ax.letter].fl

    @operand("BL", kind=OperandKind.AXIS)
    def reverse_limit(self, ax: Axis) -> float:
        return self.axes[ax.letter].bl

    @operand("LF", kind=OperandKind.AXIS)
    def forward_switch(self, ax: Axis) -> float:
        return 0 if self.axes[ax.letter].forward else 1

    @operand("LR", kind=OperandKind.AXIS)
    def reverse_switch(self, ax: Axis) -> float:
        return 0 if self.axes[ax.letter].reverse else 1

    @operand("TS", kind=OperandKind.AXIS)
    def status_byte(self, ax: Axis) -> float:
        """``TS``: moving, motor off, the limit bits, home input high, latch not armed."""
        m = ax.m
        value = 0x01 | self.switch_bits(ax)
        if m.moving:
            value |= 0x80
        if not m.motor_on:
            value |= 0x20
        return value
