"""An axis geared to a contour or vector-path axis that a limit stops on the way (a placed
limit switch; the controller turns its gearing off) is reported by the contour or the path
itself, once its own motion is over, with the error ``MoveHandle.wait`` raises for a dropped
follower, and the library forgets that gearing there (decision 0049): not only at the
master's next start (``refuse_dropped``).
"""

from __future__ import annotations

import numpy as np
import pytest

import galil
from galil import Line
from galil.errors import MotionError
from galil.testing import sim_of, transcript


def _ramp(to: float, segments: int) -> np.ndarray:
    return np.linspace(to / segments, to, segments)


def _check_dropped(err: MotionError, dmc: galil.Controller, master: str) -> None:
    assert err.axis == "C"
    assert err.stop_codes["C"] == 2
    assert err.position == dmc.C.reference_position
    text = err.args[0]  # (str() adds the recent exchange)
    assert text.startswith(f"a follower stopped early (C, geared to {master}: ")
    assert text.endswith("; its gearing is off)")


@pytest.mark.parametrize("segments", [40, 1500])  # sent whole; still streaming at the switch
def test_a_contour_reports_a_follower_a_limit_switch_stopped_at_its_end_and_forgets_it(
    dmc: galil.Controller, segments: int
) -> None:
    sim = sim_of(dmc)
    gearing = dmc.C.gear_to("A", 2)
    sim.place_limit_switches("C", forward=1000)  # C would reach 2000
    with pytest.raises(MotionError) as caught:
        dmc.contour("A", _ramp(1000, segments), dt=1)
    _check_dropped(caught.value, dmc, "A")
    assert caught.value.stop_codes["A"] == 51  # the contour itself ran to its end
    assert dmc.A.reference_position == 1000
    assert 1000 <= dmc.C.reference_position < 2000
    assert not gearing.engaged
    c_at = dmc.C.reference_position
    dmc.contour("A", -_ramp(500, 40), dt=1)  # the master alone now: no stale report
    assert dmc.C.reference_position == c_at


def test_the_same_contour_of_the_same_error_as_a_move_of_the_master(
    dmc: galil.Controller,
) -> None:
    sim = sim_of(dmc)
    sim.place_limit_switches("C", forward=1000)
    dmc.C.gear_to("A", 2)
    with pytest.raises(MotionError) as moved:
        dmc.A.move_by(1000).wait()
    dmc.C.move_to(0).wait()
    dmc.A.move_to(0).wait()
    dmc.C.gear_to("A", 2)
    with pytest.raises(MotionError) as streamed:
        dmc.contour("A", _ramp(1000, 40), dt=4)
    assert type(streamed.value) is type(moved.value)
    assert streamed.value.args[0] == moved.value.args[0]
    _check_dropped(streamed.value, dmc, "A")  # (where C stopped: on A's speed at the switch)


def test_a_contour_whose_follower_still_follows_reports_nothing_and_costs_no_exchange(
    dmc: galil.Controller,
) -> None:
    with transcript(dmc) as alone:
        dmc.contour("A", _ramp(1000, 40), dt=4)
    dmc.A.move_to(0).wait()
    gearing = dmc.C.gear_to("A", 2)
    with transcript(dmc) as geared:
        result = dmc.contour("A", _ramp(1000, 40), dt=4)
    assert len(geared.lines) == len(alone.lines)  # the followers ride on the same polls
    assert result.increments.sum() == 1000
    assert gearing.engaged
    assert dmc.C.reference_position == 2000


def test_a_vector_path_reports_a_follower_of_a_path_axis_a_limit_switch_stopped(
    dmc: galil.Controller,
) -> None:
    sim = sim_of(dmc)
    gearing = dmc.C.gear_to("A", 2)
    sim.place_limit_switches("C", forward=1000)
    h = dmc.vector_move("AB", [Line(1000, 500)], speed=20_000)
    with pytest.raises(MotionError) as caught:
        h.wait()
    _check_dropped(caught.value, dmc, "A")
    assert caught.value.stop_codes == {"A": 101, "B": 101, "C": 2}
    assert not gearing.engaged


@pytest.mark.parametrize("segments", [200, 3000])  # sent whole; still streaming at the stop
def test_a_contour_a_switch_stops_names_a_follower_a_limit_stopped_before_and_forgets_it(
    dmc: galil.Controller, segments: int
) -> None:
    sim = sim_of(dmc)
    gearing = dmc.C.gear_to("A", 2)
    sim.place_limit_switches("C", forward=1000)  # reached with A at 500
    sim.place_limit_switches("A", forward=2000)  # then the contour's own stop
    with pytest.raises(MotionError, match="stopped by the controller") as caught:
        dmc.contour("A", _ramp(4000, segments), dt=1)
    err = caught.value
    assert err.axis == "A"
    assert err.stop_codes == {"A": 2, "C": 2}
    assert err.position == dmc.A.reference_position
    assert err.args[0].endswith(
        "(A: Decelerating or stopped by FWD limit switch or soft limit FL; C, geared to A: "
        "Decelerating or stopped by FWD limit switch or soft limit FL; its gearing is off)"
    )
    assert not gearing.engaged
    dmc.contour("A", -_ramp(500, 40), dt=1)  # the master alone now: no stale report
