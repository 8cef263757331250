"""A contour that runs into a limit switch ends with the stop reported (decision 0041).

The controller stops the whole contour at the switch (stop code 2 or 3 on that axis, 51 on the
others) and leaves contour mode; ``controller.contour`` raises :class:`galil.MotionError` with
the stop codes, and sends no ``CD`` once the stop is seen: not while the buffer is being fed,
nor at the end (``CD 0=0``), nor while it waits for the last segments.
"""

from __future__ import annotations

import numpy as np
import pytest

import galil
from galil.sim.controller import SimController
from galil.testing import sim_of, simulated


def ramp(to: float, segments: int) -> np.ndarray:
    """A two-axis path: A to ``to``, B to half of it, at constant speed."""
    a = np.linspace(to / segments, to, segments)
    return np.column_stack([a, a / 2])


def check_stopped_at_switch(
    dmc: galil.Controller, sim: SimController, path: np.ndarray, switch: int
) -> galil.MotionError:
    t0 = sim.start_trace("A")
    with pytest.raises(galil.MotionError, match="stopped by the controller") as caught:
        dmc.contour("AB", path, dt=1)
    exc = caught.value
    trace = sim.stop_trace("A")["A"]
    assert exc.axis == "A"
    assert exc.stop_codes == {"A": 2, "B": 51}
    assert exc.position == trace[-1]
    assert switch <= trace[-1] < path[-1, 0]
    stop = t0 + int(np.flatnonzero(trace != trace[-1])[-1]) + 1  # where A came to rest
    late = [text for k, text in sim.command_log if k > stop and text.startswith("CD")]
    assert late == []  # nothing fed once the contour was over
    bg_a, bg_b, cm = dmc.query_operands(["_BGA", "_BGB", "_CM"])
    assert (bg_a, bg_b, cm) == (0, 0, 511)
    return exc


def test_a_long_contour_into_a_switch_raises_and_stops_feeding() -> None:
    # 3000 segments: the switch is reached while the stream still feeds the buffer.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=20_000)
        check_stopped_at_switch(dmc, sim, ramp(60_000, 3000), 20_000)
        # Away from the switch, the next contour runs and ends as usual.
        result = dmc.contour("AB", -ramp(5000, 50), dt=1)
        assert dmc.query_operands(["_SCA", "_SCB"]) == [51, 51]
        assert result.increments.shape == (50, 2)


def test_a_short_contour_sent_whole_into_a_switch_raises_at_its_end() -> None:
    # 200 segments fit the buffer: the stop comes while the stream waits for the end.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=1000)
        check_stopped_at_switch(dmc, sim, ramp(4000, 200), 1000)


def test_a_contour_into_a_switch_over_tcp_raises_and_stops_feeding(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    sim.place_limit_switches("A", forward=12_000)
    check_stopped_at_switch(dmc, sim, ramp(40_000, 1500), 12_000)


@pytest.mark.parametrize("stale", [1, 2])
def test_a_stop_code_left_from_before_the_contour_is_not_read_as_its_stop(
    monkeypatch: pytest.MonkeyPatch, stale: int
) -> None:
    # Whether a controller sets _SC to 50 at CM is not sourced: one that kept the code of
    # the motion before (a move's 1, a limit's 2) all through the contour must not make a
    # contour that ran to its end look stopped. Only on an axis seen reading 50 is a stop
    # code the contour's stop (decision 0041).
    with simulated() as dmc:
        sim = sim_of(dmc)
        operands = sim._m.interp.axis_operands  # (the simulator's own _SC, the lowest layer)
        real = operands["SC"]
        monkeypatch.setitem(operands, "SC", lambda ax: stale if real(ax) in (50, 51) else real(ax))
        result = dmc.contour("AB", ramp(4000, 200), dt=1)
        assert result.increments.shape == (200, 2)
        assert dmc.query_operands(["_RPA", "_RPB"]) == [4000, 2000]
