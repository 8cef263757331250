"""The link: one transport and one session, safe to share between threads.

Every exchange goes through a sans-I/O :class:`~galil.protocol.session.Session` under one lock,
so each caller gets its own reply however many threads share the link. A ``?`` is explained at
once with ``TC1`` and raised as :class:`~galil.errors.CommandError`; every error carries the
last exchanges (``error.recent``). Bytes on the wire are logged at DEBUG on ``galil.wire``.

Step-keeping: anything raised between writing a command and reading its whole reply (a
timeout, Ctrl-C, a broken pipe, a bad argument in a caller's hook) leaves the session out of
step, and the next exchange resynchronises first, so a late reply is never taken for the next
command's. An exchange that went out of step raises :class:`~galil.errors.ProtocolError` ("the
command may have executed"), never "rejected".

Nothing above this module touches bytes; the rooms above type against :class:`CommandLink`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import threading
import time
import types
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, TypeVar, overload

from galil.codes import parse_tc1
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
    decimal_hint,
)
from galil.models import ModelSpec
from galil.protocol import commands as cmds
from galil.protocol.commands import Command, ReplyKind
from galil.protocol.framing import Unsolicited
from galil.protocol.numbers import parse_number, parse_plain_read, parse_read, whole
from galil.protocol.session import Completed, Session
from galil.transport import ByteRate, ControllerClock, Transport
from galil.units import is_quantity, plain_seconds

__all__ = [
    "LONGEST_TIMEOUT",
    "RECONNECT_ADVICE",
    "TRANSFER_MARGIN",
    "TRANSFER_TIMEOUT",
    "CommandLink",
    "Link",
    "WireCapture",
    "WireLog",
    "check_callable",
    "check_count",
    "check_flag",
    "check_items",
    "check_seconds",
    "check_timeout",
    "check_wait_timeout",
    "is_query",
    "parse_numbers_reply",
    "refuse_link_settings",
    "warn_caller",
]

#: The longest timeout, wait or pause :func:`check_seconds` takes (seconds, about 31 years:
#: for ever, in practice; ``None`` is the way to wait for ever). Every deadline and socket
#: timeout holds it; a 64-bit ``time_t`` of nanoseconds ends at about 9.2e9 s.
LONGEST_TIMEOUT = 1e9
#: What a dead link's error ends with: the way to open it again.
RECONNECT_ADVICE = "; call reconnect() to open it again"
#: The burns: the controller holds their answer (and every later one) while flash is written.
_BURNS = frozenset({"BN", "BP", "BV"})
#: The least reply timeout a bulk transfer (``QU``, ``QD``, ``DL``, ``UL``, ``LV``) gets: what
#: every transfer had before its size counted (EPICS allows 10 s for a download); the link's
#: own timeout when that is longer (decision 0064).
TRANSFER_TIMEOUT = 10.0
#: A transfer's time on the line, this many times over, comes on top: generous, since a
#: controller may print more slowly than its line carries and the host may be late to read.
TRANSFER_MARGIN = 2.0

_WIRE = logging.getLogger("galil.wire")
# The logger's own cache of isEnabledFor() answers (cleared in place when levels change): one
# dict lookup on the hot path instead of a method call; None when not known yet.
_WIRE_CACHE: dict[int, bool] = getattr(_WIRE, "_cache", {})
_DEBUG = logging.DEBUG
_monotonic = time.monotonic

_E = TypeVar("_E", bound=GalilError)
_T = TypeVar("_T")

# Polling loops send the same few lines again and again: each text is parsed once (a plain
# dict, looked up inline by Link.command; cleared when it grows, so it stays bounded).
_PARSED: dict[str, Command] = {}

# MG prints several values back to back, a space before a positive one and only the sign
# before a negative one (" 1.0000-2.0000"); TP separates with commas (+ spaces).
_NUMBER_TOKEN = re.compile(r"\$-?[0-9A-Fa-f]+(?:\.[0-9A-Fa-f]*)?|[-+]?(?:\d+(?:\.\d*)?|\.\d+)")
_SEPARATORS = re.compile(r"[\s,]*")
_DECIMAL = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)"
_PLAIN_NUMBERS = re.compile(rf"[\s,]*{_DECIMAL}(?:[\s,]+{_DECIMAL})*[\s,]*")


def _parse(text: str) -> Command:
    cmd = _PARSED.get(text)
    if cmd is None:
        cmd = cmds.parse_line(text)
        refuse_link_settings(cmd)  # (once per text: a refused line is never cached)
        if len(_PARSED) >= 512:
            _PARSED.clear()
        _PARSED[text] = cmd
    return cmd


def _last_refused(done: Sequence[Completed]) -> Completed:
    """The part of ``done`` that ``TC1`` explains: the last one refused (the controller keeps
    only its last error's code, so a line with two refused parts gets the second's)."""
    return [d for d in done if not d.ok][-1]


#: The earlier refused parts of a line a :class:`CommandError` names; the rest are counted.
_REFUSED_NAMED = 5


def _with_replies(error: GalilError, done: Sequence[Completed]) -> GalilError:
    """A refusal in a compound line carries the replies of its parts (``galil terminal``
    prints them): what the controller answered before the rejected part, and after it. Parts
    refused before the one explained are named: ``TC1`` tells only the last error's code."""
    if isinstance(error, CommandError) and len(done) > 1:
        error.replies = tuple(d.text if d.ok else None for d in done)
        earlier = [repr(d.command.text) for d in done if not d.ok][:-1]
        if earlier:
            named = ", ".join(earlier[:_REFUSED_NAMED])
            if len(earlier) > _REFUSED_NAMED:  # (a line of hundreds refused: decision 0100)
                named += f" and {len(earlier) - _REFUSED_NAMED} more"
            error.args = (
                f"{error.args[0]} (also refused: {named}, why not known: TC1 "
                "tells only the last error's code)",
                *error.args[1:],
            )
    return error


def refuse_link_settings(command: Command) -> None:
    """Refuse a raw command that would change the link's own settings or reset the
    controller under it (``RS``, ``^R^S``, ``CW 1``, ``EO 0``, ``CF``, ``IHS=>``; decision 0031),
    or burn the link's own settings (``BN``; decision 0057).

    Raises:
        InvalidArgument: saying what to use instead; nothing is sent.
    """
    for part in cmds.split_commands(command.text):
        why = cmds.link_setting(part)
        if why is not None:
            raise InvalidArgument(f"not sent: {why}")


def check_count(value: object, name: str) -> int:
    """``value`` as a positive whole number (an ``int`` or a numpy integer; a bool is refused
    too).

    Raises:
        InvalidArgument: naming ``name``.
    """
    n = whole(value)
    if n is None or n < 1:
        raise InvalidArgument(f"{name} must be a positive integer, not {value!r}")
    return n


def check_flag(value: object, name: str) -> bool:
    """``value`` if it is ``True`` or ``False``: a flag takes nothing else (``"no"`` is true,
    ``None`` and ``0`` would be a guess).

    Raises:
        InvalidArgument: naming ``name``.
    """
    if value is not True and value is not False:
        raise InvalidArgument(f"{name} must be True or False, not {value!r:.60}")
    return value


@overload
def check_items(value: Iterable[_T], name: str) -> list[_T]: ...
@overload
def check_items(value: object, name: str) -> list[object]: ...
def check_items(value: Iterable[_T] | object, name: str) -> list[_T] | list[object]:
    """The items of a list, tuple or other iterable given where several things are expected; a
    string (one item, or characters?), a mapping or anything not iterable is refused.

    Raises:
        InvalidArgument: naming ``name``.
    """
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
        raise InvalidArgument(f"{name} must be a list, not {value!r:.60}")
    return list(value)


def check_callable(value: object, name: str) -> None:
    """Refuse a callback that cannot be called (it would fail later, on another thread).

    Raises:
        InvalidArgument: naming ``name``.
    """
    if not callable(value):
        raise InvalidArgument(f"{name} must be callable, not {value!r:.60}")


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn_caller(message: str, category: type[Warning] = RuntimeWarning) -> None:
    """``warnings.warn`` attributed to the first caller outside the ``galil`` package (the
    user's line that connected, reconnected ...), however deep inside it the warning comes
    from: a fixed ``stacklevel`` points at one of the library's own lines when the depth
    varies (``connect()``, ``Controller()``, ``reconnect()``)."""
    frame: types.FrameType | None = sys._getframe(1)
    level = 2  # (warn's stacklevel 2: this function's caller)
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level if frame is not None else 2)


def _finite(value: float) -> bool:
    """``math.isfinite`` that says no to an int no float holds (10**400) rather than raise."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def check_seconds(value: object, name: str = "timeout", *, positive: bool = False) -> float:
    """The one check of every timeout, wait and pause in the public API: ``value`` must be a
    finite number of seconds >= 0 (``> 0`` with ``positive``: a reply timeout, a watchdog
    period, where 0 cannot be met), and at most :data:`LONGEST_TIMEOUT`; a time Quantity
    (``0.5 * ureg.s``, ``100 * ureg.ms``) is taken in seconds. The wrappers below decide what
    ``None`` means.

    Returns:
        ``value`` as a float.

    Raises:
        InvalidArgument: naming ``name``: ``None``, a bool, a string or anything else that is
            not an int, a float or a time Quantity, a Quantity of another dimension, NaN,
            infinity, a negative number (or 0 with ``positive``), more than
            :data:`LONGEST_TIMEOUT`.
    """
    given = value
    if type(value) is not float and type(value) is not int and is_quantity(value):
        value = plain_seconds(value, name)  # (a time Quantity: 0.5 * ureg.s, 100 * ureg.ms)
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not _finite(value)
        or value < 0
        or (positive and value == 0)
        or value > LONGEST_TIMEOUT
    ):
        least = "> 0" if positive else ">= 0"
        raise InvalidArgument(
            f"{name} must be a finite number of seconds {least} (or a time Quantity), at most"
            f" {LONGEST_TIMEOUT:g} (about 31 years), not {given!r}{decimal_hint(value)}"
        )
    return float(value)


def check_wait_timeout(timeout: object, name: str = "timeout") -> float | None:
    """A wait's timeout: ``None`` (what it means is the wait's own: for ever, or a default it
    works out, such as a move's predicted duration plus a margin) or :func:`check_seconds`.
    Infinity is refused: ``None`` is the way to wait for ever.

    Raises:
        InvalidArgument: naming ``name`` (see :func:`check_seconds`).
    """
    return None if timeout is None else check_seconds(timeout, name)


def check_timeout(timeout: object, default: float, what: str = "timeout") -> float:
    """A reply timeout (or another link setting in seconds): ``None`` is ``default``, else
    :func:`check_seconds` with ``positive`` (no reply comes in 0 s).

    Raises:
        InvalidArgument: naming ``what`` (see :func:`check_seconds`).
    """
    return default if timeout is None else check_seconds(timeout, what, positive=True)


_QUERY_KINDS = frozenset({ReplyKind.DATA, ReplyKind.RECORD, ReplyKind.CTRL_Z})


def is_query(command: Command) -> bool:
    """Whether a command only reads (its reply carries data): safe to ask again."""
    parts = command.parts or (command,)
    # ANY: a raw line whose reply shape is unknown (an assignment, a program line): not a query.
    return all(p.expect.kind in _QUERY_KINDS and not p.payload for p in parts)


def parse_numbers_reply(reply: str) -> list[float]:
    """Every number in a reply (``" 1.0000-2.0000"``, ``"0, 5, 7"``).

    Raises:
        InvalidArgument: no number, or something that is not a number between them.
        ProtocolError: a number the controller cannot have sent (hundreds of digits).
    """
    if _PLAIN_NUMBERS.fullmatch(reply) is not None:
        # The usual reply: decimals between blanks or commas (float() reads each exactly as
        # parse_number does once its pattern matched).
        values = [float(f) for f in reply.replace(",", " ").split()]
        if not all(math.isfinite(v) for v in values):
            raise ProtocolError(f"a number out of any controller's range in {reply!r}")
        return values
    fields = _NUMBER_TOKEN.findall(reply)
    if not fields or _SEPARATORS.fullmatch(_NUMBER_TOKEN.sub("", reply)) is None:
        raise InvalidArgument("no number in the reply")
    values = [parse_number(f) for f in fields]
    if not all(math.isfinite(v) for v in values):
        raise ProtocolError(f"a number out of any controller's range in {reply!r}")
    return values


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
        check_callable(hook, "hook")
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


# ----------------------------------------------------------------------------------- protocol


class CommandLink(Protocol):
    """What the rooms above the link (axes, motion, contour, I/O ...) need from it."""

    @property
    def is_open(self) -> bool:
        """Whether a transport is attached and not closed."""
        ...

    @property
    def dead(self) -> str:
        """Why the link broke (``""`` while it works or after a clean close)."""
        ...

    @property
    def model(self) -> ModelSpec:
        """The controller's model."""
        ...

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample."""
        ...

    def command(
        self, text: str, *, timeout: float | None = None, allow_compound: bool = False
    ) -> str:
        """Send one raw command line, return its reply text."""
        ...

    def command_line(
        self, parts: Sequence[str | Command], *, timeout: float | None = None
    ) -> list[str]:
        """Send several commands as compound lines, return one reply per part."""
        ...

    def exchange(
        self, command: Command, *, timeout: float | None = None, stall: float | None = None
    ) -> Completed:
        """Send a prepared command, return its whole reply (``stall``: :meth:`Link.exchange`)."""
        ...

    def query_operands(self, names: Sequence[str], *, timeout: float | None = None) -> list[float]:
        """Read operands or variables in as few lines as fit."""
        ...

    def transfer_timeout(self, command: Command, reply_bytes: int = 0) -> float:
        """A bulk transfer's reply timeout, from its size (:meth:`Link.transfer_timeout`)."""
        ...

    @property
    def transfer_stall(self) -> float:
        """The longest a transfer's reply may stay silent (:attr:`Link.transfer_stall`)."""
        ...

    def transfer(self, command: Command, reply_bytes: int = 0) -> Completed:
        """Exchange a bulk transfer, bounded by its size and silences (:meth:`Link.transfer`)."""
        ...

    def clock(self) -> float:
        """Seconds on the controller's clock."""
        ...

    @property
    def byte_rate(self) -> float | None:
        """Bytes per second the transport carries, when it says (:attr:`Link.byte_rate`)."""
        ...

    @property
    def keepalive(self) -> tuple[Command, float] | None:
        """A running watchdog's heartbeat and its interval (:attr:`Link.keepalive`)."""
        ...

    def pause(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller."""
        ...

    @property
    def simulated_time(self) -> bool:
        """Whether the controller runs on a clock of its own (pauses cost no real time)."""
        ...

    def error(self, kind: type[_E], message: str) -> _E:
        """An error of ``kind`` carrying the model and the recent exchanges."""
        ...

    @property
    def recent(self) -> tuple[str, ...]:
        """The last exchanges on the link, oldest first."""
        ...


def _format_exchange(entry: Completed | tuple[str, str]) -> str:
    if type(entry) is Completed:
        sent, reply, ok = entry.command.text, entry.text, entry.ok
        if ok:
            return f"-> {sent!r}  <- {reply!r}"
        return f"-> {sent!r}  <- ? {reply!r}" if reply else f"-> {sent!r}  <- ?"
    kind, text = entry  # type: ignore[misc]
    if kind == "m":
        return f"<< {text!r} (unsolicited)"
    if kind == "t":
        return f"-> {text!r}  (no reply: timeout)"
    return f"-- {text}"


def _new_completed(fields: tuple[Command, bool, str, None]) -> Completed:
    # tuple.__new__ skips NamedTuple's argument handling: this is on the hot path.
    return tuple.__new__(Completed, fields)


def _case_hint(text: str) -> str | None:
    """For a command refused as unrecognised: what lower case in it may be to blame (the
    commands and operands upper case, or variables of those names not defined: see
    :func:`~galil.protocol.commands.unrecognized_hint`)."""
    return cmds.unrecognized_hint(text)


# ----------------------------------------------------------------------------------- the link


class LinkCore:
    """One transport and its session: the only room that touches bytes (see :class:`Link`).

    Args:
        timeout: default seconds to wait for each reply.
        history: exchanges kept in the ring buffer attached to errors.

    Attributes:
        transport: the open transport (``None`` before :meth:`attach`).
        model: the controller's model (set by the handshake).
        timeout: default reply timeout in seconds.
        bytes_sent / bytes_received: bytes written to / read from the command link.
        wire_log: hooks on the raw bytes.
        on_messages: called with unsolicited lines, outside the lock, in order.
    """

    def __init__(self, *, timeout: float = 1.0, history: int = 64) -> None:
        self.timeout = check_timeout(timeout, 1.0)
        if check_count(history, "history") > sys.maxsize:  # more than a deque can hold
            raise InvalidArgument(f"history must be at most {sys.maxsize}, not {history!r:.40}")
        self.transport: Transport | None = None
        self._model: ModelSpec | None = None
        self._sample_period: float | None = None
        self._lock = threading.Lock()
        self._session = Session()
        # Completed replies are kept as they are (immutable); text is made only for an error.
        self._recent: deque[Completed | tuple[str, str]] = deque(maxlen=history)
        self.wire_log = WireLog()
        self.bytes_sent = 0
        self.bytes_received = 0
        self._open = False
        self._dead = ""  # why the command link broke, until it is attached again
        self._rebooting = False  # a silence is the controller's reboot (RS), not a dead link
        self._clock_source: ControllerClock | None = None
        self._inbox: list[str] = []
        self.on_messages: Callable[[list[str]], None] | None = None
        # What close() sends back, each with the link's own setting it undoes (if one).
        self._restore: list[tuple[Command, Command | None]] = []
        self._keepalive: tuple[Command, float] | None = None
        self._reopened = threading.Event()  # cleared while a reconnect is under way
        self._reopened.set()
        #: Called with the error when the link is found dead (automatic reconnect).
        self.on_dead: Callable[[GalilConnectionError], None] | None = None
        self._recovering = False
        self._asked = 0  # TC1 questions so far (each gets a marker of its own)

    # -- life cycle -------------------------------------------------------------------------

    def attach(self, transport: Transport) -> None:
        """Take an open transport (a fresh session; old bytes on it are drained)."""
        with self._lock:
            self.transport = transport
            self._clock_source = transport if isinstance(transport, ControllerClock) else None
            self._session = Session()
            self._restore = []
            self._open = True
            self._dead = ""
            for _ in range(64):
                # Bytes left over from an earlier program or session would pass for replies.
                try:
                    if not self._read(0.0):
                        break
                except GalilConnectionError:
                    break  # (dropped at once, the link is dead: the handshake says why)

    def detach(self) -> None:
        """Send what must be restored (best effort), then close the transport; idempotent."""
        with self._lock:
            if not self._open:
                return
            try:
                for command, _ in reversed(self._restore):
                    if self._dead:
                        break
                    with contextlib.suppress(GalilError):
                        self._roundtrip((command,), min(self.timeout, 0.5))
            finally:  # (closed whatever interrupts the restoring: a Ctrl-C goes on after)
                self._restore = []
                self._dead = ""
                self._close_transport()

    def failed(self, reason: str) -> None:
        """The link could not be reopened: it is dead (``reason``), not closed. Calls say so
        and advise ``reconnect()``; a guard and ``close()`` reopen it once for their stops."""
        with self._lock:
            self._open = True
            self._dead = reason

    def _close_transport(self) -> None:
        self._open = False
        if self.transport is not None:
            with contextlib.suppress(GalilError, OSError):
                self.transport.close()

    def reopening(self) -> contextlib.AbstractContextManager[None]:
        """A block in which the link is closed and opened again: commands wait for it."""
        return _ReopenBlock(self._reopened)

    def _await_reopen(self, t: float) -> None:
        if not self._reopened.wait(t):
            raise self.error(
                GalilConnectionError, f"the link was being reopened and was not back within {t:g} s"
            )

    def restore_on_close(self, command: Command, *, own: Command | None = None) -> None:
        """Send ``command`` when the link closes (undo what connecting changed); last in, first.

        ``own`` is the setting of the link's that ``command`` undoes (``CW 1`` for ``CW 2``),
        when the controller may keep it: see :meth:`own_settings`.
        """
        self._restore.append((command, own))

    def own_settings(self) -> list[tuple[Command, Command]]:
        """The controller settings the link changed for itself at connect, in the order it
        changed them: each as (the controller's own value, restored at close; the link's)."""
        return [(command, own) for command, own in self._restore if own is not None]

    @property
    def is_open(self) -> bool:
        """Whether a transport is attached and not closed."""
        return self._open

    @property
    def dead(self) -> str:
        """Why the link broke (``""`` while it works or after a clean close)."""
        return self._dead

    @property
    def model(self) -> ModelSpec:
        """The controller's model.

        Raises:
            GalilConnectionError: not identified yet.
        """
        if self._model is None:
            raise GalilConnectionError("the controller has not been identified")
        return self._model

    @model.setter
    def model(self, spec: ModelSpec) -> None:
        self._model = spec

    @property
    def model_name(self) -> str | None:
        """The model's name, or ``None`` before identification."""
        return None if self._model is None else self._model.name

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample (the model's, or what ``TM`` was last read as)."""
        if self._sample_period is not None:
            return self._sample_period
        model = self._model  # (self.model, without the property's call: a hot path)
        if model is None:
            return self.model.sample_period  # (raises: not identified)
        return model.sample_period

    @sample_period.setter
    def sample_period(self, seconds: float) -> None:
        self._sample_period = seconds

    @property
    def byte_rate(self) -> float | None:
        """Bytes per second the transport carries, when it says (serial, Ethernet)."""
        t = self.transport
        return float(t.byte_rate) if isinstance(t, ByteRate) else None

    def set_echo(self, echo: bool) -> None:
        """Strip (or stop stripping) the controller's echo from replies (lock held by caller)."""
        self._session = Session(echo=echo)

    # -- the exchange -----------------------------------------------------------------------

    def _roundtrip(
        self, batch: Sequence[Command], t: float, stall: float | None = None
    ) -> list[Completed]:
        """Write ``batch`` and read until every reply is complete (lock held).

        ``stall``: a transfer's reply must begin within that many seconds of its bytes being
        on the line (at :attr:`byte_rate`, :data:`TRANSFER_MARGIN` times) and never pause
        longer (decision 0067); ``t`` bounds the whole.

        Whatever is raised once the bytes may be out leaves the session out of step, so the
        next exchange resynchronises before anything else goes out.
        """
        session = self._session
        if session.out_of_step:
            self._resync(t)
        transport = self.transport
        assert transport is not None
        try:
            # From the first command queued in the session on, whatever is raised (even
            # before the write: a wire-log hook, Ctrl-C) leaves the session out of step, so
            # no reply can be matched to a command that was queued but never written.
            if len(batch) == 1:
                data = session.send(batch[0])
            else:
                data = b"".join([session.send(c) for c in batch])
            # Bookkeeping happens before the write: any Python work between the write and
            # the read delays the reply (a local peer may be waiting for the GIL we hold).
            self.bytes_sent += len(data)
            watch = bool(self.wire_log.hooks) or _WIRE.isEnabledFor(_DEBUG)
            if watch:
                self._observe("out", data)
            clock = self._clock_source
            sim_start = clock.controller_time() if clock is not None else 0.0
            first = t if stall is None else min(t, stall + _line_time(self.byte_rate, len(data)))
            start = _monotonic()
            try:
                transport.write(data)
                chunk = transport.read(first)  # (the timeout as given: transports cache it)
            except OSError as exc:
                dead = _dead_link(exc, transport)
                if dead is None or dead is exc:
                    raise
                raise dead from exc
        except BaseException as exc:
            session.abandon()
            if isinstance(exc, GalilConnectionError):
                raise self._link_failed(exc) from exc
            raise
        if stall is None:
            return self._guarded_collect(batch, t, start, sim_start, chunk, watch)
        quiet = _Quiet(stall, start + first, sim_start + first)
        if chunk:
            quiet.heard(clock)
        return self._guarded_collect(batch, t, start, sim_start, chunk, watch, quiet)

    def _guarded_collect(
        self,
        batch: Sequence[Command],
        t: float,
        start: float,
        sim_start: float,
        chunk: bytes,
        watch: bool,
        quiet: _Quiet | None = None,
    ) -> list[Completed]:
        try:
            events = self._take(chunk, watch)
            if len(events) == 1 and not self._session.pending and type(events[0]) is Completed:
                self._recent.append(events[0])  # the common case: the whole reply in one read
                return events  # type: ignore[return-value]
            return self._collect(batch, t, start, sim_start, events, watch, quiet)
        except BaseException:
            if self._session.pending:
                self._session.abandon()
            raise

    def _collect(
        self,
        batch: Sequence[Command],
        t: float,
        start: float,
        sim_start: float,
        events: list[Completed | Unsolicited],
        watch: bool,
        quiet: _Quiet | None = None,
    ) -> list[Completed]:
        """Take ``events`` (from the first read), then read until ``batch`` is answered (and,
        with ``quiet``, until the reply pauses too long)."""
        session = self._session
        transport = self.transport
        assert transport is not None
        recent = self._recent
        clock = self._clock_source
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
                wait = min(wait, sim_start + t - clock.controller_time())
            # (a transfer's silence may run out first: decision 0067)
            silent = quiet if quiet is not None and (pause := quiet.left(clock)) < wait else None
            if silent is not None:
                wait = pause
            if wait <= 0:
                begun = session.receiving  # (before abandon() forgets it)
                lost = session.abandon()
                for c in lost:
                    recent.append(("t", c.text))
                text = lost[0].text if lost else batch[-1].text
                what = _no_reply(text, t, begun) if silent is None else silent.what(text)
                raise self.error(
                    GalilTimeoutError,
                    f"{what} (the link will resynchronise before the next command)",
                )
            try:
                chunk = transport.read(wait)
            except OSError as exc:
                dead = _dead_link(exc, transport)
                if dead is None:
                    raise
                raise self._link_failed(dead) from exc
            if chunk and quiet is not None:
                quiet.heard(clock)
            events = self._take(chunk, watch)

    def _take(self, chunk: bytes, watch: bool) -> list[Completed | Unsolicited]:
        """Count, log and parse one chunk read from the command link (nothing for b"")."""
        if not chunk:
            return []
        self.bytes_received += len(chunk)
        if watch:
            self._observe("in", chunk)
        try:
            return self._session.receive_data(chunk)
        except ProtocolError as exc:
            self.note(f"protocol error: {exc}")
            raise self.error(
                ProtocolError, f"{exc}; the command may have executed (the link resynchronises)"
            ) from exc

    @contextlib.contextmanager
    def rebooting(self) -> Iterator[None]:
        """While the controller reboots (after ``RS``) it is silent: a resynchronisation that
        hears nothing then does not mark the link dead (decision 0089), so the handshake can
        try again until the reboot is over."""
        self._rebooting = True
        try:
            yield
        finally:
            self._rebooting = False

    def _resync(self, t: float, before: bytes = b"") -> None:
        """Write the marker (behind ``before``) and read until its answer comes back (lock
        held): what comes before it is thrown away.

        Raises:
            GalilConnectionError: no answer within ``t`` (at least 0.2 s). If not one byte
                came and no burn was given up (the controller holds a burn's answer for
                seconds), the link is dead: a connection gone silent without being closed
                (decision 0089; the automatic reconnect reopens it). Otherwise it stays
                open and out of step, and the next exchange tries again (decision 0081).
        """
        session = self._session
        held = [c.text.strip() for c in session.unanswered if c.text.strip() in _BURNS]
        self.note("link out of step: resynchronising")
        self._write(before + session.resync())
        limit = max(t, 0.2)
        heard = _hunt(self, limit)
        if heard is None:
            self.note("link back in step")
        elif self._rebooting and not heard:
            raise self.error(
                GalilConnectionError,
                f"the controller is still silent after its reset (nothing within {limit:g} s)",
            )
        elif heard or held:
            raise self.error(GalilConnectionError, _unsynced(limit, heard, held))
        else:
            raise self._link_failed(GalilConnectionError(_unsynced(limit, 0, held)))

    # -- raw I/O (lock held) ------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        assert self.transport is not None
        try:
            self.transport.write(data)
        except OSError as exc:
            dead = _dead_link(exc, self.transport)
            if dead is None:
                raise
            raise self._link_failed(dead) from exc
        self.bytes_sent += len(data)
        if self.wire_log.hooks or _WIRE.isEnabledFor(_DEBUG):
            self._observe("out", data)

    def _read(self, timeout: float) -> bytes:
        assert self.transport is not None
        try:
            data = self.transport.read(timeout)
        except OSError as exc:
            dead = _dead_link(exc, self.transport)
            if dead is None:
                raise
            raise self._link_failed(dead) from exc
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
        # The link broke under a read or write: remember it, so the next call (and repr)
        # says the link is dead and what to do, rather than failing on a broken pipe.
        self._dead = str(exc)
        if self.transport is not None:  # a broken socket or port is no use; reconnect() opens anew
            with contextlib.suppress(GalilError, OSError):
                self.transport.close()
        return self.error(GalilConnectionError, f"{exc}{RECONNECT_ADVICE}")

    def _closed_error(self) -> GalilConnectionError:
        if not self._reopened.is_set():
            return _ReopeningError("the link is being reopened")
        if self._dead:
            return self.error(
                GalilConnectionError,
                f"the controller link died ({self._dead}){RECONNECT_ADVICE}",
            )
        return self.error(
            GalilConnectionError,
            "the controller link is closed (close(), or the end of its with block); "
            "galil.connect() opens a new one",
        )

    def error(self, kind: type[_E], message: str) -> _E:
        """An error of ``kind`` carrying the model name and the recent exchanges."""
        return kind(message, model=self.model_name, recent=self.recent)

    def note(self, text: str) -> None:
        """Add a line to the recent exchanges (what errors carry)."""
        self._recent.append(("n", text))

    @property
    def recent(self) -> tuple[str, ...]:
        """The last exchanges on the link, oldest first (what errors carry)."""
        return tuple(_format_exchange(e) for e in list(self._recent))

    # -- unsolicited output -----------------------------------------------------------------

    def _message(self, line: str) -> None:
        self._recent.append(("m", line))
        self._inbox.append(line)

    def _flush(self) -> None:
        # Delivered outside the lock, so that a callback may send commands itself.
        lines, self._inbox = self._inbox, []
        sink = self.on_messages
        if lines and sink is not None:
            sink(lines)

    def post_messages(self, lines: list[str]) -> None:
        """Unsolicited lines read elsewhere (a message handle): remembered and delivered."""
        for line in lines:
            self._recent.append(("m", line))
        sink = self.on_messages
        if lines and sink is not None:
            sink(lines)

    def poll_unsolicited(self, wait: float) -> bool:
        """Read what arrived on an idle link (zero timeout); skip if busy for ``wait`` s.

        Returns:
            ``False`` once the link is closed or dead (the caller stops polling).
        """
        if not self._lock.acquire(timeout=wait):
            return True  # commands are flowing: they collect unsolicited lines themselves
        try:
            if not self._open or self._dead:
                return False
            chunk = self._read(0.0)
            if chunk:
                for ev in self._session.receive_data(chunk):
                    if type(ev) is Unsolicited:
                        self._message(ev.line)
        except ProtocolError:
            pass  # the session is out of step; the next command resynchronises
        except GalilConnectionError:
            return False
        finally:
            self._lock.release()
        if self._inbox:
            self._flush()
        return True

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the link's lock (for setup steps that must not interleave)."""
        with self._lock:
            yield
        if self._inbox:
            self._flush()

    def roundtrip_locked(self, batch: Sequence[Command], timeout: float) -> list[Completed]:
        """A round trip for a caller that holds :meth:`locked`; no ``?`` explanation."""
        return self._roundtrip(batch, timeout)

    def __repr__(self) -> str:
        state = "open" if self._open else ("dead" if self._dead else "closed")
        return f"<Link {self.model_name or '?'} on {self.transport!r} {state}>"


class Link(LinkCore):
    """The command link: :class:`LinkCore` plus the commands the rooms above send."""

    # -- time -------------------------------------------------------------------------------

    def clock(self) -> float:
        """Seconds on the controller's clock (simulated time on a simulator link)."""
        source = self._clock_source
        return source.controller_time() if source is not None else _monotonic()

    def pause(self, seconds: float) -> None:
        """Let ``seconds`` pass: sleep, or let a simulator's clock run (under the lock).

        With a keepalive set, a simulator's time passes in slices with the keepalive command
        between them, as a host's heartbeat thread would send it in real time.
        """
        source = self._clock_source
        if source is None:
            time.sleep(seconds)
            return
        with self._lock:
            beat = self._keepalive
            if beat is None:
                source.let_time_pass(seconds)
            else:
                left = seconds
                while left > 0:
                    step = min(left, beat[1])
                    source.let_time_pass(step)
                    left -= step
                    self._roundtrip((beat[0],), self.timeout)
        # Time passed for everyone: give a thread waiting for the link its turn now (a lock
        # is not fair, and the GIL would let this thread take it again at once). Alone, there
        # is nobody to give it to, and the yield would cost more than the pause.
        if threading.active_count() > 1:
            time.sleep(0)
        if self._inbox:
            self._flush()

    def set_keepalive(self, command: Command | None, every: float = 0.0) -> None:
        """A command a heartbeat sends every ``every`` seconds (``None``: no keepalive).

        The link only uses it to slice a simulator's pauses; real-time heartbeats are the
        caller's thread (see :mod:`galil.watchdog`).
        """
        self._keepalive = None if command is None else (command, every)

    @property
    def keepalive(self) -> tuple[Command, float] | None:
        """The heartbeat command and its interval in seconds, while a watchdog beats on the
        link (``None``: none does); a long transfer puts it on its lines (decision 0100)."""
        return self._keepalive

    @property
    def simulated_time(self) -> bool:
        """Whether the controller runs on a clock of its own (a simulator link)."""
        return self._clock_source is not None

    # -- the exchange -----------------------------------------------------------------------

    def transact(
        self, batch: Sequence[Command], timeout: float | None, stall: float | None = None
    ) -> list[Completed]:
        """Send ``batch`` (pipelined) under the lock; raise for a rejected command (the last
        one: ``TC1`` explains only the last error).

        While a reconnect is under way it waits for it (up to the timeout) instead of failing.
        ``stall``: see :meth:`exchange`.
        """
        t = self.timeout if timeout is None else check_timeout(timeout, self.timeout)
        try:
            return self._transact(batch, t, stall)
        except _ReopeningError:
            self._await_reopen(t)
            return self._transact(batch, t, stall)
        except GalilConnectionError as exc:
            if not self._recover(exc):
                raise
            return self._after_recovery(batch, t, exc)

    def _recover(self, exc: GalilConnectionError) -> bool:
        """Reopen a dead link through ``on_dead`` (automatic reconnect); False if none."""
        hook = self.on_dead
        if hook is None or not self._dead or self._recovering:
            return False
        self._recovering = True
        try:
            hook(exc)
        finally:
            self._recovering = False
        return True

    def _after_recovery(
        self, batch: Sequence[Command], t: float, exc: GalilConnectionError
    ) -> list[Completed]:
        # Queries are asked again on the new link; anything else may have run already.
        if all(is_query(c) for c in batch):
            return self._transact(batch, t)
        texts = ", ".join(repr(c.text) for c in batch[:3])
        raise self.error(
            GalilConnectionError,
            f"the link died during {texts} and was reopened; it was not sent again "
            "(it may or may not have run)",
        ) from exc

    def _transact(
        self, batch: Sequence[Command], t: float, stall: float | None = None
    ) -> list[Completed]:
        try:
            with self._lock:
                if not self._open or self._dead:
                    raise self._closed_error()
                done = self._roundtrip(batch, t, stall)
                if not all(d.ok for d in done):
                    raise _with_replies(self._explain(_last_refused(done), t), done)
                return done
        finally:
            if self._inbox:
                self._flush()

    # -- readers whose source died ----------------------------------------------------------

    def source_lost(self, what: str, exc: GalilConnectionError | None) -> str | None:
        """A reader's source is gone: ``what`` (a handle of the same controller: "the message
        handle") closed under ``exc``, or (``exc`` ``None``) the poll of the idle command link
        found it closed or dead. A closed handle may mean the controller went away: the
        command link is asked (one query) and marked dead if it does not
        answer either.

        Returns:
            ``None`` while the command link works, or a reopen is under way (it brings a new
            source); else why nothing more will come (the link's closed or dead error).
        """
        if not self._reopened.is_set():
            return None
        if exc is not None and self._open and not self._dead:
            _probe(self, what, exc)
        return self.gone() or None

    def gone(self) -> str:
        """Why a reader's queue gets nothing more from this link: the text of its closed or
        dead error; ``""`` while it works, or while a reopen is under way."""
        if not self._reopened.is_set() or (self._open and not self._dead):
            return ""
        return str(self._closed_error().args[0])

    def revive(self) -> bool:
        """For a reader's queue whose source died with the link: reopen the dead link with
        the automatic reconnect (``on_dead``, ``connect(..., reconnect=True)``), or wait for
        a reopen under way (up to :attr:`timeout`).

        Returns:
            Whether the link works again (``False``: it is closed, or dead with no automatic
            reconnect).

        Raises:
            GalilConnectionError: the automatic reconnect failed.
        """
        if not self._reopened.is_set():
            self._reopened.wait(self.timeout)
            return self._open and not self._dead
        if not self._dead:
            return False
        return self._recover(self._closed_error())

    def _explain(self, rejected: Completed, t: float) -> GalilError:
        """Ask ``TC1`` why a command was refused; a doubtful ``?`` is no refusal.

        ``TC1`` goes out with a fresh marker (``MG "TCOKn"``) right behind it: unless the
        marker comes back as the second reply, the answers were not the ones asked for (a
        stray ``?`` followed by the command's own reply), and the link is out of step.
        """
        command = rejected.command.text
        self._asked += 1
        token = f"TCOK{self._asked}"
        try:
            tc, mark = self._roundtrip([cmds.tc(1), cmds.mg(token)], t)
        except (GalilTimeoutError, ProtocolError) as exc:
            why = exc.args[0] if exc.args else exc
            return self._doubt(command, f"the link went out of step asking why ({why})")
        if not mark.ok or mark.text.strip() != token:
            return self._doubt(command, "the answer to TC1 was not the controller's")
        code: int | None = None
        if tc.ok:
            try:
                code, text = parse_tc1(tc.text)
            except ProtocolError:
                return self._doubt(command, f"TC1 answered {tc.text!r}")
        else:
            text = "(TC1 was refused too)"
        if code == 0:
            # The controller has no error to report: that '?' was not its answer to us.
            self._session.abandon()
            return self.error(
                ProtocolError,
                f"{command!r} got a '?' the controller does not explain (TC1: no error); "
                "the command may have executed",
            )
        error = CommandError(code, text, command, model=self.model_name, recent=self.recent)
        hint = _case_hint(command) if code == 1 else None
        if hint is not None:
            error.args = (f"{error.args[0]} ({hint})",)
        return error

    @property
    def echo(self) -> bool:
        """Whether the session strips an echo from replies (the controller echoes)."""
        return self._session.echo

    def settle_locked(self, batch: Sequence[Command], timeout: float, *, echo: bool) -> None:
        """Send ``batch`` unanswered, then resynchronise, for a caller that holds
        :meth:`locked`: after a failure that may have left the echo on or off and replies
        still due, the lines run whatever the state, and the marker behind them brings the
        link back in step, stripping an echo from then on if ``echo``.

        Raises:
            GalilConnectionError: no answer to the marker within ``timeout`` (the session
                stays out of step: the next exchange resynchronises first).
        """
        # (a burn given up may still hold the answers: the new session knows it)
        self._session = Session(echo=echo, unanswered=self._session.unanswered)
        self._resync(timeout, b"".join(c.text.encode("latin-1") + b"\r" for c in batch))

    def explain_locked(self, rejected: Completed, timeout: float) -> GalilError:
        """The error for a ``?`` (``TC1`` asked), for a caller that holds :meth:`locked`."""
        return self._explain(rejected, timeout)

    def _doubt(self, command: str, why: str) -> ProtocolError:
        self._session.abandon()  # whatever is still on its way must not pass for a reply
        return self.error(
            ProtocolError, f"{command!r} got '?' but {why}; the command may have executed"
        )

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
            ProtocolError: the link went out of step during the exchange (it may have run).
            GalilTimeoutError: no complete reply within the timeout.
            GalilConnectionError: the link is closed or dead.
        """
        check_flag(allow_compound, "allow_compound")
        cmd = _PARSED.get(text) if type(text) is str else None
        if cmd is None or (cmd.parts and not allow_compound):
            cmd = _one_command(text, allow_compound)
        t = self.timeout if timeout is None else check_timeout(timeout, self.timeout)
        lock = self._lock
        # acquire/release rather than `with`: half the cost on the hot path (~0.3 us).
        try:
            lock.acquire()
            try:
                if not self._open or self._dead:
                    raise self._closed_error()
                if (
                    cmd.parts
                    or self._session.out_of_step
                    or self._clock_source is not None
                    or self.wire_log.hooks
                    or _WIRE_CACHE.get(_DEBUG, True)  # unknown: take the general path
                ):
                    done = self._roundtrip((cmd,), t)
                else:
                    reply = self._quick(cmd, t)
                    if type(reply) is str:
                        return reply
                    done = reply  # type: ignore[assignment]
                if len(done) == 1 and done[0].ok:
                    return done[0].text
                if not all(d.ok for d in done):
                    raise _with_replies(self._explain(_last_refused(done), t), done)
            finally:
                lock.release()
                if self._inbox:
                    self._flush()
            return "\r\n".join(d.text for d in done if d.text)
        except _ReopeningError:
            # A reconnect is under way: wait for it, then send as if nothing happened.
            self._await_reopen(t)
            return self.command(text, timeout=timeout, allow_compound=allow_compound)
        except GalilConnectionError as exc:
            if not self._recover(exc):
                raise
            done = self._after_recovery(cmd.parts or (cmd,), t, exc)
            return "\r\n".join(d.text for d in done if d.text)

    def _quick(self, cmd: Command, t: float) -> str | list[Completed]:
        """One command, no hooks, a real link (lock held): the usual exchange, inlined.

        On a fast link every line of Python here is latency.
        """
        session = self._session
        data = session.quick_wire(cmd)
        queued = data is None
        if data is None:
            data = session.send(cmd)
        self.bytes_sent += len(data)
        start = _monotonic()
        transport = self.transport
        assert transport is not None
        try:
            try:
                transport.write(data)
                chunk = transport.read(t)
            except OSError as exc:
                dead = _dead_link(exc, transport)
                if dead is None or dead is exc:
                    raise
                raise dead from exc
        except BaseException as exc:
            # The bytes may be out: whatever their reply does, it must not be the next one's.
            if not queued:
                session.send(cmd)
            session.abandon()
            if isinstance(exc, GalilConnectionError):
                raise self._link_failed(exc) from exc
            raise
        if not queued:
            reply = session.quick_reply(cmd, chunk) if chunk else None
            if reply is not None:
                self.bytes_received += len(chunk)
                self._recent.append(_new_completed((cmd, True, reply, None)))
                return reply
            session.send(cmd)  # anything else: the session matches it as usual
        return self._guarded_collect((cmd,), t, start, 0.0, chunk, False)

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
        for p in parts if type(parts) is list else check_items(parts, "parts"):
            c = p if isinstance(p, Command) else _parse(p)
            if c.parts:
                raise InvalidArgument(f"{c.text!r} is already compound; pass its parts")
            singles.append(c)
        if not singles:
            return []
        lines = cmds.pack(singles, self._model.line_length if self._model else 80)
        return [d.text for d in self.transact(tuple(lines), timeout)]

    def transfer_timeout(self, command: Command, reply_bytes: int = 0) -> float:
        """The reply timeout of a bulk transfer whose size is known before it goes out: the
        link's own timeout (at least :data:`TRANSFER_TIMEOUT`) plus :data:`TRANSFER_MARGIN`
        times what ``command``'s bytes and ``reply_bytes`` more take at :attr:`byte_rate`
        (the reply comes after the command, so the two add up). A transport that does not
        say its rate (USB, PCI, the simulator without ``baud``) is taken to be fast: the
        least alone. Always finite (decision 0022); counted, as every reply timeout, in the
        controller's time on a simulator (decision 0064).

        Args:
            command: the command as it goes out (its payload included: ``QD``, ``DL``).
            reply_bytes: the most bytes its reply can hold.
        """
        return self.transfer_stall + _line_time(self.byte_rate, len(command.wire) + reply_bytes)

    @property
    def transfer_stall(self) -> float:
        """The longest a bulk transfer's reply may stay silent: before it begins (once the
        command's bytes are on the line) and between its pieces. The link's own timeout, at
        least :data:`TRANSFER_TIMEOUT` (decision 0067)."""
        return max(self.timeout, TRANSFER_TIMEOUT)

    def transfer(self, command: Command, reply_bytes: int = 0) -> Completed:
        """Exchange a bulk transfer (``QU``, ``QD``, ``DL``, ``UL``, ``LV``): its whole reply
        within :meth:`transfer_timeout`, and no silence longer than :attr:`transfer_stall`
        (a controller that stops answering is found out in seconds, not after the bound of
        the most the transfer could carry).

        Args:
            command: the command as it goes out (its payload included: ``QD``, ``DL``).
            reply_bytes: the most bytes its reply can hold.

        Raises:
            InvalidArgument: not a Command, or ``reply_bytes`` not a whole number >= 0;
                nothing is sent.
        """
        if not isinstance(command, Command):
            raise InvalidArgument(f"transfer() takes a Command, not {type(command).__name__}")
        if isinstance(reply_bytes, bool) or not isinstance(reply_bytes, int) or reply_bytes < 0:
            raise InvalidArgument(f"reply_bytes must be a whole number >= 0, not {reply_bytes!r}")
        wait = self.transfer_timeout(command, reply_bytes)
        return self.exchange(command, timeout=wait, stall=self.transfer_stall)

    def send(self, command: Command, *, timeout: float | None = None) -> str:
        """Send a prepared :class:`~galil.protocol.commands.Command`; return its reply text."""
        return self.exchange(command, timeout=timeout).text

    def exchange(
        self, command: Command, *, timeout: float | None = None, stall: float | None = None
    ) -> Completed:
        """Send a prepared command and return the whole :class:`Completed` (``record`` for QR).

        A compound command (from ``protocol.commands.pack``) returns its last part's reply.
        ``stall``: the reply must begin within that many seconds of the command's bytes
        being on the line (at :attr:`byte_rate`) and never pause longer, or the exchange
        fails (``GalilTimeoutError``) before ``timeout``; ``None``: only ``timeout`` counts.
        """
        if not isinstance(command, Command):
            raise InvalidArgument(f"exchange() takes a Command, not {type(command).__name__}")
        if stall is not None:
            stall = check_timeout(stall, self.timeout, "stall")
        return self.transact((command,), timeout, stall)[-1]

    def send_many(self, commands: Iterable[Command], *, timeout: float | None = None) -> list[str]:
        """Send prepared commands back to back (pipelined) and return every reply text."""
        batch = tuple(check_items(commands, "commands"))
        for c in batch:
            if not isinstance(c, Command):
                raise InvalidArgument(f"send_many() takes Commands, not {type(c).__name__}")
        if not batch:
            return []
        return [d.text for d in self.transact(batch, timeout)]

    def query_number(self, text: str, *, timeout: float | None = None) -> float:
        """Send a query (``"MG _TPA"``, ``"TPA"``) and return its one number.

        Raises:
            ProtocolError: the reply is not exactly one number.
        """
        values = self.query_numbers(text, timeout=timeout)
        if len(values) != 1:
            raise self.error(ProtocolError, f"{text!r} answered {len(values)} numbers, not one")
        return values[0]

    def query_numbers(self, text: str, *, timeout: float | None = None) -> list[float]:
        """Send a query and return every number in its reply (``"TP"`` -> ``[0.0, 5.0, ...]``)."""
        reply = self.command(text, timeout=timeout)
        try:
            return parse_numbers_reply(reply)
        except (InvalidArgument, ValueError, ProtocolError) as exc:
            raise self.error(ProtocolError, f"{text!r} answered {reply!r}: {exc}") from exc

    def query_operands(self, names: Sequence[str], *, timeout: float | None = None) -> list[float]:
        """Read operands or variables (``["_TPA", "_SCA", "speed"]``) in as few lines as fit.

        The ``MG`` lines go out pipelined under one lock, so no other thread's command
        lands between them. No ``VF`` or ``LZ`` changes what is read (decision 0032): the
        items go out plain, and a line whose reply may not be what the default ``VF 10.4``
        prints (other decimals, hex, an overflow's nines) is asked again with each item in
        ``{Z10.4}``, whose reply must be numbers with four decimals.
        """
        if type(names) is not list and type(names) is not tuple:  # (costs nothing for those)
            names = check_items(names, "names")
        if not names:
            return []
        length = self._model.line_length if self._model else 80
        batches = cmds.mg_operand_lines(names, length, formatted=False)
        done = self.transact(tuple(batches), timeout)
        out: list[float] = []
        for line, d in zip(batches, done, strict=True):
            want = line.text.count(",") + 1
            values = parse_plain_read(d.text)
            if values is None or len(values) != want:
                values = self._read_formatted(line.text[3:].split(","), length, timeout)
            out += values
        return out

    def _read_formatted(self, names: list[str], length: int, timeout: float | None) -> list[float]:
        """``names`` read with each item in ``{Z10.4}``: the answer whatever VF is set."""
        out: list[float] = []
        batches = cmds.mg_operand_lines(names, length)
        for line, d in zip(batches, self.transact(tuple(batches), timeout), strict=True):
            try:
                values = parse_read(d.text)
            except (InvalidArgument, ValueError, ProtocolError) as exc:
                raise self.error(
                    ProtocolError, f"{line.text!r} answered {d.text!r}: {exc}"
                ) from exc
            if len(values) != line.text.count(",") + 1:
                raise self.error(
                    ProtocolError, f"{line.text!r} answered {d.text!r}: not the numbers asked"
                )
            out += values
        return out


def _probe(link: Link, what: str, exc: GalilConnectionError) -> None:
    """Whether ``link`` answers, now that ``what`` (a handle of the same controller) closed
    under ``exc``: one query; a link that does not answer in time is dead."""
    try:
        link._transact([cmds.time_stamp()], link.timeout)
    except GalilTimeoutError:
        with link._lock:
            if link.is_open and not link.dead:
                link._link_failed(
                    GalilConnectionError(
                        f"{what} was closed ({exc}) and the controller did not answer on the"
                        f" command link within {link.timeout:g} s"
                    )
                )
    except GalilError:
        pass  # it answered (a refusal), or the link found itself dead or closed


def _no_reply(text: str, t: float, begun: int) -> str:
    """What a reply timeout says: no reply at all, or a reply cut part way (``begun`` bytes
    of it had arrived: a long one, such as ``LS`` on a slow line, needs a longer timeout)."""
    if not begun:
        return f"no reply to {text!r} within {t:g} s"
    return (
        f"the reply to {text!r} was cut part way: {begun} bytes had arrived and it had not "
        f"ended within {t:g} s; a long reply needs a longer timeout (pass timeout=)"
    )


def _hunt(link: LinkCore, limit: float) -> int | None:
    """Read until the resync marker's answer (``None``), or until ``limit`` seconds have
    passed on the host's clock or the controller's: then the bytes heard meanwhile (lock
    held). Bytes that never stop do not hold the link for ever either."""
    session = link._session
    clock = link._clock_source
    sim_deadline = clock.controller_time() + limit if clock is not None else 0.0
    deadline = _monotonic() + limit
    heard = 0
    while session.out_of_step:
        wait = deadline - _monotonic()
        if clock is not None:
            wait = min(wait, sim_deadline - clock.controller_time())
        chunk = link._read(max(wait, 0.0))
        if chunk:
            heard += len(chunk)
            try:
                events = session.receive_data(chunk)
            except ProtocolError:
                events = []  # the parser is hunting for the marker; junk is expected
            for ev in events:
                if type(ev) is Unsolicited:
                    link._message(ev.line)
        if wait <= 0 and session.out_of_step:
            return heard
    return None


def _unsynced(limit: float, heard: int, held: Sequence[str]) -> str:
    """Why a resynchronisation failed: a burn given up may still hold the answers, or a
    reply still arriving (``heard`` bytes) hid the marker's (both: try again), or not one
    byte came (the link is dead)."""
    why = "the link is out of step and did not resynchronise"
    again = (
        "so try again once it is done; if the controller does not answer at all, call reconnect()"
    )
    if held:
        return (
            f"{why} within {limit:g} s: the controller may still be busy with {held[-1]}"
            f" (a burn holds its answers for seconds), {again}"
        )
    if heard:
        return (
            f"{why} within {limit:g} s: {heard} byte{'s' if heard > 1 else ''} came but not"
            " the answer to its marker"
            f" (a long reply still arriving?), {again}"
        )
    return (
        f"{why}: not one byte came back within {limit:g} s, so the connection is gone"
        " although it was not closed (the controller or a switch on the way restarted, a"
        " cable was pulled)"
    )


def _one_command(text: str, allow_compound: bool) -> Command:
    """Parse a raw line; refuse a stray ``;`` unless a compound line is asked for."""
    cmd = _parse(text) if type(text) is str else cmds.parse_line(text)
    if cmd.parts and not allow_compound:
        raise InvalidArgument(
            f"{text!r} holds {len(cmd.parts)} commands; send one command, or pass "
            "allow_compound=True, or use command_line([...])"
        )
    return cmd


def read_handle(handle: Transport, timeout: float) -> bytes:
    """Read a secondary handle (messages, records, interrupts) for a reader thread.

    A plug-in transport's bare ``OSError`` is the dead link it means
    (:class:`GalilConnectionError`, as on the command link, decision 0036), so a reader ends
    as it does on a built-in transport instead of dying with a traceback; a bare
    ``TimeoutError`` is "nothing arrived" (the transport contract returns ``b""``).

    Raises:
        GalilConnectionError: the handle is closed or dead.
    """
    try:
        return handle.read(timeout)
    except OSError as exc:
        if isinstance(exc, GalilConnectionError):
            raise
        if isinstance(exc, TimeoutError) and not isinstance(exc, GalilError):
            return b""
        raise _broken(exc, handle) from exc


def _dead_link(exc: OSError, transport: Transport) -> GalilConnectionError | None:
    """What a transport's ``OSError`` means for the command link: the dead link it is
    (:func:`_broken`), or ``None`` for one of the library's own errors other than a dead link,
    or a timeout (the caller lets those through as they are)."""
    if isinstance(exc, (GalilError, TimeoutError)) and not isinstance(exc, GalilConnectionError):
        return None
    return _broken(exc, transport)


def _broken(exc: OSError, transport: Transport) -> GalilConnectionError:
    """A transport's ``OSError`` as the dead link it means (a timeout excepted: see the caller).

    The built-in transports raise :class:`GalilConnectionError` for a dead link; a plug-in
    transport may let a bare ``OSError`` out (a broken pipe, a reset connection, ``EIO``).
    That is a dead link all the same, and becomes the same error, as
    :class:`~galil.transport.base.TransportBase` makes it for the built-in ones.
    """
    if isinstance(exc, GalilConnectionError):
        return exc
    name = type(transport).__name__
    return GalilConnectionError(f"the {name} link failed: {type(exc).__name__}: {exc}")


def _line_time(rate: float | None, size: int) -> float:
    """Seconds ``size`` bytes take on a line of ``rate`` bytes/s, :data:`TRANSFER_MARGIN` times
    over (0 on a link that does not say its rate)."""
    if rate is None or not rate > 0:  # (NaN from a plug-in: no rate either)
        return 0.0
    return TRANSFER_MARGIN * size / rate


class _Quiet:
    """How long a transfer's reply may stay silent: until it begins (``wall``, ``sim``: the
    deadlines, on the host's clock and the controller's), then ``stall`` seconds after each
    chunk (decision 0067)."""

    __slots__ = ("begun", "sim", "stall", "wall")

    def __init__(self, stall: float, wall: float, sim: float) -> None:
        self.stall = stall
        self.wall = wall
        self.sim = sim
        self.begun = False

    def heard(self, clock: ControllerClock | None) -> None:
        """A chunk came now: the silence counts again from here."""
        self.begun = True
        self.wall = _monotonic() + self.stall
        if clock is not None:
            self.sim = clock.controller_time() + self.stall

    def left(self, clock: ControllerClock | None) -> float:
        """Seconds of silence still allowed."""
        left = self.wall - _monotonic()
        if clock is not None:
            left = min(left, self.sim - clock.controller_time())
        return left

    def what(self, text: str) -> str:
        """What the silence was, for the timeout's message about command ``text``."""
        if self.begun:
            return f"the reply to {text!r} stopped part way: nothing for {self.stall:g} s"
        return f"no reply to {text!r} within {self.stall:g} s of its bytes being on the line"


class _ReopeningError(GalilConnectionError):
    """Raised inside the link while a reconnect is under way; the caller waits and retries."""


class _ReopenBlock:
    def __init__(self, event: threading.Event) -> None:
        self._event = event

    def __enter__(self) -> None:
        self._event.clear()

    def __exit__(self, *exc: object) -> None:
        self._event.set()


def read_reply(handle: Transport, command: bytes, timeout: float) -> str:
    """Write ``command`` on a handle of its own and read its reply up to ``:`` or ``?``.

    For the few one-off exchanges on a secondary handle (``CF I``, ``MG _WH``).

    Raises:
        GalilTimeoutError: no complete answer in time.
        CommandError: the controller answered ``?``.
    """
    handle.write(command)
    got = b""
    deadline = _monotonic() + timeout
    while not got.rstrip().endswith((b":", b"?")):
        left = deadline - _monotonic()
        if left <= 0:
            raise GalilTimeoutError(f"no answer to {command!r} on a secondary handle")
        got += handle.read(left)
    text = command.decode("latin-1").strip()
    if got.rstrip().endswith(b"?"):
        raise CommandError(None, f"{text} refused on a secondary handle", text)
    return got.rstrip()[:-1].decode("latin-1").strip()
