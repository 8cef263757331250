"""The in-process link: a Transport that talks to a :class:`SimController` directly.

Registered as the ``sim`` scheme of the ``galil.transports`` entry point, so
``sim://DMC-4040`` works wherever a transport address does. Query options::

    sim://DMC-4040?lag=0.005&clock=real&messages=separate&seed=3
    sim://DMC-4040?baud=9600

With the default manual clock, time passes only while the host waits: ``read(timeout)`` runs the
servo loop for up to ``timeout`` simulated seconds and returns as soon as the controller says
something, so a client's wait for a held reply completes in simulated time without anyone
sleeping. The controller is reachable as ``transport.controller`` for tests.

With ``baud`` the link is a serial line of that rate in simulated time
(:class:`SimSerialLink`): it says its ``byte_rate`` (``baud / 10``) as the serial transport
does, and carries bytes both ways no faster than the line would (decision 0064).
"""

from __future__ import annotations

import math
import time
import urllib.parse
from collections import deque
from typing import Any

from galil.errors import GalilConnectionError, InvalidArgument, unknown_options
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultHook, FaultPlan, apply_faults

__all__ = ["SimLink", "SimMessageHandle", "SimSerialLink", "open_transport"]

_POLL_INTERVAL = 0.001


class SimLink:
    """Transport to an in-process simulated controller.

    Args:
        controller: the controller to talk to.
        faults: a :class:`~galil.sim.faults.FaultPlan` or hook applied to replies.
        auto_advance: with a manual clock, let simulated time pass while ``read`` waits.
        messages: ``"inline"`` (unsolicited output mixed in, like a serial port) or
            ``"separate"`` (on :attr:`secondary`, like a TCP message handle).
    """

    kind = "sim"

    def __init__(
        self,
        controller: SimController,
        *,
        faults: FaultHook | None = None,
        auto_advance: bool = True,
        messages: str = "inline",
    ) -> None:
        if messages not in ("inline", "separate"):
            raise InvalidArgument(f"messages must be 'inline' or 'separate', not {messages!r}")
        self.controller = controller
        self.faults = faults
        self.auto_advance = auto_advance
        self._messages = messages
        self._pending: deque[list[Any]] = deque()  # [delay_left_or_ready_time, bytes]
        self._closed = False
        self.secondary: SimMessageHandle | None = None
        if messages == "separate":
            controller.separate_messages = True
            self.secondary = SimMessageHandle(controller)

    @property
    def _manual(self) -> bool:
        return isinstance(self.controller.clock, ManualClock)

    @property
    def manual_clock(self) -> bool:
        """Whether simulated time passes only while the host waits (the default clock): a
        wait that nothing the host does can end never ends
        (:func:`galil.motion.refuse_endless_wait`)."""
        return self._manual

    def _queue(self, data: bytes) -> None:
        now = time.monotonic()
        for delay, piece in apply_faults(self.faults, data):
            # manual clock: a delay is consumed by the host's waiting; real: a ready time
            self._pending.append([delay if self._manual else now + delay, piece])

    def _ready(self, waited: float) -> bytes:
        out = bytearray()
        now = time.monotonic()
        while self._pending:
            head = self._pending[0]
            if self._manual:
                if head[0] > waited:
                    head[0] -= waited
                    waited = 0.0
                    break
                waited -= head[0]
                head[0] = 0.0
            elif head[0] > now:
                break
            out += head[1]
            self._pending.popleft()
        return bytes(out)

    def _check(self) -> None:
        if self._closed:
            raise GalilConnectionError("the simulator link is closed")

    def write(self, data: bytes) -> None:
        """Send bytes to the controller."""
        self._check()
        self._queue(self.controller.feed(bytes(data)))

    def read(self, timeout: float) -> bytes:
        """Return what the controller has said, waiting up to ``timeout`` seconds.

        Returns ``b""`` on timeout.

        Raises:
            GalilConnectionError: the link is closed.
        """
        self._check()
        self._queue(self.controller.poll())
        out = self._ready(0.0)
        if out:
            return out
        if self._manual:
            if self._pending:
                return self._ready(timeout)
            if self.auto_advance and timeout > 0:
                self._queue(self.controller.advance_until_output(timeout))
                return self._ready(0.0)
            return b""
        deadline = time.monotonic() + timeout
        while True:
            self._queue(self.controller.poll())
            out = self._ready(0.0)
            if out or time.monotonic() >= deadline:
                return out
            time.sleep(_POLL_INTERVAL)

    def controller_time(self) -> float:
        """Seconds on the simulator's clock (the ``ControllerClock`` capability)."""
        return float(self.controller.clock.now())

    def let_time_pass(self, seconds: float) -> None:
        """Let ``seconds`` pass for the simulator (``ControllerClock``): see :meth:`sleep`."""
        self.sleep(seconds)

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller: simulated time on a manual clock.

        The client pauses through this between polls, so a host script that waits for a move
        runs at simulation speed in tests instead of sleeping in real time.
        """
        self._check()
        if self._manual:
            self.controller.advance(max(0.0, seconds))
        else:
            time.sleep(max(0.0, seconds))

    def reopen(self) -> SimLink:
        """A new link to the same simulated controller, as a reconnect to a real controller
        finds it as it was (positions, variables, programs): what
        :meth:`galil.Controller.reconnect` on a ``sim://`` address opens."""
        return SimLink(
            self.controller,
            faults=self.faults,
            auto_advance=self.auto_advance,
            messages=self._messages,
        )

    def close(self) -> None:
        """Close the link (and its message handle); later calls raise."""
        self._closed = True
        if self.secondary is not None:
            self.secondary.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<SimLink {self.controller.identity!r} {state}>"


#: Slack in comparing simulated times (sums of floats): a byte due at ``t`` has arrived at ``t``.
_EPS = 1e-9


class SimSerialLink(SimLink):
    """A :class:`SimLink` that is a serial line of ``baud`` bits a second in simulated time
    (8N1: ``baud / 10`` bytes a second each way), as ``sim://MODEL?baud=9600`` opens it.

    It says its :attr:`byte_rate` as the serial transport does (the
    :class:`~galil.transport.ByteRate` capability), and carries bytes no faster: the
    controller takes each line the host wrote once the line's last byte has arrived (it acts
    on whole lines), and the host reads the controller's bytes as they arrive, one after
    another; the two directions run side by side. A fault plan's delay holds a piece back,
    in simulated time, before it goes on the line. Unsolicited output comes inline, as on a
    serial port.

    A manual clock only: paced on a real clock the link would have to sleep. For a serial
    line in real time serve :class:`~galil.sim.server.SimPtyServer` with ``baud``.

    Args:
        controller: the controller to talk to (on a :class:`~galil.sim.clock.ManualClock`).
        baud: the line's rate, bits a second (a positive number).
        faults: as :class:`SimLink`'s.
        auto_advance: as :class:`SimLink`'s (without it, only the host's sleeps let time pass).

    Raises:
        InvalidArgument: a bad ``baud``, or a controller on a clock that is not manual.
    """

    def __init__(
        self,
        controller: SimController,
        *,
        baud: float,
        faults: FaultHook | None = None,
        auto_advance: bool = True,
    ) -> None:
        self.baud = check_baud(baud)
        if not isinstance(controller.clock, ManualClock):
            raise InvalidArgument(
                "baud paces the simulator's manual clock (a real clock would have to sleep); "
                "for a serial line in real time serve SimPtyServer(baud=...) "
                "(galil sim --pty --baud 9600) and connect to its pty"
            )
        super().__init__(controller, faults=faults, auto_advance=auto_advance)
        self._rate = self.baud / 10.0
        # (time the line's last byte reaches the controller, the line), oldest first
        self._inward: deque[tuple[float, bytes]] = deque()
        # (time the piece starts to arrive: its byte j at start + j / rate, piece)
        self._outward: deque[tuple[float, bytes]] = deque()
        self._in_free = 0.0  # when the line to the controller has carried all it was given
        self._out_free = 0.0  # when the line to the host has

    @property
    def byte_rate(self) -> float:
        """Bytes a second the line carries each way: ``baud / 10`` (start, 8 data, stop)."""
        return self._rate

    def _now(self) -> float:
        return float(self.controller.clock.now())

    def write(self, data: bytes) -> None:
        """Put bytes on the line to the controller (it takes each line as it arrives)."""
        self._check()
        start = max(self._now(), self._in_free)
        sent = 0
        for line in bytes(data).splitlines(keepends=True):
            sent += len(line)
            self._inward.append((start + sent / self._rate, line))
        self._in_free = start + sent / self._rate

    def _put(self, data: bytes, at: float) -> None:
        """Put what the controller said at ``at`` on the line to the host."""
        for delay, piece in apply_faults(self.faults, data):
            start = max(at + delay, self._out_free)
            self._outward.append((start, piece))
            self._out_free = start + len(piece) / self._rate

    def _due(self, now: float) -> bool:
        """Whether a byte has reached the host by ``now``."""
        return bool(self._outward) and self._outward[0][0] + 1 / self._rate <= now + _EPS

    def _arrived(self, now: float) -> bytes:
        """Take the bytes that have reached the host by ``now``."""
        out = bytearray()
        while self._outward:
            start, piece = self._outward[0]
            n = min(len(piece), math.floor((now - start + _EPS) * self._rate))
            if n <= 0:
                break
            out += piece[:n]
            if n < len(piece):
                self._outward[0] = (start + n / self._rate, piece[n:])
                break
            self._outward.popleft()
        return bytes(out)

    def _pass(self, until: float, *, stop_at_bytes: bool) -> None:
        """Let simulated time pass to ``until``: hand the controller each line when it has
        arrived, put what the controller says on the line when it says it; with
        ``stop_at_bytes``, stop as soon as bytes have reached the host."""
        controller = self.controller
        while True:
            now = self._now()
            while self._inward and self._inward[0][0] <= now + _EPS:
                self._put(controller.feed(self._inward.popleft()[1]), now)
            self._put(controller.poll(), now)
            if now + _EPS >= until or (stop_at_bytes and self._due(now)):
                return
            end = min(until, self._inward[0][0]) if self._inward else until
            if stop_at_bytes and self._outward:
                end = min(end, self._out_free)  # all that is on the line, in one read
            said = controller.advance_until_output(end - now)
            if said:
                self._put(said, self._now())
            elif end > self._now():
                controller.advance(end - self._now())  # (less than a servo sample)

    def read(self, timeout: float) -> bytes:
        """Return the bytes that have reached the host, letting up to ``timeout`` seconds of
        simulated time pass for the first of them (none without ``auto_advance``).

        Raises:
            GalilConnectionError: the link is closed.
        """
        self._check()
        now = self._now()
        self._pass(now + timeout if self.auto_advance else now, stop_at_bytes=True)
        return self._arrived(self._now())

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of simulated time pass, the line carrying bytes meanwhile."""
        self._check()
        self._pass(self._now() + max(0.0, seconds), stop_at_bytes=False)

    def reopen(self) -> SimSerialLink:
        """A new line of the same rate to the same simulated controller (see
        :meth:`SimLink.reopen`); bytes still on the old line are lost."""
        return SimSerialLink(
            self.controller, baud=self.baud, faults=self.faults, auto_advance=self.auto_advance
        )

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<SimSerialLink {self.controller.identity!r} at {self.baud:g} baud {state}>"


class SimMessageHandle:
    """The unsolicited-message handle of a :class:`SimLink` opened with separate messages."""

    kind = "sim"
    secondary: None = None

    def __init__(self, controller: SimController) -> None:
        self.controller = controller
        self._closed = False

    def write(self, data: bytes) -> None:
        """The message handle accepts no commands; bytes written are ignored."""
        if self._closed:
            raise GalilConnectionError("the simulator message handle is closed")

    def read(self, timeout: float) -> bytes:
        """Return unsolicited output (``b""`` if none); never advances time.

        Raises:
            GalilConnectionError: the handle is closed.
        """
        if self._closed:
            raise GalilConnectionError("the simulator message handle is closed")
        out = self.controller.read_messages()
        if out or isinstance(self.controller.clock, ManualClock):
            return out
        deadline = time.monotonic() + timeout
        while not out and time.monotonic() < deadline:
            time.sleep(_POLL_INTERVAL)
            out = self.controller.read_messages()
        return out

    def close(self) -> None:
        """Close the handle."""
        self._closed = True


def _flag(value: Any, what: str) -> bool:
    """True or False, or their spellings in a URL query (``1``/``0``, ``yes``/``no`` ...)."""
    if isinstance(value, bool):
        return value
    text = value.lower() if isinstance(value, str) else value
    if text in (1, "1", "true", "yes", "on"):
        return True
    if text in (0, "0", "false", "no", "off"):
        return False
    raise InvalidArgument(f"{what} must be true or false, not {value!r:.60}")


def _number(value: Any, what: str, kind: type[int] | type[float]) -> Any:
    """An int or a float option, or its text from a URL query; anything else refused."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise InvalidArgument(f"{what} must be a number, not {value!r:.60}")
    try:
        return kind(value)
    except (ValueError, OverflowError) as exc:  # "x", nan or inf as a seed, 10**400 as a float
        raise InvalidArgument(f"{what} must be a number, not {value!r:.60}") from exc


def check_baud(value: object) -> float:
    """A line rate in bits a second: a positive finite number, or its text from a URL query.

    Raises:
        InvalidArgument: anything else.
    """
    rate: float = _number(value, "baud", float)
    if not (math.isfinite(rate) and rate > 0):
        raise InvalidArgument(f"baud must be a positive number of bits a second, not {value!r:.60}")
    return rate


#: What ``open_transport`` takes (an unknown option's refusal suggests the closest).
_SIM_OPTIONS = (
    "controller", "clock", "lag", "faults", "seed", "auto_advance", "messages", "baud",
    "firmware", "timeout",
)  # fmt: skip


def _clock_of(clock: object) -> Any:
    """The clock of a simulator ``sim://`` builds: ``"manual"`` (the default), ``"real"``, or
    a clock object (one with ``now()``)."""
    if clock == "manual":
        return ManualClock()
    if clock == "real":
        return RealTimeClock()
    if hasattr(clock, "now"):
        return clock
    raise InvalidArgument(f"clock must be 'manual' or 'real', not {clock!r}")


def open_transport(url: str | urllib.parse.SplitResult, **options: object) -> SimLink:
    """Open ``sim://MODEL`` as a :class:`SimLink` (the ``sim`` transport scheme).

    Options (keywords or URL query): ``controller`` (an existing :class:`SimController`, for
    tests), ``clock`` (``"manual"`` or ``"real"``, or a clock object), ``lag`` (servo lag, s),
    ``faults`` (a :class:`FaultPlan` or hook), ``seed`` (random faults: split and interleave
    with this seed), ``auto_advance``, ``messages`` (``"inline"``/``"separate"``), ``baud``
    (a serial line of that rate in simulated time: a :class:`SimSerialLink`; manual clock and
    inline messages only), ``firmware`` (the revision ``^R^V`` reports, ``sim://DMC-30010?
    firmware=1.1b``: :class:`SimController`'s).

    Raises:
        InvalidArgument: a bad scheme, model or option.
    """
    parts = urllib.parse.urlsplit(url) if isinstance(url, str) else url
    if parts.scheme and parts.scheme != "sim":
        raise InvalidArgument(f"not a sim:// address: {parts.geturl()!r}")
    opts: dict[str, Any] = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
    opts.update(options)
    model = parts.netloc or parts.path.strip("/") or "DMC-4040"
    controller = opts.pop("controller", None)
    clock_opt = opts.pop("clock", "manual")
    lag = _number(opts.pop("lag", 0.003), "lag", float)
    faults = opts.pop("faults", None)
    if faults is not None and not callable(faults):
        raise InvalidArgument(f"faults must be a FaultPlan or a hook, not {faults!r:.60}")
    seed = opts.pop("seed", None)
    if faults is None and seed is not None:
        faults = FaultPlan(split=True, seed=_number(seed, "seed", int))
    auto_advance = _flag(opts.pop("auto_advance", True), "auto_advance")
    messages = str(opts.pop("messages", "inline"))
    baud = opts.pop("baud", None)
    firmware = opts.pop("firmware", None)
    if firmware is not None and (not isinstance(firmware, str) or not firmware.strip()):
        raise InvalidArgument(f"firmware must be a revision such as '1.2a', not {firmware!r:.60}")
    if baud is not None:
        baud = check_baud(baud)
        if messages != "inline":
            raise InvalidArgument(
                "baud is a serial line, where unsolicited output comes inline; "
                f"leave out messages={messages!r}"
            )
    opts.pop("timeout", None)  # accepted for symmetry with other transports
    if opts:
        raise unknown_options("sim://", opts, _SIM_OPTIONS)
    if controller is None:
        clock = _clock_of(clock_opt)
        if firmware is None:  # (the SimController's own revision)
            controller = SimController(model, clock, servo_lag=lag)
        else:
            controller = SimController(model, clock, servo_lag=lag, firmware=firmware.strip())
    elif not isinstance(controller, SimController):
        raise InvalidArgument("controller must be a SimController")
    if baud is not None:
        return SimSerialLink(controller, baud=baud, faults=faults, auto_advance=auto_advance)
    return SimLink(controller, faults=faults, auto_advance=auto_advance, messages=messages)
