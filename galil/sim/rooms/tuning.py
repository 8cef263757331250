"""Motor and loop settings: MT KS KP KI KD IL TL ER OE BR CE, and the flash burns BN BP BV.

Each setting is stored per axis with the model's range (:class:`~galil.models.ModelSpec`) and
read back quantised as the controller stores it (gains to ``gain_resolution``, KS to 1/32).
The simulated motor follows its reference whatever the gains: the values are kept and reported,
not used by the plant (a stepper's KS filter is not modelled; see
:func:`galil.predict.stepper_output`). ``BN``/``BP``/``BV`` hold their ``:`` for
:data:`BURN_SECONDS` of simulated time, as a flash write keeps a real controller busy.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, Wait, handler, operand
from galil.sim.servo import Axis, at_rest

__all__ = ["BURN_SECONDS", "Tuning"]

#: How long BN, BP and BV keep the controller busy in the simulator (an assumption: EPICS
#: allows 3 s; no measured duration is known).
BURN_SECONDS = 0.25

Fields = list[tuple[Axis, str]]


@dataclass
class _Settings:
    mt: float = 1.0
    ks: float = 2.0
    kp: float = 6.0
    ki: float = 0.0
    kd: float = 64.0
    il: float = 9.998
    tl: float = 9.998
    er: float = 16384.0
    oe: float = 0.0
    br: float = 0.0
    ce: float = 0.0


def motor_off(command: str, then: Callable[[Axis, float], float]) -> Callable[[Axis, float], float]:
    """A value check for ``command`` that refuses it while the axis's motor is on, then checks
    with ``then``. The DMC-4103 command reference's MT remark: "The axis must be in the motor
    off state (MO) before setting MT"; it gives no code: TC 135 "Motor must be in MO" is the
    one of its TC list that says so (decision 0043)."""

    def check(ax: Axis, v: float) -> float:
        if ax.m.motor_on:
            raise Refused(135, f"{command} with the motor on")
        return then(ax, v)

    return check


def _floor(value: float, step: float) -> float:
    return math.floor(value / step + 1e-9) * step


class Tuning(Room):
    """The motor type and the servo loop's settings of every axis, and the burns."""

    def reset(self) -> None:
        # IL and TL start at their maxima (the DMC-4103 reference's defaults: 9.9982 both).
        spec = self.machine.spec
        self.axes = {letter: _Settings(il=spec.il_max, tl=spec.tl_max) for letter in spec.axes}
        #: How many times each burn ran since power-on (BN, BP, BV).
        self.burns = {"BN": 0, "BP": 0, "BV": 0}
        #: The axes whose OE is 1 or 3 (their error beyond ER turns the motor off).
        self.off_on_error: frozenset[str] = frozenset()

    def burn(self, name: str) -> object | None:
        # The DMC-4103 reference's BN table lists all of them: MT KS KP KI KD IL TL ER OE BR CE.
        return self.axes if name == "BN" else None

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, dict)
        self.axes = saved
        self.off_on_error = frozenset(c for c, s in self.axes.items() if s.oe in (1, 3))

    def stepper(self, ax: Axis) -> bool:
        """Whether the axis is configured as a stepper (MT ±2, ±2.5)."""
        return abs(self.axes[ax.letter].mt) in (2.0, 2.5)

    def _setting(
        self,
        name: str,
        fields: Fields,
        check: Callable[[Axis, float], float],
        fmt: str,
    ) -> str:
        attr = name.lower()

        def get(ax: Axis) -> float:
            value: float = getattr(self.axes[ax.letter], attr)
            return value

        def apply(ax: Axis, v: float) -> None:
            setattr(self.axes[ax.letter], attr, v)

        i = self.machine.interp
        return i.parameters(fields, get, check, apply, lambda v: i.num(v, fmt))

    def _ranged(self, lo: float, hi: float, step: float | None = None) -> Callable[..., float]:
        def check(ax: Axis, v: float) -> float:
            if not lo <= v <= hi:
                raise Refused(6, "number out of range")
            return v if step is None else _floor(v, step)

        return check

    def _choice(self, allowed: frozenset[float] | tuple[float, ...]) -> Callable[..., float]:
        def check(ax: Axis, v: float) -> float:
            if v not in allowed:
                raise Refused(6, "not a valid setting")
            return v

        return check

    # ---- commands ----------------------------------------------------------------------
    @handler("MT", Args.VALUES)
    def mt(self, fields: Fields) -> str:
        check = at_rest("MT", motor_off("MT", self._choice(self.machine.spec.motor_types)))
        return self._setting("MT", fields, check, "2.1")

    @handler("KS", Args.VALUES)
    def ks(self, fields: Fields) -> str:
        lo, hi = self.machine.spec.ks_range
        return self._setting("KS", fields, self._ranged(lo, hi, 1 / 32), "2.4")

    # ``KP ?`` answers in the command's own format (the model's reply_formats: KP and KD 4.2,
    # KI 4.4 or 4.0); ``MG _KPA`` prints the same value in VF.
    def _gain(self, name: str, fields: Fields, high: float, step: float) -> str:
        spec = self.machine.spec
        return self._setting(name, fields, self._ranged(0, high, step), spec.reply_formats[name])

    @handler("KP", Args.VALUES, every=True)
    def kp(self, fields: Fields) -> str:
        spec = self.machine.spec
        return self._gain("KP", fields, spec.kp_max, spec.gain_resolution)

    @handler("KI", Args.VALUES, every=True)
    def ki(self, fields: Fields) -> str:
        spec = self.machine.spec
        return self._gain("KI", fields, spec.ki_max, spec.ki_resolution)

    @handler("KD", Args.VALUES, every=True)
    def kd(self, fields: Fields) -> str:
        spec = self.machine.spec
        return self._gain("KD", fields, spec.kd_max, spec.gain_resolution)

    @handler("IL", Args.VALUES)
    def il(self, fields: Fields) -> str:
        spec = self.machine.spec
        return self._setting("IL", fields, self._ranged(spec.il_min, spec.il_max, 1e-4), "1.4")

    @handler("TL", Args.VALUES)
    def tl(self, fields: Fields) -> str:
        return self._setting("TL", fields, self._ranged(0, self.machine.spec.tl_max, 1e-4), "1.4")

    @handler("ER", Args.VALUES)
    def er(self, fields: Fields) -> str:
        spec = self.machine.spec
        return self._setting("ER", fields, self._ranged(spec.er_min, spec.er_max, 1), "10.0")

    @handler("OE", Args.VALUES, every=True)
    def oe(self, fields: Fields) -> str:
        reply = self._setting("OE", fields, self._choice((0.0, 1.0, 2.0, 3.0)), "1.0")
        self.off_on_error = frozenset(c for c, s in self.axes.items() if s.oe in (1, 3))
        return reply

    @handler("BR", Args.VALUES)
    def br(self, fields: Fields) -> str:
        return self._setting("BR", fields, at_rest("BR", self._choice((-1.0, 0.0, 1.0))), "2.0")

    @handler("CE", Args.VALUES)
    def ce(self, fields: Fields) -> str:
        # "Not Valid while in motion" (DMC-4103 reference); 0 .. 15, the main encoder's type
        # plus the auxiliary's (0, 4, 8, 12). Kept and reported, not modelled: the simulated
        # encoder counts as if quadrature, whatever its polarity.
        choices = tuple(float(n) for n in range(16))
        return self._setting("CE", fields, at_rest("CE", self._choice(choices)), "2.0")

    # ---- operands ----------------------------------------------------------------------
    @operand("MT", kind=OperandKind.AXIS)
    def _mt_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].mt

    @operand("KS", kind=OperandKind.AXIS)
    def _ks_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].ks

    @operand("KP", kind=OperandKind.AXIS)
    def _kp_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].kp

    @operand("KI", kind=OperandKind.AXIS)
    def _ki_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].ki

    @operand("KD", kind=OperandKind.AXIS)
    def _kd_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].kd

    @operand("IL", kind=OperandKind.AXIS)
    def _il_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].il

    @operand("TL", kind=OperandKind.AXIS)
    def _tl_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].tl

    @operand("ER", kind=OperandKind.AXIS)
    def _er_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].er

    @operand("OE", kind=OperandKind.AXIS)
    def _oe_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].oe

    @operand("BR", kind=OperandKind.AXIS)
    def _br_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].br

    @operand("CE", kind=OperandKind.AXIS)
    def _ce_value(self, ax: Axis) -> float:
        return self.axes[ax.letter].ce

    # ---- burns -------------------------------------------------------------------------
    def _burn(self, name: str, args: str) -> Wait:
        if args.strip():
            raise Refused(6, f"{name} takes no argument")
        if name != "BV" and self.machine.programs.threads:
            raise Refused(17, "BN and BP not valid while a program runs")
        servo = self.machine.servo
        # DMC-4103 command reference: BP "Not Valid while in motion" (BN, BV are valid).
        if name == "BP" and any(ax.m.moving for ax in servo.axes.values()):
            raise Refused(7, "BP while moving")
        wake = servo.sample + max(1, round(BURN_SECONDS / servo.ts))

        def done() -> str:
            self.burns[name] += 1
            self.machine.burn(name)
            return ""

        return Wait(wake=wake, then=done)

    @handler("BN")
    def bn(self, args: str) -> Wait:
        return self._burn("BN", args)

    @handler("BP")
    def bp(self, args: str) -> Wait:
        return self._burn("BP", args)

    @handler("BV")
    def bv(self, args: str) -> Wait:
        return self._burn("BV", args)
