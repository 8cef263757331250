"""TC/SC tables, operand decoders and data-record layouts (constructed bytes)."""

from __future__ import annotations

import numpy as np
import pytest

from galil.codes import STOP_CODES, TC_CODES, parse_tc1, stop_text, tc_text
from galil.errors import InvalidArgument, ProtocolError
from galil.models import get_model
from galil.protocol.operands import decode_operand, parse_axes_reply
from galil.protocol.records import decode_record, parse_qz, record_dtype, record_to_dict


def test_tc_table_facts() -> None:
    assert tc_text(20) == "Begin not valid with motor off"
    assert tc_text(22) == "Begin not possible due to limit switch"
    assert tc_text(7) == "Command not valid while running"
    assert tc_text(6) == "Number out of range"
    assert tc_text(999) == "unknown error code 999"
    assert len(TC_CODES) > 100
    assert stop_text(4).endswith("(ST)")
    assert stop_text(7).endswith("(AB)")
    assert set(STOP_CODES) >= {0, 1, 2, 3, 4, 7, 50, 51, 99}


@pytest.mark.parametrize(
    ("reply", "parsed"),
    [
        (" 1 Unrecognized command", (1, "Unrecognized command")),
        ("20 Begin not valid with motor off\r\n", (20, "Begin not valid with motor off")),
        (" 22", (22, "Begin not possible due to limit switch")),
        ("0", (0, "unknown error code 0")),
    ],
)
def test_parse_tc1(reply: str, parsed: tuple[int, str]) -> None:
    assert parse_tc1(reply) == parsed


@pytest.mark.parametrize("reply", ["", "Unrecognized", "?", "1234 x"])
def test_parse_tc1_refuses(reply: str) -> None:
    with pytest.raises(ProtocolError):
        parse_tc1(reply)


@pytest.mark.parametrize(
    ("name", "text", "value"),
    [
        ("_TPA", " 1000.0000", 1000),
        ("_TPA", "-0000000009", -9),
        ("_TEB", "5", 5),
        ("_RPC", " 12", 12),
        ("_PAA", "-2147483648.0000", -2147483648),
        ("_TVA", " 512.5000", 512.5),
        ("_SPA", "25000.0000", 25000.0),
        ("_ACA", "256000", 256000.0),
        ("_DCA", "256000", 256000.0),
        ("_BGA", "1.0000", True),
        ("_BGA", "0", False),
        ("_MOA", " 1", True),
        ("_SCA", " 4.0000", 4),
        ("_TC", " 20", 20),
        ("_CM", "511.0000", 511),
        ("myvar", "1.5000", 1.5),
    ],
)
def test_decode_operand(name: str, text: str, value: object) -> None:
    got = decode_operand(name, text)
    assert got == value
    assert type(got) is type(value)


@pytest.mark.parametrize(
    ("name", "text", "error"),
    [
        ("_TPA", "12.5", ProtocolError),
        ("_BGA", "2", ProtocolError),
        ("_TPA", "abc", ProtocolError),
        ("_TCA", "1", InvalidArgument),
        ("TP A", "1", InvalidArgument),
        ("_tpa", "1", InvalidArgument),
    ],
)
def test_decode_operand_refuses(name: str, text: str, error: type[Exception]) -> None:
    with pytest.raises(error):
        decode_operand(name, text)


def test_parse_axes_reply_forms() -> None:
    assert parse_axes_reply(" 0000001000", "A", counts=True) == {"A": 1000}
    assert parse_axes_reply("-9, 5, 0, 7", "ABCD", counts=True) == {"A": -9, "B": 5, "C": 0, "D": 7}
    assert parse_axes_reply("0000000000,0000000005", "AB") == {"A": 0.0, "B": 5.0}
    assert parse_axes_reply("0,0", "AB") == {"A": 0.0, "B": 0.0}
    assert parse_axes_reply("500.0000", "A") == {"A": 500.0}
    with pytest.raises(ProtocolError):
        parse_axes_reply("1, 2", "A")
    with pytest.raises(ProtocolError):
        parse_axes_reply("", "A")
    with pytest.raises(ProtocolError):
        parse_axes_reply("1.5", "A", counts=True)


def test_parse_qz() -> None:
    assert parse_qz(" 8, 52, 26, 36") == (8, 52, 26, 36)
    assert parse_qz(" 2, 24, 16, 28") == (2, 24, 16, 28)
    with pytest.raises(ProtocolError):
        parse_qz("8, 52, 26")


@pytest.mark.parametrize(
    ("model", "size", "axis_fields"),
    [
        ("DMC-4040", 82 + 4 * 36, 13),
        ("DMC-4080", 82 + 8 * 36, 13),
        ("DMC-2183", 44 + 8 * 28, 10),
        ("DMC-1842", 44 + 4 * 28, 10),  # gclib GDataRecord1802: 2 reserved bytes per axis
        ("DMC-30010", 4 + 18 + 16 + 36, 13),
    ],
)
def test_record_dtype_sizes(model: str, size: int, axis_fields: int) -> None:
    spec = get_model(model)
    dtype = record_dtype(spec)
    assert dtype.itemsize == size == spec.record_size
    assert len(dtype["A"].names or ()) == axis_fields


def test_record_4000_offsets_and_decode() -> None:
    model = get_model("DMC-4040")
    raw = bytearray(226)
    raw[0:4] = bytes([0x87, 0x0F, 226, 0])
    raw[4:6] = (1234).to_bytes(2, "little")
    raw[50] = 20  # error code
    raw[60:62] = (511).to_bytes(2, "little")  # contour buffer space
    b = 82 + 36  # axis B block
    raw[b : b + 2] = (0x8000).to_bytes(2, "little")
    raw[b + 3] = 4
    raw[b + 8 : b + 12] = (-5).to_bytes(4, "little", signed=True)
    raw[b + 20 : b + 24] = (64 * 1000).to_bytes(4, "little", signed=True)
    rec = decode_record(bytes(raw), model)
    d = record_to_dict(rec)
    assert d["sample"] == 1234
    assert d["error_code"] == 20
    assert d["contour_buffer"] == 511
    assert d["B"]["status"] == 0x8000
    assert d["B"]["stop_code"] == 4
    assert d["B"]["position"] == -5
    assert d["B"]["velocity"] == 64_000
    assert record_dtype(model).fields is not None
    assert record_dtype(model).fields["A"][1] == 82  # type: ignore[index]


def test_record_2103_offsets() -> None:
    model = get_model("DMC-2183")
    dtype = record_dtype(model)
    assert dtype.fields is not None
    assert dtype.fields["error_code"][1] == 26
    assert dtype.fields["general_status"][1] == 27
    assert dtype.fields["A"][1] == 44
    assert dtype["A"].fields["torque"][0] == np.dtype("<i2")  # type: ignore[index]


def test_record_with_some_axes_uses_header_bits() -> None:
    model = get_model("DMC-4040")
    size = 82 + 2 * 36
    raw = bytearray(size)
    raw[0:4] = bytes([0x87, 0b0110, size, 0])  # axes B and C
    raw[82 + 36 + 8 : 82 + 36 + 12] = (77).to_bytes(4, "little", signed=True)
    rec = decode_record(bytes(raw), model)
    assert rec.dtype.names is not None
    assert "A" not in rec.dtype.names
    assert record_to_dict(rec)["C"]["position"] == 77


@pytest.mark.parametrize(
    "raw",
    [
        b"",
        b"\x07\x0f\x10\x00",
        bytes([0x87, 0x0F, 100, 0]) + bytes(10),
        bytes([0x87, 0x0F, 14, 0]) + bytes(10),
    ],
)
def test_bad_records_refused(raw: bytes) -> None:
    with pytest.raises(ProtocolError):
        decode_record(raw, get_model("DMC-4040"))


def test_model_without_record() -> None:
    with pytest.raises(InvalidArgument):
        record_dtype(get_model("DMC-1500"))
