"""The contour planner: integer increments that never drift from the ideal path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.contour import increments, sample_path
from galil.errors import InvalidArgument


@settings(max_examples=200, deadline=None)
@given(
    path=st.lists(st.floats(-1e7, 1e7, allow_nan=False), min_size=1, max_size=200),
    start=st.integers(-1000, 1000),
)
def test_running_sum_is_the_rounded_path(path: list[float], start: int) -> None:
    inc = increments(path, start=start)
    assert inc.dtype == np.int64
    assert inc.size == len(path)
    running = start + np.cumsum(inc)
    assert np.array_equal(running, np.floor(np.asarray(path) + 0.5))
    assert np.max(np.abs(running - np.asarray(path))) <= 0.5
    assert running[-1] == math.floor(path[-1] + 0.5)


def test_one_minus_cos_seed() -> None:
    def x(t: np.ndarray) -> np.ndarray:
        ms = t * 1000
        return 50 * ms - (6000 / (2 * math.pi)) * np.sin(2 * math.pi * ms / 120)

    path = sample_path(x, 0.120, 3, sample_period=0.001)
    inc = increments(path)
    assert int(inc.sum()) == 6000
    assert inc.size == 15
    assert list(inc) == list(inc[::-1])  # symmetric speed profile
    assert inc[0] < inc[7]


def test_sample_path_clips_the_last_segment() -> None:
    path = sample_path(lambda t: 1000 * t, 0.05, 4, sample_period=1 / 1024)
    assert path[-1] == pytest.approx(50)
    assert path.size == math.ceil(0.05 / (16 / 1024))


def test_bad_input() -> None:
    with pytest.raises(InvalidArgument):
        increments([[1.0]])
    with pytest.raises(InvalidArgument):
        increments([float("nan")])
    with pytest.raises(InvalidArgument):
        increments([1.0], start=0.5)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument):
        sample_path(lambda t: t, 1.0, 9)
    with pytest.raises(InvalidArgument):
        sample_path(lambda t: t, -1.0, 3)
    with pytest.raises(InvalidArgument):
        sample_path(lambda t: np.zeros(3), 1.0, 3)
