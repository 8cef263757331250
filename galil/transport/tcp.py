"""Ethernet transport: a TCP socket to the controller's command port (23 by default).

Galil Ethernet controllers serve several handles (connections to the same port, A to H); the
client asks for a second one with :meth:`TcpTransport.open_secondary` and points unsolicited
messages at it (``CF I`` sent on that handle), so that they never share a stream with replies.
:meth:`TcpTransport.open_handle` opens further handles (a ``DR`` data-record stream gets its
own).
"""

from __future__ import annotations

import contextlib
import socket
from typing import Any
from urllib.parse import SplitResult

from galil.errors import GalilConnectionError, InvalidArgument
from galil.models import ETHERNET_BYTES_PER_S
from galil.transport import parse_options, timeout_grid

__all__ = ["DEFAULT_PORT", "TcpTransport", "open_tcp"]

DEFAULT_PORT = 23
_CHUNK = 65536


class TcpTransport:
    """A connected TCP handle.

    Args:
        host: controller host name or address.
        port: TCP port (23, the Galil command port, by default).
        connect_timeout: seconds allowed for the TCP handshake.
        sock: an already connected socket to adopt instead of connecting (tests, tunnels).
        message_port: a port that carries only unsolicited output (the simulator's server,
            protocol gateways); :meth:`open_secondary` connects there instead of to ``port``.

    Attributes:
        messages_only: this handle carries only unsolicited output (no ``CF`` needed).
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        connect_timeout: float = 5.0,
        sock: socket.socket | None = None,
        message_port: int | None = None,
        messages_only: bool = False,
    ) -> None:
        if not isinstance(port, int) or not 0 < port < 65536:
            raise InvalidArgument(f"TCP port must be 1..65535, got {port!r}")
        self.host = host
        self.port = port
        self.connect_timeout = connect_timeout
        if message_port is not None and (
            isinstance(message_port, bool)
            or not isinstance(message_port, int)
            or not 0 < message_port < 65536
        ):
            raise InvalidArgument(f"message port must be 1..65535, got {message_port!r}")
        self.message_port = message_port
        self.messages_only = messages_only
        self.secondary: TcpTransport | None = None
        if sock is None:
            try:
                sock = socket.create_connection((host, port), timeout=connect_timeout)
            except OSError as exc:
                raise GalilConnectionError(
                    f"cannot connect to {host}:{port} over TCP: {exc}"
                ) from exc
        # Commands are a few bytes each; Nagle would hold them back waiting for an ACK.
        # (A socketpair adopted in tests is no TCP socket: nothing to tune then.)
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock: socket.socket | None = sock
        self._timeout: float | None = -1.0  # forces the first settimeout
        self._timeout_in = -1.0

    @property
    def kind(self) -> str:
        """Always ``"ethernet"``."""
        return "ethernet"

    @property
    def byte_rate(self) -> float:
        """Sustained command bytes per second (round trips, not the wire, set the pace)."""
        return ETHERNET_BYTES_PER_S

    def __repr__(self) -> str:
        state = "open" if self._sock is not None else "closed"
        return f"<TcpTransport {self.host}:{self.port} {state}>"

    def _live(self) -> socket.socket:
        sock = self._sock
        if sock is None:
            raise GalilConnectionError(f"TCP link to {self.host}:{self.port} is closed")
        return sock

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        sock = self._sock
        if sock is None:
            raise GalilConnectionError(f"TCP link to {self.host}:{self.port} is closed")
        try:
            sock.sendall(data)
        except OSError as exc:
            raise GalilConnectionError(
                f"TCP link to {self.host}:{self.port} failed while sending: {exc}"
            ) from exc

    def read(self, timeout: float) -> bytes:
        """Return what arrives within ``timeout`` seconds (``b""`` if nothing)."""
        sock = self._sock
        if sock is None:
            raise GalilConnectionError(f"TCP link to {self.host}:{self.port} is closed")
        try:
            if timeout != self._timeout_in:
                # settimeout costs syscalls; a caller repeating its timeout reuses the one set.
                t = timeout_grid(timeout)
                if t != self._timeout:
                    sock.settimeout(t)
                    self._timeout = t
                self._timeout_in = timeout
            data = sock.recv(_CHUNK)
        except (TimeoutError, BlockingIOError):
            return b""
        except OSError as exc:
            raise GalilConnectionError(
                f"TCP link to {self.host}:{self.port} failed while reading: {exc}"
            ) from exc
        if not data:
            raise GalilConnectionError(f"controller at {self.host}:{self.port} closed the link")
        return data

    def open_secondary(self) -> TcpTransport:
        """Open (once) a second handle to the same controller and return it.

        Raises:
            GalilConnectionError: the controller refused another handle.
        """
        if self.secondary is None:
            self._live()
            if self.message_port is not None:
                self.secondary = TcpTransport(
                    self.host,
                    self.message_port,
                    connect_timeout=self.connect_timeout,
                    messages_only=True,
                )
            else:
                self.secondary = TcpTransport(
                    self.host, self.port, connect_timeout=self.connect_timeout
                )
        return self.secondary

    def open_handle(self) -> TcpTransport:
        """Open another handle to the same controller port; the caller owns and closes it.

        Raises:
            GalilConnectionError: this link is closed, or the controller refused the handle
                (it has eight at most).
        """
        self._live()
        return TcpTransport(self.host, self.port, connect_timeout=self.connect_timeout)

    def close(self) -> None:
        """Close this handle and the secondary one; idempotent."""
        if self.secondary is not None:
            self.secondary.close()
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):  # already reset by the peer
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()


def open_tcp(url: SplitResult, **options: Any) -> TcpTransport:
    """Open ``tcp://host[:port]``; options: ``port``, ``connect_timeout``, ``message_port``.

    Raises:
        InvalidArgument: no host, or an option we do not know.
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
    port = opts.pop("port", url_port if url_port is not None else DEFAULT_PORT)
    connect_timeout = float(opts.pop("connect_timeout", 5.0))
    message_port = opts.pop("message_port", None)
    if opts:
        raise InvalidArgument(f"unknown TCP option(s): {', '.join(sorted(opts))}")
    return TcpTransport(host, port, connect_timeout=connect_timeout, message_port=message_port)
