"""The shared motion engine: commands, refusals, and chunking independence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import CommandError, InvalidArgument
from galil.predict.engine import AxisProfiler

TS = 1 / 1024
SETTINGS = settings(max_examples=60, deadline=None)


def run_chunked(eng: AxisProfiler, total: int, chunks: list[int]) -> np.ndarray:
    """Advance ``total`` samples in the given (cycled) chunk sizes."""
    out = []
    done = 0
    i = 0
    while done < total:
        n = min(chunks[i % len(chunks)], total - done)
        out.append(eng.advance(n))
        done += n
        i += 1
    return np.concatenate(out)


def test_move_ends_exactly_on_target_and_reports_done() -> None:
    eng = AxisProfiler(position=100)
    eng.begin_move(10_100, 20_000, 256_000, 256_000)
    assert eng.moving
    assert eng.mode == "position"
    assert eng.stop_code == 0
    assert eng.target == 10_100
    end = eng.end_sample
    assert end is not None
    r = eng.advance(end)
    assert r[-1] == 10_100
    assert not eng.moving
    assert eng.stop_code == 1
    assert eng.mode == "idle"
    assert eng.position == eng.reference == 10_100
    # the sample before the end has not yet been flagged complete
    eng2 = AxisProfiler(position=100)
    eng2.begin_move(10_100, 20_000, 256_000, 256_000)
    eng2.advance(end - 1)
    assert eng2.moving


def test_idle_holds_position() -> None:
    eng = AxisProfiler(position=-7)
    assert list(eng.advance(5)) == [-7] * 5
    assert eng.sample == 5
    assert not eng.moving


def test_preview_does_not_commit() -> None:
    eng = AxisProfiler()
    eng.begin_move(5000, 10_000, 100_000, 100_000)
    p = eng.preview(100)
    assert eng.sample == 0
    assert np.array_equal(eng.advance(100), p)


@SETTINGS
@given(
    distance=st.integers(-200_000, 200_000),
    speed=st.integers(1, 500).map(lambda x: x * 1000),
    accel=st.integers(1, 400).map(lambda x: x * 1024),
    decel=st.integers(1, 400).map(lambda x: x * 1024),
    chunks=st.lists(st.integers(1, 97), min_size=1, max_size=6),
    it=st.sampled_from([1.0, 0.5, 0.125, 1 / 64]),
)
def test_chunking_does_not_change_the_output(
    distance: int, speed: int, accel: int, decel: int, chunks: list[int], it: float
) -> None:
    a = AxisProfiler(position=3)
    a.begin_move(3 + distance, speed, accel, decel, smoothing=it)
    b = AxisProfiler(position=3)
    b.begin_move(3 + distance, speed, accel, decel, smoothing=it)
    total = 3000
    whole = a.advance(total)
    parts = run_chunked(b, total, chunks)
    assert np.array_equal(whole, parts)
    assert a.moving == b.moving


@SETTINGS
@given(
    events=st.lists(
        st.tuples(
            st.integers(1, 400),
            st.sampled_from(["speed", "accel", "stop", "ip"]),
            st.integers(-30_000, 30_000),
        ),
        max_size=4,
    ),
    chunks=st.lists(st.integers(1, 60), min_size=1, max_size=5),
    it=st.sampled_from([1.0, 0.25]),
)
def test_same_events_same_samples_same_output(
    events: list[tuple[int, str, int]], chunks: list[int], it: float
) -> None:
    """Two engines given the same commands at the same samples agree, however chunked."""

    def drive(engine: AxisProfiler, step: list[int]) -> np.ndarray:
        engine.begin_jog(8000, 51_200, 25_600, smoothing=it)
        out = []
        k = 0
        j = 0
        for at, what, value in sorted(events):
            while k < at:
                n = min(step[j % len(step)], at - k)
                out.append(engine.advance(n))
                k += n
                j += 1
            try:
                if what == "speed":
                    engine.set_speed(value)
                elif what == "accel":
                    engine.set_accel(abs(value) + 1024)
                elif what == "stop":
                    engine.stop()
                else:
                    engine.increment(value // 100, 8000, 51_200, 25_600)
            except (CommandError, InvalidArgument):  # (a refused value: the sim's TC 6)
                pass
        out.append(engine.advance(1500))
        return np.concatenate(out)

    assert np.array_equal(drive(AxisProfiler(), [10_000]), drive(AxisProfiler(), chunks))


def test_bg_while_running_is_tc21() -> None:
    eng = AxisProfiler()
    eng.begin_move(1000, 1000, 10_240, 10_240)
    with pytest.raises(CommandError) as info:
        eng.begin_move(0, 1000, 10_240, 10_240)
    assert info.value.code == 21
    with pytest.raises(CommandError) as info:
        eng.begin_jog(1000, 10_240, 10_240)
    assert info.value.code == 21


def test_ip_wrong_sign_is_tc16_and_during_stop_too() -> None:
    eng = AxisProfiler()
    eng.begin_move(10_000, 10_000, 102_400, 102_400)
    eng.advance(50)
    with pytest.raises(CommandError) as info:
        eng.increment(-100, 10_000, 102_400, 102_400)
    assert info.value.code == 16
    eng.stop()
    assert eng.stop_code == 4
    with pytest.raises(CommandError) as info:
        eng.increment(100, 10_000, 102_400, 102_400)
    assert info.value.code == 16


def test_ip_retargets_a_position_move() -> None:
    eng = AxisProfiler()
    eng.begin_move(10_000, 10_000, 102_400, 102_400)
    eng.advance(100)
    eng.increment(2500, 10_000, 102_400, 102_400)
    assert eng.target == 12_500
    out = eng.advance(5000)
    assert out[-1] == 12_500
    assert np.all(np.diff(out) >= 0)  # no reversal
    assert not eng.moving
    assert eng.stop_code == 1


def test_ip_while_idle_is_pr_and_bg() -> None:
    a = AxisProfiler(position=50)
    a.increment(-700, 3000, 20_480, 20_480)
    b = AxisProfiler(position=50)
    b.begin_move(-650, 3000, 20_480, 20_480)
    assert np.array_equal(a.advance(2000), b.advance(2000))


def test_ip_while_jogging_is_an_instant_step() -> None:
    a = AxisProfiler()
    a.begin_jog(2048, 1_024_000, 1_024_000)
    b = AxisProfiler()
    b.begin_jog(2048, 1_024_000, 1_024_000)
    a.advance(10)
    b.advance(10)
    a.increment(500, 0, 1024, 1024)
    ra = a.advance(20)
    rb = b.advance(20)
    assert np.array_equal(ra - rb, np.full(20, 500))


def test_st_ramps_down_at_dc_and_reports_code_4() -> None:
    eng = AxisProfiler()
    eng.begin_jog(10_240, 102_400, 51_200)
    eng.advance(200)
    assert eng.velocity == pytest.approx(10_240)
    eng.stop()
    stop_samples = 10_240 / 51_200 / TS
    assert eng.end_sample is not None
    # the ramp takes the closed-form number of samples
    assert abs(eng.end_sample - 200 - stop_samples) <= 2
    out = eng.advance(int(stop_samples) + 5)
    assert not eng.moving
    assert eng.stop_code == 4
    steps = np.diff(out)
    # decelerates at DC: the per-sample velocity falls by DC*Ts² (+ rounding)
    assert np.all(np.abs(np.diff(steps)) <= 51_200 * TS * TS + 2)
    assert np.all(steps >= 0)


def test_limit_stop_uses_given_code() -> None:
    eng = AxisProfiler()
    eng.begin_move(100_000, 10_240, 102_400, 102_400)
    eng.advance(100)
    eng.limit_stop(2)
    assert eng.stop_code == 2
    eng.advance(1000)
    assert not eng.moving
    assert eng.stop_code == 2
    assert eng.position < 100_000


def test_abort_stops_instantly() -> None:
    eng = AxisProfiler()
    eng.begin_jog(10_240, 102_400, 102_400)
    eng.advance(300)
    here = eng.position
    eng.abort()
    assert not eng.moving
    assert eng.stop_code == 7
    assert eng.velocity == 0
    assert np.all(eng.advance(10) == here)


def test_jog_sign_change_passes_through_zero_at_dc_then_ac() -> None:
    ac, dc = 204_800, 51_200
    eng = AxisProfiler()
    eng.begin_jog(4096, ac, dc)
    eng.advance(100)
    x0, v0 = eng.position, 4096 * TS
    eng.set_speed(-4096)
    out = eng.advance(200)
    # closed form: slow down at DC to zero, then speed up the other way at AC
    d, a = dc * TS * TS, ac * TS * TS
    t1 = v0 / d
    t = np.arange(1, 201, dtype=float)
    x = np.where(
        t <= t1,
        x0 + v0 * t - 0.5 * d * t * t,
        x0
        + v0 * t1 / 2
        - 0.5 * a * np.minimum(t - t1, v0 / a) ** 2
        - v0 * np.maximum(t - t1 - v0 / a, 0),
    )
    # x0 is the rounded start: half a count there plus half a count of rounding now
    assert np.max(np.abs(out - x)) <= 1.0 + 1e-6
    assert eng.velocity == pytest.approx(-4096)


def test_speed_change_in_motion_replans() -> None:
    eng = AxisProfiler()
    eng.begin_move(50_000, 5120, 51_200, 51_200)
    eng.advance(200)
    eng.set_speed(10_240)
    out = eng.advance(20_000)
    v = np.diff(out) / TS
    assert v.max() > 9000
    assert out[-1] == 50_000
    assert not eng.moving


def test_accel_change_in_motion_replans() -> None:
    slow = AxisProfiler()
    slow.begin_move(50_000, 10_240, 10_240, 51_200)
    fast = AxisProfiler()
    fast.begin_move(50_000, 10_240, 10_240, 51_200)
    slow.advance(10)
    fast.advance(10)
    fast.set_accel(102_400)
    a = slow.advance(10_000)
    b = fast.advance(10_000)
    assert a[-1] == b[-1] == 50_000
    assert int(np.argmax(b == 50_000)) < int(np.argmax(a == 50_000))


def test_contour_manual_example() -> None:
    eng = AxisProfiler()
    eng.begin_contour()
    assert eng.mode == "contour"
    assert eng.stop_code == 50
    eng.add_segment(48, 2)
    eng.add_segment(240, 3)
    eng.add_segment(48, 4)
    assert eng.queued_segments == 3
    out = eng.advance(28)
    assert list(out[:4]) == [12, 24, 36, 48]
    assert out[3] == 48
    assert out[11] == 288
    assert out[27] == 336
    assert eng.queued_segments == 0
    # an empty queue holds position, still in contour mode
    assert np.all(eng.advance(5) == 336)
    assert eng.moving
    eng.end_contour()
    assert not eng.moving
    assert eng.stop_code == 51


def test_contour_chunking_and_floor_rule() -> None:
    segs = [(100, 4), (-37, 1), (5, 8), (-32_000, 3), (7, 2)]

    def build() -> AxisProfiler:
        e = AxisProfiler(position=10)
        e.begin_contour()
        for c, n in segs:
            e.add_segment(c, n)
        e.end_contour()
        return e

    total = sum(2**n for _, n in segs)
    whole = build().advance(total + 3)
    parts = run_chunked(build(), total + 3, [1, 3, 7, 2])
    assert np.array_equal(whole, parts)
    # sample j of a segment sits at r0 + floor(c*j / 2**n)
    r0, k = 10, 0
    for c, n in segs:
        for j in range(1, 2**n + 1):
            assert whole[k] == r0 + math.floor(c * j / 2**n)
            k += 1
        r0 += c
    assert whole[-1] == 10 + sum(c for c, _ in segs)


def test_contour_refusals() -> None:
    eng = AxisProfiler()
    with pytest.raises(CommandError) as info:
        eng.add_segment(10, 2)
    assert info.value.code == 8
    eng.begin_contour()
    with pytest.raises(CommandError) as info:
        eng.add_segment(10, 9)
    assert info.value.code == 6
    with pytest.raises(CommandError) as info:
        eng.increment(10, 1000, 1024, 1024)
    assert info.value.code == 18
    mover = AxisProfiler()
    mover.begin_jog(100, 1024, 1024)
    with pytest.raises(CommandError) as info:
        mover.begin_contour()
    assert info.value.code == 7


def test_smoothing_ends_exactly_on_target_after_the_profile() -> None:
    it = 0.05
    plain = AxisProfiler()
    plain.begin_move(2000, 20_480, 204_800, 204_800)
    n_plain = plain.end_sample
    assert n_plain is not None
    smooth = AxisProfiler()
    smooth.begin_move(2000, 20_480, 204_800, 204_800, smoothing=it)
    parts = []
    while smooth.moving:
        parts.append(smooth.advance(1))
    out = np.concatenate(parts)
    end = smooth.sample
    assert end > n_plain
    assert out[-1] == 2000
    assert smooth.reference == 2000
    # y follows y[k] = y[k-1] + IT (r[k] - y[k-1]) exactly, rounded to the nearest count
    r = plain.advance(end).astype(float)
    y = np.empty_like(r)
    prev = 0.0
    for k, rk in enumerate(r):
        prev = prev + it * (rk - prev)
        y[k] = prev
    assert np.array_equal(np.floor(y + 0.5).astype(np.int64), out)
    # it ends at the first sample after the profile where y is within half a count
    close = np.flatnonzero(np.abs(y - 2000) < 0.5)
    first = close[close >= n_plain - 1][0]
    assert end == first + 1


def test_bad_arguments_are_invalid_argument() -> None:
    eng = AxisProfiler()
    with pytest.raises(InvalidArgument):
        eng.begin_move(10, 100, 0, 1024)
    with pytest.raises(InvalidArgument):
        eng.begin_move(10, 100, 1024, 1024, smoothing=2.0)
    with pytest.raises(InvalidArgument):
        eng.advance(-1)
    with pytest.raises(InvalidArgument):
        AxisProfiler(sample_period=0)
