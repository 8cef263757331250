"""Checks on the motion a path implies: per-axis speed and acceleration, named where they fail."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import InvalidArgument, LimitError
from galil.models import get_model

TS = 1 / 1024
AC_MAX = get_model("DMC-4040").ac_max
SP_MAX = get_model("DMC-4040").sp_max


def knot_accelerations(c: list[int], lengths: list[int], ts: float = TS) -> list[float]:
    """Written out by hand: segment speeds at their midpoints, rest at both ends."""
    times = [0.0]
    speeds = [0.0]
    t = 0.0
    for ci, n in zip(c, lengths, strict=True):
        times.append((t + n / 2) * ts)
        speeds.append(ci / (n * ts))
        t += n
    times.append(t * ts)
    speeds.append(0.0)
    return [(speeds[i + 1] - speeds[i]) / (times[i + 1] - times[i]) for i in range(len(times) - 1)]


def test_the_issue_contour_is_refused_naming_sample_and_acceleration() -> None:
    # dmc.contour("A", [0, 5] mm at 1000 counts/mm, dt=1): rest to 2.56e6 counts/s in 2 samples
    with pytest.raises(LimitError) as info:
        predict.check_contour([0, 5000], 1, axis="A")
    err = info.value
    assert err.name == "acceleration"
    assert err.value == pytest.approx(2500 / 2 * 1024**2)  # 1.31e9 counts/s²
    assert err.limit == AC_MAX
    assert err.sample == 2
    assert err.time == pytest.approx(2 * TS)
    assert err.axis == "A"
    assert "segment 0 -> 1" in str(err)
    assert "sample 2" in str(err)
    assert "DMC-4040 maximum" in str(err)


def test_a_first_segment_from_rest_needs_twice_its_speed_over_its_length() -> None:
    # one constant acceleration a over T from rest moves a*T²/2: the check gives a back
    report = predict.check_motion([1000], samples=8)
    a = 2 * 1000 / (8 * TS) ** 2
    assert report.peak_accel == (pytest.approx(a),)
    assert report.peak_speed == (pytest.approx(1000 / (8 * TS)),)
    predict.check_contour([1000], 3, accel_limit=a * 1.001)
    with pytest.raises(LimitError) as info:
        predict.check_contour([1000], 3, accel_limit=a * 0.999, axis="C")
    assert info.value.sample == 0
    assert "start into segment 0" in str(info.value)
    assert "the limit given" in str(info.value)


def test_the_stop_at_the_end_is_checked() -> None:
    # a gentle ramp up, then the path just ends at speed
    c = [100, 200, 300, 400, 500, 600]
    accels = knot_accelerations(c, [4] * 6)
    limit = max(abs(a) for a in accels[:-1]) * 1.01
    assert abs(accels[-1]) > limit
    with pytest.raises(LimitError) as info:
        predict.check_contour(c, 2, accel_limit=limit)
    assert info.value.sample == 24
    assert "stop after segment 5" in str(info.value)


def test_speed_over_the_model_maximum_names_the_segment() -> None:
    c = [1000, 20_000, 30_000, 20_000]  # 30000 counts in 1 sample... of DT 1: 15.4 M counts/s
    predict.check_contour(c, 1, accel_limit=1e12)
    with pytest.raises(LimitError) as info:
        predict.check_motion(c, samples=1, accel_limit=1e12, axes="B")
    err = info.value
    assert err.name == "speed"
    assert err.value == pytest.approx(30_000 * 1024)
    assert err.limit == SP_MAX
    assert err.sample == 2
    assert err.axis == "B"
    assert "segment 2 (samples 2..3)" in str(err)


@settings(max_examples=80, deadline=None)
@given(
    segments=st.lists(
        st.tuples(st.integers(-32_000, 32_000), st.integers(1, 8)), min_size=1, max_size=40
    ),
    fraction=st.floats(0.1, 1.5),
)
def test_contour_acceleration_is_the_hand_written_one(
    segments: list[tuple[int, int]], fraction: float
) -> None:
    c = [x for x, _ in segments]
    dt = [n for _, n in segments]
    expected = knot_accelerations(c, [2**n for n in dt])
    peak = max(abs(a) for a in expected)
    if peak == 0:
        return  # a path that never moves: no limit to test it against
    report = predict.check_motion(c, samples=[2**n for n in dt], accel_limit=1e15)
    assert report.peak_accel == (pytest.approx(peak),)
    limit = peak * fraction
    if peak == 0 or fraction > 1.001:
        predict.check_contour(c, dt, accel_limit=limit, speed_limit=1e12)
    elif fraction < 0.999:
        with pytest.raises(LimitError) as info:
            predict.check_contour(c, dt, accel_limit=limit, speed_limit=1e12)
        first = next(i for i, a in enumerate(expected) if abs(a) > limit)
        starts = np.concatenate([[0], np.cumsum([2**n for n in dt])])
        assert info.value.sample == starts[first]
        assert info.value.value == pytest.approx(abs(expected[first]))


def test_limits_per_axis_and_positions_or_increments() -> None:
    path = np.array([[0, 0], [100, 1000], [300, 3000], [400, 4000]], dtype=float)
    by_pos = predict.check_motion(positions=path, samples=16, axes="XY")
    by_inc = predict.check_motion(np.diff(path, axis=0), samples=16, axes="XY")
    assert by_pos == by_inc
    assert by_pos.peak_accel[1] == pytest.approx(10 * by_pos.peak_accel[0])
    y_peak = by_pos.peak_accel[1]
    predict.check_motion(positions=path, samples=16, accel_limit=[None, y_peak * 1.01])
    with pytest.raises(LimitError) as info:
        predict.check_motion(
            positions=path, samples=16, axes="XY", accel_limit=[y_peak, y_peak * 0.5]
        )
    assert info.value.axis == "Y"


def test_a_jog_with_an_ip_step_is_an_acceleration() -> None:
    smooth = predict.jog(20_000, 256_000, 256_000, stop_at=0.5)
    predict.check(smooth, axis="A")
    predict.check_profile_motion(smooth, accel_limit=256_000)
    stepped = predict.jog(
        20_000, 256_000, 256_000, stop_at=0.5, events=[predict.Increment(0.25, 3000)]
    )
    with pytest.raises(LimitError) as info:
        predict.check(stepped, axis="A")
    assert info.value.name == "acceleration"
    # IP at sample 256: the segment starting there (the step into sample 257) jumps
    assert info.value.sample == 256
    assert stepped.position[257] - stepped.position[256] > 3000
    assert info.value.axis == "A"


def test_a_jog_still_running_need_not_stop_and_may_start_moving() -> None:
    running = predict.jog(40_000, 512_000, 512_000, duration=0.5, initial_speed=40_000)
    assert running.stop_code == 0
    report = predict.check_profile_motion(running, accel_limit=512_000)
    assert report.peak_speed[0] == pytest.approx(40_000, rel=0.03)
    # the same samples read as a path that ends at rest need a hard stop
    with pytest.raises(LimitError, match="stop after"):
        predict.check_motion(
            positions=running.position, start_velocity=40_000, rounding=0.5, accel_limit=512_000
        )


@settings(max_examples=60, deadline=None)
@given(
    distance=st.integers(-50_000, 50_000).filter(bool),
    speed=st.integers(10, 400).map(lambda x: x * 500.0),
    accel=st.integers(10, 2000).map(lambda x: x * 1024.0),
    it=st.sampled_from([1.0, 0.5, 0.1]),
)
def test_a_predicted_move_passes_at_its_own_speed_and_acceleration(
    distance: int, speed: float, accel: float, it: float
) -> None:
    p = predict.move(distance, speed, accel, accel, smoothing=it)
    predict.check_profile_motion(p, speed_limit=speed, accel_limit=accel)


def test_empty_and_malformed_paths() -> None:
    assert predict.check_motion(np.zeros((0, 2))).peak_accel == (0.0, 0.0)
    assert predict.check_contour([], 1) is None
    with pytest.raises(InvalidArgument, match="either"):
        predict.check_motion()
    with pytest.raises(InvalidArgument, match="either"):
        predict.check_motion([1], positions=[0, 1])
    with pytest.raises(InvalidArgument, match="one value per axis"):
        predict.check_motion(np.ones((3, 2)), accel_limit=[1.0])
    with pytest.raises(InvalidArgument, match="positive"):
        predict.check_motion([1, 2], speed_limit=0)
    with pytest.raises(InvalidArgument, match="at least one sample"):
        predict.check_motion([1, 2], samples=0)
    with pytest.raises(InvalidArgument, match="finite"):
        predict.check_motion([1.0, float("nan")])
