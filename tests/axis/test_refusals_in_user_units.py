"""A refusal of values given in an axis's units states the offending value and the limit in
that unit too (after the counts), with the axis named: one test per family of refusal, on
axes in mm and in degrees with a negative sign."""

from __future__ import annotations

import numpy as np
import pytest
from axis_helpers import in_unit, scale_in_mm

import galil
from galil import Line
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm, s, deg = ureg.mm, ureg.s, ureg.degree
#: The 32-bit position range's end in mm (2000 counts/mm) and in degrees (4096 counts/°).
TOP_MM, TOP_DEG = 1.07374e06, 524288


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        scale_in_mm(controller)
        c = controller.C.set_scale(counts_per=4096 / deg, sign=-1)
        c.speed = 20 * deg / s
        c.accel = c.decel = 200 * deg / s**2
        yield controller


def test_a_path_speed_or_acceleration_beyond_the_model_states_it_in_the_paths_unit(
    dmc: galil.Controller,
) -> None:
    square = [Line(10 * mm, 0), Line(0, 10 * mm)]
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.plan_vector("AB", square, speed=30_000 * mm / s)
    assert info.value.name == "VS"
    assert "(in user units: 30000 mm / s, limit 11000 mm / s)" in str(info.value)
    with pytest.raises(galil.LimitError) as info:
        dmc.plan_vector("AB", square, speed=20 * mm / s, accel=1e6 * mm / s**2)
    assert info.value.name == "VA"
    assert in_unit(info.value.limit_in_units, "mm/s**2") == pytest.approx(536870.4)
    with pytest.raises(galil.LimitError) as info:  # the path's length (TC 31)
        dmc.plan_vector("AB", [Line(2e6 * mm, 0)], speed=20 * mm / s)
    assert "(in user units: 2e+06 mm, limit 1e+06 mm)" in str(info.value)


def test_a_position_beyond_the_32_bit_range_states_it_in_the_axis_unit(
    dmc: galil.Controller,
) -> None:
    x, c = dmc.A, dmc.C
    with nothing_sent(dmc, allow_queries=True):
        with pytest.raises(galil.LimitError, match=r"PA .* on A") as info:
            x.plan_to(2e6 * mm)
        assert f"(in user units: reaches 2e+06 mm, limit {TOP_MM:g} mm)" in str(info.value)
        with pytest.raises(galil.LimitError, match=r"PR .* on A") as info:
            dmc.plan({"A": 2e6 * mm}, relative=True)
        assert f"(in user units: 2e+06 mm, limit {TOP_MM:g} mm)" in str(info.value)
        with pytest.raises(galil.LimitError, match=r"DP .* on C") as info:
            c.define_position(1e6 * deg)  # sign -1: -4096e6 counts, beyond INT32_MIN
        assert f"(in user units: reaches 1e+06 deg, limit {TOP_DEG} deg)" in str(info.value)
        with pytest.raises(galil.LimitError, match=r"FL .* on C") as info:
            c.soft_limits = (-1e6 * deg, 5 * deg)  # the low end is C's FL
        assert in_unit(info.value.value_in_units, "deg") == pytest.approx(-1e6)


def test_a_contour_point_or_step_beyond_range_states_it_in_the_axis_unit(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.contour("A", np.array([0.0, 2e6]) * mm, dt=1)
    assert "path point 1 on A" in str(info.value)
    assert f"(in user units: 2e+06 mm, limit {TOP_MM:g} mm)" in str(info.value)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        dmc.contour("B", np.array([0.0, 40.0]) * mm, dt=8)
    assert info.value.name == "CD"
    assert "CD 80000 on B" in str(info.value)
    assert "(in user units: 40 mm, limit 16 mm)" in str(info.value)


def test_a_speed_schedule_change_too_early_names_the_axis_and_its_unit(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.ScheduleError) as info:
        dmc.C.speed_schedule(20 * deg, [(0.01 * deg, 10 * deg / s)])
    err = info.value
    assert err.axis == "C"
    assert str(err).startswith("axis C: change 0 at 40.96 counts")
    assert "(in user units: the smallest is 1 deg, you gave 0.01 deg)" in str(err)


def test_a_jog_from_beyond_a_soft_limit_states_it_in_the_axis_unit(
    dmc: galil.Controller,
) -> None:
    x = dmc.A
    x.soft_limits = (-5 * mm, 5 * mm)
    dmc.command("DPA=20000")  # (the axis found at 10 mm, beyond FL 5 mm)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
        x.jog(5 * mm / s)
    assert "(in user units: reaches 10 mm, limit 5 mm)" in str(info.value)


def test_a_geared_followers_refusal_states_it_in_the_followers_unit(
    dmc: galil.Controller,
) -> None:
    gearing = dmc.C.gear_to(dmc.A, 100)
    with pytest.raises(galil.LimitError, match="axis C is geared to A") as info:
        dmc.A.plan_by(100 * mm, speed=5000 * mm / s, accel=1e5 * mm / s**2)
    assert "limit 5371.09 deg / s)" in str(info.value)
    gearing.off()
    dmc.C.soft_limits = (-1 * deg, 1 * deg)
    gearing = dmc.C.gear_to(dmc.A, 1)
    with pytest.raises(galil.LimitError, match="axis C is geared to A") as info:
        dmc.A.plan_by(10 * mm)  # C: +20000 counts, -4.88 deg (sign -1), beyond -1 deg
    assert "limit -1 deg, end -4.88281 deg)" in str(info.value)
    gearing.off()


def test_units_on_an_axis_without_a_scale_are_refused_in_one_wording(
    dmc: galil.Controller,
) -> None:
    d = dmc.D
    for refuse in (
        lambda: d.move_to(1 * mm),
        lambda: setattr(d, "speed", 1 * mm / s),
        lambda: dmc.contour("D", np.array([0.0, 1.0]) * mm, dt=1),
    ):
        with pytest.raises(galil.InvalidArgument, match="has units but axis D has no scale"):
            refuse()


def test_galil_plan_with_a_scale_refuses_in_its_unit(capsys: pytest.CaptureFixture[str]) -> None:
    from galil import cli

    assert cli.main(["plan", "10deg", "--scale", "4096/deg", "--speed", "1e4deg/s"]) == 2
    err = capsys.readouterr().err
    assert "(in user units: 10000 deg / s, limit 5371.09 deg / s)" in err


def _set(axis: galil.Axis, name: str, value: object) -> None:
    setattr(axis, name, value)


@pytest.mark.parametrize(
    ("name", "call"),
    [
        ("SP", lambda x, v: _set(x, "speed", v)),
        ("JG", lambda x, v: _set(x, "jog_speed", v)),
        ("JG", lambda x, v: _set(x, "jog_speed", -v)),
        ("HV", lambda x, v: _set(x, "home_speed", v)),
        ("JG", lambda x, v: x.jog(v)),
        ("SP", lambda x, v: x.move_by(1 * mm, speed=v)),
        ("SP", lambda x, v: x.speed_schedule(10 * mm, [(5 * mm, v)])),
    ],
)
def test_a_speed_under_one_step_is_refused_with_the_smallest_speed_in_the_axis_unit(
    dmc: galil.Controller, name: str, call: object
) -> None:
    x = dmc.A  # 2000 counts/mm: one step (2 counts/s at TM 1000) is 0.001 mm/s
    x.jog_speed = x.home_speed = 5 * mm / s
    before = (x.speed, x.jog_speed, x.home_speed)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument) as info:
        call(x, 0.0004 * mm / s)  # type: ignore[operator]
    assert isinstance(info.value, galil.LimitError)
    assert (info.value.name, info.value.limit, info.value.axis) == (name, 2, "A")
    assert f"it would be {name} 0" in str(info.value)
    assert "the smallest speed above 0 (2 counts/s at TM 1000)" in str(info.value)
    # (before: "the smallest speed above 0 is one step (in user units: 0.0004 mm / s, limit
    # 0.001 mm / s)", which read as if the speed given were the smallest)
    assert str(info.value).endswith(
        "(in user units: the smallest is 0.001 mm / s, you gave 0.0004 mm / s) [DMC-4040]"
    )
    assert in_unit(info.value.limit_in_units, "mm/s") == pytest.approx(0.001)
    assert (x.speed, x.jog_speed, x.home_speed) == before
    assert not x.moving


def test_a_speed_of_0_or_of_one_step_is_still_set(dmc: galil.Controller) -> None:
    x = dmc.A
    x.speed = 0.001 * mm / s
    assert x.speed == 0.001 * mm / s
    x.speed = 0 * mm / s
    x.jog_speed = 0 * mm / s
    assert (x.speed, x.jog_speed) == (0 * mm / s, 0 * mm / s)
