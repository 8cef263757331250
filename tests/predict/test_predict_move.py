"""Rules of the profiler model for position moves, jogs and changes in motion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import CommandError, InvalidArgument
from galil.predict.engine import AxisProfiler

SETTINGS = settings(max_examples=150, deadline=None)

# bounded so a move lasts at most ~40 s (keeps the suite fast)
distances = st.integers(-200_000, 200_000).filter(lambda d: d != 0)
speeds = st.integers(10, 2000).map(lambda x: x * 500.0)
accels = st.integers(1, 2000).map(lambda x: x * 1024.0)
periods = st.sampled_from([1 / 1024, 1 / 2048, 0.002])


def closed_form(
    distance: float, sp: float, ac: float, dc: float
) -> tuple[float, float, str, object]:
    """Continuous profile written independently of the library: (T, peak, shape, x(t))."""
    d = abs(distance)
    sign = math.copysign(1, distance)
    if d >= sp * sp / (2 * ac) + sp * sp / (2 * dc):
        peak, shape = sp, "trapezoid"
    else:
        peak, shape = math.sqrt(2 * d * ac * dc / (ac + dc)), "triangle"
    ta, td = peak / ac, peak / dc
    tc = (d - peak * peak / (2 * ac) - peak * peak / (2 * dc)) / peak
    total = ta + max(tc, 0) + td

    def x(t: np.ndarray) -> np.ndarray:
        t = np.clip(t, 0, total)
        acc = 0.5 * ac * np.minimum(t, ta) ** 2
        cruise = peak * np.clip(t - ta, 0, max(tc, 0))
        t3 = np.clip(t - ta - max(tc, 0), 0, td)
        dec = peak * t3 - 0.5 * dc * t3 * t3
        return sign * (acc + cruise + dec)

    return total, peak, shape, x


@SETTINGS
@given(
    distance=distances, sp=speeds, ac=accels, dc=accels, ts=periods, start=st.integers(-1000, 1000)
)
def test_move_obeys_every_rule_of_the_model(
    distance: int, sp: float, ac: float, dc: float, ts: float, start: int
) -> None:
    p = predict.move(distance, sp, ac, dc, sample_period=ts, start=start)
    total, peak, shape, x = closed_form(distance, sp, ac, dc)
    r = p.position
    # r[0] is the start and r[N] exactly the target
    assert r[0] == start
    assert r[-1] == start + distance
    # N within 2 samples of the closed-form duration
    assert abs(p.samples - total / ts) <= 2
    assert p.duration == pytest.approx(p.samples * ts)
    # trapezoid or triangle chosen by the rule, with the right peak
    assert p.shape == shape
    assert p.peak_speed == pytest.approx(peak, rel=1e-9)
    # fidelity to the closed form at every sample
    ideal = start + x(np.arange(r.size) * ts)
    assert np.max(np.abs(r - ideal)) <= sp * ts + 2
    # velocity never above SP; accel/decel per sample bounded; one count of rounding
    steps = np.diff(r)
    assert np.max(np.abs(steps)) <= sp * ts + 1
    assert np.max(np.abs(np.diff(steps)), initial=0) <= max(ac, dc) * ts * ts + 2
    # no reversal in a plain move
    assert np.all(np.sign(steps) * np.sign(distance) >= 0)


@settings(max_examples=60, deadline=None)
@given(
    distance=distances,
    sp=speeds,
    ac=accels,
    dc=accels,
    chunks=st.lists(st.integers(1, 2000), min_size=1, max_size=5),
)
def test_predict_move_equals_the_stepped_engine(
    distance: int, sp: float, ac: float, dc: float, chunks: list[int]
) -> None:
    p = predict.move(distance, sp, ac, dc, start=5)
    eng = AxisProfiler(position=5)
    eng.begin_move(5 + distance, sp, ac, dc)
    out = [np.array([5])]
    i = 0
    while eng.moving:
        out.append(eng.advance(chunks[i % len(chunks)]))
        i += 1
    stepped = np.concatenate(out)
    assert np.array_equal(stepped[: p.position.size], p.position)
    assert np.all(stepped[p.position.size :] == 5 + distance)


@settings(max_examples=40, deadline=None)
@given(
    distance=distances.filter(lambda d: abs(d) >= 1000),
    sp=speeds,
    ac=accels,
    ratio=st.sampled_from([0.25, 0.5, 1.0, 2.0, 4.0]),
)
def test_durations_agree_with_ruckig_at_high_jerk(
    distance: int, sp: float, ac: float, ratio: float
) -> None:
    # ruckig's solver is not robust at extreme jerk/accel ratios, so keep the inputs sane
    ruckig = pytest.importorskip("ruckig")
    dc = ac * ratio
    # ruckig solves best in units of order one: scale distances by |distance| (times unchanged)
    s = float(abs(distance))
    inp = ruckig.InputParameter(1)
    inp.current_position = [0.0]
    inp.target_position = [distance / s]
    inp.max_velocity = [sp / s]
    up, down = (ac, dc) if distance > 0 else (dc, ac)
    inp.max_acceleration = [up / s]
    inp.min_acceleration = [-down / s]
    jerk = 2000 * max(ac, dc)
    inp.max_jerk = [jerk / s]
    traj = ruckig.Trajectory(1)
    ruckig.Ruckig(1).calculate(inp, traj)
    ts = 1 / 1024
    p = predict.move(distance, sp, ac, dc, sample_period=ts)
    # a finite jerk adds at most about 2 * accel/jerk per ramp
    slack = 2 * ts + 4 * max(ac, dc) / jerk + 1e-6 * traj.duration
    assert abs(p.duration - traj.duration) <= slack


def test_fig_6_1_trapezoids_and_a_triangle_with_the_same_slopes() -> None:
    sp, ac, dc = 10_240, 102_400, 102_400
    axes = predict.together(
        {
            "X": predict.move(20_000, sp, ac, dc),
            "Y": predict.move(-30_000, sp, ac, dc),
            "Z": predict.move(500, sp, ac, dc),
        }
    )
    assert axes["X"].shape == "trapezoid"
    assert axes["Y"].shape == "trapezoid"
    assert axes["Z"].shape == "triangle"
    assert axes["Z"].peak_speed < sp
    assert axes["X"].peak_speed == axes["Y"].peak_speed == sp
    # same acceleration: the rising edges coincide sample for sample until Z must slow down
    ramp = int(axes["Z"].peak_speed / ac * 1024) - 1
    x = axes["X"].position[:ramp]
    # Y is the mirror image, up to half-way values (rounded up, so -12.5 -> -12, 12.5 -> 13)
    assert np.max(np.abs(x + axes["Y"].position[:ramp])) <= 1
    assert np.array_equal(x, axes["Z"].position[:ramp])
    # and the falling edges have the same slope (fit of velocity against time)
    for name in "XYZ":
        p = axes[name].profiler
        n = round(axes[name].duration * 1024)  # its own end, not the padded one
        t = np.arange(p.size) / 1024
        v = np.diff(p) * 1024
        tail = slice(n - int(axes[name].peak_speed / dc * 1024) + 3, n - 3)
        slope = np.polyfit(t[1:][tail], np.abs(v[tail]), 1)[0]
        assert slope == pytest.approx(-dc, rel=0.05)
    assert axes.duration == axes["Y"].duration
    assert axes["Z"].position.size == axes["Y"].position.size  # padded on one time base
    assert axes["Z"].position[-1] == 500


def test_ip_retarget_and_speed_change_events() -> None:
    base = predict.move(10_000, 10_240, 102_400, 102_400)
    longer = predict.move(10_000, 10_240, 102_400, 102_400, events=[predict.Increment(0.3, 4000)])
    assert longer.end == 14_000
    assert longer.shape == "changed"
    assert longer.duration > base.duration
    # until the event both predictions are the same
    k = round(0.3 * 1024)
    assert np.array_equal(longer.position[: k + 1], base.position[: k + 1])
    with pytest.raises(CommandError) as info:
        predict.move(10_000, 10_240, 102_400, 102_400, events=[predict.Increment(0.3, -4000)])
    assert info.value.code == 16
    faster = predict.move(40_000, 10_240, 102_400, 102_400, events=[predict.SetSpeed(0.5, 20_480)])
    assert faster.peak_speed == pytest.approx(20_480)
    assert faster.end == 40_000
    assert np.max(np.diff(faster.position)) <= 20_480 / 1024 + 1


def test_st_during_a_move_decelerates_at_dc() -> None:
    p = predict.move(100_000, 10_240, 102_400, 51_200, events=[predict.Stop(0.5)])
    assert p.shape == "stopped"
    assert p.stop_code == 4
    assert p.end < 100_000
    k = round(0.5 * 1024)
    # from the stop the velocity falls to zero in SP/DC seconds
    assert abs((p.samples - k) / 1024 - 10_240 / 51_200) <= 2 / 1024


@settings(max_examples=60, deadline=None)
@given(
    js=st.lists(st.integers(-40, 40).map(lambda x: x * 512.0), min_size=1, max_size=4),
    ac=accels,
    dc=accels,
)
def test_jog_ramps_respect_ac_when_growing_and_dc_when_shrinking(
    js: list[float], ac: float, dc: float
) -> None:
    ts = 1 / 1024
    changes = [(0.25 * (i + 1), j) for i, j in enumerate(js[1:])]
    p = predict.jog(js[0], ac, dc, changes=changes, duration=0.25 * len(js) + 0.5)
    v = np.diff(p.profiler).astype(float)
    dv = np.diff(v)
    assert np.max(np.abs(dv), initial=0) <= max(ac, dc) * ts * ts + 2
    assert np.max(np.abs(v), initial=0) <= max(abs(j) for j in js) * ts + 1
    if not changes:  # one jog: the engine run directly gives the same samples
        eng = AxisProfiler()
        eng.begin_jog(js[0], ac, dc)
        assert np.array_equal(eng.advance(p.samples), p.profiler[1:])


# Closed forms for a slow-down in the same direction (the rate must be DC, not AC): from rest
# to 20,480 counts/s at AC 204,800 (0.1 s, 1,024 counts), cruise to t = 1 s (19,456 counts),
# then 10,240 counts/s: 0.2 s at DC 51,200 adds 4,096 - 1,024 counts (at AC it would be
# 0.05 s, and 768 counts fewer by t = 1.2 s).
SLOWED_AT_1_2 = 19_456 + 20_480 * 0.2 - 0.5 * 51_200 * 0.2**2


def test_a_jog_slowed_in_its_direction_ramps_at_dc_closed_form() -> None:
    p = predict.jog(20_480, 204_800, 51_200, changes=[(1.0, 10_240)], duration=1.5)
    assert p.at(1.0) == pytest.approx(19_456, abs=25)
    assert p.at(1.2) == pytest.approx(SLOWED_AT_1_2, abs=25)
    assert p.at(1.5) == pytest.approx(SLOWED_AT_1_2 + 10_240 * 0.3, abs=25)


def test_a_move_slowed_by_sp_ramps_at_dc_closed_form() -> None:
    p = predict.move(60_000, 20_480, 204_800, 51_200, events=[predict.SetSpeed(1.0, 10_240)])
    assert p.at(1.2) == pytest.approx(SLOWED_AT_1_2, abs=25)
    # then 10,240 counts/s until the last 1,024 counts, which take 0.2 s at DC
    cruise = (60_000 - SLOWED_AT_1_2 - 1_024) / 10_240
    assert p.duration == pytest.approx(1.2 + cruise + 0.2, abs=3 / 1024)
    assert p.end == 60_000


def test_a_decel_changed_in_a_jog_sets_the_rate_of_its_later_ramp_down_closed_form() -> None:
    # The same slow-down as above, with DC 204,800 given at 0.5 s and changed to 51,200 at
    # 0.9 s: the ramp at 1 s runs at the last DC.
    p = predict.jog(
        20_480,
        204_800,
        204_800,
        changes=[(1.0, 10_240)],
        events=[predict.SetDecel(0.5, 409_600), predict.SetDecel(0.9, 51_200)],
        duration=1.5,
    )
    assert p.at(1.2) == pytest.approx(SLOWED_AT_1_2, abs=25)
    assert p.at(1.5) == pytest.approx(SLOWED_AT_1_2 + 10_240 * 0.3, abs=25)


def test_a_decel_changed_mid_ramp_and_mid_stop_re_plans_from_the_present_state() -> None:
    # 20,480 counts/s, then JG 0 at 1 s (DC 51,200: 0.4 s), DC 204,800 at 1.1 s: 15,360
    # counts/s left, gone in 0.075 s.
    ramp = predict.jog(
        20_480,
        204_800,
        51_200,
        changes=[(1.0, 0)],
        events=[predict.SetDecel(1.1, 204_800)],
        duration=1.5,
    )
    assert np.all(ramp.velocity[round(1.18 * 1024) :] == 0)
    assert ramp.velocity[round(1.17 * 1024)] != 0
    # The same with ST: the stop's ramp re-plans too, and it ends with stop code 4.
    stop = predict.jog(
        20_480, 204_800, 51_200, stop_at=1.0, events=[predict.SetDecel(1.1, 204_800)]
    )
    assert stop.stop_code == 4
    assert stop.duration == pytest.approx(1.175, abs=2 / 1024)
    assert stop.end == ramp.position[-1]
    moved = predict.move(
        100_000, 20_480, 204_800, 51_200, events=[predict.Stop(1.0), predict.SetDecel(1.1, 204_800)]
    )
    assert moved.duration == pytest.approx(1.175, abs=2 / 1024)
    assert moved.stop_code == 4


def test_a_decel_change_in_a_position_move_is_refused_as_the_controller_does() -> None:
    with pytest.raises(CommandError) as info:
        predict.move(100_000, 20_480, 204_800, 51_200, events=[predict.SetDecel(0.5, 102_400)])
    assert info.value.code == 7
    # At rest (after the move) it is kept for what comes next: the IP's move ramps up for
    # 0.1 s, cruises 15,360 counts, ramps down 4,096 counts in 0.4 s (at DC 204,800 the
    # cruise would be 0.9 s and the ramp down 0.1 s: 1.7 s).
    later = predict.move(
        1_000,
        20_480,
        204_800,
        204_800,
        events=[predict.SetDecel(0.5, 51_200), predict.Increment(0.6, 20_480)],
    )
    assert later.duration == pytest.approx(0.6 + 0.1 + 0.75 + 0.4, abs=2 / 1024)


def test_jog_without_end_runs_until_the_ramp_settles_then_stop() -> None:
    p = predict.jog(-20_480, 204_800, 102_400)
    assert p.samples == pytest.approx(0.1 * 1024, abs=2)
    assert p.velocity[-1] == pytest.approx(-20_480, abs=1024)
    s = predict.jog(20_480, 204_800, 102_400, stop_at=1.0)
    assert s.stop_code == 4
    assert s.velocity[-1] == 0
    assert abs(s.duration - 1.2) <= 2 / 1024


def test_move_with_model_quantises_first() -> None:
    a = predict.move(10_000, 10_001, 150_000, 150_000, model="DMC-4040")
    b = predict.move(10_000, 10_000, 149_504, 149_504)
    assert np.array_equal(a.position, b.position)


def test_plan_move_matches_move() -> None:
    plan = predict.plan_move(123_456, 50_000, 512_000, 256_000)
    p = predict.move(123_456, 50_000, 512_000, 256_000)
    assert plan.samples == p.samples
    assert plan.shape == p.shape == "trapezoid"
    assert plan.peak_speed == 50_000
    assert plan.accel_time == pytest.approx(50_000 / 512_000)
    assert plan.decel_time == pytest.approx(50_000 / 256_000)
    total = plan.accel_time + plan.cruise_time + plan.decel_time
    assert plan.exact_duration == pytest.approx(total)


def test_smoothing_lengthens_and_ends_on_target() -> None:
    plain = predict.move(5000, 20_480, 204_800, 204_800)
    smooth = predict.move(5000, 20_480, 204_800, 204_800, smoothing=0.1)
    assert smooth.end == 5000
    assert smooth.duration > plain.duration
    assert np.array_equal(smooth.profiler[: plain.position.size], plain.position)
    assert np.max(np.abs(np.diff(smooth.position))) <= np.max(np.abs(np.diff(plain.position)))


def test_profile_at_plot_and_reprs() -> None:
    p = predict.move(1000, 10_240, 102_400, 102_400)
    assert p.at(0) == 0
    assert p.at(10.0) == 1000
    assert p.at(-1) == 0
    mid = p.at(np.array([0.0, p.duration / 2, p.duration]))
    assert mid[0] == 0
    assert mid[-1] == 1000
    assert 400 < mid[1] < 600
    assert p.shape == "triangle"  # 1,000 counts: too short to reach 10,240 counts/s
    assert "triangle" in p._repr_html_()
    assert "Profile" in repr(p)

    class Printer:
        def __init__(self) -> None:
            self.out = ""

        def text(self, s: str) -> None:
            self.out += s

    pr = Printer()
    p._repr_pretty_(pr, False)
    assert "duration" in pr.out
    fig = p.plot()
    assert len(fig.axes) == 3
    multi = predict.together({"A": p, "B": predict.move(-50, 1024, 10_240, 10_240)})
    assert len(multi.plot().axes) == 2
    assert "<table>" in multi._repr_html_()
    assert multi.position.shape == (2, p.position.size)


def test_bad_arguments() -> None:
    with pytest.raises(InvalidArgument):
        predict.move(100, 0, 1024, 1024)
    with pytest.raises(InvalidArgument):
        predict.move(100, 1000, -1, 1024)
    with pytest.raises(InvalidArgument):
        predict.move(100, 1000, 1024, 1024, events=[predict.Stop(-1)])
    with pytest.raises(InvalidArgument):
        predict.together({})
    with pytest.raises(InvalidArgument):
        predict.together(
            {
                "A": predict.move(1, 1000, 1024, 1024),
                "B": predict.move(1, 1000, 1024, 1024, sample_period=0.002),
            }
        )


def test_jog_from_an_existing_speed() -> None:
    p = predict.jog(-10_240, 102_400, 51_200, initial_speed=10_240)
    assert p.velocity[0] == 10_240
    # slows at DC to zero (0.2 s), then speeds up the other way at AC (0.1 s)
    assert abs(p.duration - 0.3) <= 2 / 1024
    assert p.velocity[-1] == pytest.approx(-10_240, abs=1024)
    assert p.peak_speed == pytest.approx(10_240)


def test_single_value_quantise_forms() -> None:
    assert predict.quantise_value("AC", 150_000, "DMC-4040") == 149_504
    assert predict.quantise_value("JG", -3001) == -3000
    assert predict.quantise_limits("DMC-2183")["AC"] == (1024, 67_107_840)
    with pytest.raises(InvalidArgument) as info:
        predict.check_parameter("DC", 2e9, "DMC-4040", axis="C")
    assert getattr(info.value, "axis", None) == "C"
    p = predict.move(100, 1000, 10_240, 10_240)
    with pytest.raises(InvalidArgument):
        predict.check_soft_limits(p, forward_limit=50)


def test_several_axes_are_shown_and_plotted_each_in_its_own_unit() -> None:
    # Before: the table and the plot were in counts while each mp["A"] showed mm, and the
    # shorter profile lost its unit when padded to the longer one.
    a = predict.move(20_000, 40_000, 400_000, 400_000).with_units(2000.0, "mm")
    b = predict.move(10_000, 40_000, 400_000, 400_000).with_units(2000.0, "mm")
    multi = predict.together({"A": a, "B": b})
    table = multi._repr_html_()
    assert "<td>10 mm</td><td>20 mm/s</td>" in table
    assert "<td>5 mm</td><td>20 mm/s</td>" in table
    assert multi["B"].display == (2000.0, 0.0, "mm")
    fig = multi.plot()
    assert fig.axes[0].get_ylabel() == "position (mm)"
    assert fig.axes[1].get_ylabel() == "velocity (mm/s)"
    assert max(fig.axes[0].lines[0].get_ydata()) == 10.0
    turns = predict.move(4096, 40_960, 409_600, 409_600).with_units(4096.0, "turn")
    mixed = predict.together({"A": a, "C": turns, "D": predict.move(100, 1024, 10_240, 10_240)})
    fig = mixed.plot()
    assert fig.axes[0].get_ylabel() == "position"
    assert [line.get_label() for line in fig.axes[0].lines] == ["A (mm)", "C (turn)", "D (counts)"]
    assert "<td>1 turn</td>" in mixed._repr_html_()
    assert "<td>100 counts</td><td>" in mixed._repr_html_()
