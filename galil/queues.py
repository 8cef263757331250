"""Where unsolicited lines, interrupts and records go: a bounded, thread-safe queue, and the
callbacks subscribed to them.

When nobody reads the queue, the oldest items are dropped (``dropped`` counts them) rather than
the queue growing without end. A callback that fails is logged and the others still run. A
wait's timeout is checked as every wait's is (:func:`~galil.link.check_wait_timeout`), the
same check as the async twin's (:class:`galil.aio.LoopQueue`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

from galil.errors import GalilConnectionError, InvalidArgument, QueueTimeoutError
from galil.link import Link, check_wait_timeout

__all__ = ["CHECK", "BoundedQueue", "Subscribers", "source_ended"]

T = TypeVar("T")

#: Seconds between a waiting :meth:`BoundedQueue.get`'s looks at its source (a dead link).
CHECK = 0.25


class BoundedQueue(Generic[T]):
    """Items oldest first; bounded (the oldest drop, counted in ``dropped``).

    Args:
        maxlen: items kept before the oldest drop.
        what: what an item is, for the :class:`~galil.errors.QueueTimeoutError` message
            (``"unsolicited message"``).
    """

    def __init__(self, maxlen: int = 1000, what: str = "item") -> None:
        self._items: deque[T] = deque()
        self._maxlen = maxlen
        self._what = what
        self._cond = threading.Condition(threading.Lock())
        self._closed = ""  # why no more items will come (closed, or their source died)
        self.dropped = 0
        #: Why the source of the items is gone while the queue is open (the link died: its
        #: error), ``""`` while it works; a wait looks every :data:`CHECK` seconds.
        self.gone: Callable[[], str] | None = None
        #: Called by a :meth:`get` that finds none will come: reopens the link if it can (the
        #: automatic reconnect), and says whether it did.
        self.revive: Callable[[], bool] | None = None

    def put(self, item: T) -> None:
        """Append an item (used by the reader that receives them)."""
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def ended(self) -> str:
        """Why no more items will come (the queue was closed, or its source is gone: the link
        died); ``""`` while they may."""
        gone = self.gone
        return self._closed or ("" if gone is None else gone())

    def get(self, timeout: float | None = None) -> T:
        """Return the oldest item, waiting up to ``timeout`` seconds (``None``: for ever).

        When none is waiting and none will come (the controller was closed, or its link
        died), :attr:`revive` gets its chance first: with an automatic reconnect
        (``connect(..., reconnect=True)``) the link is reopened and the wait goes on.

        Raises:
            InvalidArgument: a timeout that is not ``None`` or a finite number >= 0 (infinity
                too: ``None`` waits for ever).
            QueueTimeoutError: nothing arrived in time (a ``GalilTimeoutError`` that is also
                a ``queue.Empty``).
            GalilConnectionError: nothing is waiting and none will come: the controller was
                closed or its link died (before or during the wait), or the reconnect failed.
        """
        timeout = check_wait_timeout(timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._cond:
                while not self._items:
                    why = self.ended()
                    if why:
                        break
                    left = math.inf if deadline is None else deadline - time.monotonic()
                    if left <= 0:
                        raise QueueTimeoutError(f"no {self._what} within {timeout} s")
                    self._cond.wait(min(left, CHECK))
                else:
                    return self._items.popleft()
            revive = self.revive
            if not (revive is not None and revive()):
                why = self.ended()
                if why:
                    raise GalilConnectionError(f"no {self._what} will come: {why}")

    def close(self, why: str = "the controller is closed") -> None:
        """No more items will come: a :meth:`get` waiting (or called later, once the items
        left are taken) raises :class:`~galil.errors.GalilConnectionError` saying ``why``
        (unless :attr:`revive` reopens the link)."""
        with self._cond:
            self._closed = why
            self._cond.notify_all()

    def reopen(self) -> None:
        """Items come again (the link was opened again)."""
        with self._cond:
            self._closed = ""

    def get_nowait(self) -> T:
        """Return the oldest item at once; raise :class:`~galil.errors.QueueTimeoutError`
        (also a ``queue.Empty``) when there is none."""
        with self._cond:
            if not self._items:
                raise QueueTimeoutError(f"no {self._what} waiting")
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


class Subscribers(Generic[T]):
    """The callbacks each item goes to, in the order they subscribed.

    Subscribing and unsubscribing replace the list rather than change it, so a thread
    delivering an item never sees it change under it; a callback that raises is logged on
    ``log`` (``"<what> callback ... failed"``) and the rest still get the item.

    Args:
        what: what an item is, for the log (``"interrupt"``).
        log: the logger of the room that delivers the items.
    """

    def __init__(self, what: str, log: logging.Logger) -> None:
        self._callbacks: list[Callable[[T], object]] = []
        self._what = what
        self._log = log

    def add(self, callback: Callable[[T], object]) -> Callable[[], None]:
        """Subscribe ``callback``; return the function that unsubscribes it.

        Raises:
            InvalidArgument: ``callback`` is not callable.
        """
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        self._callbacks = [*self._callbacks, callback]

        def unsubscribe() -> None:
            self._callbacks = [c for c in self._callbacks if c is not callback]

        return unsubscribe

    def notify(self, item: T) -> None:
        """Call every callback with ``item`` (on the calling thread)."""
        for cb in self._callbacks:
            try:
                cb(item)
            except Exception:
                self._log.exception("%s callback %r failed", self._what, cb)

    def __bool__(self) -> bool:
        return bool(self._callbacks)


def source_ended(
    link: Link,
    queue: BoundedQueue[T],
    stop: threading.Event,
    what: str,
    exc: GalilConnectionError | None,
) -> None:
    """A reader thread's source is gone (:meth:`~galil.link.Link.source_lost`: ``what``
    closed under ``exc``, or the idle command link found dead): unless the reader was stopped
    meanwhile (the controller closed, or a reconnect replaced it), ``queue`` is closed saying
    why, so that a :meth:`~BoundedQueue.get` waiting for it (or a later one) does not wait for
    ever: it raises, or reopens the link with the automatic reconnect
    (:attr:`~BoundedQueue.revive`).
    """
    why = link.source_lost(what, exc)
    if stop.is_set():
        return
    if why is None:
        if exc is None:
            return
        why = (
            f"{what} was closed ({exc}) while the command link works; call reconnect() to"
            " open it again"
        )
    queue.close(why)
