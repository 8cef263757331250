"""Helpers shared by the axis tests (a module of its own: conftest is not importable)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from galil.predict import Profile


def recorded(trace: npt.NDArray[np.int64], trace_start: int, begin: int, n: int) -> np.ndarray:
    """The ``n`` recorded reference positions from controller sample ``begin`` on."""
    offset = begin - trace_start
    assert offset >= 0, "the trace starts after the motion began"
    out = trace[offset : offset + n]
    assert out.size == n, f"the trace holds {out.size} of the {n} predicted samples"
    return out


def assert_follows(
    trace: npt.NDArray[np.int64], trace_start: int, profile: Profile, begin: int | None
) -> None:
    """The servo loop's reference equals the prediction, sample for sample."""
    assert begin is not None
    got = recorded(trace, trace_start, begin, profile.position.size)
    np.testing.assert_array_equal(got, profile.position)
