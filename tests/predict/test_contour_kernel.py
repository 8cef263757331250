"""predict.contour writes whole paths at once; it must give the engine's integers exactly."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import InvalidArgument
from galil.predict.engine import AxisProfiler

# the module, not the function of the same name that galil.predict exports
contour_module = importlib.import_module("galil.predict.contour")
SETTINGS = settings(max_examples=120, deadline=None)


def by_engine(c: list[int], dt: int | list[int], start: int) -> np.ndarray:
    """The previous implementation: queue every segment in the engine, step it to the end."""
    eng = AxisProfiler(position=start)
    eng.begin_contour()
    n = [dt] * len(c) if isinstance(dt, int) else dt
    for ci, ni in zip(c, n, strict=True):
        eng.add_segment(ci, ni)
    ref = eng.advance(sum(2**ni for ni in n))
    return np.concatenate([[start], ref])


increments = st.lists(st.integers(-32_000, 32_000), min_size=1, max_size=200)
starts = st.integers(-(2**31), 2**31 - 1)


@SETTINGS
@given(c=increments, dt=st.integers(1, 8), start=starts)
def test_one_dt_equals_the_engine(c: list[int], dt: int, start: int) -> None:
    p = predict.contour(c, dt, start=start)
    assert np.array_equal(p.position, by_engine(c, dt, start))
    assert p.peak_speed == max(abs(x) for x in c) / 2**dt * 1024


@SETTINGS
@given(
    segments=st.lists(
        st.tuples(st.integers(-32_000, 32_000), st.integers(1, 8)), min_size=1, max_size=200
    ),
    start=starts,
)
def test_mixed_dt_equals_the_engine(segments: list[tuple[int, int]], start: int) -> None:
    c = [x for x, _ in segments]
    dt = [n for _, n in segments]
    p = predict.contour(c, dt, start=start)
    assert np.array_equal(p.position, by_engine(c, dt, start))
    assert p.duration == sum(2**n for n in dt) / 1024


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dt=st.sampled_from([1, 2, 3, 8, None]))
def test_paths_longer_than_a_block_equal_the_engine(seed: int, dt: int | None) -> None:
    rng = np.random.default_rng(seed)
    c = rng.integers(-32_000, 32_000, 300).tolist()
    n: int | list[int] = rng.integers(1, 9, 300).tolist() if dt is None else dt
    # blocks of 64 samples: every path here spans many blocks, with carries between them
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(contour_module, "_BLOCK", 64)
        got = predict.contour(c, n, start=17).position
    assert np.array_equal(got, by_engine(c, n, 17))


def test_the_manual_example_and_an_empty_path() -> None:
    assert predict.contour([48], 2).position.tolist() == [0, 12, 24, 36, 48]
    empty = predict.contour([], 3, start=5)
    assert empty.position.tolist() == [5]
    assert empty.stop_code == 51
    assert empty.peak_speed == 0.0


def test_float_increments_must_be_whole_and_dt_in_range() -> None:
    assert predict.contour(np.array([2.0, -4.0]), 1).position.tolist() == [0, 1, 2, 0, -2]
    with pytest.raises(InvalidArgument, match="whole counts"):
        predict.contour([1.5], 1)
    with pytest.raises(InvalidArgument, match="DT 9 of segment 0"):
        predict.contour([1], 9)
    with pytest.raises(InvalidArgument, match="DT 0 of segment 1"):
        predict.contour([1, 2], [1, 0])
