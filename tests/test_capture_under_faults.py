"""A capture whose start is answered badly, and the calls a capture refuses in the wrong
state: a typed error, no recording left running on the controller, the link in step."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from client_fakes import pull_cable_after
from rewritten_replies import Change, lost, rewritten

import galil
from galil.capture import Capture
from galil.errors import GalilConnectionError, GalilTimeoutError, InvalidArgument, ProtocolError
from galil.sim.controller import SimController
from galil.testing import nothing_sent, sim_of, simulated


@pytest.mark.parametrize(
    ("change", "error"),
    [
        (lost, GalilTimeoutError),
        (lambda answer: answer.replace(b".0000", b".00x0"), ProtocolError),
    ],
    ids=["lost", "malformed"],
)
def test_a_capture_whose_start_is_answered_badly_leaves_no_recording_running(
    change: Change, error: type[Exception]
) -> None:
    dmc, wire = rewritten()
    with dmc:
        wire.once(b"RC 1,", change)  # RC 1,2000;MG TIME (4 s): the recording did start
        with pytest.raises(error):
            dmc.capture(["_RPA"], count=2000)
        assert not wire.rules
        assert dmc.query_operands(["_RC"]) == [0]  # stopped again
        assert dmc.query_number("MG 1") == 1
        with dmc.capture(["_RPA"], count=10) as cap:  # the next one is not refused
            pass
        assert cap.result is not None


def test_a_capture_not_started_is_not_done_and_cannot_be_waited_for_or_stopped() -> None:
    with simulated() as dmc:
        cap = Capture(dmc.link, ["_RPA"], count=10)
        assert "new" in repr(cap)
        assert not cap.done
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="start"):
            cap.wait()
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="start"):
            cap.stop()
        cap.start()
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="already"):
            cap.start()
        with cap:  # entering a started capture does not start it again
            pass
        assert cap.result is not None  # stopped and uploaded on leaving the block
        assert cap.wait() is cap.result  # uploaded once
        assert dmc.query_number("MG 1") == 1


def test_waiting_past_its_timeout_raises_and_the_recording_goes_on_until_stopped() -> None:
    with simulated() as dmc:
        cap = dmc.capture(["_RPA"], every=256, count=1000)  # 256 s
        with pytest.raises(GalilTimeoutError, match="still records"):
            cap.wait(timeout=0.5)
        assert dmc.query_operands(["_RC"]) == [1]
        rec = cap.stop()
        assert 0 < len(rec) < 10
        assert dmc.query_operands(["_RC"]) == [0]


# -- a capture whose link dies once its RC went out (decision 0085) ----------------------------


def _recording(sim: SimController) -> bool:
    """``_RC`` read on a handle of the test's own (not through the library)."""
    port = sim.open_port("audit")
    try:
        reply = sim.feed(b"MG _RC\r", port)
    finally:
        sim.close_port(port)
    return bool(round(float(reply.decode("latin-1").strip().rstrip(":"))))


def _start_cut_short(dmc: galil.Controller) -> SimController:
    """A capture whose link dies once its ``RC`` line went out: the start raises, and the
    controller records on (its ``RC 0`` could not go out)."""
    sim = sim_of(dmc)
    pull_cable_after(dmc.link.transport, b"RC 1,")
    with pytest.raises(GalilConnectionError):
        dmc.capture(["_RPA"], count=2000)  # 4 s of recording
    assert _recording(sim)
    return sim


def test_a_capture_whose_start_lost_its_link_is_stopped_when_the_link_is_reopened(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with simulated() as dmc, caplog.at_level(logging.WARNING, "galil.controller"):
        sim = _start_cut_short(dmc)
        dmc.reconnect()
        assert not _recording(sim)  # before: recording on, and the next capture refused
        assert "still recording after its start was cut short; it is stopped now" in caplog.text
        assert len(dmc.capture(["_RPA"], count=10).wait()) == 10  # not refused


def test_a_capture_whose_start_lost_its_link_is_stopped_by_the_automatic_reconnect() -> None:
    with simulated(reconnect=True) as dmc:
        sim = sim_of(dmc)
        pull_cable_after(dmc.link.transport, b"RC 1,")
        with pytest.raises(GalilConnectionError, match="reopened"):
            dmc.capture(["_RPA"], count=2000)
        assert not _recording(sim)
        assert dmc.capture(["_RPA"], count=10).wait() is not None


def test_close_stops_a_capture_whose_start_lost_its_link() -> None:
    dmc = galil.connect("sim://DMC-4040")
    sim = _start_cut_short(dmc)
    dmc.close()  # the dead link reopened once for the RC 0, as for the stops (0073)
    assert not _recording(sim)
    assert "closed" in repr(dmc)


def test_a_capture_whose_stop_lost_its_link_is_stopped_on_reopening_and_keeps_its_values() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        dmc.A.jog(20_000)  # (something to record)
        started: list[Capture] = []

        def block() -> None:
            with dmc.capture(["_RPA"], count=2000) as cap:
                started.append(cap)
                dmc.sleep(0.5)
                transport = dmc.link.transport
                assert transport is not None
                transport.close()  # the cable is pulled: the block's stop cannot go out
                dmc.command("MG 1")

        with pytest.raises(GalilConnectionError):
            block()
        cap = started[0]
        assert _recording(sim)
        sim.advance(0.5)  # (recording on meanwhile)
        dmc.reconnect()
        assert not _recording(sim)  # before: on to its 2000th value, the arrays the user's
        assert not cap.stop_pending
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match=r"stopped .* of 2000 values"):
            cap.wait()  # fewer values than asked for: the whole recording is not there
        rec = cap.stop()  # what was recorded until the RC 0, every value the controller's
        assert 500 < len(rec) < 2000
        # the jog's, to the last one uploaded (no unrecorded zeros at the end)
        assert (np.diff(rec["_RPA"]) >= 0).all()
        assert rec["_RPA"][-1] > 0


def test_a_capture_whose_wait_lost_its_link_goes_on_and_is_read_whole_after_reconnect() -> None:
    # Not left behind: the caller holds it and its recording is intact.
    with simulated() as dmc:
        sim = sim_of(dmc)
        dmc.A.jog(20_000)
        cap = dmc.capture(["_RPA"], count=100)
        transport = dmc.link.transport
        assert transport is not None
        transport.close()
        with pytest.raises(GalilConnectionError):
            cap.wait()
        sim.advance(1.0)
        dmc.reconnect()
        rec = cap.wait()
        assert len(rec) == 100
        assert (np.diff(rec["_RPA"]) >= 0).all()
        assert rec["_RPA"][-1] > 0


def test_a_capture_whose_stop_lost_its_link_after_its_rc_0_keeps_only_the_values_recorded() -> None:
    # The RC 0 went out and the controller stopped; the reply was lost with the link. After
    # the reconnect _RC reads 0 ("stopped already"): only _RD tells how far it got.
    with simulated() as dmc:
        dmc.A.jog(20_000)  # (something to record)
        cap = dmc.capture(["_RPA"], count=2000)  # 4 s of recording
        dmc.sleep(0.5)
        pull_cable_after(dmc.link.transport, b"RC 0")
        with pytest.raises(GalilConnectionError):
            cap.stop()
        assert cap.stop_pending
        dmc.reconnect()
        assert not cap.stop_pending
        assert not _recording(sim_of(dmc))
        dmc.sleep(4.0)  # (past the recording's whole duration: it recorded no more)
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match=r"stopped .* of 2000 values"):
            cap.wait()  # before: 2000 values, the last ones the arrays' unrecorded zeros
        rec = cap.stop()
        assert 200 < len(rec) < 300  # 0.5 s every 2 samples
        assert (np.diff(rec["_RPA"]) >= 0).all()
        assert rec["_RPA"][-1] > 0


def test_a_capture_that_ended_by_itself_before_its_stop_lost_its_link_is_read_whole() -> None:
    with simulated() as dmc:
        dmc.A.jog(20_000)
        cap = dmc.capture(["_RPA"], count=100)  # 0.2 s
        dmc.sleep(0.5)  # every value recorded
        pull_cable_after(dmc.link.transport, b"_RC")  # the stop's query of _RC: no reply
        with pytest.raises(GalilConnectionError):
            cap.stop()
        assert cap.stop_pending
        dmc.reconnect()
        rec = cap.wait()  # _RD says all 100 were recorded: nothing was cut
        assert len(rec) == 100
        assert (np.diff(rec["_RPA"]) >= 0).all()
        assert rec["_RPA"][-1] > 0
