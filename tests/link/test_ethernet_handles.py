"""Ethernet handles on the simulator's TCP server: ``CF``, ``WH``, ``TH``, as on the controller.

Every connection to the command port is a handle (A to H). ``CF I`` sent on a handle makes it
the destination of unsolicited output; the client's default (no ``message_port=``) opens a
second handle and claims the messages with it.
"""

from __future__ import annotations

import socket
import warnings
from collections.abc import Iterator

import pytest
from concurrency import hammer, handles_closed

import galil.controller
from galil.errors import GalilConnectionError, GalilTimeoutError
from galil.protocol.commands import Command
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.server import SimTcpServer
from galil.transport.tcp import TcpTransport

WAIT = 5.0


def _until(sock: socket.socket, terminators: int) -> bytes:
    got = b""
    while got.count(b":") + got.count(b"?") < terminators:
        chunk = sock.recv(4096)
        assert chunk, got
        got += chunk
    return got


def _ask(sock: socket.socket, text: bytes) -> bytes:
    sock.sendall(text + b"\r")
    return _until(sock, 1)


def _quiet(sock: socket.socket, settle: float = 0.1) -> bytes:
    sock.settimeout(settle)
    try:
        return sock.recv(4096)
    except TimeoutError:
        return b""
    finally:
        sock.settimeout(WAIT)


@pytest.fixture
def server() -> Iterator[SimTcpServer]:
    with SimTcpServer(SimController("DMC-4040", ManualClock())) as srv:
        yield srv


def _handle(srv: SimTcpServer) -> socket.socket:
    return socket.create_connection(srv.address, timeout=WAIT)


def test_client_default_claims_messages_with_cf_on_a_second_handle() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim, message_port=None) as srv:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no fall-back to CW1 marking
            c = galil.controller.connect(srv.url, timeout=2.0)
        with c:
            second = c.transport.secondary
            assert isinstance(second, TcpTransport)
            assert not second.messages_only
            assert any("CF I" in line for line in c.recent)
            assert c.query_number("MG _CW") == 2  # nothing marked: messages have a handle
            handles = c.command("TH")
            assert handles.count("TCP PORT") == 2
            sim.emit_message("from a program")
            assert c.messages.get(timeout=WAIT) == "from a program"
            sim.emit_message("not in a reply")
            assert c.query_number("MG 3") == 3
            assert c.messages.get(timeout=WAIT) == "not in a reply"


def test_cf_wins_over_the_message_port(server: SimTcpServer) -> None:
    port = socket.create_connection(server.message_address, timeout=WAIT)
    with galil.controller.connect(server.url, timeout=2.0) as c:
        server.controller.emit_message("to the CF handle")
        assert c.messages.get(timeout=WAIT) == "to the CF handle"
        assert _quiet(port) == b""
    # The claiming handle closed: output falls back to the message port (once the server
    # has seen the connections close).
    handles_closed(server.controller)
    server.controller.emit_message("back to the port")
    port.settimeout(WAIT)
    got = b""
    while not got.endswith(b"\n"):
        got += port.recv(4096)
    assert got == b"back to the port\r\n"
    port.close()


def test_cf_letters_route_output_to_that_handle(server: SimTcpServer) -> None:
    a, b = _handle(server), _handle(server)
    assert _ask(a, b"WH") == b"IHA\r\n:"
    assert _ask(b, b"WH") == b"IHB\r\n:"
    assert _ask(b, b"MG _WH") == b" 1.0000\r\n:"
    assert _ask(a, b"CF B") == b":"
    server.controller.emit_message("for B")
    assert _until_line(b) == b"for B\r\n"
    assert _quiet(a) == b""
    assert _ask(b, b"CF I") == b":"  # still B
    assert _ask(a, b"CF S") == b":"  # the main port: here the message port
    msg = socket.create_connection(server.message_address, timeout=WAIT)
    server.controller.emit_message("for the port")
    assert _until_line(msg) == b"for the port\r\n"
    assert _quiet(b) == b""
    for s in (a, b, msg):
        s.close()


def _until_line(sock: socket.socket) -> bytes:
    got = b""
    while not got.endswith(b"\n"):
        chunk = sock.recv(4096)
        assert chunk, got
        got += chunk
    return got


def test_cf_refusals_leave_the_destination_alone(server: SimTcpServer) -> None:
    a = _handle(server)
    assert _ask(a, b"CF I") == b":"
    assert _ask(a, b"CF D") == b"?"  # no handle D
    assert _ask(a, b"TC1") == b" 126 Closed Ethernet handle\r\n:"
    assert _ask(a, b"CF Q") == b"?"
    assert _ask(a, b"TC1").startswith(b" 6 ")
    assert _ask(a, b"CF") == b"?"
    server.controller.emit_message("still A")
    assert _until_line(a) == b"still A\r\n"
    a.close()


def test_handle_letters_are_reused_and_eight_is_the_limit(server: SimTcpServer) -> None:
    socks = [_handle(server) for _ in range(8)]
    assert [_ask(s, b"WH") for s in socks] == [f"IH{c}\r\n:".encode() for c in "ABCDEFGH"]
    ninth = _handle(server)
    ninth.settimeout(WAIT)
    assert ninth.recv(16) == b""  # refused: the server closes it
    ninth.close()
    socks[2].close()
    handles_closed(server.controller, 7)
    again = _handle(server)
    assert _ask(again, b"WH") == b"IHC\r\n:"  # the freed letter
    th = _ask(again, b"TH")
    assert th.count(b"TCP PORT") == 8
    for s in [*socks[:2], *socks[3:], again]:
        s.close()


def test_serial_like_ports_are_rs232() -> None:
    sim = SimController("DMC-4040", ManualClock())
    link = SimLink(sim)
    with galil.controller.connect(link) as c:
        assert c.command("WH") == "RS232"
        assert c.query_number("MG _WH") == -1
        # CF I on the main port keeps output there (inline, marked with CW1). (Sent as a
        # prepared command on the link: raw, CF is refused: decision 0031.)
        c.link.exchange(Command("CF I"))
        q = c.messages
        sim.emit_message("inline")
        assert q.get(timeout=WAIT) == "inline"


def test_server_without_message_port_has_no_message_address() -> None:
    with SimTcpServer(message_port=None) as srv, pytest.raises(GalilConnectionError):
        _ = srv.message_address


def test_open_handle_is_an_independent_connection(server: SimTcpServer) -> None:
    host, port = server.address
    t = TcpTransport(host, port)
    h = t.open_handle()
    other = t.open_handle()
    try:
        assert other is not h  # each call: a new handle
        other.write(b"WH\r")
        got = b""
        while not got.endswith(b":"):
            got += other.read(WAIT)
        assert got == b"IHC\r\n:"
        h.write(b"WH\r")
        got = b""
        while not got.endswith(b":"):
            got += h.read(WAIT)
        assert got == b"IHB\r\n:"
        assert t.secondary is None
    finally:
        other.close()
        h.close()
        t.close()
    with pytest.raises(GalilConnectionError):
        t.open_handle()


def test_threads_timeouts_and_messages_over_the_cf_handle() -> None:
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim, message_port=None) as srv,
        galil.controller.connect(srv.url, timeout=2.0) as c,
    ):

        def tick(k: int, i: int) -> None:
            if k == 0 and i % 10 == 0:
                sim.emit_message(f"tick {i}")

        assert hammer(c, threads=8, per_thread=40, before=tick) == []
        assert [c.messages.get(timeout=WAIT) for _ in range(4)] == [
            f"tick {i}" for i in (0, 10, 20, 30)
        ]
        with pytest.raises(GalilTimeoutError):
            c.command("BV", timeout=0.05)  # the controller holds the ':' while it burns
        assert c.query_number("MG 77", timeout=3.0) == 77
