"""Data records: ``controller.record()`` (QR) and ``controller.records(period)`` (DR or QR).

Over TCP the simulator streams ``DR`` records to a handle of their own; the records are
checked against the simulator's own sample-by-sample trace, so every field read must be the
state at exactly the record's sample.
"""

from __future__ import annotations

import queue
import socket
import struct
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from concurrency import handles_closed
from hypothesis import given, settings
from hypothesis import strategies as st

import galil.controller
from galil.controller import Controller
from galil.errors import InvalidArgument, LimitError, ProtocolError
from galil.models import get_model
from galil.protocol.records import RecordSplitter, decode_record, record_size
from galil.records import RecordStream
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
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


def test_qr_record_matches_the_operands(tcp: tuple[SimTcpServer, Controller]) -> None:
    srv, c = tcp
    c.command("SH")
    c.command("PR 1000,-500")
    c.command("BG AB")
    srv.advance(0.05)
    rec = c.record()
    sim = srv.controller
    assert rec["sample"] == sim.sample & 0xFFFF
    assert rec["A"]["reference"] == sim.motion("A").reference
    assert rec["A"]["position"] == sim.motion("A").encoder
    assert rec["B"]["reference"] == sim.motion("B").reference < 0
    assert rec["A"]["status"] & 0x8000  # moving
    assert rec["C"]["status"] & 0x8000 == 0
    srv.advance(1.0)
    done = c.record(as_dict=True)
    assert done["A"]["reference"] == 1000
    assert done["B"]["reference"] == -500
    assert done["A"]["stop_code"] == 1
    assert done["error_code"] == c.query_number("MG _TC")
    assert done["contour_buffer"] == 511


def test_qr_of_some_axes(tcp: tuple[SimTcpServer, Controller]) -> None:
    _, c = tcp
    c.command("DP ,77,,-3")
    rec = c.record("BD")
    assert rec["axes_present"] == 0b1010
    assert rec.dtype.names is not None
    assert "A" not in rec.dtype.names
    assert (rec["B"]["position"], rec["D"]["position"]) == (77, -3)
    with pytest.raises(InvalidArgument):
        c.record("Q")


def test_dr_stream_matches_the_servo_trace(tcp: tuple[SimTcpServer, Controller]) -> None:
    srv, c = tcp
    sim = srv.controller
    c.command("SH")
    c.command("JG 3000,-7000")
    start = sim.start_trace("AB")
    c.command("BG AB")
    with c.records(8) as stream:
        assert stream.method == "DR"
        srv.advance(0.2)
        recs = stream.take(20, timeout=WAIT)
        trace = sim.stop_trace("AB")
    samples = recs["sample"].astype(np.int64)
    assert np.all(np.diff(samples) == 8)
    for letter in "AB":
        expected = trace[letter][samples - (start & 0xFFFF)]
        assert np.array_equal(recs[letter]["reference"], expected)
    assert recs["B"]["reference"][-1] < 0 < recs["A"]["reference"][-1]
    assert c.query_number("MG _DR") == 0  # closing the stream sent DR 0
    handles_closed(sim, 2)  # and closed its handle


def test_dr_callbacks_and_iteration(tcp: tuple[SimTcpServer, Controller]) -> None:
    srv, c = tcp
    seen: list[int] = []
    stream = c.records(16)
    stream.subscribe(lambda rec: seen.append(int(rec["sample"])))
    srv.advance(0.1)
    got = []
    for rec in stream:
        got.append(int(rec["sample"]))
        if len(got) == 5:
            break
    assert np.all(np.diff(got) == 16)
    c.close()  # stops every stream
    assert stream.closed
    # What had arrived can still be read; then the iteration ends.
    rest = [int(rec["sample"]) for rec in stream]
    assert np.all(np.diff(got + rest) == 16)
    # Callbacks run on the reader thread just after a record is queued, so the iteration may
    # be ahead of them until close() has joined that thread; then they have seen every record.
    assert seen == got + rest
    assert len(got + rest) <= 0.1 / srv.controller.sample_period / 16 + 1


def test_a_full_queue_drops_the_oldest_records_and_counts_them_as_missed(
    tcp: tuple[SimTcpServer, Controller], caplog: pytest.LogCaptureFixture
) -> None:
    # Decision 0096: what the host dropped is missing for the reader too (missed, gaps, one
    # WARNING per burst), and dropped says how much of it the host dropped.
    srv, c = tcp
    with caplog.at_level("WARNING", logger="galil.records"), c.records(8, maxlen=10) as stream:
        srv.advance(0.5)  # 64 records, in several batches, nobody reading
        deadline = time.monotonic() + WAIT
        while stream.dropped + len(stream) < 60 and time.monotonic() < deadline:
            time.sleep(0.01)
        kept = stream.take(len(stream), timeout=WAIT)
    assert len(kept) == 10
    assert stream.dropped >= 50
    assert np.all(np.diff(kept["time"]) == 8)  # the newest ten, in order
    assert stream.missed == stream.dropped
    assert stream.gaps == [(int(kept["time"][0]), stream.dropped)]
    assert caplog.text.count("queue is full") == 1


def test_dr_period_below_the_minimum_is_refused(tcp: tuple[SimTcpServer, Controller]) -> None:
    srv, c = tcp
    with nothing_sent(c), pytest.raises(LimitError, match="DR period") as info:
        c.records(1)
    assert info.value.limit == 2
    handles_closed(srv.controller, 2)  # no record handle was opened
    with pytest.raises(InvalidArgument):
        c.records(0)
    with pytest.raises(InvalidArgument):
        c.records(8, method="UDP")


def test_econo_model_records_over_tcp() -> None:
    sim = SimController("DMC-2143", ManualClock())
    with SimTcpServer(sim) as srv, galil.controller.connect(srv.url, timeout=2.0) as c:
        with nothing_sent(c), pytest.raises(LimitError):
            c.records(4)  # 8 samples at least on the 21x3
        with c.records(8) as stream:
            srv.advance(0.05)
            recs = stream.take(3, timeout=WAIT)
        # The record's bytes, and the controller time each was taken at (8 bytes more).
        assert recs.dtype.itemsize == 4 + 24 + 16 + 4 * 28 + 8
        assert np.all(np.diff(recs["sample"].astype(int)) == 8)
        assert np.all(np.diff(recs["time"]) == 8)
        assert stream.missed == 0


def test_dr_on_a_model_without_ethernet_is_refused_before_a_byte_even_over_tcp() -> None:
    # A PCI (or serial) model reached over TCP (a device server) offers the transport's
    # second handles, but the controller has no Ethernet port to push records to one.
    sim = SimController("DMC-18x2", ManualClock())
    with SimTcpServer(sim) as srv, galil.controller.connect(srv.url, timeout=2.0) as c:
        handles = sim.describe_handles()
        with nothing_sent(c), pytest.raises(InvalidArgument, match="DMC-18x2 has no Ethernet"):
            c.records(8, method="DR")
        assert sim.describe_handles() == handles  # no record handle was opened
        with c.records(8) as stream:
            assert stream.method == "QR"  # "auto" polls


def test_qr_polling_where_there_is_no_second_handle() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with Controller(SimLink(sim)) as c:
        c.command("SH")
        c.command("JG 1000")
        c.command("BG A")
        with pytest.raises(InvalidArgument, match="DR needs"):
            c.records(8, method="DR")
        stream = c.records(32)
        assert isinstance(stream, RecordStream)
        assert stream.method == "QR"
        recs = stream.take(6)
        assert np.all(np.diff(recs["sample"].astype(int)) == 32)
        assert np.all(np.diff(recs["A"]["reference"]) > 0)
        with pytest.raises(queue.Empty):
            stream.get(timeout=32 * sim.sample_period / 4)
    assert stream.closed


def test_raw_dr_semantics() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as srv:
        a = socket.create_connection(srv.address, timeout=WAIT)
        b = socket.create_connection(srv.address, timeout=WAIT)

        def ask(s: socket.socket, text: bytes) -> bytes:
            s.sendall(text + b"\r")
            got = b""
            while not got.endswith((b":", b"?")):
                got += s.recv(4096)
            return got

        assert ask(a, b"DR 4,5") == b"?"  # no handle F
        assert ask(a, b"DR 4,8") == b"?"
        assert ask(a, b"DR 1,1") == b"?"
        assert ask(a, b"DR 4,1") == b":"  # to B, asked on A
        assert ask(a, b"MG _DR") == b" 4.0000\r\n:"
        assert int(ask(a, b"TB")[:-3]) & 0x40
        srv.advance(0.02)  # 20 samples: 5 records
        size = 82 + 4 * 36
        data = b""
        while len(data) < 5 * size:
            data += b.recv(65536)
        assert len(data) == 5 * size  # no ':' between streamed records
        heads = [struct.unpack_from("<BBHH", data, i * size) for i in range(5)]
        assert [h[3] for h in heads] == [4, 8, 12, 16, 20]
        b.close()  # the stream's handle closed: the stream stops
        # The server sees the close on its next tick, which may come after a's next line.
        handles_closed(sim, 1)
        assert ask(a, b"MG _DR") == b" 0.0000\r\n:"
        assert ask(a, b"DR 2") == b":"  # to the asking handle
        srv.advance(0.004)
        got = b""
        while len(got) < 2 * size:
            got += a.recv(65536)
        assert ask(a, b"DR 0")[-1:] == b":"
        a.close()
    # The serial port (in-process) has no handle to stream to.
    assert sim.feed(b"DR 2\r") == b"?"


def _records(model: str, n: int) -> list[bytes]:
    sim = SimController(model, ManualClock())
    out = []
    for i in range(n):
        sim.advance(0.01)
        out.append(sim.record("AC" if i % 3 == 2 else ""))
    return out


@settings(max_examples=100, deadline=None)
@given(
    cuts=st.lists(st.integers(0, 2000), max_size=12),
    model=st.sampled_from(["DMC-4040", "DMC-2183"]),
)
def test_splitter_cuts_a_stream_anywhere(cuts: list[int], model: str) -> None:
    records = _records(model, 6)
    stream = b"".join(records)
    qz = get_model(model).qz
    assert qz is not None
    splitter = RecordSplitter(qz)
    out: list[bytes] = []
    at = 0
    for cut in [*sorted({min(c, len(stream)) for c in cuts}), len(stream)]:
        out += splitter.feed(stream[at:cut])
        at = cut
    assert out == records
    for data in out:
        rec = decode_record(data, qz)
        assert rec["size"] == len(data) == record_size(qz, data[1])


def test_splitter_refuses_what_is_not_a_record() -> None:
    qz = (4, 52, 26, 36)
    with pytest.raises(ProtocolError, match="header"):
        RecordSplitter(qz).feed(b"\x07\x0f\xe2\x00")
    with pytest.raises(ProtocolError, match="axes need"):
        RecordSplitter(qz).feed(b"\x87\x0f\x10\x00")
    with pytest.raises(ProtocolError, match="announces 2 bytes"):
        RecordSplitter().feed(b"\x87\x0f\x02\x00")
    good = _records("DMC-4040", 1)[0]
    s = RecordSplitter(qz)
    assert s.feed(good[:100]) == []
    s.reset()
    assert s.feed(good) == [good]


def test_dmc30010_answers_qr_in_the_layout_qz_describes() -> None:
    with galil.connect("sim://DMC-30010") as dmc:
        dmc.command("PRA=1000")
        dmc.command("BGA")
        dmc.sleep(0.5)
        rec = dmc.record()
        assert int(rec["A"]["reference"]) == 1000
        assert int(rec["A"]["stop_code"]) == 1


def test_a_failing_record_callback_is_logged_and_the_others_still_get_records(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with simulated() as c:
        stream = c.records(8, method="QR")
        seen: list[int] = []

        def broken(rec: np.void) -> None:
            raise RuntimeError("callback bug")

        stream.subscribe(broken)
        unsubscribe = stream.subscribe(lambda rec: seen.append(int(rec["sample"])))
        with caplog.at_level("ERROR", logger="galil"):
            first = [int(stream.get(timeout=1)["sample"]) for _ in range(3)]
        assert seen == first
        assert "data-record callback" in caplog.text
        assert "callback bug" in caplog.text
        unsubscribe()
        stream.get(timeout=1)
        assert seen == first
        with pytest.raises(InvalidArgument, match="callable"):
            stream.subscribe("not callable")  # type: ignore[arg-type]
        stream.close()


def test_two_threads_polling_one_qr_stream_get_successive_records_never_the_same() -> None:
    """The first poll is held inside its QR write while a second thread asks: the second
    waits for its turn and takes the next record, a period later (not a second QR at once)."""
    with simulated("DMC-4040") as c, c.records(32) as stream:
        held = threading.Event()
        go_on = threading.Event()

        def hook(direction: str, data: bytes) -> None:
            if direction == "out" and b"QR" in data and not go_on.is_set():
                held.set()
                go_on.wait(timeout=10)  # bounded: a broken test fails, never hangs

        remove = c.wire_log.add(hook)
        got: list[int] = []
        first = threading.Thread(target=lambda: got.append(int(stream.get()["time"])))
        first.start()
        assert held.wait(10)
        second = threading.Thread(target=lambda: got.append(int(stream.get()["time"])))
        second.start()
        time.sleep(0.05)  # (not motion: lets the second thread reach its poll)
        go_on.set()
        first.join(10)
        second.join(10)
        remove()
        assert sorted(got)[1] - sorted(got)[0] == 32
        assert stream.missed == 0
