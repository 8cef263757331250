"""``galil terminal``: type to a controller as in Galil's own terminal.

Every line goes to the controller as typed, compound lines included (``PRA=1000;BGA``); the
reply is printed, a ``?`` is explained with ``TC1`` and the session goes on, and unsolicited
output (a program's ``MG``) is printed the moment it arrives. ``DL`` alone starts a program
download: the lines typed (or pasted) after it are collected until a line holding ``\\`` and
sent as one ``DL``. ``UL`` prints the program. ``RS`` alone resets the controller through
:meth:`~galil.Controller.reset` (the link is set up again), ``BN`` alone burns through
:meth:`~galil.Controller.save`; the commands that would change the link's own settings
(``CW 1``, ``EO 0``, ``CF``, ``^R^S``, ``RS`` or ``BN`` in a compound line) are not sent, and
the terminal says why. Ctrl-C sends ``ST`` (and says so), Ctrl-D
leaves; a reply that does not come in time is reported and the next command resynchronises the
link first.

On a terminal, input goes through prompt-toolkit (history, line editing, messages printed above
the prompt); piped input is read line by line, so ``galil terminal ADDRESS < setup.txt`` runs a
script.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

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

__all__ = ["Terminal", "default_history_path", "program_lines", "run_terminal"]

PROMPT = ":"
DOWNLOAD_PROMPT = "DL> "
# What TC 2 means at a terminal (AM, MC, WT and the other trippoints are "Not Valid in
# terminal" in the DMC-4103 command reference; decision 0044).
_PROGRAM_ONLY_HINT = (
    "  (program only: put it in a program (DL) and run that (XQ);"
    " from here, wait for a move by polling MG _BGA until it is 0)"
)


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
        assert self._download is not None
        text = line.replace("\t", " ").strip()
        head, slash, _ = text.partition("\\")
        if head:
            self._download.append(head)
        if not slash:
            return
        lines, self._download = self._download, None
        if not lines:
            self.write("download cancelled: no program lines")
            return
        self.download(lines)

    def download(self, lines: Iterable[str]) -> bool:
        """Send a program with ``DL``; print what happened. Returns whether it was accepted."""
        try:
            command = cmds.dl(list(lines), model=self.controller.model)
            link = self.controller.link
            wait = max(self.timeout, link.transfer_timeout(command))
            link.exchange(command, timeout=wait, stall=max(self.timeout, link.transfer_stall))
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

    def _send(self, command: str) -> None:
        try:
            reply = self.controller.command(command, timeout=self.timeout, allow_compound=True)
        except GalilError as exc:
            self._report(exc, command)
            return
        for text in reply.splitlines():
            self.write(text)

    def _report(self, exc: GalilError, command: str) -> None:
        message = str(exc.args[0]) if exc.args else type(exc).__name__
        if isinstance(exc, CommandError):
            code = "?" if exc.code is None else str(exc.code)
            self.write(f"? {code} {exc.text}")
            hint = message.partition("(Galil commands")
            if hint[1]:
                self.write(f"  (Galil commands{hint[2]}")
            elif exc.command != command:
                self.write(f"  (refused: {exc.command!r})")
            if exc.code == 2:
                self.write(_PROGRAM_ONLY_HINT)
        elif isinstance(exc, GalilTimeoutError):
            self.write(f"timeout: {message}; the controller may still be busy (Ctrl-C sends ST)")
        elif isinstance(exc, InvalidArgument):
            self.write(f"not sent: {message}")
        elif isinstance(exc, GalilConnectionError):
            if self.controller.link.dead or self.controller.closed:
                raise exc
            # Out of step and not back yet: the controller still holds an earlier reply.
            self.write(f"not sent: {message} (an earlier reply may still be due, e.g. a burn's)")
        else:
            self.write(f"error: {message}")

    def interrupt(self) -> None:
        """Ctrl-C: cancel a download being typed and stop all motion with ``ST``."""
        self.cancel()
        try:
            self.controller.stop()
        except GalilError as exc:
            if isinstance(exc, GalilConnectionError) and self.controller.link.dead:
                raise
            self.write(f"Ctrl-C: ST not sent: {exc.args[0] if exc.args else exc}")
            return
        self.write("Ctrl-C: sent ST, motion stopped on every axis (Ctrl-D leaves)")


def _print(text: str) -> None:
    print(text, flush=True)


def run_terminal(
    controller: Controller,
    *,
    timeout: float = 5.0,
    history: Path | None = None,
    interactive: bool | None = None,
) -> int:
    """Run the terminal on ``controller`` until Ctrl-D (or the end of piped input).

    Args:
        controller: the connected controller.
        timeout: seconds to wait for each reply.
        history: file that keeps the typed lines between sessions (``None``: memory only).
        interactive: use the line editor; default: when stdin and stdout are terminals.
    """
    if interactive is None:
        interactive = sys.stdin.isatty() and sys.stdout.isatty()
    screen = _Screen() if interactive else None
    term = Terminal(controller, timeout=timeout, write=screen.write if screen else None)
    unsubscribe = controller.subscribe(term.write)
    try:
        if screen is not None:
            _interactive(term, screen, history)
        else:
            _piped(term)
    finally:
        unsubscribe()
    return 0


def _piped(term: Terminal) -> None:
    while True:
        try:
            line = sys.stdin.readline()
            if not line:
                return
            term.feed(line.rstrip("\r\n"))
        except KeyboardInterrupt:
            term.interrupt()


def _interactive(term: Terminal, screen: _Screen, history_file: Path | None) -> None:
    from prompt_toolkit import PromptSession
    from prompt_toolkit.history import FileHistory, History, InMemoryHistory

    history: History = InMemoryHistory()
    if history_file is not None:
        try:
            history_file.parent.mkdir(parents=True, exist_ok=True)
            history = FileHistory(str(history_file))
        except OSError:
            pass  # a read-only home: keep the history for this session only
    session: PromptSession[str] = PromptSession(history=history)
    # Ctrl-C at the prompt is a key; between prompts (the tty is then in cooked mode) it is a
    # SIGINT, which must not land inside prompt-toolkit's setup: it is noted and handled here.
    state = {"interrupted": False}

    def note(signum: int, frame: object) -> None:
        state["interrupted"] = True

    previous = signal.getsignal(signal.SIGINT)
    try:
        _prompt_loop(term, screen, session, note, state)
    finally:
        signal.signal(signal.SIGINT, previous)


def _prompt_loop(
    term: Terminal,
    screen: _Screen,
    session: Any,
    note: Callable[[int, Any], None],
    state: dict[str, bool],
) -> None:
    # Anything else printed while the prompt is shown (a warning, say) goes above it too.
    from prompt_toolkit.patch_stdout import patch_stdout

    with patch_stdout(raw=True):
        while True:
            signal.signal(signal.SIGINT, note)
            line: str | None = None

            def start(app: Any = session.app) -> None:
                screen.prompt_shown(app)
                # A Ctrl-C that came while the prompt was being set up: act on it now.
                if state["interrupted"]:
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
                screen.prompt_gone()
            if state["interrupted"]:
                state["interrupted"] = False
                term.interrupt()
                continue
            if line is None:
                continue
            signal.signal(signal.SIGINT, signal.default_int_handler)
            try:
                try:
                    term.feed(line)
                finally:
                    # Noted again before the loop goes round: a Ctrl-C just after the reply
                    # (shown before feed returns) would raise where nothing catches it.
                    signal.signal(signal.SIGINT, note)
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
