"""Programs and threads: the user's program on the controller (``controller.programs``).

``download`` checks the whole program against the model before a byte is sent (line length,
program lines, labels, characters, quotes, no empty lines; see
:mod:`galil.protocol.programs`), then reads the program in memory (``UL``) and sends nothing
when it is already there. The library's own routines (the watchdog, speed schedules) live in a
block after a marker line (``docs/decisions/0013``); a download keeps that block and never
takes a label of it. A download stops every thread, so it is refused while a program of the
user's runs; the library's own threads are halted for it and started again, and the result
says which (``docs/decisions/0017``)::

    dmc.programs.download(\"\"\"
    #SQUARES
    i=0
    #LOOP
    sq[i]=i*i
    i=i+1
    JP #LOOP,i<10
    EN
    \"\"\")
    dmc.programs.run("#SQUARES", thread=1)
    dmc.programs.wait(1)
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from galil.codes import tc_text
from galil.errors import (
    CommandError,
    FixedAttributes,
    GalilTimeoutError,
    InvalidArgument,
    ProgramError,
    ReadOnly,
)
from galil.link import CommandLink, check_flag, check_seconds
from galil.motion import MotionTracker
from galil.protocol import commands as cmds
from galil.protocol.numbers import whole
from galil.protocol.programs import check_program, program_lines
from galil.routines import MARKER, Routines, check_user_labels, split_program
from galil.tuning import burn

__all__ = ["Download", "Programs", "check_thread_timeout"]

_LOG = logging.getLogger("galil.programs")


@dataclass(frozen=True)
class Download:
    """What :meth:`Programs.download` did.

    Attributes:
        sent: whether the program went out (``False``: it was in memory already).
        lines: lines of the user's program as stored.
        restarted: library threads (the watchdog ...) halted for the download and started
            again.
    """

    sent: bool
    lines: int
    restarted: tuple[int, ...] = ()

    def __bool__(self) -> bool:
        return self.sent


#: Read with the threads at ``run`` and at every poll of ``wait``: the line and thread of the
#: last error in a program, and the error code (the operand: reading it clears nothing).
_ERROR_OPERANDS = ("_ED", "_ED1", "_TC")
_CMDERR = re.compile(r"#CMDERR(?![A-Za-z0-9])")


@dataclass(frozen=True)
class _Mark:
    """``_ED``, ``_ED1`` and ``_TC`` at one moment."""

    line: int
    thread: int
    code: int

    @classmethod
    def of(cls, values: Sequence[float]) -> _Mark:
        return cls(round(values[0]), round(values[1]), round(values[2]))

    def failed_since(self, before: _Mark) -> bool:
        """Whether a program error came between ``before`` and now: ``_ED``/``_ED1`` moved
        to another line or thread, or, at the same one, the code cleared at ``before`` is set
        (a host's ``?`` is explained and cleared at once by the link's ``TC1``). A reset puts
        ``_ED1`` back to -1: no error."""
        if self.thread < 0:
            return False
        moved = (self.line, self.thread) != (before.line, before.thread)
        return moved or (before.code == 0 and self.code != 0)


def check_thread_timeout(timeout: object) -> float:
    """A thread wait's timeout: :func:`~galil.link.check_seconds`, a finite number of
    seconds >= 0, as every wait's; ``None`` is refused too (a thread wait has an end: the
    default is 10 s). ``Programs.wait`` and its async twin both use it.

    Raises:
        InvalidArgument: anything else, naming ``timeout``.
    """
    return check_seconds(timeout, "timeout")


#: A one-line string that looks like a path: a path separator, or a file suffix at its end
#: (``.dmc``, ``.txt``); ``_PROGRAM_TEXT`` rules out what a program line holds.
_PATHLIKE = re.compile(r"[/\\]|\.[A-Za-z][A-Za-z0-9_]*$")
_PROGRAM_TEXT = re.compile(r"^\s*[#']|[;=,\"]")


def _read_source(source: str | os.PathLike[str]) -> str:
    """The program's text: a path's file read, a one-line string naming a file read, any
    other string as it is.

    Raises:
        InvalidArgument: neither text nor a path, or a one-line string that looks like a
            path (:func:`_looks_like_path`) and names no file: a mistyped file name would
            otherwise replace the program with the path's text.
        OSError: a file that cannot be read.
    """
    if isinstance(source, os.PathLike):
        return Path(source).read_text(encoding="ascii", errors="strict")
    if not isinstance(source, str):
        raise InvalidArgument(f"a program is text or a path, not {source!r}")
    if "\n" not in source and "\r" not in source and source.strip():
        path = Path(source)
        try:
            if path.is_file():
                return path.read_text(encoding="ascii", errors="strict")
        except (OSError, ValueError):
            pass
        if _looks_like_path(source):
            raise InvalidArgument(
                f"no such file: {source!r}; to download a one-line program that reads like a "
                "path, end it with a line break"
            )
    return source


def _looks_like_path(text: str) -> bool:
    """Whether a one-line string reads as a file name rather than a program line: a path
    separator (``/``, ``\\``) or a file suffix at its end (``.dmc``, ``.txt``), and none of
    a program line's marks (a label or a comment at its start, ``;``, ``=``, ``,``, ``"``)."""
    return _PATHLIKE.search(text.strip()) is not None and not _PROGRAM_TEXT.search(text)


class Programs(FixedAttributes):
    """The user's program, its threads, and burning it to flash.

    Args:
        link: the command link.
        routines: the library's routines (their block is kept by every download).
        tracker: the motion the library started (``burn`` is refused unsent during it).
    """

    link: ReadOnly[CommandLink] = ReadOnly()
    routines: ReadOnly[Routines] = ReadOnly()

    def __init__(
        self, link: CommandLink, routines: Routines, tracker: MotionTracker | None = None
    ) -> None:
        self._link = link
        self._routines = routines
        self._tracker = tracker
        #: ``_ED``/``_ED1``/``_TC`` as each thread's run began (decision 0059).
        self._marks: dict[int, _Mark] = {}

    def __repr__(self) -> str:
        m = self.link.model
        return f"<Programs of {m.name}: {m.threads} threads, {m.program_lines} lines>"

    def download(
        self,
        source: str | os.PathLike[str],
        *,
        strip_comments: bool = False,
        pack: bool = False,
    ) -> Download:
        """Download a program (text, or the path of a file), unless it is there already.

        Args:
            source: the program text, or a path (a :class:`~pathlib.Path`, or a one-line
                string naming a file that exists). A one-line string that looks like a path
                (a ``/`` or ``\\``, or a suffix such as ``.dmc`` at its end, and no label,
                ``;``, ``=``, ``,`` or ``"``) but names no file is refused: a mistyped file
                name never replaces the program.
            strip_comments: drop comments and the lines they leave empty (program memory is
                scarce; comments take it too).
            pack: join lines into compound lines up to the model's line length.

        Returns:
            What was done (:class:`Download`; true when the program went out).

        Raises:
            InvalidArgument: a line or the program breaks a rule of the model (nothing is
                sent), a label of the library's routines (:data:`galil.routines.RESERVED`
                always, before anything is sent; those of a speed schedule's routine in
                memory), a program of the user's running, or a file that does not exist.
        """
        check_flag(strip_comments, "strip_comments")
        check_flag(pack, "pack")
        model = self.link.model
        try:
            text = _read_source(source)
        except (OSError, UnicodeError) as exc:
            raise InvalidArgument(f"cannot read the program {source!r}: {exc}") from exc
        lines = program_lines(
            text, strip_comments=strip_comments, pack=model.line_length if pack else None
        )
        check_program(lines, model)
        check_user_labels(line.text for line in lines)  # (before the UL: nothing is sent)
        for line in lines:
            if line.text == MARKER:
                raise InvalidArgument(
                    f"program line {line.source}: {MARKER!r} marks the library's routines; "
                    "use another comment"
                )
        stored = [line.text for line in lines]
        sent, restarted = self.routines.replace_user(stored)
        if restarted:
            _LOG.warning(
                "galil: library thread(s) %s halted for the program download and started again",
                list(restarted),
            )
        return Download(sent, len(stored), restarted)

    def upload(self) -> str:
        """The user's program in memory (``UL``), without the library's routines."""
        user, _ = split_program(self.routines.upload())
        return "\n".join(user)

    def _thread(self, thread: object) -> int:
        n = self.link.model.threads
        t = whole(thread)
        if t is None or not 0 <= t < n:
            raise InvalidArgument(
                f"{self.link.model.name} has threads 0..{n - 1}, not {thread!r}",
                model=self.link.model.name,
            )
        label = self.routines.holder(t)
        if label is not None:
            raise InvalidArgument(
                f"thread {t} runs the library's {label} (a library routine: the watchdog, a "
                "speed schedule or an input wait); stop that through the library",
                model=self.link.model.name,
            )
        return t

    def run(self, label: str = "#A", thread: int = 0) -> None:
        """Run the program from ``label`` on ``thread`` (``XQ``). Where the last program
        error was (``_ED``, ``_ED1``) is read with the threads, so that :meth:`wait` can tell
        an end on an error from one at ``EN``; an error code no one has read (``_TC``) is
        cleared (``TC0``) on the same line as the ``XQ`` (decision 0059).

        Raises:
            InvalidArgument: a bad label or thread, a thread that runs a program already or
                one the library uses.
            CommandError: the controller refused (TC 10: no such label).
        """
        command = cmds.xq(label, self._thread(thread))
        running, values = self.routines.running_and(_ERROR_OPERANDS)
        if thread in running and thread not in self.routines.threads:
            raise InvalidArgument(
                f"thread {thread} runs a program already; halt it first or pick another",
                model=self.link.model.name,
            )
        mark = _Mark.of(values)
        self._marks.pop(thread, None)
        self.link.command_line([cmds.tc(0), command] if mark.code else [command])
        self._marks[thread] = _Mark(mark.line, mark.thread, 0)

    def halt(self, thread: int | None = None) -> None:
        """Halt ``thread`` (``HX n``), or every thread of the user's (``None``); the library's
        own threads (the watchdog) keep running."""
        if thread is not None:
            self.link.command_line([cmds.hx(self._thread(thread))])
            self._marks.pop(thread, None)
            return
        busy = sorted(self.threads)
        if busy:
            self.link.command_line([cmds.hx(t) for t in busy])
        for t in busy:
            self._marks.pop(t, None)

    @property
    def threads(self) -> dict[int, int]:
        """The user's running threads and the line each is on (``_XQn``); the library's own
        threads are left out. One round trip."""
        running = self.routines.running()  # (forgets the library's runs that ended)
        return {t: line for t, line in running.items() if t not in self.routines.threads}

    def wait(self, thread: int = 0, timeout: float = 10.0) -> None:
        """Wait until ``thread`` has finished (its ``_XQn`` reads -1), in controller time,
        and say whether it ended on an error (decision 0059).

        An error is seen when ``_ED``/``_ED1`` (the line and thread of the last program
        error) moved since :meth:`run` started the thread (since this wait began, for a
        thread started otherwise), or the error code cleared at :meth:`run` is set again.
        An end at ``EN``, a halt (``HX``, :meth:`halt`, ``AB``) and a reset are no error; a
        program with ``#CMDERR`` handles its errors itself, and its threads never raise.
        The error is said once: a second wait on the thread returns.

        Raises:
            InvalidArgument: a bad thread or timeout.
            GalilTimeoutError: it still runs after ``timeout`` seconds (it is not halted).
            ProgramError: it stopped on an error: of its own, or of another thread (which
                stops every thread); code, line, and the line's text (``UL``). Motion the
                program started is left as the controller leaves it.
        """
        n = self._thread(thread)
        timeout = check_thread_timeout(timeout)
        link = self.link
        deadline = link.clock() + timeout
        names = [f"_XQ{n}", *_ERROR_OPERANDS]
        while True:
            values = link.query_operands(names)
            if round(values[0]) < 0:
                break
            self._marks.setdefault(n, _Mark.of(values[1:]))
            if link.clock() >= deadline:
                raise link.error(GalilTimeoutError, f"thread {n} still runs after {timeout} s")
            link.pause(0.01)
        before = self._marks.pop(n, None)
        now = _Mark.of(values[1:])
        if before is not None and now.failed_since(before):
            error = self._error(n, now)
            if error is not None:
                raise error

    def _error(self, waited: int, now: _Mark) -> ProgramError | None:
        """The error of a program that stopped at ``now``'s line; ``None`` when the program
        has ``#CMDERR`` (it handled the error). One ``UL`` for the line's text."""
        try:
            program = self.routines.upload()
        except CommandError:  # (a locked program: TC 106)
            program = []
        if any(_CMDERR.match(line.strip()) for line in program):
            return None
        text = program[now.line].strip() if 0 <= now.line < len(program) else ""
        code = now.code or None
        return ProgramError(
            code,
            tc_text(code) if code is not None else "",
            text,
            line=now.line,
            thread=now.thread,
            waited=waited,
            model=self.link.model.name,
            recent=self.link.recent,
        )

    def burn(self, timeout: float | None = None) -> None:
        """Burn the program into flash (``BP``), the library's routines with it; it then
        survives a power cycle. Slow: the model's ``burn_timeout`` is allowed. The same as
        ``controller.save_program()``. The controller refuses ``BP`` while a program runs
        (TC 17): the library's own threads (the watchdog, a wait for an input) are halted for
        the burn and started again, as for :meth:`download` (decision 0087); a program of
        the user's, or a speed schedule, running is refused unsent
        (:class:`~galil.errors.InvalidArgument`). So is a motion the library started (the
        controller's TC 7 otherwise)."""
        burn(self.link, "BP", timeout, self._tracker, self.routines)
