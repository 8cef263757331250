"""UDP handles: what ``EI`` sends its interrupt packets to on a real controller."""

from __future__ import annotations

import math
import queue
import socket
import threading
import time

import pytest

import galil
from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.server import SimTcpServer
from galil.transport import DatagramSource
from galil.transport.tcp import TcpTransport, UdpTransport


def test_a_tcp_link_opens_a_udp_handle_that_the_controller_answers_on() -> None:
    with SimTcpServer() as server:
        host, port = server.address
        tcp = TcpTransport(host, port)
        assert isinstance(tcp, DatagramSource)
        udp = tcp.open_datagram_handle()
        try:
            udp.write(b"MG 6*7\r")
            got = b""
            while not got.endswith(b":"):
                chunk = udp.read(2.0)
                assert chunk, "no answer on the UDP handle"
                got += chunk
            assert got == b" 42.0000\r\n:"
            assert "UDP PORT" in server.controller.describe_handles()
            assert "open" in repr(udp)
        finally:
            udp.close()
            tcp.close()
        udp.close()  # idempotent
        with pytest.raises(GalilConnectionError, match="closed"):
            udp.write(b"MG 1\r")
    with pytest.raises(InvalidArgument):
        UdpTransport("127.0.0.1", 0)


def test_interrupts_come_on_a_udp_handle_and_a_tcp_handle_is_refused() -> None:
    with SimTcpServer() as server, galil.connect(server.url, timeout=2.0) as dmc:
        dmc.interrupts.enable()
        assert "UDP PORT" in dmc.command("TH")
        got: queue.Queue[galil.Interrupt] = queue.Queue()
        dmc.interrupts.subscribe(got.put)
        dmc.programs.download("#UI\nUI 7\nEN")
        dmc.programs.run("#UI")
        assert str(got.get(timeout=5)) == "UI 7"
        # As on a controller, EI names a UDP handle: this TCP handle (A) is refused.
        with pytest.raises(galil.CommandError) as info:
            dmc.command("EI 256,,0")
        assert info.value.code == 133


def test_a_udp_handle_takes_the_tcp_links_write_timeout_and_refuses_a_bad_one() -> None:
    with SimTcpServer() as server:
        host, port = server.address
        tcp = TcpTransport(host, port, write_timeout=0.25)
        udp = tcp.open_datagram_handle()
        try:
            assert isinstance(udp, UdpTransport)
            assert udp.write_timeout == 0.25
        finally:
            udp.close()
            tcp.close()

    def no_socket(*args: object, **kwargs: object) -> socket.socket:
        raise AssertionError("a socket was made before the options were checked")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(socket, "socket", no_socket)
        for bad in (0, -1, math.nan, math.inf, "x", True):
            with pytest.raises(InvalidArgument, match="write_timeout"):
                UdpTransport("127.0.0.1", 23, write_timeout=bad)  # type: ignore[arg-type]


def _full_datagram_pair() -> tuple[socket.socket, socket.socket]:
    """Two connected datagram sockets, the first with no room left for another datagram.

    A UDP send over loopback never waits on Linux (the loopback device frees the sender's
    buffer at once), so a datagram socket pair stands in for a UDP socket that is full.
    """
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    a.setblocking(False)
    try:
        while True:
            a.send(b"f" * 1000)
    except BlockingIOError:
        return a, b


def test_a_udp_write_with_no_room_gives_up_after_the_write_timeout() -> None:
    a, b = _full_datagram_pair()
    udp = UdpTransport("127.0.0.1", 23, sock=a, write_timeout=0.05)
    try:
        assert udp.read(0.0) == b""  # a poll: the socket's timeout is 0 now
        with pytest.raises(GalilConnectionError, match=r"did not accept data within 0\.05 s"):
            udp.write(b"MG 1\r")
    finally:
        udp.close()
        b.close()


def test_a_udp_write_after_a_polling_read_waits_for_room_as_the_peer_reads() -> None:
    a, b = _full_datagram_pair()
    b.settimeout(10.0)  # a failed test ends its reader too
    udp = UdpTransport("127.0.0.1", 23, sock=a, write_timeout=10.0)
    mine = [b"%04d" % i + b"x" * 996 for i in range(300)]  # about three socketfuls
    got: list[bytes] = []

    def drain() -> None:
        while len(got) == 0 or got[-1] != mine[-1]:
            try:
                got.append(b.recv(2000))
            except OSError:  # the writer failed: the test closed the socket
                return

    reader = threading.Thread(target=drain)
    try:
        assert udp.read(0.0) == b""
        reader.start()
        for datagram in mine:
            udp.write(datagram)
        reader.join(timeout=30)
        assert [g for g in got if not g.startswith(b"f")] == mine
    finally:
        udp.close()
        b.close()
        reader.join(timeout=30)


def test_a_udp_write_to_a_port_nothing_answers_raises_the_transports_error() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # free again once closed: nothing listens there
    udp = UdpTransport("127.0.0.1", port)
    try:
        udp.write(b"MG 1\r")  # over loopback the ICMP "port unreachable" is back at once
        with pytest.raises(GalilConnectionError, match=f"nothing answers UDP at 127.0.0.1:{port}"):
            udp.write(b"MG 1\r")
    finally:
        udp.close()


def test_closing_wakes_a_thread_blocked_reading() -> None:
    # (the interrupt reader waited out its read timeout, so close() with interrupts on took
    # a quarter of a second; here the read would wait 60 s)
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    udp = UdpTransport(*peer.getsockname())
    reading = threading.Event()
    ended: queue.Queue[object] = queue.Queue()

    def read() -> None:
        reading.set()
        try:
            ended.put(udp.read(60.0))
        except GalilConnectionError as exc:
            ended.put(exc)

    reader = threading.Thread(target=read)
    reader.start()
    try:
        assert reading.wait(10.0)
        time.sleep(0.05)  # (into recv: a read begun after close() fails at once anyway)
        udp.close()
        reader.join(timeout=10.0)
        assert not reader.is_alive()
        result = ended.get_nowait()
        assert result == b"" or isinstance(result, GalilConnectionError)
    finally:
        udp.close()
        reader.join()
        peer.close()
