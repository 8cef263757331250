"""Reports and queries: ``TP`` ``RP`` ``TE`` ``TD`` ``TV`` ``SC`` ``TC`` and ``MG``.

Positions print in the PF format, ``MG`` numbers in VF, or in the ``{Fm.n}``, ``{Zm.n}`` or
``{$m.n}`` written in their own argument (``MG _TPA{Z10.4},_TPB{Z10.4}``: the DMC-4103 reference
places formatters "after each argument"; one format does not carry to the next argument, an
assumption, decision 0032); ``TC`` clears the code while ``_TC`` does not. ``TD`` reads an
auxiliary encoder rigidly coupled to the motor (``TP`` plus what ``DE`` set; a stepper's ``TD``
is its step count, its ``TP`` an encoder that counts its steps, plus what its ``DE`` set, which
only ``TP`` and the data record show: trippoints and gearing read the step count); ``TV`` is
the encoder velocity averaged over a quarter second, as the manuals describe.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from galil.codes import tc_text
from galil.errors import InvalidArgument
from galil.protocol.numbers import format_reply
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.tuning import Tuning
from galil.sim.servo import Axis

__all__ = ["Reports"]

_BRACES = re.compile(r"\{([^}]*)\}")


class Reports(Room):
    """What the controller tells about its axes and itself."""

    # ---- per-axis reports --------------------------------------------------------------
    @handler("TP")
    def tp(self, args: str) -> str:
        return self._positions(args, self.position)

    @handler("TD")
    def td(self, args: str) -> str:
        return self._positions(args, self.auxiliary)

    @handler("RP")
    def rp(self, args: str) -> str:
        return self._positions(args, self.reference)

    @handler("TE")
    def te(self, args: str) -> str:
        return self._positions(args, self.error)

    def _positions(self, args: str, get: Callable[[Axis], float]) -> str:
        """A position report in PF, or in a format of its own written after the axes: "Local
        format: ``TP {F2.2}`` -> ``-05.00, 05.00, 00.00, 07.00``; ``TP {$4.2}`` -> hex"
        (galil-protocol.md section 1.4, DMC-2x00 user manual p.166-167, DMC-1700 p.172).
        ``{Zm.n}`` drops the leading zeros as in ``MG``. [U] The manuals show it on ``TP``;
        ``TD``, ``RP`` and ``TE``, which PF formats too, take it here as well."""
        i = self.machine.interp
        found = _BRACES.search(args) if "{" in args else None
        if found is None:
            return i.report(i.axis_list(args), get, i.pnum)
        fmt = found.group(1).strip()
        if fmt[:1].upper() not in ("F", "Z", "$") or _BRACES.search(args, found.end()):
            raise Refused(53, f"bad format {{{fmt}}}")
        self._number(0, fmt)  # a bad format is refused before anything is read
        axes = i.axis_list(args[: found.start()] + args[found.end() :])
        return i.report(axes, get, lambda v: self._number(v, fmt))

    @handler("TV", Args.AXES)
    def tv(self, axes: list[Axis]) -> str:
        i = self.machine.interp
        return i.report(axes, self.velocity, lambda v: i.num(v, "8.0"))

    @handler("SC", Args.AXES)
    def sc(self, axes: list[Axis]) -> str:
        i = self.machine.interp
        return i.report(axes, self.stop_code, lambda v: i.num(v, "3.0"))

    @operand("TP", "DP", kind=OperandKind.AXIS)
    def position(self, ax: Axis) -> float:
        """``_TP`` (and ``_DP``, "the current main encoder position")."""
        return ax.m.encoder + (ax.shift if self.machine.room(Tuning).stepper(ax) else 0)

    @operand("TD", "DE", kind=OperandKind.AXIS)
    def auxiliary(self, ax: Axis) -> float:
        """``_TD`` (and ``_DE``): a servo's auxiliary encoder, a stepper's step count."""
        return ax.m.encoder + (0 if self.machine.room(Tuning).stepper(ax) else ax.aux)

    @operand("RP", kind=OperandKind.AXIS)
    def reference(self, ax: Axis) -> float:
        return ax.m.reference

    @operand("TE", kind=OperandKind.AXIS)
    def error(self, ax: Axis) -> float:
        return ax.m.error

    @operand("TV", kind=OperandKind.AXIS)
    def velocity(self, ax: Axis) -> float:
        return round(ax.m.velocity)

    @operand("TT", kind=OperandKind.AXIS)
    def torque(self, ax: Axis) -> float:
        """``_TT``: the torque command, 0: the simulator models no amplifier or load (its data
        record's torque is 0 too; unsourced as a model of a controller)."""
        return 0.0

    @operand("SC", kind=OperandKind.AXIS)
    def stop_code(self, ax: Axis) -> float:
        return int(ax.m.profiler.stop_code)

    # ---- the error code ----------------------------------------------------------------
    @handler("TC")
    def tc(self, args: str) -> str:
        i = self.machine.interp
        a = args.strip()
        if a not in ("", "0", "1"):
            raise Refused(6, "TC takes 0 or 1")
        code = i.tc
        i.tc = 0
        if a == "1" and code:
            return f"{i.num(code, '3.0')} {tc_text(code)}\r\n"
        return i.num(code, "3.0") + "\r\n"

    @operand("TC")
    def error_code(self) -> float:
        return self.machine.interp.tc

    # ---- MG ----------------------------------------------------------------------------
    @handler("MG")
    def mg(self, args: str) -> str:
        """Each comma-separated argument is a string, a number (in VF, or in the ``{Fm.n}``,
        ``{Zm.n}``, ``{$m.n}`` written in that argument: it formats that argument only) or
        ``{^n}`` characters; ``{N}`` leaves out the CR LF (decision 0032)."""
        if not args.strip():
            return "\r\n"
        items, newline = _mg_plan(args)
        i = self.machine.interp
        out: list[str] = []
        for kind, text, fmt in items:
            if kind == "num":
                out.append(self._number(i.evaluate(text), fmt))
            elif kind == "text":
                if len(text) > i.spec.mg_max:
                    # "MG text max 72 chars (C40x0 p.165, C18x2 optcom-145), 31 chars on
                    # DMC-1000/1500 (C1000 p.96)" (galil-protocol.md §1.1): TC 52 "Missing
                    # quote or string too long" (§1.2).
                    raise Refused(52, "string too long")
                out.append(text)
            else:
                out.append(self._character(text))
        return "".join(out) + ("\r\n" if newline else "")

    def _character(self, text: str) -> str:
        code = int(self.machine.interp.evaluate(text))
        if not 0 <= code <= 255:
            raise Refused(53, "bad character code")
        return chr(code)

    def _number(self, value: float, fmt: str | None) -> str:
        i = self.machine.interp
        if fmt is None:
            return i.vnum(value)
        kind, body = fmt[0].upper(), fmt[1:]
        try:
            if kind == "$":
                return format_reply(value, "$" + body)
            return format_reply(value, body, kind == "Z", sign_space=True)
        except InvalidArgument:
            raise Refused(53, f"bad format {fmt}") from None


# What an MG line's arguments are, read once per text (the library sends the same few reads
# again and again): (kind, text, format) per item and whether the line ends with CR LF. A line
# with a syntax error raises every time (nothing is kept); kept texts are cleared past 512.
_Plan = tuple[tuple[tuple[str, str, "str | None"], ...], bool]
_MG_PLANS: dict[str, _Plan] = {}


def _mg_plan(args: str) -> _Plan:
    plan = _MG_PLANS.get(args)
    if plan is None:
        plan = _build_mg_plan(args)
        if len(_MG_PLANS) >= 512:
            _MG_PLANS.clear()
        _MG_PLANS[args] = plan
    return plan


def _build_mg_plan(args: str) -> _Plan:
    items: list[tuple[str, str, str | None]] = []
    newline = True
    for part in split_fields(args):
        fmt: str | None = None
        for spec in _BRACES.findall(part):
            s = spec.strip()
            if s.upper() == "N":
                newline = False
            elif s.startswith("^"):
                items.append(("char", s[1:], None))
            elif s[:1].upper() in ("F", "Z", "$"):
                fmt = s
            elif s[:1].upper() not in ("E", "P"):
                raise Refused(53, f"bad format {{{s}}}")
        expr = _BRACES.sub("", part).strip() if "{" in part else part.strip()
        if expr.startswith('"'):
            if len(expr) < 2 or not expr.endswith('"') or '"' in expr[1:-1]:
                raise Refused(52, "missing quote")
            if "?" in expr:
                # TC 54 "Question mark part of string" (galil-protocol.md §1.2). The whole
                # line is refused before it prints anything, from a program thread when it
                # runs there [U: whether a download refuses the line sooner is not sourced].
                raise Refused(54, "question mark part of string")
            items.append(("text", expr[1:-1], None))
        elif expr:
            items.append(("num", expr, fmt))
    return tuple(items), newline
