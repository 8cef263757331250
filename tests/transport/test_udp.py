"""UDP handles: what ``EI`` sends its interrupt packets to on a real controller."""

from __future__ import annotations

import queue

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
