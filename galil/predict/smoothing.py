"""IT smoothing: the controller's single-pole low-pass on the reference position.

``y[k] = y[k-1] + IT*(r[k] - y[k-1])`` (Galil application note 3312). A first-order recursion
cannot be vectorised directly, so it is evaluated a fixed-size page at a time in closed form:
``y[i] = c**(i+1) * y_prev + sum_{j<=i} IT * c**(i-j) * r[j]`` with ``c = 1 - IT``. Pages always
have the same length, so the same inputs give bit-identical outputs however a caller chunks its
requests (the engine anchors pages at the sample of the last command).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.models import IT_RANGE

__all__ = [
    "END_LOOKAHEAD",
    "IT_MAX",
    "IT_MIN",
    "IT_STORED_MIN",
    "PAGE",
    "SmoothCache",
    "quantise_it",
    "smooth",
    "smooth_page",
    "stored_it",
]

IT_MIN, IT_MAX = IT_RANGE
#: The smallest IT a controller holds: IT 0.004 (the command's minimum) is stored as one step
#: of 1/256, which ``MG _ITA`` prints as 0.0039. A profiler takes IT from this value up, and a
#: value between it and the step (a 4-decimal reading) as that step.
IT_STORED_MIN = 0.0039
#: Samples per smoothing page. 256 keeps the matrix small (512 KiB) and c**256 well above
#: underflow even at IT = 1/256.
PAGE = 256
#: How far ahead (samples) the end of a smoothed move is looked for: a profile ending later
#: than this reports no end yet (see :meth:`SmoothCache.find_end`).
END_LOOKAHEAD = 1 << 16
# Past the profile's own end, y falls towards the target by (1 - IT) per sample: from any
# int32 distance it is within half a count after 23 / IT samples (IT >= 1/256).
_TAIL_MAX = 23 * 256 + 2 * PAGE
# Samples already stepped past that the cache drops (at its next fill).
_TRIM = 16 * PAGE


def quantise_it(value: float) -> float:
    """Return IT as the controller stores it: a multiple of 1/256 in [0.004, 1].

    Raises:
        InvalidArgument: the value is outside [0.004, 1] or not finite.
    """
    if not np.isfinite(value) or not IT_MIN <= value <= IT_MAX:
        raise InvalidArgument(f"IT must be in [{IT_MIN}, {IT_MAX}], got {value!r}")
    # 0.004 is just above 1/256, so the smallest legal value maps to one step.
    return max(1, round(value * 256)) / 256.0


def stored_it(reading: float) -> float:
    """IT as the controller holds it, from its 4-decimal reading (``MG _ITA``: IT 0.1, held as
    26/256, reads 0.1016; the smallest step reads 0.0039): the nearest multiple of 1/256 in
    [1/256, 1]. The steps are 0.0039 apart, so a reading names exactly one."""
    return min(256, max(1, round(reading * 256))) / 256.0


@lru_cache(maxsize=32)
def _page_matrix(it: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    c = 1.0 - it
    i = np.arange(PAGE)
    lag = i[:, None] - i[None, :]
    powers = c ** np.clip(lag, 0, None).astype(np.float64)
    matrix = np.where(lag >= 0, it * powers, 0.0)
    carry = c ** (i + 1).astype(np.float64)
    matrix.setflags(write=False)
    carry.setflags(write=False)
    return matrix, carry


def smooth_page(r: npt.NDArray[np.float64], y_prev: float, it: float) -> npt.NDArray[np.float64]:
    """Filter exactly one page (``PAGE`` samples) of ``r`` starting from ``y_prev``."""
    matrix, carry = _page_matrix(it)
    out: npt.NDArray[np.float64] = carry * y_prev + matrix @ r
    return out


def smooth(r: npt.ArrayLike, it: float, y0: float) -> npt.NDArray[np.float64]:
    """Filter a whole array with IT from the initial state ``y0`` (page by page).

    Args:
        r: profiler positions r[1..n].
        it: the smoothing factor (already quantised).
        y0: the filter state before the first element.

    Returns:
        y[1..n] as floats (not rounded).
    """
    x = np.asarray(r, dtype=np.float64)
    n = x.size
    if it >= 1.0:
        same: npt.NDArray[np.float64] = x.copy()
        return same
    pages = -(-n // PAGE)
    padded = np.empty(pages * PAGE)
    padded[:n] = x
    padded[n:] = x[-1] if n else y0
    out = np.empty_like(padded)
    y = y0
    for p in range(pages):
        s = slice(p * PAGE, (p + 1) * PAGE)
        out[s] = smooth_page(padded[s], y, it)
        y = float(out[s][-1])
    return out[:n]


Int64Array = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


class SmoothCache:
    """Profiler positions ``r`` and filtered ``y`` of one plan, from sample ``k + 1`` on.

    Filled a page at a time; pages are anchored at the sample where the plan began, so the
    values do not depend on how a caller chunks its requests. Arrays are replaced, never
    written in place, so a shallow copy of the cache is an independent snapshot.

    Attributes:
        k: the sample before the first cached value.
        r: profiler positions (int64).
        y: filtered positions (float, not rounded); exactly the target from :attr:`end` on.
        end: the first sample at which the filtered output has settled on the target for
            good, once found: at or after the profile's own end, within half a count.
    """

    __slots__ = ("end", "k", "r", "y")

    def __init__(self, k: int) -> None:
        self.k = k
        self.r: Int64Array = np.empty(0, np.int64)
        self.y: FloatArray = np.empty(0)
        self.end: int | None = None

    def fill(
        self,
        raw: Callable[[int, int], Int64Array],
        now: int,
        n: int,
        y_now: float,
        it: float,
        plan_end: int | None,
        final: float,
    ) -> None:
        """Cover the ``n`` samples after ``now``; drop the ones before it.

        Args:
            raw: ``raw(start, count)``: profiler positions at absolute samples.
            now: the last committed sample.
            n: samples needed after ``now``.
            y_now: the filter state at ``now`` (used when nothing is cached).
            it: IT.
            plan_end: sample at which the profile issues its target (``None`` for a jog).
            final: the target.
        """
        used = min(now - self.k, self.r.size)
        if used >= _TRIM:
            self.r, self.y, self.k = self.r[used:], self.y[used:], self.k + used
        have = self.r.size - (now - self.k)
        if have >= n:
            return
        pages = -(-(n - have) // PAGE)
        r_parts = [self.r]
        y_parts = [self.y]
        start = self.k + self.r.size + 1
        y_prev = float(self.y[-1]) if self.y.size else y_now
        for p in range(pages):
            s0 = start + p * PAGE
            r = raw(s0, PAGE)
            if self.end is not None and s0 >= self.end:
                y = np.full(PAGE, final)
            else:
                y = smooth_page(r.astype(np.float64), y_prev, it)
                if plan_end is not None and s0 + PAGE > plan_end:
                    k = np.arange(s0, s0 + PAGE)
                    hit = np.flatnonzero((k >= plan_end) & (np.abs(y - final) < 0.5))
                    if hit.size:
                        i = int(hit[0])
                        self.end = s0 + i
                        y[i:] = final
            y_prev = float(y[-1])
            r_parts.append(r)
            y_parts.append(y)
        self.r = np.concatenate(r_parts)
        self.y = np.concatenate(y_parts)

    def find_end(
        self,
        raw: Callable[[int, int], Int64Array],
        now: int,
        y_now: float,
        it: float,
        plan_end: int,
        final: float,
    ) -> int | None:
        """The sample at which the smoothed move ends, when the profile ends soon.

        Fills the cache through the profile's end and the filter's tail, the values that
        stepping will use, so the end found is the one stepping reaches. A profile ending
        more than :data:`END_LOOKAHEAD` samples after ``now`` gives ``None`` (not yet known)
        and costs nothing.
        """
        if self.end is not None or plan_end - now > END_LOOKAHEAD:
            return self.end
        need = max(0, plan_end - now) + PAGE
        while self.end is None and need <= max(0, plan_end - now) + _TAIL_MAX:
            self.fill(raw, now, need, y_now, it, plan_end, final)
            need += 4 * PAGE
        return self.end
