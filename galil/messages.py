"""Unsolicited output: where it comes from, the queue it lands in, and the callbacks it reaches.

A controller prints on its own (``MG`` in a program, a thread's errors). :class:`Messages`
routes that output away from command replies when the link connects: a second Ethernet handle
(``CF I`` sent on it, or a message-only port), else ``CW 1`` marks every unsolicited byte with
bit 7 on the command link. Lines land in a bounded :class:`MessageQueue` and go to subscribers
in order, outside the link lock, so a callback may send commands itself, on any transport.

The lines the library's own routines print for the library (the input wait's ``galil-input
n``: :func:`galil.routines.is_library_line`) go to the library's subscribers only
(:meth:`Messages.subscribe_library`), never to the queue or the user's callbacks: a script
reading its own program's ``MG`` output sees none of them (decision 0086).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections import deque
from collections.abc import Callable

from galil.errors import GalilConnectionError, GalilError, ProtocolError
from galil.link import Link, check_count, read_handle, read_reply, warn_caller
from galil.protocol import commands as cmds
from galil.protocol.framing import FrameParser, Unsolicited
from galil.protocol.numbers import read_one
from galil.queues import BoundedQueue, Subscribers, source_ended
from galil.routines import is_library_line
from galil.transport import HandleSource, MessagesOnly, Transport

__all__ = ["MessageCallback", "MessageQueue", "Messages"]

_LOG = logging.getLogger("galil.messages")

MessageCallback = Callable[[str], None]


class MessageQueue(BoundedQueue[str]):
    """Unsolicited lines from the controller, oldest first; a bounded, thread-safe queue.

    When nobody reads it, the oldest lines are dropped (``dropped`` counts them) rather than
    growing without end.
    """

    def __init__(self, maxlen: int = 1000) -> None:
        super().__init__(maxlen, "unsolicited message")


class _Dispatcher:
    """Delivers lines to callbacks in order, one at a time, never recursively.

    Whichever thread brings lines while nobody is delivering delivers them (and any that
    arrive meanwhile); a callback that sends a command, which brings more lines on the same
    thread, only queues them for the loop already running. No lock is held while a callback
    runs, so nothing can deadlock on it.
    """

    def __init__(self, what: str = "unsolicited-message") -> None:
        self.subscribers: Subscribers[str] = Subscribers(what, _LOG)
        self._pending: deque[str] = deque()
        self._state = threading.Lock()
        self._delivering = False

    def __call__(self, lines: list[str]) -> None:
        with self._state:
            self._pending.extend(lines)
            if self._delivering or not self.subscribers:
                if not self.subscribers:
                    self._pending.clear()
                return
            self._delivering = True
        try:
            while True:
                with self._state:
                    if not self._pending:
                        self._delivering = False
                        return
                    line = self._pending.popleft()
                self.subscribers.notify(line)
        except BaseException:
            with self._state:
                self._delivering = False
            raise


class Messages:
    """The unsolicited side of one controller: routing, the queue, callbacks, reader threads.

    Args:
        link: the command link.
        max_messages: lines kept in :attr:`queue` before the oldest drop.
        poll_interval: seconds between polls for lines while the link is idle.
    """

    def __init__(self, link: Link, *, max_messages: int = 1000, poll_interval: float = 0.02):
        check_count(max_messages, "max_messages")
        self.link = link
        self.queue = MessageQueue(max_messages)
        self._dispatch = _Dispatcher()
        self._library = _Dispatcher("library-message")  # (the library's own lines)
        self._poll_interval = poll_interval
        self._stop = threading.Event()
        self._pump: threading.Thread | None = None
        self._reader: threading.Thread | None = None
        self._secondary: Transport | None = None
        self._claimed = False  # the message handle was claimed with CF I (not given)
        self.marking = False  # unsolicited output is marked with CW 1 on the command link
        self._wanted_pump = False
        link.on_messages = self._accept
        self.queue.gone, self.queue.revive = link.gone, link.revive  # (a dead link's get())

    def _accept(self, lines: list[str]) -> None:
        users: list[str] = []
        library: list[str] = []
        for line in lines:
            (library if is_library_line(line) else users).append(line)
        for line in users:
            self.queue.put(line)
        if users:
            self._dispatch(users)
        if library:
            self._library(library)

    # -- subscribers ------------------------------------------------------------------------

    def subscribe(self, callback: MessageCallback) -> Callable[[], None]:
        """Call ``callback(line)`` for each unsolicited line; returns an unsubscriber."""
        unsubscribe = self._dispatch.subscribers.add(callback)
        self.ensure_polling()
        return unsubscribe

    def subscribe_library(self, callback: MessageCallback) -> Callable[[], None]:
        """Call ``callback(line)`` for each line the library's routines print for the
        library (:func:`~galil.routines.is_library_line`), which the queue and the user's
        callbacks never see; returns an unsubscriber."""
        unsubscribe = self._library.subscribers.add(callback)
        self.ensure_polling()
        return unsubscribe

    # -- routing at connect -----------------------------------------------------------------

    def route(self) -> None:
        """Send unsolicited output away from replies (second handle, else CW1 marking)."""
        link = self.link
        transport = link.transport
        assert transport is not None
        self._stop = threading.Event()
        self._claimed = self.marking = False
        ready = transport.secondary
        if ready is not None:
            # The transport brought its own message handle (a simulator's, a gateway's).
            self._start_reader(ready, "the transport's message handle")
            return
        if isinstance(transport, HandleSource) and link.model.has_ethernet:
            try:
                secondary = transport.open_secondary()
                if isinstance(secondary, MessagesOnly) and secondary.messages_only:
                    self._start_reader(secondary, "the message port")
                else:
                    self._claim(secondary)
                return
            except GalilError as exc:
                with contextlib.suppress(AttributeError):
                    transport.secondary = None  # closed: do not offer it to anyone
                warn_caller(
                    f"no second Ethernet handle for unsolicited messages ({exc}); "
                    "they will be marked with CW1 on the command handle instead",
                )
        self._mark()

    def _claim(self, secondary: Transport) -> None:
        # "CF I" sent on a handle makes that handle the destination of unsolicited output.
        try:
            read_reply(secondary, b"CF I\r", self.link.timeout)
        except GalilError:
            with contextlib.suppress(GalilError, OSError):
                secondary.close()
            raise
        self._start_reader(secondary, "the second Ethernet handle (CF I)")
        self._claimed = True

    def after_reset(self, previous: int | None) -> None:
        """After ``RS`` on the same link (``Controller.reset``): route unsolicited output again
        as at connect: ``CF I`` on a claimed message handle, ``CW 1`` where output is marked.

        Args:
            previous: ``_CW`` as read right after ``RS`` (restored at close), if it was.
        """
        secondary, reader = self._secondary, self._reader
        if self._claimed and secondary is not None:
            # The reader would take the reply: it pauses while CF I is asked on its handle.
            self._stop.set()
            if reader is not None and reader is not threading.current_thread():
                reader.join(timeout=2.0)
            self._stop = threading.Event()
            try:
                read_reply(secondary, b"CF I\r", self.link.timeout)
            finally:
                self._start_reader(secondary, "the second Ethernet handle (CF I again)")
        elif self.marking:
            self._mark(previous)

    def _mark(self, known: int | None = None) -> None:
        """``CW 1`` on the command link (the previous setting, or ``known``, restored at
        close)."""
        link = self.link
        with link.locked():
            previous = _read_cw(link) if known is None else known
            ok = _set_cw1(link)
        if not ok:
            warn_caller(
                f"{link.model.name} refused CW 1: unsolicited output is not marked and may be "
                "mistaken for replies",
            )
            return
        self.marking = True
        if previous != 1:
            link.restore_on_close(cmds.cw(previous), own=cmds.cw(1))

    def _start_reader(self, secondary: Transport, where: str) -> None:
        self.link.note(f"unsolicited output comes on {where}")
        self._secondary = secondary
        self._reader = threading.Thread(
            target=self._read_secondary,
            args=(secondary, self._stop),
            name=f"galil-messages-{self.link.model_name}",
            daemon=True,
        )
        self._reader.start()

    # -- threads ----------------------------------------------------------------------------

    def ended(self) -> str:
        """Why no more lines will come (the controller was closed, or its link died: the
        queue's :meth:`~galil.queues.BoundedQueue.ended`); ``""`` while they may."""
        return self.queue.ended()

    def ensure_polling(self) -> None:
        """Poll an idle command link for unsolicited lines (unless a handle carries them)."""
        self._wanted_pump = True
        if self._pump is not None or self._reader is not None or not self.link.is_open:
            return
        self._pump = threading.Thread(
            target=self._poll_idle, args=(self._stop,), name="galil-poll", daemon=True
        )
        self._pump.start()

    def poll(self) -> None:
        """Read what an idle command link holds now, when no handle of its own carries the
        lines (a zero-timeout read; nothing when a command is under way: it collects them).

        The idle poll runs on real time; a wait on a simulator's clock calls this between
        its pauses, so a line printed in simulated time is heard in it, not seconds later.
        """
        if self._reader is None and self.link.is_open:
            self.link.poll_unsolicited(0.0)

    def _poll_idle(self, stop: threading.Event) -> None:
        # Reads only with a zero timeout while holding the lock, so a command never waits
        # behind a blocked poll.
        while not stop.wait(self._poll_interval):
            if not self.link.poll_unsolicited(self._poll_interval):
                # Closed or dead: whoever waits for a line hears so (unless stopped).
                source_ended(self.link, self.queue, stop, "the command link", None)
                return

    def _read_secondary(self, secondary: Transport, stop: threading.Event) -> None:
        parser = FrameParser(unsolicited_only=True)
        while not stop.is_set():
            try:
                chunk = read_handle(secondary, 0.25)
            except GalilConnectionError as exc:
                if not stop.is_set():  # (closed by stop(): nothing to tell)
                    source_ended(self.link, self.queue, stop, "the message handle", exc)
                return
            if not chunk:
                # Some handles return at once when idle (a simulator's): do not spin.
                stop.wait(self._poll_interval)
                continue
            try:
                events = parser.feed(chunk)
            except ProtocolError:
                parser.reset()
                continue
            lines = [ev.line for ev in events if type(ev) is Unsolicited]
            if lines:
                self.link.post_messages(lines)

    def stop(self) -> None:
        """Stop the reader threads and close the message handle (after the link closed)."""
        self._stop.set()
        if self._secondary is not None:
            with contextlib.suppress(GalilError, OSError):
                self._secondary.close()
        me = threading.current_thread()
        for t in (self._pump, self._reader):
            if t is not None and t is not me:
                t.join(timeout=2.0)
        self._pump = self._reader = None
        self._secondary = None

    def restart(self) -> None:
        """After a reconnect: route again, and poll again if someone was listening."""
        self.route()
        if self._wanted_pump:
            self.ensure_polling()

    @property
    def threads(self) -> list[threading.Thread]:
        """The background threads now running (for tests and diagnostics)."""
        return [t for t in (self._pump, self._reader) if t is not None and t.is_alive()]


# A running program's output is not marked until CW 1 has run, and may come in front of a
# reply: the link is then out of step, and the exchange is tried again (it resynchronises).
_TRIES = 3


def _read_cw(link: Link) -> int:
    """``_CW`` as the controller has it (lock held); the factory default (2: unmarked) if it
    cannot be read."""
    for _ in range(_TRIES):
        try:
            done = link.roundtrip_locked([cmds.mg_operand("_CW")], link.timeout)[0]
            value = round(read_one(done.text)) if done.ok else None
        except ProtocolError:
            continue  # (a program's line came first: ask again)
        except (GalilError, ValueError):
            break
        return value if value in (1, 2) else 2
    return 2


def _set_cw1(link: Link) -> bool:
    """``CW 1`` (lock held): whether it took. A reply out of step is no refusal: ``CW 1``
    may have run, and goes again (the same setting; once it runs, output is marked and
    cannot get in the way); if it never got a clean answer, ``_CW`` says."""
    for _ in range(_TRIES):
        try:
            return link.roundtrip_locked([cmds.cw(1)], link.timeout)[0].ok
        except ProtocolError:
            continue
        except GalilError:
            return False
    return _read_cw(link) == 1
