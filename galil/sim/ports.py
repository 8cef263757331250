"""Ports and handles: where the simulated controller's bytes come in and go out.

Port 0 is the main port (a serial port, or the command handle of the TCP server's first
client); :meth:`Ports.open` adds Ethernet handles, lettered A-H in the order the controller
hands them out. Each port has its unparsed input, its output queue and what it waits for (a
held ``:``). Unsolicited output (program ``MG``, messages) goes where ``CF`` routes it: to a
handle, to the message queue of a TCP message handle (``separate``), or into the main port's
stream (serial behaviour), with the high bit set under ``CW 1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.parse import Refused
from galil.sim.registry import Collect, Wait

__all__ = ["HANDLES", "Port", "Ports"]

#: Ethernet handle letters, in the order the controller hands them out.
HANDLES = "ABCDEFGH"


@dataclass(eq=False)
class Port:
    """One command handle: its unparsed input, its output and what it is waiting for."""

    name: str
    number: int = 0
    letter: str = ""  # Ethernet handle letter (A-H); "" for the main (serial) port
    inbuf: str = ""
    out: bytearray = field(default_factory=bytearray)
    wait: Wait | None = None
    download: list[str] | None = None
    download_refused: bool = False  # a DL line was refused (TC 60): the rest is dropped
    collect: Collect | None = None
    collected: str = ""
    swallow_cr: bool = False

    def take(self) -> bytes:
        """Return and clear the output waiting for the host."""
        out = bytes(self.out)
        self.out.clear()
        return out


class Ports:
    """The open ports, the routing of unsolicited output and the output settings.

    Attributes:
        separate: unsolicited output goes to :meth:`take_messages` (a TCP message handle)
            instead of the main port's stream.
        route: number of the port ``CF`` sends unsolicited output to (None: the default).
        echo: ``EO 1``: input is echoed.
        cw: ``CW`` first field (1: unsolicited bytes get the high bit; 2: they do not).
        cw_mode: ``CW`` second field.
    """

    def __init__(self) -> None:
        self.ports: dict[int, Port] = {0: Port("main")}
        self._next = 1
        self.separate = False
        self.route: int | None = None
        self._messages = bytearray()
        self.reset()

    def reset(self) -> None:
        """Power-on output settings; held replies and downloads are dropped. ``CF`` goes
        back to the main port (R4103: CF is not burnable, its default is S)."""
        self.echo = False
        self.cw = 2
        self.cw_mode = 0
        self.route = None
        for port in self.ports.values():
            port.wait = None
            port.download = None
            port.collect = None

    def get(self, number: int) -> Port:
        """The open port ``number``.

        Raises:
            InvalidArgument: no such port is open.
        """
        try:
            return self.ports[number]
        except KeyError:
            raise InvalidArgument(f"no open port {number}") from None

    def open(self, name: str) -> Port:
        """Open a handle with the first free letter A-H.

        Raises:
            GalilConnectionError: all eight handles are in use.
        """
        used = {p.letter for p in self.ports.values()}
        free = [c for c in HANDLES if c not in used]
        if not free:
            raise GalilConnectionError("all eight Ethernet handles are in use")
        port = Port(name, number=self._next, letter=free[0])
        self._next += 1
        self.ports[port.number] = port
        return port

    def close(self, number: int) -> None:
        """Close a handle (the main port stays); output routed to it falls back."""
        if number != 0:
            self.ports.pop(number, None)
            if self.route == number:
                self.route = None

    def handle(self, letter: str) -> Port:
        """The open handle named ``letter``.

        Raises:
            Refused: TC 126, the handle is not open.
        """
        for p in self.ports.values():
            if p.letter == letter:
                return p
        raise Refused(126, f"Ethernet handle {letter} is not open")

    def emit(self, text: str) -> None:
        """Send unsolicited output (a program's ``MG``) where ``CF`` routes it."""
        data = text.encode("latin-1", "replace")
        if self.cw == 1:
            data = bytes(b | 0x80 for b in data)
        if self.route is not None and self.route in self.ports:
            self.ports[self.route].out += data
        elif self.separate:
            self._messages += data
        else:
            self.ports[0].out += data

    def take_messages(self) -> bytes:
        """Return and clear the output waiting for the message handle."""
        out = bytes(self._messages)
        self._messages.clear()
        return out

    def describe(self) -> str:
        """The ``TH`` text: the controller's address and each handle's user."""
        lines = ["CONTROLLER IP ADDRESS 127,0,0,1 ETHERNET ADDRESS 00-50-4C-00-00-01"]
        names = {p.letter: p.name for p in self.ports.values() if p.letter}
        for letter in HANDLES:
            lines.append(f"IH{letter} {names.get(letter, 'AVAILABLE')}")
        return "\r\n".join(lines) + "\r\n"
