"""The simulator's side of discovery, on loopback only.

- :class:`SimDiscoveryResponder` answers ``^R^V`` datagrams on a UDP port of 127.0.0.1, as a
  controller answers what is sent to its multicast group (:func:`galil.discovery.find` sends
  to the group; a test points it at this port instead).
- :func:`send_bootp_request` sends what a controller without an IP address broadcasts, to a
  loopback port where a test listens (a controller sends it to UDP port 67).
- The TCP probe needs nothing here: :class:`~galil.sim.server.SimTcpServer` answers ``^R^V``.
"""

from __future__ import annotations

import socket
import threading
from types import TracebackType

from galil.errors import GalilConnectionError, InvalidArgument
from galil.protocol.discovery import GALIL_MAC_PREFIX, build_bootp_request

__all__ = ["SimDiscoveryResponder", "send_bootp_request"]

_IDENTIFY = b"\x12\x16"


def _loopback(host: str) -> str:
    if not host.startswith("127."):
        raise InvalidArgument(f"the simulator's discovery stays on loopback, not {host!r}")
    return host


class SimDiscoveryResponder:
    """Answers ``^R^V`` datagrams with a controller's identity (``DMC4040 Rev 1.0\\r\\n:``).

    Anything else gets ``?``, as a controller answers a command it does not know.

    Args:
        identity: what ``^R^V`` answers, e.g. ``SimController(...).identity``.
        host: a loopback address to bind.
        port: UDP port (0 picks a free one; see :attr:`address`).
    """

    def __init__(self, identity: str, *, host: str = "127.0.0.1", port: int = 0) -> None:
        self.identity = identity
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((_loopback(host), port))
        self._sock.settimeout(0.05)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.answered = 0

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the responder listens on."""
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def start(self) -> None:
        """Answer on a background thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name="sim-discovery", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop answering and close the socket (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self._sock.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, peer = self._sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                return
            reply = (self.identity + "\r\n:").encode("latin-1") if _IDENTIFY in data else b"?"
            try:
                self._sock.sendto(reply, peer)
                self.answered += 1
            except OSError:
                continue

    def __enter__(self) -> SimDiscoveryResponder:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def send_bootp_request(
    address: tuple[str, int], serial_number: int = 7, *, family: int = 0x58, dhcp: bool = True
) -> bytes:
    """Send one BOOTP/DHCP request from a simulated Galil MAC to ``address`` (loopback only).

    The MAC is ``00:50:4C:<family>:<serial, 2 bytes>``, as on Galil's controllers. Returns the
    packet sent.

    Raises:
        InvalidArgument: a non-loopback address, or a serial number beyond 16 bits.
        GalilConnectionError: the datagram could not be sent.
    """
    host, port = address
    _loopback(host)
    if not 0 <= serial_number <= 0xFFFF or not 0 <= family <= 0xFF:
        raise InvalidArgument("serial_number must fit 16 bits and family 8 bits")
    mac = GALIL_MAC_PREFIX + bytes([family, serial_number >> 8, serial_number & 0xFF])
    packet = build_bootp_request(mac, xid=0x47414C00 | (serial_number & 0xFF), dhcp=dhcp)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.sendto(packet, (host, port))
        except OSError as exc:
            raise GalilConnectionError(f"cannot send to {host}:{port}: {exc}") from exc
    return packet
