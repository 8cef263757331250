"""Mistakes users make with units, overrides, soft limits and axis names: named clearly and refused
before anything is sent.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

import galil
from galil.predict import HomeSwitch
from galil.testing import nothing_sent, transcript
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.mark.parametrize(
    ("name", "value"),
    [("speed", -5 * mm / s), ("accel", -200 * mm / s**2), ("decel", -200 * mm / s**2)],
)
def test_a_negative_rate_is_refused_not_flipped(
    dmc: galil.Controller, x: galil.Axis, name: str, value: object
) -> None:
    before = getattr(x, name)
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="must not be negative"):
        setattr(x, name, value)
    assert getattr(x, name) == before


def test_a_negative_speed_without_a_scale_is_refused_too(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="direction comes from"):
        dmc.B.speed = -5000


def test_a_negative_speed_override_is_refused_before_the_move(
    dmc: galil.Controller, x: galil.Axis
) -> None:
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument):
        x.move_to(5 * mm, speed=-10 * mm / s)
    assert not x.moving


def test_a_reversed_axis_still_takes_positive_rates_and_signed_jogs(
    dmc: galil.Controller,
) -> None:
    y = dmc.B.set_scale(counts_per=2000 / mm, sign=-1)
    y.speed = 10 * mm / s
    y.accel = 100 * mm / s**2
    assert y.speed.to("mm/s").magnitude == pytest.approx(10, rel=1e-3)
    with transcript(dmc) as sent:
        y.jog(-5 * mm / s)
    assert any("JGB=10000" in line for line in sent.lines)  # user -5 mm/s = motor +10000
    y.stop()


def test_an_override_with_the_wrong_unit_is_named_as_the_user_spelled_it(
    x: galil.Axis,
) -> None:
    with pytest.raises(galil.InvalidArgument, match=r"^speed: 5 mm has the wrong dimension"):
        x.plan_to(10 * mm, speed=5 * mm)


@pytest.mark.parametrize("where", ["move_to", "move_by", "plan_to", "plan_by"])
def test_a_misspelled_override_names_the_public_call(
    dmc: galil.Controller, x: galil.Axis, where: str
) -> None:
    with nothing_sent(dmc), pytest.raises(TypeError, match=rf"^{where}\(\) .* 'sped'.*speed="):
        getattr(x, where)(1 * mm, sped=5 * mm / s)


@pytest.mark.parametrize("internal", [{"dry_run": True}, {"command": "IP"}])
def test_internal_keywords_are_not_overrides(
    dmc: galil.Controller, x: galil.Axis, internal: dict[str, object]
) -> None:
    with nothing_sent(dmc), pytest.raises(TypeError, match="move_to"):
        x.move_to(1 * mm, **internal)
    with nothing_sent(dmc), pytest.raises(TypeError, match=r"^move\(\)"):
        dmc.move({"A": 1 * mm}, **internal)
    with nothing_sent(dmc), pytest.raises(TypeError, match=r"^plan\(\)"):
        dmc.plan({"A": 1 * mm}, speed=1 * mm / s, acel=1)


def test_a_soft_limit_refusal_also_speaks_millimetres(x: galil.Axis) -> None:
    x.soft_limits = (-5 * mm, 20 * mm)
    with pytest.raises(galil.LimitError) as info:
        x.plan_to(25 * mm)
    message = str(info.value)
    assert "beyond FL 40000" in message  # the counts stay, for the controller's view
    assert "limit 20 mm" in message
    assert "end 25 mm" in message
    reached = info.value.value
    assert reached is not None
    assert f"reaches {reached / 2000:.6g} mm" in message


def test_a_soft_limit_refusal_on_a_reversed_axis_maps_counts_back(
    dmc: galil.Controller,
) -> None:
    y = dmc.B.set_scale(counts_per=1000 / mm, sign=-1)
    y.speed = 10 * mm / s
    y.accel = y.decel = 100 * mm / s**2
    y.soft_limits = (-3 * mm, 4 * mm)
    with pytest.raises(galil.LimitError, match=r"limit -3 mm, end -6 mm"):
        y.plan_to(-6 * mm)


def test_an_axis_without_a_scale_keeps_the_counts_message(dmc: galil.Controller) -> None:
    dmc.C.speed = 10_000
    dmc.C.soft_limits = (None, 1000)
    with pytest.raises(galil.LimitError) as info:
        dmc.C.plan_to(2000)
    assert "user units" not in str(info.value)


def test_a_speed_out_of_range_states_the_range_in_user_units(
    dmc: galil.Controller, x: galil.Axis
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.LimitError) as info:
        x.speed = 50 * ureg.m / s
    top = dmc.model.sp_max / 2000
    assert f"limit {top:g} mm / s" in str(info.value)
    assert "50000 mm / s" in str(info.value)


def test_soft_limits_the_wrong_way_round_read_plainly(x: galil.Axis) -> None:
    with pytest.raises(galil.InvalidArgument) as info:
        x.soft_limits = (30 * mm, 0 * mm)
    assert "Quantity(" not in str(info.value)
    assert "30 mm" in str(info.value)


@pytest.mark.parametrize("name", ["E", "a"])
def test_a_wrong_axis_attribute_lists_the_axes(dmc: galil.Controller, name: str) -> None:
    with pytest.raises(AttributeError, match="DMC-4040 has axes A, B, C, D"):
        getattr(dmc, name)
    assert not hasattr(dmc, name)


@pytest.mark.parametrize(
    ("field", "bad"),
    [
        ("edge", "abc"),
        ("edge", 1.5),
        ("edge", True),
        ("index_period", math.nan),
        ("index_period", "4000"),
        ("index_offset", None),
        ("side", True),
    ],
)
def test_a_home_switch_with_a_field_that_is_no_count_is_refused_naming_it(
    field: str, bad: object
) -> None:
    with pytest.raises(galil.InvalidArgument, match=f"^{field} "):
        HomeSwitch(**{"edge": 500, field: bad})  # type: ignore[arg-type]


def test_a_home_switch_in_numpy_integers_predicts_as_in_ints(dmc: galil.Controller) -> None:
    switch = HomeSwitch(np.int64(500), np.int64(-1), np.int32(4000), np.int64(0))
    assert switch == HomeSwitch(500, -1, 4000, 0)
    assert type(switch.edge) is int
    dmc.A.home_speed = 2000
    handle = dmc.A.home(switch=switch)
    handle.wait()
    assert dmc.A.reference_position == 0


@pytest.mark.parametrize("value", [Fraction(1, 3), 1, 1.99, 0.5 * ureg.count / s])
def test_a_home_speed_under_one_step_is_refused_not_sent_as_hv_0(
    dmc: galil.Controller, value: object
) -> None:
    dmc.A.home_speed = 2000
    with nothing_sent(dmc), pytest.raises(galil.LimitError, match=r"^HV .* less than one step"):
        dmc.A.home_speed = value
    assert dmc.A.home_speed == 2000
    dmc.A.home_speed = Fraction(7, 2)  # (a Fraction as any number: HV 2)
    assert dmc.A.home_speed == 2


def test_a_home_speed_under_one_step_is_told_in_the_axis_unit_too(x: galil.Axis) -> None:
    said = r"the smallest is 0\.001 mm / s, you gave 0\.0002 mm / s"
    with pytest.raises(galil.LimitError, match=said) as info:
        x.home_speed = 0.0002 * mm / s
    assert (info.value.name, info.value.limit) == ("HV", 2)


def test_a_home_speed_above_the_maximum_names_hv_not_sp(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(galil.LimitError, match=r"^HV 1e\+09 counts/s") as info:
        dmc.A.home_speed = 1e9
    assert info.value.name == "HV"
