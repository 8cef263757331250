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
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

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
from galil.link import Link, check_count, check_timeout, check_wait_timeout, read_handle, read_reply
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
    record_to_dict,
    with_time,
    with_times,
)
from galil.queues import Subscribers
from galil.transport import HandleSource, Transport
from galil.units import plain_seconds

__all__ = ["READ_INTERVAL", "TAKE_MAX", "RecordCallback", "RecordStream", "Records"]

_LOG = logging.getLogger("galil.records")

#: A pushed stream's reader takes what has arrived at most this often (seconds): records
#: reach ``get()`` and callbacks up to this late, and a fast stream costs the host one
#: wake-up per interval rather than one per record.
READ_INTERVAL = 0.02

#: The most records :meth:`RecordStream.take` gathers into one array (12 days at 2 kHz).
TAKE_MAX = 2**31 - 1

RecordCallback = Callable[[np.void], None]
Layout = tuple[int, int, int, int]


class RecordStream(FixedAttributes):
    """Data records at a fixed period, decoded, oldest first. Build it with
    :meth:`galil.Controller.records`.

    Over Ethernet the controller pushes them (``DR period,handle``) to a handle of their own,
    read by a background thread into a bounded queue (``dropped`` counts records lost when
    nobody reads). Elsewhere (serial, USB, the in-process simulator) each :meth:`get` waits
    until the next record is due and asks for it with ``QR``, so records are as far apart as
    asked, in the controller's time (simulated time on a manual-clock simulator).

    Each record's ``time`` field is the controller sample it was taken at. The stream checks
    that consecutive records are ``period`` samples apart: :attr:`missed` counts the records
    that never arrived (the controller sent them, a poll came late, or they were lost while
    a reconnect reopened the stream), :attr:`gaps` says
    where, and each gap is logged (WARNING on ``galil.records``).

    Attributes:
        period: servo samples between records.
        method: ``"DR"`` (pushed) or ``"QR"`` (polled).
        dropped: records dropped from a full queue (``DR`` only).
        missed: records missing between the ones received.
        gaps: ``(time, missed)`` for each gap: the record after it, and how many were missing.
    """

    period: ReadOnly[int] = ReadOnly()
    method: ReadOnly[str] = ReadOnly()
    dropped: ReadOnly[int] = ReadOnly()
    missed: ReadOnly[int] = ReadOnly()
    gaps: ReadOnly[list[tuple[int, int]]] = ReadOnly()

    def __init__(
        self,
        source: Records,
        period: int,
        method: str,
        *,
        handle: Transport | None = None,
        maxlen: int = 10_000,
    ) -> None:
        self._period = period
        self._method = method
        self._dropped = 0
        self._missed = 0
        self._gaps: list[tuple[int, int]] = []
        self._last: int | None = None  # time of the last record
        self._fresh = False  # the next pushed record is the first after a DR line
        self._anchor: tuple[int, float] | None = None  # (TIME, host clock) on the DR line
        self._source = source
        self._handle = handle
        self._items: deque[np.void] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        self._closed = False
        self._error: GalilError | None = None
        self._subscribers: Subscribers[np.void] = Subscribers("data-record", _LOG)
        self._next_due: float | None = None
        self._poll_lock = threading.Lock()  # one QR poll at a time
        self._thread: threading.Thread | None = None
        self._suspended = False

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
            self._missed += missed
            self.gaps.append((t, missed))
            _LOG.warning(
                "galil: %d data record(s) missing before sample %d (every %d samples)",
                missed,
                t,
                self.period,
            )

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
        with self._cond:
            items = self._items
            over = len(items) + len(rows) - self._maxlen
            if over > 0:
                # The oldest go first, as if each had been pushed alone into a full queue.
                skipped = max(0, over - len(items))
                for _ in range(min(over, len(items))):
                    items.popleft()
                rows = rows[skipped:]
                self._dropped += over
            items.extend(rows)
            self._cond.notify_all()
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
            return self._poll(timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._cond:
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready = self._cond.wait_for(
                    lambda: self._items or self._closed or self._error is not None, left
                )
                if self._items:
                    return self._items.popleft()
                error = self._error
                if error is None:
                    if self._closed:
                        raise GalilConnectionError("the data-record stream is closed")
                    assert not ready
                    raise QueueTimeoutError(f"no data record within {timeout} s")
            if not self._revived(error):
                raise error

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
            return self._poll_locked(left)
        finally:
            self._poll_lock.release()

    def _poll_locked(self, timeout: float | None) -> np.void:
        if self._closed:
            raise GalilConnectionError("the data-record stream is closed")
        link = self._source.link
        now = link.clock()
        if self._next_due is None:
            self._next_due = now
        wait = self._next_due - now
        if wait > 0:
            if timeout is not None and wait > timeout:
                link.pause(timeout)
                raise QueueTimeoutError(f"no data record within {timeout} s")
            link.pause(wait)
        rec = self._source.record()
        self._count_gap(rec)
        # The next one is due a period after this one was due, so records do not drift.
        self._next_due = max(self._next_due, now) + self.period * link.sample_period
        self._subscribers.notify(rec)
        return rec

    def take(self, n: int, timeout: float | None = None) -> np.ndarray[Any, np.dtype[Any]]:
        """Return the next ``n`` records as one structured array (``a["A"]["position"]``).

        ``timeout`` bounds the wait for each record.
        """
        check_count(n, "n")
        if n > TAKE_MAX:
            raise InvalidArgument(f"n must be at most {TAKE_MAX} records at once, not {n!r:.40}")
        timeout = check_wait_timeout(timeout)
        first = self.get(timeout)
        out = np.empty(n, dtype=first.dtype)
        out[0] = first
        for i in range(1, n):
            out[i] = self.get(timeout)
        return out

    def __iter__(self) -> Iterator[np.void]:
        """Records until the stream is closed (:meth:`close`: the loop ends).

        Raises:
            GalilConnectionError: the stream's link died (with the automatic reconnect,
                ``reconnect=True``, the link is reopened and the loop goes on; this if the
                reconnect failed), or its handle was closed while the link works.
        """
        while True:
            try:
                rec = self.get()
            except GalilConnectionError:
                if self._closed:
                    return
                raise
            yield rec

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

    def __enter__(self) -> RecordStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        waiting = len(self)
        lost = f", {self.missed} missed" if self.missed else ""
        return (
            f"<RecordStream {self.method} every {self.period} samples, {waiting} waiting"
            f"{lost}, {state}>"
        )


class Records:
    """The data-record room of one controller: the layout, single records, streams."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._layout: Layout | None = None
        self._streams: list[RecordStream] = []
        self._lock = threading.Lock()

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

    def decode(self, whole: bytes, layout: Layout) -> np.ndarray[Any, np.dtype[Any]]:
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

    def record_dict(self, axes: str = "", *, timeout: float | None = None) -> dict[str, Any]:
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
        ``Controller.records``)."""
        if (period is None) == (seconds is None):
            raise InvalidArgument("give the record period in samples or in seconds=, not both")
        if seconds is not None:
            period = self.samples_of(seconds)
        n = whole(period)
        if n is None or not 1 <= n <= 65535:
            raise InvalidArgument(f"period is a number of samples 1..65535, not {period!r}")
        period = n
        if method not in ("auto", "DR", "QR"):
            raise InvalidArgument(f"method is 'auto', 'DR' or 'QR', not {method!r}")
        check_count(maxlen, "maxlen")
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
        if method != "QR" and pusher is not None:
            cmds.dr(period, 0, model=self.link.model)  # the model's DR range, before any byte
        layout = self.layout()
        if method == "QR" or pusher is None:
            stream = RecordStream(self, period, "QR", maxlen=maxlen)
        else:
            stream = self._pushed(pusher, period, maxlen, layout)
        with self._lock:
            self._streams.append(stream)
        return stream

    def _pushed(
        self, transport: HandleSource, period: int, maxlen: int, layout: Layout
    ) -> RecordStream:
        link = self.link
        try:
            handle = transport.open_handle()
        except GalilConnectionError as exc:
            raise link.error(GalilConnectionError, f"no handle for DR: {exc}") from exc
        try:
            index = self._which_handle(handle)
            stream = RecordStream(self, period, "DR", handle=handle, maxlen=maxlen)
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

    def _which_handle(self, handle: Transport) -> int:
        # _WH on a handle names it (0..7 for A..H), which is what DR's second field wants.
        link = self.link
        text = read_reply(handle, _WHICH_HANDLE, link.timeout)
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
