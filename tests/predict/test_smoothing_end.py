"""IT smoothing: a smoothed move ends where the filtered reference settles on its target.

The reference model here is written independently of the library: a plain per-sample filter
``y[k] = y[k-1] + IT*(r[k] - y[k-1])`` over the unsmoothed profile ``r`` (IT = 1), and the end is
the first sample, not before the profile's own end, from which ``y`` stays within half a count
of the target.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.predict.engine import AxisProfiler
from galil.predict.smoothing import END_LOOKAHEAD
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

SETTINGS = settings(max_examples=80, deadline=None)

its = st.floats(0.02, 1.0)
speeds = st.integers(20, 400).map(lambda x: x * 500.0)
accels = st.integers(20, 2000).map(lambda x: x * 1024.0)


def plain_filter(r: np.ndarray, it: float) -> tuple[np.ndarray, int]:
    """Filter r[0..E] (r[E] the target, held after) sample by sample; return y and the end."""
    target = float(r[-1])
    tail = math.ceil(40 / it) + 10
    x = np.concatenate([r.astype(float), np.full(tail, target)])
    y = np.empty_like(x)
    y[0] = prev = x[0]
    for k in range(1, x.size):
        prev = prev + it * (x[k] - prev)
        y[k] = prev
    off = np.flatnonzero(np.abs(y - target) >= 0.5)
    end = max(r.size - 1, int(off[-1]) + 1 if off.size else 0)
    assert end < x.size - 1, "tail too short for the reference model"
    return y, end


def assert_agrees(smoothed: predict.Profile, unsmoothed: predict.Profile, it: float) -> None:
    """Same path (to a count of rounding at a tie) and the same end within 3 samples."""
    y, end = plain_filter(unsmoothed.position, it)
    assert abs(smoothed.samples - end) <= 3, (smoothed.samples, end)
    n = min(smoothed.position.size, end + 1)
    diff = smoothed.position[:n] - np.floor(y[:n] + 0.5).astype(np.int64)
    assert np.abs(diff).max(initial=0) <= 1
    # A count apart only where the reference sits on a tie (x.5 to within float error): the
    # two evaluation orders may land either side of it (IT 0.8 makes exact ties common).
    ties = np.abs(y[:n] - np.floor(y[:n]) - 0.5) < 1e-6
    assert not np.any((diff != 0) & ~ties), np.flatnonzero((diff != 0) & ~ties)[:5]
    assert smoothed.end == unsmoothed.end
    # settled: nothing after the reported end moves
    assert smoothed.position[-1] == unsmoothed.end


@SETTINGS
@given(
    distance=st.integers(-20_000, 20_000).filter(bool),
    it=its,
    sp=speeds,
    ac=accels,
    dc=accels,
)
def test_smoothed_move_agrees_with_a_plain_filter(
    distance: int, it: float, sp: float, ac: float, dc: float
) -> None:
    smoothed = predict.move(distance, sp, ac, dc, smoothing=it)
    plain = predict.move(distance, sp, ac, dc)
    assert_agrees(smoothed, plain, it)


@SETTINGS
@given(
    speed=st.integers(-400, 400).filter(bool).map(lambda x: x * 250.0),
    it=its,
    ac=accels,
    dc=accels,
    stop_at=st.floats(0.0, 0.6),
)
def test_stopped_jog_agrees_with_a_plain_filter(
    speed: float, it: float, ac: float, dc: float, stop_at: float
) -> None:
    smoothed = predict.jog(speed, ac, dc, stop_at=stop_at, smoothing=it)
    plain = predict.jog(speed, ac, dc, stop_at=stop_at)
    assert_agrees(smoothed, plain, it)


@settings(max_examples=40, deadline=None)
@given(it=its, first=st.integers(6_000, 9_000), second=st.integers(12_000, 14_000))
def test_speed_schedule_agrees_with_a_plain_filter(it: float, first: int, second: int) -> None:
    changes = [(first, 40_000.0), (second, 10_000.0)]
    smoothed = predict.speed_schedule(20_000, 20_000, changes, 512_000, 512_000, smoothing=it)
    plain = predict.speed_schedule(20_000, 20_000, changes, 512_000, 512_000)
    # AD watches the profiler before smoothing: the triggers, and so r, are the same
    assert np.array_equal(
        smoothed.profile.profiler[: plain.profile.position.size], plain.profile.position
    )
    assert_agrees(smoothed.profile, plain.profile, it)


@settings(max_examples=60, deadline=None)
@given(
    segments=st.lists(
        st.tuples(st.integers(-3000, 3000), st.integers(1, 8)), min_size=1, max_size=30
    ),
    start=st.integers(-10_000, 10_000),
)
def test_contour_ends_with_its_last_segment(segments: list[tuple[int, int]], start: int) -> None:
    # IT smooths independent moves (JG, PR, PA, IP), not contour mode: a contour lasts exactly
    # its segments, and follows the floor rule sample by sample.
    inc = [c for c, _ in segments]
    dts = [n for _, n in segments]
    p = predict.contour(inc, dts, start=start)
    expected = [start]
    for c, n in segments:
        r0 = expected[-1]
        expected += [r0 + (c * j) // 2**n for j in range(1, 2**n + 1)]
    assert p.samples == sum(2**n for n in dts)
    assert p.position.tolist() == expected


def test_the_issue_examples_end_when_the_reference_settles() -> None:
    # galil plan 10000 --speed 40000 --accel 409600 --smoothing 0.1: 396 samples, not 1024
    p = predict.move(10_000, 40_000, 409_600, 409_600, smoothing=0.1)
    assert p.position[395] != 10_000
    assert p.samples == 396
    assert p.duration == pytest.approx(396 / 1024)
    short = predict.move(20, 25_000, 256_000, 256_000, smoothing=0.1)
    assert short.samples == 1 + int(np.flatnonzero(short.position != 20)[-1])


def test_end_sample_is_known_at_bg_and_moving_falls_there() -> None:
    eng = AxisProfiler()
    eng.begin_move(3_000, 30_000, 256_000, 256_000, smoothing=0.05)
    end = eng.end_sample
    assert end is not None
    while eng.moving:
        assert eng.sample < end
        eng.advance(7)
        if eng.sample < end:
            assert eng.end_sample == end
    assert eng.reference == 3_000
    one = AxisProfiler()
    one.begin_move(3_000, 30_000, 256_000, 256_000, smoothing=0.05)
    out = [int(one.advance(1)[0]) for _ in range(end)]
    assert not one.moving
    assert out[-1] == 3_000
    assert out[-2] != 3_000


def test_a_far_end_is_unknown_until_within_the_lookahead() -> None:
    # 200 s at 10000 counts/s: the profile ends far beyond the lookahead
    eng = AxisProfiler()
    eng.begin_move(2_000_000, 10_000, 256_000, 256_000, smoothing=0.5)
    assert eng.end_sample is None
    whole = predict.move(2_000_000, 10_000, 256_000, 256_000, smoothing=0.5)
    eng.advance(whole.samples - END_LOOKAHEAD // 2)
    assert eng.end_sample == whole.samples
    rest = eng.advance(END_LOOKAHEAD)
    assert not eng.moving
    tail = whole.position[whole.samples - END_LOOKAHEAD // 2 + 1 :]
    assert np.array_equal(rest[: tail.size], tail)


def test_the_simulator_completes_a_smoothed_move_on_the_predicted_sample() -> None:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(b"IT 0.1;PR 20;SP 25000;AC 256000;DC 256000\r")
    assert sim.feed(b"DL\r#W\rAM A;MG TIME\rEN\r\\\r") == b"::"  # AM holds the thread
    assert sim.feed(b"BG A;XQ #W\r") == b"::"
    done = sim.advance_until_output(5.0)
    predicted = predict.move(20, 25_000, 256_000, 256_000, smoothing=0.1, model="DMC-4040")
    assert done == f" {predicted.samples}.0000\r\n".encode()


def test_smoothing_none_means_no_smoothing_everywhere() -> None:
    q = predict.quantise("DMC-4040", speed=20_000, accel=256_000, decel=256_000)
    assert q.smoothing is None
    args = (5_000, 20_000, 256_000, 256_000)
    assert np.array_equal(
        predict.move(*args, smoothing=q.smoothing).position, predict.move(*args).position
    )
    assert np.array_equal(
        predict.move(*args, smoothing=None, model="DMC-4040").position,
        predict.move(*args, model="DMC-4040").position,
    )
    assert np.array_equal(
        predict.jog(20_000, 256_000, 256_000, stop_at=0.2, smoothing=None).position,
        predict.jog(20_000, 256_000, 256_000, stop_at=0.2).position,
    )
    sched = predict.speed_schedule(20_000, 20_000, [(8_000, 30_000)], 512_000, 512_000)
    none = predict.speed_schedule(
        20_000, 20_000, [(8_000, 30_000)], 512_000, 512_000, smoothing=None
    )
    assert np.array_equal(sched.profile.position, none.profile.position)
    eng = AxisProfiler()
    eng.begin_move(100, 10_000, 102_400, 102_400, smoothing=None)
    assert eng.smoothing == 1.0
