"""What only the TCP transport does: addresses, options, extra handles, adopted sockets.

The behaviour every transport shares (round trips, timeouts, close, a vanished peer) is in
test_contract.py.
"""

from __future__ import annotations

import socket
import threading

import pytest
from transport_peers import TcpPeer, read_until

import galil
from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.server import SimTcpServer
from galil.transport import MessagesOnly, open_transport
from galil.transport.tcp import DEFAULT_PORT, TcpTransport


def open_tcp(peer: TcpPeer, **options: object) -> TcpTransport:
    t = open_transport(f"tcp://127.0.0.1:{peer.port}", **options)
    assert isinstance(t, TcpTransport)
    return t


def test_bare_ipv4_means_tcp(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"127.0.0.1:{tcp_peer.port}")
    try:
        assert isinstance(t, TcpTransport)
        t.write(b"MG 7\r")
        assert read_until(t.read, b":") == b" 7\r\n:"
    finally:
        t.close()


def test_port_option_overrides_url(tcp_peer: TcpPeer) -> None:
    t = open_transport("tcp://127.0.0.1:1", port=tcp_peer.port)
    try:
        assert isinstance(t, TcpTransport)
        assert t.port == tcp_peer.port
        assert tcp_peer.accepted.acquire(timeout=2)
    finally:
        t.close()


def test_secondary_handle_is_a_second_connection_closed_with_the_first(tcp_peer: TcpPeer) -> None:
    t = open_tcp(tcp_peer)
    try:
        second = t.open_secondary()
        assert t.secondary is second
        assert t.open_secondary() is second  # once only
        assert not second.messages_only  # a command handle: the client sends CF I on it
        assert tcp_peer.accepted.acquire(timeout=2)
        assert tcp_peer.accepted.acquire(timeout=2)
        second.write(b"MG 1\r")
        assert read_until(second.read, b":") == b" 1\r\n:"
    finally:
        t.close()
    assert "closed" in repr(second)
    with pytest.raises(GalilConnectionError, match="closed"):
        second.read(0)


def test_message_port_gives_a_messages_only_secondary(tcp_peer: TcpPeer) -> None:
    with socket.create_server(("127.0.0.1", 0)) as messages:
        t = open_tcp(tcp_peer, message_port=messages.getsockname()[1])
        try:
            second = t.open_secondary()
            conn, _ = messages.accept()
            conn.close()
            assert isinstance(second, MessagesOnly)
            assert second.messages_only
            assert second.port == messages.getsockname()[1]
            assert not t.messages_only
        finally:
            t.close()


def test_open_handle_gives_a_new_handle_each_time(tcp_peer: TcpPeer) -> None:
    t = open_tcp(tcp_peer)
    handles = [t.open_handle(), t.open_handle()]
    try:
        assert handles[0] is not handles[1]
        assert t.secondary is None  # owned by the caller, not by t
        for h in handles:
            h.write(b"MG 3\r")
            assert read_until(h.read, b":") == b" 3\r\n:"
    finally:
        t.close()
    assert "open" in repr(handles[0])  # closing t leaves the caller's handles alone
    for h in handles:
        h.close()


def test_closed_link_opens_no_more_handles(tcp_peer: TcpPeer) -> None:
    t = open_tcp(tcp_peer)
    t.close()
    with pytest.raises(GalilConnectionError, match="closed"):
        t.open_secondary()
    with pytest.raises(GalilConnectionError, match="closed"):
        t.open_handle()


def test_peer_closing_says_so(tcp_peer: TcpPeer) -> None:
    t = open_tcp(tcp_peer)
    try:
        assert tcp_peer.accepted.acquire(timeout=2)
        tcp_peer.drop_all()
        with pytest.raises(GalilConnectionError, match="closed the link"):
            read_until(t.read, b":")
    finally:
        t.close()


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
        ("tcp://127.0.0.1", {"port": True}, "1..65535"),
        ("tcp://127.0.0.1", {"message_port": 70000}, "message port"),
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


def test_a_large_write_after_a_polling_read_waits_for_a_slow_reader() -> None:
    # A zero-timeout read must not leave the socket unable to wait: an 8 MB write overflows
    # every socket buffer, so it has to block until the (slow) peer has read it all.
    size = 8_000_000
    got = bytearray()
    with socket.create_server(("127.0.0.1", 0)) as server:
        t = open_transport(f"tcp://127.0.0.1:{server.getsockname()[1]}", write_timeout=10.0)
        conn, _ = server.accept()

        def drain_slowly() -> None:
            while len(got) < size:
                chunk = conn.recv(4096)  # small reads: the writer outpaces it
                if not chunk:
                    return
                got.extend(chunk)

        reader = threading.Thread(target=drain_slowly)
        try:
            assert t.read(0.0) == b""  # a poll
            reader.start()
            t.write(b"x" * size)
            reader.join(timeout=30)
            assert len(got) == size
            assert t.read(0.0) == b""  # still a poll afterwards
            conn.sendall(b":")
            assert read_until(t.read, b":") == b":"
        finally:
            t.close()
            conn.close()
            reader.join(timeout=30)


def test_a_write_the_peer_never_takes_gives_up_after_the_write_timeout() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        t = open_transport(f"tcp://127.0.0.1:{server.getsockname()[1]}", write_timeout=0.05)
        conn, _ = server.accept()
        try:
            t.read(0.0)
            with pytest.raises(GalilConnectionError, match=r"did not accept data within 0\.05 s"):
                t.write(b"x" * 50_000_000)
        finally:
            t.close()
            conn.close()


def test_the_longest_timeouts_work_on_a_tcp_link() -> None:
    # (9.3e9 s crashed in settimeout, 1e308 in the 10 ms grid; the longest now reaches no
    # OS call longer than it takes, and a reply still comes at once)
    with SimTcpServer() as server:
        with galil.connect(server.url, timeout=1e9, connect_timeout=1e6, write_timeout=1e6) as c:
            assert c.command("MG 1", timeout=1e9).strip() == "1.0000"
            assert c.query_number("MG 2") == 2
        for bad in (9.3e9, 1e10, 1e308):
            with pytest.raises(galil.InvalidArgument, match=r"at most 1e\+09"):
                galil.connect(server.url, timeout=bad)
