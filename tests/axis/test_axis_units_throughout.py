"""User units end to end on scaled axes: plans read in mm, refusals say mm (and counts), paths
for several axes and in Quantities, and the motion a path implies checked before sending."""

from __future__ import annotations

import numpy as np
import pytest
from axis_helpers import in_unit, scale_in_mm

import galil
from galil.contour import sample_path
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        scale_in_mm(controller)
        yield controller


def test_a_plan_on_a_scaled_axis_reads_in_its_units(dmc: galil.Controller) -> None:
    plan = dmc.A.plan_to(12.5 * mm)
    assert plan.peak_speed == 40_000  # the arrays and figures stay counts...
    q = plan.q  # ...and the same motion reads in mm
    assert in_unit(q.peak_speed, "mm/s") == pytest.approx(20)
    assert in_unit(q.end, "mm") == pytest.approx(12.5)
    assert in_unit(q.distance, "mm") == pytest.approx(12.5)
    assert q.duration.to("s").magnitude == pytest.approx(plan.duration)
    assert in_unit(q.position[-1], "mm") == pytest.approx(12.5)
    one_count = 1024 / 2000  # a sample's velocity may be one count over SP (mm/s)
    assert in_unit(np.max(np.abs(q.velocity)), "mm/s") <= 20 + one_count
    handle = dmc.A.move_to(12.5 * mm)
    assert in_unit(handle.profile.q.end, "mm") == pytest.approx(12.5)


def test_refusals_carry_the_users_units_and_the_counts(dmc: galil.Controller) -> None:
    x = dmc.A
    x.soft_limits = (-5 * mm, 10 * mm)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        x.plan_to(12.5 * mm)
    err = info.value
    assert err.limit == 20_000  # counts, as the controller sees them
    assert in_unit(err.limit_in_units, "mm") == pytest.approx(10)
    assert in_unit(err.value_in_units, "mm") > 10
    with pytest.raises(galil.LimitError) as info:
        x.speed = 20_000 * mm / s
    assert in_unit(info.value.value_in_units, "mm/s") == pytest.approx(20_000)


def test_a_contour_step_beyond_the_models_acceleration_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.contour("A", np.array([0.0, 5.0]) * mm, dt=1)
    err = info.value
    assert err.name == "acceleration"
    assert err.sample == 2
    assert err.segment == 1
    assert err.value > dmc.model.ac_max
    assert "sample 2" in str(err)
    assert in_unit(err.value_in_units, "mm/s**2") == pytest.approx(err.value / 2000)


def test_a_contour_within_the_users_own_limits_or_refused(dmc: galil.Controller) -> None:
    # 5 mm in 0.5 s along 1 - cos: from rest to rest, peak 20 mm/s and 126 mm/s².
    travel, period = 5.0, 0.5
    path = sample_path(
        lambda t: travel * mm * (t / period - np.sin(2 * np.pi * t / period) / (2 * np.pi)),
        duration=period,
        dt=3,
    )
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.contour("A", path, dt=3, accel_limit=50 * mm / s**2)
    assert info.value.name == "acceleration"
    assert in_unit(info.value.limit_in_units, "mm/s**2") == pytest.approx(50)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.contour("A", path, dt=3, speed_limit={"A": 15 * mm / s})
    assert info.value.name == "speed"
    result = dmc.contour("A", path, dt=3, accel_limit=200 * mm / s**2, speed_limit=25 * mm / s)
    assert in_unit(result.profiles["A"].q.end, "mm") == pytest.approx(travel, abs=0.001)


def test_sample_path_takes_several_axes_and_keeps_quantities(dmc: galil.Controller) -> None:
    circle = sample_path(
        lambda t: np.stack([np.cos(2 * np.pi * t) - 1, np.sin(2 * np.pi * t)], axis=1) * 2 * mm,
        duration=1.0,
        dt=4,
    )
    assert circle.shape == (64, 2)
    assert circle.units == mm  # never stripped
    start = dmc.query_operands(["_RPA", "_RPB"])
    dmc.contour("AB", circle, dt=4)
    end = dmc.query_operands(["_RPA", "_RPB"])
    assert end == start  # a full circle comes back to where it began
    with pytest.raises(galil.InvalidArgument, match="shape"):
        sample_path(lambda t: np.zeros((t.size, 2, 2)), duration=1.0, dt=4)
    with pytest.raises(galil.InvalidArgument):
        sample_path(lambda t: ["x"] * t.size, duration=1.0, dt=4)


def test_an_increment_that_would_jump_beyond_the_speed_range_while_jogging_is_refused(
    dmc: galil.Controller,
) -> None:
    jog = dmc.B.jog(5 * mm / s)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError, match="one sample"):
        dmc.B.increment(20 * mm)  # 40,000 counts in one sample: 41 M counts/s
    dmc.B.increment(0.5 * mm)
    jog.stop()
    jog.wait()
