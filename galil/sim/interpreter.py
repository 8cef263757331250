"""The interpreter: one command's text to its handler, variables, operands and reply formats.

A command is two upper-case letters and arguments; the command table (filled from the rooms'
:func:`~galil.sim.registry.handler` marks) names its handler and how its arguments are parsed.
``name=expression`` assigns a variable unless the name is a command followed by axis letters
(``PRA=5``). Expressions read variables, ``TIME`` and operands (``_TPA``, ``_TC``, ``_XQ0``) from
the operand tables. Replies are printed in the PF/VF formats with LZ, a blank in the sign
position of positive numbers; ``TC`` keeps the error code of the last refused command.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from galil.models import INT32_MAX, INT32_MIN, ModelSpec
from galil.protocol.numbers import format_reply, parse_format
from galil.sim.parse import FUNCTIONS, Refused, evaluate, quantised, split_fields
from galil.sim.ports import Port
from galil.sim.programs import NOT_IN_PROGRAM, PROGRAM_ONLY, Thread, program_only
from galil.sim.registry import Args, HandlerSpec, Result
from galil.sim.servo import Axis, Servo

__all__ = ["Caller", "Command", "Interpreter", "int32"]

#: Who runs a command: a host port, a program thread, or nobody (a released wait).
Caller = Port | Thread | None

_RESERVED = frozenset({"TIME"})
_ELEMENT = re.compile(r"([A-Za-z][A-Za-z0-9]*)\[(.+)\]")
#: A remark line (``REM text``): the host's software strips it; no command (decision 0051).
_REMARK = re.compile(r"REM(?:\s|$)")
#: The coordinate systems (vector planes).
_PLANES = ("S", "T")


@dataclass(frozen=True)
class Command:
    """A command of the table: its spec and the bound handler."""

    spec: HandlerSpec
    run: Callable[..., Result]


def int32(value: float) -> int:
    """A 32-bit integer argument (positions, PR/PA/IP, FL/BL), rounded.

    Raises:
        Refused: TC 6, out of the controller's integer range.
    """
    if not INT32_MIN <= value <= INT32_MAX:
        raise Refused(6, "position out of range")
    return round(value)


class Interpreter:
    """Runs command text against the command and operand tables.

    Args:
        spec: the model (axis letters, name lengths).
        servo: the servo loop (axes and ``TIME``).

    Attributes:
        commands: command name -> :class:`Command`.
        operands: plain operands (``_TC``) -> value.
        axis_operands: axis operands (``_TPA``) -> value of an axis.
        index_operands: indexed operands (``_XQ0``) -> value for the text after the name.
        plane_commands: commands for coordinate systems (``BG S``) -> :class:`Command`,
            beside (not instead of) the axis command of the same name.
        plane_operands: coordinate-system operands (``_BGS``) -> value for the plane letter.
        functions: expression functions (``@ABS[x]``) -> value for the argument.
        element: an array element's value (``arr[3]`` in an expression), set by the room
            that keeps the arrays; ``None`` while no room does (``arr[3]`` is refused).
        store_element: ``arr[3]=expression``, set by the same room.
        caller: who runs the command being executed (``WH``, ``CF I``, ``DL``).
        tc: the error code of the last refused command.
    """

    def __init__(self, spec: ModelSpec, servo: Servo) -> None:
        self.spec = spec
        self.servo = servo
        self.commands: dict[str, Command] = {}
        self.operands: dict[str, Callable[[], float]] = {}
        self.axis_operands: dict[str, Callable[[Axis], float]] = {}
        self.index_operands: dict[str, Callable[[str], float]] = {}
        self.plane_commands: dict[str, Command] = {}
        self.plane_operands: dict[str, Callable[[str], float]] = {}
        self.functions: dict[str, Callable[[float], float]] = dict(FUNCTIONS)
        self.element: Callable[[str, float], float] | None = None
        self.store_element: Callable[[str, float, float], None] | None = None
        self.caller: Caller = None
        self._variable = re.compile(rf"[A-Za-z][A-Za-z0-9]{{0,{spec.variable_length - 1}}}")
        self._letters = frozenset(spec.axes) | frozenset(spec.aliases)
        self.reset()

    def reset(self) -> None:
        """Power-on defaults: no variables, no error, PF 10.0, VF 10.4, LZ 1."""
        self.variables: dict[str, float] = {}
        self.tc = 0
        self.pf = "10.0"
        self.vf = "10.4"
        self.lz = True

    # ---- running a command -------------------------------------------------------------
    def execute(self, text: str, caller: Caller) -> Result:
        """Run one command for ``caller``; return its data text (with CR LF), a wait, or
        ``DOWNLOAD``.

        Raises:
            Refused: the command is rejected; nothing was changed.
        """
        before, self.caller = self.caller, caller
        try:
            return self._execute(text)
        finally:
            self.caller = before

    def _execute(self, text: str) -> Result:
        s = text.strip(" \t\n")
        if not s:
            return ""
        if s[0] == "\x12":
            control = self.commands.get(s)
            if control is None:
                raise Refused(1, "unknown control command")
            self._check_caller(s)
            return control.run("")
        if s[0] == "'":
            return ""  # a comment: "Valid in terminal ... Valid in program" (its entry)
        if _REMARK.match(s):
            # REM "is NOT a controller command": Galil's PC software strips REM lines before a
            # download. Its entry reads "Not Valid in terminal ... Not Valid in program".
            raise Refused(3 if isinstance(self.caller, Thread) else 2, "REM is no command")
        word = program_only(s)
        if word is not None:
            self._check_caller(word)
            raise Refused(1, f"{word} is run by a program thread")
        eq = _find_eq(s)
        if eq > 0 and s[eq - 1] == "]" and self.store_element is not None:
            target = _ELEMENT.fullmatch(s[:eq].strip())
            if target is not None:
                index = self.evaluate(target.group(2))
                self.store_element(target.group(1), index, self.evaluate(s[eq + 1 :]))
                return ""
        command = self.commands.get(s[:2])
        if self.plane_commands:
            planes = self._planes(s)
            if planes is not None:
                self._check_caller(s[:2])  # AM S as AM A
                return self.plane_commands[s[:2]].run(planes)
        if command is not None:
            if eq > 0 and self._is_assignment(s, eq, equals=command.spec.equals):
                return self.assign(s[:eq].strip(), s[eq + 1 :])
            self._check_caller(s[:2])
            args = s[2:]
            kind = command.spec.args
            if kind is Args.TEXT:
                return command.run(args)
            if kind is Args.AXES:
                return command.run(self.axis_list(args))
            return command.run(self.axis_fields(args, every=command.spec.every))
        if eq > 0:
            return self.assign(s[:eq].strip(), s[eq + 1 :])
        raise Refused(1, f"unrecognised command {s!r}")

    def _is_assignment(self, s: str, eq: int, *, equals: bool) -> bool:
        """Whether ``s`` (a command's name first, ``=`` at ``eq``) assigns a variable.

        A command whose own syntax has ``=`` (``CD 100=2``, ``VSS=``, ``IHA=>-1``) keeps it
        after a blank or a plane/axis/handle letter; glued digits make a variable name:
        "``CD0=0`` would assign a variable named CD0 -- need ``CD 0=0`` with a space"
        (galil-protocol.md §3 contour mode; C1400 DT, C18x6 CD, C40x0 DT).
        """
        name = s[:eq].strip()
        if not self._variable.fullmatch(name):
            return False
        if equals:
            return s[2:3].isdigit()
        return not self._is_axis_spec(s[2:eq].strip())

    def _check_caller(self, name: str) -> None:
        """Refuse a program-only command (:data:`~galil.sim.programs.PROGRAM_ONLY`) that a
        host port sent, and a host-only one (:data:`~galil.sim.programs.NOT_IN_PROGRAM`)
        that a program thread reached.

        Raises:
            Refused: TC 2, "Command only valid from program"; TC 3, "Command not valid in
                program".
        """
        if not isinstance(self.caller, Thread):
            if name in PROGRAM_ONLY:
                raise Refused(2, f"{name} only in a program")
        elif name in NOT_IN_PROGRAM:
            raise Refused(3, f"{name!r} not valid in a program")

    def _planes(self, s: str) -> list[str] | None:
        """The planes a plane command names (``BG ST``), with the axes named beside them
        (``BG SA``: :attr:`~galil.sim.registry.Args.PLANES_AND_AXES`), or ``None`` if it is
        not one."""
        if s[:2] not in self.plane_commands:
            return None
        letters = s[2:].replace(" ", "").replace(",", "")
        if not any(c in _PLANES for c in letters):
            return None
        if any(c not in _PLANES and c not in self._letters for c in letters):
            return None
        return list(dict.fromkeys(letters))

    def _is_axis_spec(self, text: str) -> bool:
        letters = text.replace(" ", "").replace(",", "")
        return bool(letters) and all(c in self._letters for c in letters)

    # ---- variables and expressions -----------------------------------------------------
    def is_name(self, name: str) -> bool:
        """Whether ``name`` is a valid variable or array name on this model."""
        return bool(self._variable.fullmatch(name)) and name not in _RESERVED

    def assign(self, name: str, rhs: str) -> str:
        """``name=expression`` (or ``name=`` to read it back).

        Raises:
            Refused: a bad name, an undefined variable read, a value out of range.
        """
        if not self._variable.fullmatch(name) or name in _RESERVED:
            raise Refused(1, f"bad variable name {name!r}")
        rhs = rhs.strip()
        if rhs in ("", "?"):
            if name not in self.variables:
                raise Refused(1, f"undefined variable {name!r}")
            return self.vnum(self.variables[name]) + "\r\n"
        value = self.evaluate(rhs)
        if not INT32_MIN <= value < INT32_MAX + 1:
            raise Refused(6, "out of range")
        if name not in self.variables and len(self.variables) >= self.spec.variables:
            raise Refused(67, "too many variables")
        self.variables[name] = quantised(value)  # 32.16, as every number (parse.py)
        return ""

    def evaluate(self, text: str) -> float:
        """Evaluate an expression (left to right) with this controller's names.

        Raises:
            Refused: a syntax error or an unknown name.
        """
        return evaluate(text, self.lookup, self.functions, self.element)

    def lookup(self, name: str) -> float:
        """The value of a variable, ``TIME`` or an operand (``_TPA``).

        Raises:
            Refused: no such name.
        """
        if name == "TIME":
            return float(self.servo.sample)
        if name.startswith("_"):
            return self.operand(name[1:])
        try:
            return self.variables[name]
        except KeyError:
            raise Refused(1, f"undefined variable {name!r}") from None

    def operand(self, name: str) -> float:
        """The value of operand ``_name`` (name without the underscore).

        Raises:
            Refused: TC 1 for an unknown operand, TC 4 for an unknown axis.
        """
        code, rest = name[:2], name[2:]
        if rest in _PLANES:
            plane = self.plane_operands.get(code)
            if plane is not None:
                return float(plane(rest))
        if not rest:
            plain = self.operands.get(code)
            if plain is not None:
                return float(plain())
        indexed = self.index_operands.get(code)
        if indexed is not None:
            return float(indexed(rest))
        if len(rest) != 1:
            raise Refused(1, f"unknown operand _{name}")
        ax = self.axis(rest)
        getter = self.axis_operands.get(code)
        if getter is None:
            raise Refused(1, f"unknown operand _{name}")
        return float(getter(ax))

    # ---- arguments ---------------------------------------------------------------------
    def axis(self, letter: str) -> Axis:
        """The axis named ``letter`` (aliases accepted).

        Raises:
            Refused: TC 4, no such axis.
        """
        axes = self.servo.axes
        found = axes.get(letter)
        if found is not None:
            return found
        letter = self.spec.aliases.get(letter.upper(), letter.upper())
        if letter not in axes:
            raise Refused(4, f"no axis {letter!r}")
        return axes[letter]

    def axis_list(self, args: str) -> list[Axis]:
        """The axes named in ``args`` (``"AB"``, ``"A,C"``), in order; none named: all."""
        letters = args.replace(" ", "").replace(",", "")
        if not letters:
            return list(self.servo.axes.values())
        out: list[Axis] = []
        for c in letters:
            ax = self.axis(c)
            if ax not in out:
                out.append(ax)
        return out

    def axis_fields(self, args: str, *, every: bool = False) -> list[tuple[Axis, str]]:
        """Per-axis fields: ``"1,,3"`` by position, ``"AB=5"`` by name; empty fields skipped.
        With ``every``, ``"*=5"`` (``KP*=5``, ``LD*=?``) names every axis of the model.

        Raises:
            Refused: a missing value, more fields than axes, an unknown axis.
        """
        a = args.strip()
        if not a:
            return []
        eq = a.find("=")
        if eq >= 0:
            value = a[eq + 1 :].strip()
            if not value:
                raise Refused(1, "missing value")
            named = a[:eq].strip()
            if every and named == "*":
                return [(ax, value) for ax in self.servo.axes.values()]
            return [(ax, value) for ax in self.axis_list(named)] if named else []
        fields = split_fields(a)
        axes = list(self.servo.axes.values())
        if len(fields) > len(axes):
            raise Refused(4, "more fields than axes")
        return [(axes[i], f.strip()) for i, f in enumerate(fields) if f.strip()]

    def parameters(
        self,
        fields: list[tuple[Axis, str]],
        get: Callable[[Axis], float],
        check: Callable[[Axis, float], float],
        apply: Callable[[Axis, float], None],
        fmt: Callable[[float], str],
    ) -> str:
        """Set and/or interrogate a per-axis parameter; all checks come before any change."""
        queries: list[Axis] = []
        sets: list[tuple[Axis, float]] = []
        for ax, text in fields:
            if text == "?":
                queries.append(ax)
            else:
                sets.append((ax, check(ax, self.evaluate(text))))
        for ax, value in sets:
            apply(ax, value)
        if not queries:
            return ""
        return ",".join(fmt(get(ax)) for ax in queries) + "\r\n"

    # ---- replies -----------------------------------------------------------------------
    def pnum(self, value: float) -> str:
        """A number in the position format (PF)."""
        return format_reply(value, self.pf, self.lz, sign_space=True)

    def vnum(self, value: float) -> str:
        """A number in the variable format (VF)."""
        return format_reply(value, self.vf, self.lz, sign_space=True)

    def num(self, value: float, fmt: str) -> str:
        """A number in a command's own format (``"10.0"``), with LZ.

        Unlike PF and VF, whose overflow prints nines, m is taken as a minimum width here: a
        wider whole part prints in full (``TM ?`` in format 1.0 gives ``1000``; see
        :attr:`galil.models.ModelSpec.reply_formats`).
        """
        is_hex, digits, decimals = parse_format(fmt)
        if not is_hex and abs(value) >= 10**digits - 0.5:
            width = len(str(int(round(abs(value), decimals))))
            fmt = f"{min(max(digits, width), 10)}.{decimals}"
        return format_reply(value, fmt, self.lz, sign_space=True)

    def report(
        self, axes: Iterable[Axis], get: Callable[[Axis], float], fmt: Callable[[float], str]
    ) -> str:
        """One value per axis, comma separated, as a reply line."""
        return ",".join([fmt(get(ax)) for ax in axes]) + "\r\n"


def _find_eq(s: str) -> int:
    if '"' not in s:
        return s.find("=")  # no quotes: the first '=' is outside them
    quoted = False
    for i, ch in enumerate(s):
        if ch == '"':
            quoted = not quoted
        elif ch == "=" and not quoted:
            return i
    return -1
