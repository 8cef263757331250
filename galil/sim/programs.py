"""Programs and threads: the downloaded program, its labels, and the threads running it.

``DL`` switches a port to collecting lines until ``\\``; the program replaces the last one and
stops every thread. Each thread runs a few commands per servo sample (the firmware runs a few
per millisecond) until a command blocks it (a trippoint's :class:`~galil.sim.registry.Wait`),
it reaches ``EN`` or the end, or a command fails: a failed command halts its thread and sets
the error code; nothing is printed. ``JP`` and ``EN`` are flow control, handled here.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from galil.sim.parse import Refused, split_fields, split_program_line
from galil.sim.ports import Port
from galil.sim.registry import Collect, Download, Result, Wait

__all__ = ["LINES_PER_SAMPLE", "Executor", "Programs", "Thread"]

#: Program commands one thread may execute per servo sample (the firmware runs a few per ms).
LINES_PER_SAMPLE = 16

_LABEL = re.compile(r"#([A-Za-z][A-Za-z0-9]*)")


@dataclass(eq=False)
class Thread:
    """One program thread: where it is, and what it waits for."""

    number: int
    line: int = 0
    cmd: int = 0
    wait: Wait | None = None
    sample: int = -1
    ran: int = 0


class Executor(Protocol):
    """What a thread needs of the interpreter."""

    tc: int

    def execute(self, text: str, caller: Port | Thread | None) -> Result:
        """Run one command for ``caller``."""
        ...

    def evaluate(self, text: str) -> float:
        """Evaluate an expression."""
        ...


class Programs:
    """The program store and its threads.

    Args:
        executor: runs the threads' commands (the interpreter).
        emit: sends a thread's output as unsolicited output.
        clock: the present servo sample.
    """

    def __init__(
        self, executor: Executor, emit: Callable[[str], None], clock: Callable[[], int]
    ) -> None:
        self._x = executor
        self._emit = emit
        self._sample = clock
        self.program: list[str] = []
        self.labels: dict[str, int] = {}
        self.threads: dict[int, Thread] = {}

    def reset(self) -> None:
        """Stop every thread (the program stays)."""
        self.threads.clear()

    def line_of(self, label: str) -> int:
        """The program line of ``#label``.

        Raises:
            Refused: TC 10, no such label.
        """
        m = _LABEL.fullmatch(label.strip())
        if m is None or m.group(1) not in self.labels:
            raise Refused(10, "undefined label")
        return self.labels[m.group(1)]

    # ---- DL ----------------------------------------------------------------------------
    def collect(self, p: Port) -> bool:
        """Collect program lines from ``p`` until ``\\``; return False when more is needed."""
        assert p.download is not None
        while True:
            cut = [i for i in (p.inbuf.find("\r"), p.inbuf.find("\n")) if i >= 0]
            slash = p.inbuf.find("\\")
            if slash >= 0 and (not cut or slash < min(cut)):
                head = p.inbuf[:slash]
                if head.strip():
                    p.download.append(head)
                p.inbuf = p.inbuf[slash + 1 :]
                self._install(p.download)
                p.download = None
                p.swallow_cr = True
                p.out += b"::"
                return True
            if not cut:
                return False
            i = min(cut)
            line = p.inbuf[:i]
            p.inbuf = p.inbuf[i + 1 :]
            if line.strip():
                p.download.append(line)

    def _install(self, lines: list[str]) -> None:
        self.threads.clear()
        self.program = [ln.strip() for ln in lines]
        self.labels = {}
        for i, line in enumerate(self.program):
            m = _LABEL.match(line)
            if m and m.group(1) not in self.labels:
                self.labels[m.group(1)] = i

    # ---- threads -----------------------------------------------------------------------
    def run(self) -> bool:
        """Run every thread until it blocks or uses its budget; True if any did anything."""
        progress = False
        for th in list(self.threads.values()):
            if self._run_thread(th):
                progress = True
        return progress

    def _run_thread(self, th: Thread) -> bool:
        """Run ``th`` until it blocks or uses its budget; return True if it did anything."""
        did = False
        while True:
            if th.wait is not None:
                released = self._release(th)
                if released is None:
                    return did
                did = True
                if not released:
                    return True
            now = self._sample()
            if th.sample != now:
                th.sample, th.ran = now, 0
            if th.ran >= LINES_PER_SAMPLE:
                return did
            if th.line >= len(self.program):
                self.threads.pop(th.number, None)
                return True
            cmds = split_program_line(self.program[th.line])
            if th.cmd >= len(cmds):
                th.line, th.cmd = th.line + 1, 0
                continue
            text = cmds[th.cmd].strip()
            th.cmd += 1
            th.ran += 1
            did = True
            if not self._command(th, text):
                return True

    def _release(self, th: Thread) -> bool | None:
        """Release ``th``'s wait if it is over: None (not yet), False (halted), True."""
        assert th.wait is not None
        if not th.wait.ready(self._sample()):
            return None
        w, th.wait = th.wait, None
        if w.then is not None:
            try:
                out = w.then()
            except Refused as e:
                self._halt(th, e.code)
                return False
            if out:
                self._emit(out)
        return True

    def _command(self, th: Thread, text: str) -> bool:
        """Run one program command; return False when the thread stopped."""
        if not text or text[0] in "#'" or text.startswith(("REM", "NO")):
            return True
        try:
            if text.startswith("EN"):
                self.threads.pop(th.number, None)
                return False
            if text.startswith("JP"):
                self._jump(th, text[2:])
                return True
            result = self._x.execute(text, th)
        except Refused as e:
            self._halt(th, e.code)
            return False
        if isinstance(result, Wait):
            th.wait = result
        elif isinstance(result, (Download, Collect)):
            self._halt(th, 3)
            return False
        elif result:
            self._emit(result)
        return th.number in self.threads

    def _halt(self, th: Thread, code: int) -> None:
        self._x.tc = code
        self.threads.pop(th.number, None)

    def _jump(self, th: Thread, args: str) -> None:
        fields = split_fields(args)
        line = self.line_of(fields[0])
        if len(fields) > 2:
            raise Refused(1, "JP takes a label and one condition")
        if len(fields) == 2 and not self._x.evaluate(fields[1]):
            return
        th.line, th.cmd = line, 0
