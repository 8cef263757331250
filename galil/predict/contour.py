"""Contour mode (CM, CD, DT): linear per-sample interpolation inside each segment.

Sample ``j`` (1..2**n) of a segment starting at ``r0`` is at ``r0 + floor(c*j / 2**n)``: the
engine's contour queue (what the simulator steps) and :func:`contour` compute the same integers.
Here whole paths are written straight into the output array, a block of equal-length segments
at a time, without per-sample temporaries.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.predict.counts import whole_counts
from galil.predict.profile import Profile
from galil.predict.quantities import no_quantity, period_seconds

__all__ = ["contour", "interpolate"]

Int64Array = npt.NDArray[np.int64]

# Samples written per block: the temporaries of one block stay in the CPU's cache.
_BLOCK = 1 << 15


def _bases(c: Int64Array, carry: int) -> Int64Array:
    """Position before each segment of a block that starts at ``carry``."""
    base = np.cumsum(c)
    base -= c
    base += carry
    return base


def _uniform(out: Int64Array, c: Int64Array, n: int, start: int) -> None:
    """Segments of one DT: ``out`` (segments x 2**n) = ``r0 + floor(c*j / 2**n)``, j = 1..2**n.

    Short segments column by column (numpy's inner loop then runs over segments), longer
    ones as flat blocks of whole segments.
    """
    length = 1 << n
    rows = max(1, _BLOCK >> n)
    carry = start
    flat = out.reshape(-1)
    tmp = np.empty(min(rows, c.size), np.int64)
    js = np.tile(np.arange(1, length + 1, dtype=np.int64), min(rows, c.size) if n > 2 else 0)
    for a in range(0, c.size, rows):
        cb = c[a : a + rows]
        bb = _bases(cb, carry)
        carry = int(bb[-1] + cb[-1])
        if n <= 2:
            t, ob = tmp[: cb.size], out[a : a + rows]
            for j in range(1, length + 1):
                np.multiply(cb, j, out=t)
                np.right_shift(t, n, out=t)
                np.add(t, bb, out=ob[:, j - 1])
        else:
            dst = flat[a * length : (a + cb.size) * length]
            np.multiply(np.repeat(cb, length), js[: dst.size], out=dst)
            np.right_shift(dst, n, out=dst)
            dst += np.repeat(bb, length)


def _mixed(out: Int64Array, c: Int64Array, dt: Int64Array, start: int) -> None:
    """Segments of different DT, a block of whole segments (about _BLOCK samples) at a time."""
    lengths = np.left_shift(np.int64(1), dt)
    ends = np.cumsum(lengths)
    cuts = np.searchsorted(ends, np.arange(_BLOCK, int(ends[-1]), _BLOCK), side="right")
    bounds = np.unique(np.concatenate(([0], cuts, [c.size]))).tolist()
    carry = start
    for a, b in itertools.pairwise(bounds):
        lb = lengths[a:b]
        bb = _bases(c[a:b], carry)
        carry = int(bb[-1] + c[b - 1])
        s0 = int(ends[a] - lengths[a])
        dst = out[s0 : int(ends[b - 1])]
        # j = 1 + the sample's index in its segment
        j = np.arange(1, dst.size + 1, dtype=np.int64)
        j -= np.repeat(ends[a:b] - lb - s0, lb)
        np.multiply(np.repeat(c[a:b], lb), j, out=dst)
        np.right_shift(dst, np.repeat(dt[a:b], lb), out=dst)
        dst += np.repeat(bb, lb)


def interpolate(increments: Int64Array, dt: int | Int64Array, start: int, out: Int64Array) -> None:
    """Write the contour's positions at samples 1..N into ``out`` (length N).

    Temporaries are a block's worth (and, for an array of DT, one array per segment), never
    one per sample of the whole path.

    Args:
        increments: CD of each segment (int64).
        dt: DT of all segments, or of each (int64 array, same length), 1..8.
        start: position before the first segment.
        out: the destination, ``sum(2**dt)`` samples.
    """
    m = increments.size
    if m == 0:
        return
    if isinstance(dt, np.ndarray):
        lo, hi = int(dt.min()), int(dt.max())
        if lo != hi:
            _mixed(out, increments, dt, start)
            return
        dt = lo
    _uniform(out.reshape(m, 1 << dt), increments, dt, start)


def contour(
    increments: npt.ArrayLike,
    dt: int | Sequence[int],
    *,
    start: int = 0,
    sample_period: float = 1 / 1024,
) -> Profile:
    """Predict a contour: segment i moves ``increments[i]`` counts over ``2**dt[i]`` samples.

    Sample j (1..2**n) of a segment starting at r0 is at ``r0 + floor(c*j / 2**n)``, so each
    segment ends exactly on ``r0 + c``. The profile ends when the last segment does (IT does
    not smooth contour mode).

    Raises:
        InvalidArgument: non-integer increments, or DT outside 1..8.
    """
    no_quantity(increments, "contour increments", "counts")
    no_quantity(dt, "dt", "DT (an exponent: a segment lasts 2**dt samples)", counts=False)
    sample_period = period_seconds(sample_period)
    c = np.asarray(increments)
    if c.ndim != 1:
        raise InvalidArgument("increments must be a 1-D sequence")
    if not np.issubdtype(c.dtype, np.integer):
        whole = bool(np.all(np.isfinite(c)) and np.all(c == np.round(c)))
        if not whole:
            raise InvalidArgument("contour increments must be whole counts")
    c = c.astype(np.int64, copy=False)
    n = np.asarray(dt, dtype=np.int64)
    if n.ndim == 0:
        if c.size and not 1 <= int(n) <= 8:
            raise InvalidArgument(f"DT {int(n)} of segment 0 is outside 1..8")
        total = c.size << int(n)
        span = np.array([c.max(), -c.min()]) if c.size else np.zeros(1, np.int64)
        peak = float(span.max()) / float(1 << int(n))
    else:
        n = np.broadcast_to(n, c.shape)
        bad = np.flatnonzero((n < 1) | (n > 8))
        if bad.size:
            raise InvalidArgument(f"DT {int(n[bad[0]])} of segment {int(bad[0])} is outside 1..8")
        lengths = np.left_shift(np.int64(1), n)
        total = int(lengths.sum())
        peak = float(np.max(np.abs(c) / lengths)) if c.size else 0.0
    start = whole_counts(start, "start")
    pos = np.empty(total + 1, np.int64)
    pos[0] = start
    interpolate(c, int(n) if n.ndim == 0 else n, start, pos[1:])
    return Profile.from_samples(
        pos,
        sample_period=sample_period,
        shape="contour",
        peak_speed=peak / sample_period,
        stop_code=51,
    )
