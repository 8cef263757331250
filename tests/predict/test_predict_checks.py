"""Pre-send checks, contour prediction and speed schedules."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from galil import contour as planner
from galil import predict
from galil.errors import InvalidArgument, LimitError
from galil.predict.checks import contour_bytes
from galil.protocol import commands as cmds
from galil.protocol.numbers import format_reply


def test_quantise_as_the_controller_stores_values() -> None:
    q = predict.quantise("DMC-4040", speed=12_345, accel=150_000, decel=500)
    assert q.accel == 149_504  # the manual's example: AC 150000 reads back 149504
    assert q.decel == 1024  # at least one step
    assert q.speed == 12_344
    assert q.sample_period == pytest.approx(1 / 1024)
    assert predict.quantise("DMC-4040", speed=-3001, jog=True).speed == -3000
    assert predict.quantise("DMC-1500").sample_period == 0.002
    assert predict.quantise(smoothing=0.5).smoothing == 0.5
    assert predict.quantise(smoothing=0.004).smoothing == 1 / 256


def test_quantisation_follows_the_tm_in_force() -> None:
    # SP step 2*(1000/TM) counts/s, AC/DC step and minimum 1024*(1000/TM)**2 counts/s²
    # (DMC-4103 command reference; docs/decisions/0025): at TM 250, 8 and 16384.
    q = predict.quantise("DMC-4040", speed=25_005, accel=40_000, decel=1_500, tm=250)
    assert (q.speed, q.accel, q.decel) == (25_000, 32_768, 16_384)
    assert q.sample_period == pytest.approx(250 / 1_024_000)
    assert predict.quantise("DMC-4040", speed=-25_007, jog=True, tm=500).speed == -25_004
    odd = predict.quantise_speed(25_005, "DMC-4040", tm=187.5)  # a step of 10.666... counts/s
    assert odd == pytest.approx(2344 * 2000 / 187.5)
    assert predict.quantise_speed(odd, "DMC-4040", tm=187.5) == odd  # stored values stay put
    assert predict.check_parameter("AC", 5_000, "DMC-4040", tm=2000) == 4_864  # 256-steps


#: A value this close below a step goes out on the wire as the step (four decimals).
HALF_DIGIT = 0.5e-4 + 0.5 / 65536  # (and the 32.16 the controller holds it in)


@settings(max_examples=100, deadline=None)
@given(value=st.floats(1, 67_107_840))
@example(value=3071.9999999925494)  # (written "3072" on the wire: stored as 3072)
def test_quantised_accel_is_the_multiple_of_1024_the_wire_value_rounds_down_to(
    value: float,
) -> None:
    q = predict.quantise_accel(value, "DMC-2183")
    assert q % 1024 == 0
    assert q >= 1024
    assert q <= max(value + HALF_DIGIT, 1024)
    assert q > value - 1024


@settings(max_examples=200, deadline=None)
@given(value=st.floats(0, 22_000_000), k=st.integers(2, 640))
@example(value=21999999.999999996, k=219)  # (q and value - step one ulp across)
@example(value=14755993.75, k=185)  # (its step times n lands a hair above 14755993.6)
@example(value=22_000_000.0, k=459)  # (the maximum: not a step beyond it)
@example(value=1038.875, k=636)  # (stored 1038.79245...: in 32.16, printed 1038.7924)
def test_a_tm_scaled_speed_is_the_largest_step_not_above_the_wire_value_and_stays_put(
    value: float, k: int
) -> None:
    tm = 31.25 * k  # TM's own grid, 62.5 ... 20,000 µs
    step = 2 * 1000 / tm
    q = predict.quantise_speed(value, "DMC-4040", tm=tm)
    # (n * step and value - step are each rounded: they may cross by an ulp or two)
    assert value - step < q + 4 * math.ulp(value)
    assert q <= value + HALF_DIGIT  # (a value just short of a step is written as it)
    assert predict.quantise_speed(q, "DMC-4040", tm=tm) == q
    # what SP ? answers (four decimals) reads back as the same step
    assert predict.quantise_speed(round(q, 4), "DMC-4040", tm=tm) == q
    # and what MG _SPA prints: the 32.16 value the controller holds, at four decimals
    # (1/65536 below the step, then rounded down: up to 5.8e-5 short of it)
    printed = float(format_reply(float(q), "10.4"))
    assert predict.quantise_speed(printed, "DMC-4040", tm=tm) == q


def test_out_of_range_values_name_value_and_limit() -> None:
    with pytest.raises(LimitError) as info:
        predict.quantise("DMC-2183", accel=100_000_000)
    assert info.value.name == "AC"
    assert info.value.limit == 67_107_840
    assert info.value.value == 100_000_000
    with pytest.raises(LimitError) as info:
        predict.quantise("DMC-4040", speed=30_000_000)
    assert info.value.name == "SP"
    with pytest.raises(LimitError) as info:
        predict.quantise("DMC-4040", decel=-5)
    assert info.value.name == "DC"
    with pytest.raises(LimitError) as info:
        predict.quantise(smoothing=2)
    assert info.value.name == "IT"


def test_soft_limits_checked_over_the_whole_path_not_the_end() -> None:
    # out and back: the end is inside the limits, the middle is not
    p = predict.contour([200, 200, 200, -300, -300], 4)
    assert p.end == 0
    with pytest.raises(LimitError) as info:
        predict.check(p, forward_limit=450)
    err = info.value
    assert err.name == "FL"
    assert err.limit == 450
    assert err.value == p.position[err.sample]
    assert p.position[err.sample] > 450
    assert np.all(p.position[: err.sample] <= 450)
    assert err.time == pytest.approx(err.sample / 1024)
    predict.check(p, forward_limit=600, backward_limit=-1)
    with pytest.raises(LimitError) as info:
        predict.check(predict.move(-5000, 10_240, 102_400, 102_400), backward_limit=-4000, axis="B")
    assert info.value.name == "BL"
    assert info.value.axis == "B"
    assert info.value.time is not None
    assert info.value.time < 5000 / 10_240 + 0.2


def test_check_returns_the_quantised_values() -> None:
    p = predict.move(1000, 10_000, 102_400, 102_400)
    checked = predict.check(p, model="DMC-4040", speed=10_001, accel=102_401, decel=102_400)
    assert checked.quantised.speed == 10_000
    assert checked.quantised.accel == 102_400
    assert checked.stream is None


def test_contour_increments_must_fit_cd_range_and_dt() -> None:
    with pytest.raises(LimitError) as info:
        predict.check(increments=[100, 40_000, 5], dt=3, model="DMC-4040")
    assert info.value.name == "CD"
    assert info.value.value == 40_000
    assert info.value.limit == 32_000
    assert info.value.sample == 8
    with pytest.raises(LimitError) as info:
        predict.check_contour([1, 2], [3, 9])
    assert info.value.name == "DT"
    with pytest.raises(LimitError) as info:
        predict.check_contour([32_500], 3, model="DMC-18x2")
    assert info.value.limit == 32_000
    predict.check_contour([32_500], 3, model="DMC-1806")  # ±32,762 there


def test_contour_stream_too_slow_for_serial() -> None:
    c = np.full(500, 100)
    with pytest.raises(LimitError) as info:
        predict.check_contour(c, 1, baud=9600)
    assert info.value.name == "link byte rate"
    assert info.value.limit == pytest.approx(960 * 0.8)
    report = predict.check_contour(c, 6, baud=115_200)
    assert report is not None
    assert report.needed_rate < report.link_rate
    # 500 segments of 64 ms each, "CD 100" (7 bytes) at 11.5 kB/s: each is sent long before
    # it runs, the first of them after the "=6" of the DT (9 bytes).
    assert report.bytes_total == 9 + 499 * 7
    assert report.min_slack > 0.05
    assert predict.check_contour(c, 1, ethernet=True) is not None


def test_contour_bytes_are_the_bytes_the_builder_writes() -> None:
    c = [100, -5, 0, 12345, -32000, 7]
    dt = [3, 3, 4, 4, 4, 1]
    wire = []
    for i, (inc, n) in enumerate(zip(c, dt, strict=True)):
        changed = i == 0 or dt[i - 1] != n
        wire.append(len(cmds.cd(inc, dt=n if changed else None).text) + 1)  # + CR
    assert contour_bytes(c, dt).tolist() == wire


def test_contour_buffer_runs_dry_when_fast_segments_come_first() -> None:
    # on average the link keeps up, but the first hundred segments need 4 kB/s
    c = np.full(200, 50)
    dt = np.array([1] * 100 + [8] * 100)
    with pytest.raises(LimitError) as info:
        predict.check_contour(c, dt, link_rate=2000, utilisation=1.0, buffer_depth=511)
    err = info.value
    assert err.name == "contour stream"
    assert err.sample is not None
    assert 0 < err.sample <= 200
    assert err.value > err.limit
    # preloading the buffer (DT -1 on 40x0) makes it feasible
    ok = predict.check_contour(c, dt, link_rate=2000, utilisation=1.0, preload=True)
    assert ok is not None
    assert ok.min_slack >= 0
    # a one-deep buffer cannot be preloaded far enough
    with pytest.raises(LimitError):
        predict.check_contour(c, dt, link_rate=2000, utilisation=1.0, preload=True, buffer_depth=1)


def test_contour_manual_example() -> None:
    p = predict.contour([48, 240, 48], [2, 3, 4])
    assert p.shape == "contour"
    assert p.position[4] == 48
    assert p.position[12] == 288
    assert p.position[28] == 336
    assert list(p.position[1:5]) == [12, 24, 36, 48]
    assert p.samples == 28
    assert p.stop_code == 51


def test_one_minus_cos_contour_example() -> None:
    # 6000 counts in 120 ms, x = 50T - (6000/2pi) sin(2pi T/120), T in ms; DT 3 on a 1 ms loop
    def x(t: np.ndarray) -> np.ndarray:
        ms = t * 1000
        return 50 * ms - 6000 / (2 * math.pi) * np.sin(2 * math.pi * ms / 120)

    path = planner.sample_path(x, 0.120, 3, sample_period=0.001)
    assert path.size == 15
    inc = planner.increments(path)
    assert inc.sum() == 6000
    assert np.max(np.abs(np.cumsum(inc) - path)) <= 0.5
    predict.check_contour(inc, 3, model="DMC-18x2")
    p = predict.contour(inc, 3, sample_period=0.001)
    assert p.samples == 120
    assert p.end == 6000
    ideal = x(p.t)
    # linear interpolation of x inside 8 ms segments: error <= h²/8 max|x''| (+ rounding)
    bound = 8**2 / 8 * 50 * 2 * math.pi / 120 + 1.5
    assert np.max(np.abs(p.position - ideal)) <= bound
    # the speed is 1 - cos shaped: zero at both ends, 100 counts/ms in the middle
    assert p.peak_speed <= 100_000 * 1.01
    assert abs(p.velocity[1]) < 5000


def test_contour_bad_input() -> None:
    with pytest.raises(InvalidArgument):
        predict.contour([1.5], 2)
    with pytest.raises(InvalidArgument):
        predict.contour([1], 0)


def test_speed_schedule_seed_example() -> None:
    # "AC.05 DE.15 VE50 DI15 DC5 VE10 DC5 VE5 GO" with 1000 counts per unit
    u = 1000
    ac, dc = 50 * u / 0.05, 50 * u / 0.15
    s = predict.speed_schedule(15 * u, 50 * u, [(5 * u, 10 * u), (10 * u, 5 * u)], ac, dc)
    assert s.triggers == (5 * u, 10 * u)
    assert s.speeds == (50 * u, 10 * u, 5 * u)
    assert s.ramp_ends[0] == pytest.approx(1.25 * u)
    assert s.ramp_ends[1] == pytest.approx(8.6 * u)
    p = s.profile
    assert p.end == 15 * u
    assert p.stop_code == 1
    # at each trigger the speed is still the previous one, and it settles on the new one
    ts = p.sample_period
    for trig, before, after in [(5 * u, 50 * u, 10 * u), (10 * u, 10 * u, 5 * u)]:
        k = int(np.argmax(p.profiler >= trig))
        v = np.diff(p.profiler) / ts
        assert np.mean(v[k - 20 : k - 1]) == pytest.approx(before, rel=0.03)
        settle = k + int(abs(before - after) / dc / ts) + 5
        assert np.mean(v[settle : settle + 20]) == pytest.approx(after, rel=0.06)


def test_speed_schedule_reports_the_earliest_valid_trigger() -> None:
    u = 1000
    ac, dc = 50 * u / 0.05, 50 * u / 0.15
    with pytest.raises(predict.ScheduleError) as info:
        predict.speed_schedule(15 * u, 50 * u, [(5 * u, 10 * u), (7 * u, 5 * u)], ac, dc)
    assert info.value.index == 1
    assert info.value.earliest == math.ceil(8.6 * u)
    assert info.value.limit == info.value.earliest
    # the earliest point it names is valid
    predict.speed_schedule(15 * u, 50 * u, [(5 * u, 10 * u), (8600, 5 * u)], ac, dc)
    with pytest.raises(predict.ScheduleError) as info:
        predict.speed_schedule(1000, 50 * u, [], ac, dc)
    assert info.value.index == 0
    assert info.value.earliest == math.ceil(1250 + 50 * u * 50 * u / (2 * dc))
    with pytest.raises(predict.ScheduleError) as info:
        predict.speed_schedule(15 * u, 50 * u, [(1000, 10 * u)], ac, dc)
    assert info.value.earliest == 1250


def test_soft_limits_refuse_only_outward_motion() -> None:
    # An axis already past FL may come back inside; it may not go further out.
    back = predict.move(-4500, 10_000, 102_400, 102_400, start=5000)
    predict.check_soft_limits(back, forward_limit=1000)
    further = predict.move(500, 10_000, 102_400, 102_400, start=5000)
    with pytest.raises(LimitError) as info:
        predict.check_soft_limits(further, forward_limit=1000)
    assert info.value.name == "FL"
    assert info.value.sample is not None
    assert info.value.sample > 0
    below = predict.move(4500, 10_000, 102_400, 102_400, start=-5000)
    predict.check_soft_limits(below, backward_limit=-1000)


def test_profile_with_units_changes_only_what_is_shown() -> None:
    p = predict.move(25_000, 25_000, 256_000, 256_000)
    shown = p.with_units(-2000.0, "mm", offset=5.0)
    assert shown.position is p.position  # arrays stay in counts
    rows = dict(predict.profile._summary_rows(shown))
    assert rows["start → end"].startswith("5 → -7.5 mm")
    assert rows["peak speed"].startswith("12.5 mm/s")
    fig = shown.plot()
    assert fig.axes[0].get_ylabel() == "position (mm)"
    assert fig.axes[0].lines[0].get_ydata()[-1] == pytest.approx(-7.5)
    with pytest.raises(InvalidArgument):
        p.with_units(0.0, "mm")
