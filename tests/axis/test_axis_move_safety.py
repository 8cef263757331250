"""Refusals before the first byte and setters that never start motion: jog_speed on a stopped
jog, an increment past a soft limit, gear followers past theirs.
"""

from __future__ import annotations

import asyncio
import functools
import re
import warnings
from collections.abc import Callable

import pytest

import galil
import galil.aio as aio
from galil.errors import InvalidArgument, LimitError, MotionError
from galil.testing import nothing_sent, sim_of, simulated, transcript
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def _begins(lines: list[str]) -> list[str]:
    """The lines that hold a BG command (not an ``MG _BGA`` query)."""
    return [line for line in lines if re.search(r"(^|;)\s*BG", line)]


# -- jog_speed ------------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["stop", "abort"])
def test_setting_jog_speed_after_a_stopped_jog_only_presets_it(
    dmc: galil.Controller, how: str
) -> None:
    a = dmc.A
    a.jog(1000)
    dmc.sleep(0.5)
    if how == "stop":
        a.stop()
    else:
        dmc.abort()
        dmc.servo_here()
    dmc.sleep(1.0)  # the jog's handle is never polled: the tracker still holds it
    with transcript(dmc) as sent:
        a.jog_speed = 500
    dmc.sleep(1.0)
    assert not a.moving
    assert not _begins(sent.lines)
    assert a.jog_speed == 500


def test_setting_jog_speed_after_a_limit_stop_does_not_restart_the_jog(
    dmc: galil.Controller,
) -> None:
    a = dmc.A
    a.soft_limits = (-1000, 2000)
    a.jog(4000)
    dmc.sleep(2.0)  # the soft limit stops the jog; nobody looks at its handle
    assert not a.moving
    with transcript(dmc) as sent:
        a.jog_speed = -500
    dmc.sleep(0.5)
    assert not a.moving
    assert not _begins(sent.lines)


def test_setting_jog_speed_while_jogging_changes_the_running_jog(dmc: galil.Controller) -> None:
    j = dmc.B.jog(2000)
    dmc.sleep(0.3)
    dmc.B.jog_speed = 3000
    dmc.sleep(0.5)
    assert dmc.B.velocity == pytest.approx(3000, rel=0.01)
    j.stop()
    r = j.wait()
    assert r.predicted == r.final


def test_setting_jog_speed_while_the_jog_stops_is_refused(dmc: galil.Controller) -> None:
    dmc.C.accel = dmc.C.decel = 1024
    dmc.C.jog(5000)
    dmc.sleep(0.5)
    dmc.C.stop()  # 5 s of deceleration
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="stopping"):
        dmc.C.jog_speed = 8000


def test_setting_jog_speed_during_a_position_move_is_refused(dmc: galil.Controller) -> None:
    dmc.A.move_by(50_000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="move"):
        dmc.A.jog_speed = 1000


def test_async_set_jog_speed_after_a_stopped_jog_only_presets_it() -> None:
    async def body() -> None:
        async with await aio.connect("sim://DMC-4040") as c:
            await c.A.jog(1000)
            await c.sleep(0.5)
            await c.A.stop()
            await c.sleep(1.0)
            await c.A.set_jog_speed(500)
            await c.sleep(1.0)
            assert not await c.A.moving()

    asyncio.run(asyncio.wait_for(body(), 30))


# -- increment ------------------------------------------------------------------------------
def test_increment_during_a_move_past_the_soft_limit_is_refused(dmc: galil.Controller) -> None:
    a = dmc.A
    a.soft_limits = (-1000, 5000)
    h = a.move_to(4000)
    dmc.sleep(0.2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        a.increment(3000)
    assert caught.value.name == "FL"
    assert caught.value.axis == "A"
    a.increment(1000)  # to 5000, on the limit: allowed
    r = h.wait()
    assert r.final == {"A": 5000}


def test_increment_during_a_move_beyond_32_bits_is_refused(dmc: galil.Controller) -> None:
    dmc.A.move_to(2_147_000_000)  # far away: still moving when the increment comes
    dmc.sleep(0.2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="32-bit"):
        dmc.A.increment(1_000_000)


def test_an_increment_beyond_32_bits_is_refused_naming_the_ip(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(LimitError) as caught:
        dmc.A.increment(2**31)  # (the increment itself: no query either)
    assert str(caught.value).startswith("IP 2147483648 on A is outside the 32-bit")
    assert caught.value.name == "IP"
    dmc.A.move_by(1000).wait()
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.A.increment(2**31 - 10)  # (idle: the position it would reach)
    assert "IP 2147483638 on axis A moves the axis to 2147484638, outside" in str(caught.value)
    dmc.A.move_to(2_147_000_000)
    dmc.sleep(0.2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.A.increment(1_000_000)  # (in a move: the target it would move)
    assert "IP 1000000 on axis A moves the target of the move to" in str(caught.value)


def test_increment_while_jogging_past_the_soft_limit_is_refused(dmc: galil.Controller) -> None:
    d = dmc.D
    d.soft_limits = (-5000, 5000)
    d.jog(1000)
    dmc.sleep(0.2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        d.increment(6000)
    assert caught.value.name == "FL"
    d.stop()


def test_increment_during_a_master_move_past_a_followers_limit_is_refused(
    dmc: galil.Controller,
) -> None:
    dmc.A.soft_limits = (-1000, 1000)
    dmc.A.gear_to("B", 2)
    dmc.B.move_by(400)
    dmc.sleep(0.01)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.B.increment(200)  # B ends at 600: A at 1200
    assert caught.value.axis == "A"


# -- gear followers -------------------------------------------------------------------------
def test_a_master_move_taking_a_follower_past_its_soft_limit_is_refused(
    dmc: galil.Controller,
) -> None:
    dmc.A.soft_limits = (-1000, 1000)
    dmc.A.gear_to("B", 100)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.B.move_by(100)
    assert caught.value.axis == "A"
    assert caught.value.name == "FL"
    with pytest.raises(LimitError, match="axis A"):
        dmc.B.plan_by(100)
    r = dmc.B.move_by(10).wait()  # A to 1000: on its limit
    assert r.final == {"B": 10}
    assert dmc.A.reference_position == 1000


def test_a_master_move_driving_a_follower_too_fast_is_refused(dmc: galil.Controller) -> None:
    dmc.A.gear_to("B", 100)
    dmc.B.speed = 500_000  # the follower would run at 50 M counts/s
    dmc.B.accel = dmc.B.decel = 5_000_000
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.B.move_by(100_000)
    assert caught.value.axis == "A"
    assert caught.value.name == "speed"


def test_a_master_jog_driving_a_follower_too_fast_is_refused(dmc: galil.Controller) -> None:
    dmc.A.gear_to("B", 100)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.B.jog(500_000)
    assert caught.value.axis == "A"


@pytest.mark.parametrize("how", ["stop", "raw ST"])
def test_increment_while_a_stopped_schedule_ramps_down_is_refused(
    dmc: galil.Controller, how: str
) -> None:
    # (a schedule's track does not record the ST: the IP went out for TC 16)
    schedule = dmc.B.speed_schedule(12000, [(4000, 8000)], speed=15000)
    dmc.sleep(0.3)
    if how == "stop":
        dmc.stop()
    else:
        dmc.command("ST B")
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="stopping"):
        dmc.B.increment(5)
    if how == "stop":
        schedule.wait()
    else:  # (an ST behind the library's back: the schedule did not end, decision 0105)
        with pytest.raises(MotionError, match=r"B by ST \(stop code 4\)"):
            schedule.wait()


@pytest.mark.parametrize(
    "start", [lambda ax: ax.move_by(1000), lambda ax: ax.jog(1000), lambda ax: ax.increment(10)]
)
def test_a_start_towards_an_active_limit_switch_is_refused_before_sending(
    dmc: galil.Controller, start: Callable[[galil.Axis], object]
) -> None:
    # (the controller refuses the BG with TC 22: the PA or JG had gone out, and a
    # CommandError came back)
    sim_of(dmc).place_limit_switches("A", forward=500)
    with pytest.raises(galil.MotionError):
        dmc.A.move_by(3000).wait()
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 22"):
        start(dmc.A)
    dmc.A.move_by(-1000).wait()  # away from it: allowed


def test_a_jog_on_past_a_soft_limit_the_axis_is_beyond_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    dmc.A.move_to(-12000).wait()
    dmc.A.soft_limits = (-5000, None)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="TC 22"):
        dmc.A.jog(-3000)
    jog = dmc.A.jog(3000)  # back inside: allowed
    jog.stop()
    jog.wait()


def test_a_move_that_off_on_error_ends_raises_in_wait_not_a_deviation_warning() -> None:
    with simulated() as dmc:
        dmc.command("OE 1,1,1,1")
        dmc.A.error_limit = 5  # the servo lag's error passes 5 counts at once
        handle = dmc.A.move_by(200_000)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no "ended ... counts away" warning
            with pytest.raises(galil.MotionError, match="Off on Error") as info:
                handle.wait()
        assert info.value.stop_codes == {"A": 8}
        assert handle.result.stop_codes == {"A": 8}
        assert handle.result.predicted == {}  # a fault's end is not the prediction's
        assert dmc.query_operands(["_MOA", "_BGA"]) == [1, 0]  # the motor is off, at rest


@pytest.mark.parametrize("start", ["home", "find_edge", "find_index"])
def test_homing_on_past_a_soft_limit_the_axis_is_beyond_is_refused_before_sending(
    dmc: galil.Controller, start: str
) -> None:
    dmc.A.move_to(9000).wait()
    dmc.A.soft_limits = (None, 5000)
    dmc.A.jog_speed = 25000  # (FI's direction: forward)
    dmc.A.home_speed = 2000
    sim_of(dmc).set_home_switch("A", edge=20000, index_period=2000)  # ahead: HM, FE go forward
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="TC 22"):
        getattr(dmc.A, start)()
    dmc.A.soft_limits = (None, None)
    homing = getattr(dmc.A, start)()  # inside again: allowed
    homing.stop()
    homing.wait()


@pytest.mark.parametrize(
    ("start", "limits", "name"),
    [
        ("home", (-5000, None), "BL"),  # (the edge at -10,000: HM passes it, back to -8000)
        ("find_edge", (-9000, None), "BL"),  # (FE decelerates past the edge)
        ("find_index", (-3000, None), "BL"),  # (JG < 0: the index at -4000)
        ("find_index", (None, 3000), "FL"),  # (JG > 0: the index at 4000)
    ],
)
def test_a_homing_whose_predicted_path_crosses_a_soft_limit_is_refused_before_sending(
    dmc: galil.Controller, start: str, limits: tuple[int | None, int | None], name: str
) -> None:
    """Given the switch positions, the whole predicted sequence is checked against BL and FL
    as a move's path is (decision 0003): the controller would stop it at the limit (stop code
    3 or 2), short of its switch, the axis left unhomed."""
    a = dmc.A
    a.home_speed = 2000
    a.jog_speed = -2000 if name == "BL" else 2000
    a.soft_limits = limits
    switch = sim_of(dmc).home_switch("A")
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as info:
        getattr(a, start)(switch=switch)
    assert info.value.name == name
    assert info.value.limit == limits[0] if name == "BL" else limits[1]
    assert info.value.axis == "A"
    assert "switch positions" in str(info.value)
    assert a.position == 0
    assert a.moving is False
    a.soft_limits = (None, None)  # nothing in the way: the same start goes ahead
    assert getattr(a, start)(switch=switch).wait().stop_codes == {
        "A": 9 if start == "find_edge" else 10
    }


def test_a_homing_path_is_checked_in_the_counts_it_starts_in(dmc: galil.Controller) -> None:
    """HM defines 0 at the index only when it ends: the controller meets its soft limits in
    the counts at the start. The prediction's profile is in the counts it ends with (from
    +8000 down to 0 here), which a limit at 5000 would refuse; the path itself (0 down past
    the edge at -10,000, back to the index at -8000) never comes near it."""
    a = dmc.A
    a.home_speed = 2000
    a.soft_limits = (-20_000, 5000)
    assert a.home(switch=sim_of(dmc).home_switch("A")).wait().stop_codes == {"A": 10}
    assert a.position == 0


def test_a_refused_homing_path_speaks_the_axis_unit(dmc: galil.Controller, x: galil.Axis) -> None:
    x.home_speed = 1 * mm / s
    x.soft_limits = (-2.5 * mm, None)  # (-5000 counts: HM passes it on its way to the edge)
    switch = sim_of(dmc).home_switch("A")
    with pytest.raises(LimitError, match=r"in user units: reaches -2.5\d* mm, limit -2.5 mm"):
        x.home(switch=switch)


def test_a_speed_schedule_towards_an_active_limit_switch_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    # (its program's BG would fail with TC 22 on the controller, and the handle wait for a
    # move that never began)
    sim_of(dmc).place_limit_switches("C", reverse=-500)
    dmc.C.move_to(-500).wait()
    dmc.sleep(0.1)  # (the motor settles onto the switch)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 22"):
        dmc.C.speed_schedule(-12_000, [(4000, 8000)], speed=15_000)
    assert dmc.C.speed_schedule(2000, [(1000, 3000)], speed=5000).wait().final == {"C": 1500}


def test_a_reversing_increment_in_a_moves_last_samples_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    """At its target (``_RP`` = ``_PA``) a move still runs for a sample or two (``_BG`` 1) and
    the controller still refuses an IP against its direction (TC 16); one the same way is
    taken. (The remaining distance, 0 then, showed no direction: the IP went out.)"""
    handle = dmc.D.move_by(700)
    while True:
        pa, rp, bg = dmc.query_operands(["_PAD", "_RPD", "_BGD"])
        if pa == rp:
            break
        dmc.sleep(0.001)
    assert bg == 1
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="ending"):
        dmc.D.increment(-2000)
    assert dmc.D.increment(300) is handle
    assert handle.wait().final == {"D": 1000}


_AT_ZERO: dict[str, tuple[str, Callable[[galil.Controller], object]]] = {
    # what is 0, how it is started: one condition, one type wherever it is met
    "move_by": ("SP", lambda dmc: dmc.A.move_by(1000)),
    "move": ("SP", lambda dmc: dmc.move({"A": 1000})),
    "home": ("SP", lambda dmc: dmc.A.home()),
    "find_edge": ("SP", lambda dmc: dmc.A.find_edge()),
    "speed_schedule": ("SP", lambda dmc: dmc.A.speed_schedule(2000, [(1000, 3000)])),
    "home at HV 0": ("HV", lambda dmc: dmc.A.home()),
    "find_index at HV 0": ("HV", lambda dmc: dmc.A.find_index()),
    "find_index at JG 0": ("JG", lambda dmc: dmc.A.find_index()),
}


@pytest.mark.parametrize("start", sorted(_AT_ZERO))
def test_a_start_at_a_speed_of_0_is_a_limit_error_whatever_starts_it(
    dmc: galil.Controller, start: str
) -> None:
    """``axis A has SP 0: set a speed first`` was a ``LimitError`` from a move and a plain
    ``InvalidArgument`` from a homing; HV 0 and JG 0 likewise. Each is a ``LimitError``
    (an ``InvalidArgument`` too) naming the speed, its value 0, and the axis."""
    name, begin = _AT_ZERO[start]
    dmc.A.speed, dmc.A.home_speed, dmc.A.jog_speed = 20_000, 2000, 2000
    setattr(dmc.A, {"SP": "speed", "HV": "home_speed", "JG": "jog_speed"}[name], 0)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as info:
        begin(dmc)
    assert info.value.name == name
    assert info.value.value == 0
    assert info.value.axis == "A"
    assert f"{name} 0" in str(info.value) or f"{name}, which is 0" in str(info.value)
    assert not dmc.A.moving


@pytest.mark.parametrize("how", ["gear_to", "set_ratio"])
@pytest.mark.parametrize("ratio", [0, 0.0, 1e-9])
def test_a_gear_ratio_of_0_is_a_limit_error_whether_gearing_or_changing_it(
    dmc: galil.Controller, how: str, ratio: float
) -> None:
    gearing = dmc.B.gear_to(dmc.A, 1) if how == "set_ratio" else None
    change = (
        functools.partial(dmc.B.gear_to, dmc.A, ratio)
        if gearing is None
        else functools.partial(gearing.set_ratio, ratio)
    )
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as info:
        change()
    assert info.value.name == "GR"
    assert info.value.value == 0
    assert "a gear ratio of 0 is no gearing" in str(info.value)
    if gearing is not None:
        assert gearing.engaged
        assert gearing.ratio == 1
        gearing.off()


@pytest.mark.parametrize("distance", [0, 100])
def test_a_move_at_speed_0_is_refused_before_anything_moves_even_of_no_distance(
    distance: int,
) -> None:
    """BG refuses SP 0 (TC 6) even for a move to where the axis is: the library says to set a
    speed first rather than send the move and meet the controller's refusal."""
    dmc = galil.connect("sim://DMC-4040")
    dmc.A.speed = 0
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="set a speed"):
        dmc.A.move_by(distance)
    dmc.close()
