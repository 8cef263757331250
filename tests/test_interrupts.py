"""``controller.interrupts`` over TCP: the handle, the mask, reconnects, failing callbacks."""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Iterator

import pytest

import galil
from galil.errors import GalilTimeoutError
from galil.link import read_reply
from galil.protocol.interrupts import packet
from galil.sim.server import SimTcpServer
from galil.testing import transcript
from galil.transport.tcp import UdpTransport


@pytest.fixture
def served() -> Iterator[tuple[SimTcpServer, galil.Controller]]:
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url, timeout=2.0) as dmc:
        yield server, dmc


def test_enable_names_the_handle_it_opened_and_disable_turns_it_off(
    served: tuple[SimTcpServer, galil.Controller],
) -> None:
    server, dmc = served
    with transcript(dmc) as sent:
        dmc.interrupts.enable(axes="AB", all_done=True)
    assert sent.lines == ["EI 259,,2"]  # handles A (commands) and B (messages) were taken
    assert dmc.interrupts.enabled
    assert "IHC" in server.controller.describe_handles()
    dmc.move({"A": 300, "B": 200}).wait(timeout=5)
    got = {str(dmc.interrupts.get(timeout=5)) for _ in range(3)}
    assert got == {"axis A done", "axis B done", "all done ($D8)"}
    with transcript(dmc) as sent:
        dmc.interrupts.disable()
    assert sent.lines == ["EI 0;IHC=>-1"]  # the UDP handle is freed on the controller too
    assert not dmc.interrupts.enabled
    assert "IHC AVAILABLE" in server.controller.describe_handles()


def test_interrupt_handles_do_not_run_out_over_many_connections() -> None:
    # A UDP handle's close reaches no controller: freed with IHm=>-1, or all eight are taken
    # after a few connections (enable() then fails with "no handle for interrupts").
    with SimTcpServer(model="DMC-4040") as server:
        for _ in range(8):  # each takes two TCP handles and a UDP one
            with galil.connect(server.url, timeout=2.0) as dmc:
                dmc.interrupts.enable(axes="A")
                dmc.interrupts.disable()
                dmc.interrupts.enable(axes="B")
        # (the TCP handles are freed when the server sees their sockets close, a moment later;
        # the UDP ones by the IH line, before close() returns)
        assert "UDP" not in server.controller.describe_handles()


def test_enable_with_every_handle_taken_says_so_and_leaves_the_link_working() -> None:
    # (it said "no answer to b'MG _WH' on a secondary handle": the controller ignores the
    # packets of a UDP peer when no handle is AVAILABLE)
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url, timeout=0.3) as dmc:
        others = [socket.create_connection(server.address) for _ in range(7)]
        try:
            deadline = time.monotonic() + 5.0  # (until the server has accepted all seven)
            while "AVAILABLE" in server.controller.describe_handles():
                assert time.monotonic() < deadline
                time.sleep(0.002)
            with pytest.raises(GalilTimeoutError, match="no free Ethernet handle"):
                dmc.interrupts.enable(axes="A")
            assert not dmc.interrupts.enabled
            assert dmc.query_operands(["_TPA"]) == [0]
        finally:
            for sock in others:
                sock.close()


def test_interrupts_come_back_after_a_reconnect() -> None:
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as dmc:
        dmc.interrupts.enable(axes="A")
        dmc.reconnect()
        assert dmc.interrupts.enabled
        assert dmc.interrupts.mask == 1
        dmc.programs.download("#U\nUI 4\nEN")
        dmc.programs.run("#U", thread=1)
        assert str(dmc.interrupts.get(timeout=5)) == "UI 4"


def _udp_handles(server: SimTcpServer) -> list[str]:
    """The controller's UDP handles, as TH lists them."""
    return [line for line in server.controller.describe_handles().splitlines() if "UDP" in line]


def test_a_reconnect_frees_the_old_interrupt_handle_on_the_controller() -> None:
    # (the old UDP handle stayed: every reconnect took one more, and after six the eight
    # handles were used up and the reconnect failed with "no handle for interrupts")
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as dmc:
        dmc.interrupts.enable(axes="A")
        (old,) = _udp_handles(server)
        letter = old[2]
        with transcript(dmc) as sent:
            dmc.reconnect()
        assert "TH" in sent.lines
        assert f"IH{letter}=>-1" in sent.lines
        for _ in range(6):  # (without freeing, the eight handles run out here)
            dmc.reconnect()
        assert len(_udp_handles(server)) == 1
        dmc.programs.download("#U\nUI 5\nEN")
        dmc.programs.run("#U", thread=1)
        assert str(dmc.interrupts.get(timeout=5)) == "UI 5"


def test_a_reconnect_leaves_the_old_handle_letter_alone_once_another_client_has_it() -> None:
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as dmc:
        dmc.interrupts.enable(axes="A")
        (old,) = _udp_handles(server)
        letter = old[2]
        dmc.command(f"IH{letter}=>-1")  # freed behind the library's back (as a reset would)
        host, port = server.address
        other = UdpTransport(host, port)  # another client: its first datagram takes the letter
        try:
            assert round(float(read_reply(other, b"MG _WH\r", 2.0))) == "ABCDEFGH".index(letter)
            (theirs,) = _udp_handles(server)
            assert theirs.startswith(f"IH{letter} UDP")
            with transcript(dmc) as sent:
                dmc.reconnect()
            assert "TH" in sent.lines
            assert f"IH{letter}=>-1" not in sent.lines
            assert theirs in _udp_handles(server)  # still open: the other client's
            assert read_reply(other, b"MG 6*7\r", 2.0).strip() == "42.0000"
        finally:
            other.close()


def test_a_failing_callback_is_logged_and_the_others_still_hear(
    served: tuple[SimTcpServer, galil.Controller], caplog: pytest.LogCaptureFixture
) -> None:
    _, dmc = served
    heard: list[galil.Interrupt] = []

    def broken(_: galil.Interrupt) -> None:
        raise RuntimeError("callback bug")

    dmc.interrupts.subscribe(broken)
    unsubscribe = dmc.interrupts.subscribe(heard.append)
    dmc.interrupts.enable()
    with caplog.at_level(logging.ERROR, logger="galil.interrupts"):
        dmc.programs.download("#U\nUI 1\nUI 2\nEN")
        dmc.programs.run("#U", thread=1)
        assert [dmc.interrupts.get(timeout=5).number for _ in range(2)] == [1, 2]
    assert [i.number for i in heard] == [1, 2]
    assert "callback bug" in caplog.text
    unsubscribe()
    with pytest.raises(galil.InvalidArgument):
        dmc.interrupts.subscribe("not callable")  # type: ignore[arg-type]


class _BadPacketBeside:
    """A fault hook for the simulator's fronts: the interrupt packet of ``UI 1`` gets a
    malformed packet after it in the same datagram, and that of ``UI 3`` is cut short (its
    datagram holds ``01 D0`` alone). Other output passes unchanged."""

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if data == packet([0xF1]):
            return [(0.0, data + b"\x01\xd0\x07")]
        if data == packet([0xF3]):
            return [(0.0, b"\x01\xd0")]
        return [(0.0, data)]


def test_a_malformed_interrupt_datagram_loses_no_good_interrupt_beside_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # UI 1 was lost with the bad packet after it in its datagram, and UI 4 was lost with the
    # cut-short datagram before it (its bytes were taken as that packet's continuation).
    with (
        SimTcpServer(model="DMC-4040", faults=_BadPacketBeside()) as server,
        galil.connect(server.url, timeout=2.0) as dmc,
        caplog.at_level(logging.WARNING, logger="galil.interrupts"),
    ):
        dmc.interrupts.enable()
        for number in (1, 3, 4):  # one datagram each
            dmc.programs.download(f"#U\nUI {number}\nEN")
            dmc.programs.run("#U", thread=1)
            if number != 3:
                assert dmc.interrupts.get(timeout=5).number == number
    dropped = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(dropped) == 2, dropped
    assert "length 7" in dropped[0]
    assert "cut short" in dropped[1]
