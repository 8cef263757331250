"""``sim://MODEL?baud=...``: the in-process simulator behind a serial line of that rate, in
simulated time (decision 0064): it says its byte rate and carries bytes no faster."""

from __future__ import annotations

from typing import Any

import pytest

import galil
from galil.errors import InvalidArgument
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultPlan
from galil.sim.link import SimLink, SimSerialLink, open_transport
from galil.transport import ByteRate

RATE = 960.0  # 9600 baud: 960 bytes a second
BYTE = 1 / RATE


def _line(**options: Any) -> SimSerialLink:
    link = open_transport("sim://DMC-4040?baud=9600", **options)
    assert isinstance(link, SimSerialLink)
    return link


def test_a_line_says_its_byte_rate_as_a_serial_port_does() -> None:
    link = _line()
    assert isinstance(link, ByteRate)
    assert link.byte_rate == RATE
    assert not isinstance(open_transport("sim://DMC-4040"), ByteRate)
    with galil.connect("sim://DMC-4040?baud=19200") as c:
        assert c.link.byte_rate == 1920.0
        assert c.query_number("MG 6*7") == 42


def test_a_reply_arrives_when_the_line_has_carried_the_command_and_the_reply() -> None:
    link = _line()
    link.write(b"MG 1\r")  # 5 bytes out, 10 back
    assert link.read(1.0) == b" 1.0000\r\n:"
    assert link.controller_time() == pytest.approx(15 * BYTE, abs=1e-9)


def test_a_read_gets_the_bytes_that_have_arrived_by_its_timeout() -> None:
    link = _line()
    link.write(b"MG 1\r")
    assert link.read(10 * BYTE) == b" 1.00"  # the command took 5 byte times, the reply 5 more
    assert link.controller_time() == pytest.approx(10 * BYTE, abs=1e-9)
    assert link.read(0.0) == b""  # a read without time finds nothing new
    assert link.read(1.0) == b"00\r\n:"
    assert link.controller_time() == pytest.approx(15 * BYTE, abs=1e-9)


def test_both_directions_carry_at_once_and_each_one_byte_after_another() -> None:
    link = _line()
    link.write(b"MG 1\rMG 2\r")  # the second command arrives while the first reply flows
    got = b""
    while got.count(b":") < 2:
        got += link.read(1.0)
    assert got == b" 1.0000\r\n: 2.0000\r\n:"
    # 5 bytes in, then the two replies back to back (the second was asked for in time)
    assert link.controller_time() == pytest.approx(25 * BYTE, abs=1e-9)


def test_a_sleep_lets_the_line_carry_bytes() -> None:
    link = _line()
    link.write(b"MG 1\r")
    link.sleep(1.0)
    assert link.controller_time() == pytest.approx(1.0)
    assert link.read(0.0) == b" 1.0000\r\n:"
    without = _line(auto_advance=False)
    without.write(b"MG 1\r")
    assert without.read(1.0) == b""  # only the host's sleeps let time pass
    without.let_time_pass(15 * BYTE)
    assert without.read(0.0) == b" 1.0000\r\n:"


def test_a_held_reply_and_a_programs_message_come_over_the_line_when_said() -> None:
    link = _line()
    link.write(b'DL\r#W\rWT 500\rMG "done"\rEN\r\\\r')
    assert link.read(1.0) == b"::"
    link.write(b"XQ #W\r")
    started = link.controller_time()
    assert link.read(1.0) == b":"
    assert link.read(0.1) == b""  # the program waits 0.5 s
    assert link.read(5.0) == b"done\r\n"
    # XQ took 6 byte times to arrive, the message 6 more to come back
    assert link.controller_time() - started == pytest.approx(0.5 + 12 * BYTE, abs=0.002)


def test_a_fault_delay_holds_a_piece_back_in_simulated_time() -> None:
    link = _line(faults=FaultPlan(delay=0.5))
    link.write(b"MG 1\r")
    assert link.read(0.4) == b""
    assert link.read(1.0) == b" 1.0000\r\n:"
    assert link.controller_time() == pytest.approx(0.5 + 15 * BYTE, abs=1e-9)


def test_a_reopened_line_has_the_same_rate_and_controller() -> None:
    link = _line()
    again = link.reopen()
    assert isinstance(again, SimSerialLink)
    assert again.byte_rate == RATE
    assert again.controller is link.controller
    assert "9600 baud" in repr(again)


@pytest.mark.parametrize("baud", [0, -9600, "fast", "nan", "inf", float("nan"), True, None, [1]])
def test_a_baud_rate_is_a_positive_number(baud: object) -> None:
    if baud is None:
        with pytest.raises(InvalidArgument, match="baud"):
            SimSerialLink(SimController("DMC-4040", ManualClock()), baud=baud)  # type: ignore[arg-type]
        return
    with pytest.raises(InvalidArgument, match="baud"):
        open_transport("sim://DMC-4040", baud=baud)


def test_a_line_paces_the_manual_clock_only_and_carries_messages_inline() -> None:
    with pytest.raises(InvalidArgument, match="SimPtyServer"):
        open_transport("sim://DMC-4040?baud=9600&clock=real")
    with pytest.raises(InvalidArgument, match="inline"):
        open_transport("sim://DMC-4040?baud=9600&messages=separate")
    assert type(open_transport("sim://DMC-4040?messages=separate")) is SimLink
