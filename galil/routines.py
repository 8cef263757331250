"""The library's own programs live beside the user's, never instead of it.

A controller holds one program. The library's routines (a speed schedule, the watchdog) are
kept in a block at the end of program memory, after a marker line; everything above the marker
is the user's program and is never changed. Installing a routine uploads the program, replaces
only the library block, and downloads the result (nothing is sent when it is already there).
See ``docs/decisions/0013``.

A routine is its label line, its lines, and ``EN`` last; it may hold inner labels (a loop),
but only its first label may follow an ``EN`` line: that is how the routines in memory are told
apart (a routine starts at the first line of the block, or at a label right after an ``EN``).
A routine owns all its labels: installing it again replaces the whole routine.

Rules, all checked before the download:
- none of a routine's labels (inner ones included) may be one of the user's labels, or a label
  of another of the library's routines (``InvalidArgument``);
- the labels of the library's own routines (:data:`RESERVED`: the watchdog's, the input
  wait's, a speed schedule's default) belong to them: a routine of another kind may not take
  one (``Routine`` refuses it), nor may a program of the user's (:func:`check_user_labels`);
- the whole program must fit the model's line length and line count;
- no user program may be running (a download would disturb it): the caller is told which
  thread runs (:class:`ProgramRunning`); the library's own threads are halted for the
  download and started again, whatever came of it, as for a burn (:meth:`Routines.paused`;
  decision 0094): a thread whose ``XQ`` the controller refused is forgotten and said in a
  WARNING.

Two of the library's features of one session never take the same thread by default
(:meth:`Routines.default_thread`: the last thread that runs neither a program of the user's
nor another of this session's routines), and a thread one of them runs on is refused to the
other with the feature named (decision 0086).
"""

from __future__ import annotations

import contextlib
import logging
import re
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import TypeVar

from galil.errors import CommandError, GalilConnectionError, GalilError, InvalidArgument
from galil.link import RECONNECT_ADVICE, CommandLink
from galil.models import ModelSpec
from galil.protocol import commands as cmds
from galil.protocol.numbers import whole

__all__ = [
    "INPUT_MESSAGE",
    "MARKER",
    "RESERVED",
    "WATCHDOG_FIRED",
    "ProgramRunning",
    "Routine",
    "Routines",
    "check_user_labels",
    "is_library_line",
    "split_program",
    "ul_reply_bytes",
]

#: The line that separates the user's program (above) from the library's routines (below).
MARKER = "'galil library"

#: The variable the watchdog's routine sets to 1 once it stopped the axes (:mod:`galil.watchdog`):
#: a contour the controller stopped reads it to say why (decision 0100).
WATCHDOG_FIRED = "gwfire"

#: The labels of the library's own routines (first and inner ones), each with the routine it
#: belongs to. A routine of another kind may not take one (a speed schedule's ``label=``
#: would replace the watchdog's code), and a program of the user's may not use one.
RESERVED: Mapping[str, str] = MappingProxyType(
    {
        "#GWDOG": "the watchdog",
        "#GWDOGL": "the watchdog",
        "#GINWAIT": "wait_for_input",
        "#GINLOOP": "wait_for_input",
        "#GSCHED": "a speed schedule",
    }
)
#: What the input wait's routine prints when its input is at the level (``galil-input  3``):
#: a line for the library, kept out of the user's messages (:func:`is_library_line`).
INPUT_MESSAGE = "galil-input"
_LIBRARY_LINE = re.compile(rf"{INPUT_MESSAGE} +[0-9]+")
_LABEL = re.compile(r"#([A-Za-z][A-Za-z0-9]*)")
_T = TypeVar("_T")
_END = re.compile(r"EN\b")
_LOG = logging.getLogger("galil.routines")


def ul_reply_bytes(model: ModelSpec) -> int:
    """The most bytes ``UL``'s reply can hold: a full program memory (the model's program
    lines, each as long as a line can be, with CR LF), then ^Z and ``:``."""
    return model.program_lines * (model.line_length + 2) + 2


class ProgramRunning(InvalidArgument):
    """A routine could not be installed: a program runs, and the download it needs would
    disturb it (a caller that can do without the routine, a wait for an input, polls
    instead)."""


def is_library_line(line: str) -> bool:
    """Whether ``line`` (an unsolicited line) is one the library's routines print for the
    library itself: the input wait's ``galil-input n``. The watchdog's ``galil watchdog:
    motion stopped`` is the user's to read, and is not one (decision 0086)."""
    return _LIBRARY_LINE.fullmatch(line.strip()) is not None


def ls_reply_bytes(model: ModelSpec) -> int:
    """The most bytes ``LS``'s reply can hold: a full program memory, each line numbered
    (``1999 `` before its text) and ended with CR LF, then ``:``."""
    number = len(str(model.program_lines - 1)) + 1
    return model.program_lines * (number + model.line_length + 2) + 1


def _first(exc: BaseException) -> str:
    """The first line of ``exc``'s text (a ``GalilError``'s recent exchanges left out)."""
    text = str(exc).splitlines()
    return text[0] if text else type(exc).__name__


def _label_of(line: str) -> str | None:
    m = _LABEL.match(line.strip())
    return None if m is None else "#" + m.group(1)


def _is_end(line: str) -> bool:
    return _END.match(line.strip()) is not None


@dataclass(frozen=True)
class Routine:
    """A piece of program the library installs: its label line first, its lines, ``EN``
    last. Inner labels are allowed, never right after an ``EN`` (there a routine starts).

    Attributes:
        kind: what the routine is (``"the watchdog"``, ``"a speed schedule"``): it may take
            the :data:`RESERVED` labels of its own kind only.

    Raises:
        InvalidArgument: a bad label, lines that do not start with it or end with ``EN``, an
            inner label right after an ``EN``, a label twice, or a label reserved for a
            routine of another kind.
    """

    label: str
    lines: tuple[str, ...]
    kind: str = ""

    def __post_init__(self) -> None:
        cmds.xq(self.label)  # the label rules (refused before anything is sent)
        for label in sorted(_labels(self.lines) | {self.label}):
            owner = RESERVED.get(label)
            if owner is not None and owner != self.kind:
                raise InvalidArgument(
                    f"{label} is the label of {owner}'s routine, reserved by the library; "
                    f"choose another label for {self.kind or 'this routine'}"
                )
        if not self.lines or self.lines[0] != self.label:
            raise InvalidArgument(f"a routine starts with its label line {self.label!r}")
        if not _is_end(self.lines[-1]):
            raise InvalidArgument(f"routine {self.label} must end with EN")
        seen: set[str] = set()
        for before, line in zip(self.lines, self.lines[1:], strict=False):
            inner = _label_of(line)
            if inner is not None and _is_end(before):
                raise InvalidArgument(
                    f"routine {self.label}: label {inner} right after an EN would read as "
                    "another routine's start"
                )
            if inner is not None and (inner in seen or inner == self.label):
                raise InvalidArgument(f"routine {self.label} holds label {inner} twice")
            if inner is not None:
                seen.add(inner)

    @property
    def labels(self) -> frozenset[str]:
        """Every label of the routine, its first one and the inner ones."""
        return frozenset(_labels(self.lines))


def _labels(lines: Iterable[str]) -> set[str]:
    return {label for line in lines if (label := _label_of(line)) is not None}


def check_user_labels(lines: Iterable[str]) -> None:
    """Refuse a program of the user's that uses a label of the library's own routines
    (:data:`RESERVED`), whether or not the routine is in memory now: it would clash the day
    the library installs it.

    Raises:
        InvalidArgument: such a label, named with the routine it belongs to.
    """
    taken = sorted(_labels(lines) & RESERVED.keys())
    if taken:
        whose = ", ".join(f"{label} ({RESERVED[label]})" for label in taken)
        raise InvalidArgument(
            f"your program uses the label(s) {whose} that the library reserves for its own "
            "routines; rename them"
        )


def routine_at(lines: Sequence[str], line: int) -> str | None:
    """The first label of the library's routine that holds program line ``line`` (``_XQn``,
    from 0) of the program ``lines`` (as uploaded: the controller keeps no empty line, so
    they are numbered as it numbers them); ``None`` for a line of the user's."""
    if MARKER not in lines:
        return None
    at = list(lines).index(MARKER)
    if not at < line < len(lines):
        return None
    current: str | None = None
    for i in range(at + 1, line + 1):
        label = _label_of(lines[i])
        if current is None or (label is not None and _is_end(lines[i - 1])):
            current = label
    return current


def split_program(lines: Sequence[str]) -> tuple[list[str], dict[str, tuple[str, ...]]]:
    """The user's lines, and the library's routines by their first label, from an uploaded
    program. A routine starts at the block's first line or at a label right after an ``EN``
    line, and runs to the next routine's start: its inner labels stay in it."""
    if MARKER not in lines:
        return list(lines), {}
    at = list(lines).index(MARKER)
    user, library = list(lines[:at]), list(lines[at + 1 :])
    routines: dict[str, tuple[str, ...]] = {}
    current: list[str] = []
    for line in library:
        if current and _label_of(line) is not None and _is_end(current[-1]):
            _keep(routines, current)
            current = []
        current.append(line)
    if current:
        _keep(routines, current)
    return user, routines


def _keep(routines: dict[str, tuple[str, ...]], lines: list[str]) -> None:
    # A second block under the same first label (left by an older version) joins the first:
    # both go when the routine is installed again.
    routines[lines[0]] = routines.get(lines[0], ()) + tuple(lines)


def _merge(library: dict[str, tuple[str, ...]], routines: Sequence[Routine]) -> None:
    """Put ``routines`` into ``library`` in place of the ones of the same first label, and
    drop stale blocks of their inner labels.

    Raises:
        InvalidArgument: a label shared with another routine (installed or given).
    """
    owners: dict[str, str] = {}
    for r in routines:
        for label in r.labels:
            if owners.setdefault(label, r.label) != r.label:
                raise InvalidArgument(f"routines {owners[label]} and {r.label} share {label}")
    for r in routines:
        for key, lines in list(library.items()):
            if key == r.label:
                continue
            shared = _labels(lines) & r.labels
            if shared and key in r.labels and _labels(lines) <= r.labels:
                del library[key]  # an inner block split off by an older version: stale
            elif shared:
                raise InvalidArgument(
                    f"the library's routine {key} uses the label(s) {sorted(shared)} of "
                    f"routine {r.label}"
                )
        library[r.label] = r.lines


def _threads_named(running: Mapping[int, int], library: Mapping[int, str]) -> str:
    """``thread 7 (the library's #GWDOG: the watchdog), thread 1``: running threads, the
    library's routines named."""
    named = []
    for t in sorted(running):
        label = library.get(t)
        whose = RESERVED.get(label, "a routine of the library's") if label else ""
        named.append(f"thread {t} (the library's {label}: {whose})" if label else f"thread {t}")
    return ", ".join(named) + (" is" if len(named) == 1 else " are")


def _say_not_restarted(
    thread: int, label: str, what: str, why: str, *, held: bool, fate: str = ""
) -> None:
    """A WARNING: the library's ``thread`` (running ``label``), halted for ``what``, was not
    started again, ``why``; whether the library still holds it (``held``: the ``XQ`` may have
    gone out, or goes out once the link is reopened: ``fate``) or forgot it."""
    whose = RESERVED.get(label, "a routine of the library's")
    if held:
        fate = fate or "the library still holds it"
    else:
        fate = "it no longer runs, and the library no longer holds it"
        if whose == "the watchdog":
            fate += " (nothing guards the motion: start a new watchdog)"
    _LOG.warning(
        "galil: the library's thread %d (%s: %s), halted for %s, was not started again: %s; %s",
        thread,
        label,
        whose,
        what,
        why,
        fate,
    )


class _Restarts:
    """The restarts of the library's threads halted for a download or a burn (decision 0094):
    :class:`Routines`' threads (the same dict), the commands sent before each routine's
    ``XQ``, and the threads whose ``XQ`` a dead link kept from going out. Used under
    :class:`Routines`' lock."""

    def __init__(self, link: CommandLink, threads: dict[int, str]) -> None:
        self.link = link
        self.threads = threads  # (Routines' own: library thread -> label it runs)
        self.preludes: dict[str, tuple[cmds.Command, ...]] = {}  # label -> sent before its XQ
        self.unsent: dict[int, str] = {}  # halted, XQ not sent (link dead): restart on reopen

    def xq_again(self, label: str, thread: int) -> None:
        """``XQ label,thread`` after a halt, behind the routine's :meth:`Routines.restart_with`
        commands on the same line."""
        self.link.command_line([*self.preludes.get(label, ()), cmds.xq(label, thread)])

    def restart(self, threads: Mapping[int, str], what: str, *, failed: bool) -> None:
        """``XQ`` each of the library's ``threads``, halted for ``what``, again.

        A thread whose ``XQ`` the controller refused runs nothing: the library forgets it and
        tries the next. One whose ``XQ``'s fate is unknown (the link died under it, a Ctrl-C)
        stays the library's, as :meth:`Routines.start` keeps it (decision 0076), and the
        threads not tried yet are forgotten (halted, never started again). On a link already
        dead no ``XQ`` goes out: the threads left are :meth:`not_sent`. Each is said in a
        WARNING on the ``galil.routines`` logger.

        Raises:
            The first failure, unless ``failed`` (``what`` failed: its error is the one
            raised), when a ``GalilError`` is suppressed; anything else (a Ctrl-C) is raised.
        """
        refused: CommandError | None = None
        left = dict(threads)
        for t, label in threads.items():
            if not self.link.is_open or self.link.dead:  # (known dead: no XQ goes out)
                self.not_sent(left, what)
                if failed:
                    return
                raise self.link.error(
                    GalilConnectionError, f"the link died during {what}{RECONNECT_ADVICE}"
                )
            del left[t]
            try:
                self.xq_again(label, t)
            except CommandError as exc:  # (refused: the routine does not run)
                self.threads.pop(t, None)
                why = f"its XQ was refused ({_first(exc)})"
                _say_not_restarted(t, label, what, why, held=False)
                refused = refused or exc
            except BaseException as exc:  # (the XQ may have gone out: held, as start() holds)
                why = f"its XQ's fate is unknown ({_first(exc)})"
                _say_not_restarted(t, label, what, why, held=True)
                for other, its in left.items():
                    self.threads.pop(other, None)
                    why = f"thread {t}'s restart failed first"
                    _say_not_restarted(other, its, what, why, held=False)
                if failed and isinstance(exc, GalilError):
                    return
                raise
        if refused is not None and not failed:
            raise refused

    def not_sent(self, threads: Mapping[int, str], what: str) -> None:
        """The link is dead: no ``XQ`` of ``threads`` (halted for ``what``) went out. The
        library still holds them, and :meth:`Routines.reopened` starts them again once the link is
        reopened (decision 0094's amendment); each is said in a WARNING."""
        for t, label in threads.items():
            self.unsent[t] = label
            why = "its XQ was not sent (the link is dead)"
            fate = "the library starts it again once the link is reopened (reconnect())"
            _say_not_restarted(t, label, what, why, held=True, fate=fate)

    def reopened(self, running: Mapping[int, int]) -> tuple[int, ...]:
        """:meth:`Routines.reopened`, the threads ``running`` read (under its lock)."""
        pending, self.unsent = dict(self.unsent), {}
        started = []
        for t, label in pending.items():
            if self.threads.get(t) != label or t in running:
                continue  # (halted or taken since, or something runs there)
            try:
                self.xq_again(label, t)
            except CommandError as exc:
                self.threads.pop(t, None)
                why = f"its XQ was refused after the reopening ({_first(exc)})"
                _say_not_restarted(t, label, "a reopening", why, held=False)
            except GalilError as exc:
                self.unsent[t] = label
                why = f"its XQ failed after the reopening ({_first(exc)})"
                _say_not_restarted(t, label, "a reopening", why, held=True)
            else:
                started.append(t)
        return tuple(started)


class Routines:
    """Installs the library's routines into program memory and runs them on threads."""

    def __init__(self, link: CommandLink) -> None:
        self.link = link
        self._threads: dict[int, str] = {}  # library thread -> label it runs
        self._owners: dict[int, object] = {}  # thread -> the one-shot run that holds it
        self._lock = threading.RLock()
        self._restarts = _Restarts(link, self._threads)

    def restart_with(self, label: str, *commands: cmds.Command) -> None:
        """Send ``commands`` on the line of every ``XQ`` that starts the routine ``label``
        again after the library halted it for a download or a burn (:meth:`paused`): the
        watchdog's fresh heartbeat (``gwbeat=TIME``), without which the routine would measure
        its silence from a beat taken before the halt and fire at once."""
        with self._lock:
            self._restarts.preludes[label] = tuple(commands)

    def upload(self) -> list[str]:
        """The program in memory, one string per line (``UL``).

        Its size is not known before it comes, so the reply timeout covers the most the
        model's program memory holds (decision 0064); a controller that stops answering is
        found out once its reply has been silent for the link's transfer stall (decision 0067).
        """
        text = self.link.transfer(cmds.ul(), ul_reply_bytes(self.link.model)).text
        return [line for line in text.replace("\r\n", "\n").split("\n") if line.strip()]

    def running(self) -> dict[int, int]:
        """Running threads and the line each is on (``_XQn``), read in one round trip.

        A one-shot run of the library's (a speed schedule) whose thread no longer runs has
        ended: the library holds that thread no more.
        """
        return self.running_and(())[0]

    def running_and(self, names: Sequence[str]) -> tuple[dict[int, int], list[float]]:
        """:meth:`running`, and the operands ``names`` read in the same round trip."""
        n = self.link.model.threads
        values = self.link.query_operands([*(f"_XQ{t}" for t in range(n)), *names])
        running = {t: round(v) for t, v in enumerate(values[:n]) if round(v) >= 0}
        with self._lock:
            for t in [t for t in self._owners if t not in running]:
                del self._owners[t]
                self._threads.pop(t, None)
        return running, values[n:]

    def holder(self, thread: int) -> str | None:
        """The label of the library's routine on ``thread``, or ``None`` when the library does
        not hold it (a one-shot run is asked whether it still runs: one query)."""
        with self._lock:
            if thread in self._owners:
                self.running()
            return self._threads.get(thread)

    def install(self, *routines: Routine) -> bool:
        """Put ``routines`` into the library block, each replacing the whole routine of the
        same first label (inner labels and stale copies of its inner blocks included).

        Returns:
            Whether a download was needed.

        Raises:
            InvalidArgument: a label (inner ones included) the user's program or another
                of the library's routines uses, a program too long for the
                model, or a user program running (the download would disturb it).
        """
        with self._lock:
            current = self.upload()
            user, library = split_program(current)
            clash = _labels(user).intersection(set().union(*(r.labels for r in routines)))
            if clash:
                raise InvalidArgument(
                    f"the program in memory uses the label(s) {sorted(clash)} that the library "
                    "needs; rename them in your program",
                    model=self.link.model.name,
                )
            _merge(library, routines)
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
        """Download, the library's own threads halted around it and started again whatever
        came of it (:meth:`_halted`); return the threads halted and started again.

        Raises:
            ProgramRunning: a program of the user's runs, or a speed schedule; nothing is
                sent but the one ``_XQn`` query.
        """
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
            raise ProgramRunning(
                f"a program runs on thread(s) {users}; {what}", model=self.link.model.name
            )
        once = sorted(t for t in running if t in self._owners)
        if once:
            raise ProgramRunning(
                f"thread(s) {once} run a speed schedule, which a download would start again "
                "(its motion with it): wait for the schedule to end or stop it first",
                model=self.link.model.name,
            )
        with self._halted("DL", running) as halted:
            self.link.transfer(download)
        return halted

    @contextlib.contextmanager
    def paused(self, what: str) -> Iterator[tuple[int, ...]]:
        """Halt the library's own threads (the watchdog, a wait for an input) for ``what``
        (``BN``, ``BP``), which the controller refuses while any thread runs (TC 17), and
        start them again after it, whatever came of it, as a download does (one path:
        :meth:`_halted`; decision 0094). Yields the threads halted (none: nothing is sent).

        Raises:
            InvalidArgument: a program of the user's runs, or a speed schedule (its start
                again would move the axis): nothing is sent but the one ``_XQn`` query.
        """
        with self._lock:
            running = self.running()
            users = {t: line for t, line in running.items() if t not in self._threads}
            once = sorted(t for t in running if t in self._owners)
            if users or once:
                named = _threads_named(running, self._threads)
                advice = (
                    "halt your program first (controller.programs.halt())"
                    if users
                    else "wait for the speed schedule to end, or stop it, first"
                )
                raise InvalidArgument(
                    f"{what} is not valid while a program runs ({named} running): the "
                    f"controller refuses it (TC 17); nothing was sent. {advice.capitalize()}; "
                    "the library's own routines (the watchdog) are halted for it and started "
                    "again",
                    model=self.link.model.name,
                )
            with self._halted(what, running) as halted:
                yield halted

    @contextlib.contextmanager
    def _halted(self, what: str, running: Mapping[int, int]) -> Iterator[tuple[int, ...]]:
        """Halt the library's threads among ``running`` (one line of ``HX n``) for ``what``
        (``DL``, ``BN``, ``BP``), and start each again after it, whatever came of it: a
        failed download or burn leaves the routines that ran running again, each with its
        :meth:`restart_with` commands (the watchdog's fresh heartbeat). A restart that failed
        is said (:meth:`_restart`); raised when ``what`` worked, else ``what``'s error is
        (decision 0094). Yields the threads halted. Under the lock."""
        restart = {t: label for t, label in self._threads.items() if t in running}
        if restart:
            self.link.command_line([cmds.hx(t) for t in restart])
        try:
            yield tuple(sorted(restart))
        except BaseException:
            self._restarts.restart(restart, what, failed=True)
            raise
        self._restarts.restart(restart, what, failed=False)

    def reopened(self) -> tuple[int, ...]:
        """The link was reopened: start again each thread halted for a download or a burn
        whose ``XQ`` was not sent because the link was dead, if the library still holds it
        for that routine and it does not run, behind its :meth:`restart_with` commands (the
        watchdog's fresh heartbeat). A refused ``XQ`` forgets the thread, and another failure
        leaves it for the next reopening; each is said in a WARNING. Nothing is sent when no
        thread waits (decision 0094's amendment).

        Returns:
            The threads started again.
        """
        with self._lock:
            if not self._restarts.unsent:
                return ()
            try:
                running = self.running()
            except GalilError:
                return ()
            return self._restarts.reopened(running)

    def replace_user(self, lines: Sequence[str]) -> tuple[bool, tuple[int, ...]]:
        """Put ``lines`` above the marker as the user's program, keeping the library's block.

        Returns:
            Whether a download was needed, and the library threads halted for it and started
            again (the watchdog, say).

        Raises:
            InvalidArgument: a label of the library's routines (installed, or
                :data:`RESERVED`) in ``lines``, a program too long with the routines, or a
                user program running.
        """
        check_user_labels(lines)
        with self._lock:
            current = self.upload()
            _, library = split_program(current)
            clash = _labels(lines) & _labels([line for r in library.values() for line in r])
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

    def check_thread(self, thread: object) -> int:
        """``thread`` if the model has it; nothing is sent.

        Raises:
            InvalidArgument: not an integer, or no such thread.
        """
        model = self.link.model
        t = whole(thread)
        if t is None:
            raise InvalidArgument(f"thread must be an integer, not {thread!r}")
        if not 0 <= t < model.threads:
            raise InvalidArgument(
                f"{model.name} has threads 0..{model.threads - 1}, not {t}",
                model=model.name,
            )
        return t

    def check_free(self, thread: int, label: str) -> bool:
        """Refuse a thread that does not exist or runs another program (one query; and an
        upload when the thread runs a program the library does not know it holds).

        A thread found running inside the library's own ``label`` routine (left by an
        earlier session, or by a call whose link died) is the library's again: the caller
        halts it and starts it afresh (:meth:`start`).

        Returns:
            Whether the thread still runs the library's ``label``.

        Raises:
            InvalidArgument: the thread does not exist or runs a program (another of the
                library's routines too: the error says which; one this session runs is
                named with its feature, one left by an earlier session with how to halt it).
        """
        self.check_thread(thread)
        with self._lock:
            return self._free(thread, label, self.running())

    def free_thread(self, thread: int | None, label: str) -> int:
        """:meth:`check_free` of ``thread``, or of :meth:`default_thread`'s choice when it is
        ``None``, in one query (an upload as :meth:`check_free`'s).

        Returns:
            The thread.

        Raises:
            ProgramRunning: no thread named, and every thread runs a program of the user's
                or another routine of this session's (a caller that can do without the
                routine, a wait for an input, polls instead).
            InvalidArgument: what :meth:`check_free` raises for a named thread.
        """
        if thread is not None:
            self.check_thread(thread)
        with self._lock:
            running = self.running()
            t = self._default(label, running) if thread is None else thread
            if t is None:
                raise ProgramRunning(
                    f"every thread of {self.link.model.name} runs a program "
                    f"({_threads_named(running, self._threads)} running): none is free "
                    f"for {RESERVED.get(label, 'the routine ' + label)}",
                    model=self.link.model.name,
                )
            self._free(t, label, running)
            return t

    def _free(self, thread: int, label: str, running: Mapping[int, int]) -> bool:
        """:meth:`check_free`, the threads ``running`` read (under the lock)."""
        model = self.link.model
        busy = thread in running
        held = self._threads.get(thread)
        if not busy or held == label:
            return busy
        if held is not None:  # (this session's: never advise to halt it raw)
            raise InvalidArgument(
                f"thread {thread} runs {self._feature(thread, held)}, started in this "
                "session; choose another thread (thread=...), or leave thread= out: by "
                "default the library's routines take threads apart",
                model=model.name,
            )
        left = routine_at(self.upload(), running[thread])
        if left == label:
            self._hold(thread, label, None)  # (an earlier session's: the library's again)
            return True
        if left is not None:
            raise InvalidArgument(
                f"thread {thread} runs the library's routine {left} "
                f"({RESERVED.get(left, 'a routine of the library')}), left running by an "
                f"earlier session; halt it (controller.programs.halt({thread}), or HX{thread})"
                " or choose another thread (thread=...)",
                model=model.name,
            )
        raise InvalidArgument(
            f"thread {thread} runs a program; choose another thread (thread=...)",
            model=model.name,
        )

    def _feature(self, thread: int, label: str) -> str:
        """What runs ``label`` on ``thread``: ``the watchdog (#GWDOG)``."""
        what = RESERVED.get(label)
        if what is None:
            what = "a speed schedule" if thread in self._owners else "a routine of the library's"
        return f"{what} ({label})"

    def default_thread(self, label: str) -> int:
        """The thread a routine of ``label`` takes when none is named: the last one that runs
        neither another of this session's routines nor a program of the user's (one query; an
        upload when a thread runs a program the library does not know it holds, to tell an
        earlier session's ``label`` from the user's). A thread that runs ``label`` itself is
        not skipped (a new watchdog takes over the running one's). With no such thread, the
        last one (:meth:`check_free` refuses it, saying what runs there)."""
        with self._lock:
            t = self._default(label, self.running())
            return self.link.model.threads - 1 if t is None else t

    def _default(self, label: str, running: Mapping[int, int]) -> int | None:
        """:meth:`default_thread`, the threads ``running`` read (under the lock); ``None``
        when every thread runs something else."""
        lines: list[str] | None = None
        for t in reversed(range(self.link.model.threads)):
            held = self._threads.get(t)
            if t not in running or held == label:
                return t
            if held is not None:
                continue  # (another routine of this session's)
            lines = self.upload() if lines is None else lines
            if routine_at(lines, running[t]) == label:
                return t  # (an earlier session's: taken over, as check_free does)
        return None

    def release(self, thread: int, label: str) -> None:
        """The routine ``label`` ended by itself on ``thread`` (the input wait's, once it
        said so): the library holds the thread no more, unless another routine took it."""
        with self._lock:
            if self._threads.get(thread) == label and thread not in self._owners:
                del self._threads[thread]

    def start(self, label: str, thread: int, *, owner: object | None = None) -> None:
        """Run the routine at ``label`` on ``thread`` (which must be free).

        Args:
            owner: marks a one-shot run (a speed schedule: it starts motion): a download
                refuses to start it again while it runs, and ``halt(thread, owner=owner)``
                halts the thread only while this run holds it.

        A routine of the library's that still runs ``label`` on the thread, left by a call
        whose link died before it could halt it (a watchdog, a wait for an input), is halted
        and started again; a one-shot run's (``owner``) is not (``XQ`` refuses it: TC 19).
        The thread is the library's from the moment its ``XQ`` may have gone out.

        Raises:
            InvalidArgument: the thread does not exist or runs a program.
            CommandError: the controller refused the ``XQ``.
        """
        with self._lock:
            left = self.check_free(thread, label)
            line = [cmds.hx(thread)] if left and owner is None else []
            try:
                self.link.command_line([*line, cmds.xq(label, thread)])
            except CommandError:  # refused: the thread is as it was
                raise
            except BaseException:  # (the XQ's fate unknown: the link died under it)
                self._hold(thread, label, owner)
                raise
            self._hold(thread, label, owner)

    def _hold(self, thread: int, label: str, owner: object | None) -> None:
        """``thread`` runs the library's ``label`` (a one-shot run of ``owner``'s)."""
        self._threads[thread] = label
        self._owners.pop(thread, None)
        self._restarts.unsent.pop(thread, None)
        if owner is not None:
            self._owners[thread] = owner

    def download_raw(self, send: Callable[[], _T]) -> _T:
        """Run ``send``, a ``DL`` the library did not build (typed at the terminal, ``galil
        dl``, ``Controller.send(commands.dl(...))``): it replaces the whole program, the
        library's routines with it. Refused, unsent, while any thread runs (one query): the
        controller refuses ``DL`` then (TC 17) and runs the program's lines that follow as
        commands (the simulator does; unsourced for a controller: decision 0084). Once sent
        (whatever came of it) the library forgets the threads it held: none runs, and its
        routines are no longer in memory (the next use installs them again, as every use
        does: :meth:`install` reads the program first).

        Raises:
            InvalidArgument: a thread runs (the library's own are named).
        """
        with self._lock:
            running = self.running()
            if running:
                raise InvalidArgument(
                    f"{_threads_named(running, self._threads)} running: the controller "
                    "refuses DL while a program runs (TC 17) and would then run the "
                    f"program's lines as commands; {self._ending_advice(running)}, or "
                    "download with controller.programs.download(), which keeps the "
                    "library's routines running",
                    model=self.link.model.name,
                )
            try:
                return send()
            finally:
                self.forget()

    def _ending_advice(self, running: Mapping[int, int]) -> str:
        """How to end the ``running`` threads first: this session's routines of the library
        through the library (never a raw ``HX`` behind its back), the others with a halt."""
        features = {RESERVED.get(self._threads[t]) for t in running if t in self._threads}
        advice = []
        if "the watchdog" in features:
            advice.append("stop the watchdog (its stop())")
        if "wait_for_input" in features:
            advice.append("let the wait for an input end (at its input or its timeout)")
        if features - {"the watchdog", "wait_for_input"}:
            advice.append("let the speed schedule end, or stop its motion")
        others = sorted(t for t in running if t not in self._threads)
        if others:
            advice.append(f"halt thread(s) {others} (controller.programs.halt(n), or HX n)")
        return "; ".join(advice) + " first"

    def forget(self, thread: int | None = None) -> None:
        """``thread`` was halted behind :meth:`halt`'s back (after a failed start); with no
        ``thread``, every one: the controller was reset (``RS``), its threads are halted and
        the program in memory is the burned one, or a raw ``DL`` replaced the program
        (:meth:`download_raw`), so the library runs no routine any more."""
        with self._lock:
            if thread is None:
                self._threads.clear()
                self._owners.clear()
                self._restarts.unsent.clear()
            else:
                self._threads.pop(thread, None)
                self._owners.pop(thread, None)
                self._restarts.unsent.pop(thread, None)

    def halt(self, thread: int, *, owner: object | None = None) -> bool:
        """Halt a library thread (``HX n``); with ``owner``, only if the run started with
        that owner still holds it (a later run on the thread is left alone).

        Returns:
            Whether ``HX`` was sent.
        """
        with self._lock:
            if owner is not None and self._owners.get(thread) is not owner:
                return False
            self.link.command_line([cmds.hx(thread)])
            self._threads.pop(thread, None)
            self._owners.pop(thread, None)
            self._restarts.unsent.pop(thread, None)
            return True

    @property
    def threads(self) -> dict[int, str]:
        """The threads the library runs, and the label each started at (as last seen: a
        speed schedule that has ended is forgotten at the next :meth:`running`)."""
        return dict(self._threads)
