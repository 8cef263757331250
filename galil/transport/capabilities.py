"""Optional capabilities a transport may offer, as small Protocols.

The link above a transport asks ``isinstance(transport, Capability)`` once, when it opens,
and never looks inside a transport for anything else. A plug-in transport gets a feature by
offering its methods; nothing has to inherit from anything.

- :class:`ControllerClock`: the controller keeps its own time (a simulator). Timeouts also
  count in it, and the host's pauses let it pass (simulated time on a manual clock).
- :class:`HandleSource`: further handles to the same controller (Ethernet): one for
  unsolicited output, more for data-record streams.
- :class:`DatagramSource`: a UDP handle to the same controller (interrupt packets).
- :class:`MessagesOnly`: a handle that carries only unsolicited output (no ``CF`` needed).
- :class:`LocalAddress`: a handle that knows the host's end of it (how ``TH`` names it).
- :class:`ByteRate`: how many bytes a second the link carries, for stream planning.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    from galil.transport import Transport

__all__ = [
    "ByteRate",
    "ControllerClock",
    "DatagramSource",
    "HandleSource",
    "LocalAddress",
    "MessagesOnly",
]


@runtime_checkable
class ControllerClock(Protocol):
    """A transport whose controller runs on a clock of its own (a simulator)."""

    def controller_time(self) -> float:
        """Seconds on the controller's clock (simulated time on a simulator)."""
        ...

    def let_time_pass(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller (advance a manual clock, or sleep)."""
        ...


@runtime_checkable
class HandleSource(Protocol):
    """A transport that can open more handles to the same controller (Ethernet)."""

    def open_secondary(self) -> Transport:
        """Open (once) the handle unsolicited output goes to, and return it."""
        ...

    def open_handle(self) -> Transport:
        """Open a further handle that the caller owns and closes (a record stream's)."""
        ...


@runtime_checkable
class DatagramSource(Protocol):
    """A transport that can open a UDP handle to the same controller (where ``EI`` sends its
    interrupt packets)."""

    def open_datagram_handle(self) -> Transport:
        """Open a UDP handle that the caller owns and closes."""
        ...


@runtime_checkable
class MessagesOnly(Protocol):
    """A handle that may carry only unsolicited output (``messages_only`` True)."""

    messages_only: bool


@runtime_checkable
class ByteRate(Protocol):
    """A link whose capacity matters for streaming (serial lines, Ethernet)."""

    @property
    def byte_rate(self) -> float:
        """Bytes per second the link carries in each direction."""
        ...


@runtime_checkable
class LocalAddress(Protocol):
    """A handle that knows its host end: the address and port the controller sees it come
    from (NAT aside), as ``TH`` lists them."""

    @property
    def local_address(self) -> tuple[str, int] | None:
        """``(dotted address, port)`` of the host's end, ``None`` if unknown."""
        ...
