"""Unsolicited messages, interrupts and data records as async iterators.

Messages and interrupts arrive through the sync controller's subscriptions (a reader thread
calls back) and wait in a :class:`LoopQueue`; a reader waiting on any event loop is woken
with that loop's ``call_soon_threadsafe``: no thread waits for them, and no loop is bound at
connect (decision 0091). Records stay
in the sync :class:`~galil.records.RecordStream` (its queue, its ``dropped`` count, its
errors) and are taken from it in batches on a worker thread, in slices of at most
:data:`SLICE` seconds so a cancelled reader frees its thread soon. One such call at a time
per stream: a read cancelled while it runs leaves it to finish, and the next read waits for
it (its records are kept, in order) rather than starting a second one beside it.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import math
import threading
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

from galil.aio._worker import Worker, shielded
from galil.errors import FixedAttributes, GalilConnectionError, InvalidArgument, QueueTimeoutError
from galil.link import check_count, check_wait_timeout
from galil.queues import CHECK
from galil.records import TAKE_MAX, RecordStream, fill_room

__all__ = ["SLICE", "AsyncMessages", "AsyncRecordStream", "LoopQueue"]

#: Longest a worker thread blocks in one call while waiting for a record (seconds).
SLICE = 0.1
#: Most records taken from the sync stream in one worker call.
BATCH = 1000

T = TypeVar("T")


def _wait_seconds(timeout: object) -> float:
    """A queue's or a record stream's wait, checked as its sync twin checks it
    (:func:`~galil.link.check_wait_timeout`: ``None`` is for ever, infinity is refused)."""
    seconds = check_wait_timeout(timeout)
    return math.inf if seconds is None else seconds


class LoopQueue(FixedAttributes, Generic[T]):
    """Items handed over from a thread of the sync core to the event loop that reads them,
    oldest first: ``async for item in queue`` or ``await queue.get(timeout)``.

    No loop is bound: the items wait here (thread-safe), and a reader waiting on any loop is
    woken on its own loop, so a controller connected in one ``asyncio.run`` is read in the
    next (decision 0091). Bounded: when nobody reads, the oldest items drop (``dropped``
    counts them).

    Args:
        maxlen: items kept before the oldest drop.
        what: what an item is, for the :class:`~galil.errors.QueueTimeoutError` text
            (``"unsolicited message"``).
    """

    _awaited = True

    def __init__(self, maxlen: int, what: str = "item") -> None:
        self._items: deque[T] = deque()
        self._lock = threading.Lock()  # the items, the count and the readers waiting
        self._waiting: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()
        self._maxlen = maxlen
        self._what = what
        self._closed = False
        self._dropped = 0
        self._gone: Callable[[], str] | None = None  # (see _follow())
        self._revive_link: Callable[[], Awaitable[bool]] | None = None

    @property
    def dropped(self) -> int:
        """Items dropped from a full queue (the oldest first)."""
        return self._dropped

    def deliver(self, item: T) -> None:
        """Hand an item over from any thread (a subscriber of the sync core)."""
        self._put(item)

    def _put(self, item: T) -> None:
        with self._lock:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self._dropped += 1
            self._items.append(item)
        self._wake()

    def _wake(self) -> None:
        """Wake every reader waiting, each on its own loop."""
        with self._lock:
            waiting = list(self._waiting)
        for loop, event in waiting:
            with contextlib.suppress(RuntimeError):  # its loop closed meanwhile
                loop.call_soon_threadsafe(event.set)

    def _follow(self, gone: Callable[[], str], revive: Callable[[], Awaitable[bool]]) -> None:
        """Follow the sync core's link (the async controller does, once, at connect):
        ``gone`` says why no item will come (its queue's :meth:`~galil.queues.BoundedQueue.
        ended`: the link died), ``""`` while they may (a wait looks every
        :data:`~galil.queues.CHECK` seconds); ``revive`` reopens a dead link (the automatic
        reconnect, on a worker thread) for a :meth:`get` that finds none will come, and says
        whether it did."""
        self._gone, self._revive_link = gone, revive

    def _ended(self) -> str:
        gone = self._gone
        return "" if gone is None else gone()

    async def _revive(self) -> None:
        """None will come (the link died): reopen it (``revive`` of :meth:`_follow`) or
        raise."""
        revive = self._revive_link
        if revive is not None and await revive():
            return
        why = self._ended()
        if why:
            raise GalilConnectionError(f"no {self._what} will come: {why}")

    async def get(self, timeout: float | None = None) -> T:
        """The oldest item, waiting up to ``timeout`` seconds (``None``: for ever), on the
        loop that awaits it.

        Raises:
            InvalidArgument: a timeout the sync queue refuses too (not ``None`` or a finite
                number >= 0), before anything is awaited.
            QueueTimeoutError: nothing arrived in time (a ``GalilTimeoutError`` that is also
                a ``queue.Empty``).
            GalilConnectionError: the controller was closed, or its link died (with an
                automatic reconnect, ``reconnect=True``, the link is reopened first, and the
                wait goes on; this if the reconnect failed).
        """
        wait = _wait_seconds(timeout)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wait
        while True:
            with self._lock:
                if self._items:
                    return self._items.popleft()
            if self._closed:
                raise GalilConnectionError("the async controller is closed")
            if self._ended():
                await self._revive()
                continue
            left = deadline - loop.time()
            if left <= 0:
                raise QueueTimeoutError(f"no {self._what} within {wait} s")
            if self._gone is not None:
                left = min(left, CHECK)
            await self._sleep(loop, left)

    async def _sleep(self, loop: asyncio.AbstractEventLoop, left: float) -> None:
        """Wait on ``loop`` until an item comes, the queue closes or ``left`` seconds pass.

        Not asyncio.wait_for: before Python 3.12 it swallows a cancellation that comes as the
        item does, and returns (decision 0027). The timer only wakes the loop (in time for a
        look at the source, when it has one)."""
        waiter = (loop, asyncio.Event())
        with self._lock:
            if self._items:
                return
            self._waiting.add(waiter)
        timer = None if math.isinf(left) else loop.call_later(left, waiter[1].set)
        try:
            if not self._closed:
                await waiter[1].wait()
        finally:
            with self._lock:
                self._waiting.discard(waiter)
            if timer is not None:
                timer.cancel()

    def get_nowait(self) -> T:
        """The oldest item at once; :class:`~galil.errors.QueueTimeoutError` (also a
        ``queue.Empty``) when there is none."""
        with self._lock:
            if self._items:
                return self._items.popleft()
        raise QueueTimeoutError(f"no {self._what} waiting")

    def drain(self) -> list[T]:
        """Remove and return every waiting item."""
        with self._lock:
            out = list(self._items)
            self._items.clear()
        return out

    def close(self) -> None:
        """End the iteration of every reader (the controller is closing)."""
        self._closed = True
        self._wake()

    def __aiter__(self) -> LoopQueue[T]:
        return self

    async def __anext__(self) -> T:
        try:
            return await self.get()
        except GalilConnectionError:
            if not self._closed:
                raise  # the link died: the loop does not end as if all were well
            raise StopAsyncIteration from None

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {len(self)} waiting, {self.dropped} dropped>"


class AsyncMessages(LoopQueue[str]):
    """Unsolicited lines (program ``MG`` output ...), oldest first: ``async for line in
    controller.messages`` or ``await controller.messages.get(timeout)``, on any event loop.

    Bounded: when nobody reads, the oldest lines drop (``dropped`` counts them).
    """

    def __init__(self, maxlen: int) -> None:
        super().__init__(maxlen, "unsolicited message")


def _take(stream: RecordStream, wait: float, limit: int) -> list[np.void]:
    """Up to ``limit`` records: the first waited for (at most ``wait`` s), the rest ready."""
    try:
        out = [stream.get(wait)]
    except QueueTimeoutError:
        return []
    while len(out) < limit:
        try:
            out.append(stream.get(0.0))
        except QueueTimeoutError:
            break
    return out


class AsyncRecordStream(FixedAttributes):
    """Data records every ``period`` samples, decoded: ``async for rec in stream``.

    Build it with ``await controller.records(period)``; close it (or use ``async with``) to
    stop it: ``async for`` ends then. If its link dies, ``async for`` raises
    :class:`~galil.errors.GalilConnectionError` (with ``reconnect=True`` the link is reopened
    and the loop goes on), as the sync stream's ``for`` does. Records are the sync stream's
    (:attr:`sync`): pushed by ``DR`` over Ethernet, polled with ``QR`` elsewhere, on the
    controller's clock.
    """

    _awaited = True

    def __init__(self, stream: RecordStream, worker: Worker) -> None:
        self._sync = stream
        self._worker = worker
        self._ready: deque[np.void] = deque()
        # The worker call in flight: a thread's future, bound to no event loop.
        self._pending: concurrent.futures.Future[list[np.void]] | None = None

    @property
    def sync(self) -> RecordStream:
        """The sync :class:`~galil.records.RecordStream` this one reads."""
        return self._sync

    @property
    def period(self) -> int:
        """Servo samples between records."""
        return self.sync.period

    @property
    def method(self) -> str:
        """``"DR"`` (pushed) or ``"QR"`` (polled)."""
        return self.sync.method

    @property
    def dropped(self) -> int:
        """Records dropped from a full queue (``DR`` only; counted in :attr:`missed` too)."""
        return self.sync.dropped

    @property
    def missed(self) -> int:
        """Records a reader will never get: missing between the ones received (gaps in their
        ``time``), and those :attr:`dropped`."""
        return self.sync.missed

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """``(time, missed)`` for each gap: the record after it, and how many were missing
        (a copy; the latest :data:`~galil.records.GAPS_KEPT`)."""
        return self.sync.gaps

    @property
    def gap_count(self) -> int:
        """Gaps seen since the stream began (:attr:`gaps` keeps the latest)."""
        return self.sync.gap_count

    @property
    def period_seconds(self) -> float:
        """Seconds between records."""
        return self.sync.period_seconds

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self.sync.closed

    def __len__(self) -> int:
        """Records received and not read yet."""
        return len(self._ready) + len(self.sync)

    async def subscribe(self, callback: Callable[[np.void], None]) -> Callable[[], None]:
        """Call ``callback(record)`` on this event loop for each record as it arrives (with
        ``QR``: as a read polls it); returns a function that unsubscribes.

        Raises:
            InvalidArgument: ``callback`` cannot be called.
        """
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        loop = asyncio.get_running_loop()

        def deliver(rec: np.void) -> None:
            if not loop.is_closed():
                loop.call_soon_threadsafe(callback, rec)

        return self.sync.subscribe(deliver)

    def _fetch(self, wait: float, limit: int) -> concurrent.futures.Future[list[np.void]]:
        """The worker call taking records, started unless one is in flight already: one at
        a time, so a read cancelled while its call runs (a timeout) leaves no second call
        beside the next read's (two would split or repeat records, or poll twice at once).
        The call's records go to :attr:`_ready` as it ends (on its thread), before any
        reader resumes; a reader on another event loop than the last one's waits for it as
        well (decision 0091)."""
        pending = self._pending
        if pending is None:
            pending = self._worker.submit(_take, self.sync, wait, limit)
            self._pending = pending
            pending.add_done_callback(self._keep)  # first: it runs before any reader resumes
        return pending

    def _keep(self, future: concurrent.futures.Future[list[np.void]]) -> None:
        if not future.cancelled() and future.exception() is None:
            self._ready.extend(future.result())
        if self._pending is future:
            self._pending = None

    async def _await_fetch(self, wait: float, limit: int) -> None:
        """Wait for the worker call in flight (started if none is: at most ``wait`` s for a
        record); cancelling the wait leaves the call running (its records wait for the next
        read)."""
        await shielded(self._fetch(wait, limit))

    async def batch(self, limit: int = 1000, timeout: float | None = None) -> list[np.void]:
        """The records waiting (at least one, at most ``limit``), waiting up to ``timeout`` s
        for the first.

        Raises:
            InvalidArgument: ``limit`` or ``timeout`` refused (as by the sync stream's
                ``get``), before anything is read.
            QueueTimeoutError: no record within ``timeout`` (also a ``queue.Empty``).
            GalilConnectionError: the stream is closed (or its handle died).
        """
        check_count(limit, "limit")
        wait = _wait_seconds(timeout)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + wait
        while not self._ready:
            left = deadline - loop.time()
            # Take what is there in one worker call, even when asked for one record.
            await self._await_fetch(max(0.0, min(SLICE, left)), max(limit, BATCH))
            if not self._ready and loop.time() >= deadline:
                raise QueueTimeoutError(f"no data record within {wait} s")
        out: list[np.void] = []
        while self._ready and len(out) < limit:
            out.append(self._ready.popleft())
        return out

    async def get(self, timeout: float | None = None) -> np.void:
        """The next record, waiting up to ``timeout`` seconds (``None``: for ever)."""
        got = await self.batch(1, timeout)
        return got[0]

    async def take(self, n: int, timeout: float | None = None) -> npt.NDArray[np.void]:
        """The next ``n`` records as one structured array; ``timeout`` bounds each wait.

        Cancelled or timed out part-way, the records it had taken wait for the next read
        (as the sync stream's).

        Raises:
            InvalidArgument: ``n`` not a positive integer, more than ``TAKE_MAX``, or more
                records than memory holds (as by the sync stream's ``take``), or a bad
                timeout, before anything is read.
        """
        if check_count(n, "n") > TAKE_MAX:
            raise InvalidArgument(f"n must be at most {TAKE_MAX} records at once, not {n!r:.40}")
        _wait_seconds(timeout)
        room = self.sync._room(n)
        records: list[np.void] = []
        try:
            while len(records) < n:
                records.extend(await self.batch(n - len(records), timeout))
            return fill_room(room, records)
        except BaseException:  # cancelled, or timed out: the records taken wait for the next
            self._ready.extendleft(reversed(records))
            raise

    def __aiter__(self) -> AsyncIterator[np.void]:
        """Records until the stream is closed: ``async for rec in stream``.

        The loop closes the stream as it ends (``break``, ``return``, an exception, a
        cancellation: ``DR 0`` and its handle let go, as the loop's iterator is finalized),
        unless ``async with`` holds the stream or the loop ended because the link died, as
        the sync stream's ``for`` does.
        """
        return self._loop()

    async def _loop(self) -> AsyncIterator[np.void]:
        close = True  # as the loop ends, unless its link died (a reconnect() may revive it)
        try:
            while True:
                try:
                    rec = await self.get()
                except GalilConnectionError:
                    if self.sync.closed:
                        return
                    close = False
                    raise
                yield rec
        finally:
            if close and not self.sync._held and not self.sync.closed:
                await self.close()

    async def __anext__(self) -> np.void:
        try:
            return await self.get()
        except GalilConnectionError:
            if not self.sync.closed:
                raise  # the link died: the loop does not end as if all were well
            raise StopAsyncIteration from None

    async def close(self) -> None:
        """Stop the stream (``DR 0``) and close its handle; idempotent."""
        await self._worker.run_shielded(self.sync.close)

    async def __aenter__(self) -> AsyncRecordStream:
        self.sync._held = True
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def __repr__(self) -> str:
        return f"<AsyncRecordStream of {self.sync!r}>"
