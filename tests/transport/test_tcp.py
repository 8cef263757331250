"""TcpTransport against a real loopback server."""

from __future__ import annotations

import socket
import time

import pytest
from transport_peers import TcpPeer, read_until

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import Transport, open_transport
from galil.transport.tcp import DEFAULT_PORT, TcpTransport


def test_round_trip_and_kind(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"tcp://127.0.0.1:{tcp_peer.port}")
    try:
        assert isinstance(t, TcpTransport)
        assert isinstance(t, Transport)
        assert t.kind == "ethernet"
        assert t.secondary is None
        t.write(b"MG 42\r")
        assert read_until(t.read, b":") == b" 42\r\n:"
        t.write(b"SHA\rbg\r")
        assert read_until(t.read, b"?") == b":?"
    finally:
        t.close()


def test_bare_ipv4_means_tcp(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"127.0.0.1:{tcp_peer.port}")
    try:
        assert t.kind == "ethernet"
        t.write(b"MG 7\r")
        assert read_until(t.read, b":") == b" 7\r\n:"
    finally:
        t.close()


def test_port_option_overrides_url(tcp_peer: TcpPeer) -> None:
    t = open_transport("tcp://127.0.0.1:1", port=tcp_peer.port)
    t.close()


def test_read_times_out_empty(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"tcp://127.0.0.1:{tcp_peer.port}")
    try:
        start = time.monotonic()
        assert t.read(0.05) == b""
        assert time.monotonic() - start >= 0.04
        assert t.read(0) == b""  # a poll returns at once
    finally:
        t.close()


def test_secondary_handle_is_a_second_connection(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"tcp://127.0.0.1:{tcp_peer.port}")
    assert isinstance(t, TcpTransport)
    try:
        second = t.open_secondary()
        assert t.secondary is second
        assert t.open_secondary() is second  # once only
        assert tcp_peer.accepted.acquire(timeout=2)
        assert tcp_peer.accepted.acquire(timeout=2)
        second.write(b"MG 1\r")
        assert read_until(second.read, b":") == b" 1\r\n:"
    finally:
        t.close()
    with pytest.raises(GalilConnectionError):
        second.read(0)


def test_peer_closing_is_a_connection_error(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"tcp://127.0.0.1:{tcp_peer.port}")
    try:
        assert tcp_peer.accepted.acquire(timeout=2)
        tcp_peer.drop_all()
        with pytest.raises(GalilConnectionError, match="closed the link"):
            read_until(t.read, b":")
    finally:
        t.close()


def test_closed_transport_refuses(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"tcp://127.0.0.1:{tcp_peer.port}")
    t.close()
    t.close()  # idempotent
    with pytest.raises(GalilConnectionError, match="closed"):
        t.write(b"TP\r")
    with pytest.raises(GalilConnectionError, match="closed"):
        t.read(0.01)
    assert "closed" in repr(t)


def test_connection_refused() -> None:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(GalilConnectionError, match=f"127.0.0.1:{port}"):
        open_transport(f"tcp://127.0.0.1:{port}", connect_timeout=1.0)


@pytest.mark.parametrize(
    ("address", "options", "message"),
    [
        ("tcp://", {}, "no host"),
        ("tcp://127.0.0.1:99999", {}, "port"),
        ("tcp://127.0.0.1", {"baudrate": 9600}, "unknown TCP option"),
        ("tcp://127.0.0.1", {"port": 0}, "1..65535"),
    ],
)
def test_bad_tcp_addresses(address: str, options: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidArgument, match=message):
        open_transport(address, **options)


def test_default_port_is_telnet() -> None:
    assert DEFAULT_PORT == 23


def test_adopts_a_connected_socket() -> None:
    a, b = socket.socketpair()
    t = TcpTransport("pair", 1, sock=a)
    try:
        t.write(b"abc")
        assert b.recv(10) == b"abc"
        b.sendall(b":")
        assert t.read(1.0) == b":"
    finally:
        t.close()
        b.close()
