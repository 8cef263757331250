"""Uploads and listings when the controller's answer is lost, refused or malformed: a typed
error, the user's VF put back, and the link in step for the next command."""

from __future__ import annotations

import pytest
from rewritten_replies import Change, answering, lost, rewritten

import galil
from galil.errors import CommandError, GalilTimeoutError, ProtocolError


def _in_step_with_vf_4(dmc: galil.Controller) -> None:
    assert dmc.command("MG 1.5") == " 2"  # the user's VF 4.0 is in force again
    assert dmc.query_number("MG 1") == 1


@pytest.mark.parametrize(
    ("mark", "change", "error", "match"),
    [
        (b"VF 10.4", lost, GalilTimeoutError, "VF 10.4"),
        (b"QU", lost, GalilTimeoutError, "QU"),
        (b"QU", answering(b" 1.0000, 2.0000\r\n\x1a:"), ProtocolError, "2 values, not 3"),
        (b"QU", answering(b" 1.0000, x, 2.0000\r\n\x1a:"), ProtocolError, "x"),
    ],
    ids=["read-format-lost", "upload-lost", "too-few-values", "not-a-number"],
)
def test_a_failed_upload_puts_the_users_vf_back_and_keeps_the_link_in_step(
    mark: bytes, change: Change, error: type[Exception], match: str
) -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.arrays.define("a", 3)
        dmc.command("VF 4.0")
        wire.once(mark, change)
        with pytest.raises(error, match=match):
            dmc.arrays.upload("a")
        assert not wire.rules  # the fault did happen
        _in_step_with_vf_4(dmc)
        assert dmc.arrays.upload("a").tolist() == [0.0, 0.0, 0.0]


def test_an_upload_the_controller_refuses_says_why_and_puts_the_vf_back() -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.command("VF 4.0")
        wire.once(b"LA", answering(b" gone[3]\r\n:"))  # listed, but not there any more
        with pytest.raises(CommandError, match="Undefined array") as info:
            dmc.arrays.upload("gone")
        assert info.value.code == 82
        _in_step_with_vf_4(dmc)


@pytest.mark.parametrize(
    ("mark", "answer", "read"),
    [
        (b"LV", b" gain = 1.0000\r\n what\r\n:", lambda d: d.variables.list()),
        (b"LV", b" gain = 1.0.0\r\n:", lambda d: d.variables.list()),
        (b"LA", b" a[3]\r\n b[\r\n:", lambda d: d.arrays.list()),
    ],
    ids=["lv-line", "lv-number", "la-line"],
)
def test_a_listing_line_that_is_not_a_name_and_value_is_a_protocol_error(
    mark: bytes, answer: bytes, read: object
) -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.command("VF 4.0")
        wire.once(mark, answering(answer))
        with pytest.raises(ProtocolError, match="answered a line"):
            read(dmc)  # type: ignore[operator]
        _in_step_with_vf_4(dmc)


def test_blank_lines_in_a_listing_are_passed_over() -> None:
    dmc, wire = rewritten()
    with dmc:
        wire.once(b"LA", answering(b"\r\n a[3]\r\n\r\n b[4]\r\n:"))
        assert dmc.arrays.list() == {"a": 3, "b": 4}
        wire.once(b"LV", answering(b"\r\n gain = 2.5000\r\n:"))
        assert dmc.variables.list() == {"gain": 2.5}
        assert repr(dmc.arrays) == "<Arrays of DMC-4040>"
        assert dmc.query_number("MG 1") == 1


def test_a_firmware_without_vf_operand_uploads_as_it_prints() -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.arrays.define("a", 2)
        dmc.arrays.download("a", [1.5, -2])
        wire.once(b"_VF", answering(b"?"))  # _VF refused (TC1 then names the real reason)
        wire.once(b"TC1", lambda a: b" 1 Unrecognized command\r\n" + a[a.index(b":") :])
        before = len(wire.sent)
        assert dmc.arrays.upload("a").tolist() == [1.5, -2.0]
        assert not any(b"VF 10.4" in line for line in wire.sent[before:])  # no VF sent
        assert dmc.query_number("MG 1") == 1
