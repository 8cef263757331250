"""The library's own programs live beside the user's, never instead of it.

A controller holds one program. The library's routines (a speed schedule, the watchdog) are
kept in a block at the end of program memory, after a marker line; everything above the marker
is the user's program and is never changed. Installing a routine uploads the program, replaces
only the library block, and downloads the result (nothing is sent when it is already there).
See ``docs/decisions/0013``.

Rules, all checked before the download:
- a routine's label may not be one of the user's labels (``InvalidArgument``);
- the whole program must fit the model's line length and line count;
- no user program may be running (a download would disturb it): the caller is told which
  thread runs; the library's own threads are halted for the download and started again.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Sequence
from dataclasses import dataclass

from galil.errors import InvalidArgument
from galil.link import CommandLink
from galil.protocol import commands as cmds

__all__ = ["MARKER", "Routine", "Routines", "split_program"]

#: The line that separates the user's program (above) from the library's routines (below).
MARKER = "'galil library"
_LABEL = re.compile(r"#([A-Za-z][A-Za-z0-9]*)")
_DOWNLOAD_TIMEOUT = 10.0  # EPICS allows 10 s for a download


@dataclass(frozen=True)
class Routine:
    """A piece of program the library installs: its label line first, then its lines."""

    label: str
    lines: tuple[str, ...]

    def __post_init__(self) -> None:
        cmds.xq(self.label)  # the label rules (refused before anything is sent)
        if not self.lines or self.lines[0] != self.label:
            raise InvalidArgument(f"a routine starts with its label line {self.label!r}")


def _labels(lines: Sequence[str]) -> set[str]:
    out = set()
    for line in lines:
        m = _LABEL.match(line.strip())
        if m:
            out.add("#" + m.group(1))
    return out


def split_program(lines: Sequence[str]) -> tuple[list[str], dict[str, tuple[str, ...]]]:
    """The user's lines, and the library's routines by label, from an uploaded program."""
    if MARKER not in lines:
        return list(lines), {}
    at = list(lines).index(MARKER)
    user, library = list(lines[:at]), list(lines[at + 1 :])
    routines: dict[str, tuple[str, ...]] = {}
    current: list[str] = []
    for line in library:
        m = _LABEL.match(line.strip())
        if m and current:
            routines[current[0]] = tuple(current)
            current = []
        current.append(line)
    if current:
        routines[current[0]] = tuple(current)
    return user, routines


class Routines:
    """Installs the library's routines into program memory and runs them on threads."""

    def __init__(self, link: CommandLink) -> None:
        self.link = link
        self._threads: dict[int, str] = {}  # library thread -> label it runs
        self._lock = threading.RLock()

    def upload(self) -> list[str]:
        """The program in memory, one string per line (``UL``)."""
        text = self.link.exchange(cmds.ul(), timeout=_DOWNLOAD_TIMEOUT).text
        return [line for line in text.replace("\r\n", "\n").split("\n") if line.strip()]

    def running(self) -> dict[int, int]:
        """Running threads and the line each is on (``_XQn``), read in one round trip."""
        n = self.link.model.threads
        values = self.link.query_operands([f"_XQ{t}" for t in range(n)])
        return {t: round(v) for t, v in enumerate(values) if round(v) >= 0}

    def install(self, *routines: Routine) -> bool:
        """Put ``routines`` into the library block (replacing ones of the same label).

        Returns:
            Whether a download was needed.

        Raises:
            InvalidArgument: a label the user's program uses, a program too long for the
                model, or a user program running (the download would disturb it).
        """
        with self._lock:
            current = self.upload()
            user, library = split_program(current)
            clash = _labels(user) & {r.label for r in routines}
            if clash:
                raise InvalidArgument(
                    f"the program in memory uses the label(s) {sorted(clash)} that the library "
                    "needs; rename them in your program"
                )
            for r in routines:
                library[r.label] = r.lines
            combined = [*user, MARKER, *(line for lines in library.values() for line in lines)]
            if combined == current:
                return False
            download = self._checked(combined)
            self._download(download)
            return True

    def _checked(self, lines: list[str]) -> cmds.Command:
        model = self.link.model
        if len(lines) > model.program_lines:
            raise InvalidArgument(
                f"the program with the library's routines needs {len(lines)} lines; "
                f"{model.name} holds {model.program_lines}",
                model=model.name,
            )
        return cmds.dl(lines, model=model)

    def _download(self, download: cmds.Command, *, for_user: bool = False) -> tuple[int, ...]:
        """Download, halting the library's own threads around it; return the threads halted
        and started again."""
        running = self.running()
        users = sorted(t for t in running if t not in self._threads)
        if users:
            what = (
                "your new program cannot be downloaded without stopping it (halt it first: "
                "controller.programs.halt())"
                if for_user
                else "the library cannot add its routine without disturbing it (halt it "
                "first, or install the routine before you start your program)"
            )
            raise InvalidArgument(
                f"a program runs on thread(s) {users}; {what}", model=self.link.model.name
            )
        restart = {t: label for t, label in self._threads.items() if t in running}
        for t in restart:
            self.link.command_line([cmds.hx(t)])
        self.link.exchange(download, timeout=_DOWNLOAD_TIMEOUT)
        for t, label in restart.items():
            self.link.command_line([cmds.xq(label, t)])
        return tuple(sorted(restart))

    def replace_user(self, lines: Sequence[str]) -> tuple[bool, tuple[int, ...]]:
        """Put ``lines`` above the marker as the user's program, keeping the library's block.

        Returns:
            Whether a download was needed, and the library threads halted for it and started
            again (the watchdog, say).

        Raises:
            InvalidArgument: a label of the library's routines in ``lines``, a program too
                long with the routines, or a user program running.
        """
        with self._lock:
            current = self.upload()
            _, library = split_program(current)
            clash = _labels(lines) & set(library)
            if clash:
                raise InvalidArgument(
                    f"your program uses the label(s) {sorted(clash)} of the library's own "
                    "routines (the watchdog, a speed schedule); rename them",
                    model=self.link.model.name,
                )
            block = [line for routine in library.values() for line in routine]
            combined = [*lines, MARKER, *block] if library else list(lines)
            if combined == current:
                return False, ()
            return True, self._download(self._checked(combined), for_user=True)

    def check_free(self, thread: int, label: str) -> None:
        """Refuse a thread that does not exist or runs another program (one query).

        Raises:
            InvalidArgument: the thread does not exist or runs a program.
        """
        model = self.link.model
        if isinstance(thread, bool) or not isinstance(thread, int):
            raise InvalidArgument(f"thread must be an integer, not {thread!r}")
        if not 0 <= thread < model.threads:
            raise InvalidArgument(
                f"{model.name} has threads 0..{model.threads - 1}, not {thread}",
                model=model.name,
            )
        if thread in self.running() and self._threads.get(thread) != label:
            raise InvalidArgument(
                f"thread {thread} runs a program; choose another thread (thread=...)",
                model=model.name,
            )

    def start(self, label: str, thread: int) -> None:
        """Run the routine at ``label`` on ``thread`` (which must be free).

        Raises:
            InvalidArgument: the thread does not exist or runs a program.
        """
        with self._lock:
            self.check_free(thread, label)
            self.link.command_line([cmds.xq(label, thread)])
            self._threads[thread] = label

    def halt(self, thread: int) -> None:
        """Halt a library thread (``HX n``)."""
        with self._lock:
            self.link.command_line([cmds.hx(thread)])
            self._threads.pop(thread, None)

    @property
    def threads(self) -> dict[int, str]:
        """The threads the library runs, and the label each started at."""
        return dict(self._threads)
