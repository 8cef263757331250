"""Settings and formats: ``LZ`` ``PF`` ``VF`` ``EO`` ``CW`` ``TM`` ``RS``, ``^R^V`` and ``^R^S``.

The formats belong to the interpreter and the output settings to the ports; this room only
answers the commands that read and change them. ``TM`` changes the sample period (the facts
come from the model: its range, or a fixed period); samples already run keep their times.
"""

from __future__ import annotations

import math

from galil.errors import InvalidArgument
from galil.protocol.numbers import parse_format
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.programs import Thread
from galil.sim.registry import handler, operand

__all__ = ["Settings"]


class Settings(Room):
    """Reply formats, echo, unsolicited marking, the sample period, resets and identity."""

    def _choice(self, args: str, choices: tuple[int, ...]) -> int | None:
        """The value of a setting that takes one of ``choices`` (the first by default);
        None for ``?``."""
        a = args.strip()
        if a == "?":
            return None
        value = self.machine.interp.evaluate(a) if a else choices[0]
        if value not in choices:
            raise Refused(6, f"value must be one of {choices}")
        return int(value)

    @staticmethod
    def _format(args: str) -> str | None:
        """A PF/VF format (``"10.4"``, ``"$4.0"``); None for ``?``."""
        a = args.strip()
        if a == "?":
            return None
        try:
            is_hex, m, n = parse_format(a)
        except InvalidArgument:
            raise Refused(6, "bad format") from None
        return f"{'$' if is_hex else ''}{m}.{n}"

    def burn(self, name: str) -> object | None:
        # The BN table: LZ PF VF (the interpreter's), EO CW (the ports'), TM (the servo's).
        if name != "BN":
            return None
        i, ports = self.machine.interp, self.machine.ports
        return i.lz, i.pf, i.vf, ports.echo, ports.cw, ports.cw_mode, self.machine.servo.tm

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, tuple)
        i, ports, servo = self.machine.interp, self.machine.ports, self.machine.servo
        i.lz, i.pf, i.vf, ports.echo, ports.cw, ports.cw_mode, tm = saved
        if tm != servo.tm:
            servo.set_tm(tm)
            for ax in servo.axes.values():
                servo.reseat(ax, ax.m.reference)

    # ---- formats -----------------------------------------------------------------------
    @handler("LZ")
    def lz(self, args: str) -> str:
        i = self.machine.interp
        v = self._choice(args, (1, 0))
        if v is None:
            return i.num(int(i.lz), "1.0") + "\r\n"
        i.lz = bool(v)
        return ""

    @handler("PF")
    def pf(self, args: str) -> str:
        v = self._format(args)
        if v is None:
            return f" {self.machine.interp.pf}\r\n"
        self.machine.interp.pf = v
        return ""

    @handler("VF")
    def vf(self, args: str) -> str:
        v = self._format(args)
        if v is None:
            return f" {self.machine.interp.vf}\r\n"
        self.machine.interp.vf = v
        return ""

    @operand("LZ")
    def leading_zeros(self) -> float:
        return 1.0 if self.machine.interp.lz else 0.0

    @operand("VF")
    def variable_format(self) -> float:
        """``_VF``: the format as a number (VF 10.4 -> 10.4, hex VF -4.2 -> -4.2)."""
        return _format_value(self.machine.interp.vf)

    @operand("PF")
    def position_format(self) -> float:
        return _format_value(self.machine.interp.pf)

    # ---- output ------------------------------------------------------------------------
    @handler("EO")
    def eo(self, args: str) -> str:
        ports = self.machine.ports
        v = self._choice(args, (1, 0))
        if v is None:
            return self.machine.interp.num(int(ports.echo), "1.0") + "\r\n"
        ports.echo = bool(v)
        return ""

    @handler("CW")
    def cw(self, args: str) -> str:
        ports = self.machine.ports
        i = self.machine.interp
        fields = split_fields(args)
        first = fields[0].strip()
        if len(fields) == 1 and first in ("", "?", "0"):
            # R4103, CW: "n0 = 0 causes controller to return a copyright information string.
            # Equivalent to n0 = ?" (and so when it is omitted); the text is this simulator's.
            return f"Copyright (c) {self.machine.identity} (simulated)\r\n"
        mode = ports.cw
        if first:
            mode = int(i.evaluate(fields[0]))
            if mode not in (1, 2):
                raise Refused(6, "CW takes 1 or 2")
        pause = ports.cw_mode
        if len(fields) > 1 and fields[1].strip():
            pause = int(i.evaluate(fields[1]))
            if pause not in (0, 1):
                raise Refused(6, "CW second field is 0 or 1")
        ports.cw = mode
        ports.cw_mode = pause
        return ""

    @operand("EO")
    def echo(self) -> float:
        return 1.0 if self.machine.ports.echo else 0.0

    @operand("CW")
    def marking(self) -> float:
        return self.machine.ports.cw

    # ---- the sample period -------------------------------------------------------------
    @handler("TM")
    def tm(self, args: str) -> str:
        servo = self.machine.servo
        spec = self.machine.spec
        if not spec.has_axes:  # gclib: "RIO doesn't have TM" [unsourced: the code it answers]
            raise Refused(1, "no TM on this model")
        a = args.strip()
        if a == "?":
            return self.machine.interp.num(servo.tm, spec.reply_formats["TM"]) + "\r\n"
        if not a:
            return ""
        value = self.machine.interp.evaluate(a)
        if not spec.tm_adjustable:  # as the host's TM builder refuses it (models.py)
            raise Refused(6, "this model's sample period is fixed")
        if any(ax.m.moving for ax in servo.axes.values()):
            raise Refused(7, "TM while moving")
        if value <= 0:
            return self._loop_off(value)
        # A TM off the step (31.25 µs) is taken down to it, as the gains are to theirs
        # [unsourced: the references give the step, not what a value off it does].
        step = spec.tm_resolution
        value = math.floor(value / step + 1e-9) * step
        low, high = spec.tm_range
        if not low <= value <= high:
            raise Refused(6, "TM out of range")
        servo.set_tm(value)
        for ax in servo.axes.values():
            servo.reseat(ax, ax.m.reference)
        return ""

    def _loop_off(self, value: float) -> str:
        """``TM <= 0``: "turns the servo loop off" (M40-CR p246): the motors are no longer
        driven (taken here as MO on every axis: [unsourced]); the clock runs on at the last
        period and ``TM ?`` answers the value given."""
        servo = self.machine.servo
        for ax in servo.axes.values():
            ax.m.motor_on = False
        servo.tm = value
        return ""

    @operand("TM")
    def sample_time(self) -> float:
        # A RIO, which has no TM command, answers _TM with its fixed 1000 [unsourced].
        return self.machine.servo.tm

    # ---- reset and identity ------------------------------------------------------------
    @handler("RS")
    def rs(self, args: str) -> str:
        # R4103, RS: "resets the state of the processor to its power-on condition. The
        # previously saved state of the hardware, along with parameter values and saved
        # program, are restored." "n = 0 performs normal reset. n = -1 performs soft master
        # reset": "restores factory default settings without erasing the EEPROM". What BN,
        # BP and BV burned comes back (after RS -1 the parameters stay at their defaults, the
        # program and variables come back: decision 0052); #AUTO runs after RS and RS 0.
        a = args.strip()
        if a not in ("", "0", "-1"):
            raise Refused(6, "RS takes 0 or -1")
        self.machine.power_on(parameters=a != "-1")
        programs = self.machine.programs
        if a != "-1" and "AUTO" in programs.labels:
            programs.threads[0] = Thread(0, line=programs.labels["AUTO"])
        return ""

    @operand("RS")
    def reset_state(self) -> float:
        # R4103, _RS: checksum errors found at the last power-up (bits 0-3); none here.
        return 0.0

    @handler("\x12\x13")
    def master_reset(self, args: str) -> str:
        # ^R^S, the master reset: factory defaults, and the burned parameters, program and
        # variables erased (R4103, BN: "All parameters which have been burned into memory can
        # be restored to their factory defaults through a master reset"; the program and the
        # variables erased too is this simulator's reading: decision 0052).
        self.machine.flash.clear()
        self.machine.reset()
        return ""

    @handler("\x12\x16")
    def revision(self, args: str) -> str:
        return self.machine.identity + "\r\n"

    @operand("BN")
    def serial_number(self) -> float:
        return 4040.0


def _format_value(fmt: str) -> float:
    is_hex, m, n = parse_format(fmt)
    value = m + n / 10
    return -value if is_hex else value
