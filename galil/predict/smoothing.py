"""IT smoothing: the controller's single-pole low-pass on the reference position.

``y[k] = y[k-1] + IT*(r[k] - y[k-1])`` (Galil application note 3312). A first-order recursion
cannot be vectorised directly, so it is evaluated a fixed-size page at a time in closed form:
``y[i] = c**(i+1) * y_prev + sum_{j<=i} IT * c**(i-j) * r[j]`` with ``c = 1 - IT``. Pages always
have the same length, so the same inputs give bit-identical outputs however a caller chunks its
requests (the engine anchors pages at the sample of the last command).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.models import IT_RANGE

__all__ = ["IT_MAX", "IT_MIN", "PAGE", "quantise_it", "smooth", "smooth_page"]

IT_MIN, IT_MAX = IT_RANGE
#: Samples per smoothing page. 256 keeps the matrix small (512 KiB) and c**256 well above
#: underflow even at IT = 1/256.
PAGE = 256


def quantise_it(value: float) -> float:
    """Return IT as the controller stores it: a multiple of 1/256 in [0.004, 1].

    Raises:
        InvalidArgument: the value is outside [0.004, 1] or not finite.
    """
    if not np.isfinite(value) or not IT_MIN <= value <= IT_MAX:
        raise InvalidArgument(f"IT must be in [{IT_MIN}, {IT_MAX}], got {value!r}")
    # 0.004 is just above 1/256, so the smallest legal value maps to one step.
    return max(1, round(value * 256)) / 256.0


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
