"""Motion that runs for hours: stopping, aborting or planning it costs no more memory than
motion of a minute, and its prediction stays exact (the simulator runs the same hours)."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable, Iterator

import pytest

import galil
from galil.controller import Controller
from galil.motion import MoveHandle

HOURS = 2.0


@pytest.fixture
def dmc() -> Iterator[Controller]:
    c = galil.connect("sim://DMC-4040")
    yield c
    c.close()


def _peak_bytes(action: Callable[[], object]) -> float:
    tracemalloc.start()
    try:
        action()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("end", ["axis stop", "handle stop", "abort", "speed change then stop"])
def test_a_jog_ended_after_hours_is_predicted_exactly_in_bounded_memory(
    dmc: Controller, end: str
) -> None:
    jog = dmc.A.jog(20_000)
    dmc.sleep(HOURS * 3600)

    def finish(handle: MoveHandle = jog) -> None:
        if end == "axis stop":
            dmc.A.stop()
        elif end == "handle stop":
            handle.stop()
        elif end == "abort":
            dmc.abort()
        else:
            dmc.A.jog_speed = 5_000
            dmc.sleep(1.0)
            dmc.A.stop()
        handle.wait()

    peak = _peak_bytes(finish)
    result = jog.result
    assert result is not None
    assert result.deviation == {"A": 0}
    assert result.final["A"] > 20_000 * HOURS * 3600 * 0.99
    # The jog's samples would take about 300 MB (7.4 million of them, 40 bytes each).
    assert peak < 60e6, f"{peak / 1e6:.0f} MB"


def test_a_move_of_a_day_ending_at_the_soft_limit_is_planned_in_bounded_memory(
    dmc: Controller,
) -> None:
    dmc.A.soft_limits = (None, 2_000_000_000)
    plan = dmc.A.plan_to(2_000_000_000)
    assert plan.duration > 22 * 3600
    peak = _peak_bytes(lambda: dmc.A.plan_to(2_000_000_000))
    assert peak < 20e6, f"{peak / 1e6:.0f} MB"  # (its samples: about 2.6 GB)
    with pytest.raises(galil.LimitError) as caught:
        dmc.A.plan_to(2_000_000_001)
    assert caught.value.name == "FL"
    assert caught.value.value == 2_000_000_001
