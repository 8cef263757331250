"""Contour mode, host side: turn an ideal path into the integer increments CD sends.

The planner keeps the commanded path within half a count of the ideal one: increment i is
``round(path[i]) - round(path[i-1])``, so the running sum is the rounded ideal position at every
segment end (no drift) and the total is exact.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument

__all__ = ["increments", "sample_path"]


def _round(x: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    # Half-way values round up (floor(x + 0.5)) so the rule does not depend on parity.
    out: npt.NDArray[np.int64] = np.floor(x + 0.5).astype(np.int64)
    return out


def increments(path: npt.ArrayLike, *, start: int = 0) -> npt.NDArray[np.int64]:
    """Integer CD increments that follow ``path`` (ideal absolute positions at segment ends).

    Args:
        path: ideal positions in counts at the end of each segment (floats allowed).
        start: the (integer) position before the first segment.

    Returns:
        int64 increments; ``start + cumsum(increments) == round(path)`` element by element.

    Raises:
        InvalidArgument: the path is not 1-D and finite, or ``start`` is not a whole count.
    """
    x = np.asarray(path, dtype=np.float64)
    if x.ndim != 1:
        raise InvalidArgument(f"path must be 1-D, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InvalidArgument("path holds NaN or infinity")
    if int(start) != start:
        raise InvalidArgument(f"start must be a whole count, got {start!r}")
    ends = _round(x)
    out: npt.NDArray[np.int64] = np.diff(ends, prepend=np.int64(int(start)))
    return out


def sample_path(
    func: Callable[[npt.NDArray[np.float64]], npt.ArrayLike],
    duration: float,
    dt: int,
    sample_period: float = 1 / 1024,
) -> npt.NDArray[np.float64]:
    """Sample ``func(t)`` (t in seconds) at the end of each ``2**dt``-sample segment.

    The last segment end is clipped to ``duration`` so the path ends on ``func(duration)``
    (that segment then moves its whole remainder in ``2**dt`` samples).

    Args:
        func: position in counts as a function of time; called once with an array of times.
        duration: seconds covered.
        dt: the DT exponent (1..8).
        sample_period: seconds per servo sample.

    Returns:
        Ideal absolute positions at the segment ends (floats), ready for :func:`increments`.

    Raises:
        InvalidArgument: bad duration, DT or sample period, or ``func`` returns a wrong shape.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise InvalidArgument(f"duration must be positive, got {duration!r}")
    if not 1 <= int(dt) <= 8 or int(dt) != dt:
        raise InvalidArgument(f"DT must be an integer in 1..8, got {dt!r}")
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise InvalidArgument(f"sample_period must be positive, got {sample_period!r}")
    seg = (1 << int(dt)) * sample_period
    count = max(1, math.ceil(duration / seg - 1e-9))
    t = np.minimum(np.arange(1, count + 1, dtype=np.float64) * seg, duration)
    x = np.asarray(func(t), dtype=np.float64)
    if x.shape != t.shape:
        raise InvalidArgument(f"func returned shape {x.shape}, expected {t.shape}")
    return x
