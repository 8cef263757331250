"""The engine's fast paths (scalar for short chunks, gathered for whole moves) give exactly
what its segment-by-segment numpy path gives."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument
from galil.predict import engine
from galil.predict.engine import (
    FRACTION,
    AxisProfiler,
    KinematicPlan,
    PlanSamples,
    _Active,
    _round_fixed,
    plan_jog,
    plan_position,
    plan_stop,
    sample_plan,
)

SETTINGS = settings(max_examples=150, deadline=None)

rates = st.floats(0.001, 5.0)
# Positions on the engine's grid: it keeps them in 1/65536 count, so the distance left to a
# target is 0 or at least that (a distance of 1e-167 gives a ramp of 1e162 counts/sample²,
# which no comparison of float paths survives).
starts = st.integers(-(10**6) * FRACTION, 10**6 * FRACTION).map(lambda n: n / FRACTION)
distances = st.integers(-(10**6) * FRACTION, 10**6 * FRACTION).map(lambda n: n / FRACTION)


@st.composite
def plans(draw: st.DrawFn) -> KinematicPlan:
    x0 = draw(starts)
    v0 = draw(st.floats(-60.0, 60.0))
    kind = draw(st.sampled_from(["position", "jog", "stop"]))
    if kind == "position":
        target = x0 + draw(distances)
        return plan_position(x0, v0, target, draw(st.floats(0.1, 300.0)), draw(rates), draw(rates))
    if kind == "jog":
        speed = draw(st.one_of(st.just(0.0), st.floats(-300.0, 300.0)))
        return plan_jog(x0, v0, speed, draw(rates), draw(rates))
    return plan_stop(x0, v0, draw(rates))


@SETTINGS
@given(plan=plans(), k0=st.integers(-100, 100), where=st.floats(-0.05, 1.2), n=st.integers(0, 400))
def test_scalar_positions_are_the_vector_ones(
    plan: KinematicPlan, k0: int, where: float, n: int
) -> None:
    active = _Active(plan, k0)
    span = plan.duration if math.isfinite(plan.duration) else 50_000.0
    start = k0 + math.floor(where * min(span, 1e5))
    vector = _round_fixed(active.fixed(start, n))
    scalar, velocity = active.step_values(start, n)
    assert scalar == vector.tolist()
    assert active.rounded(start, n) == scalar
    if n:
        assert velocity == active.state(start + n - 1)[1]


@SETTINGS
@given(plan=plans(), k0=st.integers(-100, 100), where=st.floats(-0.05, 1.2), n=st.integers(0, 3000))
def test_gathered_positions_are_the_segment_by_segment_ones(
    plan: KinematicPlan, k0: int, where: float, n: int
) -> None:
    active = _Active(plan, k0)
    span = plan.duration if math.isfinite(plan.duration) else 50_000.0
    start = k0 + math.floor(where * min(span, 1e5))
    gathered = active.fixed(start, n)
    saved = engine._GATHER_MAX
    engine._GATHER_MAX = -1  # every chunk segment by segment
    try:
        looped = active.fixed(start, n)
    finally:
        engine._GATHER_MAX = saved
    np.testing.assert_array_equal(gathered, looped)


def test_a_whole_plan_sampled_at_once_is_the_profiler_preview() -> None:
    eng = AxisProfiler(position=-7)
    eng.begin_move(123_456, 50_000, 512_000, 256_000)
    end = eng.end_sample
    assert end is not None
    plan = eng.plan
    assert plan is not None
    np.testing.assert_array_equal(sample_plan(plan), eng.preview_from(0, end + 1))
    with pytest.raises(InvalidArgument):
        sample_plan(plan_jog(0.0, 0.0, 10.0, 1.0, 1.0))


@SETTINGS
@given(
    d=st.integers(-400_000, 400_000),
    speed=st.integers(1_000, 500_000),
    accel=st.integers(1, 2000).map(lambda v: 1024 * v),
    chunks=st.lists(st.integers(1, 80), min_size=1, max_size=6),
    jog=st.booleans(),
)
def test_short_chunks_commit_what_one_long_chunk_commits(
    d: int, speed: int, accel: int, chunks: list[int], jog: bool
) -> None:
    whole, parts = AxisProfiler(), AxisProfiler()
    for eng in (whole, parts):
        if jog:
            eng.begin_jog(math.copysign(speed, d or 1), accel, accel)
        else:
            eng.begin_move(d, speed, accel, accel)
    total = 3000
    expected = whole.advance(total)
    got: list[int] = []
    i = 0
    while len(got) < total:
        n = min(chunks[i % len(chunks)], total - len(got))
        got += parts.advance_values(n)
        assert parts.position == expected[len(got) - 1]
        assert parts.reference == parts.position
        i += 1
    np.testing.assert_array_equal(np.array(got), expected)
    assert (parts.moving, parts.stop_code, parts.mode) == (
        whole.moving,
        whole.stop_code,
        whole.mode,
    )
    assert parts.velocity == whole.velocity
    assert parts.sample == whole.sample


def test_advance_values_falls_back_for_smoothing_and_idle() -> None:
    smooth, ref = AxisProfiler(), AxisProfiler()
    for eng in (smooth, ref):
        eng.begin_move(5000, 40_000, 256_000, 256_000, 0.25)
    expected = ref.advance(700).tolist()
    got: list[int] = []
    while len(got) < 700:
        got += smooth.advance_values(7)
    assert got == expected
    idle = AxisProfiler(position=42)
    assert idle.advance_values(5) == [42] * 5
    assert idle.sample == 5
    assert idle.advance_values(0) == []


def test_a_deep_copy_is_independent_of_the_original() -> None:
    jog, ref = AxisProfiler(), AxisProfiler()
    for eng in (jog, ref):
        eng.begin_jog(20_000, 256_000, 256_000, 0.5)
        eng.advance(300)
    snap = copy.deepcopy(jog)
    jog.increment(5000, 20_000, 256_000, 256_000)  # shifts the jog's plan in place
    jog.advance(200)
    np.testing.assert_array_equal(snap.advance(400), ref.advance(400))
    contour, twin = AxisProfiler(), AxisProfiler()
    for eng in (contour, twin):
        eng.begin_contour()
        eng.add_segment(100, 3)
    snap = copy.deepcopy(contour)
    contour.add_segment(-500, 2)
    twin_values = twin.advance(20)
    np.testing.assert_array_equal(snap.advance(20), twin_values)
    assert snap.queued_segments == twin.queued_segments


@SETTINGS
@given(
    start=st.integers(-2_000_000_000, 2_000_000_000),
    distance=st.integers(-100_000, 100_000),
    v=st.floats(1.0, 300.0),
    a=rates,
    d=rates,
)
def test_a_planned_move_knows_its_ends_and_bounds_without_sampling(
    start: int, distance: int, v: float, a: float, d: float
) -> None:
    plan = plan_position(float(start), 0.0, float(start + distance), v, a, d)
    known = PlanSamples.of(plan)
    sampled = sample_plan(plan)
    assert (known.start, known.end, known.samples) == (
        sampled[0],
        sampled[-1],
        sampled.size - 1,
    )
    low, high = known.bounds
    assert low <= sampled.min()
    assert sampled.max() <= high


def _plan_fields(plan: engine.KinematicPlan) -> tuple[object, ...]:
    # repr() keeps signed zeros and every bit of the floats apart
    return tuple(
        repr(v) for v in (plan.x0, plan.x_end, plan.duration, plan.peak, plan.shape, plan.segments)
    )


@settings(max_examples=400, deadline=None)
@given(
    x0=st.integers(-(2**31), 2**31 - 1),
    distance=st.integers(-(2**31), 2**31 - 1),
    speed=st.floats(1e-3, 3e4),
    accel=st.floats(1e-6, 70.0),
    decel=st.floats(1e-6, 70.0),
)
def test_plan_from_rest_is_plan_position_from_rest_bit_for_bit(
    x0: int, distance: int, speed: float, accel: float, decel: float
) -> None:
    # The planner's hot path written out: the same operations in the same order, so every
    # field of the plan (floats by their bits, signed zeros too) must be the general one's.
    target = float(x0 + distance)
    fast = engine.plan_from_rest(float(x0), target, speed, accel, decel)
    general = engine.plan_position(float(x0), 0.0, target, speed, accel, decel)
    assert _plan_fields(fast) == _plan_fields(general)
