"""Contour mode (CM, CD, DT): linear per-sample interpolation inside each segment."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.predict.engine import AxisProfiler
from galil.predict.profile import Profile

__all__ = ["contour"]


def contour(
    increments: npt.ArrayLike,
    dt: int | Sequence[int],
    *,
    start: int = 0,
    sample_period: float = 1 / 1024,
) -> Profile:
    """Predict a contour: segment i moves ``increments[i]`` counts over ``2**dt[i]`` samples.

    Sample j (1..2**n) of a segment starting at r0 is at ``r0 + floor(c*j / 2**n)``, so each
    segment ends exactly on ``r0 + c``. The profile ends when the last segment does.

    Raises:
        InvalidArgument: non-integer increments, or DT outside 1..8.
    """
    c = np.asarray(increments)
    if c.ndim != 1:
        raise InvalidArgument("increments must be a 1-D sequence")
    whole = np.issubdtype(c.dtype, np.integer) or bool(
        np.all(np.isfinite(c)) and np.all(c == np.round(c))
    )
    if not whole:
        raise InvalidArgument("contour increments must be whole counts")
    c = c.astype(np.int64)
    n = np.broadcast_to(np.asarray(dt, dtype=np.int64), c.shape)
    bad = np.flatnonzero((n < 1) | (n > 8))
    if bad.size:
        raise InvalidArgument(f"DT {int(n[bad[0]])} of segment {int(bad[0])} is outside 1..8")
    eng = AxisProfiler(sample_period=sample_period, position=int(start))
    eng.begin_contour()
    for ci, ni in zip(c.tolist(), n.tolist(), strict=True):
        eng.add_segment(ci, ni)
    total = int(np.sum(np.left_shift(np.int64(1), n))) if c.size else 0
    ref = eng.advance(total)
    eng.end_contour()
    lengths = np.left_shift(np.int64(1), n)
    peak = float(np.max(np.abs(c) / lengths)) / sample_period if c.size else 0.0
    return Profile.from_samples(
        np.concatenate([[int(start)], ref]),
        sample_period=sample_period,
        shape="contour",
        peak_speed=peak,
        stop_code=eng.stop_code,
    )
