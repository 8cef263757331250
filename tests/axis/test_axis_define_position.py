"""``Axis.define_position`` (``DP``, a stepper's ``DE`` too; decision 0058) through the public
API on ``sim://`` (one case over TCP loopback, one through ``galil.aio``): the coordinate moves,
the motor does not, the soft limits stay where they are on the machine, and every refusal is
made before anything but a query goes out."""

from __future__ import annotations

import asyncio

import pytest
from axis_helpers import assert_follows

import galil
import galil.aio
from galil.sim.controller import SimController
from galil.testing import nothing_sent, sim_of, transcript
from galil.tuning import MotorType
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def test_define_position_moves_the_coordinate_not_the_motor(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    x = dmc.A.set_scale(2000 / mm, offset=1 * mm)
    x.move_to(11 * mm).wait()
    machine = sim.machine_position("A")
    with transcript(dmc) as sent:
        x.define_position(5 * mm)
    assert sent.lines[-1] == "DPA=8000"  # (5 mm - the 1 mm offset) x 2000 counts/mm
    assert sim.machine_position("A") == machine
    assert x.position == 5 * mm
    assert x.reference_position == 5 * mm
    assert x.scale is not None
    assert x.scale.offset == 1 * mm  # the scale is the user's


def test_a_move_after_define_position_ends_where_predicted(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    x = dmc.A.set_scale(2000 / mm)
    x.move_to(3 * mm).wait()
    x.define_position()  # the default: 0 in the axis's units
    t0 = sim.start_trace("A")
    h = x.move_to(-2 * mm)
    assert h.profile.start == 0
    r = h.wait()
    trace = sim.stop_trace("A")["A"]
    assert_follows(trace, t0, h.profile, h.begin["A"])
    assert r.final == r.predicted == {"A": -4000}
    assert sim.machine_position("A") == 6000 - 4000


def test_soft_limits_shift_with_the_coordinate(dmc: galil.Controller) -> None:
    a, b = dmc.A, dmc.B
    a.soft_limits = (-5000, 50000)
    b.soft_limits = (None, 40000)  # BL off
    dmc.move({"A": 12000, "B": 10000}).wait()
    a.define_position(0)
    b.define_position(-1000)
    assert a.soft_limits == (-17000, 38000)
    assert b.soft_limits == (None, 29000)  # off stays off
    assert dmc.query_operands(["_BLB"]) == [galil.models.INT32_MIN]
    with pytest.raises(galil.LimitError, match="FL"), nothing_sent(dmc, allow_queries=True):
        a.move_to(38001)  # one count past where FL 50000 was on the machine
    assert a.move_to(38000).wait().final == {"A": 38000}


def test_kept_soft_limits_refuse_a_position_beyond_them_unsent(dmc: galil.Controller) -> None:
    x = dmc.A.set_scale(2000 / mm)
    x.soft_limits = (-10 * mm, 10 * mm)
    with (
        pytest.raises(galil.LimitError, match="FL") as caught,
        nothing_sent(dmc, allow_queries=True),
    ):
        x.define_position(11 * mm, shift_limits=False)
    assert caught.value.value_in_units == 11 * mm
    with pytest.raises(galil.LimitError, match="BL"), nothing_sent(dmc, allow_queries=True):
        x.define_position(-11 * mm, shift_limits=False)
    x.define_position(4 * mm, shift_limits=False)
    assert x.soft_limits == (-10 * mm, 10 * mm)
    assert x.position == 4 * mm


def test_a_soft_limit_shifted_past_32_bits_is_refused_unsent(dmc: galil.Controller) -> None:
    a = dmc.A
    a.soft_limits = (-1000, galil.models.INT32_MAX - 10)
    a.move_to(-500).wait()
    with (
        pytest.raises(galil.LimitError, match=r"FL .* 32-bit"),
        nothing_sent(dmc, allow_queries=True),
    ):
        a.define_position(0)  # FL would be 2**31 + 489
    assert a.reference_position == -500


@pytest.mark.parametrize(
    ("value", "error"),
    [
        ("x", galil.InvalidArgument),
        (None, galil.InvalidArgument),
        (5 * s, galil.InvalidArgument),
        (2**31, galil.LimitError),
        (-(2**31) - 1, galil.LimitError),
        (float("nan"), galil.InvalidArgument),
    ],
)
def test_bad_positions_are_refused_unsent(
    dmc: galil.Controller, value: object, error: type[Exception]
) -> None:
    with pytest.raises(error), nothing_sent(dmc):
        dmc.A.define_position(value)


def test_wrong_units_and_a_bad_flag_are_refused_unsent(dmc: galil.Controller) -> None:
    x = dmc.A.set_scale(2000 / mm)
    with pytest.raises(galil.InvalidArgument), nothing_sent(dmc):
        x.define_position(3 * s)
    with pytest.raises(galil.InvalidArgument), nothing_sent(dmc):
        x.define_position(3)  # a plain number other than 0 on a scaled axis
    with pytest.raises(galil.InvalidArgument, match="shift_limits"), nothing_sent(dmc):
        x.define_position(0, shift_limits="no")  # type: ignore[arg-type]


def test_refused_unsent_in_motion(dmc: galil.Controller) -> None:
    a = dmc.A
    for start in (lambda: a.jog(5000), lambda: a.move_by(100_000)):
        h = start()
        with (
            pytest.raises(galil.InvalidArgument, match="moves"),
            nothing_sent(dmc, allow_queries=True),
        ):
            a.define_position(0)
        a.stop()
        h.wait()
    a.define_position(0)
    assert a.position == 0


def test_a_move_nobody_waited_for_ends_in_the_old_counts(dmc: galil.Controller) -> None:
    a = dmc.A
    h = a.move_to(3000)
    dmc.sleep(h.duration + 0.1)
    a.define_position(0)
    assert h.wait().final == {"A": 3000}
    assert a.position == 0


def test_gear_master_and_follower_are_refused_unsent(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    gearing = dmc.B.gear_to("A", 0.5)
    with pytest.raises(galil.InvalidArgument, match="gear master of B"), nothing_sent(dmc):
        dmc.A.define_position(1000)
    with pytest.raises(galil.InvalidArgument, match="geared to A"), nothing_sent(dmc):
        dmc.B.define_position(0)
    gearing.off()
    dmc.A.define_position(1000)
    dmc.sleep(0.05)
    assert dmc.A.position == 1000
    assert (dmc.B.position, sim.machine_position("B")) == (0, 0)  # B did not jump


def test_a_gearing_set_up_elsewhere_refuses_define_position_on_any_other_axis(
    dmc: galil.Controller,
) -> None:
    # (GA has no operand: B's master may be A, and DP on A would make B jump with it)
    sim = sim_of(dmc)
    assert sim.feed(b"GA ,CA;GR ,0.5\r") == b"::"  # a program's or another host's gearing
    for a in "AC":
        with (
            pytest.raises(galil.InvalidArgument, match=r"may be the gear master of B \(GR 0\.5\)"),
            nothing_sent(dmc, allow_queries=True),
        ):
            dmc.axes[a].define_position(1000)
    dmc.B.gear_off()
    dmc.A.define_position(1000)
    dmc.sleep(0.05)
    assert dmc.A.position == 1000
    assert (dmc.B.position, sim.machine_position("B")) == (0, 0)  # B did not jump


def test_homed_stays_true_and_says_that_zero_moved(dmc: galil.Controller) -> None:
    a = dmc.A
    a.home().wait()
    assert "redefined" not in a.homed.how
    a.move_to(2000).wait()
    a.define_position(0)
    assert a.homed
    assert "define_position: DP 0 where RP was 2000" in a.homed.how
    a.home().wait()
    assert "redefined" not in a.homed.how  # a new home defines 0 again


def test_a_stepper_gets_de_so_its_encoder_reads_the_position_too(
    dmc: galil.Controller,
) -> None:
    a = dmc.A
    a.move_to(1500).wait()
    dmc.motor_off("A")
    a.motor_type = MotorType.STEPPER_ACTIVE_LOW
    dmc.servo_here("A")
    with transcript(dmc) as sent:
        a.define_position(100)
    assert sent.lines[-1] == "DPA=100;DEA=100"
    values = dmc.query_operands(["_TPA", "_RPA", "_TDA"])
    assert values == [100, 100, 100]


def test_define_position_over_tcp(tcp: tuple[galil.Controller, SimController]) -> None:
    dmc, _ = tcp
    a = dmc.A
    a.soft_limits = (-1000, 1000)
    a.define_position(-200)
    assert (a.position, a.reference_position, a.soft_limits) == (-200, -200, (-1200, 800))
    assert a.move_to(0).wait().final == {"A": 0}


def test_the_aio_twin_defines_the_position() -> None:
    async def main() -> tuple[float, float]:
        async with await galil.aio.connect("sim://DMC-4040") as dmc:
            await (await dmc.A.move_to(700))
            await dmc.A.define_position(50)
            with pytest.raises(galil.InvalidArgument):
                await dmc.A.define_position("x")
            return await dmc.A.position(), await dmc.A.reference_position()

    assert asyncio.run(main()) == (50, 50)
