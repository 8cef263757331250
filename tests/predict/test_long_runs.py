"""Predictions of long motion keep no more than their summary until their samples are read.

A jog stopped after hours, a move aborted late, a move of hours checked against a soft limit
at its end: each is predicted without holding every sample (``KEEP_SAMPLES``, the parts of
``check_soft_limits``), and what it predicts is what the whole arrays give.
"""

from __future__ import annotations

import importlib
import tracemalloc
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import LimitError
from galil.predict import checks
from galil.predict.profile import Profile

TS = 1 / 1024
#: (``galil.predict.move`` is the function; its module is this)
move_module = importlib.import_module("galil.predict.move")


def _same(lazy: Profile, whole: Profile) -> None:
    # (the summary first: it must be known before the arrays are computed)
    assert lazy.samples == whole.samples
    assert lazy.start == whole.start
    assert lazy.end == whole.end
    assert lazy.duration == whole.duration
    assert lazy.shape == whole.shape
    assert lazy.stop_code == whole.stop_code
    assert lazy.peak_speed == whole.peak_speed
    low, high = lazy.bounds()
    assert low == int(whole.position.min())
    assert high == int(whole.position.max())
    np.testing.assert_array_equal(lazy.position, whole.position)
    np.testing.assert_array_equal(lazy.profiler, whole.profiler)
    np.testing.assert_array_equal(lazy.velocity, whole.velocity)
    np.testing.assert_array_equal(lazy.t, whole.t)


def _both(
    monkeypatch: pytest.MonkeyPatch, predict_it: Callable[[], Profile]
) -> tuple[Profile, Profile]:
    whole = predict_it()
    monkeypatch.setattr(move_module, "KEEP_SAMPLES", 100)
    monkeypatch.setattr(move_module, "_PIECE", 37)
    lazy = predict_it()
    assert "position" not in lazy.__dict__, "a run past KEEP_SAMPLES kept its samples"
    return lazy, whole


EVENTS: list[tuple[str, list[predict.Event]]] = [
    ("stop", [predict.Stop(0.9)]),
    ("speed then stop", [predict.SetSpeed(0.3, -4000.0), predict.Stop(1.2)]),
    ("accel, stop, decel", [predict.SetAccel(0.2, 90000.0), predict.Stop(0.5)]),
    ("abort", [predict.Abort(0.7)]),
    ("stop then abort in the ramp", [predict.Stop(0.5), predict.Abort(0.51)]),
]


@pytest.mark.parametrize("smoothing", [1.0, 0.3])
@pytest.mark.parametrize(("label", "events"), EVENTS, ids=[e[0] for e in EVENTS])
def test_a_long_jog_predicts_the_samples_the_whole_run_gives(
    monkeypatch: pytest.MonkeyPatch, label: str, events: list[predict.Event], smoothing: float
) -> None:
    lazy, whole = _both(
        monkeypatch,
        lambda: predict.jog(6000.0, 40000.0, 30000.0, events=events, smoothing=smoothing, start=17),
    )
    _same(lazy, whole)


@pytest.mark.parametrize("smoothing", [1.0, 0.5])
@pytest.mark.parametrize(
    "events",
    [
        [predict.Stop(0.4)],
        [predict.SetSpeed(0.2, 3000.0)],
        [predict.Increment(0.3, 500)],
        [predict.Abort(0.35)],
    ],
)
def test_a_long_changed_move_predicts_the_samples_the_whole_run_gives(
    monkeypatch: pytest.MonkeyPatch, events: list[predict.Event], smoothing: float
) -> None:
    lazy, whole = _both(
        monkeypatch,
        lambda: predict.move(
            9000, 8000.0, 50000.0, 60000.0, smoothing=smoothing, start=-3, events=events
        ),
    )
    _same(lazy, whole)


def test_a_resumed_jog_keeps_its_start_velocity_when_its_samples_are_computed_later(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    lazy, whole = _both(
        monkeypatch,
        lambda: predict.jog(
            -2000.0, 40000.0, 30000.0, initial_speed=5000.0, stop_at=0.6, smoothing=0.4
        ),
    )
    assert whole.velocity[0] == 5000.0
    _same(lazy, whole)


@pytest.mark.parametrize("smoothing", [1.0, 0.25])
def test_an_abort_is_the_profile_cut_at_its_sample(smoothing: float) -> None:
    """``Abort`` at t is the jog (stopped there) cut at that sample, as AB leaves the reference
    where it is; once the motion is over it changes nothing but what ends it."""
    jog = predict.jog(6000.0, 40000.0, 30000.0, stop_at=0.3, smoothing=smoothing)
    aborted = predict.jog(
        6000.0, 40000.0, 30000.0, events=[predict.Abort(0.3)], smoothing=smoothing
    )
    k = round(0.3 / TS)
    assert aborted.samples == k
    assert aborted.stop_code == 7
    np.testing.assert_array_equal(aborted.position, jog.position[: k + 1])
    np.testing.assert_array_equal(aborted.profiler, jog.profiler[: k + 1])
    move = predict.move(1000, 8000.0, 50000.0, 50000.0, smoothing=smoothing)
    late = predict.move(
        1000, 8000.0, 50000.0, 50000.0, smoothing=smoothing, events=[predict.Abort(9.0)]
    )
    np.testing.assert_array_equal(late.position, move.position)
    assert late.stop_code == 1


def test_a_jog_stopped_after_hours_is_predicted_in_bounded_memory() -> None:
    tracemalloc.start()
    try:
        profile = predict.jog(20000.0, 256000.0, 256000.0, stop_at=3 * 3600.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert profile.samples > 11_000_000
    assert profile.end == round(20000.0 * 3 * 3600.0)
    # The whole arrays would be about 440 MB; one piece of the run is a few MB.
    assert peak < 40e6, f"{peak / 1e6:.0f} MB"


@settings(max_examples=150, deadline=None)
@given(
    distance=st.integers(-40_000, 40_000).filter(lambda d: d != 0),
    start=st.integers(-(2**31) + 50_000, 2**31 - 50_000),
    slack=st.integers(-3, 3),
    speed=st.sampled_from([300.0, 2500.0, 25000.0]),
    side=st.sampled_from(["FL", "BL", "both"]),
)
def test_a_planned_move_is_checked_part_by_part_as_its_whole_samples_are(
    distance: int, start: int, slack: int, speed: float, side: str
) -> None:
    profile = predict.move(distance, speed, 256000.0, 256000.0, start=start)
    end = start + distance
    fl = end + slack if side != "BL" else None
    bl = end - slack if side != "FL" else None
    if side == "both":
        fl, bl = max(start, end) + slack, min(start, end) - slack

    def outcome(check: Callable[[], None]) -> tuple[object, ...] | None:
        try:
            check()
        except LimitError as exc:
            return (exc.name, exc.value, exc.limit, exc.sample, exc.time, str(exc))
        return None

    whole = Profile.from_samples(
        profile.position, sample_period=profile.sample_period, shape="", peak_speed=0.0
    )
    expected = outcome(lambda: checks.check_soft_limits(whole, forward_limit=fl, backward_limit=bl))
    original = checks._STRETCH
    try:
        checks._STRETCH = 61  # many parts, most skipped
        fresh = predict.move(distance, speed, 256000.0, 256000.0, start=start)
        got = outcome(lambda: checks.check_soft_limits(fresh, forward_limit=fl, backward_limit=bl))
    finally:
        checks._STRETCH = original
    assert got == expected
    assert "position" not in fresh.__dict__, "the check computed every sample"


def test_a_move_of_a_day_to_the_end_of_the_range_is_checked_without_its_samples() -> None:
    tracemalloc.start()
    try:
        profile = predict.move(2**31 - 1, 25000.0, 256000.0, 256000.0)
        checks.check_soft_limits(profile, forward_limit=2**31 - 1, backward_limit=-(2**31))
        with pytest.raises(LimitError) as caught:
            checks.check_soft_limits(profile, forward_limit=2**31 - 2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert profile.duration > 23 * 3600
    assert caught.value.value == 2**31 - 1
    assert profile.samples - 8 <= caught.value.sample <= profile.samples  # (its last samples)
    assert peak < 20e6, f"{peak / 1e6:.0f} MB"  # (the samples would be 2.8 GB)
