"""The key axis scenarios again, over real transports: TCP loopback and a pty serial port.

The simulator runs on a real-time clock sped up 8x, so waits are real waits; every check is
still exact because the handle stamps its commands with the controller's TIME. The clock
leaves out the time this process is paused (``RunningClock``): a loaded machine that stops the
host and the simulator together must not run the controller on meanwhile.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

import numpy as np
import pytest
from axis_helpers import RunningClock, assert_follows

import galil
from galil.errors import InvalidArgument, LimitError
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimPtyServer, SimTcpServer
from galil.testing import nothing_sent
from galil.units import ureg

SPEED = 8.0  # simulated seconds per real second


@pytest.fixture(params=["tcp", "pty"])
def link(request: pytest.FixtureRequest) -> Iterator[tuple[galil.Controller, SimController]]:
    sim = SimController("DMC-4040", RunningClock(SPEED))
    if request.param == "tcp":
        with (
            SimTcpServer(sim) as server,
            galil.connect(server.url, message_port=server.message_address[1], timeout=2.0) as dmc,
        ):
            assert dmc.transport.kind == "ethernet"
            yield dmc, sim
    else:
        with SimPtyServer(sim) as server, galil.connect(server.path, timeout=2.0) as dmc:
            assert dmc.transport.kind == "serial"
            yield dmc, sim


def _sample(sim: SimController, pattern: str, since: int) -> int:
    rx = re.compile(pattern)
    return next(k for k, text in sim.command_log if k >= since and rx.fullmatch(text))


def test_moves_over_the_link(link: tuple[galil.Controller, SimController]) -> None:
    dmc, sim = link
    mm, s = ureg.mm, ureg.s
    x = dmc.A.set_scale(counts_per=2000 / mm)
    x.speed, x.accel, x.decel = 40 * mm / s, 400 * mm / s**2, 400 * mm / s**2
    t0 = sim.start_trace("AB")
    h = dmc.move({"A": 6 * mm, "B": -9000})
    r = h.wait()
    traces = sim.stop_trace("AB")
    bg = _sample(sim, r"BG AB", t0)
    assert h.begin == {"A": bg, "B": bg}
    assert r.final == {"A": 12_000, "B": -9000}
    assert r.worst == 0
    for a in "AB":
        assert_follows(traces[a], t0, h.profiles[a], bg)
    assert x.reference_position == 6 * mm


def test_jog_and_stop_over_the_link(link: tuple[galil.Controller, SimController]) -> None:
    dmc, sim = link
    t0 = sim.start_trace("C")
    j = dmc.C.jog(40_000)
    dmc.sleep(0.1)
    dmc.C.jog(-20_000)
    dmc.sleep(0.1)
    dmc.stop("C")
    r = j.wait()
    assert r.stop_codes == {"C": 4}
    assert r.worst == 0
    assert r.predicted == r.final
    assert_follows(sim.stop_trace("C")["C"], t0, j.profile, j.begin["C"])


def test_contour_and_schedule_over_the_link(
    link: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = link
    # More than twice the buffer. DT 3 (8 ms a segment): the buffer holds 4 s of controller
    # time, 0.5 s of real time; at DT 1 a stall of 128 ms ran it dry, once (before streams
    # were pre-loaded: the buffer now starts full). A stall of about 0.5 s did at DT 3 on a
    # plain RealTimeClock, once in about 40 loaded suite runs. The RunningClock leaves out the
    # time the simulator's thread is not run (on a loaded machine, the whole process is
    # paused): only the host's own lateness while the simulator runs can run the buffer dry.
    path = np.cumsum(np.full(1200, 21.7))
    t0 = sim.start_trace("D")
    result = dmc.contour("D", path, dt=3)
    trace = sim.stop_trace("D")["D"]
    assert dmc.D.reference_position == round(path[-1])
    started = _sample(sim, r"DT 3", t0)  # pre-loaded under DT -1, started by its DT
    assert result.begin == started
    assert_follows(trace, t0, result.profiles["D"], started)
    t1 = sim.start_trace("B")
    h = dmc.B.speed_schedule(12_000, [(6000, 8000)], speed=30_000)
    assert h.wait().worst == 0
    assert_follows(sim.stop_trace("B")["B"], t1, h.profile, h.begin["B"])


def test_guard_and_refusals_over_the_link(link: tuple[galil.Controller, SimController]) -> None:
    dmc, _sim = link

    def scan() -> None:
        with dmc.motion():
            dmc.A.move_by(200_000)
            raise RuntimeError("scan failed")

    with pytest.raises(RuntimeError, match="scan failed"):
        scan()
    assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]
    x = dmc.B.set_scale(counts_per=1000 / ureg.mm)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="wrong dimension"):
        x.move_to(3 * ureg.s)
    with nothing_sent(dmc), pytest.raises(LimitError):
        x.speed = 1e9 * ureg.mm / ureg.s
    with nothing_sent(dmc), pytest.raises(LimitError, match="CD"):
        dmc.contour("B", [0, 50_000], dt=1)


def test_slow_serial_link_refuses_a_contour_in_advance() -> None:
    sim = SimController("DMC-4040", RealTimeClock(speed=SPEED))
    with SimPtyServer(sim) as server, galil.connect(server.path, baudrate=9600) as dmc:
        assert dmc.transport.port.baudrate == 9600  # what the feasibility check reads
        path = np.cumsum(np.full(600, 555.0))
        with nothing_sent(dmc), pytest.raises(LimitError) as info:
            dmc.contour("A", path, dt=1)
        assert info.value.name == "link byte rate"
        assert "bytes/s" in str(info.value)
        dmc.contour("A", path[:12], dt=7)  # slow segments fit the same link
        assert dmc.A.reference_position == round(path[11])
