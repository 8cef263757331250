"""Item 3 of issue 6: moves, jogs, increments, stops and their handles, on the in-process sim.

Every scenario compares the simulator's servo loop with the handle's prediction sample by
sample: the handle stamps each command with the controller's TIME, so the two must agree.
"""

from __future__ import annotations

import re
import threading

import pytest
from axis_helpers import assert_follows

import galil
from galil.errors import GalilTimeoutError, InvalidArgument, MotionError
from galil.testing import nothing_sent, sim_of, simulated, transcript
from galil.units import ureg


def _log(dmc: galil.Controller, pattern: str, since: int = 0) -> list[tuple[int, str]]:
    rx = re.compile(pattern)
    return [(k, t) for k, t in sim_of(dmc).command_log if k >= since and rx.fullmatch(t)]


def test_move_to_follows_prediction(dmc: galil.Controller) -> None:
    mm, s = ureg.mm, ureg.s
    x = dmc.A.set_scale(counts_per=2000 / mm)
    x.speed, x.accel, x.decel = 20 * mm / s, 200 * mm / s**2, 300 * mm / s**2
    plan = x.plan_to(12.5 * mm)
    sim = sim_of(dmc)
    t0 = sim.start_trace("A")
    with transcript(dmc) as sent:
        h = x.move_to(12.5 * mm)
    assert sent.lines[-1] == "PAA=25000;BG A;MG TIME{Z10.4}"  # one line: target, begin, stamp
    assert h.kind == "position"
    assert h.axes == "A"
    assert not h.done
    assert h.profile.position.tolist() == plan.position.tolist()
    assert h.duration == pytest.approx(plan.duration)
    r = h.wait()
    trace = sim.stop_trace("A")["A"]
    assert h.done
    assert h.result is r
    assert r.final == {"A": 25000}
    assert r.predicted == {"A": 25000}
    assert r.worst == 0
    assert r.stop_codes == {"A": 1}
    ((bg, _),) = _log(dmc, r"BG A", t0)
    assert h.begin == {"A": bg}
    assert_follows(trace, t0, h.profile, bg)
    assert x.reference_position == 12.5 * mm


def test_several_axes_in_one_line_begin_in_the_same_sample(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    dmc.B.speed = 50_000
    t0 = sim.start_trace()
    with transcript(dmc) as sent:
        h = dmc.move({"A": 3000, "D": -8000, "B": 20_000}, accel=512_000)
    moving = [line for line in sent.lines if not line.startswith("MG _")]
    assert moving == ["AC 512000,512000,,512000;PA 3000,20000,,-8000;BG ABD;MG TIME{Z10.4}"]
    r = h.wait()
    traces = sim.stop_trace()
    assert h.axes == "ABD"
    assert r.final == {"A": 3000, "B": 20_000, "D": -8000}
    assert r.worst == 0
    ((bg, _),) = _log(dmc, r"BG ABD", t0)
    assert set(h.begin.values()) == {bg}
    for a in "ABD":
        assert_follows(traces[a], t0, h.profiles[a], bg)
    plan = dmc.plan({"A": 0, "B": 0}, relative=True)
    assert set(plan) == {"A", "B"}


def test_move_by_with_overrides_and_a_speed_change_in_motion(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("C")
    h = dmc.C.move_by(-40_000, speed=30_000, decel=100_000)
    dmc.sleep(0.3)
    dmc.C.speed = 60_000  # SP in motion: the prediction follows it
    dmc.C.accel = 512_000
    r = h.wait()
    trace = sim.stop_trace("C")["C"]
    assert dmc.C.speed == 60_000
    assert r.final == {"C": -40_000}
    assert r.deviation == {"C": 0}
    assert h.profile.shape == "changed"
    assert_follows(trace, t0, h.profile, h.begin["C"])


def test_jog_with_speed_changes_and_stop(dmc: galil.Controller) -> None:
    mm, s = ureg.mm, ureg.s
    x = dmc.A.set_scale(counts_per=2000 / mm)
    sim = sim_of(dmc)
    t0 = sim.start_trace("A")
    j = x.jog(10 * mm / s)
    assert j.kind == "jog"
    assert j.duration == float("inf")
    dmc.sleep(0.02)  # still ramping: the change must not assume the ramp was complete
    assert x.jog(-5 * mm / s) is j
    dmc.sleep(0.5)
    assert x.velocity.to(mm / s).magnitude == pytest.approx(-5, rel=0.01)
    x.jog_speed = 7 * mm / s  # the setter changes speed in motion too
    dmc.sleep(0.4)
    j.stop()
    assert j.duration < float("inf")
    r = j.wait()
    trace = sim.stop_trace("A")["A"]
    assert r.stop_codes == {"A": 4}
    assert r.predicted == r.final
    assert r.worst == 0
    assert_follows(trace, t0, j.profile, j.begin["A"])
    with pytest.raises(GalilTimeoutError):
        dmc.B.jog(1000).wait(timeout=0.2)
    dmc.stop("B")


def test_jog_refused_during_a_position_move(dmc: galil.Controller) -> None:
    dmc.A.move_by(50_000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="stop it"):
        dmc.A.jog(1000)
    dmc.A.stop()
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="moving"):
        dmc.A.move_to(0)


def test_increment_idle_is_a_relative_move(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("B")
    with transcript(dmc) as sent:
        h = dmc.B.increment(7000)
    assert sent.lines[-1] == "IPB=7000;MG TIME{Z10.4}"
    r = h.wait()
    assert r.final == {"B": 7000}
    assert r.worst == 0
    assert_follows(sim.stop_trace("B")["B"], t0, h.profile, h.begin["B"])


def test_increment_during_a_move_extends_it(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("A")
    h = dmc.A.move_by(20_000)
    dmc.sleep(0.25)
    assert dmc.A.increment(5000) is h
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 16"):
        dmc.A.increment(-3000)  # a reversal: the controller would refuse it
    r = h.wait()
    assert r.final == {"A": 25_000}
    assert r.predicted == {"A": 25_000}
    assert_follows(sim.stop_trace("A")["A"], t0, h.profile, h.begin["A"])


def test_increment_against_a_move_in_its_last_samples_is_refused_unsent(
    dmc: galil.Controller,
) -> None:
    # In a move's last samples _RP reads the target already (the profile's fraction is
    # still moving); the controller still takes IP's sign against the move's (TC 16).
    h = dmc.A.move_by(-4953)
    for _ in range(400):
        dmc.sleep(dmc.link.sample_period)
        rp, pa, bg = dmc.link.query_operands(["_RPA", "_PAA", "_BGA"])
        if rp == pa:
            break
    assert (rp, pa, bg) == (-4953, -4953, 1)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="ending"):
        dmc.A.increment(5)
    assert dmc.A.increment(-5) is h  # the move's own way is taken
    assert h.wait().final == {"A": -4958}


def test_increment_while_jogging_and_while_stopping(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("D")
    j = dmc.D.jog(-20_000)
    dmc.sleep(0.3)
    assert dmc.D.increment(-1500) is j
    dmc.sleep(0.1)
    dmc.D.stop()
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="stopping"):
        dmc.D.increment(-100)
    r = j.wait()
    assert r.worst == 0
    assert r.predicted == r.final
    assert_follows(sim.stop_trace("D")["D"], t0, j.profile, j.begin["D"])


def test_controller_stop_and_abort(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace()
    h = dmc.move({"A": 100_000, "B": -100_000})
    j = dmc.C.jog(30_000)
    dmc.sleep(0.3)
    dmc.stop()
    r, rj = h.wait(), j.wait()
    assert r.stop_codes == {"A": 4, "B": 4}
    assert rj.stop_codes == {"C": 4}
    assert r.worst == 0
    assert rj.worst == 0
    assert set(r.predicted) == {"A", "B"}
    traces = sim.stop_trace()
    for a in "AB":
        assert_follows(traces[a], t0, h.profiles[a], h.begin[a])
    t1 = sim.start_trace("A")
    h = dmc.A.move_by(50_000)
    dmc.sleep(0.2)
    dmc.abort()
    r = h.wait()
    assert r.stop_codes == {"A": 7}
    assert r.worst == 0
    assert h.profile.stop_code == 7
    assert_follows(sim.stop_trace("A")["A"], t1, h.profile, h.begin["A"])


def test_handle_progress_and_callbacks(
    dmc: galil.Controller, capsys: pytest.CaptureFixture[str]
) -> None:
    seen: list[galil.MoveHandle] = []
    called = threading.Event()
    h = dmc.A.move_by(30_000)
    h.add_callback(seen.append)
    h.add_callback(lambda _h: called.set())
    r = h.wait(progress=True)
    assert called.wait(5)
    assert seen == [h]
    assert r is h.result
    later: list[galil.MoveHandle] = []
    h.add_callback(later.append)  # already done: called at once
    assert later == [h]
    err = capsys.readouterr().err
    assert "position A" in err
    assert "100%" in err
    j = dmc.B.jog(5000)
    dmc.sleep(0.1)
    j.stop()
    j.wait(progress=True)  # a jog has no total: the bar counts seconds
    assert "jog B" in capsys.readouterr().err
    assert "done" in repr(h)


def test_limit_switch_stops_a_move_with_motion_error(dmc: galil.Controller) -> None:
    h = dmc.A.move_by(100_000)
    dmc.sleep(0.1)
    sim_of(dmc).set_limit_switch("A", "forward", True)
    with pytest.raises(galil.MotionError, match="FWD limit") as info:
        h.wait()
    assert info.value.axis == "A"
    assert info.value.stop_codes == {"A": 2}
    assert not isinstance(info.value, galil.LimitError)  # it moved: not a refusal
    assert h.result is not None
    assert h.result.stop_codes == {"A": 2}
    assert "A" not in h.result.predicted  # a limit is not something the prediction knew


def test_motor_off_refused(dmc: galil.Controller) -> None:
    dmc.motor_off("B")
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="motor off"):
        dmc.B.move_by(100)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="motor off"):
        dmc.B.jog(100)


@pytest.mark.parametrize("axes", ["B", "", "AB"])
def test_motor_off_on_a_moving_axis_is_refused_before_mo_goes_out(
    dmc: galil.Controller, axes: str
) -> None:
    jog = dmc.B.jog(3000)
    refused = pytest.raises(InvalidArgument, match=r"B moving.*MO in motion \(TC 7\).*stop")
    with nothing_sent(dmc, allow_queries=True) as sent, refused:
        dmc.motor_off(axes)
    assert len(sent.lines) == 1  # the one state query
    assert dmc.A.motor_on
    assert dmc.B.motor_on
    jog.stop()
    jog.wait()
    dmc.motor_off(axes)  # at rest: it goes out
    assert not dmc.B.motor_on


def test_a_stop_the_library_did_not_send_is_a_motion_error_with_the_result_kept() -> None:
    with simulated("DMC-4040") as dmc:
        handle = dmc.A.move_by(20_000)
        dmc.sleep(0.1)
        dmc.link.command_line(["ST A"])  # behind the library's back (decision 0105)
        with pytest.raises(MotionError, match=r"A by ST \(stop code 4\) at \d+ counts"):
            handle.wait()
        final = dmc.A.reference_position
        result = handle.result
        assert result is not None
        assert result.final == {"A": final}
        assert result.predicted == {}  # (not where the prediction ends: no deviation)
        assert result.stop_codes == {"A": 4}


@pytest.mark.parametrize("start", ["home", "find_edge", "find_index"])
def test_an_increment_during_homing_is_refused_before_sending(
    dmc: galil.Controller, start: str
) -> None:
    # (the controller refuses IP during HM/FE/FI, TC 16: it went out and came back as a
    # CommandError)
    dmc.A.home_speed = 2000
    homing = getattr(dmc.A, start)(switch=sim_of(dmc).home_switch("A"))
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 16"):
        dmc.A.increment(5)
    homing.wait()


def test_a_jog_aborted_after_its_ramp_is_predicted_to_the_abort(dmc: galil.Controller) -> None:
    # (the jog's profile ended once at speed; the abort cut it there, not at the AB's sample)
    jog = dmc.A.jog(-30000)
    dmc.sleep(0.2)  # at speed after 0.12 s
    dmc.abort()
    result = jog.wait(timeout=1.0)
    assert result.stop_codes == {"A": 7}
    assert result.deviation == {"A": 0}
    assert result.final["A"] < -3000


def test_settings_not_valid_in_motion_are_refused_unsent_while_the_librarys_move_runs(
    dmc: galil.Controller,
) -> None:
    a = dmc.A
    a.speed, a.accel, a.decel = 20_000, 1_024_000, 1_024_000
    move = a.move_by(100_000)  # 5 s
    for setting, value in (("decel", 512_000), ("motor_type", 1), ("brush", 1)):
        with (
            nothing_sent(dmc, allow_queries=True) as sent,
            pytest.raises(InvalidArgument, match=r"(DC|MT|BR) is not valid while axis A moves"),
        ):
            setattr(a, setting, value)
        assert sent.lines == ["MG _BGA,_RPA,_SCA"]  # (one read: no limit ended it)
    # What the reference allows in motion still goes out (and the move follows SP and AC).
    a.speed, a.accel, a.smoothing, a.kp = 30_000, 2_048_000, 1, 6
    a.soft_limits = (None, None)
    assert move.wait().deviation == {"A": 0}
    a.decel = 512_000  # at rest: it goes out
    assert a.decel == 512_000


def test_a_decel_change_goes_out_in_a_jog_and_once_a_move_is_over_by_its_prediction(
    dmc: galil.Controller,
) -> None:
    a = dmc.A
    move = a.move_by(1000)
    dmc.sleep(1.0)  # over, unwaited: the library does not know, its prediction does
    a.decel = 512_000
    assert move.wait().deviation == {"A": 0}
    jog = a.jog(5000)
    # The reference allows DC in a jog: it goes out, stamped, and the controller takes it.
    with transcript(dmc) as sent:
        a.decel = 256_000
    assert sent.lines == ["DCA=256000;MG TIME{Z10.4}"]
    assert a.decel == 256_000
    jog.stop()
    assert jog.wait().deviation == {"A": 0}


def test_a_jogs_ramps_down_follow_a_decel_changed_in_motion(dmc: galil.Controller) -> None:
    a, sim = dmc.A, sim_of(dmc)
    a.accel, a.decel = 512_000, 512_000
    t0 = sim.start_trace("A")
    jog = a.jog(40_000)
    dmc.sleep(0.2)
    a.decel = 102_400  # the ramp down to the lower speed takes 0.29 s, not 0.06 s
    a.jog_speed = 10_000
    dmc.sleep(0.1)  # mid-ramp: a new DC re-plans the rest of it
    a.decel = 20_480
    dmc.sleep(0.3)
    a.decel = 1_024_000  # the stop's rate
    jog.stop()
    result = jog.wait()
    assert result.stop_codes == {"A": 4}
    assert result.deviation == {"A": 0}
    assert_follows(sim.stop_trace("A")["A"], t0, jog.profile, jog.begin["A"])
    # (at DC 512,000 it would be at 10,000 counts/s from 0.26 s on)
    assert jog.profile.velocity[round(0.55 * 1024)] > 20_000


def test_a_decel_change_while_an_st_ramps_a_move_down_re_plans_the_stop(
    dmc: galil.Controller,
) -> None:
    a, sim = dmc.B, sim_of(dmc)
    a.speed, a.accel, a.decel = 50_000, 512_000, 51_200
    t0 = sim.start_trace("B")
    move = a.move_by(200_000)
    dmc.sleep(0.3)
    move.stop()  # a 1 s ramp at DC 51200
    dmc.sleep(0.1)
    with transcript(dmc) as sent:
        a.decel = 512_000  # "directly following an axis stop ... while still decelerating"
    assert sent.lines == ["DCB=512000;MG TIME{Z10.4}"]
    result = move.wait()
    assert result.stop_codes == {"B": 4}
    assert result.deviation == {"B": 0}
    assert move.duration < 0.6
    assert_follows(sim.stop_trace("B")["B"], t0, move.profile, move.begin["B"])


def test_a_decel_change_in_a_position_move_is_refused_unsent_and_by_the_controller(
    dmc: galil.Controller,
) -> None:
    move = dmc.C.move_by(50_000)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match="DC is not valid"),
    ):
        dmc.C.decel = 512_000
    with pytest.raises(galil.CommandError) as refused:
        dmc.command("DCC=512000")  # (the library's refusal is the controller's)
    assert refused.value.code == 7
    assert move.wait().deviation == {"C": 0}


def test_a_decel_change_goes_out_while_a_limit_the_library_has_not_seen_stops_its_move(
    dmc: galil.Controller,
) -> None:
    # DMC-4103 reference, DC: "directly following an axis stop (i.e. ST m or a limit switch),
    # the DC value of a PA or PR move may be changed while the axis is still decelerating".
    a, sim = dmc.A, sim_of(dmc)
    a.speed, a.accel, a.decel = 50_000, 1_024_000, 102_400  # a limit's stop takes ~0.5 s
    move = a.move_by(1_000_000)  # 20 s by its prediction
    dmc.sleep(0.5)
    sim.set_limit_switch("A", "forward", True)  # (no poll since: the handle does not know)
    dmc.sleep(0.1)
    with transcript(dmc) as sent:
        a.decel = 1_024_000  # the rest of the ramp at the new rate
    assert sent.lines[0] == "MG _BGA,_RPA,_SCA"  # one read, as the refusal would have made
    assert sent.lines[1].startswith("DCA=1024000")
    dmc.sleep(0.1)  # (at 102400 counts/s² the ramp would last another 0.4 s)
    assert not a.moving
    with pytest.raises(galil.MotionError, match="FWD limit") as info:
        move.wait()
    assert info.value.stop_codes == {"A": 2}
    assert a.decel == 1_024_000


def test_a_decel_change_goes_out_once_a_limit_the_library_has_not_seen_ended_its_move(
    dmc: galil.Controller,
) -> None:
    a, sim = dmc.A, sim_of(dmc)
    move = a.move_by(-1_000_000)
    dmc.sleep(0.2)
    sim.set_limit_switch("A", "reverse", True)
    dmc.sleep(0.5)  # at rest on the switch; the prediction still has it moving
    with transcript(dmc) as sent:
        a.decel = 512_000
    assert sent.lines == ["MG _BGA,_RPA,_SCA", "DCA=512000"]
    assert a.decel == 512_000
    with pytest.raises(galil.MotionError, match="REV limit") as info:
        move.wait()  # (the end that read saw: the handle reports it)
    assert info.value.stop_codes == {"A": 3}


def test_a_decel_change_is_refused_unsent_while_a_stop_ramps_a_vector_sequence_down(
    dmc: galil.Controller,
) -> None:
    # DC may change in a stop's ramp of a PA or PR move only: a sequence ramps down at VD, and
    # the controller answers DC on its axes with TC 7 until it is over (decision 0043). A
    # random operation sequence found the library letting it out on the stop code 4 alone.
    run = dmc.vector_move("AB", [galil.Line(50_000, 0)], speed=20_000)
    dmc.sleep(0.5)
    dmc.stop("")
    with transcript(dmc) as sent, pytest.raises(galil.InvalidArgument, match="DC"):
        dmc.A.decel = 20_480
    assert sent.lines == ["MG _BGA,_RPA,_SCA"]  # (the one read; it still moves, code 4)
    run.wait()
    with transcript(dmc) as sent:
        dmc.A.decel = 20_480  # at rest: taken, nothing read first
    assert sent.lines == ["DCA=20480"]


def test_motor_type_is_refused_unsent_while_the_motor_is_on(dmc: galil.Controller) -> None:
    # DMC-4103 reference, MT: "The axis must be in the motor off state (MO) before setting MT".
    a = dmc.A
    with (
        nothing_sent(dmc, allow_queries=True) as sent,
        pytest.raises(InvalidArgument, match=r"MT needs axis A's motor off"),
    ):
        a.motor_type = galil.MotorType.STEPPER_ACTIVE_LOW
    assert sent.lines == ["MG _MOA"]
    assert a.motor_type is galil.MotorType.SERVO
    dmc.motor_off("A")
    a.motor_type = galil.MotorType.STEPPER_ACTIVE_LOW
    assert a.motor_type is galil.MotorType.STEPPER_ACTIVE_LOW
    dmc.servo_here("A")
    assert a.motor_on
