"""A capture whose start is answered badly, and the calls a capture refuses in the wrong
state: a typed error, no recording left running on the controller, the link in step."""

from __future__ import annotations

import pytest
from rewritten_replies import Change, lost, rewritten

from galil.capture import Capture
from galil.errors import GalilTimeoutError, InvalidArgument, ProtocolError
from galil.testing import nothing_sent, simulated


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
