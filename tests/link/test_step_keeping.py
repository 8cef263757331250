"""The link never loses step: whatever is raised in the middle of an exchange (Ctrl-C, an
OverflowError, a failing wire hook), the next exchange resynchronises first, so no command
ever takes another's reply.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from client_fakes import Interrupt, Tripwire
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import galil
from galil.errors import GalilError, ProtocolError
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.proxy import FaultProxy
from galil.sim.server import SimTcpServer


@pytest.fixture
def wired() -> Iterator[tuple[galil.Controller, Tripwire]]:
    wire = Tripwire(SimLink(SimController("DMC-4040", ManualClock())))
    with galil.connect(wire, timeout=0.5) as dmc:  # type: ignore[arg-type]
        yield dmc, wire


def _pairs_all_right(dmc: galil.Controller, n: int = 100) -> None:
    for i in range(n):
        dmc.command(f"gv={i}")
        assert dmc.query_number("MG gv") == i


EXCHANGES = [
    lambda dmc: dmc.command("MG 11"),
    lambda dmc: dmc.query_operands(["_TPA", "_TPB", "_RPA"]),
    lambda dmc: dmc.command_line(["gv=5", "MG gv", "MG TIME"]),
    lambda dmc: dmc.command("XX"),  # refused: the TC1 question is part of the exchange
]


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    which=st.integers(0, len(EXCHANGES) - 1),
    at=st.integers(0, 5),
    after=st.booleans(),
    error=st.sampled_from([Interrupt, KeyboardInterrupt, OverflowError, RuntimeError]),
)
def test_an_interruption_anywhere_leaves_every_later_reply_right(
    wired: tuple[galil.Controller, Tripwire],
    which: int,
    at: int,
    after: bool,
    error: type[BaseException],
) -> None:
    dmc, wire = wired
    wire.calls, wire.at, wire.after, wire.error = 0, at, after, error
    with contextlib.suppress(error, GalilError):
        EXCHANGES[which](dmc)
    wire.at = -1
    _pairs_all_right(dmc, 20)


def test_ctrl_c_between_write_and_read_cannot_shift_replies(
    wired: tuple[galil.Controller, Tripwire],
) -> None:
    dmc, wire = wired
    dmc.command("v1=1;v2=2", allow_compound=True)
    wire.calls, wire.at, wire.after = 0, 1, False  # the read of "MG v1"
    with pytest.raises(Interrupt):
        dmc.query_number("MG v1")
    wire.at = -1
    assert dmc.query_number("MG v2") == 2  # not v1's late reply
    assert any("out of step" in r for r in dmc.recent)
    _pairs_all_right(dmc)


def test_a_failing_wire_hook_cannot_shift_replies(
    wired: tuple[galil.Controller, Tripwire],
) -> None:
    dmc, _ = wired
    calls = []

    def hook(direction: str, data: bytes) -> None:
        calls.append(direction)
        if direction == "in" and len(calls) == 2:
            raise OverflowError("a user's hook failed")

    remove = dmc.wire_log.add(hook)
    with pytest.raises(OverflowError):
        dmc.query_number("MG 1")
    remove()
    _pairs_all_right(dmc)


def test_an_interruption_before_the_write_cannot_shift_replies(
    wired: tuple[galil.Controller, Tripwire],
) -> None:
    dmc, _ = wired

    def hook(direction: str, data: bytes) -> None:
        if direction == "out" and b"MG 7" in data:
            raise KeyboardInterrupt  # queued in the session, never written

    remove = dmc.wire_log.add(hook)
    with pytest.raises(KeyboardInterrupt):
        dmc.query_number("MG 7")
    remove()
    assert dmc.query_number("MG 1") == 1  # not a reply matched to the unwritten MG 7
    dmc.command("SPA=1000")  # an acknowledgement goes to its own command too
    _pairs_all_right(dmc)


def test_an_infinite_timeout_is_refused_before_the_wire(
    wired: tuple[galil.Controller, Tripwire],
) -> None:
    dmc, wire = wired
    before = len(wire.log)
    for bad in (float("inf"), float("nan"), -1, 0, True, "1"):
        with pytest.raises(galil.InvalidArgument):
            dmc.command("MG 1", timeout=bad)  # type: ignore[arg-type]
    with pytest.raises(galil.InvalidArgument):
        dmc.sleep(float("inf"))
    assert len(wire.log) == before
    with pytest.raises(galil.InvalidArgument):
        galil.connect("sim://DMC-4040", timeout=float("inf"))


@dataclass
class StrayQuestion:
    """A fault hook: a stray '?' before the reply of every command line that holds ``mark``."""

    mark: bytes
    armed: bool = False

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if self.armed:
            self.armed = False
            return [(0.0, b"?"), (0.0, data)]
        return [(0.0, data)]


def test_a_stray_question_mark_is_never_reported_as_a_rejection() -> None:
    sim = SimController("DMC-4040", ManualClock())
    stray = StrayQuestion(b"BG")
    link = SimLink(sim, faults=stray)
    with galil.connect(link, timeout=0.5) as dmc:
        dmc.command("SPA=10000;PRA=5000", allow_compound=True)
        stray.armed = True
        with pytest.raises(ProtocolError, match="may have executed") as info:
            dmc.command("BGA")
        assert not isinstance(info.value, galil.CommandError)
        assert dmc.query_number("MG _BGA") == 1  # it did run
        _pairs_all_right(dmc, 10)


def test_a_stray_question_mark_before_a_late_reply_cannot_shift_later_replies() -> None:
    # Over TCP: the '?' arrives on its own, the query's own reply 5 ms later, and the reply to
    # the TC1 that asks why 50 ms after that. TC1 must not take the query's reply for its own,
    # or every later reply would be one behind.
    plan = {"step": 0}

    def faults(data: bytes) -> list[tuple[float, bytes]]:
        step = plan["step"]
        if step == 1:
            plan["step"] = 2
            return [(0.0, b"?"), (0.005, data)]
        if step == 2:
            plan["step"] = 0
            return [(0.05, data)]
        return [(0.0, data)]

    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address, faults=faults) as proxy,
        galil.connect(proxy.url, timeout=0.5) as dmc,
    ):
        dmc.command("gv=12345")
        plan["step"] = 1
        with pytest.raises(ProtocolError, match="may have executed"):
            dmc.query_number("MG gv")
        _pairs_all_right(dmc, 50)


def test_a_400_digit_reply_is_a_protocol_error_not_an_overflow() -> None:
    huge = {"armed": 0}

    def replace(data: bytes) -> list[tuple[float, bytes]]:
        if huge["armed"]:
            huge["armed"] -= 1
            return [(0.0, b" " + b"9" * 400 + b"\r\n:")]
        return [(0.0, data)]

    sim = SimController("DMC-4040", ManualClock())
    with galil.connect(SimLink(sim, faults=replace), timeout=0.5) as dmc:
        huge["armed"] = 1
        with pytest.raises(ProtocolError, match="range"):
            dmc.query_number("MG 1")
        huge["armed"] = 1
        assert dmc.query_operands(["_TPA"]) == [0]  # not the default's shape: asked again
        huge["armed"] = 2  # and the reply to the formatted read is as bad
        with pytest.raises(ProtocolError):
            dmc.query_operands(["_TPA"])
        _pairs_all_right(dmc, 5)
