"""Fixtures for the axis layer: controllers on simulators, reached only through the public API."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import galil
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    """A DMC-4040 on an in-process simulator with a manual clock."""
    with simulated("DMC-4040") as controller:
        yield controller


@pytest.fixture
def x(dmc: galil.Controller) -> galil.Axis:
    """Axis A scaled to millimetres (2000 counts/mm), 20 mm/s, 200 mm/s² both ways."""
    axis = dmc.A.set_scale(counts_per=2000 / mm)
    axis.speed = 20 * mm / s
    axis.accel = axis.decel = 200 * mm / s**2
    return axis


@pytest.fixture
def tcp() -> Iterator[tuple[galil.Controller, SimController]]:
    """A DMC-4040 simulator served over TCP loopback (8x real time), and a controller on it."""
    sim = SimController("DMC-4040", RealTimeClock(speed=8.0))
    with (
        SimTcpServer(sim) as server,
        galil.connect(server.url, message_port=server.message_address[1], timeout=2.0) as dmc,
    ):
        assert dmc.transport.kind == "ethernet"
        yield dmc, sim
