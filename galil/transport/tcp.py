"""Ethernet transport: a TCP socket to the controller's command port (23 by default).

Galil Ethernet controllers serve several handles (connections to the same port, A to H); the
client asks for a second one with :meth:`TcpTransport.open_secondary` and points unsolicited
messages at it (``CF I`` sent on that handle), so that they never share a stream with replies.
:meth:`TcpTransport.open_handle` opens further handles (a ``DR`` data-record stream gets its
own).
"""

from __future__ import annotations

import contextlib
import select
import selectors
import socket
import time
from typing import cast
from urllib.parse import SplitResult

from galil.errors import GalilConnectionError, InvalidArgument, unknown_options
from galil.models import ETHERNET_BYTES_PER_S
from galil.portnumber import check_port
from galil.transport import parse_options
from galil.transport.base import TransportBase
from galil.transport.options import dotted_quad, seconds

__all__ = ["DEFAULT_PORT", "TcpTransport", "UdpTransport", "open_tcp"]

DEFAULT_PORT = 23
_CHUNK = 65536
# poll() where there is one (no FD_SETSIZE ceiling, no descriptor of its own), else select().
_Selector = selectors.PollSelector if hasattr(select, "poll") else selectors.SelectSelector


class TcpTransport(TransportBase[socket.socket]):
    """A connected TCP handle.

    Capabilities: :class:`~galil.transport.HandleSource` (:meth:`open_secondary`,
    :meth:`open_handle`), :class:`~galil.transport.MessagesOnly` and
    :class:`~galil.transport.ByteRate`.

    Args:
        host: controller host name or address.
        port: TCP port (23, the Galil command port, by default).
        connect_timeout: seconds allowed for the TCP handshake.
        write_timeout: seconds a write may wait for the peer to take more data (whatever
            the read timeout is).
        sock: an already connected socket to adopt instead of connecting (tests, tunnels).
        message_port: a port that carries only unsolicited output (the simulator's server,
            protocol gateways); :meth:`open_secondary` connects there instead of to ``port``.
        messages_only: this handle carries only unsolicited output (set on the handle
            :meth:`open_secondary` opens to ``message_port``).

    Attributes:
        messages_only: this handle carries only unsolicited output (no ``CF`` needed).
    """

    kind = "ethernet"

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        connect_timeout: float = 5.0,
        write_timeout: float = 5.0,
        sock: socket.socket | None = None,
        message_port: int | None = None,
        messages_only: bool = False,
    ) -> None:
        check_port(port, "TCP port")
        if message_port is not None:
            check_port(message_port, "message port")
        self.host = host
        self.port = port
        self.connect_timeout = seconds(connect_timeout, "connect_timeout")
        self.write_timeout = seconds(write_timeout, "write_timeout")
        self.message_port = message_port
        self.messages_only = messages_only
        if sock is None:
            dotted_quad(host, "TCP host")  # no DNS query for 999.1.1.1
            try:
                sock = socket.create_connection((host, port), timeout=connect_timeout)
            except OSError as exc:
                hint = ""
                if isinstance(exc, ConnectionResetError):
                    # (a controller with its eight handles taken drops a connection at once)
                    hint = (
                        ": the controller may have no free Ethernet handle (TH on another"
                        " connection lists them: close one, or free a stale one with IHm=>-1)"
                    )
                raise GalilConnectionError(
                    f"cannot connect to {host}:{port} over TCP: {exc}{hint}"
                ) from exc
        # Commands are a few bytes each; Nagle would hold them back waiting for an ACK.
        # (A socketpair adopted in tests is no TCP socket: nothing to tune then.)
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # Reads wait with the socket's timeout (one C-level poll and recv: the round trip's
        # hot path). A write goes out with whatever timeout the last read left, 0 included;
        # when the peer takes no more, it waits for room up to write_timeout on a selector of
        # its own (a zero-timeout poll must not leave a large write unable to wait).
        self._writable = _Selector()
        self._writable.register(sock, selectors.EVENT_WRITE)
        super().__init__(sock, name=f"{host}:{port}", label=f"TCP link to {host}:{port}")

    @property
    def byte_rate(self) -> float:
        """Sustained command bytes per second (round trips, not the wire, set the pace)."""
        return ETHERNET_BYTES_PER_S

    def _send(self, handle: socket.socket, data: bytes) -> None:
        n = self._send_some(handle, data)  # a command line fits the socket buffer: one send
        if n < len(data):
            super()._send(handle, data[n:])  # the rest piece by piece, waiting for room

    def _send_some(self, handle: socket.socket, data: bytes | memoryview) -> int:
        try:
            return handle.send(data)
        except (BlockingIOError, TimeoutError):  # no room now: _wait_writable waits for it
            return 0

    def _set_timeout(self, handle: socket.socket, seconds: float) -> None:
        handle.settimeout(seconds)  # 0 makes the socket non-blocking: a poll

    def _wait_writable(self, handle: socket.socket) -> None:
        if not self._writable.select(self.write_timeout):
            raise GalilConnectionError(
                f"{self.label} did not accept data within {self.write_timeout:g} s"
            )

    def _recv(self, handle: socket.socket, timeout: float) -> bytes:
        try:
            data = handle.recv(_CHUNK)
        except (TimeoutError, BlockingIOError):
            return b""
        if not data:
            raise GalilConnectionError(f"controller at {self.host}:{self.port} closed the link")
        return data

    def _release(self, handle: socket.socket) -> None:
        self._writable.close()
        with contextlib.suppress(OSError):  # already reset by the peer
            handle.shutdown(socket.SHUT_RDWR)
        handle.close()

    def open_secondary(self) -> TcpTransport:
        """Open (once) a second handle to the same controller and return it.

        Raises:
            GalilConnectionError: this link is closed, or the controller refused another
                handle.
        """
        second = self.secondary
        if isinstance(second, TcpTransport):
            return second
        self._live()
        if self.message_port is not None:
            second = TcpTransport(
                self.host,
                self.message_port,
                connect_timeout=self.connect_timeout,
                write_timeout=self.write_timeout,
                messages_only=True,
            )
        else:
            second = self._another()
        self.secondary = second
        return second

    def open_handle(self) -> TcpTransport:
        """Open another handle to the same controller port; the caller owns and closes it.

        Raises:
            GalilConnectionError: this link is closed, or the controller refused the handle
                (it has eight at most).
        """
        self._live()
        return self._another()

    def _another(self) -> TcpTransport:
        return TcpTransport(
            self.host,
            self.port,
            connect_timeout=self.connect_timeout,
            write_timeout=self.write_timeout,
        )

    def open_datagram_handle(self) -> UdpTransport:
        """Open a UDP handle to the same controller and port (interrupts go to one); the
        caller owns and closes it. The controller gives it a handle letter at its first
        command.

        Raises:
            GalilConnectionError: this link is closed, or no socket could be made.
        """
        self._live()
        return UdpTransport(self.host, self.port, write_timeout=self.write_timeout)


class UdpTransport(TransportBase[socket.socket]):
    """A UDP handle to a controller: each write is one datagram, each read one or more.

    Galil controllers answer commands on UDP port 23 as on TCP, and send ``EI`` interrupt
    packets only to a UDP handle. Loss is possible: use it for what may be lost (interrupts
    are also visible as ``_BG``), not for motion commands.

    Capability: :class:`~galil.transport.LocalAddress` (the host's end, as ``TH`` names it).

    As on TCP, reads wait with the socket's timeout and a write goes out with whatever
    timeout the last read left (a poll before the first read, so no write waits for ever); a
    datagram the socket has no room for then waits for room on a selector until
    ``write_timeout`` has passed since the write began, and fails with
    :class:`~galil.errors.GalilConnectionError`.

    Args:
        host: controller host name or address.
        port: UDP port (23 by default).
        write_timeout: seconds a datagram may wait for room in the socket.
        sock: an already connected datagram socket to adopt instead of making one (tests).
    """

    kind = "ethernet"

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        write_timeout: float = 5.0,
        sock: socket.socket | None = None,
    ) -> None:
        check_port(port, "UDP port")
        self.write_timeout = seconds(write_timeout, "write_timeout")
        self.host = host
        self.port = port
        if sock is None:
            dotted_quad(host, "UDP host")
            sock = _udp_socket(host, port)
        sock.settimeout(0.0)  # a poll until the first read sets its timeout
        self._local = _sockname(sock)
        self._writable = _Selector()
        self._writable.register(sock, selectors.EVENT_WRITE)
        super().__init__(
            sock, name=f"udp {host}:{port}", label=f"UDP handle to {host}:{port}", timeout=0.0
        )

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The host's end of the handle, ``(address, port)``, as ``TH`` on the controller
        names it (``None`` if the socket could not say)."""
        return self._local

    def _send(self, handle: socket.socket, data: bytes) -> None:
        # One datagram: it goes whole or not at all, so a retry sends all of it again.
        deadline = time.monotonic() + self.write_timeout
        while True:
            try:
                handle.send(data)
                return
            except (BlockingIOError, TimeoutError):  # no room now
                pass
            except ConnectionRefusedError as exc:  # an ICMP "port unreachable" came back
                raise self._unanswered() from exc
            left = deadline - time.monotonic()
            if left <= 0 or not self._writable.select(left):
                raise GalilConnectionError(
                    f"{self.label} did not accept data within {self.write_timeout:g} s"
                )

    def _set_timeout(self, handle: socket.socket, seconds: float) -> None:
        handle.settimeout(seconds)

    def _recv(self, handle: socket.socket, timeout: float) -> bytes:
        try:
            return handle.recv(_CHUNK)
        except (TimeoutError, BlockingIOError):
            return b""
        except ConnectionRefusedError as exc:  # an ICMP "port unreachable" came back
            raise self._unanswered() from exc

    def _unanswered(self) -> GalilConnectionError:
        return GalilConnectionError(f"nothing answers UDP at {self.host}:{self.port}")

    def _release(self, handle: socket.socket) -> None:
        self._writable.close()
        # A thread blocked in recv() on this socket (an interrupt reader) wakes at once on
        # Linux after a shutdown; close() alone would leave it to its timeout.
        with contextlib.suppress(OSError):
            handle.shutdown(socket.SHUT_RDWR)
        handle.close()


def _sockname(sock: socket.socket) -> tuple[str, int] | None:
    try:
        name = sock.getsockname()
    except OSError:
        return None
    if not isinstance(name, tuple) or len(name) < 2:
        return None
    return str(name[0]), int(name[1])


def _udp_socket(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.connect((host, port))
    except OSError as exc:
        sock.close()
        raise GalilConnectionError(f"cannot open a UDP handle to {host}:{port}: {exc}") from exc
    return sock


def open_tcp(url: SplitResult, **options: object) -> TcpTransport:
    """Open ``tcp://host[:port]``.

    Options: ``port``, ``connect_timeout``, ``write_timeout``, ``message_port``.

    Raises:
        InvalidArgument: no host, a path after it, a bad value, or an option we do not know.
        GalilConnectionError: the connection failed.
    """
    opts = parse_options(url, options)
    try:
        url_port = url.port
    except ValueError as exc:
        raise InvalidArgument(f"bad TCP port in {url.geturl()!r}: {exc}") from exc
    host = url.hostname
    if not host:
        raise InvalidArgument(f"no host in {url.geturl()!r}; write tcp://host[:port]")
    if url.path not in ("", "/") or url.fragment:
        raise InvalidArgument(f"a TCP address has no path: {url.geturl()!r}")
    port = check_port(opts.pop("port", DEFAULT_PORT if url_port is None else url_port), "TCP port")
    connect_timeout = seconds(opts.pop("connect_timeout", 5.0), "connect_timeout")
    write_timeout = seconds(opts.pop("write_timeout", 5.0), "write_timeout")
    message_port = opts.pop("message_port", None)
    if message_port is not None:
        check_port(message_port, "message port")
    if opts:
        raise unknown_options(
            "TCP", opts, ("port", "connect_timeout", "write_timeout", "message_port")
        )
    return TcpTransport(
        host,
        port,
        connect_timeout=connect_timeout,
        write_timeout=write_timeout,
        message_port=cast("int | None", message_port),  # (checked above)
    )
