"""``galil terminal``: type to a controller as in Galil's own terminal.

Every line goes to the controller as typed, compound lines included (``PRA=1000;BGA``); the
reply is printed, a ``?`` is explained with ``TC1`` and the session goes on, and unsolicited
output (a program's ``MG``) is printed the moment it arrives. ``DL`` alone starts a program
download: the lines typed (or pasted) after it are collected until a line holding ``\\`` alone
and sent as one ``DL`` (a ``\\`` inside a line is refused, as ``galil dl`` refuses it, and no
line after it runs). ``UL`` prints the program and ``LS`` lists it, each with a timeout from
the most its reply can hold, as every bulk transfer has (a whole program memory over a slow
serial line takes minutes). ``QR`` says how long the data record was (it is binary: in Python,
:meth:`~galil.Controller.record` reads it). ``RS`` alone resets the controller through
:meth:`~galil.Controller.reset` (the link is set up again), ``BN`` alone burns through
:meth:`~galil.Controller.save`; the commands that would change the link's own settings
(``CW 1``, ``EO 0``, ``CF``, ``^R^S``, ``RS`` or ``BN`` in a compound line) are not sent, and
the terminal says why and what to type instead. A compound line with a rejected part prints
the replies of the other parts, in order around the rejection. Ctrl-C sends ``ST`` and halts
the threads that run a program of the user's (which could start motion again), leaving the
library's routines running (and says so); Ctrl-D leaves, warning of an axis that still moves
or a program that still runs; a reply that does not come in time is reported and the next command
resynchronises the link first. SIGTERM and SIGHUP end the terminal as Ctrl-D does (the tty is
put back, the controller closed) with status 128 + the signal's number.

On a terminal, input goes through prompt-toolkit (history, line editing, messages printed above
the prompt); a history file that cannot be written is kept for the session only, and the
terminal says so. Piped input is read line by line, so ``galil terminal ADDRESS < setup.txt``
runs a script; its status is then 1 when any line was refused or failed.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import os
import re
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from galil.controller import Controller
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
)
from galil.link import check_seconds
from galil.protocol import commands as cmds
from galil.protocol.programs import ProgramLine, check_program
from galil.protocol.session import Completed
from galil.routines import RESERVED, ls_reply_bytes, routine_at, ul_reply_bytes

if TYPE_CHECKING:
    from prompt_toolkit.history import History

__all__ = ["Terminal", "default_history_path", "program_lines", "run_terminal"]

PROMPT = ":"
DOWNLOAD_PROMPT = "DL> "
# What TC 2 means at a terminal (AM, MC, WT and the other trippoints are "Not Valid in
# terminal" in the DMC-4103 command reference; decision 0044).
_PROGRAM_ONLY_HINT = (
    "  (program only: put it in a program (DL) and run that (XQ);"
    " from here, wait for a move by polling MG _BGA until it is 0)"
)
# Typed alone, these get a reply bigger than a line: a program (UL, LS) or a binary record (QR,
# also with its axes written right after it: QRA, QRAB, as QR A).
_TRANSFER = re.compile(r"(?:UL|LS)(?=$|[\s#,0-9])|QR(?=$|[\s,0-9A-Z])")
# What the library's refusals advise in Python (decision 0031), said for a person typing here.
_TYPE_INSTEAD = {
    "RS": "RS in a line with other commands would reset the controller under the link: type "
    "RS alone (the terminal then sets the link up again)",
    # RS with an argument: RS 0 is RS; RS -1 is a soft master reset (factory defaults, the
    # burned settings kept for the next RS), as the DMC-40x0 command reference has it
    # (unsourced here: not in the shared references).
    "RS n": "{cmd!r}: RS with an argument is not sent from here. Type RS alone to restart the "
    "controller from its burned settings (the terminal then sets the link up again); RS -1 (a "
    "soft master reset: factory defaults, the burned settings kept) would undo the link's own "
    "settings under it: use Galil's own tools for it, then start galil terminal again",
    "BN": "BN in a line with other commands would burn the link's own CW 1 and EO 0: type BN "
    "alone (the terminal then burns the controller's own)",
    "^R^S": "^R^S (master reset) returns the controller to its factory settings: use Galil's "
    "own tools, then start galil terminal again",
    "CW": "{cmd!r} changes how program output is marked, which the link set up when it "
    "connected (MG _CW reads it)",
    "EO": "{cmd!r} switches the echo the link handles (MG _EO reads it)",
    "CF": "{cmd!r} would send program output away from this terminal (MG _CF reads where it goes)",
    "IH": "{cmd!r} would close the handle this terminal talks on (Ctrl-D leaves; IHC=>-1 "
    "frees another handle)",
    "DL": "{cmd!r}: a program download starts with DL typed alone; then type or paste the "
    "program and end it with a line holding \\ (DL #label is not sent from here)",
    "QD": "{cmd!r}: QD takes an array's values from the lines after it, which this terminal "
    "does not send: set the elements one at a time (x[0]=1)",
}


def program_lines(text: str) -> list[str]:
    """The lines of a program file as ``DL`` sends them.

    Leading and trailing blanks are stripped (indentation would only use program memory),
    empty lines are dropped (the controller rejects them) and tabs become spaces. A line
    holding only ``\\`` ends the program, as it ends a download typed at a terminal.

    Raises:
        InvalidArgument: nothing left to download.
    """
    lines: list[str] = []
    for raw in text.splitlines():
        line = raw.replace("\t", " ").strip()
        if line == "\\":
            break
        if line:
            lines.append(line)
    if not lines:
        raise InvalidArgument("the program is empty")
    return lines


def default_history_path() -> Path:
    """Where the terminal keeps its history: ``$XDG_STATE_HOME/galil/terminal-history``."""
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(
        os.path.expanduser("~"), ".local", "state"
    )
    return Path(base) / "galil" / "terminal-history"


class Terminal:
    """The terminal's behaviour, without any input device: feed it lines, it prints.

    Args:
        controller: the connected controller.
        write: prints one line of output (``print`` by default).
        timeout: seconds to wait for a reply: a finite number > 0
            (:func:`~galil.link.check_seconds`).

    Raises:
        InvalidArgument: a bad timeout.
    """

    def __init__(
        self,
        controller: Controller,
        *,
        write: Callable[[str], None] | None = None,
        timeout: float = 5.0,
    ) -> None:
        self.controller = controller
        self.write: Callable[[str], None] = write if write is not None else _print
        self.timeout = check_seconds(timeout, "timeout", positive=True)  # a reply timeout
        #: Lines refused or failed so far (a piped session's exit status tells whether any).
        self.failures = 0
        self._download: list[str] | None = None

    @property
    def prompt(self) -> str:
        """The prompt to show: ``:`` as on the controller, ``DL>`` while collecting a program."""
        return PROMPT if self._download is None else DOWNLOAD_PROMPT

    @property
    def downloading(self) -> bool:
        """Whether program lines are being collected for a ``DL``."""
        return self._download is not None

    def feed(self, text: str) -> None:
        """Handle what was typed: one line, or several when text was pasted."""
        for line in text.splitlines() or [""]:
            self._line(line)

    def _line(self, line: str) -> None:
        if self._download is not None:
            self._collect(line)
            return
        command = line.strip()
        if not command:
            return
        if command.upper() == "DL":
            self._download = []
            self.write("download: type or paste the program, then a line with \\ (Ctrl-C cancels)")
            return
        if command == "RS":
            self.reset()
            return
        if command == "BN":
            self.save()
            return
        self._send(command)

    def reset(self) -> None:
        """``RS`` typed alone: :meth:`~galil.Controller.reset` (the raw ``RS`` is refused: it
        would break the link's settings); print what happened."""
        try:
            self.controller.reset()
        except GalilError as exc:
            self._report(exc, "RS")
            return
        self.write(
            "reset (RS): the controller restarted from its burned settings; the link is set up"
        )

    def save(self) -> None:
        """``BN`` typed alone: :meth:`~galil.Controller.save` (the raw ``BN`` is refused: it
        would burn the link's own ``CW 1``/``EO 0``); print what happened."""
        try:
            self.controller.save()
        except GalilError as exc:
            self._report(exc, "BN")
            return
        self.write("saved (BN): the parameters are burned, with the controller's own CW and EO")

    def _collect(self, line: str) -> None:
        """A line of a program being typed: only a line holding ``\\`` alone ends it. A
        ``\\`` elsewhere (``' data in C:\\scans``) stays in its line, which makes
        :meth:`download` refuse the program as ``galil dl`` refuses it: cut there, the lines
        after it would run as commands (a pasted ``BGA`` would move the axis)."""
        assert self._download is not None
        text = line.replace("\t", " ").strip()
        if text != "\\":
            if "\\" in text:
                self.write(
                    f"DL line {len(self._download) + 1}: character '\\\\' cannot be downloaded: "
                    "this program will not be sent; a line holding only \\ ends it (Ctrl-C "
                    "cancels)"
                )
            if text:
                self._download.append(text)
            return
        lines, self._download = self._download, None
        if not lines:
            self.write("download cancelled: no program lines")
            return
        self.download(lines)

    def download(self, lines: Iterable[str]) -> bool:
        """Send a program with ``DL``; print what happened. Returns whether it was accepted.

        The program is checked as :meth:`~galil.programs.Programs.download` checks it (each
        line, the labels, and the model's program memory); nothing is sent if it breaks a rule.
        """
        try:
            program = list(lines)
            command = cmds.dl(program, model=self.controller.model)
            numbered = [ProgramLine(text, n) for n, text in enumerate(program, 1)]
            check_program(numbered, self.controller.model, at_terminal=True)
            user, library = threads_running(self.controller)  # (said as typed here)
            if user or library:
                raise InvalidArgument(_running_refusal(user, library))
            # (refused while a thread runs; the library forgets the routines it replaces)
            self.controller.routines.download_raw(lambda: self._transfer(command))
        except GalilError as exc:
            self._report(exc, "DL")
            return False
        count = command.payload.count(b"\r")
        self.write(f"downloaded {count} line{'s' if count != 1 else ''}")
        return True

    def cancel(self) -> None:
        """Drop a program being collected."""
        if self._download is not None:
            self._download = None
            self.write("download cancelled")

    def _transfer(self, command: cmds.Command, reply_bytes: int = 0) -> Completed:
        """A bulk transfer, with the timeout its size gives (never less than the terminal's)."""
        link = self.controller.link
        wait = max(self.timeout, link.transfer_timeout(command, reply_bytes))
        return link.exchange(command, timeout=wait, stall=max(self.timeout, link.transfer_stall))

    def _send(self, command: str) -> None:
        try:
            reply = self._exchange(command)
        except GalilError as exc:
            instead = _type_instead(command) if isinstance(exc, InvalidArgument) else None
            if instead is None:
                self._report(exc, command)
            else:
                self.failures += 1
                self.write(f"not sent: {instead}")
            return
        for text in reply.splitlines():
            self.write(text)

    def _exchange(self, command: str) -> str:
        """Send one typed line; what to print."""
        special = _TRANSFER.match(command)
        if special is None or len(cmds.split_commands(command)) > 1:
            return self.controller.command(command, timeout=self.timeout, allow_compound=True)
        parsed = cmds.parse_line(command)
        model = self.controller.model
        if special.group() == "UL":
            return self._transfer(parsed, ul_reply_bytes(model)).text
        if special.group() == "LS":  # each line numbered: "1999 " before the text
            return self._transfer(parsed, ls_reply_bytes(model)).text
        record = self.controller.exchange(parsed, timeout=self.timeout).record or b""
        return (
            f"(QR: a {len(record)}-byte binary data record, not shown; MG reads its values "
            "as text: MG _TPA, _RPA)"
        )

    def _report(self, exc: GalilError, command: str) -> None:
        self.failures += 1
        message = str(exc.args[0]) if exc.args else type(exc).__name__
        if isinstance(exc, CommandError):
            self._refused(exc, command, message)
        elif isinstance(exc, GalilTimeoutError):
            message = message.replace("(pass timeout=)", "(give a longer --timeout)")
            self.write(f"timeout: {message}; the controller may still be busy (Ctrl-C stops it)")
        elif isinstance(exc, InvalidArgument):
            self.write(f"not sent: {message.removeprefix('not sent: ')}")
        elif isinstance(exc, GalilConnectionError):
            if self.controller.link.dead or self.controller.closed:
                raise exc
            # Out of step and not back yet: the controller still holds an earlier reply.
            self.write(f"not sent: {message} (an earlier reply may still be due, e.g. a burn's)")
        else:
            self.write(f"error: {message}")

    def _refused(self, exc: CommandError, command: str, message: str) -> None:
        """A ``?``, explained, among the replies of the rest of its compound line."""
        replies = exc.replies
        refused = [i for i, reply in enumerate(replies) if reply is None]
        at = refused[-1] if refused else len(replies)  # (TC1 explains the last one refused)
        parts = cmds.split_commands(command)
        for i, reply in enumerate(replies[:at]):
            if reply is not None:
                self._show([reply])
            else:  # (the controller keeps one error code: the last one's)
                part = parts[i].strip() if len(parts) == len(replies) else "a part"
                self.write(
                    f"? (refused: {part!r}; why is not known: TC1 tells only the last error)"
                )
        code = "?" if exc.code is None else str(exc.code)
        self.write(f"? {code} {exc.text}")
        hint = message.partition("(Galil commands")
        if hint[1]:
            self.write(f"  (Galil commands{hint[2]}")
        elif exc.command != command:
            self.write(f"  (refused: {exc.command!r})")
        if exc.code == 2:
            self.write(_PROGRAM_ONLY_HINT)
        self._show(replies[at + 1 :])

    def _show(self, replies: Iterable[str | None]) -> None:
        for reply in replies:
            for text in (reply or "").splitlines():
                self.write(text)

    def interrupt(self) -> None:
        """Ctrl-C: cancel a download being typed, stop all motion with ``ST`` and halt the
        threads that run a program of the user's (``HX n``: a running program could start
        motion again); the library's routines (the watchdog, an input wait) are left running,
        and said."""
        self.cancel()
        try:
            self.controller.stop()
        except GalilError as exc:
            if isinstance(exc, GalilConnectionError) and self.controller.link.dead:
                raise
            self.write(f"Ctrl-C: ST not sent: {exc.args[0] if exc.args else exc}")
            return
        try:
            user, library = threads_running(self.controller)
            if user:
                self.controller.link.command_line([cmds.hx(t) for t in user])
                self.controller.stop()  # (a move a program began before its halt)
        except GalilError as exc:
            if isinstance(exc, GalilConnectionError) and self.controller.link.dead:
                raise
            self.write(
                "Ctrl-C: sent ST to every axis; the program threads could not be read or "
                f"halted ({exc.args[0] if exc.args else exc}): a running program may start "
                "motion again (HX halts every thread)"
            )
            return
        said = "sent ST, motion stopped on every axis"
        if user:
            halted = ", ".join(f"HX{t}" for t in user)
            said = f"sent ST to every axis and halted the program threads ({halted})"
        self.write(f"Ctrl-C: {said}{_library_threads(library)} (Ctrl-D leaves)")

    def leaving(self) -> None:
        """Ctrl-D (or the end of piped input): say what still moves or runs, which the end
        of the terminal leaves as it is (one query)."""
        model = self.controller.model
        try:
            running, moving = self.controller.routines.running_and([f"_BG{a}" for a in model.axes])
            user, _ = threads_running(self.controller, running)
        except GalilError:
            return  # (the link has gone: nothing to tell)
        axes = [a for a, bg in zip(model.axes, moving, strict=True) if bg]
        going = [f"axis {a} moves" for a in axes] + [f"thread {t} runs" for t in user]
        if going:
            self.write(
                f"warning: leaving while {', '.join(going)}: the end of the terminal stops "
                "nothing (ST stops the motion, HX n halts thread n)"
            )


def threads_running(
    controller: Controller, running: Mapping[int, int] | None = None
) -> tuple[list[int], dict[int, str]]:
    """The threads that run a program of the user's, and those that run one of the library's
    routines, by label: this session's are known, another session's (the watchdog of another
    link) are told by their line in program memory (one upload, only when a thread this
    session does not hold runs).

    Args:
        controller: the controller.
        running: the running threads and their lines (``_XQn``), if just read.
    """
    if running is None:
        running = controller.routines.running()
    library = {t: label for t, label in controller.routines.threads.items() if t in running}
    others = [t for t in running if t not in library]
    if others:
        lines = controller.routines.upload()
        for t in others:
            label = routine_at(lines, running[t])
            if label is not None:
                library[t] = label
    return sorted(t for t in running if t not in library), library


#: What ends a thread that runs one of the library's routines, said for a person typing.
_ENDING = {
    "the watchdog": "stop the watchdog in the program that started it (HX{t} would end it "
    "unseen, and leave its motion unguarded)",
    "wait_for_input": "let the wait for an input end (at its input or its timeout)",
}


def _running_refusal(user: list[int], library: dict[int, str]) -> str:
    """Why a ``DL`` is not sent while threads run, and what to type or do first: ``HX n`` for
    a program of the user's; the library's routines (``#GWDOG``: a watchdog, perhaps of
    another session) named, and ended where they were started, never halted behind the
    library's back."""
    named = [f"thread {t}" for t in user]
    named += [
        f"thread {t} (the library's {label}: {RESERVED.get(label, 'a library routine')})"
        for t, label in sorted(library.items())
    ]
    advice = (
        [f"halt {'it' if len(user) == 1 else 'them'} first ({', '.join(f'HX{t}' for t in user)})"]
        if user
        else []
    )
    for t, label in sorted(library.items()):
        what = RESERVED.get(label, "")
        advice.append(
            _ENDING.get(what, "let its run (a speed schedule) end, or stop its motion").format(t=t)
        )
    verb = "is" if len(named) == 1 else "are"
    return (
        f"{', '.join(named)} {verb} running: the controller refuses DL while a program runs "
        f"(TC 17) and would then run the program's lines as commands; {'; '.join(advice)}"
    )


def _library_threads(library: dict[int, str]) -> str:
    if not library:
        return ""
    named = ", ".join(
        f"thread {t} runs the library's {label} ({RESERVED.get(label, 'a library routine')})"
        for t, label in sorted(library.items())
    )
    return f"; {named}: left running"


def _print(text: str) -> None:
    print(text, flush=True)


def _type_instead(command: str) -> str | None:
    """What to type instead of a line the library refuses to send, or ``None``."""
    parts = cmds.split_commands(command)
    for part in parts:
        text = part.strip()
        head = "^R^S" if text.startswith("\x12\x13") else text[:2].upper()
        if head == "RS" and len(parts) == 1 and cmds.link_setting(part):
            return _TYPE_INSTEAD["RS n"].format(cmd=text)  # (alone, with an argument)
        if head in ("DL", "QD") or (head in _TYPE_INSTEAD and cmds.link_setting(part)):
            return _TYPE_INSTEAD[head].format(cmd=text)
    return None


def run_terminal(
    controller: Controller,
    *,
    timeout: float = 5.0,
    history: Path | None = None,
    interactive: bool | None = None,
) -> int:
    """Run the terminal on ``controller`` until Ctrl-D (or the end of piped input).

    SIGTERM and SIGHUP end it too (when it runs in the main thread): the line being handled
    is abandoned as Ctrl-C abandons it, the tty is put back as the line editor found it, and
    the caller closes the controller.

    Args:
        controller: the connected controller.
        timeout: seconds to wait for each reply.
        history: file that keeps the typed lines between sessions (``None``: memory only;
            one that cannot be written is kept for this session only, and the terminal says so).
        interactive: use the line editor; default: when stdin and stdout are terminals.

    Returns:
        The exit status: 0; for piped input, 1 when any line was refused or failed; 128 plus
        the signal's number when SIGTERM or SIGHUP ended it.
    """
    if interactive is None:
        interactive = sys.stdin.isatty() and sys.stdout.isatty()
    screen = _Screen() if interactive else None
    term = Terminal(controller, timeout=timeout, write=screen.write if screen else None)
    signals = _Signals()
    unsubscribe = controller.subscribe(term.write)
    try:
        with signals.installed():
            if screen is not None:
                _interactive(term, screen, history, signals)
            else:
                signals.feeding = True  # nothing to put back: a signal ends it at once
                _piped(term)
    except _Ended as ended:
        return 128 + ended.signum
    finally:
        unsubscribe()
    term.leaving()
    return 1 if term.failures and not interactive else 0


def _piped(term: Terminal) -> None:
    while True:
        try:
            line = sys.stdin.readline()
            if not line:
                return
            term.feed(line.rstrip("\r\n"))
        except KeyboardInterrupt:
            term.interrupt()


class _Ended(BaseException):
    """SIGTERM or SIGHUP ended the terminal (a BaseException, as KeyboardInterrupt: nothing on
    its way out mistakes it for a failed command)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


class _Signals:
    """SIGTERM and SIGHUP, which end the terminal.

    While a line is handled (``feeding``), the signal raises :class:`_Ended` at once (as
    Ctrl-C raises there); while a prompt is shown, the prompt is ended from its own event loop
    with :class:`_Ended`, so that prompt-toolkit puts the tty back; in between, the signal is
    noted and :meth:`check` raises it (a signal must not land inside prompt-toolkit's setup).
    """

    def __init__(self) -> None:
        self.ended = 0  # the signal that came, or 0
        self.feeding = False
        self._app: Any = None  # the prompt shown, and its loop
        self._loop: asyncio.AbstractEventLoop | None = None

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        """Handle the signals in the block (only the main thread can)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        names = ("SIGTERM", "SIGHUP")
        ending = [getattr(signal, n) for n in names if hasattr(signal, n)]
        previous = {signum: signal.signal(signum, self._handle) for signum in ending}
        try:
            yield
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, signal.SIG_DFL if handler is None else handler)

    def _handle(self, signum: int, frame: object) -> None:
        if self.ended:
            return  # (on its way out already)
        self.ended = signum
        if self.feeding:
            raise _Ended(signum)
        loop, app = self._loop, self._app
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # closed: check() raises after the prompt
                loop.call_soon_threadsafe(self._end_prompt, app)

    def prompt_shown(self, app: Any) -> None:
        """The prompt ``app`` is shown (called on its loop): a signal now ends it."""
        self._app, self._loop = app, asyncio.get_running_loop()
        self._end_prompt(app)  # (one that came while the prompt was set up)

    def prompt_gone(self) -> None:
        """The prompt has returned."""
        self._app = self._loop = None

    def _end_prompt(self, app: Any) -> None:
        if self.ended and app.is_running and not app.future.done():
            app.exit(exception=_Ended(self.ended))

    def check(self) -> None:
        """Raise :class:`_Ended` if a signal came."""
        if self.ended:
            raise _Ended(self.ended)


class _History:
    """The history of the line editor: a file, or memory when the file cannot be used."""

    def __init__(self, note: Callable[[str], None]) -> None:
        self.note = note

    def open(self, path: Path | None) -> History:
        """A history kept in ``path``, if it can be written; else in memory (said once)."""
        from prompt_toolkit.history import InMemoryHistory

        if path is None:
            return InMemoryHistory()
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "ab"):  # (a directory, a file not ours, a read-only home)
                pass
        except OSError as exc:
            self.lost(path, exc)
            return InMemoryHistory()
        return _file_history(path, self)

    def lost(self, path: Path | str, exc: OSError) -> None:
        """Say that the history file cannot be used."""
        why = exc.strerror or type(exc).__name__
        self.note(f"history: cannot use {path} ({why}); the history is kept for this session only")


def _file_history(path: Path, kept: _History) -> History:
    """A prompt-toolkit ``FileHistory`` that, when its file fails (full, taken away), goes on
    in memory and says so once: prompt-toolkit would leave its prompt hung on the error."""
    from prompt_toolkit.history import FileHistory

    class _Kept(FileHistory):
        failed = False

        def load_history_strings(self) -> Iterable[str]:
            try:
                return list(super().load_history_strings())
            except OSError as exc:
                self._failed(exc)
                return []

        def store_string(self, string: str) -> None:
            if self.failed:
                return
            try:
                super().store_string(string)
            except OSError as exc:
                self._failed(exc)

        def _failed(self, exc: OSError) -> None:
            self.failed = True
            kept.lost(path, exc)

    return _Kept(str(path))


def _interactive(
    term: Terminal, screen: _Screen, history_file: Path | None, signals: _Signals
) -> None:
    from prompt_toolkit import PromptSession

    session: PromptSession[str] = PromptSession(history=_History(term.write).open(history_file))
    # Ctrl-C at the prompt is a key; between prompts (the tty is then in cooked mode) it is a
    # SIGINT, which must not land inside prompt-toolkit's setup: it is noted and handled here.
    state = {"interrupted": False}

    def note(signum: int, frame: object) -> None:
        state["interrupted"] = True

    previous = signal.getsignal(signal.SIGINT)
    try:
        _prompt_loop(term, screen, session, note, state, signals)
    finally:
        signal.signal(signal.SIGINT, previous)


def _prompt_loop(
    term: Terminal,
    screen: _Screen,
    session: Any,
    note: Callable[[int, Any], None],
    state: dict[str, bool],
    signals: _Signals,
) -> None:
    # Anything else printed while the prompt is shown (a warning, say) goes above it too.
    from prompt_toolkit.patch_stdout import patch_stdout

    with patch_stdout(raw=True):
        while True:
            signal.signal(signal.SIGINT, note)
            line: str | None = None

            def start(app: Any = session.app) -> None:
                screen.prompt_shown(app)
                signals.prompt_shown(app)
                # A Ctrl-C that came while the prompt was being set up: act on it now.
                if state["interrupted"] and not app.future.done():
                    app.exit(exception=KeyboardInterrupt())

            try:
                line = session.prompt(term.prompt, pre_run=start)
            except KeyboardInterrupt:
                state["interrupted"] = True
            except EOFError:
                if not term.downloading:
                    return
                term.cancel()
            finally:
                signals.prompt_gone()
                screen.prompt_gone()
            signals.check()
            if state["interrupted"]:
                state["interrupted"] = False
                term.interrupt()
                continue
            if line is None:
                continue
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signals.feeding = True
            try:
                try:
                    signals.check()
                    term.feed(line)
                finally:
                    # Noted again before the loop goes round: a Ctrl-C just after the reply
                    # (shown before feed returns) would raise where nothing catches it.
                    signal.signal(signal.SIGINT, note)
                    signals.feeding = False
            except KeyboardInterrupt:
                term.interrupt()


class _Screen:
    """Prints the line-edited terminal's lines, from any thread, losing none while prompts come
    and go.

    Between prompts a line is written at once. While a prompt is shown, a line (a program's
    ``MG`` from the poll thread) is handed to the prompt's event loop and printed above the
    prompt (``run_in_terminal``). A line is kept until it has been written: once the prompt
    has its answer, its loop is about to be closed and may never run what it was handed, so
    lines wait and are written when the prompt has returned. (prompt-toolkit's ``patch_stdout``
    proxy hands a line to a prompt's loop just so; when that prompt ends first, the line is
    lost, and once the loop is closed, the proxy's thread dies and every later line with it.)
    """

    def __init__(self) -> None:
        from prompt_toolkit.application import get_app_session

        self._output = get_app_session().output  # the terminal's, before patch_stdout
        self._lock = threading.Lock()
        self._pending: list[str] = []  # lines not written yet
        self._held = False  # a prompt is shown or ending: lines wait in _pending
        self._loop: asyncio.AbstractEventLoop | None = None  # the shown prompt's loop
        self._context = contextvars.Context()  # the prompt's (run_in_terminal finds it there)

    def write(self, text: str) -> None:
        """Print one line (any thread)."""
        with self._lock:
            if not self._held:
                self._put([text])
                return
            self._pending.append(text)
            if self._loop is None or len(self._pending) > 1:
                return  # the prompt is ending, or the lines before are already on their way
            with contextlib.suppress(RuntimeError):  # closed: prompt_gone() writes them
                self._loop.call_soon_threadsafe(self._show_pending, context=self._context)

    def prompt_shown(self, app: Any) -> None:
        """The prompt ``app`` is shown (called on its loop): lines go above it until it has
        its answer."""
        with self._lock:
            self._held = True
            self._loop = asyncio.get_running_loop()
            self._context = contextvars.copy_context()
        app.future.add_done_callback(self._prompt_answered)

    def _prompt_answered(self, _: object) -> None:
        with self._lock:
            self._loop = None  # about to end: hand it nothing more

    def prompt_gone(self) -> None:
        """The prompt has returned (its loop is closed): write what it did not."""
        with self._lock:
            self._held = False
            self._loop = None
            lines, self._pending = self._pending, []
            self._put(lines)

    def _show_pending(self) -> None:
        from prompt_toolkit.application import run_in_terminal

        run_in_terminal(self._write_pending)

    def _write_pending(self) -> None:
        with self._lock:
            lines, self._pending = self._pending, []
            self._put(lines)

    def _put(self, lines: list[str]) -> None:
        if lines:
            self._output.write_raw("".join(f"{text}\n" for text in lines))
            self._output.flush()
