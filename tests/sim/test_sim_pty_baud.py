"""The pty server paces its line like a serial port of the baud rate it is given."""

from __future__ import annotations

import time

import pytest

import galil
from galil.errors import InvalidArgument
from galil.sim.server import SimPtyServer, _Line

BAUD = 19_200  # 1,920 bytes a second


def test_commands_and_replies_still_pair_up_on_a_paced_line() -> None:
    with SimPtyServer(baud=BAUD) as srv, galil.connect(srv.path, timeout=2.0) as c:
        assert c.link.byte_rate == pytest.approx(11_520.0)  # pyserial's default 115200
        c.command("PR 1000")
        assert c.query_number("MG _PRA") == 1000


def test_a_paced_line_is_no_faster_than_its_baud_rate() -> None:
    # A lower bound on time only: a slow or busy machine can make it slower, never faster.
    payload = b"MG 1\r" * 80  # 400 bytes out, 80 replies of 10 bytes back
    with SimPtyServer(baud=BAUD) as srv, galil.connect(srv.path, timeout=2.0) as c:
        port = c.link.transport
        start = time.perf_counter()
        port.write(payload)
        got = b""
        while got.count(b":") < 80:
            got += port.read(1.0)
        spent = time.perf_counter() - start
    carried = max(len(payload), len(got))  # the two directions run side by side
    assert spent >= 0.9 * carried / (BAUD / 10)


def test_a_quiet_line_saves_up_no_time() -> None:
    line = _Line(1000.0)
    line._last -= 10.0  # ten quiet seconds
    line.refill()
    line.sending += b"x" * 100
    assert line.carry() == b""  # nothing carried yet: the bytes have only just been written
    line._last -= 0.05
    line.refill()
    assert len(line.carry()) == 50


def test_a_baud_rate_must_be_positive() -> None:
    with pytest.raises(InvalidArgument):
        SimPtyServer(baud=0)
