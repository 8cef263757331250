"""Programs and threads: the downloaded program, its labels, and the threads running it.

``DL`` switches a port to collecting lines until ``\\``; the program replaces the last one and
stops every thread. Each thread runs a few commands per servo sample (the firmware runs a few
per millisecond) until a command blocks it (a trippoint's :class:`~galil.sim.registry.Wait`),
it reaches ``EN`` or the end, or a command fails: a failed command halts its thread and sets
the error code; nothing is printed. ``JP``, ``JS``, ``EN`` and ``ZS`` are flow control, handled
here, as is the subroutine stack that ``JS`` and the automatic subroutines share.

An automatic subroutine (``#LIMSWI``, ``#POSERR``, ``#ININT``, ``#MCTIME``, ``#CMDERR``) runs on
thread 0 (:meth:`Programs.interrupt`): a running thread 0 is interrupted (where it was, and
the trippoint it waited for, go on its stack), an idle one is started. One runs at a time; one
due meanwhile waits for the running one to return. ``EN n``, ``RE n`` and ``RI n`` return,
restoring the interrupted trippoint when ``n`` is 1 and dropping it otherwise (decision 0029).
An error in a program runs ``#CMDERR`` when the program has it: the failing thread stops
(thread 0 goes on after the failed command once the routine returns); without it, every
thread stops (decision 0059). ``_ED``/``_ED1`` keep the line and thread of the last error.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from galil.sim.parse import Refused, internal_error, split_fields, split_program_line
from galil.sim.ports import Port
from galil.sim.registry import Collect, Download, Result, Wait

__all__ = [
    "DOWNLOAD_ERROR",
    "LINES_PER_SAMPLE",
    "NOT_IN_PROGRAM",
    "NO_ERROR",
    "PROGRAM_ONLY",
    "STACK_DEPTH",
    "Executor",
    "Frame",
    "Memory",
    "Programs",
    "Thread",
    "program_only",
]

#: ``_ED`` and ``_ED1`` before any error in a program (and after a reset).
NO_ERROR = (0, -1)
#: Program commands one thread may execute per servo sample (the firmware runs a few per ms).
LINES_PER_SAMPLE = 16
#: How deep subroutine calls nest (JS: "can be nested, called up to 16 deep").
STACK_DEPTH = 16

_LABEL = re.compile(r"#([A-Za-z][A-Za-z0-9]*)")
#: ``IF (condition)``, ``ELSE``, ``ENDIF``: the words of a conditional (``IFa=1`` is an
#: assignment, so IF needs a blank or a parenthesis after it).
_BRANCH = re.compile(r"(?:(IF)(?=[\s(])|(ELSE|ENDIF)\s*$)")

#: The commands the simulator runs that the DMC-4103 command reference marks "Not Valid in
#: terminal" (its usage line), in one place: from a host port each answers ``?`` with TC 2
#: ("Command only valid from program"); a thread runs them (decision 0037).
#: AM, MC and WT are among them (decision 0044): a host waits for motion by polling ``_BGm``.
PROGRAM_ONLY = frozenset(
    {
        *("AD", "AI", "AM", "AP", "AR", "AS", "AT", "AV", "EN", "JP", "JS", "MC", "MF", "MR"),
        *("RE", "RI", "WT", "ZS", "IF", "ELSE", "ENDIF"),
    }
)
#: The commands the simulator runs that the same reference marks "Not Valid in program", in
#: one place: a program thread that reaches one stops with TC 3 ("Command not valid in
#: program"), ``_ED`` its line, as for any program error; from a host they run. A download
#: stores such a line as any other (DL: "Instructions in the file will be accepted as a data
#: stream"); the refusal comes when a thread reaches it (decision 0047).
NOT_IN_PROGRAM = frozenset({"DL", "LS", "QD", "RS", "UL", "WH", "\x12\x13", "\x12\x16"})


def program_only(text: str) -> str | None:
    """The program-only command ``text`` starts with (see :data:`PROGRAM_ONLY`): ``"IF"``,
    ``"ELSE"``, ``"ENDIF"``, or ``None`` for any other text. Two-letter commands are found by
    the interpreter once it knows the text is not an assignment."""
    m = _BRANCH.match(text)
    return None if m is None else m.group(m.lastindex or 0)


@dataclass(eq=False)
class Frame:
    """Where a subroutine returns to.

    Attributes:
        line: the line to go on at.
        cmd: the command of that line.
        wait: the trippoint an automatic subroutine interrupted (restored by ``RE 1``).
        routine: the automatic subroutine this call runs (``"LIMSWI"``), ``None`` for ``JS``.
        ends: the thread was started for the routine: returning ends it.
    """

    line: int
    cmd: int
    wait: Wait | None = None
    routine: str | None = None
    ends: bool = False


@dataclass(eq=False)
class Thread:
    """One program thread: where it is, what it waits for, and its subroutine stack."""

    number: int
    line: int = 0
    cmd: int = 0
    wait: Wait | None = None
    sample: int = -1
    ran: int = 0
    stack: list[Frame] = field(default_factory=list)
    #: IFs entered and not yet left by their ENDIF.
    ifs: int = 0
    #: The reference sample of ``AT`` (``AT 0`` sets it; 0, the last reset, until then).
    at: int = 0

    def in_routine(self) -> bool:
        """Whether the thread runs an automatic subroutine."""
        return any(f.routine is not None for f in self.stack)


class Executor(Protocol):
    """What a thread needs of the interpreter."""

    tc: int

    def execute(self, text: str, caller: Port | Thread | None) -> Result:
        """Run one command for ``caller``."""
        ...

    def evaluate(self, text: str) -> float:
        """Evaluate an expression."""
        ...


class Memory(Protocol):
    """What a program memory holds (a :class:`~galil.models.ModelSpec` says it)."""

    @property
    def program_lines(self) -> int:
        """Lines of program memory."""
        ...

    @property
    def line_length(self) -> int:
        """Characters of the longest line."""
        ...


@dataclass(frozen=True)
class _Memory:
    program_lines: int = 2000
    line_length: int = 80


#: What ends a download: "terminate with ``\\`` (also ^Z, ^Q, ^D accepted)"
#: (galil-wave2-facts.md §5 DL [P: EPICS, BLISS, IRTF]).
_DL_ENDS = ("\\", "\x1a", "\x11", "\x04")

#: TC 60: "Download error - line too long or too many lines" (galil.codes).
DOWNLOAD_ERROR = 60


class Programs:
    """The program store and its threads.

    Args:
        executor: runs the threads' commands (the interpreter).
        emit: sends a thread's output as unsolicited output.
        clock: the present servo sample.
        memory: the program memory's size: lines, and characters a line (the model's).
    """

    def __init__(
        self,
        executor: Executor,
        emit: Callable[[str], None],
        clock: Callable[[], int],
        *,
        memory: Memory | None = None,
    ) -> None:
        self._x = executor
        self._emit = emit
        self._sample = clock
        self._memory: Memory = _Memory() if memory is None else memory
        self.program: list[str] = []
        self.labels: dict[str, int] = {}
        self.threads: dict[int, Thread] = {}
        #: Automatic subroutines due while another one runs, in the order they came.
        self.pending: list[str] = []
        #: What the last subroutine returned (``EN ,,value``; ``_JS``).
        self.returned = 0.0
        #: The line and thread of the last error in a program (``_ED``, ``_ED1``); ED: "_ED0
        #: returns 0 if no error has occurred", "_ED1 returns -1 if no error has occurred".
        self.error_at = NO_ERROR

    def reset(self) -> None:
        """Stop every thread (the program stays)."""
        self.threads.clear()
        self.pending.clear()

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
        """Collect program lines from ``p`` until ``\\`` (or ^Z, ^Q, ^D); return False when
        more is needed.

        A line longer than the model's line length, or one more than its program memory
        holds, is refused as the controller refuses it: ``?`` at once and TC 60 ("Download
        error - line too long or too many lines"; galil-protocol.md: "a rejected line
        produces ``?``", before the ``\\``). The rest of the download is dropped, the
        ``\\`` ends it with ``:`` (two terminators in all, as a download's ``::``) and the
        program in memory stays as it was. [UNVERIFIED: what follows the ``?`` on hardware,
        and whether a refused download leaves the old program.]
        """
        assert p.download is not None
        while True:
            cut = [i for i in (p.inbuf.find("\r"), p.inbuf.find("\n")) if i >= 0]
            ends = [i for i in map(p.inbuf.find, _DL_ENDS) if i >= 0]
            slash = min(ends) if ends else -1
            if slash >= 0 and (not cut or slash < min(cut)):
                head = p.inbuf[:slash]
                if head.strip():
                    self._take(p, head)
                p.inbuf = p.inbuf[slash + 1 :]
                if p.download_refused:
                    p.out += b":"
                else:
                    self.install(p.download)
                    p.out += b"::"
                p.download = None
                p.download_refused = False
                p.swallow_cr = True
                return True
            if not cut:
                return False
            i = min(cut)
            line = p.inbuf[:i]
            p.inbuf = p.inbuf[i + 1 :]
            if line.strip():
                self._take(p, line)

    def _take(self, p: Port, line: str) -> None:
        """One downloaded line: kept, or refused (TC 60) when it does not fit."""
        assert p.download is not None
        if p.download_refused:
            return
        memory = self._memory
        if len(line) > memory.line_length or len(p.download) >= memory.program_lines:
            self._x.tc = DOWNLOAD_ERROR
            p.out += b"?"
            p.download_refused = True
            return
        p.download.append(line)

    def install(self, lines: list[str]) -> None:
        """Make ``lines`` the program (the threads stop): a download, or the burned program
        at ``RS``."""
        self.reset()
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
            except Exception:
                self._halt(th, internal_error("a held program command").code)
                return False
            if out:
                self._emit(out)
        return True

    def _command(self, th: Thread, text: str) -> bool:
        """Run one program command; return False when the thread stopped."""
        if not text or text[0] in "#'" or text.startswith("NO"):
            return True
        try:
            flow = self._flow(th, text)
            if flow is not None:
                return flow
            result = self._x.execute(text, th)
        except Refused as e:
            self._halt(th, e.code)
            return False
        except Exception:  # a simulator bug: halt the thread as a refused command does
            self._halt(th, internal_error(text).code)
            return False
        # (DL and QD, which switch a port to collecting, never run here: NOT_IN_PROGRAM)
        assert not isinstance(result, (Download, Collect)), text
        if isinstance(result, Wait):
            th.wait = result
        elif result:
            self._emit(result)
        return th.number in self.threads

    def _flow(self, th: Thread, text: str) -> bool | None:
        """Run ``text`` if it is flow control (JP JS EN ZS IF ELSE ENDIF): whether the thread
        goes on; ``None`` for any other command."""
        word = program_only(text)
        code = text[:2]
        if word is not None:
            self._branch(th, word, text)
        elif code == "JP":
            self._jump(th, text[2:])
        elif code == "JS":
            self._call(th, text[2:])
        elif code == "EN":
            return self._end(th, text[2:])
        elif code == "ZS":
            self._zero_stack(th, text[2:])
        else:
            return None
        return True

    def _halt(self, th: Thread, code: int) -> None:
        """A command of ``th`` failed: set the error code and ``_ED``; run #CMDERR (the
        failing thread stops, thread 0 goes on after it), or, without one, stop every thread
        (#CMDERR: "Without #CMDERR defined, if an error ... occurs in an application program
        ..., the program (and all threads) will stop")."""
        self._x.tc = code
        self.error_at = (th.line, th.number)
        if "CMDERR" not in self.labels:
            self.reset()
            return
        handled = not any(f.routine == "CMDERR" for t in self.threads.values() for f in t.stack)
        if not handled or th.number != 0:  # (an error in #CMDERR stops its thread only)
            self.threads.pop(th.number, None)
        if handled:
            self.interrupt("CMDERR")

    def _jump(self, th: Thread, args: str) -> None:
        line = self._target(args)
        if line is not None:
            th.line, th.cmd = line, 0

    def _target(self, args: str) -> int | None:
        """The line of ``#label[,condition]``; ``None`` when the condition is false."""
        fields = split_fields(args)
        line = self.line_of(fields[0])
        if len(fields) > 2:
            raise Refused(1, "a jump takes a label and one condition")
        if len(fields) == 2 and not self._condition(fields[1]):
            return None
        return line

    def _condition(self, text: str) -> bool:
        """A condition of JP, JS or IF: true when its expression is not zero (``&`` and
        ``|`` combine conditions bitwise, left to right, as in any expression)."""
        return self._x.evaluate(text) != 0

    # ---- IF / ELSE / ENDIF -------------------------------------------------------------
    def _branch(self, th: Thread, word: str, text: str) -> None:
        """``IF (condition)``: go on, or skip to its ELSE or ENDIF; ``ELSE`` reached from
        the true part: skip to the ENDIF; ``ENDIF``: leave the IF.

        Raises:
            Refused: TC 63 for an IF without ENDIF, or an ELSE/ENDIF without an IF.
        """
        if word == "IF":
            # (true: in its first part; false: in its ELSE part, or past its ENDIF)
            if self._condition(text[2:]) or self._skip(th, to_else=True):
                th.ifs += 1
        elif th.ifs == 0:
            raise Refused(63, f"{word} without IF")
        elif word == "ELSE":
            self._skip(th, to_else=False)
            th.ifs -= 1
        else:
            th.ifs -= 1

    def _skip(self, th: Thread, to_else: bool) -> bool:
        """Move ``th`` past the ENDIF (or, with ``to_else``, the ELSE) that belongs to the
        IF it is in, skipping nested IFs; True if it stopped after an ELSE.

        Raises:
            Refused: TC 63, the program ends first (``th`` has not moved).
        """
        depth = 0
        line, cmd = th.line, th.cmd
        while line < len(self.program):
            cmds = split_program_line(self.program[line])
            while cmd < len(cmds):
                word = program_only(cmds[cmd].strip())
                cmd += 1
                if word == "IF":
                    depth += 1
                elif word == "ENDIF" and depth > 0:
                    depth -= 1
                elif word == "ENDIF" or (word == "ELSE" and depth == 0 and to_else):
                    th.line, th.cmd = line, cmd
                    return word == "ELSE"
            line, cmd = line + 1, 0
        raise Refused(63, "IF without ENDIF")

    def _call(self, th: Thread, args: str) -> None:
        if "(" in split_fields(args)[0]:
            raise Refused(1, "JS arguments are not simulated")
        line = self._target(args)
        if line is None:
            return
        if len(th.stack) >= STACK_DEPTH:
            raise Refused(1, "subroutines nested too deep")
        th.stack.append(Frame(th.line, th.cmd))
        th.line, th.cmd = line, 0

    def _end(self, th: Thread, args: str) -> bool:
        """``EN [restore][,,value]``: return from a subroutine, or end the thread."""
        fields = split_fields(args) if args.strip() else []
        restore = bool(fields) and fields[0].strip() != "" and self._x.evaluate(fields[0]) == 1
        if len(fields) > 2 and fields[2].strip():
            self.returned = self._x.evaluate(fields[2])
        if th.stack:
            self.return_from(th, restore)
            return th.number in self.threads
        self.threads.pop(th.number, None)
        self._start_pending()
        return False

    def _zero_stack(self, th: Thread, args: str) -> None:
        n = self._x.evaluate(args) if args.strip() else 0
        if n not in (0, 1):
            raise Refused(6, "ZS takes 0 or 1")
        if n == 0:
            th.stack.clear()
        elif th.stack:
            th.stack.pop()
        self._start_pending()

    # ---- subroutines -------------------------------------------------------------------
    def return_from(self, th: Thread, restore: bool) -> None:
        """Return ``th`` from its subroutine (``EN``, ``RE``, ``RI``); with ``restore``, the
        trippoint an automatic subroutine interrupted is waited for again. With an empty
        stack the thread ends."""
        if not th.stack:
            self.threads.pop(th.number, None)
        else:
            frame = th.stack.pop()
            if frame.ends:
                self.threads.pop(th.number, None)
            else:
                th.line, th.cmd = frame.line, frame.cmd
                th.wait = frame.wait if restore else None
        self._start_pending()

    def interrupt(self, label: str) -> None:
        """Run the automatic subroutine ``#label`` on thread 0 when the program has it: now,
        or once the one running has returned."""
        if label in self.labels and label not in self.pending:
            self.pending.append(label)
            self._start_pending()

    def _start_pending(self) -> None:
        th = self.threads.get(0)
        if not self.pending or (th is not None and th.in_routine()):
            return
        label = self.pending.pop(0)
        line = self.labels.get(label)
        if line is None:
            return
        if th is None:
            th = self.threads[0] = Thread(0, stack=[Frame(0, 0, routine=label, ends=True)])
        else:
            th.stack.append(Frame(th.line, th.cmd, th.wait, routine=label))
            th.wait = None
        th.line, th.cmd = line, 0
