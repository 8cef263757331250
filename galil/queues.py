"""A bounded, thread-safe queue: what unsolicited lines and interrupts wait in.

When nobody reads it, the oldest items are dropped (``dropped`` counts them) rather than the
queue growing without end.
"""

from __future__ import annotations

import queue
import threading
from collections import deque
from typing import Generic, TypeVar

__all__ = ["BoundedQueue"]

T = TypeVar("T")


class BoundedQueue(Generic[T]):
    """Items oldest first; bounded (the oldest drop, counted in ``dropped``).

    Args:
        maxlen: items kept before the oldest drop.
        what: what an item is, for the ``queue.Empty`` message (``"unsolicited message"``).
    """

    def __init__(self, maxlen: int = 1000, what: str = "item") -> None:
        self._items: deque[T] = deque()
        self._maxlen = maxlen
        self._what = what
        self._cond = threading.Condition(threading.Lock())
        self.dropped = 0

    def put(self, item: T) -> None:
        """Append an item (used by the reader that receives them)."""
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> T:
        """Return the oldest item, waiting up to ``timeout`` seconds (``None``: for ever).

        Raises:
            queue.Empty: nothing arrived in time.
        """
        with self._cond:
            if not self._cond.wait_for(lambda: self._items, timeout):
                raise queue.Empty(f"no {self._what} within {timeout} s")
            return self._items.popleft()

    def get_nowait(self) -> T:
        """Return the oldest item at once; raise ``queue.Empty`` when there is none."""
        with self._cond:
            if not self._items:
                raise queue.Empty(f"no {self._what} waiting")
            return self._items.popleft()

    def drain(self) -> list[T]:
        """Remove and return every waiting item."""
        with self._cond:
            out = list(self._items)
            self._items.clear()
            return out

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {len(self)} waiting, {self.dropped} dropped>"
