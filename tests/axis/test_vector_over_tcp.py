"""Issue 13's "done when", over TCP: the simulator served on loopback, a real-time clock.

The simulator runs 8 times faster than real time, so waits are real waits; the checks are still
exact because every line that starts or changes motion is stamped with the controller's TIME.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import galil
from galil import Arc, Line
from galil.errors import CommandError, InvalidArgument, LimitError
from galil.sim.controller import SimController
from galil.testing import nothing_sent
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def traced(
    sim: SimController, handle: galil.MoveHandle, t0: int, axes: str
) -> dict[str, np.ndarray]:
    """The recorded references from the handle's first sample, as long as its prediction."""
    trace = sim.stop_trace(axes)
    k = handle.begin[handle.axes[0]]
    assert k is not None
    return {a: trace[a][k - t0 : k - t0 + handle.profiles[a].position.size] for a in axes}


def test_a_rounded_square_runs_exactly_as_predicted(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    for a in "AB":
        dmc.axis(a).set_scale(counts_per=2000 / mm)
    square = [
        Line(30 * mm, 0),
        Arc(5 * mm, 270, 90),
        Line(0, 30 * mm),
        Arc(5 * mm, 0, 90),
        Line(-30 * mm, 0),
        Arc(5 * mm, 90, 90),
        Line(0, -30 * mm),
        Arc(5 * mm, 180, 90),
    ]
    t0 = sim.start_trace("AB")
    h = dmc.vector_move(
        "AB", square, speed=60 * mm / s, accel=600 * mm / s**2, decel=600 * mm / s**2
    )
    result = h.wait()
    got = traced(sim, h, t0, "AB")
    for a in "AB":
        np.testing.assert_array_equal(got[a], h.profiles[a].position)
    assert result.worst == 0
    assert result.stop_codes == {"A": 101, "B": 101}
    assert (dmc.A.reference_position, dmc.B.reference_position) == (0 * mm, 0 * mm)


def test_a_straight_line_is_the_closed_form_vector_trapezoid(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    vs, va, vd = 40_000, 256_000, 512_000
    t0 = sim.start_trace("AB")
    h = dmc.vector_move("AB", [Line(30_000, 40_000)], speed=vs, accel=va, decel=vd)
    h.wait()
    got = traced(sim, h, t0, "AB")
    length, ts = 50_000, dmc.sample_period
    ta, td = vs / va, vs / vd
    tc = (length - vs * ta / 2 - vs * td / 2) / vs

    def ideal(t: float) -> float:
        if t <= ta:
            return va * t * t / 2
        if t <= ta + tc:
            return vs * ta / 2 + vs * (t - ta)
        u = max(0.0, ta + tc + td - t)
        return length - vd * u * u / 2

    p = h.counts
    assert abs(p.duration - (ta + tc + td)) <= 2 * ts
    along = np.hypot(got["A"], got["B"])  # the recorded path, from the origin
    closed = np.array([ideal(t) for t in p.t])
    assert np.max(np.abs(along - closed)) <= vs * ts + 2
    for i, a in enumerate("AB"):
        np.testing.assert_array_equal(got[a], p.position[i])
    # Both axes move on the line: 3/5 and 4/5 of the way, within a count.
    assert np.max(np.abs(got["A"] * 4 - got["B"] * 3)) <= 5


def test_a_full_circle_closes_on_its_start_point(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    dmc.move({"A": 12_345, "B": -678}).wait()
    t0 = sim.start_trace("AB")
    h = dmc.vector_move("AB", [Arc(7777.25, 45, 360)], speed=60_000, accel=1_024_000)
    h.wait()
    got = traced(sim, h, t0, "AB")
    centre = (12_345 - 7777.25 * math.cos(math.pi / 4), -678 - 7777.25 * math.sin(math.pi / 4))
    radius = np.hypot(got["A"] - centre[0], got["B"] - centre[1])
    assert np.max(np.abs(radius - 7777.25)) <= 1  # within a count of the ideal circle
    assert (got["A"][-1], got["B"][-1]) == (12_345, -678)
    assert dmc.query_operands(["_RPA", "_RPB"]) == [12_345, -678]


def test_a_path_beyond_an_axis_speed_or_the_buffer_is_refused_before_a_byte(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, _ = tcp
    y = dmc.B.set_scale(counts_per=1000 / mm)
    dmc.A.set_scale(counts_per=1000 / mm)
    y.soft_limits = (None, 55 * mm)
    path = [Line(50 * mm, 0), Arc(10 * mm, 270, 90), Line(0, 40 * mm)]
    fast = {"speed": 30 * mm / s, "accel": 300 * mm / s**2, "decel": 300 * mm / s**2}
    # B may move at 20 mm/s: the arc turns the path's 30 mm/s onto it.
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as err:
        dmc.vector_move("AB", path, axis_speed={"B": 20 * mm / s}, **fast)
    assert "segment 1: axis B speed" in str(err.value)
    assert err.value.sample is not None
    assert 0 < err.value.sample < dmc.plan_vector("AB", path, **fast).counts.samples
    # A last line up to 60 mm goes beyond B's forward soft limit.
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as err:
        dmc.vector_move("AB", [*path, Line(0, 10 * mm)], **fast)
    assert "segment 3" in str(err.value)
    assert err.value.name == "FL"
    assert err.value.sample is not None
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match="segment 511"):
        dmc.vector_move("AB", [Line(5 * mm, 5 * mm)] * 600, stream=False, **fast)


def test_a_follower_is_ratio_times_master_motion_sample_by_sample(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    dmc, sim = tcp
    gearing = dmc.C.gear_to(dmc.A, -0.375)
    t0 = sim.start_trace("AC")
    h = dmc.A.move_by(24_001, speed=30_000)
    h.wait()
    got = traced(sim, h, t0, "AC")
    np.testing.assert_array_equal(got["C"], h.profiles["C"].position)
    np.testing.assert_array_equal(got["C"], galil.predict.gear(got["A"], gearing.ratio))
    gearing.off()


def test_a_path_into_an_active_switch_is_refused_unsent_and_bg_s_gets_tc_22(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    """The library refuses it before sending (decision 0050); the same sequence sent raw
    meets the simulator's TC 22 at ``BG S``, as an independent ``BG`` does."""
    dmc, sim = tcp
    sim.set_limit_switch("A", "reverse", True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match=r"axis A .*active reverse limit switch.*TC 22"),
    ):
        dmc.vector_move("AB", [Line(-1000, 200)], speed=20_000)
    dmc.command("CA S;VM AB;VP -1000,200;VE", allow_compound=True)
    with pytest.raises(CommandError) as err:
        dmc.command("BG S")
    assert err.value.code == 22
    assert dmc.query_operands(["_BGS", "_RPA", "_RPB"]) == [0, 0, 0]
    done = dmc.vector_move("AB", [Line(1000, 200)], speed=20_000).wait()  # away: taken
    assert done.final == {"A": 1000, "B": 200}
