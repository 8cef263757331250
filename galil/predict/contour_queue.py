"""The contour buffer of one axis (CM, CD, DT) as the engine steps it.

Segments run back to back; sample ``j`` (1..2**n) of a segment starting at ``r0`` is at
``r0 + floor(c*j / 2**n)`` (see ``shared/reference/profiler-model.md``, "Contour mode"). An empty
queue holds the position.
"""

from __future__ import annotations

import copy

import numpy as np
import numpy.typing as npt

__all__ = ["ContourQueue"]

Int64Array = npt.NDArray[np.int64]


class ContourQueue:
    """Queued contour segments and the progress of the one running.

    Attributes:
        base: position at the start of the running segment (the held position when empty).
        rate: the last stepped segment's speed, counts/sample (0 when empty).
        ending: ``CD 0=0`` received: leave contour mode once the queue drains.
    """

    __slots__ = ("_c", "_head", "_n", "base", "elapsed", "ending", "rate")

    def __init__(self, base: int) -> None:
        self._c: list[int] = []
        self._n: list[int] = []
        self._head = 0
        self.elapsed = 0  # samples already run of the head segment
        self.base = int(base)
        self.rate = 0.0
        self.ending = False

    def __deepcopy__(self, memo: dict[int, object]) -> ContourQueue:
        new = copy.copy(self)
        new._c = list(self._c)
        new._n = list(self._n)
        return new

    def add(self, increment: int, n: int) -> None:
        """Queue ``CD increment`` over ``2**n`` samples."""
        self._c.append(int(increment))
        self._n.append(int(n))

    @property
    def queued(self) -> int:
        """Segments not yet finished (including the one running)."""
        return len(self._c) - self._head

    def window(self, n: int) -> tuple[Int64Array, int, int, int, float]:
        """Positions of the next ``n`` samples and the queue state after them.

        Returns:
            ``(positions, segments finished, elapsed in the new head, its base, rate)``.
        """
        h = self._head
        # Each segment lasts at least 2 samples, so this many always cover the window.
        m = min(len(self._c) - h, n // 2 + 2)
        if m == 0:
            return np.full(n, self.base, np.int64), 0, 0, self.base, 0.0
        c = np.array(self._c[h : h + m], dtype=np.int64)
        e = np.array(self._n[h : h + m], dtype=np.int64)
        length = np.left_shift(1, e)
        ends = np.cumsum(length) - self.elapsed
        starts = ends - length
        bases = self.base + np.cumsum(c) - c
        s = np.arange(1, n + 1, dtype=np.int64)
        idx = np.searchsorted(ends, s, side="left")
        inside = idx < m
        ic = np.minimum(idx, m - 1)
        j = s - starts[ic]
        pos = bases[ic] + np.right_shift(c[ic] * j, e[ic])
        final = int(bases[-1] + c[-1])
        out = np.where(inside, pos, final)
        done = int(np.searchsorted(ends, n, side="right"))
        if done < m:
            elapsed = int(n - starts[done])
            base = int(bases[done])
        else:
            elapsed, base = 0, final
        last = int(idx[-1])
        rate = float(c[last]) / float(length[last]) if last < m else 0.0
        return out.astype(np.int64), done, elapsed, base, rate

    def rates(self, n: int) -> npt.NDArray[np.float64]:
        """The speed (counts/sample) of the segment each of the next ``n`` samples is in, as
        :attr:`rate` reads once that sample has run (0 beyond the last segment queued)."""
        h = self._head
        m = min(len(self._c) - h, n // 2 + 2)  # (as in window: enough to cover n samples)
        if m == 0:
            return np.zeros(n)
        length = np.left_shift(1, np.array(self._n[h : h + m], dtype=np.int64))
        ends = np.cumsum(length) - self.elapsed
        idx = np.searchsorted(ends, np.arange(1, n + 1, dtype=np.int64), side="left")
        speed = np.append(np.array(self._c[h : h + m], dtype=np.float64) / length, 0.0)
        out: npt.NDArray[np.float64] = speed[idx]
        return out

    def step(self, n: int) -> Int64Array:
        """Run ``n`` samples: return their positions and drop the finished segments."""
        r, done, elapsed, base, rate = self.window(n)
        self._head += done
        self.elapsed, self.base, self.rate = elapsed, base, rate
        if self._head > 4096 and self._head * 2 > len(self._c):
            del self._c[: self._head], self._n[: self._head]
            self._head = 0
        return r
