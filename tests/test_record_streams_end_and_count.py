"""Record streams end when their user is done and count what a reader lost (decision 0096).

The controller has one ``DR``: a second pushed stream is refused while one is open, and a
``for`` loop over a stream closes it as the loop ends, so streams left in loops never take
the controller's handles. ``take`` keeps what it took when it fails, and refuses a count the
host cannot hold before it reads; a polled stream faster than its link says so once and keeps
its gaps bounded. Pushed records come over TCP loopback from a manual-clock simulator.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from concurrency import handles_closed

import galil.controller
from galil.controller import Controller
from galil.errors import GalilConnectionError, InvalidArgument, QueueTimeoutError
from galil.records import GAPS_KEPT, LOG_EVERY, TAKE_MAX, RecordStream
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, simulated

WAIT = 5.0


@pytest.fixture
def tcp() -> Iterator[tuple[SimTcpServer, Controller]]:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as srv:
        c = galil.controller.connect(srv.url, timeout=2.0)
        yield srv, c
        c.close()


@pytest.fixture
def live() -> Iterator[tuple[SimTcpServer, Controller]]:
    """A simulator on a real clock: a stream opened in a ``for`` statement gets records."""
    sim = SimController("DMC-4040", RealTimeClock())
    with SimTcpServer(sim) as srv:
        c = galil.controller.connect(srv.url, timeout=2.0)
        yield srv, c
        c.close()


def _dr_stopped(srv: SimTcpServer, c: Controller) -> None:
    """``DR 0`` went out and the stream's handle is closed (the controller's own two stay)."""
    assert c.query_number("MG _DR") == 0
    handles_closed(srv.controller, 2)


def test_a_second_dr_stream_is_refused_naming_the_open_one_before_a_byte(
    tcp: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = tcp
    first = c.records(8)
    with nothing_sent(c), pytest.raises(InvalidArgument, match="one DR record stream") as info:
        c.records(16)
    assert "every 8 samples" in str(info.value)
    assert "test_record_streams_end_and_count.py" in str(info.value)  # where it was opened
    # The first one still has the controller's DR and its records.
    srv.advance(0.05)
    assert np.all(np.diff(first.take(3, timeout=WAIT)["time"]) == 8)
    assert c.query_number("MG _DR") == 8
    with c.records(16, method="QR") as polled:  # polling takes no DR
        assert polled.method == "QR"
    first.close()
    with c.records(16) as second:  # the DR is free again
        srv.advance(0.05)
        assert np.all(np.diff(second.take(2, timeout=WAIT)["time"]) == 16)


def test_a_for_loop_left_by_break_return_or_an_exception_closes_its_stream(
    live: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = live

    def by_return() -> int:
        for rec in c.records(8):
            return int(rec["time"])
        raise AssertionError("no record")

    def by_exception(stream: RecordStream) -> None:
        for _ in stream:
            raise RuntimeError("the user's bug")

    assert by_return() > 0
    _dr_stopped(srv, c)
    stream = c.records(8)
    for _ in stream:
        break
    assert stream.closed
    _dr_stopped(srv, c)
    stream = c.records(8)
    with pytest.raises(RuntimeError, match="the user's bug"):
        by_exception(stream)
    assert stream.closed
    _dr_stopped(srv, c)


def test_streams_left_in_loops_never_use_up_the_controllers_handles(
    live: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = live
    for _ in range(10):  # the controller has eight handles; two are the controller's
        for _ in c.records(8):
            break
    _dr_stopped(srv, c)


def test_a_loop_over_a_stream_a_with_block_holds_leaves_it_open_for_the_block(
    tcp: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = tcp
    with c.records(8) as stream:
        srv.advance(0.1)
        first = [int(rec["time"]) for _, rec in zip(range(3), stream, strict=False)]
        assert not stream.closed
        more = stream.take(2, timeout=WAIT)["time"].tolist()
    assert np.all(np.diff([*first, *more]) == 8)
    _dr_stopped(srv, c)


def test_with_no_free_handle_a_dr_stream_says_so_and_the_link_works(
    tcp: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = tcp
    others = [socket.create_connection(srv.address, timeout=WAIT) for _ in range(6)]
    try:
        handles_closed(srv.controller, 8)  # (every handle taken)
        with pytest.raises(GalilConnectionError, match="no free Ethernet handle"):
            c.records(8)
        assert c.query_number("MG 1") == 1
        assert c.query_number("MG _DR") == 0
    finally:
        for s in others:
            s.close()
    handles_closed(srv.controller, 2)
    with c.records(8) as stream:  # refused before: nothing was left behind
        assert stream.method == "DR"


def _arrived(stream: RecordStream, n: int) -> None:
    """Wait (at most WAIT s) until ``n`` records reached the stream, queued or dropped."""
    deadline = time.monotonic() + WAIT
    while stream.dropped + len(stream) < n and time.monotonic() < deadline:
        threading.Event().wait(0.005)  # (records on their way over loopback, not motion)


def test_a_full_queue_is_in_repr_missed_gaps_and_one_warning_per_burst(
    tcp: tuple[SimTcpServer, Controller], caplog: pytest.LogCaptureFixture
) -> None:
    srv, c = tcp
    with caplog.at_level(logging.WARNING, logger="galil.records"), c.records(8, maxlen=5) as s:
        srv.advance(0.2)  # 25 records, nobody reading
        _arrived(s, 24)
        first = s.take(5, timeout=WAIT)
        assert s.missed == s.dropped >= 19
        assert s.gaps == [(int(first["time"][0]), s.dropped)]
        assert f"{s.missed} missed ({s.dropped} dropped" in repr(s)
        s.take(len(s), timeout=WAIT) if len(s) else None  # (any late ones)
        before = s.dropped
        srv.advance(0.2)  # a second burst
        _arrived(s, before + 24)
        second = s.take(5, timeout=WAIT)
        assert s.gaps[-1] == (int(second["time"][0]), s.dropped - before)
        assert s.missed == s.dropped == sum(n for _, n in s.gaps)
    assert caplog.text.count("queue is full") == 2 == s.gap_count


def test_a_take_that_times_out_keeps_the_records_it_had_taken_qr() -> None:
    with simulated("DMC-4040") as c, c.records(4) as stream:
        polled: list[int] = []
        stream.subscribe(lambda rec: polled.append(int(rec["time"])))
        with pytest.raises(QueueTimeoutError, match=r"within 0\.002 s$"):
            stream.take(5, timeout=0.002)  # one record taken, the next 4 ms away
        assert len(stream) == 1
        after = stream.take(3)["time"].tolist()
    assert after == polled[:3]
    assert np.all(np.diff(after) == 4)
    assert stream.missed == 0


def test_a_take_that_times_out_keeps_the_records_it_had_taken_dr(
    tcp: tuple[SimTcpServer, Controller],
) -> None:
    srv, c = tcp
    with c.records(8) as stream:
        srv.advance(0.05)
        got = stream.take(3, timeout=WAIT)["time"].tolist()
        srv.advance(0.024)  # some records more, then none: the clock is manual
        with pytest.raises(QueueTimeoutError, match=r"within 1\.0 s$"):
            stream.take(100, timeout=1.0)
        assert len(stream) >= 2
        kept = stream.take(len(stream), timeout=WAIT)["time"].tolist()
    assert np.all(np.diff([*got, *kept]) == 8)
    assert stream.missed == 0


def test_take_more_than_the_host_can_hold_is_refused_before_a_record_is_read() -> None:
    with simulated("DMC-4040") as c, c.records(4) as stream:
        with nothing_sent(c), pytest.raises(InvalidArgument, match="cannot be allocated"):
            stream.take(TAKE_MAX)
        assert stream.missed == 0
        first, second = stream.take(2)["time"].tolist()
    assert second - first == 4


def test_a_poll_faster_than_the_link_says_so_once_and_keeps_its_gaps_bounded(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with (
        caplog.at_level(logging.WARNING, logger="galil.records"),
        simulated("DMC-4040", baud=19200) as c,
    ):
        start = c.link.clock()
        with c.records(2) as stream:
            assert "cannot keep up" in caplog.text
            for i, _ in enumerate(stream):
                if i == GAPS_KEPT + 100:
                    break
        elapsed = c.link.clock() - start
    assert stream.gap_count == GAPS_KEPT + 100  # a gap before every record but the first
    assert len(stream.gaps) == GAPS_KEPT
    assert stream.gaps == sorted(stream.gaps)
    assert sum(n for _, n in stream.gaps) < stream.missed
    warnings = [r for r in caplog.records if "missing" in r.getMessage()]
    assert 2 <= len(warnings) <= elapsed / LOG_EVERY + 2
    logged = sum(int(r.getMessage().split()[1]) for r in warnings)
    assert logged == stream.missed  # every missing record logged, in a few lines
