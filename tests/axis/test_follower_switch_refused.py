"""A start of a master that would drive a geared follower towards its active limit switch is
refused before anything is sent (decision 0053): for a move, a jog, a vector sequence (a master
axis of the path, or ``S``), a contour and a speed schedule. Driven away from the switch, or
towards one ``LD`` disables, the follower is taken.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil import LimitDisable, Line
from galil.errors import InvalidArgument
from galil.sim.controller import SimController
from galil.testing import nothing_sent, sim_of

_Start = Callable[[galil.Controller, int], object]

# Each start drives the master B (or S) forward for ``way`` = 1, backward for -1.
_STARTS: dict[str, _Start] = {
    "move": lambda dmc, way: dmc.B.move_by(400 * way),
    "plan": lambda dmc, way: dmc.B.plan_by(400 * way),
    "jog": lambda dmc, way: dmc.B.jog(2000 * way),
    "vector": lambda dmc, way: dmc.vector_move("BC", [Line(400 * way, 100)], speed=20_000),
    "contour": lambda dmc, way: dmc.contour("B", np.linspace(0, 400 * way, 8), dt=4),
    "speed schedule": lambda dmc, way: dmc.B.speed_schedule(
        5000 * way, [(2000, 10_000)], speed=20_000
    ),
}


def _finish(dmc: galil.Controller, started: object) -> None:
    """Let the motion ``started`` run to its end (a jog: for a while, then stopped); a
    contour has run already."""
    if isinstance(started, galil.MoveHandle):
        if started.kind == "jog":
            dmc.sleep(0.1)
            started.stop()
        started.wait()


@pytest.mark.parametrize("start", list(_STARTS))
@pytest.mark.parametrize(("ratio", "switch"), [(2.0, "forward"), (-0.5, "reverse")])
def test_a_masters_start_driving_its_follower_into_its_active_switch_is_refused_unsent(
    dmc: galil.Controller, start: str, ratio: float, switch: str
) -> None:
    gearing = dmc.A.gear_to("B", ratio)
    sim_of(dmc).set_limit_switch("A", switch, True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument) as caught,
    ):
        _STARTS[start](dmc, 1)
    text = str(caught.value)
    assert f"axis A is geared to B at {ratio:g}" in text
    assert f"active {switch} limit switch" in text
    assert "move A off the switch" in text
    assert gearing.engaged
    assert dmc.query_operands(["_RPA", "_RPB", "_BGB", "_SCA"]) == [0, 0, 0, 0]


@pytest.mark.parametrize("start", list(_STARTS))
def test_a_follower_on_its_switch_driven_away_from_it_is_taken(
    dmc: galil.Controller, start: str
) -> None:
    gearing = dmc.A.gear_to("B", 2)
    sim_of(dmc).set_limit_switch("A", "forward", True)
    started = _STARTS[start](dmc, -1)  # A goes backward, off its forward switch
    if start != "plan":
        _finish(dmc, started)
        assert dmc.A.reference_position < 0
    assert gearing.engaged


def test_a_follower_of_s_driven_into_its_active_switch_is_refused_unsent(
    dmc: galil.Controller,
) -> None:
    gearing = dmc.A.gear_to("S", -1)  # the distance along S only grows: A goes backward
    sim_of(dmc).set_limit_switch("A", "reverse", True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match=r"axis A is geared to S at -1: .*active reverse"),
    ):
        dmc.vector_move("BC", [Line(-400, 100)], speed=20_000)
    assert gearing.engaged
    sim_of(dmc).set_limit_switch("A", "reverse", False)
    sim_of(dmc).set_limit_switch("A", "forward", True)
    done = dmc.vector_move("BC", [Line(-400, 100)], speed=20_000).wait()
    assert done.follower_final["A"] < 0  # away from the forward switch: taken
    assert gearing.engaged


def test_a_follower_driven_towards_a_switch_ld_disables_is_taken(dmc: galil.Controller) -> None:
    gearing = dmc.A.gear_to("B", 2)
    sim_of(dmc).set_limit_switch("A", "forward", True)
    dmc.A.limit_disable = LimitDisable.REVERSE  # (not this one: still refused)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="axis A"):
        dmc.B.move_by(400)
    dmc.A.limit_disable = LimitDisable.FORWARD
    done = dmc.B.move_by(400).wait()
    assert done.follower_final == {"A": 800}
    assert gearing.engaged


def test_a_follower_on_its_switch_is_refused_unsent_over_tcp(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    gearing = dmc.A.gear_to("B", 2)
    sim.set_limit_switch("A", "forward", True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match=r"axis A is geared to B at 2: .*active forward"),
    ):
        dmc.B.move_by(400)
    assert dmc.query_operands(["_RPA", "_RPB", "_SCA"]) == [0, 0, 0]
    assert gearing.engaged
    done = dmc.B.move_by(-400).wait()  # away from it: taken
    assert done.follower_final == {"A": -800}
