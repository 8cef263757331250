"""Motion: independent moves and jogs (PR PA DP DE SP AC DC JG IT BG IP ST AB SH MO).

The values stored are the ones the predictor plans with (its quantisation), and every change in
motion is a call on the axis's :class:`~galil.predict.engine.AxisProfiler`: this room holds no
motion math. ``BG`` begins the mode chosen last: a position move after ``PR``/``PA``, a jog
after ``JG``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

from galil.errors import InvalidArgument, LimitError
from galil.predict.checks import quantise_accel, quantise_speed
from galil.predict.smoothing import quantise_it
from galil.sim.driven import DrivenProfiler
from galil.sim.interpreter import int32
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.reports import Reports
from galil.sim.rooms.tuning import Tuning
from galil.sim.servo import Axis, at_rest, engine

__all__ = ["Motion"]

Fields = list[tuple[Axis, str]]
#: What ``BG`` starts on an axis: a mode's name, ``None`` for a jog, a position move's target.
Begin = tuple[Axis, int | str | None]
Check = Callable[[Axis, float], float]


@dataclass
class Params:
    """The motion parameters of one axis."""

    sp: float = 25000.0
    ac: float = 256000.0
    dc: float = 256000.0
    jg: float = 25000.0
    it: float = 1.0
    pr: int = 0
    pa: int = 0
    absolute: bool = False
    next_mode: str = "position"
    began: str = "position"  # the mode the last BG (or an IP at rest) began
    move_start: int = 0  # profiler position at the last BG: AD/AR measure from here
    starts: int = 0  # moves begun with BG (AR measures from the last AD/AR of the same one)


#: A mode another room starts with BG: ``check(ax)`` refuses (before any axis starts),
#: ``start(ax)`` begins it.
Mode = tuple[Callable[[Axis], None], Callable[[Axis], None]]


class Motion(Room):
    """Per-axis motion parameters, and the commands that start, change and stop motion.

    ``modes`` maps a ``next_mode`` name to the room that starts it at ``BG`` (HM, FE and FI
    register theirs), so this room stays the one place ``BG`` is answered.
    """

    requires = (Limits,)

    def __init__(self, machine: Machine) -> None:
        super().__init__(machine)
        self.modes: dict[str, Mode] = {}

    def reset(self) -> None:
        spec = self.machine.spec
        self.axes = {
            letter: Params(
                sp=spec.default_speed,
                jg=spec.default_speed,
                ac=spec.default_accel,
                dc=spec.default_accel,
            )
            for letter in spec.axes
        }

    def burn(self, name: str) -> object | None:
        # The BN table: AC DC SP IT, and MO (which axes are off). JG, PR, PA are not in it.
        if name != "BN":
            return None
        servo = self.machine.servo
        return {c: (p.sp, p.ac, p.dc, p.it, servo.axes[c].m.motor_on) for c, p in self.axes.items()}

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, dict)
        for c, (sp, ac, dc, it, on) in saved.items():
            p = self.axes[c]
            p.sp, p.ac, p.dc, p.it = sp, ac, dc, it
            self.machine.servo.axes[c].m.motor_on = on

    def params(self, ax: Axis) -> Params:
        """The motion parameters of ``ax``."""
        return self.axes[ax.letter]

    # ---- checks: the predictor's quantisation, so the values stored are the ones it plans
    def _accel(self, ax: Axis, value: float) -> float:
        try:
            return float(quantise_accel(value, self.machine.spec, tm=self.machine.servo.tm))
        except LimitError:
            raise Refused(6, "AC/DC out of range") from None

    def _speed(self, value: float) -> float:
        try:
            spec, tm = self.machine.spec, self.machine.servo.tm
            return float(quantise_speed(value, spec, signed=True, tm=tm))
        except LimitError:
            raise Refused(6, "speed out of range") from None

    def _set(
        self,
        fields: Fields,
        get: Callable[[Axis], float],
        check: Check,
        apply: Callable[[Axis, float], None],
        fmt: str = "",
    ) -> str:
        i = self.machine.interp
        out = functools.partial(i.num, fmt=fmt) if fmt else i.pnum
        return i.parameters(fields, get, check, apply, out)

    # ---- positions ---------------------------------------------------------------------
    @handler("PR", Args.VALUES)
    def pr(self, fields: Fields) -> str:
        def apply(ax: Axis, v: float) -> None:
            p = self.axes[ax.letter]
            p.pr, p.absolute, p.next_mode = int(v), False, "position"

        return self._set(fields, self.relative, at_rest("PR", _position), apply)

    @handler("PA", Args.VALUES)
    def pa(self, fields: Fields) -> str:
        def apply(ax: Axis, v: float) -> None:
            p = self.axes[ax.letter]
            p.pa, p.absolute, p.next_mode = int(v), True, "position"

        return self._set(fields, self.absolute, at_rest("PA", _position), apply)

    @handler("DP", Args.VALUES)
    def dp(self, fields: Fields) -> str:
        """DP sets ``TP`` and ``RP``; a stepper's ``RP`` and ``TD`` (its step count), "but
        will not effect the TP register value" (the DMC-4103 reference). Not in motion."""
        reports = self.machine.room(Reports)

        def apply(ax: Axis, v: float) -> None:
            before = ax.m.encoder
            self.machine.servo.reseat(ax, int(v))
            self.axes[ax.letter].pa = int(v)
            if self.machine.room(Tuning).stepper(ax):
                ax.shift += before - int(v)  # (its encoder reads on as it did)

        return self._set(fields, reports.position, at_rest("DP", _position), apply)

    @handler("DE", Args.VALUES)
    def de(self, fields: Fields) -> str:
        """DE defines a servo's auxiliary encoder (``TD``), a stepper's main encoder (``TP``);
        "Valid while in motion". ``DE ?`` answers ``TD``."""
        reports = self.machine.room(Reports)

        def apply(ax: Axis, v: float) -> None:
            if self.machine.room(Tuning).stepper(ax):
                ax.shift = int(v) - ax.m.encoder
            else:
                ax.aux = int(v) - ax.m.encoder

        return self._set(fields, reports.auxiliary, _position, apply)

    # ---- speeds, accelerations, smoothing ----------------------------------------------
    @handler("SP", Args.VALUES)
    def sp(self, fields: Fields) -> str:
        def check(ax: Axis, v: float) -> float:
            if v < 0:
                raise Refused(6, "negative speed")
            return self._speed(v)

        def apply(ax: Axis, v: float) -> None:
            p = self.axes[ax.letter]
            p.sp = v
            prof = ax.m.profiler
            # (a PA/PR move's, not a homing's return to its index: that runs at HV)
            if prof.moving and prof.mode == "position" and p.began == "position" and v > 0:
                engine(lambda: prof.set_speed(v))

        return self._set(fields, self.speed, check, apply, "10.0")

    @handler("AC", Args.VALUES)
    def ac(self, fields: Fields) -> str:
        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].ac = v
            prof = ax.m.profiler
            if prof.moving and prof.mode in ("position", "jog"):
                engine(lambda: prof.set_accel(v))

        return self._set(fields, self.accel, self._accel, apply, "10.0")

    @handler("DC", Args.VALUES)
    def dc(self, fields: Fields) -> str:
        # "DC may be changed during a move in Jog mode, but not in a PA or PR move", nor
        # after an ST or a limit while the axis "is still decelerating": the engine re-plans.
        def check(ax: Axis, v: float) -> float:
            p, prof = self.axes[ax.letter], ax.m.profiler
            if ax.m.moving and (p.began not in ("jog", "position") or not prof.takes_decel):
                raise Refused(7, "DC while moving")
            return self._accel(ax, v)

        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].dc = v
            prof = ax.m.profiler
            if prof.moving:
                engine(lambda: prof.set_decel(v))

        return self._set(fields, self.decel, check, apply, "10.0")

    @handler("JG", Args.VALUES, every=True)
    def jg(self, fields: Fields) -> str:
        def check(ax: Axis, v: float) -> float:
            prof = ax.m.profiler
            if prof.moving and prof.mode != "jog":
                raise Refused(13, "JG while not jogging")
            return self._speed(v)

        def apply(ax: Axis, v: float) -> None:
            p = self.axes[ax.letter]
            p.jg, p.next_mode = v, "jog"
            prof = ax.m.profiler
            if prof.moving and prof.mode == "jog":
                engine(lambda: prof.set_speed(v))

        return self._set(fields, self.jog_speed, check, apply, "10.0")

    @handler("IT", Args.VALUES)
    def it(self, fields: Fields) -> str:
        def check(ax: Axis, v: float) -> float:
            try:
                return quantise_it(v)
            except InvalidArgument:
                raise Refused(6, "IT out of range") from None

        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].it = v

        return self._set(fields, self.smoothing, check, apply, "1.4")

    # ---- starting and stopping ---------------------------------------------------------
    def _start_check(self, ax: Axis, direction: float) -> None:
        if ax.contour:
            raise Refused(18, "axis is contouring")
        if not ax.m.motor_on:
            raise Refused(20, "motor off")
        if ax.m.moving:
            raise Refused(21, "already moving")
        self.machine.room(Limits).check_start(ax, direction)

    @handler("BG", Args.AXES)
    def bg(self, axes: list[Axis]) -> str:
        self.begin(self.plan_begin(axes))
        return ""

    def plan_begin(self, axes: list[Axis]) -> list[Begin]:
        """What ``BG`` of ``axes`` starts on each, every check made (nothing changed yet):
        the mode's name, ``None`` for a jog, or the target of a position move.

        Raises:
            Refused: an axis may not begin (TC 18, 20, 21, 22, 6 ...).
        """
        plans: list[Begin] = []
        for ax in axes:
            p = self.axes[ax.letter]
            if p.next_mode in self.modes:
                self._start_check(ax, 0)
                self.modes[p.next_mode][0](ax)
                plans.append((ax, p.next_mode))
            elif p.next_mode == "jog":
                self._start_check(ax, p.jg)
                plans.append((ax, None))
            else:
                base = ax.m.profiler.position
                target = p.pa if p.absolute else base + p.pr
                int32(target)
                self._start_check(ax, target - base)
                if p.sp <= 0:
                    raise Refused(6, "SP is 0")
                plans.append((ax, target))
        return plans

    def begin(self, plans: list[Begin]) -> None:
        """Start what :meth:`plan_begin` checked."""
        for ax, goal in plans:
            p = self.axes[ax.letter]
            prof = ax.m.profiler
            ax.limit_stop = False
            p.move_start = prof.position
            p.starts += 1
            p.began = goal if isinstance(goal, str) else "jog" if goal is None else "position"
            if isinstance(goal, str):
                self.modes[goal][1](ax)
            elif goal is None:
                engine(functools.partial(prof.begin_jog, p.jg, p.ac, p.dc, p.it))
            else:
                p.pa = goal
                engine(functools.partial(prof.begin_move, goal, p.sp, p.ac, p.dc, p.it))

    @handler("IP", Args.VALUES)
    def ip(self, fields: Fields) -> str:
        i = self.machine.interp
        if any(t == "?" for _, t in fields):
            return ",".join(i.pnum(ax.m.profiler.target) for ax, _ in fields) + "\r\n"
        moves = [(ax, int32(i.evaluate(t))) for ax, t in fields]
        for ax, n in moves:
            if ax.contour:
                raise Refused(18, "axis is contouring")
            if not ax.m.moving:
                self._start_check(ax, n)
                if self.axes[ax.letter].sp <= 0:
                    raise Refused(6, "SP is 0")
        for ax, n in moves:
            p = self.axes[ax.letter]
            prof = ax.m.profiler
            if not prof.moving:
                p.pr, p.absolute, p.next_mode, ax.limit_stop = n, False, "position", False
                p.began = "position"
            engine(functools.partial(prof.increment, n, p.sp, p.ac, p.dc, p.it))
            p.pa = prof.target
        return ""

    @handler("ST", Args.AXES)
    def st(self, axes: list[Axis]) -> str:
        sequences = [p.source for ax in axes if (p := _in_sequence(ax)) is not None]
        for ax in axes:
            ax.m.profiler.stop()
        # ST of one axis of a sequence stops the sequence: every axis of it shows that at
        # once (its BG and stop code), as after ST S, not from its own next sample.
        for ax in self.machine.servo.axes.values():
            p = _in_sequence(ax)
            if p is not None and any(p.source is s for s in sequences):
                p.sync()
        return ""

    @handler("AB")
    def ab(self, args: str) -> str:
        a = args.strip()
        if a not in ("", "0", "1"):
            raise Refused(6, "AB takes 0 or 1")
        for ax in self.machine.servo.axes.values():
            if ax.m.moving:
                ax.m.profiler.abort()
        self.machine.abort()
        if a != "1":
            self.machine.programs.reset()
        return ""

    @handler("SH", Args.AXES)
    def sh(self, axes: list[Axis]) -> str:
        # DMC-4103 command reference, SH: "Not Valid while in motion" (TC 7, as MO).
        if any(ax.m.moving for ax in axes):
            raise Refused(7, "SH while moving")
        for ax in axes:
            if not ax.m.motor_on:
                ax.m.motor_on = True
                self.machine.servo.reseat(ax, ax.m.encoder)
        return ""

    @handler("MO", Args.AXES)
    def mo(self, axes: list[Axis]) -> str:
        if any(ax.m.moving for ax in axes):
            raise Refused(7, "MO while moving")
        for ax in axes:
            ax.m.motor_on = False
        return ""

    # ---- operands ----------------------------------------------------------------------
    @operand("PR", kind=OperandKind.AXIS)
    def relative(self, ax: Axis) -> float:
        return self.axes[ax.letter].pr

    @operand("PA", kind=OperandKind.AXIS)
    def absolute(self, ax: Axis) -> float:
        return self.axes[ax.letter].pa

    @operand("SP", kind=OperandKind.AXIS)
    def speed(self, ax: Axis) -> float:
        return self.axes[ax.letter].sp

    @operand("AC", kind=OperandKind.AXIS)
    def accel(self, ax: Axis) -> float:
        return self.axes[ax.letter].ac

    @operand("DC", kind=OperandKind.AXIS)
    def decel(self, ax: Axis) -> float:
        return self.axes[ax.letter].dc

    @operand("JG", kind=OperandKind.AXIS)
    def jog_speed(self, ax: Axis) -> float:
        return self.axes[ax.letter].jg

    @operand("IT", kind=OperandKind.AXIS)
    def smoothing(self, ax: Axis) -> float:
        return self.axes[ax.letter].it

    @operand("BG", kind=OperandKind.AXIS)
    def moving(self, ax: Axis) -> float:
        return 1 if ax.m.moving else 0

    @operand("MO", kind=OperandKind.AXIS)
    def motor_off(self, ax: Axis) -> float:
        return 0 if ax.m.motor_on else 1


def _position(ax: Axis, value: float) -> float:
    return int32(value)


def _in_sequence(ax: Axis) -> DrivenProfiler | None:
    """The profiler of ``ax`` if a coordinated sequence drives it."""
    p = ax.m.profiler
    if isinstance(p, DrivenProfiler) and p.driven and p.mode == "vector":
        return p
    return None
