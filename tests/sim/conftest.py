"""Fixtures for the simulator tests: one controller, or one front of it (sim_fronts.py)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sim_fronts import FRONTS, Front

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController


@pytest.fixture(params=sorted(FRONTS))
def front(request: pytest.FixtureRequest) -> Iterator[Front]:
    f = FRONTS[request.param]("DMC-4040")
    try:
        yield f
    finally:
        f.close()


@pytest.fixture
def sim() -> SimController:
    return SimController("DMC-4040", ManualClock())
