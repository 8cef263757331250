"""The Controller: one link to one controller, safe to share between threads.

``connect(address)`` opens a transport (``galil.transport``), identifies the controller
(``^R^V``), routes its unsolicited output away from replies, and returns a :class:`Controller`.
Every exchange goes through a sans-I/O :class:`~galil.protocol.session.Session` under one lock
per link, so each caller gets its own reply however many threads share the link::

    with galil.connect("tcp://192.168.0.2") as c:
        c.command("SHA")
        c.query_number("MG _TPA")        # -> 0.0
        c.messages.get(timeout=5)        # a line a program printed with MG

A ``?`` is explained at once with ``TC1`` and raised as :class:`~galil.errors.CommandError`;
every error carries the last exchanges (``error.recent``). Bytes on the wire are logged at DEBUG
on the ``galil.wire`` logger.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import re
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from galil.codes import parse_tc1
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
)
from galil.models import Identity, ModelSpec, get_model, parse_identity
from galil.protocol import commands as cmds
from galil.protocol.commands import Command, Expect
from galil.protocol.framing import FrameParser, Unsolicited
from galil.protocol.numbers import parse_number
from galil.protocol.records import RecordSplitter, decode_record, parse_qz, record_to_dict
from galil.protocol.session import Completed, Session
from galil.transport import Transport, open_transport

if TYPE_CHECKING:
    from galil.axis import Axis

__all__ = ["CLIENT_OPTIONS", "Controller", "MessageQueue", "RecordStream", "WireLog", "connect"]

_WIRE = logging.getLogger("galil.wire")
# The logger's own cache of isEnabledFor() answers (cleared in place when levels change): one
# dict lookup on the hot path instead of a method call; None when not known yet.
_WIRE_CACHE: dict[int, bool] = getattr(_WIRE, "_cache", {})
_LOG = logging.getLogger("galil.client")
_DEBUG = logging.DEBUG
_monotonic = time.monotonic

CLIENT_OPTIONS = frozenset(
    {
        "timeout",
        "model",
        "handshake",
        "unsolicited",
        "history",
        "poll_interval",
        "max_messages",
        "echo",
    }
)
"""Keyword options :func:`connect` keeps for the :class:`Controller`; the rest go to the
transport opener (``baudrate=``, ``port=``, ``backend=`` ...)."""

_E = TypeVar("_E", bound=GalilError)

# ^R^V with any reply shape, and what its echo looks like in front of the identity (the
# controller may or may not echo the control characters; an echoed CR may gain an LF).
_IDENTIFY_ANY = Command("\x12\x16", Expect.ANY)
_ECHO_OF_IDENTIFY = re.compile(r"[\x12\x16]*\r\n?")


# Polling loops send the same few lines again and again: each text is parsed once (a plain
# dict, looked up inline by Controller.command; cleared when it grows, so it stays bounded).
_PARSED: dict[str, Command] = {}


def _parse(text: str) -> Command:
    cmd = _PARSED.get(text)
    if cmd is None:
        cmd = cmds.parse_line(text)
        if len(_PARSED) >= 512:
            _PARSED.clear()
        _PARSED[text] = cmd
    return cmd


def _check_timeout(timeout: float | None, default: float) -> float:
    if timeout is None:
        return default
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not timeout > 0:
        raise InvalidArgument(f"timeout must be a positive number of seconds, not {timeout!r}")
    return float(timeout)


# ----------------------------------------------------------------------------------- messages


class MessageQueue:
    """Unsolicited lines from the controller, oldest first; a bounded, thread-safe queue.

    When nobody reads it, the oldest lines are dropped (``dropped`` counts them) rather than
    growing without end.
    """

    def __init__(self, maxlen: int = 1000) -> None:
        self._items: deque[str] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        self.dropped = 0

    def put(self, line: str) -> None:
        """Append a line (used by the client)."""
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(line)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> str:
        """Return the oldest line, waiting up to ``timeout`` seconds (``None``: for ever).

        Raises:
            queue.Empty: nothing arrived in time.
        """
        with self._cond:
            if not self._cond.wait_for(lambda: self._items, timeout):
                raise queue.Empty(f"no unsolicited message within {timeout} s")
            return self._items.popleft()

    def get_nowait(self) -> str:
        """Return the oldest line at once; raise ``queue.Empty`` when there is none."""
        with self._cond:
            if not self._items:
                raise queue.Empty("no unsolicited message waiting")
            return self._items.popleft()

    def drain(self) -> list[str]:
        """Remove and return every waiting line."""
        with self._cond:
            out = list(self._items)
            self._items.clear()
            return out

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def __repr__(self) -> str:
        return f"<MessageQueue {len(self)} waiting, {self.dropped} dropped>"


# ----------------------------------------------------------------------------------- wire log

WireHook = Callable[[str, bytes], None]
"""``hook(direction, data)``; direction is ``"out"`` (written) or ``"in"`` (read)."""


@dataclass
class WireCapture:
    """Bytes seen on the wire while a :meth:`WireLog.capture` block ran."""

    sent: bytearray = field(default_factory=bytearray)
    received: bytearray = field(default_factory=bytearray)

    def __call__(self, direction: str, data: bytes) -> None:
        (self.sent if direction == "out" else self.received).extend(data)


class WireLog:
    """Hooks that see every byte written to and read from the command link."""

    def __init__(self) -> None:
        self.hooks: list[WireHook] = []

    def add(self, hook: WireHook) -> Callable[[], None]:
        """Call ``hook(direction, data)`` for each write and read; returns a remover."""
        self.hooks = [*self.hooks, hook]  # copy-on-write: readers never see a half update

        def remove() -> None:
            self.hooks = [h for h in self.hooks if h is not hook]

        return remove

    @contextlib.contextmanager
    def capture(self) -> Iterator[WireCapture]:
        """Record the bytes of a block: ``with c.wire_log.capture() as w: ...; w.sent``."""
        cap = WireCapture()
        remove = self.add(cap)
        try:
            yield cap
        finally:
            remove()


# ----------------------------------------------------------------------------------- records

RecordCallback = Callable[["np.void"], None]


class RecordStream:
    """Data records at a fixed period, decoded, oldest first. Build it with
    :meth:`Controller.records`.

    Over Ethernet the controller pushes them (``DR period,handle``) to a handle of their own,
    read by a background thread into a bounded queue (``dropped`` counts records lost when
    nobody reads). Elsewhere (serial, USB, the in-process simulator) each :meth:`get` waits
    until the next record is due and asks for it with ``QR``, so records are as far apart as
    asked, in the controller's time (simulated time on a manual-clock simulator).

    Attributes:
        period: servo samples between records.
        method: ``"DR"`` (pushed) or ``"QR"`` (polled).
        dropped: records dropped from a full queue (``DR`` only).
    """

    def __init__(
        self,
        controller: Controller,
        period: int,
        method: str,
        *,
        handle: Transport | None = None,
        maxlen: int = 10_000,
    ) -> None:
        self.period = period
        self.method = method
        self.dropped = 0
        self._controller = controller
        self._handle = handle
        self._items: deque[np.void] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        self._closed = False
        self._error: GalilError | None = None
        self._subscribers: list[RecordCallback] = []
        self._next_due: float | None = None
        self._thread: threading.Thread | None = None

    def _start_reader(self, qz: tuple[int, int, int, int]) -> None:
        self._thread = threading.Thread(
            target=self._read, args=(qz,), name="galil-records", daemon=True
        )
        self._thread.start()

    def _read(self, qz: tuple[int, int, int, int]) -> None:
        handle = self._handle
        assert handle is not None
        splitter = RecordSplitter(qz)
        while not self._closed:
            try:
                chunk = handle.read(0.25)
                records = [decode_record(r, qz) for r in splitter.feed(chunk)] if chunk else []
            except ProtocolError as exc:
                # A stream out of step cannot be re-cut reliably: stop and say why.
                self._fail(exc)
                return
            except GalilConnectionError as exc:
                if not self._closed:
                    self._fail(exc)
                return
            if records:
                self._push(records)

    def _fail(self, exc: GalilError) -> None:
        with self._cond:
            self._error = exc
            self._cond.notify_all()

    def _push(self, records: list[np.void]) -> None:
        with self._cond:
            for rec in records:
                if len(self._items) >= self._maxlen:
                    self._items.popleft()
                    self.dropped += 1
                self._items.append(rec)
            self._cond.notify_all()
        for rec in records:
            self._notify(rec)

    def _notify(self, rec: np.void) -> None:
        for cb in self._subscribers:
            try:
                cb(rec)
            except Exception:
                _LOG.exception("data-record callback %r failed", cb)

    def subscribe(self, callback: RecordCallback) -> Callable[[], None]:
        """Call ``callback(record)`` for each record as it arrives; returns an unsubscriber.

        With ``DR`` the callback runs on the reader thread; with ``QR`` inside :meth:`get`.
        """
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        self._subscribers = [*self._subscribers, callback]

        def unsubscribe() -> None:
            self._subscribers = [c for c in self._subscribers if c is not callback]

        return unsubscribe

    def get(self, timeout: float | None = None) -> np.void:
        """Return the next record, waiting up to ``timeout`` seconds (``None``: for ever).

        Raises:
            queue.Empty: no record within ``timeout``.
            GalilConnectionError: the stream is closed (or its handle died).
            ProtocolError: the record stream could not be decoded.
        """
        if self.method == "QR":
            return self._poll(timeout)
        with self._cond:
            ready = self._cond.wait_for(
                lambda: self._items or self._closed or self._error is not None, timeout
            )
            if self._items:
                return self._items.popleft()
            if self._error is not None:
                raise self._error
            if self._closed:
                raise GalilConnectionError("the data-record stream is closed")
            assert not ready
            raise queue.Empty(f"no data record within {timeout} s")

    def _poll(self, timeout: float | None) -> np.void:
        if self._closed:
            raise GalilConnectionError("the data-record stream is closed")
        c = self._controller
        now = c._clock()
        if self._next_due is None:
            self._next_due = now
        wait = self._next_due - now
        if wait > 0:
            if timeout is not None and wait > timeout:
                c._pause(timeout)
                raise queue.Empty(f"no data record within {timeout} s")
            c._pause(wait)
        rec: np.void = c.record()
        # The next one is due a period after this one was due, so records do not drift.
        self._next_due = max(self._next_due, now) + self.period * c.sample_period
        self._notify(rec)
        return rec

    def take(self, n: int, timeout: float | None = None) -> np.ndarray[Any, np.dtype[Any]]:
        """Return the next ``n`` records as one structured array (``a["A"]["position"]``).

        ``timeout`` bounds the wait for each record.
        """
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InvalidArgument(f"n must be a positive integer, not {n!r}")
        first = self.get(timeout)
        out = np.empty(n, dtype=first.dtype)
        out[0] = first
        for i in range(1, n):
            out[i] = self.get(timeout)
        return out

    def __iter__(self) -> Iterator[np.void]:
        """Records until the stream is closed."""
        while True:
            try:
                yield self.get()
            except GalilConnectionError:
                return

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def close(self) -> None:
        """Stop the stream (``DR 0``) and close its handle; idempotent."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        c = self._controller
        c._record_streams = [s for s in c._record_streams if s is not self]
        if self.method == "DR":
            if not c.closed:
                with contextlib.suppress(GalilError):
                    c.command("DR 0")
            if self._handle is not None:
                with contextlib.suppress(GalilError, OSError):
                    self._handle.close()
            if self._thread is not None and self._thread is not threading.current_thread():
                self._thread.join(timeout=2.0)

    def __enter__(self) -> RecordStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        waiting = len(self)
        return (
            f"<RecordStream {self.method} every {self.period} samples, {waiting} waiting, {state}>"
        )


# ----------------------------------------------------------------------------------- the client


def _new_completed(fields: tuple[Any, ...]) -> Completed:
    # tuple.__new__ skips NamedTuple's argument handling: this is on the hot path.
    return tuple.__new__(Completed, fields)


def _format_exchange(entry: Completed | tuple[Any, ...]) -> str:
    if type(entry) is Completed:
        sent, reply, ok = entry.command.text, entry.text, entry.ok
        if ok:
            return f"-> {sent!r}  <- {reply!r}"
        return f"-> {sent!r}  <- ? {reply!r}" if reply else f"-> {sent!r}  <- ?"
    assert isinstance(entry, tuple)
    kind = entry[0]
    if kind == "m":
        return f"<< {entry[1]!r} (unsolicited)"
    if kind == "t":
        return f"-> {entry[1]!r}  (no reply: timeout)"
    return f"-- {entry[1]}"


class Controller:
    """A connected controller. Build it with :func:`connect`.

    Args:
        transport: an open transport, or a callable that opens one (used again by
            :meth:`reconnect`).
        timeout: default seconds to wait for each reply.
        model: the model name (or spec) when it is known; checked against ``^R^V``.
        handshake: identify the controller and route unsolicited output at connect; with
            ``False`` nothing is sent at connect and ``model`` is required.
        unsolicited: route unsolicited output (second Ethernet handle, else ``CW1``).
        history: exchanges kept in the ring buffer attached to errors.
        poll_interval: seconds between polls for unsolicited lines while the link is idle.
        max_messages: unsolicited lines kept in :attr:`messages` before the oldest drop.
        echo: what to do when the handshake finds the controller echoing (``EO 1``, a serial
            setting): ``False`` (default) switches the echo off with ``EO 0``, as Galil's own
            library does, and :meth:`close` switches it back on; ``True`` leaves it on and
            strips the echo from every reply.

    Attributes:
        transport: the open :class:`~galil.transport.Transport`.
        model: the controller's :class:`~galil.models.ModelSpec`.
        identity: the parsed ``^R^V`` reply (``None`` without a handshake).
        timeout: default reply timeout in seconds.
        bytes_sent / bytes_received: counters of bytes written to / read from the command link.
        wire_log: hooks on the raw bytes (:class:`WireLog`).
    """

    def __init__(
        self,
        transport: Transport | Callable[[], Transport],
        *,
        timeout: float = 1.0,
        model: str | ModelSpec | None = None,
        handshake: bool = True,
        unsolicited: bool = True,
        history: int = 64,
        poll_interval: float = 0.02,
        max_messages: int = 1000,
        echo: bool = False,
    ) -> None:
        self.timeout = _check_timeout(timeout, 1.0)
        if not isinstance(echo, bool):
            raise InvalidArgument(f"echo must be True or False, not {echo!r}")
        self._keep_echo = echo
        if not handshake and model is None:
            raise InvalidArgument("handshake=False needs model= (nothing identifies it then)")
        if isinstance(history, bool) or not isinstance(history, int) or history < 1:
            raise InvalidArgument(f"history must be a positive integer, not {history!r}")
        self._given_model = get_model(model) if isinstance(model, str) else model
        self._handshake = handshake
        self._unsolicited = unsolicited
        self._poll_interval = _check_timeout(poll_interval, 0.02)
        if callable(transport) and not isinstance(transport, Transport):
            self._factory: Callable[[], Transport] | None = transport
            first: Transport | None = None
        else:
            self._factory = None
            first = transport
        self._lock = threading.Lock()
        # Completed replies are kept as they are (immutable); text is made only for an error.
        self._recent: deque[Completed | tuple[Any, ...]] = deque(maxlen=history)
        self.messages_queue = MessageQueue(max_messages)
        self._subscribers: list[Callable[[str], None]] = []
        self._undelivered: list[str] = []
        self._dispatch_lock = threading.Lock()
        self.wire_log = WireLog()
        self.bytes_sent = 0
        self.bytes_received = 0
        self.model: ModelSpec = self._given_model  # type: ignore[assignment]  # set by _open
        self.identity: Identity | None = None
        self.transport: Transport = None  # type: ignore[assignment]  # set by _open
        self._session = Session()
        self._open_flag = False
        self._dead = ""  # why the command link broke, until reconnect()
        self._cw_restore: int | None = None
        self._eo_restore = False
        #: Whether the controller echoes (found at the handshake).
        self.echo = False
        self._qz: tuple[int, int, int, int] | None = None
        self._record_streams: list[RecordStream] = []
        self._pump: threading.Thread | None = None
        self._reader: threading.Thread | None = None
        self._stop = threading.Event()
        self._axes: dict[str, Axis] | None = None
        self._open(first)

    # -- life cycle -------------------------------------------------------------------------

    def _open(self, transport: Transport | None) -> None:
        if transport is None:
            if self._factory is None:
                raise GalilConnectionError("no transport and no address to open one")
            transport = self._factory()
        self.transport = transport
        clock, _ = self._sim_clock()
        self._link_clock: Any = clock if hasattr(clock, "now") else None
        self._session = Session()
        self._stop = threading.Event()
        self._cw_restore = None
        self._eo_restore = False
        self.echo = False
        self._qz = None
        self._open_flag = True
        self._dead = ""
        try:
            with self._lock:
                self._drain_stale()
                if self._handshake:
                    self._identify()
                    if self._unsolicited:
                        self._route_unsolicited()
                else:
                    self.model = self._given_model  # type: ignore[assignment]
        except BaseException:
            self._teardown()
            raise
        finally:
            self._deliver()

    def _drain_stale(self) -> None:
        # Bytes left over from an earlier program or session would be taken for our replies.
        for _ in range(64):
            if not self._read(0.0):
                return

    def _identify(self) -> None:
        given = self._given_model
        try:
            # Any reply shape: with echo on, the echo of ^R^V comes first (maybe a line of
            # its own), and that is how the echo is found.
            reply = self._roundtrip([_IDENTIFY_ANY], self.timeout)[0]
        except GalilTimeoutError as exc:
            raise self._error(
                GalilConnectionError,
                f"no answer to ^R^V on {self.transport!r} within {self.timeout} s: is a Galil "
                "controller on the other end (and the baud rate right)?",
            ) from exc
        ident: Identity | None = None
        problem = ""
        if reply.ok:
            echo = _ECHO_OF_IDENTIFY.match(reply.text)
            if echo is not None and echo.end():
                reply = Completed(reply.command, True, reply.text[echo.end() :])
                self._handle_echo()
            try:
                ident = parse_identity(reply.text)
            except InvalidArgument as exc:
                problem = str(exc)
        else:
            problem = "the controller refused ^R^V"
        if ident is None:
            if given is None:
                raise self._error(
                    GalilConnectionError,
                    f"cannot identify the controller ({problem}); pass model='DMC-....'",
                )
            warnings.warn(
                f"{problem}; using model={given.name} as given", RuntimeWarning, stacklevel=4
            )
            self.model = given
            return
        self.identity = ident
        self.model = ident.model
        if given is not None and given.name != ident.model.name:
            warnings.warn(
                f"model={given.name} was given but the controller says {ident.raw_model}; "
                f"using {ident.model.name}",
                RuntimeWarning,
                stacklevel=4,
            )

    def _handle_echo(self) -> None:
        # The controller echoes what it receives: strip the echo from now on, and unless the
        # caller wants to keep it, switch it off (restored by close()).
        self.echo = True
        self._session = Session(echo=True)
        self._remember(("n", "the controller echoes (EO 1)"))
        if self._keep_echo:
            return
        try:
            done = self._roundtrip([cmds.eo(0)], self.timeout)[0]
        except (GalilTimeoutError, ProtocolError):
            done = Completed(cmds.eo(0), False)  # the session resynchronises before the next
        if done.ok:
            self._session = Session()
            self._eo_restore = True
            self.echo = False
            return
        warnings.warn(
            f"{self.model.name if self.model else 'the controller'} echoes and refused EO 0; "
            "the echo is stripped from every reply",
            RuntimeWarning,
            stacklevel=6,
        )

    def _route_unsolicited(self) -> None:
        ready = getattr(self.transport, "secondary", None)
        if ready is not None:
            # The transport brought its own message handle (a simulator's, a gateway's).
            self._start_reader(ready, "the transport's message handle")
            return
        opener = getattr(self.transport, "open_secondary", None)
        if opener is not None and "ethernet" in self.model.transports:
            try:
                secondary = opener()
                if getattr(secondary, "messages_only", False):
                    self._start_reader(secondary, "the message port")
                else:
                    self._claim_secondary(secondary)
                return
            except GalilError as exc:
                with contextlib.suppress(AttributeError):
                    self.transport.secondary = None  # closed: do not offer it to anyone
                warnings.warn(
                    f"no second Ethernet handle for unsolicited messages ({exc}); "
                    "they will be marked with CW1 on the command handle instead",
                    RuntimeWarning,
                    stacklevel=6,
                )
        self._enable_marking()

    def _claim_secondary(self, secondary: Transport) -> None:
        # "CF I" sent on a handle makes that handle the destination of unsolicited output.
        secondary.write(b"CF I\r")
        deadline = time.monotonic() + self.timeout
        got = b""
        while not got.rstrip().endswith((b":", b"?")):
            left = deadline - time.monotonic()
            if left <= 0:
                with contextlib.suppress(GalilError):
                    secondary.close()
                raise GalilTimeoutError("no answer to CF I on the second handle")
            got += secondary.read(left)
        if got.rstrip().endswith(b"?"):
            with contextlib.suppress(GalilError):
                secondary.close()
            raise CommandError(None, "CF I refused on the second handle", "CF I")
        self._start_reader(secondary, "the second Ethernet handle (CF I)")

    def _start_reader(self, secondary: Transport, where: str) -> None:
        self._remember(("n", f"unsolicited output comes on {where}"))
        self._reader = threading.Thread(
            target=self._read_secondary,
            args=(secondary, self._stop),
            name=f"galil-messages-{self.model.name}",
            daemon=True,
        )
        self._reader.start()

    def _enable_marking(self) -> None:
        previous = 2  # factory default: unsolicited characters unmarked
        try:
            done = self._roundtrip([cmds.mg_operand("_CW")], self.timeout)[0]
            if done.ok:
                value = round(parse_number(done.text.split(",")[0]))
                if value in (1, 2):
                    previous = value
        except (GalilTimeoutError, ProtocolError, InvalidArgument):
            pass  # optional: without a reading we restore the factory default
        try:
            done = self._roundtrip([cmds.cw(1)], self.timeout)[0]
        except GalilTimeoutError:
            done = Completed(cmds.cw(1), False)
        if not done.ok:
            warnings.warn(
                f"{self.model.name} refused CW 1: unsolicited output is not marked and may be "
                "mistaken for replies",
                RuntimeWarning,
                stacklevel=5,
            )
            return
        self._cw_restore = previous

    def close(self) -> None:
        """Restore what connect changed (``CW``), stop the readers and close the link.

        Idempotent; never raises for a link that is already dead.
        """
        for stream in list(self._record_streams):
            stream.close()
        with self._lock:
            if not self._open_flag:
                return
            if self._cw_restore is not None and self._cw_restore != 1:
                with contextlib.suppress(GalilError):
                    self._roundtrip([cmds.cw(self._cw_restore)], min(self.timeout, 0.5))
            if self._eo_restore:
                # Last: once the echo is back on, replies carry it and we expect none.
                with contextlib.suppress(GalilError):
                    self._roundtrip([cmds.eo(1)], min(self.timeout, 0.5))
            self._teardown()
        self._join_threads()

    def _teardown(self) -> None:
        self._open_flag = False
        self._stop.set()
        with contextlib.suppress(GalilError, OSError):
            self.transport.close()

    def _join_threads(self) -> None:
        me = threading.current_thread()
        for t in (self._pump, self._reader):
            if t is not None and t is not me:
                t.join(timeout=2.0)
        self._pump = self._reader = None

    def reconnect(self) -> None:
        """Close the link and open it again (same address and options), handshake included.

        Raises:
            GalilConnectionError: the controller was built on a transport object, not an
                address, or the new link fails.
        """
        if self._factory is None:
            raise GalilConnectionError(
                "this Controller was given a transport object; reconnect needs an address "
                "(use galil.connect(address))"
            )
        had_pump = self._pump is not None
        self.close()
        self._open(None)
        if had_pump:
            self._ensure_pump()

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (or connecting failed)."""
        return not self._open_flag

    def __enter__(self) -> Controller:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self.closed else ("dead: call reconnect()" if self._dead else "open")
        name = self.model.name if self.model is not None else "?"
        return f"<Controller {name} on {self.transport!r} {state}>"

    # -- commands ---------------------------------------------------------------------------

    def command(
        self, text: str, *, timeout: float | None = None, allow_compound: bool = False
    ) -> str:
        """Send one raw command line and return its reply text (``""`` for a plain ``:``).

        A ``;`` outside quotes would start a second command: it is refused unless
        ``allow_compound=True`` (the replies of the parts are then joined by CR LF).

        Raises:
            InvalidArgument: the text cannot be sent (CR/LF, non-ASCII, a stray ``;``).
            CommandError: the controller answered ``?`` (code and text from ``TC1``).
            GalilTimeoutError: no complete reply within the timeout.
            GalilConnectionError: the link is closed or dead.
        """
        cmd = _PARSED.get(text) if type(text) is str else None
        if cmd is None:
            cmd = _parse(text) if type(text) is str else cmds.parse_line(text)
        if cmd.parts and not allow_compound:
            raise InvalidArgument(
                f"{text!r} holds {len(cmd.parts)} commands; send one command, or pass "
                "allow_compound=True, or use command_line([...])"
            )
        # _transact inlined: this is the path every raw command takes.
        t = self.timeout if timeout is None else _check_timeout(timeout, self.timeout)
        lock = self._lock
        # acquire/release rather than `with`: half the cost on the hot path (~0.3 us).
        lock.acquire()
        try:
            if not self._open_flag or self._dead:
                raise self._closed_error()
            session = self._session
            if (
                cmd.parts
                or session.out_of_step
                or self._link_clock is not None
                or self.wire_log.hooks
                or _WIRE_CACHE.get(_DEBUG, True)  # unknown: take the general path
            ):
                done = self._roundtrip((cmd,), t)
            else:
                # _roundtrip's common case inlined (one command, no hooks, a real link,
                # the whole reply in the first read): on a fast link every line of Python
                # here is latency.
                data = session.quick_wire(cmd)
                queued = data is None
                if data is None:
                    data = session.send(cmd)
                self.bytes_sent += len(data)
                start = _monotonic()
                transport = self.transport
                try:
                    transport.write(data)
                    chunk = transport.read(t)
                except GalilConnectionError as exc:
                    if not queued:
                        session.send(cmd)  # the bytes went out: the reply may still come
                    raise self._link_failed(exc) from exc
                if not queued:
                    reply = session.quick_reply(cmd, chunk) if chunk else None
                    if reply is not None:
                        self.bytes_received += len(chunk)
                        self._recent.append(_new_completed((cmd, True, reply, None)))
                        return reply
                    session.send(cmd)  # anything else: the session matches it as usual
                events = self._take(chunk, False)  # no hooks or logging on this path
                done = self._collect((cmd,), t, start, 0.0, events, False)
            if len(done) == 1:
                d = done[0]
                if d.ok:
                    return d.text
            for d in done:
                if not d.ok:
                    raise self._explain(d, t)
        finally:
            lock.release()
            if self._undelivered:
                self._deliver()
        return "\r\n".join(d.text for d in done if d.text)

    def command_line(
        self, parts: Sequence[str | Command], *, timeout: float | None = None
    ) -> list[str]:
        """Send several commands as compound line(s) (``PRA=1;BGA``); one reply per part.

        The parts are joined with ``;`` up to the model's line length (longer runs go on
        further lines, in order).

        Raises:
            InvalidArgument: a part is itself compound or cannot be sent.
            CommandError: a part was rejected (the error names it).
        """
        if isinstance(parts, str):
            raise InvalidArgument("command_line takes a list of commands, not one string")
        singles: list[Command] = []
        for p in parts:
            c = p if isinstance(p, Command) else _parse(p)
            if c.parts:
                raise InvalidArgument(f"{c.text!r} is already compound; pass its parts")
            singles.append(c)
        if not singles:
            return []
        lines = cmds.pack(singles, self.model.line_length if self.model else 80)
        return [d.text for d in self._transact(tuple(lines), timeout)]

    def send(self, command: Command, *, timeout: float | None = None) -> str:
        """Send a prepared :class:`~galil.protocol.commands.Command`; return its reply text."""
        return self.exchange(command, timeout=timeout).text

    def exchange(self, command: Command, *, timeout: float | None = None) -> Completed:
        """Send a prepared command and return the whole :class:`Completed` (``record`` for QR).

        A compound command (from ``protocol.commands.pack``) returns its last part's reply.
        """
        if not isinstance(command, Command):
            raise InvalidArgument(f"exchange() takes a Command, not {type(command).__name__}")
        return self._transact((command,), timeout)[-1]

    def send_many(self, commands: Iterable[Command], *, timeout: float | None = None) -> list[str]:
        """Send prepared commands back to back (pipelined) and return every reply text."""
        batch = tuple(commands)
        for c in batch:
            if not isinstance(c, Command):
                raise InvalidArgument(f"send_many() takes Commands, not {type(c).__name__}")
        if not batch:
            return []
        return [d.text for d in self._transact(batch, timeout)]

    def query_number(self, text: str, *, timeout: float | None = None) -> float:
        """Send a query (``"MG _TPA"``, ``"TPA"``) and return its one number.

        Raises:
            ProtocolError: the reply is not exactly one number.
        """
        values = self.query_numbers(text, timeout=timeout)
        if len(values) != 1:
            raise self._error(ProtocolError, f"{text!r} answered {len(values)} numbers, not one")
        return values[0]

    def query_numbers(self, text: str, *, timeout: float | None = None) -> list[float]:
        """Send a query and return every number in its reply (``"TP"`` -> ``[0.0, 5.0, ...]``)."""
        reply = self.command(text, timeout=timeout)
        try:
            return _numbers(reply)
        except (InvalidArgument, ValueError, ProtocolError) as exc:
            raise self._error(ProtocolError, f"{text!r} answered {reply!r}: {exc}") from exc

    def query_operands(self, names: Sequence[str], *, timeout: float | None = None) -> list[float]:
        """Read operands or variables (``["_TPA", "_SCA", "speed"]``) in as few lines as fit.

        The ``MG`` lines go out pipelined under one lock, so no other thread's command
        lands between them.
        """
        names = list(names)
        if not names:
            return []
        limit = (self.model.line_length if self.model else 80) - 4
        batches: list[list[str]] = [[]]
        length = 0
        for n in names:
            if batches[-1] and length + len(n) + 1 > limit:
                batches.append([])
                length = 0
            batches[-1].append(n)
            length += len(n) + 1
        lines = [cmds.mg_operand(*b) for b in batches]
        done = self._transact(tuple(lines), timeout)
        out: list[float] = []
        for batch, d in zip(batches, done, strict=True):
            try:
                values = _numbers(d.text)
            except (InvalidArgument, ValueError, ProtocolError) as exc:
                raise self._error(ProtocolError, f"MG {batch} answered {d.text!r}: {exc}") from exc
            if len(values) != len(batch):
                raise self._error(
                    ProtocolError,
                    f"MG {','.join(batch)} answered {d.text!r}: not {len(batch)} numbers",
                )
            out += values
        return out

    # The axis layer's spellings.
    _query_numbers = query_operands

    def _query_ints(self, names: Sequence[str]) -> list[int]:
        return [round(v) for v in self.query_operands(names)]

    # -- the exchange -----------------------------------------------------------------------

    def _transact(self, batch: Sequence[Command], timeout: float | None) -> list[Completed]:
        t = self.timeout if timeout is None else _check_timeout(timeout, self.timeout)
        try:
            with self._lock:
                if not self._open_flag or self._dead:
                    raise self._closed_error()
                done = self._roundtrip(batch, t)
                for d in done:
                    if not d.ok:
                        raise self._explain(d, t)
                return done
        finally:
            if self._undelivered:
                self._deliver()

    def _roundtrip(self, batch: Sequence[Command], t: float) -> list[Completed]:
        """Write ``batch`` and read until every reply is complete (lock held).

        This is the hot path of every command: it calls the transport directly and keeps
        clock reads, logging checks and allocations to the minimum.
        """
        session = self._session
        if session.out_of_step:
            self._resync(t)
        if len(batch) == 1:
            data = session.send(batch[0])
        else:
            data = b"".join([session.send(c) for c in batch])
        transport = self.transport
        # Bookkeeping happens before the write: any Python work between the write and the
        # read delays the reply (a local peer may be waiting for the GIL we hold).
        self.bytes_sent += len(data)
        watch = self.wire_log.hooks or _WIRE.isEnabledFor(_DEBUG)
        if watch:
            self._observe("out", data)
        clock = self._link_clock
        sim_start = clock.now() if clock is not None else 0.0
        start = _monotonic()
        try:
            transport.write(data)
            chunk = transport.read(t)  # the timeout as given, so transports can cache it
        except GalilConnectionError as exc:
            raise self._link_failed(exc) from exc
        events = self._take(chunk, watch)
        if len(events) == 1 and not session.pending and type(events[0]) is Completed:
            # The common case: the whole reply in one read.
            self._recent.append(events[0])
            return events  # type: ignore[return-value]
        return self._collect(batch, t, start, sim_start, events, watch)

    def _collect(
        self,
        batch: Sequence[Command],
        t: float,
        start: float,
        sim_start: float,
        events: list[Completed | Unsolicited],
        watch: object,
    ) -> list[Completed]:
        """Take ``events`` (from the first read), then read until ``batch`` is answered.

        ``start`` and ``sim_start`` are the wall and simulated times the batch was written.
        """
        session = self._session
        transport = self.transport
        recent = self._recent
        clock = self._link_clock
        done: list[Completed] = []
        while True:
            for ev in events:
                if type(ev) is Completed:
                    done.append(ev)
                    recent.append(ev)
                else:
                    self._message(ev.line)  # type: ignore[union-attr]
            if not session.pending:
                return done
            wait = start + t - _monotonic()
            if clock is not None:
                # A simulator's reads let simulated time pass: the timeout counts in it too.
                wait = min(wait, sim_start + t - clock.now())
            if wait <= 0:
                lost = session.abandon()
                for c in lost:
                    recent.append(("t", c.text))
                raise self._error(
                    GalilTimeoutError,
                    f"no reply to {lost[0].text if lost else batch[-1].text!r} within {t:g} s "
                    "(the link will resynchronise before the next command)",
                )
            try:
                chunk = transport.read(wait)
            except GalilConnectionError as exc:
                raise self._link_failed(exc) from exc
            events = self._take(chunk, watch)

    def _take(self, chunk: bytes, watch: Any) -> list[Completed | Unsolicited]:
        """Count, log and parse one chunk read from the command link (nothing for b"")."""
        if not chunk:
            return []
        self.bytes_received += len(chunk)
        if watch:
            self._observe("in", chunk)
        try:
            return self._session.receive_data(chunk)
        except ProtocolError as exc:
            raise self._protocol_error(exc) from exc

    def _protocol_error(self, exc: ProtocolError) -> ProtocolError:
        self._remember(("n", f"protocol error: {exc}"))
        return self._error(ProtocolError, str(exc))

    def _resync(self, t: float) -> None:
        session = self._session
        self._remember(("n", "link out of step: resynchronising"))
        self._write(session.resync())
        limit = max(t, 0.2)
        clock = self._link_clock
        sim_deadline = clock.now() + limit if clock is not None else 0.0
        deadline = time.monotonic() + limit
        while session.out_of_step:
            wait = deadline - time.monotonic()
            if clock is not None:
                wait = min(wait, sim_deadline - clock.now())
            chunk = self._read(max(wait, 0.0))
            if chunk:
                try:
                    events = session.receive_data(chunk)
                except ProtocolError:
                    continue  # the parser is hunting for the marker; junk is expected
                for ev in events:
                    if type(ev) is Unsolicited:
                        self._message(ev.line)
            elif wait <= 0:
                raise self._error(
                    GalilConnectionError,
                    f"the link is out of step and did not resynchronise within {max(t, 0.2):g} s;"
                    " call reconnect()",
                )
        self._remember(("n", "link back in step"))

    def _explain(self, rejected: Completed, t: float) -> CommandError:
        code: int | None = None
        try:
            tc = self._roundtrip([cmds.tc(1)], t)[0]
            if tc.ok:
                code, text = parse_tc1(tc.text)
            else:
                text = "(TC1 was refused too)"
        except (GalilTimeoutError, ProtocolError) as exc:
            text = f"(TC1 failed: {exc.args[0] if exc.args else exc})"
        name = self.model.name if self.model is not None else None
        error = CommandError(code, text, rejected.command.text, model=name, recent=self.recent)
        hint = _case_hint(rejected.command.text) if code == 1 else None
        if hint is not None:
            error.args = (f"{error.args[0]} ({hint})",)
        return error

    def _write(self, data: bytes) -> None:
        try:
            self.transport.write(data)
        except GalilConnectionError as exc:
            raise self._link_failed(exc) from exc
        self.bytes_sent += len(data)
        if self.wire_log.hooks or _WIRE.isEnabledFor(_DEBUG):
            self._observe("out", data)

    def _read(self, timeout: float) -> bytes:
        try:
            data = self.transport.read(timeout)
        except GalilConnectionError as exc:
            raise self._link_failed(exc) from exc
        if data:
            self.bytes_received += len(data)
            if self.wire_log.hooks or _WIRE.isEnabledFor(_DEBUG):
                self._observe("in", data)
        return data

    def _observe(self, direction: str, data: bytes) -> None:
        if _WIRE.isEnabledFor(_DEBUG):
            _WIRE.debug("%s %r", "->" if direction == "out" else "<-", data)
        for hook in self.wire_log.hooks:
            hook(direction, data)

    def _link_failed(self, exc: GalilConnectionError) -> GalilConnectionError:
        # The command link broke under a read or write: remember it, so the next call (and
        # repr) says the link is dead and what to do, rather than failing on a broken pipe.
        self._dead = str(exc)
        with contextlib.suppress(GalilError, OSError):
            self.transport.close()  # a broken socket or port is no use; reconnect() opens anew
        return self._error(GalilConnectionError, f"{exc}; call reconnect() to open it again")

    def _closed_error(self) -> GalilConnectionError:
        if self._dead:
            return self._error(
                GalilConnectionError,
                f"the controller link died ({self._dead}); call reconnect() to open it again",
            )
        return self._error(GalilConnectionError, "the controller link is closed")

    def _error(self, kind: type[_E], message: str) -> _E:
        name = self.model.name if self.model is not None else None
        return kind(message, model=name, recent=self.recent)

    def _remember(self, entry: tuple[Any, ...]) -> None:
        self._recent.append(entry)

    @property
    def recent(self) -> tuple[str, ...]:
        """The last exchanges on the link, oldest first (what errors carry)."""
        return tuple(_format_exchange(e) for e in list(self._recent))

    # -- unsolicited output -----------------------------------------------------------------

    @property
    def messages(self) -> MessageQueue:
        """Unsolicited lines (program ``MG`` output ...) as a queue: ``messages.get(timeout)``.

        Reading it starts the background poll of an idle link.
        """
        self._ensure_pump()
        return self.messages_queue

    def subscribe(self, callback: Callable[[str], None]) -> Callable[[], None]:
        """Call ``callback(line)`` for each unsolicited line (outside the link lock).

        Returns:
            A function that unsubscribes.
        """
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        self._subscribers = [*self._subscribers, callback]
        self._ensure_pump()

        def unsubscribe() -> None:
            self._subscribers = [c for c in self._subscribers if c is not callback]

        return unsubscribe

    def _message(self, line: str) -> None:
        self._recent.append(("m", line))
        self.messages_queue.put(line)
        if self._subscribers:
            self._undelivered.append(line)

    def _deliver(self) -> None:
        # Callbacks run outside the link lock so that they may send commands themselves.
        with self._dispatch_lock:
            lines, self._undelivered = self._undelivered, []
            for line in lines:
                for cb in self._subscribers:
                    try:
                        cb(line)
                    except Exception:
                        _LOG.exception("unsolicited-message callback %r failed", cb)

    def _ensure_pump(self) -> None:
        if self._pump is not None or self._reader is not None or not self._open_flag:
            return  # a second handle has its own reader already
        self._pump = threading.Thread(
            target=self._poll_idle, args=(self._stop,), name="galil-poll", daemon=True
        )
        self._pump.start()

    def _poll_idle(self, stop: threading.Event) -> None:
        # Reads only with a zero timeout while holding the lock, so a command never waits
        # behind a blocked poll.
        while not stop.wait(self._poll_interval):
            if not self._lock.acquire(timeout=self._poll_interval):
                continue  # commands are flowing: they collect unsolicited lines themselves
            try:
                if stop.is_set() or not self._open_flag:
                    return
                chunk = self._read(0.0)
                if chunk:
                    for ev in self._session.receive_data(chunk):
                        if type(ev) is Unsolicited:
                            self._message(ev.line)
            except ProtocolError:
                pass  # the session is out of step; the next command resynchronises
            except GalilConnectionError:
                return
            finally:
                self._lock.release()
            if self._undelivered:
                self._deliver()

    def _read_secondary(self, secondary: Transport, stop: threading.Event) -> None:
        parser = FrameParser(unsolicited_only=True)
        while not stop.is_set():
            try:
                chunk = secondary.read(0.25)
            except GalilConnectionError:
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
                with self._lock:
                    for line in lines:
                        self._message(line)
            if self._undelivered:
                self._deliver()

    # -- data records -----------------------------------------------------------------------

    def _record_layout(self) -> tuple[int, int, int, int]:
        # QZ says how the controller lays its record out (axes may have been reconfigured);
        # the model table is the fallback for firmware that refuses QZ.
        if self._qz is None:
            try:
                self._qz = parse_qz(self.command("QZ"))
            except CommandError as exc:
                if self.model.qz is None:
                    raise InvalidArgument(
                        f"{self.model.name} has no binary data record (QZ refused)"
                    ) from exc
                self._qz = self.model.qz
        return self._qz

    def record(self, axes: str = "", *, as_dict: bool = False, timeout: float | None = None) -> Any:
        """Read one data record (``QR``) and decode it.

        Args:
            axes: the blocks to ask for (``"AB"``, ``"S"`` ...); default the whole record.
            as_dict: plain Python values (nested dicts per axis) instead of a numpy record.
            timeout: seconds to wait for it.

        Returns:
            A structured numpy record (``rec["A"]["position"]``, ``rec["sample"]``,
            ``rec["error_code"]``; field names in :mod:`galil.protocol.records`), or a dict.

        Raises:
            InvalidArgument: bad axes, or the model has no data record.
            ProtocolError: the record does not match the layout ``QZ`` gave.
        """
        command = cmds.qr(axes, model=self.model)
        layout = self._record_layout()
        done = self.exchange(command, timeout=timeout)
        if done.record is None:
            raise self._error(ProtocolError, f"{command.text!r} answered no binary record")
        try:
            rec = decode_record(done.record, layout)
        except ProtocolError as exc:
            raise self._error(ProtocolError, f"{command.text!r}: {exc}") from exc
        return record_to_dict(rec) if as_dict else rec

    def records(self, period: int, *, method: str = "auto", maxlen: int = 10_000) -> RecordStream:
        """Stream data records every ``period`` servo samples.

        ``"DR"`` (the default over Ethernet) has the controller push them (``DR period,h``) to
        a handle opened for them alone, so they never mix with replies or messages; ``"QR"``
        (elsewhere) polls, one ``QR`` per record when it is due. Close the stream (or use it
        as a context manager) to stop it; :meth:`close` stops every stream.

        Args:
            period: servo samples between records (the controller's minimum applies to DR:
                2 on most models, 8 on the 21x3/41x3).
            method: ``"auto"``, ``"DR"`` or ``"QR"``.
            maxlen: records kept unread before the oldest are dropped (DR).

        Raises:
            InvalidArgument: bad period or method, DR asked for where there is no handle
                for it, or the model has no data record.
            CommandError: the controller refused ``DR`` (a period below its minimum ...).
        """
        if isinstance(period, bool) or not isinstance(period, int) or not 1 <= period <= 65535:
            raise InvalidArgument(f"period is a number of samples 1..65535, not {period!r}")
        if method not in ("auto", "DR", "QR"):
            raise InvalidArgument(f"method is 'auto', 'DR' or 'QR', not {method!r}")
        if isinstance(maxlen, bool) or not isinstance(maxlen, int) or maxlen < 1:
            raise InvalidArgument(f"maxlen must be a positive integer, not {maxlen!r}")
        opener = getattr(self.transport, "open_handle", None)
        can_push = opener is not None and self.transport.kind == "ethernet"
        if method == "DR" and not can_push:
            raise InvalidArgument(
                f"DR needs a second Ethernet handle; {self.transport!r} has none (use 'QR')"
            )
        layout = self._record_layout()
        if method == "QR" or not can_push:
            stream = RecordStream(self, period, "QR", maxlen=maxlen)
        else:
            assert opener is not None
            try:
                handle: Transport = opener()
            except GalilConnectionError as exc:
                raise self._error(GalilConnectionError, f"no handle for DR: {exc}") from exc
            try:
                index = self._which_handle(handle)
                stream = RecordStream(self, period, "DR", handle=handle, maxlen=maxlen)
                self.command(f"DR {period},{index}")
            except BaseException:
                with contextlib.suppress(GalilError, OSError):
                    handle.close()
                raise
            stream._start_reader(layout)
        self._record_streams.append(stream)
        return stream

    def _which_handle(self, handle: Transport) -> int:
        # _WH on a handle names it (0..7 for A..H), which is what DR's second field wants.
        handle.write(b"MG _WH\r")
        got = b""
        deadline = time.monotonic() + self.timeout
        while not got.rstrip().endswith((b":", b"?")):
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._error(GalilTimeoutError, "no answer to MG _WH on the record handle")
            got += handle.read(left)
        text = got.rstrip()[:-1].decode("latin-1").strip()
        if got.rstrip().endswith(b"?") or not text:
            raise CommandError(None, "MG _WH refused on the record handle", "MG _WH")
        try:
            index = round(parse_number(text))
        except (InvalidArgument, ValueError) as exc:
            raise self._error(ProtocolError, f"MG _WH answered {text!r}") from exc
        if not 0 <= index <= 7:
            raise self._error(ProtocolError, f"MG _WH answered {text!r}: not a handle 0..7")
        return index

    # -- the axis layer's needs -------------------------------------------------------------

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample (the model's default TM)."""
        return self.model.sample_period

    def _sim_clock(self) -> Any:
        # A simulator link exposes its controller; a manual clock there only moves when told.
        controller = getattr(self.transport, "controller", None)
        return getattr(controller, "clock", None), controller

    def _clock(self) -> float:
        """Seconds on the controller's clock (simulated time on a simulator link)."""
        clock, _ = self._sim_clock()
        if clock is not None:
            return float(clock.now())
        return time.monotonic()

    def _pause(self, seconds: float) -> None:
        """Let ``seconds`` pass: sleep, or advance a simulator's manual clock."""
        clock, controller = self._sim_clock()
        if clock is not None and hasattr(clock, "advance") and hasattr(controller, "advance"):
            with self._lock:
                controller.advance(seconds)
            return
        time.sleep(seconds)

    @property
    def axes(self) -> dict[str, Axis]:
        """The model's axes by letter (``controller.axes["A"]``; also ``controller.A``)."""
        if self._axes is None:
            from galil.axis import Axis

            self._axes = {letter: Axis(self, letter) for letter in self.model.axes}
        return self._axes

    # -- motion on several axes -------------------------------------------------------------

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller (simulated time on a manual-clock simulator).

        Scripts that wait between commands should use this rather than ``time.sleep`` so the
        same script runs instantly against the simulator in tests.
        """
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds >= 0:
            raise InvalidArgument(f"seconds must be a non-negative number, got {seconds!r}")
        self._pause(float(seconds))

    def move(self, targets: dict[str, Any], *, relative: bool = False, **overrides: Any) -> Any:
        """Move several axes at once, sent in one line and begun together (``BG AB``).

        Args:
            targets: position (or distance with ``relative=True``) per axis letter, in each
                axis's units.
            relative: move by the given distances instead of to the positions.
            **overrides: ``speed``, ``accel``, ``decel`` for every axis of this move.

        Returns:
            A :class:`~galil.axis.MoveHandle` over all the axes.
        """
        from galil.axis import check_overrides, execute_move

        check_overrides("move", overrides)
        return execute_move(self, targets, relative=relative, **overrides)

    def plan(self, targets: dict[str, Any], *, relative: bool = False, **overrides: Any) -> Any:
        """Predict and check :meth:`move` without sending anything; returns a MultiProfile."""
        from galil import predict
        from galil.axis import check_overrides, execute_move

        check_overrides("plan", overrides)
        handle = execute_move(self, targets, relative=relative, dry_run=True, **overrides)
        return predict.together(handle.profiles)

    def stop(self, axes: str = "") -> None:
        """Decelerate axes (default: all) to a stop at their DC (``ST``).

        The predictions of the moves in progress follow the stop (it is stamped with the
        controller's ``TIME``), so their handles still compare the end with a prediction.
        """
        from galil.axis import _letters, stop_axes

        stop_axes(self, _letters(self, axes))

    def abort(self) -> None:
        """Stop all motion at once, without deceleration (``AB 1``: programs keep running)."""
        from galil.axis import abort_all

        abort_all(self)

    def servo_here(self, axes: str = "") -> None:
        """Enable the servo on axes (default: all) at their present position (``SH``)."""
        from galil.axis import _letters

        self.command(f"SH {_letters(self, axes)}".rstrip())

    def motor_off(self, axes: str = "") -> None:
        """Turn the motors of axes (default: all) off (``MO``)."""
        from galil.axis import _letters

        self.command(f"MO {_letters(self, axes)}".rstrip())

    def motion(self, axes: str | None = None) -> Any:
        """A context in which an exception or Ctrl-C stops the moving axes and waits for them.

        ``with controller.motion(): ...``: on any exception, ``ST`` goes to every axis still
        moving (of ``axes``, default all) and the block's exception is re-raised once they
        have stopped.
        """
        from galil.axis import motion_guard

        return motion_guard(self, axes)

    def contour(
        self, axes: str, path: Any, *, dt: int, progress: bool = False, timeout: float | None = None
    ) -> Any:
        """Run a contour path on ``axes`` and return when it is done.

        ``path`` holds ideal positions in counts relative to where each axis is now, one per
        ``2**dt``-sample segment (shape (segments,) or (segments, axes)). The stream is checked
        first (CD range, DT, link speed against the model's buffer), then CM/DT/CD lines keep
        the controller's buffer fed, and ``CD 0=0`` ends it.

        Returns:
            A :class:`~galil.contour.ContourResult` (predictions, low-water mark, lines sent).
        """
        from galil.contour import stream

        return stream(self, axes, path, dt=dt, progress=progress, timeout=timeout)

    def __getattr__(self, name: str) -> Any:
        # Only single axis letters reach here (and X/Y/Z/W aliases where the model has them).
        if len(name) == 1 and name.isupper():
            model = self.__dict__.get("model")
            if model is not None:
                try:
                    return self.axes[model.axis_letter(name)]
                except InvalidArgument:
                    pass
        model = self.__dict__.get("model")
        if len(name) == 1 and name.isalpha() and model is not None:
            # Most likely an axis letter: a typo, a lower-case letter, or one the model lacks.
            raise AttributeError(
                f"{type(self).__name__!s} has no attribute {name!r}: {model.name} has axes "
                f"{', '.join(model.axes)} (controller.A, or controller.axes['A'])"
            )
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")


# MG prints several values back to back, a space before a positive one and only the sign
# before a negative one (" 1.0000-2.0000"); TP separates with commas (+ spaces).
_NUMBER_TOKEN = re.compile(r"\$-?[0-9A-Fa-f]+(?:\.[0-9A-Fa-f]*)?|[-+]?(?:\d+(?:\.\d*)?|\.\d+)")
_SEPARATORS = re.compile(r"[\s,]*")


_QUOTED = re.compile(r'"[^"]*"?')


def _case_hint(text: str) -> str | None:
    """For a command refused as unrecognised: point at lower case, the usual cause."""
    # Strings in quotes keep their case; only the command and operand names must be upper.
    bare = _QUOTED.sub("", text)
    if bare == bare.upper():
        return None
    quoted = _QUOTED.findall(text)
    pieces = _QUOTED.split(text)
    rest = zip(quoted, pieces[1:], strict=True)
    upper = pieces[0].upper() + "".join(q + p.upper() for q, p in rest)
    return f"Galil commands and operands are upper case: did you mean {upper!r}?"


def _numbers(reply: str) -> list[float]:
    fields = _NUMBER_TOKEN.findall(reply)
    if not fields or _SEPARATORS.fullmatch(_NUMBER_TOKEN.sub("", reply)) is None:
        raise InvalidArgument("no number in the reply")
    return [parse_number(f) for f in fields]


def connect(address: str | Transport, **options: Any) -> Controller:
    """Connect to a controller with one line.

    Args:
        address: ``tcp://host[:port]`` or a bare IPv4 address, ``/dev/ttyUSB0``, ``COM3``,
            ``serial:///dev/ttyS0?baudrate=19200`` or any pyserial URL,
            ``usb://[vid:pid][?serial=...]``, ``/dev/galilpci0``, ``sim://DMC-4040``; or an
            open :class:`~galil.transport.Transport`.
        **options: client options (``timeout``, ``model``, ``handshake``, ``unsolicited``,
            ``history``, ``poll_interval``, ``max_messages``); the rest go to the transport
            (``baudrate=``, ``connect_timeout=``, ``backend=`` ...).

    Raises:
        InvalidArgument: the address or an option is not understood.
        GalilConnectionError: the link cannot be opened or the controller does not answer.
    """
    client_opts = {k: options.pop(k) for k in list(options) if k in CLIENT_OPTIONS}
    if isinstance(address, str):
        transport_opts = options

        def factory() -> Transport:
            return open_transport(address, **transport_opts)

        return Controller(factory, **client_opts)
    if options:
        raise InvalidArgument(
            f"transport options {sorted(options)} need an address, not an open transport"
        )
    if not isinstance(address, Transport):
        raise InvalidArgument(f"connect() takes an address or a Transport, not {address!r}")
    return Controller(address, **client_opts)
