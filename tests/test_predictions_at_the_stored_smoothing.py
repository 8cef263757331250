"""A prediction runs at the IT the controller holds (a multiple of 1/256), not at its reading.

IT 0.1 is held as 26/256 and ``MG _ITA`` reads 0.1016: a move, jog or speed schedule planned
at the reading strays from the controller's reference by a count.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import galil
from galil.notebook import compare
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated("DMC-4040") as controller:
        yield controller


@pytest.mark.parametrize("it", [0.1, 0.3])
def test_a_smoothed_move_is_predicted_exactly_at_an_it_off_the_1_256_grid(
    dmc: galil.Controller, it: float
) -> None:
    x = dmc.A
    x.speed, x.accel, x.decel = 166524, 318999, 1821446
    x.smoothing = it
    assert x.smoothing != it  # (the reading is the 4-decimal text of the held step)
    plan = x.plan_by(60797)
    cap = dmc.capture(["_RPA"], every=2, seconds=plan.duration + 0.05)
    move = x.move_by(60797)
    rec = cap.wait()
    assert move.profiles["A"].samples == plan.samples
    assert compare(move, rec)["A"].worst == 0


@pytest.mark.parametrize("it", [0.1, 0.3])
def test_a_smoothed_jog_and_its_stop_are_predicted_exactly_at_an_it_off_the_grid(
    dmc: galil.Controller, it: float
) -> None:
    x = dmc.A
    x.accel, x.decel = 318999, 1821446
    x.smoothing = it
    cap = dmc.capture(["_RPA"], every=2, seconds=0.8)
    jog = x.jog(100_000)
    dmc.sleep(0.3)
    x.stop()
    jog.wait()
    rec = cap.wait()
    assert compare(jog, rec)["A"].worst == 0


@pytest.mark.parametrize("it", [0.1, 0.3])
def test_a_smoothed_speed_schedule_is_predicted_exactly_at_an_it_off_the_grid(
    dmc: galil.Controller, it: float
) -> None:
    b = dmc.B
    b.smoothing = it
    cap = dmc.capture(["_RPB"], every=2, seconds=1.5)
    schedule = b.speed_schedule(15_000, [(5000, 10_000), (10_000, 5000)], speed=50_000)
    schedule.wait()
    rec = cap.wait()
    assert rec.samples[-1] >= schedule.begin["B"] + schedule.profiles["B"].samples  # type: ignore[operator]
    assert compare(schedule, rec)["B"].worst == 0


def test_the_least_smoothing_is_predicted_at_its_step(dmc: galil.Controller) -> None:
    x = dmc.A
    x.speed, x.accel, x.decel = 20000, 256000, 256000
    x.smoothing = 0.004  # held as 1/256, read as 0.0039
    assert x.smoothing == 0.0039
    plan = x.plan_by(3000)
    cap = dmc.capture(["_RPA"], every=2, seconds=plan.duration + 0.05)
    move = x.move_by(3000)
    rec = cap.wait()
    assert compare(move, rec)["A"].worst == 0
