"""Item 1 and 2 of issue 6: the axes mapping, typed operands, units and scales."""

from __future__ import annotations

import math

import pint
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import galil
from galil import Arc, Line
from galil.errors import InvalidArgument
from galil.predict import quantise_value
from galil.testing import nothing_sent, sim_of, simulated
from galil.units import Scale, ureg

OTHER = pint.UnitRegistry()  # a user's own registry, not galil's


def test_axes_mapping_and_attributes(dmc: galil.Controller) -> None:
    assert list(dmc.axes) == ["A", "B", "C", "D"]
    assert dmc.A is dmc.axes["A"] is dmc.axes["A"]
    assert dmc.D.letter == "D"
    with pytest.raises(AttributeError):
        _ = dmc.E  # a DMC-4040 has four axes
    with pytest.raises(AttributeError):
        _ = dmc.X  # and no X Y Z W names
    assert "A" in repr(dmc.A)
    assert "counts" in repr(dmc.A)


@pytest.mark.parametrize("model", ["DMC-1500", "DMC-1700", "DMC-18x2"])
def test_xyzw_aliases(model: str) -> None:
    with simulated(model) as dmc:
        assert (dmc.X, dmc.Y, dmc.Z, dmc.W) == (dmc.A, dmc.B, dmc.C, dmc.D)
        h = dmc.move({"X": 1000, "Y": -500})
        assert h.axes == "AB"
        r = h.wait()
        assert r.final == {"A": 1000, "B": -500}
        assert dmc.Y.reference_position == -500


def test_typed_properties_in_counts(dmc: galil.Controller) -> None:
    a = dmc.A
    a.speed = 12_345
    a.accel = 100_000
    a.decel = 200_000
    a.smoothing = 0.5
    a.jog_speed = -7000
    # The controller's stored (quantised) values, as the predictor quantises them.
    assert a.speed == quantise_value("SP", 12_345, dmc.model) != 12_345
    assert a.accel == quantise_value("AC", 100_000, dmc.model) != 100_000
    assert a.decel == quantise_value("DC", 200_000, dmc.model)
    assert a.smoothing == 0.5
    assert a.jog_speed == -7000
    a.soft_limits = (-1000, 50_000)
    assert a.soft_limits == (-1000, 50_000)
    a.soft_limits = (None, None)
    assert a.soft_limits == (None, None)  # off reads as off (BL/FL at the 32-bit ends)
    assert dmc.query_operands(["_BLA", "_FLA"]) == [-2_147_483_648, 2_147_483_647]
    assert a.position == 0
    assert a.reference_position == 0
    assert a.velocity == 0
    assert a.error == 0
    assert a.moving is False
    assert a.motor_on is True
    assert a.stop_code[0] in (0, 1)
    assert isinstance(a.stop_code[1], str)
    h = a.move_by(30_000)
    dmc.sleep(0.2)
    assert a.moving is True
    assert a.stop_code == (0, "Motors are running, independent mode")
    assert a.velocity > 0
    assert a.reference_position > 0
    h.stop()
    h.wait()
    assert a.stop_code == (4, "Decelerating or stopped by Stop Command (ST)")
    dmc.motor_off("A")
    assert a.motor_on is False
    dmc.servo_here("A")
    assert a.motor_on is True


def test_properties_are_quantities_with_a_scale(dmc: galil.Controller) -> None:
    mm, s = ureg.mm, ureg.s
    x = dmc.A.set_scale(counts_per=2000 / mm)
    assert x.scale is not None
    assert "mm" in repr(x)
    x.speed = 20 * mm / s
    x.accel = 200 * mm / s**2
    x.decel = OTHER.Quantity(0.2, "m/s**2")  # another registry, another unit
    x.jog_speed = -5 * mm / s
    assert x.speed == 20 * mm / s
    assert x.accel == quantise_value("AC", 400_000, dmc.model) / 2000 * mm / s**2
    assert x.accel.units == mm / s**2
    assert dmc.query_number("MG _SPA") == 40_000
    assert dmc.query_number("MG _JGA") == -10_000
    assert x.jog_speed == -5 * mm / s
    x.soft_limits = (-5 * mm, OTHER.Quantity(1, "cm"))
    assert x.soft_limits == (-5 * mm, 10 * mm)
    assert dmc.query_operands(["_BLA", "_FLA"]) == [-10_000, 20_000]
    x.move_to(2.5 * mm).wait()
    assert x.reference_position == 2.5 * mm
    assert x.position.units == mm
    assert x.error.units == mm
    assert x.velocity.units == mm / s
    x.set_scale(None)
    assert x.reference_position == 5000


@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize(
    "limits", [(None, None), (None, 10.0), (-10.0, None), (-10.0, 10.0)], ids=str
)
def test_a_soft_limit_that_is_off_reads_back_as_none(
    dmc: galil.Controller, sign: int, limits: tuple[float | None, float | None]
) -> None:
    """``None`` removes a side (BL -2147483648, FL 2147483647) and reads back as ``None``,
    whatever the scale's offset and sign (a sign of -1 swaps BL and FL), not as the
    sentinel's number in the axis's unit."""
    mm = ureg.mm
    x = dmc.A.set_scale(counts_per=2000 / mm, offset=5 * mm, sign=sign)
    given = tuple(None if v is None else v * mm for v in limits)
    x.soft_limits = given
    assert x.soft_limits == given
    dmc.A.set_scale(None)
    bl, fl = dmc.A.soft_limits  # in counts too
    assert (bl is None) == (limits[0 if sign > 0 else 1] is None)
    assert (fl is None) == (limits[1 if sign > 0 else 0] is None)


def test_rotary_axis_offset_and_sign(dmc: galil.Controller) -> None:
    deg = ureg.degree
    r = dmc.B.set_scale(counts_per=4096 / (90 * deg), offset=10 * deg, sign=-1)
    r.speed = 180 * deg / ureg.s
    assert dmc.query_number("MG _SPB") == 8192
    r.move_to(OTHER.Quantity(100, "degree")).wait()  # 90° past the offset, motor negative
    assert dmc.query_number("MG _RPB") == -4096
    assert r.reference_position == 100 * deg
    r.move_by(OTHER.Quantity(-0.25, "turn")).wait()
    assert dmc.query_number("MG _RPB") == 0
    assert r.reference_position == 10 * deg
    r.soft_limits = (0 * deg, 190 * deg)  # the sign swaps BL and FL on the controller
    assert dmc.query_operands(["_BLB", "_FLB"]) == [-8192, 455]
    low, high = r.soft_limits  # whole counts: within one count of what was asked
    assert abs(low - 0 * deg) <= 90 / 4096 * deg
    assert abs(high - 190 * deg) <= 90 / 4096 * deg
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="not an angle"):
        r.move_to(5 * ureg.dimensionless)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="not an angle"):
        r.speed = 3 * ureg.Hz


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (lambda x: x.move_to(5 * ureg.s), "wrong dimension"),
        (lambda x: x.move_by(OTHER.Quantity(5, "degree")), "wrong dimension"),
        (lambda x: x.move_to(5), "needs units"),
        (lambda x: setattr(x, "speed", 5 * ureg.mm), "wrong dimension"),
        (lambda x: setattr(x, "accel", 5 * ureg.mm / ureg.s), "wrong dimension"),
        (lambda x: x.jog(OTHER.Quantity(3, "mm/s**2")), "wrong dimension"),
        (lambda x: x.increment(2 * ureg.kg), "wrong dimension"),
        (lambda x: setattr(x, "soft_limits", (0 * ureg.s, 1 * ureg.mm)), "wrong dimension"),
        (lambda x: x.move_to(math.nan * ureg.mm), "finite"),
    ],
)
def test_wrong_units_refused_before_sending(dmc: galil.Controller, action, match: str) -> None:
    x = dmc.A.set_scale(counts_per=2000 / ureg.mm)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match=match):
        action(x)


def test_units_on_an_axis_without_scale(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="no scale"):
        dmc.B.move_to(3 * ureg.mm)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="no scale"):
        dmc.B.speed = 3 * ureg.mm / ureg.s
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="number"):
        dmc.B.move_to("12")
    dmc.B.move_to(OTHER.Quantity(1500, "count")).wait()  # counts are fine
    assert dmc.B.reference_position == 1500


def test_an_axis_without_a_scale_takes_counts_per_second_as_it_takes_counts(
    dmc: galil.Controller,
) -> None:
    b = dmc.B
    b.speed = 20_000 * ureg.count / ureg.s
    b.accel = b.decel = OTHER.Quantity(512_000, "count / s**2")
    b.jog_speed = -1000 / ureg.s  # (the counts may be left out, as in a position)
    assert (b.speed, b.accel, b.decel, b.jog_speed) == (20_000, 512_000, 512_000, -1000)
    plan = b.plan_by(1000 * ureg.count, speed=OTHER.Quantity(6000, "count/s"))
    assert plan.peak_speed <= 6000
    with (
        nothing_sent(dmc),
        pytest.raises(
            InvalidArgument,
            match=r"^speed: 1000 count has the wrong dimension; expected count / second",
        ),
    ):
        b.speed = 1000 * ureg.count
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="no scale"):
        b.speed = 1000 * ureg.radian / ureg.s
    assert b.speed == 20_000


@pytest.mark.parametrize("per", [100 / ureg.degC, 100 / ureg.degF])
def test_a_scale_per_degree_celsius_is_refused_saying_what_a_scale_takes(
    dmc: galil.Controller, per: object
) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="counts per a length or an angle"):
        dmc.A.set_scale(counts_per=per)
    assert dmc.A.scale is None


def test_a_unit_only_the_users_registry_defines_is_refused_naming_the_argument(
    dmc: galil.Controller,
) -> None:
    mine = pint.UnitRegistry()
    mine.define("widget = 3 mm")
    x = dmc.A.set_scale(counts_per=2000 / ureg.mm)
    for axis in (x, dmc.B):  # (scaled or not)
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match=r"^target: 2 widget .*define"):
            axis.move_to(2 * mine.widget)
    with pytest.raises(InvalidArgument, match=r"^speed: 2\.0 widget / s .*define"):
        x.speed = 2 * mine.widget / mine.s
    with pytest.raises(InvalidArgument, match=r"^counts_per: 100 / widget .*define"):
        dmc.C.set_scale(counts_per=100 / mine.widget)


def test_a_path_in_a_unit_only_the_users_registry_defines_is_refused_naming_what_it_expected(
    dmc: galil.Controller,
) -> None:
    mine = pint.UnitRegistry()
    mine.define("quadrant = 90 * degree")
    mine.define("widget = 3 mm")
    mine.define("qturn = 90 * degree")  # (a quecto-turn to the default registry)
    for name in ("sweep", "start"):
        angles = {"start": 0, "sweep": 90, name: 1 * mine.quadrant}
        with pytest.raises(InvalidArgument, match=rf"^Arc {name}: 1 quadrant .*expected an angle"):
            Arc(radius=5, **angles)
    with pytest.raises(InvalidArgument, match=r"^Arc sweep: 1 qturn is quectoturn to pint's def"):
        Arc(5, 0, 1 * mine.qturn)
    with pytest.raises(InvalidArgument, match=r"^Arc sweep: 5 °C is not an angle; expected an"):
        Arc(5, 0, ureg.Quantity(5, "degC"))
    dmc.A.set_scale(counts_per=2000 / ureg.mm)
    dmc.B.set_scale(counts_per=2000 / ureg.mm)
    mm_s = ureg.mm / ureg.s
    cases = [
        ([Arc(1 * mine.widget, 0, 90)], {}, r"^segment 0 radius: 1 widget .*expected mm-compat"),
        ([Line(1 * mine.widget, 0)], {}, r"^segment 0 on A: 1 widget .*expected mm-compatible"),
        ([Line(1 * ureg.mm, 0)], {"speed": 2 * mine.widget / mine.s}, r"^speed: .*mm / s-comp"),
        ([Line(1 * ureg.mm, 0)], {"accel": 2 * mine.widget}, r"^accel: .*mm / s \*\* 2-comp"),
        ([Line(0, 100)], {"speed": 10, "axis_speed": {"D": 1 * mine.widget}}, r"count / sec"),
    ]
    same = [
        dmc.plan_vector("AB", [Arc(1 * ureg.mm, 0, a)], speed=10 * mm_s)
        for a in (0.25 * mine.turn, 90)
    ]  # (a unit both registries define alike is taken)
    assert same[0].duration == same[1].duration
    for segments, options, words in cases:
        options = {"speed": 10 * mm_s} | options
        axes = "CD" if "axis_speed" in options else "AB"
        with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match=words):
            dmc.plan_vector(axes, segments, **options)


@pytest.mark.parametrize(
    "bad", [2000, 2000 / ureg.s, 2000 / ureg.count, -5 / ureg.mm, math.inf / ureg.mm]
)
def test_bad_scales(bad: object) -> None:
    with pytest.raises(InvalidArgument):
        Scale(bad)
    with pytest.raises(InvalidArgument):
        Scale(2000 / ureg.mm, sign=0)
    with pytest.raises(InvalidArgument):
        Scale(2000 / ureg.mm, offset=1 * ureg.s)


def test_counts_in_the_scale_unit_are_dropped() -> None:
    s = Scale(2000 * ureg.count / ureg.mm)
    assert s.unit == ureg.mm
    assert s.position_to_counts(OTHER.Quantity(1.5, "mm")) == 3000


@settings(max_examples=150, deadline=None)
@given(
    per=st.floats(1e-3, 1e6),
    offset=st.floats(-1e4, 1e4),
    sign=st.sampled_from([1, -1]),
    x=st.floats(-1e4, 1e4),
    unit=st.sampled_from(["mm", "inch", "um", "degree", "turn"]),
)
def test_scale_round_trips(per: float, offset: float, sign: int, x: float, unit: str) -> None:
    u = ureg.Unit(unit)
    s = Scale(per / u, offset=offset * u, sign=sign)
    counts = s.position_to_counts(OTHER.Quantity(x, unit))
    assert counts == pytest.approx(sign * (x - offset) * per, rel=1e-9, abs=1e-6)
    back = s.counts_to_position(counts)
    assert back.to(u).magnitude == pytest.approx(x, rel=1e-9, abs=1e-6 * (1 + abs(offset)))
    rate = s.rate_to_counts(OTHER.Quantity(x, f"{unit}/s"), 1, "speed")
    assert s.counts_to_rate(rate, 1).to(u / ureg.s).magnitude == pytest.approx(
        x, rel=1e-9, abs=1e-9
    )
    d = s.distance_to_counts(x * u)
    assert s.counts_to_distance(d).magnitude == pytest.approx(x, rel=1e-9, abs=1e-9)


def test_sim_of_needs_a_simulator() -> None:
    with simulated() as dmc:
        assert sim_of(dmc).spec.name == "DMC-4040"


def test_plans_on_scaled_axes_are_shown_in_the_axis_unit() -> None:
    from galil.testing import simulated
    from galil.units import ureg

    with simulated() as dmc:
        x = dmc.A.set_scale(counts_per=2000 / ureg.mm)
        plan = x.plan_to(12.5 * ureg.mm)
        assert plan.end == 25_000
        assert plan.display == (2000.0, 0.0, "mm")
        assert "12.5 mm" in plan._repr_html_()
        move = x.move_to(12.5 * ureg.mm)
        assert move.profile.display == (2000.0, 0.0, "mm")
        move.wait()
        assert dmc.B.plan_to(100).display is None  # no scale: counts
