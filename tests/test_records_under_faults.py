"""A data record answered badly, and a record period that is not a time: a typed error, and
the link in step afterwards."""

from __future__ import annotations

import pint
import pytest
from rewritten_replies import Change, answering, rewritten

from galil.errors import InvalidArgument, ProtocolError
from galil.testing import nothing_sent, simulated


def _time_garbled(answer: bytes) -> bytes:
    """The record, and its ``MG TIME`` behind it garbled."""
    i = answer.rindex(b".0000")
    return answer[:i] + b".00x0" + answer[i + 5 :]


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (answering(b" 1.0000\r\n: 5.0000\r\n:"), "expected a data record"),
        (_time_garbled, "'QR': not numbers"),
    ],
    ids=["text-for-a-record", "time-not-a-number"],
)
def test_a_data_record_answered_badly_is_a_protocol_error_and_the_link_stays_in_step(
    change: Change, match: str
) -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.record()  # the layout (QZ) is read once
        wire.once(b"QR", change)
        with pytest.raises(ProtocolError, match=match):
            dmc.record()
        assert not wire.rules
        assert dmc.query_number("MG 1") == 1
        assert dmc.record()["sample"] >= 0


def test_a_record_period_that_is_not_a_time_is_refused_before_a_byte() -> None:
    ureg = pint.UnitRegistry()
    with simulated() as dmc, nothing_sent(dmc):
        for bad in (5 * ureg.mm, 5 * ureg.dimensionless):
            with pytest.raises(InvalidArgument, match="must be a time"):
                dmc.records(seconds=bad)
