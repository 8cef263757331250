"""Coordinated motion and gearing through the public API, on the in-process simulator.

Every check compares what the servo loop ran with the handle's prediction, sample by sample.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import galil
from galil import Arc, Line
from galil.errors import InvalidArgument, LimitError
from galil.testing import nothing_sent, sim_of, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s
SPEED, ACCEL = 40 * mm / s, 400 * mm / s**2


def rounded_square(side: float = 40.0, r: float = 5.0) -> list[Line | Arc]:
    """A counter-clockwise square with rounded corners, from the middle of its bottom edge."""
    straight = (side - 2 * r) * mm
    half = straight / 2
    return [
        Line(half, 0),
        Arc(r * mm, 270, 90),
        Line(0, straight),
        Arc(r * mm, 0, 90),
        Line(-straight, 0),
        Arc(r * mm, 90, 90),
        Line(0, -straight),
        Arc(r * mm, 180, 90),
        Line(half, 0),
    ]


def scaled(dmc: galil.Controller, axes: str = "AB", counts: float = 2000) -> None:
    for a in axes:
        dmc.axis(a).set_scale(counts_per=counts / mm)


def followed(dmc: galil.Controller, run: object, letters: str) -> None:
    """Run ``run()`` (returning a handle) with a trace; assert the trace is the prediction."""
    sim = sim_of(dmc)
    t0 = sim.start_trace(letters)
    handle = run()  # type: ignore[operator]
    result = handle.wait()
    trace = sim.stop_trace(letters)
    for a in letters:
        p = handle.profiles[a].position
        k = handle.begin[handle.axes[0]] - t0
        np.testing.assert_array_equal(trace[a][k : k + p.size], p, err_msg=f"axis {a}")
    assert result.worst == 0


def test_plan_vector_predicts_in_user_units_without_sending(dmc: galil.Controller) -> None:
    scaled(dmc)
    with nothing_sent(dmc, allow_queries=True):
        plan = dmc.plan_vector("AB", rounded_square(), speed=SPEED, accel=ACCEL, decel=ACCEL)
    assert plan.unit == "mm"
    assert plan.per_unit == 2000
    ideal = 4 * 30 + 2 * math.pi * 5
    assert plan.path[-1] == pytest.approx(ideal, abs=1e-3)
    assert plan.speed.max() == pytest.approx(40, rel=1e-3)
    ends = plan.position("A")[-1], plan.position("B")[-1]
    assert ends == (0.0, 0.0)  # the square closes on its start point
    assert plan.position("B").max() == pytest.approx(40, abs=1e-3)
    assert plan.duration == pytest.approx(ideal / 40 + 0.1, abs=0.01)
    assert plan.profiles["A"].display is not None
    assert "VectorPlan(AB, vector" in repr(plan)
    fig = plan.plot()
    assert len(fig.axes) == 2


def test_a_rounded_square_in_millimetres_runs_as_predicted(dmc: galil.Controller) -> None:
    scaled(dmc)
    dmc.A.move_to(3 * mm).wait()

    def run() -> galil.VectorHandle:
        return dmc.vector_move("AB", rounded_square(), speed=SPEED, accel=ACCEL, decel=ACCEL)

    followed(dmc, run, "AB")
    assert dmc.A.reference_position == 3 * mm
    assert dmc.query_operands(["_SCA", "_SCB", "_CSS"]) == [101, 101, 9]


def test_a_path_longer_than_the_buffer_is_streamed_and_still_predicted_exactly(
    dmc: galil.Controller,
) -> None:
    zigzag = [Line(37, 19 * (-1) ** k) for k in range(1400)]
    handle: list[galil.VectorHandle] = []

    def run() -> galil.VectorHandle:
        handle.append(dmc.vector_move("AB", zigzag, speed=30_000, accel=512_000, decel=512_000))
        return handle[0]

    followed(dmc, run, "AB")
    log = [text for _, text in sim_of(dmc).command_log]
    vps = [i for i, text in enumerate(log) if text.startswith("VP")]
    assert len(vps) == 1400
    begun = log.index("BG S")
    assert sum(i > begun for i in vps) == 1400 - 511  # the rest went out during the motion
    assert log.index("VE") > begun
    assert handle[0].counts.shape == "changed"  # predicted from when each line went out
    assert dmc.query_operands(["_RPA", "_RPB"]) == [37 * 1400, 0]


def test_linear_interpolation_runs_on_three_axes(dmc: galil.Controller) -> None:
    scaled(dmc, "ABC")
    path = [Line(4 * mm, 2 * mm, 1 * mm), Line(2 * mm, 4 * mm, 1 * mm), Line(1 * mm, -3 * mm, 0)]

    def run() -> galil.VectorHandle:
        return dmc.vector_move("ABC", path, speed=SPEED, accel=ACCEL, decel=ACCEL)

    followed(dmc, run, "ABC")
    log = [text for _, text in sim_of(dmc).command_log]
    assert "LM ABC" in log
    assert "LI 8000,4000,2000" in log


def test_a_reversed_axis_mirrors_the_arc_so_it_turns_as_the_user_sees_it(
    dmc: galil.Controller,
) -> None:
    dmc.A.set_scale(counts_per=1000 / mm, sign=-1)
    dmc.B.set_scale(counts_per=1000 / mm)
    dmc.vector_move("AB", [Arc(10 * mm, 0, 90)], speed=SPEED, accel=ACCEL, decel=ACCEL).wait()
    # From angle 0 counter-clockwise a quarter turn: the centre is 10 mm behind in x.
    assert dmc.A.reference_position == -10 * mm
    assert dmc.B.reference_position == 10 * mm


def test_a_full_circle_closes_on_its_start_point(dmc: galil.Controller) -> None:
    dmc.B.move_to(-1234).wait()

    def run() -> galil.VectorHandle:
        return dmc.vector_move("AB", [Arc(5000.5, 30, -360)], speed=30_000, accel=512_000)

    followed(dmc, run, "AB")
    assert dmc.query_operands(["_RPA", "_RPB"]) == [0, -1234]


def test_stop_decelerates_along_the_path_and_the_prediction_follows(
    dmc: galil.Controller,
) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("AB")
    h = dmc.vector_move("AB", [Line(100_000, 50_000)], speed=40_000, accel=256_000)
    dmc.sleep(0.5)
    h.stop()
    r = h.wait()
    trace = sim.stop_trace("AB")
    assert r.stop_codes == {"A": 4, "B": 4}
    assert r.worst == 0
    assert h.counts.shape == "stopped"
    for i, a in enumerate("AB"):
        p = h.counts.position[i]
        k = h.begin["A"] - t0
        np.testing.assert_array_equal(trace[a][k : k + p.size], p)


def test_an_abort_stops_a_sequence_at_once_and_the_prediction_follows(
    dmc: galil.Controller,
) -> None:
    h = dmc.vector_move("AB", [Line(60_000, 80_000)], speed=40_000, accel=256_000)
    dmc.sleep(0.4)
    dmc.abort()
    r = h.wait()
    assert r.stop_codes == {"A": 7, "B": 7}
    assert r.worst == 0
    assert h.counts.stop_code == 7
    assert 0 < r.final["A"] < 60_000


def test_the_motion_guard_and_controller_stop_reach_a_sequence(dmc: galil.Controller) -> None:

    def scan() -> None:
        with dmc.motion():
            dmc.vector_move("AB", [Line(100_000, 0)], speed=40_000, accel=256_000)
            raise RuntimeError("scan failed")

    with pytest.raises(RuntimeError, match="scan failed"):
        scan()
    assert dmc.query_operands(["_BGS", "_SCA"]) == [0, 4]
    h = dmc.vector_move("AB", [Line(0, 100_000)], speed=40_000, accel=256_000)
    dmc.sleep(0.2)
    dmc.stop()
    assert h.wait().worst == 0


def test_accel_and_decel_default_to_the_controllers(dmc: galil.Controller) -> None:
    dmc.command_line(["VAS=102400", "VDS=204800"])
    plan = dmc.plan_vector("AB", [Line(30_000, 0)], speed=20_000)
    assert plan.counts.speed_settings[1:3] == (102400, 204800)


def _refused(dmc: galil.Controller, error: type[Exception], match: str, **kwargs: object) -> None:
    options: dict[str, object] = {"speed": 40_000, "accel": 256_000, "decel": 256_000}
    if galil.units.is_quantity(kwargs.get("speed")):
        options.update(accel=ACCEL, decel=ACCEL)
    options.update(kwargs)
    segments = options.pop("segments", [Line(10_000, 0)])
    axes = options.pop("axes", "AB")
    with nothing_sent(dmc, allow_queries=True), pytest.raises(error, match=match):
        dmc.vector_move(axes, segments, **options)  # type: ignore[arg-type]


def test_a_path_too_fast_for_an_axis_names_the_segment_and_the_sample(
    dmc: galil.Controller,
) -> None:
    # 200 000 counts/s along the path is fine until a tiny arc: its centripetal acceleration
    # (v²/r = 4e9 counts/s²) is far beyond what an axis may do.
    path = [Line(200_000, 0), Arc(10, 270, 90), Line(0, 200_000)]
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as err:
        dmc.vector_move("AB", path, speed=200_000, accel=2_048_000, decel=2_048_000)
    assert "segment 1" in str(err.value)
    assert err.value.sample is not None
    assert err.value.sample > 0
    assert err.value.axis in ("A", "B")


def test_a_soft_limit_anywhere_on_the_path_is_refused_with_segment_and_sample(
    dmc: galil.Controller,
) -> None:
    scaled(dmc)
    dmc.B.soft_limits = (None, 25 * mm)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as err:
        dmc.vector_move("AB", rounded_square(), speed=SPEED, accel=ACCEL, decel=ACCEL)
    text = str(err.value)
    assert "segment 2" in text
    assert "sample" in text
    assert "in user units" in text
    assert err.value.name == "FL"
    assert err.value.axis == "B"


def test_the_buffer_is_respected_before_a_byte_is_sent(dmc: galil.Controller) -> None:
    many = [Line(10, 10)] * 600
    _refused(dmc, LimitError, r"segment 511.*buffer", segments=many, stream=False)
    # A slow link that cannot keep the buffer fed: refused, naming the segment and sample.
    run = galil.vector.VectorStream(
        dmc.link,
        [galil.segments.PathAxis("A"), galil.segments.PathAxis("B")],
        [Line(1, 1)] * 1200,
        speed=200_000,
        accel=2_048_000,
        decel=2_048_000,
        byte_rate=960,
    )
    with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError, match=r"segment 511"):
        run.prepare()


def test_bad_paths_and_values_are_refused_before_a_byte(dmc: galil.Controller) -> None:
    dmc.A.set_scale(counts_per=2000 / mm)
    dmc.B.set_scale(counts_per=1000 / mm)
    _refused(dmc, InvalidArgument, "ellipse", segments=[Arc(5 * mm, 0, 90)], speed=SPEED)
    _refused(
        dmc, InvalidArgument, "same counts per unit", segments=[Line(1 * mm, 1 * mm)], speed=SPEED
    )
    dmc.B.set_scale(counts_per=2000 / mm)
    _refused(dmc, InvalidArgument, "no units", segments=[Line(1 * mm, 1 * mm)], speed=40_000)
    _refused(dmc, InvalidArgument, "wrong dimension", segments=[Line(1 * s, 0)], speed=SPEED)
    with pytest.raises(InvalidArgument, match="not an angle"):
        Arc(1 * mm, 1 * mm, 90)
    _refused(
        dmc, InvalidArgument, "two axes", segments=[Arc(1 * mm, 0, 90)], axes="ABC", speed=SPEED
    )
    _refused(dmc, InvalidArgument, "components", segments=[Line(1 * mm)], speed=SPEED)
    _refused(dmc, InvalidArgument, "not a galil.Line", segments=[(1, 2)], speed=SPEED)
    _refused(dmc, LimitError, "TC 30", segments=[Line(1 * mm, 0), Line(0, 0)], speed=SPEED)
    _refused(dmc, LimitError, "VS", segments=[Line(1 * mm, 0)], speed=1e6 * mm / s)
    _refused(dmc, InvalidArgument, "no VT", segments=[Line(1 * mm, 0)], speed=SPEED, smoothing=0.5)
    _refused(  # a limit is a magnitude: a minus is a mistake, not a direction
        dmc,
        InvalidArgument,
        "must not be negative",
        segments=[Line(1 * mm, 0)],
        speed=SPEED,
        axis_speed={"A": -5 * mm / s},
    )
    dmc.B.set_scale(counts_per=2000 / mm, sign=-1)  # a reversed axis still takes a positive one
    dmc.plan_vector("AB", [Line(1 * mm, 1 * mm)], speed=SPEED, axis_speed={"B": 50 * mm / s})
    with pytest.raises(InvalidArgument, match="Line needs"):
        Line()
    with pytest.raises(InvalidArgument, match="must not be 0"):
        Arc(1, 0, 0)


@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize("name", ["speed", "accel", "decel"])
def test_a_negative_rate_along_the_path_in_user_units_is_refused_on_any_scale(
    dmc: galil.Controller, name: str, sign: int
) -> None:
    # A minus is a mistake, as in counts, not a direction; a reversed axis's scale makes
    # the counts of a positive rate negative, and that one still runs.
    dmc.A.set_scale(counts_per=2000 / mm, sign=sign)
    dmc.B.set_scale(counts_per=2000 / mm, sign=sign)
    rate = {"speed": -SPEED, "accel": -ACCEL, "decel": -ACCEL}[name]
    options = {"speed": SPEED, "accel": ACCEL, "decel": ACCEL, name: rate}
    path = [Line(1 * mm, 0)]
    _refused(dmc, InvalidArgument, f"{name} along the path must be", segments=path, **options)
    dmc.vector_move("AB", path, speed=SPEED, accel=ACCEL, decel=ACCEL).wait()
    assert dmc.A.reference_position == 1 * mm


@pytest.mark.parametrize("radius", [-5 * mm, -1000, 0, 0 * mm])
def test_an_arc_with_a_radius_that_is_not_positive_is_refused(radius: object) -> None:
    with pytest.raises(InvalidArgument, match="Arc radius must be positive"):
        Arc(radius, 0, 90)


@pytest.mark.parametrize(
    "path",
    [[Line(1000, 500)], [Line(1000, 0), Line(0, 500)], [Arc(1000, 270, 90)]],
    ids=["at-once", "after-a-segment", "arc-bending-forward"],
)
def test_a_path_whose_axis_first_heads_into_its_active_switch_is_refused_before_sending(
    dmc: galil.Controller, path: list[Line | Arc]
) -> None:
    """Before: the setup and the segments went out and the sequence ran through the switch
    (the simulator took ``BG S``; a controller refuses it: TC 22). Now nothing but the state
    read goes out (decision 0050)."""
    sim_of(dmc).set_limit_switch("B", "forward", True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match=r"axis B .*active forward limit switch.*TC 22"),
    ):
        dmc.vector_move("AB", path, speed=20_000)
    away = dmc.vector_move("AB", [Arc(1000, 90, 90)], speed=20_000)  # B bends back first
    assert away.wait().final == {"A": -1000, "B": -1000}
    dmc.B.limit_disable = galil.LimitDisable.FORWARD  # the switch no longer stops B: taken
    assert dmc.vector_move("AB", path, speed=20_000).wait().stop_codes == {"A": 101, "B": 101}


def test_the_switch_a_path_heads_into_is_the_one_its_counts_meet_on_a_reversed_axis(
    dmc: galil.Controller,
) -> None:
    scaled(dmc)
    dmc.B.set_scale(counts_per=2000 / mm, sign=-1)  # +B in millimetres: reverse in counts
    sim_of(dmc).set_limit_switch("B", "reverse", True)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(InvalidArgument, match="active reverse limit switch"),
    ):
        dmc.vector_move("AB", [Line(1 * mm, 1 * mm)], speed=SPEED)
    done = dmc.vector_move("AB", [Line(1 * mm, -1 * mm)], speed=SPEED).wait()
    assert done.final == {"A": 2000, "B": 2000}


def test_a_moving_axis_or_a_running_sequence_is_refused(dmc: galil.Controller) -> None:
    dmc.A.jog(1000)
    _refused(dmc, InvalidArgument, "axis A is moving")
    dmc.stop()
    dmc.sleep(0.5)
    dmc.vector_move("AB", [Line(100_000, 0)], speed=20_000, accel=256_000)
    _refused(dmc, InvalidArgument, "sequence is running")


def test_an_axis_with_its_motor_off_is_refused_from_its_ts(dmc: galil.Controller) -> None:
    dmc.motor_off("B")  # (the state query reads TS, whose bit 5 is "motor off")
    _refused(dmc, InvalidArgument, "axis B has its motor off")
    dmc.servo_here("B")
    assert dmc.vector_move("AB", [Line(1000, 0)], speed=20_000).wait().final == {"A": 1000, "B": 0}


def test_a_follower_is_predicted_with_its_master_sample_by_sample(dmc: galil.Controller) -> None:
    scaled(dmc, "AB")
    gearing = dmc.B.gear_to(dmc.A, 0.5)
    assert repr(gearing) == "<Gearing B = 0.5 x A engaged>"
    assert "B" in dmc.plan({"A": 10 * mm})

    def move() -> galil.MoveHandle:
        return dmc.A.move_by(10.0005 * mm, speed=20 * mm / s)

    followed(dmc, move, "AB")
    expected = gearing.predict(dmc.A.plan_by(10.0005 * mm))  # the next move, beforehand
    followed(dmc, move, "AB")  # the fraction is carried from one move to the next
    assert expected.end == dmc.query_operands(["_RPB"])[0]
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="geared"):
        dmc.B.move_by(1 * mm)
    gearing.off()
    assert not gearing.engaged
    dmc.B.move_by(1 * mm).wait()


def test_stopping_a_follower_turns_its_gearing_off_and_the_prediction_knows(
    dmc: galil.Controller,
) -> None:
    gearing = dmc.C.gear_to("A", -2)
    sim = sim_of(dmc)
    t0 = sim.start_trace("AC")
    h = dmc.A.move_by(30_000, speed=20_000)
    dmc.sleep(0.4)
    dmc.stop()  # ST on every axis: the follower is released where it is
    h.wait()
    trace = sim.stop_trace("AC")
    assert not gearing.engaged
    k = h.begin["A"] - t0
    for a in "AC":
        p = h.profiles[a].position
        np.testing.assert_array_equal(trace[a][k : k + p.size], p)


def test_a_followers_profile_follows_a_change_to_its_masters_jog(
    dmc: galil.Controller,
) -> None:
    # (the follower's profile, asked for once the jog had started, was kept when the jog was
    # stopped: it ended 4 counts out, where the master's first prediction stopped, not 245)
    dmc.B.gear_to(dmc.A, 1)
    sim = sim_of(dmc)
    t0 = sim.start_trace("AB")
    jog = dmc.A.jog(500)
    assert jog.followers == "B"
    dmc.sleep(0.5)
    jog.stop()
    result = jog.wait()
    trace = sim.stop_trace("AB")
    k = jog.begin["A"] - t0
    assert jog.profiles["B"].end == result.follower_final["B"] == result.final["A"]
    for a in "AB":
        p = jog.profiles[a].position
        np.testing.assert_array_equal(trace[a][k : k + p.size], p)


def test_a_follower_of_s_rides_the_vector_distance(dmc: galil.Controller) -> None:
    dmc.C.gear_to("S", 1.25)

    def run() -> galil.VectorHandle:
        return dmc.vector_move("AB", [Line(3000, 4000), Arc(1000, 0, 90)], speed=20_000)

    followed(dmc, run, "ABC")
    followed(dmc, run, "ABC")


def test_gearing_refusals_send_nothing_that_changes_anything(dmc: galil.Controller) -> None:
    with nothing_sent(dmc, allow_queries=True):
        with pytest.raises(InvalidArgument, match="itself"):
            dmc.A.gear_to(dmc.A, 1)
        with pytest.raises(LimitError, match="GR"):
            dmc.B.gear_to("A", 200)
    dmc.B.gear_to("A", 1)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 46"):
        dmc.C.gear_to("B", 1)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="already"):
        dmc.B.gear_to("C", 1)


def test_gearing_to_an_axis_of_another_controller_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    with simulated() as other:
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="another controller"):
            dmc.B.gear_to(other.C, 1)  # (it would gear B to this controller's C)
        assert dmc.query_operands(["_GRB"]) == [0]
        assert dmc.B.gear_to(dmc.C, 1).master == "C"  # its own axis, as an Axis


def test_a_ratio_change_at_rest_keeps_the_prediction_exact() -> None:
    with simulated() as dmc:
        gearing = dmc.B.gear_to("A", 1 / 3)
        dmc.A.move_by(1001).wait()
        gearing.set_ratio(-0.7)
        assert gearing.ratio == galil.predict.quantise_ratio(-0.7)
        followed(dmc, lambda: dmc.A.move_by(2002), "AB")


@pytest.mark.parametrize(("model", "smoothing"), [("DMC-4040", None), ("DMC-2183", 0.3)])
def test_smoothing_is_predicted_vt_where_the_model_has_it_else_the_first_axis_it(
    model: str, smoothing: float | None
) -> None:
    with simulated(model) as dmc:
        if smoothing is None:
            dmc.A.smoothing = 0.25  # no VT: the sequence is smoothed by its first axis's IT
        path = [Line(20_000, 0), Arc(2000, 270, 90), Line(0, 5000)]
        options = {"speed": 30_000, "accel": 512_000, "smoothing": smoothing}
        followed(dmc, lambda: dmc.vector_move("AB", path, **options), "AB")
        h = dmc.vector_move("AB", [Line(-20_000, 0)], **options)
        # IT 0.25 on the 4040; VT 0.3 stored in 1/256 steps (77/256) on the 2183
        assert h.counts.speed_settings[3] == (0.25 if smoothing is None else 77 / 256)
        h.wait()


def test_a_stop_from_another_thread_ends_a_streamed_path() -> None:
    import threading

    from galil.testing import simulated

    with simulated() as dmc:
        zigzag = [galil.Line(37, 19 * (-1) ** k) for k in range(1400)]
        done: list[object] = []

        def run() -> None:
            done.append(dmc.vector_move("AB", zigzag, speed=30_000, accel=512_000, decel=512_000))

        streaming = threading.Thread(target=run)
        streaming.start()
        while dmc.tracker.active("A") is None and streaming.is_alive():
            threading.Event().wait(0.001)
        dmc.stop()  # ST on every axis, from this thread, while the path streams
        streaming.join(20)
        assert not streaming.is_alive()  # the stream noticed and sent no more
        handle = done[0]
        assert isinstance(handle, galil.VectorHandle)
        assert handle.stopped
        handle.wait()
        assert dmc.query_operands(["_BGS"]) == [0]
        assert dmc.query_operands(["_RPA"])[0] < 37 * 1400


def test_an_increment_during_a_vector_sequence_is_refused_before_sending(
    dmc: galil.Controller,
) -> None:
    # (the controller refuses IP during a coordinated move, TC 29: it went out and came back
    # as a CommandError)
    path = dmc.vector_move("CD", [Line(0, 4000)], speed=5000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="TC 29"):
        dmc.C.increment(-2000)
    path.wait()
    assert dmc.query_operands(["_RPC", "_RPD"]) == [0, 4000]


def test_a_path_of_axes_without_scales_takes_its_rates_in_counts_per_second() -> None:
    """As an axis without a scale takes its speed in ``count / s``, so does a path of them; a
    rate in counts of the wrong power of time is refused, naming the power it needs."""
    with simulated() as dmc:
        move = dmc.vector_move(
            "AB",
            [Line(1000, 1000)],
            speed=10_000 * ureg.count / ureg.s,
            accel=100_000 * ureg.count / ureg.s**2,
        )
        assert move.wait().deviation == {"A": 0, "B": 0}
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="count / second"):
            dmc.vector_move("AB", [Line(1000, 1000)], speed=10_000 * ureg.count)
