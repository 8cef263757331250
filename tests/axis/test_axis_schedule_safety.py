"""Items 5, 6 and 9 of issue 6: speed schedules, the motion guard, and refused input."""

from __future__ import annotations

import math

import pytest
from axis_helpers import assert_follows

import galil
from galil.errors import InvalidArgument, LimitError
from galil.predict import ScheduleError
from galil.testing import nothing_sent, sim_of, transcript
from galil.units import ureg


def test_speed_schedule_runs_as_predicted(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("B")
    with transcript(dmc) as sent:
        h = dmc.B.speed_schedule(15_000, [(5000, 10_000), (10_000, 5000)], speed=50_000)
    assert {"#GSCHED", "SPB=50000", "PRB=15000", "BG B", "ADB=5000", "ADB=10000"} <= set(sent.lines)
    assert any("XQ #GSCHED" in line for line in sent.lines)
    assert h.kind == "schedule"
    r = h.wait()
    trace = sim.stop_trace("B")["B"]
    assert r.final == {"B": 15_000}
    assert r.worst == 0
    begin = h.begin["B"]
    assert begin is not None
    assert begin >= t0
    assert_follows(trace, t0, h.profile, begin)


def test_speed_schedule_in_units(dmc: galil.Controller) -> None:
    mm, s = ureg.mm, ureg.s
    x = dmc.C.set_scale(counts_per=2000 / mm)
    h = x.speed_schedule(-10 * mm, [(3 * mm, 10 * mm / s)], speed=25 * mm / s)
    assert h.wait().final == {"C": -20_000}
    assert x.reference_position == -10 * mm


def test_invalid_change_point_names_the_earliest(dmc: galil.Controller) -> None:
    dmc.B.accel = 100_000
    with nothing_sent(dmc, allow_queries=True), pytest.raises(ScheduleError) as info:
        dmc.B.speed_schedule(15_000, [(1000, 10_000)], speed=50_000)
    err = info.value
    ac = dmc.B.accel  # quantised as the controller stores it
    assert err.index == 0
    assert err.earliest == math.ceil(50_000**2 / (2 * ac))
    assert err.earliest > 1000
    assert "earliest valid trigger" in str(err)
    assert isinstance(err, LimitError)
    with nothing_sent(dmc), pytest.raises(InvalidArgument):
        dmc.B.speed_schedule(15_000, [(1000,)])
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="wrong dimension"):
        dmc.B.set_scale(counts_per=1000 / ureg.mm).speed_schedule(
            5 * ureg.mm, [(1 * ureg.s, 2 * ureg.mm / ureg.s)]
        )


def _cancel(dmc: galil.Controller, handle: galil.MoveHandle, how: str) -> None:
    if how == "handle":
        handle.stop()
    elif how == "axis":
        dmc.B.stop()
    elif how == "controller":
        dmc.stop()
    elif how == "abort":
        dmc.abort()
    else:
        with pytest.raises(RuntimeError), dmc.motion("B"):
            raise RuntimeError("the scan failed")


@pytest.mark.parametrize("how", ["handle", "axis", "controller", "abort", "guard"])
def test_cancelling_a_speed_schedule_before_its_change_point_restores_the_speed(
    dmc: galil.Controller, how: str
) -> None:
    b = dmc.B
    b.speed = 20_000
    h = b.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)  # at 40 000 counts/s, well before the change point
    _cancel(dmc, h, how)
    dmc.sleep(1.0)  # at rest: the controller releases the AD that waited for 30 000 counts
    assert b.speed == 20_000  # neither the schedule's 40 000 nor its change to 10 000
    assert dmc.query_operands(["_XQ0"]) == [-1]  # the routine was halted
    if how == "abort":
        dmc.servo_here()
    move = b.move_by(1000)
    assert move.params["B"].speed == 20_000
    assert move.wait().worst == 0


def test_stopping_a_follower_of_a_speed_schedule_leaves_the_schedule_running(
    dmc: galil.Controller,
) -> None:
    gearing = dmc.A.gear_to("B", 1)
    h = dmc.B.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)
    dmc.A.stop()  # the follower only: its gearing goes, the schedule runs on
    assert not gearing.engaged
    r = h.wait()
    assert r.final == {"B": 50_000}
    assert r.worst == 0
    assert dmc.B.speed == 10_000  # its change point ran


def test_cancelling_a_speed_schedule_leaves_a_later_schedules_routine_alone(
    dmc: galil.Controller,
) -> None:
    b = dmc.B.speed_schedule(50_000, [(10_000, 20_000)], speed=40_000)
    dmc.sleep(1.0)  # past its change point (its routine is over), still moving
    c = dmc.C.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)  # thread 0 again
    b.stop()
    assert c.wait().final == {"C": 50_000}
    assert dmc.C.speed == 10_000  # C's routine ran its change point: B's cancel left it alone


def test_a_speed_schedule_that_ran_its_course_keeps_its_last_speed(
    dmc: galil.Controller,
) -> None:
    dmc.B.speed = 20_000
    dmc.B.speed_schedule(20_000, [(10_000, 10_000)], speed=40_000)
    dmc.sleep(5.0)  # over, though its handle was never polled
    dmc.B.stop()  # nothing left to cancel
    assert dmc.B.speed == 10_000


def test_a_speed_schedule_while_another_runs_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    h = dmc.B.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="thread 0"):
        dmc.C.speed_schedule(20_000, [(10_000, 10_000)], speed=30_000, label="GSCHED2")
    assert not dmc.C.moving
    r = h.wait()  # the first one ran its course, its change point included
    assert r.final == {"B": 50_000}
    assert r.worst == 0
    assert dmc.B.speed == 10_000


def test_a_download_during_a_speed_schedule_is_refused_rather_than_restarting_it(
    dmc: galil.Controller,
) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("B")
    h = dmc.B.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)
    with transcript(dmc) as sent, pytest.raises(InvalidArgument, match="speed schedule"):
        dmc.watchdog(1.0)  # its routine needs a download
    assert not [line for line in sent.lines if line.startswith(("HX", "DL", "XQ"))]
    h.wait()
    begin = h.begin["B"]
    assert begin is not None
    assert_follows(sim.stop_trace("B")["B"], t0, h.profile, begin)


def _fail_during_moves(dmc: galil.Controller, exc: BaseException, guarded: str | None) -> None:
    with dmc.motion(guarded):
        dmc.A.move_by(100_000)
        dmc.C.jog(-20_000)
        dmc.sleep(0.3)
        raise exc


@pytest.mark.parametrize("exc", [RuntimeError("scan failed"), KeyboardInterrupt()])
def test_motion_guard_stops_moving_axes(dmc: galil.Controller, exc: BaseException) -> None:
    sim = sim_of(dmc)
    dmc.D.move_by(500)  # finishes before the failure: not stopped again
    with pytest.raises(type(exc)) as info:
        _fail_during_moves(dmc, exc, None)
    assert info.value is exc  # re-raised as it was
    stops = [text for _, text in sim.command_log if text.startswith("ST")]
    assert stops == ["ST AC"]
    # The guard waited: both axes are at rest, stopped by ST, when the exception arrives.
    assert dmc.query_operands(["_BGA", "_BGC", "_SCA", "_SCC"]) == [0, 0, 4, 4]


def test_motion_guard_leaves_a_clean_block_alone(dmc: galil.Controller) -> None:
    with dmc.motion("AB"):
        dmc.A.move_by(100).wait()
    with pytest.raises(ValueError, match="only B"):
        _fail_during_moves(dmc, ValueError("only B is guarded"), "B")
    assert dmc.A.moving
    assert dmc.C.moving
    assert not [t for _, t in sim_of(dmc).command_log if t.startswith("ST")]
    dmc.stop()


def test_out_of_range_values_sent_nothing(dmc: galil.Controller) -> None:
    x = dmc.A.set_scale(counts_per=2000 / ureg.mm)
    mm, s = ureg.mm, ureg.s
    cases = [
        lambda: setattr(x, "speed", 1e9 * mm / s),
        lambda: setattr(x, "accel", 1e12 * mm / s**2),
        lambda: x.move_by(1 * mm, speed=1e9 * mm / s),
        lambda: x.jog(-1e9 * mm / s),
        lambda: dmc.move({"A": 1 * mm, "B": 1e12}),
        lambda: setattr(x, "soft_limits", (-2e9 * mm, 0 * mm)),
    ]
    for case in cases:
        with nothing_sent(dmc), pytest.raises(LimitError) as info:
            case()
        assert info.value.name
    with nothing_sent(dmc), pytest.raises(InvalidArgument):
        dmc.A.smoothing = 2.0
    with nothing_sent(dmc), pytest.raises(InvalidArgument):
        dmc.move({})
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="twice"):
        dmc.move({"A": 1, "a": 2})
    with nothing_sent(dmc), pytest.raises(InvalidArgument):
        dmc.move({"Q": 1})


def test_move_past_a_soft_limit_is_refused(dmc: galil.Controller) -> None:
    x = dmc.A.set_scale(counts_per=2000 / ureg.mm)
    x.soft_limits = (-5 * ureg.mm, 5 * ureg.mm)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as info:
        x.move_to(6 * ureg.mm)
    assert "FL 10000" in str(info.value)
    assert info.value.axis == "A"
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="BL"):
        dmc.move({"B": 0, "A": -5.5 * ureg.mm})
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError):
        x.speed_schedule(12 * ureg.mm, [])
    assert x.move_to(5 * ureg.mm).wait().final == {"A": 10_000}


def test_nothing_sent_catches_a_command(dmc: galil.Controller) -> None:
    with pytest.raises(AssertionError, match="onto the wire"), nothing_sent(dmc):
        dmc.A.speed = 1000
    with (
        pytest.raises(AssertionError, match="other than queries"),
        nothing_sent(dmc, allow_queries=True),
    ):
        dmc.A.move_by(10)


def test_thread_0_is_the_users_again_once_a_speed_schedule_has_ended(
    dmc: galil.Controller,
) -> None:
    # The schedule's routine ends with its move: the library holds thread 0 no more, so the
    # user's program runs there (its default thread), and can be waited for and halted.
    dmc.programs.download('#A\nMG "hello"\nEN')
    dmc.A.speed_schedule(30_000, [(10_000, 10_000)], speed=20_000).wait()
    dmc.programs.run("#A")
    dmc.programs.wait(0)
    dmc.programs.halt(0)
    assert dmc.programs.threads == {}
    # A schedule still running keeps the thread: the user's program is refused there.
    h = dmc.A.speed_schedule(-30_000, [(10_000, 10_000)], speed=20_000)
    with pytest.raises(InvalidArgument, match="library's #GSCHED"):
        dmc.programs.run("#A")
    h.wait()
    dmc.programs.run("#A")


@pytest.mark.parametrize("label", ["GWDOG", "#GWDOG", "GWDOGL", "GINWAIT", "GINLOOP"])
def test_a_speed_schedule_may_not_take_the_label_of_another_library_routine(
    dmc: galil.Controller, label: str
) -> None:
    dog = dmc.watchdog(0.5)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="routine"):
        dmc.A.speed_schedule(20_000, [(10_000, 5000)], speed=20_000, label=label)
    jog = dmc.A.jog(20_000)
    sim_of(dmc).advance(2.0)  # the host silent: the watchdog's routine is its own still
    assert dog.fired
    assert not dmc.A.moving
    jog.wait()


def test_a_speed_schedule_label_may_be_given_with_its_hash(dmc: galil.Controller) -> None:
    with transcript(dmc) as sent:
        h = dmc.A.speed_schedule(20_000, [(10_000, 5000)], speed=20_000, label="#MINE")
    assert "#MINE" in sent.lines
    assert h.wait().final == {"A": 20_000}
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="##MINE"):
        dmc.A.speed_schedule(20_000, [(10_000, 5000)], speed=20_000, label="##MINE")


def test_a_negative_change_point_is_refused_not_made_positive(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="negative"):
        dmc.A.speed_schedule(20_000, [(-10_000, 5000)], speed=20_000)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="negative"):
        dmc.A.speed_schedule(-20_000, [(-10_000, 5000)], speed=20_000)
    mm, s = ureg.mm, ureg.s
    x = dmc.C.set_scale(counts_per=2000 / mm, sign=-1)  # a positive mm is negative counts
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="negative"):
        x.speed_schedule(10 * mm, [(-4 * mm, 2.5 * mm / s)], speed=10 * mm / s)
    h = x.speed_schedule(10 * mm, [(4 * mm, 2.5 * mm / s)], speed=10 * mm / s)
    assert h.wait().final == {"C": -20_000}


def test_a_speed_schedule_a_limit_switch_cut_short_restores_the_speed_when_waited_for(
    dmc: galil.Controller,
) -> None:
    # (SP kept the schedule's speeds: the next move ran at them, not at the user's speed)
    b = dmc.B
    b.speed = 20_000
    h = b.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)  # at 40 000 counts/s, well before the change point
    sim_of(dmc).set_limit_switch("B", "forward", True)
    with pytest.raises(galil.MotionError, match="FWD limit"):
        h.wait()
    sim_of(dmc).set_limit_switch("B", "forward", False)
    assert b.speed == 20_000  # neither the schedule's 40 000 nor its change to 10 000
    assert dmc.query_operands(["_XQ0"]) == [-1]
    with pytest.raises(galil.MotionError):
        h.wait()  # (again: the same error, nothing undone twice)
    move = b.move_by(-1000)
    assert move.params["B"].speed == 20_000
    assert move.wait().worst == 0


def test_waiting_late_for_a_cut_short_speed_schedule_leaves_a_later_moves_speed_alone(
    dmc: galil.Controller,
) -> None:
    b = dmc.B
    b.speed = 20_000
    h = b.speed_schedule(50_000, [(30_000, 10_000)], speed=40_000)
    dmc.sleep(0.2)
    sim_of(dmc).set_limit_switch("B", "forward", True)
    dmc.sleep(0.5)  # at rest on the switch
    sim_of(dmc).set_limit_switch("B", "forward", False)
    later = b.move_by(-20_000, speed=30_000)
    with pytest.raises(galil.MotionError, match="FWD limit"):
        h.wait()
    assert b.speed == 30_000  # the later move's, not put back under it
    assert later.wait().worst == 0
