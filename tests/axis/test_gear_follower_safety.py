"""Axes geared to a moving master: refused before sending when the master's path would take
them past their soft limits or the SP maximum (vector paths, contours, speed schedules), homing
a master refused while anything follows it, and a follower stopped by a limit reported by the
master's handle.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil import Line
from galil.errors import InvalidArgument, LimitError, MotionError
from galil.sim.rooms.gearing import GearFeed
from galil.testing import nothing_sent, sim_of, transcript


# -- vector paths ---------------------------------------------------------------------------
@pytest.mark.parametrize("master", ["A", "S"])
def test_a_vector_move_taking_a_follower_past_its_soft_limit_is_refused(
    dmc: galil.Controller, master: str
) -> None:
    dmc.C.soft_limits = (-1000, 1000)
    dmc.C.gear_to(master, 2)
    path = [Line(2000, 1000)]  # C: 2 x 2000 along A, 2 x 2236 along the path
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.vector_move("AB", path, speed=5000)
    assert caught.value.axis == "C"
    assert caught.value.name == "FL"
    assert f"geared to {master}" in str(caught.value)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="axis C"):
        dmc.plan_vector("AB", path, speed=5000)
    h = dmc.vector_move("AB", [Line(200, 100)], speed=5000)  # C stays inside
    h.wait()
    assert dmc.C.reference_position == h.profiles["C"].end


def test_a_vector_move_driving_a_follower_too_fast_is_refused(dmc: galil.Controller) -> None:
    dmc.C.gear_to("A", 100)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.vector_move("AB", [Line(1_000_000, 0)], speed=250_000)  # C at 25 M counts/s
    assert caught.value.axis == "C"
    assert caught.value.name == "speed"


# -- contours -------------------------------------------------------------------------------
def test_a_contour_taking_a_follower_past_its_soft_limit_is_refused(
    dmc: galil.Controller,
) -> None:
    dmc.A.soft_limits = (-1000, 1000)
    dmc.A.gear_to("B", 2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.contour("B", np.linspace(0, 2000, 40), dt=4)  # A to 4000
    assert caught.value.axis == "A"
    assert caught.value.name == "FL"
    assert "geared to B" in str(caught.value)
    dmc.contour("B", np.linspace(0, 500, 40), dt=4)  # A to 1000: on its limit
    assert dmc.query_operands(["_RPA", "_RPB", "_SCA"]) == [1000, 500, 0]


def test_a_contour_driving_a_follower_too_fast_is_refused(dmc: galil.Controller) -> None:
    dmc.A.gear_to("B", 100)
    path = np.arange(1, 41) * 4000.0  # B at 4000 counts per 16 samples: A at 25.6 M counts/s
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.contour("B", path, dt=4)
    assert caught.value.axis == "A"
    assert caught.value.name == "speed"


# -- speed schedules ------------------------------------------------------------------------
def test_a_speed_schedule_taking_a_follower_past_its_soft_limit_is_refused(
    dmc: galil.Controller,
) -> None:
    dmc.A.soft_limits = (-10_000, 10_000)
    dmc.A.gear_to("B", 2)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as caught:
        dmc.B.speed_schedule(15_000, [(5000, 10_000)], speed=20_000)  # A to 30 000
    assert caught.value.axis == "A"
    assert caught.value.name == "FL"
    h = dmc.B.speed_schedule(5000, [(2500, 10_000)], speed=20_000)  # A to 10 000: on it
    assert h.followers == "A"  # predicted with its master
    assert h.profiles["A"].end == 10_000
    h.wait()
    assert dmc.A.reference_position == 10_000


# -- homing ---------------------------------------------------------------------------------
@pytest.mark.parametrize("start", ["home", "find_edge", "find_index"])
def test_homing_a_gear_master_is_refused_while_an_axis_follows_it(
    dmc: galil.Controller, start: str
) -> None:
    dmc.B.jog_speed = 2000
    gearing = dmc.A.gear_to("B", 2)
    switch = sim_of(dmc).home_switch("B")
    with nothing_sent(dmc), pytest.raises(InvalidArgument) as caught:
        getattr(dmc.B, start)(switch=switch)
    assert "gear master of A" in str(caught.value)
    gearing.off()
    getattr(dmc.B, start)(switch=switch).wait(timeout=60)
    assert dmc.A.reference_position == 0  # A stayed where it was


def test_homing_a_geared_axis_is_refused(dmc: galil.Controller) -> None:
    dmc.A.gear_to("B", 2)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="axis A is geared to B"):
        dmc.A.home()


@pytest.mark.parametrize(
    ("move", "what"),
    [
        (lambda ax: ax.jog(1000), "jogging it"),
        (lambda ax: ax.increment(10), "an increment"),
        (lambda ax: ax.move_by(100), "moving it"),
    ],
)
def test_moving_a_geared_axis_by_itself_is_refused_as_geared_before_sending(
    dmc: galil.Controller, move: Callable[[galil.Axis], object], what: str
) -> None:
    # (a follower reads _BG 1: the jog said "in another move", and IP went out for TC 141)
    dmc.A.gear_to("B", 2)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match=f"geared to B.*before {what}"):
        move(dmc.A)


# -- a follower stopped by a limit ----------------------------------------------------------
def test_wait_reports_a_follower_stopped_by_its_soft_limit(dmc: galil.Controller) -> None:
    dmc.A.soft_limits = (-1000, 1000)
    gearing = dmc.A.gear_to("B", 2)
    jog = dmc.B.jog(1000)  # a jog has no end to check: A runs into its FL on the controller
    dmc.sleep(1.0)
    jog.stop()
    with pytest.raises(MotionError) as caught:
        jog.wait()
    err = caught.value
    assert err.axis == "A"
    assert err.stop_codes["A"] == 2
    assert err.position is not None
    assert err.position > 1000
    assert "geared to B" in str(err)
    assert not gearing.engaged  # the controller turned the gearing off: so does the library
    assert jog.result is not None
    assert jog.result.follower_stop_codes == {"A": 2}
    r = dmc.B.move_by(-100).wait()  # A does not follow any more: nothing more to report
    assert r.follower_stop_codes == {}


def test_wait_reports_a_follower_of_a_vector_path_stopped_by_a_limit(
    dmc: galil.Controller,
) -> None:
    dmc.C.gear_to("S", 1)
    h = dmc.vector_move("AB", [Line(3000, 4000)], speed=5000)
    dmc.C.soft_limits = (-1000, 1000)  # tightened after the check, while C follows
    with pytest.raises(MotionError) as caught:
        h.wait()
    assert caught.value.axis == "C"
    assert caught.value.stop_codes == {"A": 101, "B": 101, "C": 2}


@pytest.mark.parametrize("master", ["A", "S"])
def test_stopping_a_follower_leaves_the_vector_path_it_followed_running_as_predicted(
    dmc: galil.Controller, master: str
) -> None:
    # ST C turns C's gearing off and nothing else: the sequence runs to its end (101). The
    # handle took the follower's stop for a stop of the sequence and predicted it over at
    # once (0 s, no motion), then reported its whole path as a deviation (a random operation
    # sequence found it through an old handle of C whose stop() sent the ST).
    dmc.C.gear_to(master, -1.5)
    h = dmc.vector_move("AB", [Line(0, 3400), Line(-3400, 0)], speed=20_000)
    duration = h.duration
    dmc.sleep(0.1)
    dmc.stop("C")
    assert h.duration == duration
    r = h.wait()
    assert r.stop_codes == {"A": 101, "B": 101}
    assert r.deviation == {"A": 0, "B": 0}
    assert r.follower_stop_codes == {"C": 4}
    assert r.follower_final["C"] == round(h.profiles["C"].position[-1])


def test_a_follower_that_still_follows_is_not_an_error(dmc: galil.Controller) -> None:
    dmc.A.gear_to("B", 2)
    r = dmc.B.move_by(400).wait()
    assert r.follower_final == {"A": 800}
    assert r.follower_stop_codes == {"A": 0}


# -- a follower a limit dropped during a move nobody waited for -----------------------------
def _drop_follower_unawaited(dmc: galil.Controller, limit: str) -> galil.Gearing:
    """A geared to B at 2; a move of B that nobody waits for takes A into a limit (a soft
    limit tightened after the move's check, or a limit switch pressed on the way), which
    turns A's gearing off."""
    gearing = dmc.A.gear_to("B", 2)
    dmc.B.move_by(1000)  # A to 2000: not waited for
    if limit == "soft":
        dmc.A.soft_limits = (-1000, 1000)
    else:
        dmc.sleep(0.01)
        sim_of(dmc).set_limit_switch("A", "forward", True)
    dmc.sleep(2.0)
    assert dmc.query_operands(["_BGB", "_SCA"]) == [0, 2]
    return gearing


def _move_behind_the_librarys_back(dmc: galil.Controller) -> None:
    """Move the dropped follower A as a program would: its ``_SC`` then tells nothing of the
    drop (1, a move's end); its ratio reads 0."""
    assert sim_of(dmc).feed(b"PRA=-50;BGA\r") == b"::"
    dmc.sleep(0.5)
    assert dmc.query_operands(["_BGA", "_SCA", "_GRA"]) == [0, 1, 0]


_NEXT_MOTION: dict[str, Callable[[galil.Controller], object]] = {
    "move": lambda dmc: dmc.B.move_by(-100),
    "plan": lambda dmc: dmc.B.plan_by(-100),
    "jog": lambda dmc: dmc.B.jog(-1000),
    "increment": lambda dmc: dmc.B.increment(-100),
    "speed schedule": lambda dmc: dmc.B.speed_schedule(-1000, [(500, 10_000)], speed=20_000),
    "vector": lambda dmc: dmc.vector_move("BC", [Line(-100, 100)], speed=5000),
    "contour": lambda dmc: dmc.contour("B", np.linspace(0, -100, 8), dt=4),
}


@pytest.mark.parametrize("limit", ["soft", "switch"])
@pytest.mark.parametrize("motion", list(_NEXT_MOTION))
def test_the_masters_next_motion_reports_a_follower_a_limit_dropped_unawaited_and_forgets_it(
    dmc: galil.Controller, limit: str, motion: str
) -> None:
    # (it planned A from where it was geared: a move refused for A's soft limit, or one that
    # reported the old stop code as its own, A's gearing still engaged in the library)
    gearing = _drop_follower_unawaited(dmc, limit)
    start = dmc.B.reference_position
    with nothing_sent(dmc, allow_queries=True), pytest.raises(MotionError) as caught:
        _NEXT_MOTION[motion](dmc)
    err = caught.value
    assert err.axis == "A"
    assert err.stop_codes == {"A": 2}
    assert "A, geared to B" in str(err)
    assert "nobody waited for" in str(err)
    assert not gearing.engaged
    assert dmc.B.reference_position == start


@pytest.mark.parametrize("motion", list(_NEXT_MOTION))
def test_the_masters_next_motion_reports_a_follower_dropped_unseen_whose_stop_code_was_overwritten(
    dmc: galil.Controller, motion: str
) -> None:
    # (a program moved A after the limit dropped its gearing: _SCA 1 told nothing, and the
    # master's motion predicted A following, refused A's own moves as geared, and checked
    # A's soft limits for a gearing the controller no longer had)
    gearing = _drop_follower_unawaited(dmc, "switch")
    _move_behind_the_librarys_back(dmc)
    start = dmc.B.reference_position
    with nothing_sent(dmc, allow_queries=True), pytest.raises(MotionError) as caught:
        _NEXT_MOTION[motion](dmc)
    assert caught.value.axis == "A"
    assert "ratio reads 0" in str(caught.value)
    assert not gearing.engaged
    assert dmc.B.reference_position == start
    h = _NEXT_MOTION["move"](dmc)
    assert isinstance(h, galil.MoveHandle)
    assert h.followers == ""


def test_after_the_report_the_master_moves_without_the_dropped_follower(
    dmc: galil.Controller,
) -> None:
    _drop_follower_unawaited(dmc, "soft")
    a_at = dmc.A.reference_position
    with pytest.raises(MotionError, match="nobody waited for"):
        dmc.B.move_by(-100)
    h = dmc.B.move_by(-100)
    assert h.followers == ""  # not predicted any more
    r = h.wait()
    assert r.follower_stop_codes == {}
    assert dmc.A.reference_position == a_at
    dmc.A.move_by(-100).wait()  # not refused as geared either
    assert dmc.A.reference_position == a_at - 100


def test_a_follower_that_still_follows_adds_no_exchange_and_no_error_to_the_next_move(
    dmc: galil.Controller,
) -> None:
    dmc.A.gear_to("B", 2)
    dmc.B.move_by(400)  # not waited for, no limit on the way
    dmc.sleep(1.0)
    with transcript(dmc) as record:
        h = dmc.B.move_by(-400)
    # the state query (the followers' on it: pipelined MG lines, one round trip), the move
    *state, line = record.lines
    assert 1 <= len(state) <= 2
    assert all(q.startswith("MG _") for q in state), state
    assert "BG B" in line
    assert h.followers == "A"
    assert h.wait().follower_final == {"A": 0}


def test_a_stop_code_a_follower_already_showed_when_geared_is_not_taken_for_a_drop(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    # What _SC says while an axis follows is not documented: a controller that still showed
    # the forward limit of an earlier stop must not make every move of the master a "drop"
    # (refused, and the gearing forgotten while the controller still has it)
    monkeypatch.setattr(GearFeed, "stop_code", lambda self, index: self.code if self.off else 2)
    gearing = dmc.A.gear_to("B", 2)
    dmc.B.move_by(400)  # not waited for, no limit on the way
    dmc.sleep(1.0)
    assert dmc.query_operands(["_SCA", "_RPA"]) == [2, 800]
    r = dmc.B.move_by(-400).wait()
    assert gearing.engaged
    assert r.follower_stop_codes == {"A": 2}
    assert r.follower_final == {"A": 0}


@pytest.mark.parametrize(
    ("overwritten", "said"), [(False, "nobody waited for"), (True, "ratio reads 0")]
)
def test_a_new_ratio_for_a_follower_dropped_unseen_is_refused_and_forgets_it(
    dmc: galil.Controller, overwritten: bool, said: str
) -> None:
    # (GR would have engaged it again from where the limit stopped it, or a program left it,
    # the library's anchor still where it was geared: every later prediction of it off)
    gearing = _drop_follower_unawaited(dmc, "switch")
    if overwritten:
        _move_behind_the_librarys_back(dmc)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(MotionError) as caught:
        gearing.set_ratio(3)
    assert caught.value.axis == "A"
    assert said in str(caught.value)
    assert not gearing.engaged
    a_at = dmc.A.reference_position
    dmc.B.move_by(-100).wait()  # no GR was sent: A stays where it was
    assert dmc.A.reference_position == a_at
