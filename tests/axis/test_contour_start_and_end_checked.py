"""A contour is checked before it starts and when it ends (decision 0071).

- Before any byte: a path on which an axis first moves towards its active limit switch (one
  ``LD`` leaves on) is refused, as a move, a jog, a homing and a vector path are. The controller
  would stop the whole contour there at once. A path moving away from the switch runs, and so
  does one towards a switch ``LD`` disables.
- At its end: each axis is where its path ends. Something else (a program's ``ST`` of one
  contour axis, which stops that axis alone with the code of a contour's end, 51) may have cut
  the contour short. Then ``contour()`` raises ``MotionError`` instead of returning as if the
  whole path had run.
"""

from __future__ import annotations

import numpy as np
import pytest

import galil
from galil.testing import nothing_sent, sim_of


def ramp(a: float, b: float, segments: int = 12) -> np.ndarray:
    """A two-axis path from where the axes are: A by ``a``, B by ``b``, at constant speed."""
    k = np.linspace(1 / segments, 1, segments)
    return np.column_stack([k * a, k * b])


def on_forward_switch(dmc: galil.Controller, axis: str) -> None:
    """Put ``axis`` on its forward limit switch (the switch 500 counts behind it)."""
    sim = sim_of(dmc)
    sim.place_limit_switches(axis, forward=sim.machine_position(axis) - 500)
    assert dmc.axes[axis].switches.forward_limit


def test_a_contour_starting_towards_an_active_limit_switch_is_refused_before_any_byte(
    dmc: galil.Controller,
) -> None:
    on_forward_switch(dmc, "B")
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument) as caught:
        dmc.contour("AB", ramp(300, 600), dt=3)
    assert "axis B would start towards its active forward limit switch" in str(caught.value)
    assert dmc.query_operands(["_RPA", "_RPB", "_CM"]) == [0, 0, 511]  # (no CM, no segment)


def test_a_contour_that_first_moves_away_from_the_active_switch_runs_to_its_end(
    dmc: galil.Controller,
) -> None:
    on_forward_switch(dmc, "B")
    path = np.vstack([ramp(300, -600), ramp(300, -600)[::-1] * [1, 0] + [300, -600]])
    dmc.contour("AB", path, dt=3)  # B back, then it stays; A on and on
    assert dmc.query_operands(["_RPA", "_RPB"]) == [path[-1, 0], path[-1, 1]]


def test_a_contour_towards_a_switch_ld_disables_runs_to_its_end(dmc: galil.Controller) -> None:
    on_forward_switch(dmc, "B")
    dmc.B.limit_disable = galil.LimitDisable.FORWARD
    dmc.contour("AB", ramp(300, 600), dt=3)
    assert dmc.query_operands(["_RPA", "_RPB"]) == [300, 600]


def test_a_contour_one_axis_of_which_a_program_stops_is_an_error_not_a_success(
    dmc: galil.Controller,
) -> None:
    dmc.programs.download("#STOPPER\nWT 30\nST B\nEN")
    dmc.programs.run("#STOPPER", thread=1)  # ST B 30 ms into the 94 ms contour
    with pytest.raises(galil.MotionError) as caught:
        dmc.contour("AB", ramp(300, 600), dt=3)
    exc = caught.value
    b = dmc.query_operands(["_RPB"])[0]
    assert exc.axis == "B"
    assert exc.position == b
    assert 0 < b < 600
    assert exc.stop_codes == {"A": 51, "B": 51}  # (the codes of a contour's end: no halt)
    assert f"ended with B at {b:.0f}, not at the end of its path (600)" in str(exc)
    assert dmc.query_operands(["_RPA", "_BGA", "_BGB"]) == [300, 0, 0]  # (A ran on: its end)


def test_a_contour_that_runs_as_asked_ends_without_an_error_from_anywhere(
    dmc: galil.Controller,
) -> None:
    dmc.A.define_position(1000)
    dmc.B.define_position(-2000)
    result = dmc.contour("AB", ramp(300, 600), dt=3)
    assert dmc.query_operands(["_RPA", "_RPB"]) == [1300, -1400]
    assert result.profiles["A"].end == 1300
    assert result.profiles["B"].end == -1400
