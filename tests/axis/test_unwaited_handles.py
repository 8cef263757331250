"""A handle nobody waited for keeps its own move's end when other motion starts on its axes.

Found by the sequence fuzz (tests/test_operation_sequences.py): the start of the next motion
reads the axis at rest, so the earlier move is over there; a later ``wait()`` on its handle
reported the next motion's end instead (and warned of a deviation it never had), or, once the
axis followed a master, never ended at all.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil import Line
from galil.testing import sim_of

_NEXT: dict[str, Callable[[galil.Controller], object]] = {
    "move": lambda dmc: dmc.A.move_by(500),
    "jog": lambda dmc: dmc.A.jog(3000),
    "schedule": lambda dmc: dmc.A.speed_schedule(4000, [(2000, 5000)], speed=10000),
    "home": lambda dmc: dmc.A.find_edge(switch=sim_of(dmc).home_switch("A")),
    "vector": lambda dmc: dmc.vector_move("AB", [Line(700, 300)], speed=20000),
    "gearing": lambda dmc: dmc.A.gear_to("C", 2),
    "contour": lambda dmc: dmc.contour("A", np.linspace(0, 300, 8), dt=3),
}


@pytest.mark.parametrize("following", list(_NEXT))
def test_waiting_late_for_a_move_reports_its_own_end_not_the_next_motions(
    dmc: galil.Controller, following: str
) -> None:
    first = dmc.A.move_by(1000)
    dmc.sleep(1.0)  # over, but nobody looked
    _NEXT[following](dmc)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (no deviation warning either)
        result = first.wait(timeout=1.0)
    assert result.final == {"A": 1000}
    assert result.deviation == {"A": 0}
    assert result.stop_codes == {"A": 1}


def test_a_late_wait_keeps_the_end_the_first_start_after_it_read(dmc: galil.Controller) -> None:
    first = dmc.A.move_by(1000)
    dmc.sleep(1.0)
    dmc.contour("A", np.linspace(0, 300, 8), dt=3)  # (no handle of its own: first stays)
    dmc.A.move_by(200).wait()  # (this start reads A at rest too, at 1300)
    assert first.wait(timeout=1.0).final == {"A": 1000}


def test_a_late_wait_keeps_the_stop_code_of_a_limit_that_ended_the_move(
    dmc: galil.Controller,
) -> None:
    sim_of(dmc).place_limit_switches("A", forward=600)
    first = dmc.A.move_by(1000)
    dmc.sleep(1.0)
    dmc.A.move_by(-200)  # away from the switch
    with pytest.raises(galil.MotionError) as caught:
        first.wait(timeout=1.0)
    assert caught.value.stop_codes == {"A": 2}


def _schedule(axis: galil.Axis) -> galil.MoveHandle:
    return axis.speed_schedule(-12_000, [(4000, 8000), (8000, 3000)], speed=15_000)


def _time(dmc: galil.Controller) -> int:
    return round(dmc.query_operands(["TIME"])[0])


@pytest.mark.parametrize("following", list(_NEXT))
def test_a_late_wait_on_a_speed_schedule_reports_its_own_end_when_nobody_read_its_begin(
    dmc: galil.Controller, following: str
) -> None:
    first = _schedule(dmc.A)
    dmc.sleep(3.0)  # over, but nobody looked (nor read its begin)
    _NEXT[following](dmc)
    result = first.wait(timeout=1.0)
    assert result.final == {"A": -12_000}
    assert result.stop_codes == {"A": 1}


def test_a_speed_schedules_begin_stays_its_own_after_the_next_schedule_starts(
    dmc: galil.Controller,
) -> None:
    before_a = _time(dmc)
    first = _schedule(dmc.A)
    first.wait()
    before_b = _time(dmc)
    second = _schedule(dmc.B)
    second.wait()
    begin_a, begin_b = first.begin["A"], second.begin["B"]
    assert begin_a is not None
    assert begin_b is not None
    assert before_a <= begin_a < before_b <= begin_b


def test_a_late_stop_of_a_vector_sequence_leaves_the_gearing_on_its_axis_engaged(
    dmc: galil.Controller,
) -> None:
    sequence = dmc.vector_move("CD", [Line(0, 1)], speed=20000)
    dmc.sleep(1.0)  # over, but nobody looked
    dmc.C.gear_to("A", -1.5)
    sequence.stop()  # (ST S: the sequence is over, the gearing runs on)
    master = dmc.A.move_by(1000)
    assert master.followers == "C"
    assert master.wait().follower_final == {"C": -1500}


def test_a_late_stop_of_a_vector_sequence_leaves_a_jog_on_its_axis_running(
    dmc: galil.Controller,
) -> None:
    sequence = dmc.vector_move("CD", [Line(0, 1)], speed=20000)
    dmc.sleep(1.0)
    jog = dmc.C.jog(3000)
    sequence.stop()
    dmc.sleep(0.5)
    assert math.isinf(jog.duration)
    assert dmc.query_operands(["_BGC"]) == [1.0]
    jog.stop()
    assert jog.wait().stop_codes == {"C": 4}


def test_a_change_after_a_tm_change_leaves_an_unseen_stopped_jog_predicted_at_its_own_tm(
    dmc: galil.Controller,
) -> None:
    dmc.command("TM 250")
    jog = dmc.C.jog(-30000)
    ran_at = jog.profile.sample_period
    dmc.sleep(0.02)
    dmc.stop("C")
    dmc.sleep(1.0)  # over, but nobody looked
    dmc.command("TM 500")
    dmc.C.accel = 20480  # (re-predicts the jog: at the TM it ran at)
    assert jog.profile.sample_period == ran_at
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert jog.wait().deviation == {"C": 0}


def test_a_change_after_a_stopped_jogs_end_leaves_its_prediction_as_it_was(
    dmc: galil.Controller,
) -> None:
    jog = dmc.C.jog(-30000)
    dmc.sleep(0.02)
    dmc.stop("C")
    before = jog.profile
    dmc.sleep(1.0)  # over, but nobody looked
    dmc.C.accel = 20480
    assert jog.profile.samples == before.samples
    assert jog.duration == before.duration < 0.1


def _sent(dmc: galil.Controller, since: int) -> list[str]:
    return [text for _, text in list(sim_of(dmc).command_log)[since:]]


@pytest.mark.parametrize("plane", ["AB", "CD"])
@pytest.mark.parametrize("waited", [False, True])
def test_a_late_stop_of_a_vector_sequence_leaves_the_sequence_running_since_alone(
    dmc: galil.Controller, plane: str, waited: bool
) -> None:
    first = dmc.vector_move("AB", [Line(0, 1)], speed=20000)
    dmc.sleep(1.0)  # over (waited for, or nobody looked)
    if waited:
        first.wait()
    second = dmc.vector_move(plane, [Line(20000, 0)], speed=20000)
    dmc.sleep(0.1)
    before = len(sim_of(dmc).command_log)
    first.stop()  # (over: no ST S, which would reach the sequence on S now)
    assert not any(text.startswith("ST") for text in _sent(dmc, before))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = second.wait()
    assert set(result.stop_codes.values()) == {101}
    assert result.worst == 0
    assert first.wait().stop_codes == {"A": 101, "B": 101}


@pytest.mark.parametrize("waited", [False, True])
def test_a_late_stop_of_a_move_leaves_the_move_started_since_on_its_axis_running(
    dmc: galil.Controller, waited: bool
) -> None:
    old = dmc.A.move_by(1000)
    dmc.sleep(1.0)  # over (waited for, or nobody looked)
    if waited:
        old.wait()
    new = dmc.A.move_by(50_000)
    dmc.sleep(0.2)
    before = len(sim_of(dmc).command_log)
    old.stop()  # its axis moved on to the newer move: nothing is sent
    assert not any(text.startswith("ST") for text in _sent(dmc, before))
    result = new.wait()
    assert result.final == {"A": 51_000}
    assert result.stop_codes == {"A": 1}


def test_a_stop_of_a_move_not_waited_for_stops_only_the_axes_no_newer_move_took(
    dmc: galil.Controller,
) -> None:
    old = dmc.move({"A": 1000, "B": 100_000})  # A done within 1 s, B runs on
    dmc.sleep(1.0)
    new = dmc.A.move_by(50_000)  # (reads A at rest: A's part of the old move is over)
    dmc.sleep(0.2)
    before = len(sim_of(dmc).command_log)
    old.stop()  # (B: not seen done, so when in doubt, stopped)
    assert [t for t in _sent(dmc, before) if t.startswith("ST")] == ["ST B"]
    assert old.wait().stop_codes == {"A": 1, "B": 4}
    assert new.wait().stop_codes == {"A": 1}


@pytest.mark.parametrize("jog", [False, True])
def test_servo_here_after_an_abort_turned_the_motor_off_leaves_the_handle_its_own_end(
    dmc: galil.Controller, jog: bool
) -> None:
    # SH puts the reference where the encoder is (behind it after the abort): a late wait
    # reported that as where the move ended, and warned of a deviation it never had.
    a = dmc.A
    a.off_on_error = 1
    a.speed = 20_000
    sim_of(dmc).set_servo_lag(0.01, "A")
    handle = a.jog(20_000) if jog else a.move_by(100_000)
    dmc.sleep(0.5)
    dmc.abort()
    dmc.sleep(0.1)
    assert not a.motor_on
    end = round(dmc.query_operands(["_RPA"])[0])
    dmc.servo_here("A")
    assert a.motor_on
    assert round(dmc.query_operands(["_RPA"])[0]) != end  # SH moved the reference
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no deviation warning
        result = handle.wait(timeout=1.0)
    assert result.final == {"A": end}
    assert result.deviation == {"A": 0}
    assert result.stop_codes == {"A": 7}  # the abort's
