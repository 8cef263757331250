"""Program commands: ``DL`` ``UL`` ``LS`` ``XQ`` ``HX`` ``NO``, and the registration of
``JP``/``JS``/``EN``/``ZS``.

The program store and the threads are the core's :class:`~galil.sim.programs.Programs`;
``JP``, ``JS``, ``EN``, ``ZS`` and ``IF``/``ELSE``/``ENDIF`` are flow control that only a
thread runs (from a host they are refused, as every command of
:data:`~galil.sim.programs.PROGRAM_ONLY` is). ``_XQn`` is thread n's line, -1 when it is not
running; ``_NO`` the running threads' bits; ``_ZSn`` thread n's subroutine depth; ``_JS``
what the last subroutine returned (``EN ,,value``); ``_ED`` the program line of the last error
in a program, ``_ED1`` its thread.
"""

from __future__ import annotations

from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.programs import Thread
from galil.sim.registry import DOWNLOAD, Download, OperandKind, handler, operand

__all__ = ["ProgramCommands"]


class ProgramCommands(Room):
    """DL, UL, LS, XQ, HX, JP, EN, NO."""

    def burn(self, name: str) -> object | None:
        return list(self.machine.programs.program) if name == "BP" else None

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, list)
        self.machine.programs.install(saved)

    @handler("DL")
    def dl(self, args: str) -> Download:
        # (a thread that reaches DL, UL is refused before: NOT_IN_PROGRAM)
        if self.machine.programs.threads:
            raise Refused(17, "DL while a program runs")
        return DOWNLOAD

    @handler("UL")
    def ul(self, args: str) -> str:
        return "".join(line + "\r\n" for line in self.machine.programs.program) + "\x1a"

    @handler("LS")
    def ls(self, args: str) -> str:
        """``LS [n0][,n1]``: the program's lines n0 .. n1, each as ``line text``, up to and
        including the empty line after the last (the TR entry's ``LS`` shows ``3`` after a
        program of lines 0 .. 2). n0 (0 .. lines - 2, or a label) must be below n1 (1 ..
        lines - 1); a host command only (decision 0051)."""
        programs = self.machine.programs
        last = self.machine.spec.program_lines - 1
        fields = split_fields(args)
        if len(fields) > 2:
            raise Refused(6, "LS n0,n1")
        first = self._line_arg(fields[0], 0)
        end = self._line_arg(fields[1], last) if len(fields) > 1 else last
        if not 0 <= first < end <= last:
            raise Refused(6, f"LS n0 < n1, both 0 .. {last}")
        text = programs.program
        return "".join(
            f"{n} {text[n] if n < len(text) else ''}\r\n"
            for n in range(first, min(end, len(text)) + 1)
        )

    def _line_arg(self, field: str, default: int) -> int:
        f = field.strip()
        if not f:
            return default
        if f.startswith("#"):
            return self.machine.programs.line_of(f)
        n = self.machine.interp.evaluate(f)
        if n != int(n):
            raise Refused(6, "LS takes line numbers")
        return int(n)

    @handler("XQ")
    def xq(self, args: str) -> str:
        programs = self.machine.programs
        fields = split_fields(args)
        label = fields[0].strip()
        number = self._thread(fields[1]) if len(fields) > 1 and fields[1].strip() else 0
        if label and not label.startswith("#"):
            # A line number (0-based) instead of a label: "EPICS starts with XQ 0,0"
            # (galil-wave2-facts.md §5 XQ [P]). Past the program: TC 11 "Invalid label or
            # line number" (galil-protocol.md §1.2).
            line = int(self.machine.interp.evaluate(label))
            if not 0 <= line < len(programs.program):
                raise Refused(11, "no such line")
        elif label:
            line = programs.line_of(label)
        elif not programs.program:
            raise Refused(10, "no program")
        else:
            line = 0
        running = programs.threads.get(number)
        if running is not None and running is not self.machine.interp.caller:
            raise Refused(19, "thread already running")
        programs.threads[number] = Thread(number, line=line)
        return ""

    @handler("HX")
    def hx(self, args: str) -> str:
        programs = self.machine.programs
        if not args.strip():
            programs.reset()
            return ""
        programs.threads.pop(self._thread(args), None)
        return ""

    def _thread(self, text: str) -> int:
        n = int(self.machine.interp.evaluate(text))
        if not 0 <= n < self.machine.spec.threads:
            raise Refused(6, "no such thread")
        return n

    @handler("JP")
    @handler("JS")
    @handler("EN")
    @handler("ZS")
    def flow(self, args: str) -> str:
        """Flow control, which a thread runs (:meth:`~galil.sim.programs.Programs.run`); the
        interpreter refuses it from a host before it gets here (``PROGRAM_ONLY``)."""
        raise Refused(2, "flow control only in a program")

    @handler("NO")
    def no(self, args: str) -> str:
        return ""

    def _running(self, index: str) -> Thread | None:
        """The thread an operand's index names (none: thread 0), ``None`` if it is not running.

        Raises:
            Refused: TC 1, not a thread of the model.
        """
        n = int(index) if index.isdigit() else 0 if not index else -1
        if not 0 <= n < self.machine.spec.threads:
            raise Refused(1, "bad thread")
        return self.machine.programs.threads.get(n)

    @operand("XQ", kind=OperandKind.INDEX)
    def thread_line(self, index: str) -> float:
        th = self._running(index)
        return float(th.line) if th is not None else -1.0

    @operand("NO")
    def running_threads(self) -> float:
        return float(sum(1 << n for n in self.machine.programs.threads))

    @operand("ZS", kind=OperandKind.INDEX)
    def stack_depth(self, index: str) -> float:
        th = self._running(index)
        return float(len(th.stack)) if th is not None else 0.0

    @operand("JS")
    def returned(self) -> float:
        return self.machine.programs.returned

    @operand("ED", kind=OperandKind.INDEX)
    def error_line(self, index: str) -> float:
        if index not in ("", "1"):
            raise Refused(1, "_ED or _ED1")
        line, thread = self.machine.programs.error_at
        return float(thread if index == "1" else line)
