"""The in-process link, fault injection, the TCP handles and the ``galil sim`` command."""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from collections.abc import Callable

import pytest
from engine_expect import move, references
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultPlan
from galil.sim.link import SimLink, open_transport
from galil.sim.server import SimTcpServer


def test_url_opens_a_link_with_its_controller() -> None:
    t = open_transport("sim://DMC-4040?lag=0.01")
    assert t.kind == "sim"
    assert t.secondary is None
    assert t.controller.spec.name == "DMC-4040"
    assert t.controller.motion("A").lag == 0.01
    t.write(b"\x12\x16\r")
    assert t.read(0.1) == b"DMC4040 Rev 1.2f-sim\r\n:"
    t.close()
    with pytest.raises(GalilConnectionError):
        t.read(0.1)


def test_url_as_split_result_and_bad_options() -> None:
    t = open_transport(urllib.parse.urlsplit("sim://DMC-1806"))
    assert t.controller.identity.startswith("DMC1806 ")
    with pytest.raises(InvalidArgument):
        open_transport("sim://DMC-4040?bogus=1")
    with pytest.raises(InvalidArgument):
        open_transport("sim://NOT-A-MODEL")


def test_reading_lets_simulated_time_pass_until_the_controller_says_something() -> None:
    t = open_transport("sim://DMC-4040")
    t.write(b'DL\r#W\rAM A\rMG "done"\rEN\r\\\r')  # AM is a program command (0044)
    assert t.read(0.01) == b"::"
    t.write(b"PR 5000;SP 10000;BG A;XQ #W\r")
    assert t.read(0.01) == b"::::"
    assert t.read(0.1) == b""  # 0.1 s of simulated time: still moving
    assert t.read(5.0) == b"done\r\n"
    sim = t.controller
    # time stopped at the message (the sample the profile ended), not at the timeout
    assert sim.sample == len(references(move(5000, 10000)))


def test_separate_message_handle() -> None:
    t = open_transport("sim://DMC-4040", messages="separate")
    assert t.secondary is not None
    t.controller.emit_message("hi")
    assert t.read(0.0) == b""
    assert t.secondary.read(0.0) == b"hi\r\n"


def test_faults_split_and_corrupt_reproducibly() -> None:
    sim = SimController("DMC-4040", ManualClock())
    link = SimLink(sim, faults=FaultPlan(split=True, seed=1))
    link.write(b"\x12\x16\r")
    got = b""
    while b":" not in got:
        got += link.read(0.0)
    assert got == b"DMC4040 Rev 1.2f-sim\r\n:"
    plan = FaultPlan(corrupt=1.0, seed=3)
    pieces = plan(b"hello")
    assert len(pieces) == 1
    assert pieces[0][1] != b"hello"
    assert len(pieces[0][1]) == 5
    assert FaultPlan(drop=1.0)(b"abc") == []


def test_fault_delay_and_interleave() -> None:
    sim = SimController("DMC-4040", ManualClock())
    link = SimLink(sim, faults=FaultPlan(delay=0.5, interleave=1.0, message="X"))
    link.write(b"TPA\r")
    assert link.read(0.2) == b""  # the delay is consumed by waiting
    got = link.read(1.0)
    assert got == bytes(b | 0x80 for b in b"X\r\n") + b" 0\r\n:"
    with pytest.raises(InvalidArgument):
        FaultPlan(drop=2.0)


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=1, max_size=200), st.integers(0, 1000))
def test_split_keeps_every_byte_in_order(data: bytes, seed: int) -> None:
    pieces = FaultPlan(split=True, seed=seed)(data)
    assert b"".join(p for _, p in pieces) == data


def test_tcp_handles_are_listed_and_independent() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as srv:
        a = socket.create_connection(srv.address, timeout=5)
        b = socket.create_connection(srv.address, timeout=5)
        a.sendall(b"PR 10;BG A;BV\r")  # the controller holds BV's ':' while it burns
        b.sendall(b"TH\r")
        th = b""
        while not th.endswith(b":"):
            th += b.recv(4096)
        assert th.count(b"TCP PORT") == 2
        assert b"IHC AVAILABLE" in th
        got = b""
        while got.count(b":") < 2:
            got += a.recv(4096)
        srv.advance(1.0)
        while got.count(b":") < 3:
            got += a.recv(4096)
        assert got == b":::"
        a.close()
        b.close()


def test_real_time_server_moves_by_itself() -> None:
    with SimTcpServer(SimController("DMC-4040", RealTimeClock(speed=50.0))) as srv:
        s = socket.create_connection(srv.address, timeout=10)

        def ask(line: bytes) -> bytes:
            s.sendall(line + b"\r")
            got = b""
            while got.count(b":") < line.count(b";") + 1:
                chunk = s.recv(4096)
                assert chunk
                got += chunk
            return got

        assert ask(b"PR 1000;BG A;MG _BGA") == b":: 1.0000\r\n:"
        # Nobody advances the clock: the move ends by itself (polled, as a host waits).
        deadline = time.monotonic() + 10
        while ask(b"MG _BGA") != b" 0.0000\r\n:":
            assert time.monotonic() < deadline
        assert ask(b"RPA") == b" 1000\r\n:"
        s.close()


def test_cli_prints_address_and_stops_on_ctrl_c(
    spawn: Callable[..., subprocess.Popen[str]],
) -> None:
    proc = spawn(
        [sys.executable, "-c", "from galil.sim.server import main; main()", "--tcp", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("DMC-4040".replace("-", "") + " Rev")
        port = int(line.rsplit(":", 1)[1])
        s = socket.create_connection(("127.0.0.1", port), timeout=10)
        s.sendall(b"MG 7\r")
        reply = b""
        while not reply.endswith(b":"):
            reply += s.recv(100)
        assert reply == b" 7.0000\r\n:"
        s.close()
    finally:
        os.kill(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=10) == 0


@pytest.mark.parametrize("where", ["--tcp", "--pty"])
def test_cli_stops_cleanly_when_signalled_as_it_announces_itself(
    where: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Whoever starts `galil sim` waits for the address line and may stop it at once: SIGTERM
    # and Ctrl-C must already stop it cleanly (exit 0, server closed) when that line appears.
    import galil.sim.server as server_module

    announced: list[str] = []

    def signal_on_announce(*args: object, **kwargs: object) -> None:
        announced.append(" ".join(map(str, args)))
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler), f"SIGTERM would kill the server outright ({handler!r})"
        if len(announced) == 1:
            signal.raise_signal(signal.SIGTERM)  # runs the handler here, in the main thread

    previous = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(server_module, "print", signal_on_announce, raising=False)
    try:
        extra = ["127.0.0.1:0"] if where == "--tcp" else []
        assert server_module.main([where, *extra]) == 0
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert len(announced) == 1
    assert "DMC4040" in announced[0]


def test_the_tcp_server_survives_a_simulator_error(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    sim = SimController("DMC-4040", ManualClock())
    real_feed = sim.feed
    broken = [True]

    def feed(data: bytes, port: int = 0) -> bytes:
        if broken.pop() if broken else False:
            raise RuntimeError("a simulator bug")
        return real_feed(data, port)

    monkeypatch.setattr(sim, "feed", feed)
    with caplog.at_level(logging.ERROR, logger="galil.sim"), SimTcpServer(sim) as srv:
        s = socket.create_connection(srv.address, timeout=5)

        def ask(line: bytes) -> bytes:
            s.sendall(line + b"\r")
            got = b""
            while not got.endswith((b":", b"?")):
                chunk = s.recv(4096)
                assert chunk
                got += chunk
            return got

        assert ask(b"TPA") == b"?"  # answered, not silence
        assert ask(b"MG 65536*65536") == b"?"
        assert ask(b"TPA") == b" 0\r\n:"
        s.close()
    assert [r.name for r in caplog.records] == ["galil.sim"]
