"""The in-process link: a Transport that talks to a :class:`SimController` directly.

Registered as the ``sim`` scheme of the ``galil.transports`` entry point, so
``sim://DMC-4040`` works wherever a transport address does. Query options::

    sim://DMC-4040?lag=0.005&clock=real&messages=separate&seed=3

With the default manual clock, time passes only while the host waits: ``read(timeout)`` runs the
servo loop for up to ``timeout`` simulated seconds and returns as soon as the controller says
something, so a client's wait for a held reply completes in simulated time without anyone
sleeping. The controller is reachable as ``transport.controller`` for tests.
"""

from __future__ import annotations

import time
import urllib.parse
from collections import deque
from typing import Any

from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultHook, FaultPlan, apply_faults

__all__ = ["SimLink", "SimMessageHandle", "open_transport"]

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


def open_transport(url: str | urllib.parse.SplitResult, **options: Any) -> SimLink:
    """Open ``sim://MODEL`` as a :class:`SimLink` (the ``sim`` transport scheme).

    Options (keywords or URL query): ``controller`` (an existing :class:`SimController`, for
    tests), ``clock`` (``"manual"`` or ``"real"``, or a clock object), ``lag`` (servo lag, s),
    ``faults`` (a :class:`FaultPlan` or hook), ``seed`` (random faults: split and interleave
    with this seed), ``auto_advance``, ``messages`` (``"inline"``/``"separate"``).

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
    opts.pop("timeout", None)  # accepted for symmetry with other transports
    if opts:
        raise InvalidArgument(f"unknown sim:// options: {', '.join(sorted(opts))}")
    if controller is None:
        if clock_opt == "manual":
            clock: Any = ManualClock()
        elif clock_opt == "real":
            clock = RealTimeClock()
        elif hasattr(clock_opt, "now"):
            clock = clock_opt
        else:
            raise InvalidArgument(f"clock must be 'manual' or 'real', not {clock_opt!r}")
        controller = SimController(model, clock, servo_lag=lag)
    elif not isinstance(controller, SimController):
        raise InvalidArgument("controller must be a SimController")
    return SimLink(controller, faults=faults, auto_advance=auto_advance, messages=messages)
