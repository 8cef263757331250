"""Data records, host side: one record (``QR``) or a stream of them (``DR`` or polled ``QR``).

The binary layout comes from ``QZ`` (the model table is the fallback) and is decoded by
:mod:`galil.protocol.records` into numpy structured records. Every record carries ``time``:
the controller sample it was taken at in full, its 16-bit ``sample`` counter extended against
``TIME`` (read on the same round trip for ``QR``; on the ``DR`` line, then followed record by
record, for a stream). A stream notices the records it lost from the gaps in ``time``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
import types
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from galil.errors import (
    CommandError,
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    InvalidArgument,
    ProtocolError,
    QueueTimeoutError,
    ReadOnly,
    decimal_hint,
)
from galil.link import (
    RECONNECT_ADVICE,
    Link,
    check_count,
    check_timeout,
    check_wait_timeout,
    read_handle,
    read_reply,
)
from galil.protocol import commands as cmds
from galil.protocol.numbers import read_one, whole
from galil.protocol.records import (
    SAMPLE_WRAP,
    RecordSplitter,
    decode_record,
    decode_records,
    extend_sample,
    follow_samples,
    parse_qz,
    record_size,
    record_to_dict,
    with_time,
    with_times,
)
from galil.queues import Subscribers
from galil.transport import HandleSource, Transport
from galil.units import plain_seconds

__all__ = [
    "GAPS_KEPT",
    "LOG_EVERY",
    "READ_INTERVAL",
    "TAKE_MAX",
    "RecordCallback",
    "RecordStream",
    "Records",
]

_LOG = logging.getLogger("galil.records")

#: A pushed stream's reader takes what has arrived at most this often (seconds): records
#: reach ``get()`` and callbacks up to this late, and a fast stream costs the host one
#: wake-up per interval rather than one per record.
READ_INTERVAL = 0.02

#: The most records :meth:`RecordStream.take` is asked for at once (a count, not a promise:
#: the array must fit in the host's memory as well, about 230 bytes a record on a DMC-4040, so
#: this many would be 470 GiB; a take that cannot be allocated is refused before a record is
#: read).
TAKE_MAX = 2**31 - 1

#: The gaps a stream keeps in :attr:`RecordStream.gaps` (the latest; ``gap_count`` counts all).
GAPS_KEPT = 1000

#: Seconds on the controller's clock between two WARNINGs of missing records on one stream:
#: the gaps in between are summed into the next one (or into one as the stream closes).
LOG_EVERY = 10.0

RecordCallback = Callable[[np.void], None]
Layout = tuple[int, int, int, int]


class _Gaps:
    """What a stream lost, counted where a user looks: records missing between those that
    arrived (the controller never sent them, a poll came late, a reconnect) and records a
    full queue dropped before anybody read them. Both are in ``missed``; ``gaps`` keeps the
    latest :data:`GAPS_KEPT` (``count`` counts them all); the log has a WARNING at most every
    :data:`LOG_EVERY` seconds of the controller's clock for the gaps, and one per burst of
    drops. Thread-safe: the reader thread counts, any thread reads."""

    def __init__(self, period: int, maxlen: int, clock: Callable[[], float]) -> None:
        self._period = period
        self._maxlen = maxlen
        self._clock = clock
        self._lock = threading.Lock()
        self.missed = 0
        self.dropped = 0
        self.count = 0
        self._kept: deque[tuple[int, int]] = deque(maxlen=GAPS_KEPT)
        self._burst = 0  # records dropped since a reader last took one
        self._logged: float | None = None  # the clock at the last warning of a gap
        self._held = (0, 0, 0)  # gaps, records and the latest gap's sample not logged yet

    def add(self, t: int, missed: int) -> None:
        """``missed`` records were missing before the one at sample ``t``."""
        now = self._clock()
        with self._lock:
            self.missed += missed
            self._keep(t, missed)
            gaps, records, _ = self._held
            self._held = (gaps + 1, records + missed, t)
            if self._logged is not None and now - self._logged < LOG_EVERY:
                return
            first, self._logged = self._logged is None, now
            held, self._held = self._held, (0, 0, 0)
        self._warn(held, first)

    def _keep(self, t: int, missed: int) -> None:
        """The gap before ``t`` among the kept, in time order (a drop and a gap before the same
        record are one gap); the oldest kept go when there are too many."""
        kept = self._kept
        i = len(kept)
        while i and kept[i - 1][0] > t:
            i -= 1
        if i and kept[i - 1][0] == t:
            kept[i - 1] = (t, kept[i - 1][1] + missed)
            return
        self.count += 1
        if len(kept) == GAPS_KEPT:
            if i == 0:
                return  # older than every gap kept: counted only
            kept.popleft()
            i -= 1
        kept.insert(i, (t, missed))

    def _warn(self, held: tuple[int, int, int], first: bool) -> None:
        gaps, records, t = held
        if gaps == 1:
            _LOG.warning(
                "galil: %d data record(s) missing before sample %d (every %d samples)%s",
                records,
                t,
                self._period,
                f"; further gaps are logged together, once every {LOG_EVERY:g} s" if first else "",
            )
            return
        _LOG.warning(
            "galil: %d data record(s) missing in %d gaps, the latest before sample %d (every %d"
            " samples)",
            records,
            gaps,
            t,
            self._period,
        )

    def flush(self) -> None:
        """Log the gaps not logged yet (the stream is closing)."""
        with self._lock:
            held, self._held = self._held, (0, 0, 0)
        if held[0]:
            self._warn(held, False)

    def drop(self, n: int) -> bool:
        """A full queue dropped its ``n`` oldest records (the queue's lock held); says whether
        they begin a burst (then :meth:`warn_full`, once the lock is let go)."""
        with self._lock:
            self.dropped += n
            self.missed += n
            start = not self._burst
            self._burst += n
        return start

    def warn_full(self) -> None:
        _LOG.warning(
            "galil: the data-record queue is full (%d records waiting, every %d samples): the"
            " oldest are dropped until the stream is read (counted in dropped, missed and gaps)",
            self._maxlen,
            self._period,
        )

    def taken(self, t: int) -> None:
        """A reader took the record at sample ``t`` (the queue's lock held): the records
        dropped before it are one gap."""
        if self._burst:
            with self._lock:
                burst, self._burst = self._burst, 0
                self._keep(t, burst)

    def view(self, head: int | None) -> tuple[list[tuple[int, int]], int]:
        """The gaps kept and their count, with the drops of a burst going on as a gap before
        ``head``, the oldest record waiting (the queue's lock held)."""
        with self._lock:
            kept, count = list(self._kept), self.count
            burst = self._burst
        if burst and head is not None:
            i = len(kept)
            while i and kept[i - 1][0] > head:
                i -= 1
            if i and kept[i - 1][0] == head:
                kept[i - 1] = (head, kept[i - 1][1] + burst)
            else:
                kept.insert(i, (head, burst))
                count += 1
                del kept[: max(0, len(kept) - GAPS_KEPT)]
        return kept, count


class RecordStream(FixedAttributes):
    """Data records at a fixed period, decoded, oldest first. Build it with
    :meth:`galil.Controller.records`.

    Over Ethernet the controller pushes them (``DR period,handle``) to a handle of their own,
    read by a background thread into a bounded queue (``dropped`` counts records lost when
    nobody reads). The controller has one ``DR``: while such a stream is open, another is
    refused. Elsewhere (serial, USB, the in-process simulator) each :meth:`get` waits
    until the next record is due and asks for it with ``QR``, so records are as far apart as
    asked, in the controller's time (simulated time on a manual-clock simulator).

    Each record's ``time`` field is the controller sample it was taken at. The stream checks
    that consecutive records are ``period`` samples apart: :attr:`missed` counts the records
    a reader will never get (the controller sent them, a poll came late, they were lost
    while a reconnect reopened the stream, or a full queue dropped them), :attr:`gaps` says
    where, and they are logged (WARNING on ``galil.records``: at most one every
    :data:`LOG_EVERY` seconds for the gaps, one per burst of drops).

    A ``for`` loop over the stream closes it when the loop ends (``break``, ``return``, an
    exception), unless a ``with`` block holds the stream (the block closes it) or the loop
    ended because the link died (a ``reconnect()`` may bring it back).

    Attributes:
        period: servo samples between records.
        method: ``"DR"`` (pushed) or ``"QR"`` (polled).
    """

    period: ReadOnly[int] = ReadOnly()
    method: ReadOnly[str] = ReadOnly()

    def __init__(
        self,
        source: Records,
        period: int,
        method: str,
        *,
        handle: Transport | None = None,
        maxlen: int = 10_000,
        layout: Layout | None = None,
        opened_at: str = "",
    ) -> None:
        self._period = period
        self._method = method
        self._book = _Gaps(period, maxlen, source.link.clock)
        self._last: int | None = None  # time of the last record
        self._fresh = False  # the next pushed record is the first after a DR line
        self._anchor: tuple[int, float] | None = None  # (TIME, host clock) on the DR line
        self._source = source
        self._handle = handle
        self._layout = layout
        self._opened_at = opened_at
        self._items: deque[np.void] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        self._closed = False
        self._held = False  # a with block holds it (a loop ending leaves it open)
        self._error: GalilError | None = None
        self._subscribers: Subscribers[np.void] = Subscribers("data-record", _LOG)
        self._next_due: float | None = None
        self._poll_lock = threading.Lock()  # one QR poll at a time
        self._thread: threading.Thread | None = None
        self._suspended = False

    @property
    def dropped(self) -> int:
        """Records a full queue dropped before anybody read them (``DR`` only; counted in
        :attr:`missed` too)."""
        return self._book.dropped

    @property
    def missed(self) -> int:
        """Records a reader will never get: missing between those that arrived, and those
        :attr:`dropped`."""
        return self._book.missed

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """``(time, missed)`` for each gap, oldest first: the record after it, and how many
        were missing before it (a copy; the latest :data:`GAPS_KEPT`, :attr:`gap_count`
        counts them all)."""
        return self._gaps_seen()[0]

    @property
    def gap_count(self) -> int:
        """Gaps seen since the stream began (:attr:`gaps` keeps the latest)."""
        return self._gaps_seen()[1]

    def _gaps_seen(self) -> tuple[list[tuple[int, int]], int]:
        with self._cond:
            head = int(self._items[0]["time"]) if self._items else None
            return self._book.view(head)

    @property
    def period_seconds(self) -> float:
        """Seconds between records."""
        return self.period * self._source.link.sample_period

    def _anchor_at(self, time: int) -> None:
        """The controller's ``TIME`` read on the ``DR`` line (records come after it). The
        last record's time stays for the gap count: records lost across a reconnect are
        missed too (:attr:`missed`), unless the controller's ``TIME`` went back (a reset)."""
        self._anchor = (time, self._source.link.clock())
        self._fresh = True

    def _expected(self, sample: int) -> int:
        """Where the next pushed record should be: a period after the last one, or where
        the host's clock says the controller is when they disagree by more than a quarter
        wrap (or for the first record after the ``DR`` line)."""
        fresh, self._fresh = self._fresh, False
        last = None if fresh else self._last
        expected = last + self.period if last is not None else None
        if self._anchor is not None:
            t0, c0 = self._anchor
            link = self._source.link
            by_clock = t0 + round((link.clock() - c0) / link.sample_period)
            if expected is None:
                expected = t0 + self.period
            elif abs(by_clock - expected) > SAMPLE_WRAP // 4:
                expected = by_clock
        return sample if expected is None else expected

    def _timed(self, records: np.ndarray[Any, np.dtype[Any]]) -> np.ndarray[Any, np.dtype[Any]]:
        """Pushed records with their ``time``: the first from :meth:`_expected`, each next
        one a period after the one before (within half a wrap), at once."""
        first = int(records["sample"][0])
        times = follow_samples(records["sample"], self._expected(first), self.period)
        return with_times(records, times)

    def _count_gap(self, rec: np.void) -> None:
        t = int(rec["time"])
        last, self._last = self._last, t
        if last is None or t - last <= self.period:
            return
        self._gap(t, round((t - last) / self.period) - 1)

    def _count_gaps(self, times: np.ndarray[Any, np.dtype[np.int64]]) -> None:
        """:meth:`_count_gap` for a batch, in one pass (a loop only where records are missing)."""
        before = np.empty(times.size, dtype=np.int64)
        before[0] = times[0] if self._last is None else self._last
        before[1:] = times[:-1]
        steps = times - before
        for i in np.flatnonzero(steps > self.period).tolist():
            self._gap(int(times[i]), round(int(steps[i]) / self.period) - 1)
        self._last = int(times[-1])

    def _gap(self, t: int, missed: int) -> None:
        if missed > 0:
            self._book.add(t, missed)

    def _start_reader(self, layout: Layout) -> None:
        self._suspended = False
        self._thread = threading.Thread(
            target=self._read, args=(layout,), name="galil-records", daemon=True
        )
        self._thread.start()

    def _suspend(self) -> None:
        """Stop reading and drop the handle (the link is being reopened)."""
        self._suspended = True
        if self._handle is not None:
            with contextlib.suppress(GalilError, OSError):
                self._handle.close()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._handle = self._thread = None

    def _resume(self, handle: Transport, layout: Layout) -> None:
        with self._cond:
            self._error = None  # the old handle's death is healed
        self._handle = handle
        self._start_reader(layout)

    def _read(self, layout: Layout) -> None:
        handle = self._handle
        assert handle is not None
        splitter = RecordSplitter(layout)
        while not self._closed and not self._suspended:
            try:
                chunk = read_handle(handle, 0.25)
                whole = splitter.feed_block(chunk)
                records = self._timed(self._source.decode(whole, layout)) if whole else None
            except ProtocolError as exc:
                # A stream out of step cannot be re-cut reliably: stop and say why.
                self._fail(exc)
                return
            except GalilConnectionError as exc:
                if not self._closed and not self._suspended:
                    # A dead handle may mean a dead link: asked once, it is marked dead if
                    # it does not answer either (a get() then reconnects, or raises).
                    self._source.link.source_lost("the data-record handle", exc)
                    self._fail(exc)
                return
            if records is not None:
                self._push(records)
            if chunk:
                # Let a few more records arrive before the next read: one wake-up per
                # interval, not one per record (a controller may send each on its own).
                time.sleep(READ_INTERVAL)

    def _fail(self, exc: GalilError) -> None:
        with self._cond:
            self._error = exc
            self._cond.notify_all()

    def _push(self, records: np.ndarray[Any, np.dtype[Any]]) -> None:
        """Queue a batch of timed records (one wake-up for the reader of the queue)."""
        self._count_gaps(records["time"])
        rows = list(records)
        burst = False
        with self._cond:
            items = self._items
            over = len(items) + len(rows) - self._maxlen
            if over > 0:
                # The oldest go first, as if each had been pushed alone into a full queue.
                skipped = max(0, over - len(items))
                for _ in range(min(over, len(items))):
                    items.popleft()
                rows = rows[skipped:]
                burst = self._book.drop(over)
            items.extend(rows)
            self._cond.notify_all()
        if burst:
            self._book.warn_full()
        if self._subscribers:
            for rec in records:
                self._subscribers.notify(rec)

    def subscribe(self, callback: RecordCallback) -> Callable[[], None]:
        """Call ``callback(record)`` for each record as it arrives; returns an unsubscriber.

        With ``DR`` the callback runs on the reader thread; with ``QR`` inside :meth:`get`.
        """
        return self._subscribers.add(callback)

    def get(self, timeout: float | None = None) -> np.void:
        """Return the next record, waiting up to ``timeout`` seconds (``None``: for ever).

        Raises:
            InvalidArgument: ``timeout`` not ``None`` or a finite number >= 0
                (:func:`~galil.link.check_wait_timeout`, as the async stream), before a read.
            QueueTimeoutError: no record within ``timeout`` (a ``GalilTimeoutError`` that is
                also a ``queue.Empty``).
            GalilConnectionError: the stream is closed, or its handle died (with the
                automatic reconnect, ``reconnect=True``, a link that died with it is reopened
                first, the stream with it, and the wait goes on; this if the reconnect
                failed).
            ProtocolError: the record stream could not be decoded.
        """
        timeout = check_wait_timeout(timeout)
        if self.method == "QR":
            with self._cond:
                if self._items:  # (put back by a take() that failed)
                    return self._pop()
            return self._poll(timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._cond:
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready = self._cond.wait_for(
                    lambda: self._items or self._closed or self._error is not None, left
                )
                if self._items:
                    return self._pop()
                error = self._error
                if error is None:
                    if self._closed:
                        raise GalilConnectionError(_CLOSED)
                    assert not ready
                    raise QueueTimeoutError(f"no data record within {timeout} s")
            if not self._revived(error):
                raise error

    def _pop(self) -> np.void:
        """The oldest record waiting (the lock held); records dropped before it are a gap."""
        rec = self._items.popleft()
        self._book.taken(int(rec["time"]))
        return rec

    def _put_back(self, records: list[np.void]) -> None:
        """Records taken and not handed over (a take() that failed) wait again, first."""
        with self._cond:
            self._items.extendleft(reversed(records))
            self._cond.notify_all()

    def _revived(self, error: GalilError) -> bool:
        """The handle died with its link: with the automatic reconnect the link is reopened
        (and the stream with it: a new handle, ``DR`` again); says whether it was."""
        if self._closed or not isinstance(error, GalilConnectionError):
            return False
        if not self._source.link.revive():
            return False
        with self._cond:
            return self._error is None

    def _poll(self, timeout: float | None) -> np.void:
        # One poll at a time (threads, or the async stream's worker calls): each takes the
        # next record due, never the one another thread is fetching.
        started = time.monotonic()
        if not self._poll_lock.acquire(timeout=-1 if timeout is None else timeout):
            raise QueueTimeoutError(f"no data record within {timeout} s")
        try:
            left = None if timeout is None else max(0.0, timeout - (time.monotonic() - started))
            return self._poll_locked(left, timeout)
        finally:
            self._poll_lock.release()

    def _poll_locked(self, timeout: float | None, asked: float | None) -> np.void:
        """The next record polled, waiting ``timeout`` s at most (what is left of the caller's
        ``asked``, which a timeout's message gives)."""
        if self._closed:
            raise GalilConnectionError(_CLOSED)
        link = self._source.link
        now = link.clock()
        if self._next_due is None:
            self._next_due = now
        wait = self._next_due - now
        if wait > 0:
            if timeout is not None and wait > timeout:
                link.pause(timeout)
                raise QueueTimeoutError(f"no data record within {asked} s")
            link.pause(wait)
        rec = self._source.record()
        self._count_gap(rec)
        # The next one is due a period after this one was due, so records do not drift.
        self._next_due = max(self._next_due, now) + self.period * link.sample_period
        self._subscribers.notify(rec)
        return rec

    def _room(self, n: int) -> np.ndarray[Any, np.dtype[np.uint8]]:
        """Memory for ``n`` of this stream's records, before one is read.

        Raises:
            InvalidArgument: it cannot be allocated.
        """
        layout = self._layout if self._layout is not None else self._source.layout()
        return take_room(layout, n)

    def take(self, n: int, timeout: float | None = None) -> npt.NDArray[np.void]:
        """Return the next ``n`` records as one structured array (``a["A"]["position"]``).

        ``timeout`` bounds the wait for each record. Timed out (or interrupted) part-way, the
        records it had taken wait for the next read, as the async stream's.

        Raises:
            InvalidArgument: ``n`` not a positive integer, more than :data:`TAKE_MAX`, or
                more records than memory holds, or a bad timeout, before anything is read.
            QueueTimeoutError: a record did not come within ``timeout`` (the message gives
                ``timeout``).
        """
        check_count(n, "n")
        if n > TAKE_MAX:
            raise InvalidArgument(f"n must be at most {TAKE_MAX} records at once, not {n!r:.40}")
        timeout = check_wait_timeout(timeout)
        room = self._room(n)
        got: list[np.void] = []
        try:
            while len(got) < n:
                got.append(self.get(timeout))
            return fill_room(room, got)
        except BaseException:
            self._put_back(got)
            raise

    def __iter__(self) -> Iterator[np.void]:
        """Records until the stream is closed (:meth:`close`: the loop ends).

        The loop closes the stream as it ends (``break``, ``return``, an exception: ``DR 0``
        and its handle let go), unless a ``with`` block holds the stream or the loop ended
        because the link died.

        Raises:
            GalilConnectionError: the stream's link died (with the automatic reconnect,
                ``reconnect=True``, the link is reopened and the loop goes on; this if the
                reconnect failed), or its handle was closed while the link works.
        """
        return self._loop()

    def _loop(self) -> Iterator[np.void]:
        close = True  # as the loop ends, unless its link died (a reconnect() may revive it)
        try:
            while True:
                try:
                    rec = self.get()
                except GalilConnectionError:
                    if self._closed:
                        return
                    close = False
                    raise
                yield rec
        finally:
            if close and not self._held:
                self.close()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def close(self) -> None:
        """Stop the stream (``DR 0``) and close its handle; idempotent."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._source.forget(self)
        if self.method == "DR":
            link = self._source.link
            if link.is_open:
                with contextlib.suppress(GalilError):
                    link.command_line([cmds.dr(0)])
            if self._handle is not None:
                with contextlib.suppress(GalilError, OSError):
                    self._handle.close()
            if self._thread is not None and self._thread is not threading.current_thread():
                self._thread.join(timeout=2.0)
        self._book.flush()

    def __enter__(self) -> RecordStream:
        self._held = True
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        waiting = len(self)
        missed, dropped = self.missed, self.dropped
        lost = f", {missed} missed" if missed else ""
        lost += f" ({dropped} dropped from the full queue)" if dropped else ""
        where = f", opened at {self._opened_at}" if self._opened_at else ""
        return (
            f"<RecordStream {self.method} every {self.period} samples, {waiting} waiting"
            f"{lost}, {state}{where}>"
        )


_CLOSED = "the data-record stream is closed"


def take_room(layout: Layout, n: int) -> np.ndarray[Any, np.dtype[np.uint8]]:
    """Memory for ``n`` records of ``layout`` (every axis, with their ``time``), allocated
    before a record is read: a take too large for the host is refused rather than failing
    part-way, a record read.

    Raises:
        InvalidArgument: ``n`` such records cannot be allocated.
    """
    size = record_size(layout, (1 << layout[0]) - 1) + 8
    try:
        return np.empty(n * size, dtype=np.uint8)
    except (MemoryError, ValueError) as exc:  # (ValueError: beyond numpy's size)
        raise InvalidArgument(
            f"{n} records of {size} bytes ({n * size / 2**30:.3g} GiB) cannot be allocated on"
            " this host: take fewer at once"
        ) from exc


def fill_room(
    room: np.ndarray[Any, np.dtype[np.uint8]], records: list[np.void]
) -> np.ndarray[Any, np.dtype[Any]]:
    """``records`` as one structured array, in ``room`` (from :func:`take_room`) when they
    are the size it was made for.

    Raises:
        InvalidArgument: they are not, and no other room could be allocated.
    """
    dtype = records[0].dtype
    if room.size == len(records) * dtype.itemsize:
        out = room.view(dtype)
    else:  # (records of fewer axes than the layout has: not from a stream of its own)
        try:
            out = np.empty(len(records), dtype=dtype)
        except MemoryError as exc:
            raise InvalidArgument(f"{len(records)} records cannot be allocated") from exc
    for i, rec in enumerate(records):
        out[i] = rec
    return out


class Records:
    """The data-record room of one controller: the layout, single records, streams."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._layout: Layout | None = None
        self._streams: list[RecordStream] = []
        self._lock = threading.Lock()
        self._opening = False  # a DR stream is being opened (the controller has one DR)

    def reset(self) -> None:
        """Forget the layout (after a reconnect: axes may have been reconfigured)."""
        self._layout = None

    def layout(self) -> Layout:
        """The ``QZ`` layout (asked once; the model table is the fallback).

        Raises:
            InvalidArgument: the model has no binary data record.
        """
        if self._layout is None:
            model = self.link.model
            if model.qz is None and not model.generic:  # the table says so: QZ would be refused
                raise InvalidArgument(
                    f"{model.name} has no binary data record (QR, DR); read operands instead",
                    model=model.name,
                )
            try:
                self._layout = parse_qz(self.link.send(cmds.qz()))
            except CommandError as exc:
                if model.qz is None:
                    raise InvalidArgument(
                        f"{model.name} has no binary data record (QZ refused)"
                    ) from exc
                self._layout = model.qz
        return self._layout

    def decode(self, whole: bytes, layout: Layout) -> npt.NDArray[np.void]:
        """Records laid end to end, in ``layout`` (the ``QZ`` reply), their axis blocks as the
        model has them (an 18x2's end in reserved bytes, a 21x3's in the analog input: the
        same QZ)."""
        return decode_records(whole, layout, analog=self.link.model.record_axis_analog)

    def record(self, axes: str = "", *, timeout: float | None = None) -> np.void:
        """Read one data record (``QR``, with ``MG TIME`` behind it) and decode it.

        The record's ``time`` is its sample counter extended against that ``TIME``.

        Raises:
            InvalidArgument: bad axes or timeout (a reply timeout: ``None`` is the link's,
                else :func:`~galil.link.check_timeout`), before the first byte (``QZ``), or
                the model has no data record.
            ProtocolError: the record does not match the layout ``QZ`` gave.
        """
        link = self.link
        wait = check_timeout(timeout, link.timeout)
        command = cmds.qr(axes, model=link.model)
        layout = self.layout()
        done, stamp = link.transact((command, cmds.time_stamp()), wait)
        if done.record is None:
            raise link.error(ProtocolError, f"{command.text!r} answered no binary record")
        try:
            rec = decode_record(done.record, layout, analog=link.model.record_axis_analog)
            now = round(read_one(stamp.text))
        except (ProtocolError, InvalidArgument, ValueError) as exc:
            raise link.error(ProtocolError, f"{command.text!r}: {exc}") from exc
        return with_time(rec, extend_sample(int(rec["sample"]), now))

    def record_dict(self, axes: str = "", *, timeout: float | None = None) -> dict[str, object]:
        """:meth:`record` as plain Python values (nested dicts per axis)."""
        return record_to_dict(self.record(axes, timeout=timeout))

    def samples_of(self, seconds: object) -> int:
        """A record period given in seconds (a number or a time Quantity), in samples.

        The period is rounded to whole samples (``0.01`` s is 10 samples at TM 1000, 2.3 %
        shorter: :attr:`RecordStream.period_seconds` says what it is).

        Raises:
            InvalidArgument: not a positive time, or more than 5 % from a whole number of
                samples.
        """
        value = plain_seconds(seconds, "seconds")  # (a time Quantity, in seconds)
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not (math.isfinite(value) and value > 0)
        ):
            raise InvalidArgument(
                f"seconds must be a positive number, not {seconds!r}{decimal_hint(value)}"
            )
        ts = self.link.sample_period
        if value / ts > 2**53:
            raise InvalidArgument(f"{value} s is longer than a record stream can count")
        samples = round(float(value) / ts)
        if samples < 1 or abs(samples * ts - value) > 0.05 * value:
            raise InvalidArgument(
                f"{value} s is not a whole number of {ts * 1e6:.6g} µs samples (nearest: "
                f"{max(samples, 1)} samples, {max(samples, 1) * ts:.6g} s)"
            )
        return samples

    def stream(
        self,
        period: int | None = None,
        *,
        seconds: object = None,
        method: str = "auto",
        maxlen: int = 10_000,
    ) -> RecordStream:
        """A stream of records every ``period`` samples or ``seconds`` (see
        ``Controller.records``).

        Raises:
            InvalidArgument: a bad argument, DR where there is none, or a DR stream open
                already (the controller has one ``DR``), before a byte is sent.
        """
        if (period is None) == (seconds is None):
            raise InvalidArgument(
                "give the record period in samples or in seconds=, not both"
                if period is not None
                else "give the record period: in samples (records(8)) or in seconds="
                " (records(seconds=0.01))"
            )
        if seconds is not None:
            period = self.samples_of(seconds)
        n = whole(period)
        if n is None or not 1 <= n <= 65535:
            raise InvalidArgument(f"period is a number of samples 1..65535, not {period!r}")
        if method not in ("auto", "DR", "QR"):
            raise InvalidArgument(f"method is 'auto', 'DR' or 'QR', not {method!r}")
        check_count(maxlen, "maxlen")
        pusher = self._pusher(method)
        opened_at = _opener()
        if pusher is None:
            layout = self.layout()
            self._warn_if_slow(n, layout)
            stream = RecordStream(self, n, "QR", maxlen=maxlen, layout=layout, opened_at=opened_at)
            with self._lock:
                self._streams.append(stream)
            return stream
        cmds.dr(n, 0, model=self.link.model)  # the model's DR range, before any byte
        self._reserve_dr()
        try:
            stream = self._pushed(pusher, n, maxlen, self.layout(), opened_at)
            with self._lock:
                self._streams.append(stream)
        finally:
            with self._lock:
                self._opening = False
        return stream

    def _pusher(self, method: str) -> HandleSource | None:
        """The transport a ``DR`` stream gets its handle from; ``None`` to poll (``QR``).

        Raises:
            InvalidArgument: ``method`` is ``"DR"`` and there is no Ethernet handle for it.
        """
        transport: object = self.link.transport
        model = self.link.model
        if method == "DR" and not model.has_ethernet:
            raise InvalidArgument(
                f"DR needs a second Ethernet handle; {model.name} has no Ethernet (use 'QR')",
                model=model.name,
            )
        pusher = transport if isinstance(transport, HandleSource) and model.has_ethernet else None
        if method == "DR" and pusher is None:
            raise InvalidArgument(
                f"DR needs a second Ethernet handle; {transport!r} has none (use 'QR')"
            )
        return None if method == "QR" else pusher

    def dr_stream(self) -> RecordStream | None:
        """The open stream that holds the controller's one ``DR`` (decision 0096), if any."""
        with self._lock:
            return next((s for s in self._streams if s.method == "DR" and not s.closed), None)

    def _reserve_dr(self) -> None:
        """Take the controller's one ``DR`` for a stream being opened (release it by
        clearing ``_opening``).

        Raises:
            InvalidArgument: a ``DR`` stream is open (or being opened by another thread):
                a second ``DR`` would take the first one's records (decision 0096).
        """
        with self._lock:
            held = next((s for s in self._streams if s.method == "DR" and not s.closed), None)
            if held is None and not self._opening:
                self._opening = True
                return
        what = repr(held) if held is not None else "another thread's stream, being opened,"
        raise InvalidArgument(
            f"the controller has one DR record stream, and {what} has it: a second DR would"
            " take its records; close that one first (a for loop over a stream closes it as"
            " the loop ends), or poll with method='QR'"
        )

    def _warn_if_slow(self, period: int, layout: Layout) -> None:
        """A polled stream whose records alone take longer than its period on the link (a
        serial line) misses records: said once, up front (the rate Ethernet is said to have
        is an assumption for timeouts, not a limit: not checked)."""
        link = self.link
        rate = link.byte_rate
        if rate is None or getattr(link.transport, "kind", "") == "ethernet":
            return
        size = record_size(layout, (1 << layout[0]) - 1) + 1  # (and its ':')
        each = size / rate
        if each <= period * link.sample_period:
            return
        _LOG.warning(
            "galil: a QR poll every %d samples cannot keep up on this link: each record alone"
            " is %d bytes, %.3g ms at %g bytes/s; records will be missed (missed, gaps): the"
            " record alone needs a period of %d samples or more",
            period,
            size,
            each * 1e3,
            rate,
            math.ceil(each / link.sample_period),
        )

    def _pushed(
        self,
        transport: HandleSource,
        period: int,
        maxlen: int,
        layout: Layout,
        opened_at: str,
    ) -> RecordStream:
        link = self.link
        try:
            handle = transport.open_handle()
        except GalilConnectionError as exc:
            raise link.error(GalilConnectionError, f"no handle for DR: {exc}") from exc
        try:
            index = self._which_handle(handle, opening=True)
            stream = RecordStream(
                self,
                period,
                "DR",
                handle=handle,
                maxlen=maxlen,
                layout=layout,
                opened_at=opened_at,
            )
            replies = link.command_line(
                [cmds.dr(period, index, model=link.model), cmds.time_stamp()]
            )
            stream._anchor_at(_stamp(link, replies[-1]))
        except BaseException:
            with contextlib.suppress(GalilError, OSError):
                handle.close()
            raise
        stream._start_reader(layout)
        return stream

    def _which_handle(self, handle: Transport, *, opening: bool = False) -> int:
        """``_WH`` on a handle names it (0..7 for A..H), which is what DR's second field
        wants.

        Raises:
            GalilConnectionError: the controller dropped the handle (``opening``: a new one,
                which a controller with no free handle accepts and drops at once).
        """
        link = self.link
        try:
            text = read_reply(handle, _WHICH_HANDLE, link.timeout)
        except GalilConnectionError as exc:
            if not opening:
                raise
            why = str(exc.args[0] if exc.args else exc).removesuffix(RECONNECT_ADVICE)
            raise link.error(
                GalilConnectionError,
                f"the controller dropped the data-record handle before it answered MG _WH"
                f" ({why}): it may have no free Ethernet handle (it has eight; TH lists them:"
                " close a record stream or another connection, or free a stale one with"
                " IHm=>-1); the command link works",
            ) from exc
        if not text:
            raise CommandError(None, "MG _WH answered nothing on the record handle", "MG _WH")
        try:
            index = round(read_one(text))
        except ProtocolError as exc:
            raise link.error(ProtocolError, f"MG _WH answered {text!r}") from exc
        if not 0 <= index <= 7:
            raise link.error(ProtocolError, f"MG _WH answered {text!r}: not a handle 0..7")
        return index

    def suspend(self) -> None:
        """Before a reconnect: pushed streams let go of their handles (they stay open)."""
        with self._lock:
            streams = [s for s in self._streams if s.method == "DR"]
        for s in streams:
            s._suspend()

    def resume(self) -> None:
        """After a reconnect: pushed streams get new handles and ``DR`` again, same period."""
        with self._lock:
            streams = [s for s in self._streams if s.method == "DR" and not s.closed]
        transport: object = self.link.transport
        if not streams or not isinstance(transport, HandleSource):
            return
        layout = self.layout()
        for s in streams:
            handle = transport.open_handle()
            try:
                index = self._which_handle(handle)
                replies = self.link.command_line(
                    [cmds.dr(s.period, index, model=self.link.model), cmds.time_stamp()]
                )
                s._anchor_at(_stamp(self.link, replies[-1]))
            except BaseException:
                with contextlib.suppress(GalilError, OSError):
                    handle.close()
                raise
            s._resume(handle, layout)

    def abandon(self, error: GalilError) -> None:
        """Suspended pushed streams end with ``error`` (what their readers then raise)."""
        with self._lock:
            streams = [s for s in self._streams if s.method == "DR" and s._suspended]
        for s in streams:
            s._fail(error)

    def forget(self, stream: RecordStream) -> None:
        """A stream closed itself."""
        with self._lock:
            self._streams = [s for s in self._streams if s is not stream]

    def close_all(self) -> None:
        """Close every open stream."""
        with self._lock:
            streams = list(self._streams)
        for s in streams:
            s.close()


def _opener() -> str:
    """``file:line`` of the user's call that opened a stream (the first frame outside
    ``galil``); ``""`` when it was opened on a worker thread (the async controller's)."""
    frame: types.FrameType | None = sys._getframe(1)
    name = ""
    while frame is not None:
        name = str(frame.f_globals.get("__name__", ""))
        if name != "galil" and not name.startswith("galil."):
            break
        frame = frame.f_back
    if frame is None or name in ("threading", "concurrent.futures.thread"):
        return ""
    return f"{frame.f_code.co_filename}:{frame.f_lineno}"


# ``_WH`` on a new handle, in the library's read format (decision 0032).
_WHICH_HANDLE = f"MG _WH{cmds.READ_FORMAT}\r".encode()


def _stamp(link: Link, reply: str) -> int:
    """The sample in a ``MG TIME{Z10.4}`` reply.

    Raises:
        ProtocolError: it is not one number in that format.
    """
    try:
        return round(read_one(reply))
    except ProtocolError as exc:
        raise link.error(ProtocolError, f"MG TIME answered {reply!r}") from exc
