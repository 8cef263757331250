"""Galil fixed point: parsing every reply format, argument and reply formatting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument, ProtocolError
from galil.protocol.numbers import (
    format_number,
    format_reply,
    from_fixed,
    parse_format,
    parse_number,
    parse_numbers,
    to_fixed,
)

FIXED = st.integers(min_value=-(1 << 47), max_value=(1 << 47) - 1)


@pytest.mark.parametrize(
    ("text", "value"),
    [
        (" 0000001000", 1000.0),
        ("0000000021", 21.0),
        ("-0000000009", -9.0),
        ("-9", -9.0),
        ("12.5000", 12.5),
        (" 21", 21.0),
        ("0000000010.0000", 10.0),
        ("+3", 3.0),
        (".5", 0.5),
        ("$00FF", 255.0),
        ("$FFFFFFFF", -1.0),
        ("$FFFFFFFE.8000", -1.5),
        ("$0001.8000", 1.5),
        ("$7FFFFFFF", 2147483647.0),
        ("$80000000", -2147483648.0),
        (" 500.0000\r\n", 500.0),
    ],
)
def test_parse_number_reply_formats(text: str, value: float) -> None:
    assert parse_number(text) == value


@pytest.mark.parametrize(
    "text",
    ["", " ", "nan", "inf", "1e5", "1_000", "12a", "$", "$1FFFFFFFF", "--1", "1.2.3", "$1.12345"],
)
def test_parse_number_refuses_garbage(text: str) -> None:
    with pytest.raises(ProtocolError):
        parse_number(text)


def test_parse_numbers_both_separators() -> None:
    assert parse_numbers("-9, 5, 0, 7") == [-9.0, 5.0, 0.0, 7.0]
    assert parse_numbers("0000000000,0000000005") == [0.0, 5.0]
    with pytest.raises(ProtocolError):
        parse_numbers("1,,2")


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1000, "1000"),
        (0.5, "0.5"),
        (-2.25, "-2.25"),
        (1 / 3, "0.3333"),
        (-0.00001, "0"),
        (2147483647.9999, "2147483647.9999"),
        (-2147483648, "-2147483648"),
        (10.0, "10"),
    ],
)
def test_format_number(value: float, text: str) -> None:
    assert format_number(value) == text


@pytest.mark.parametrize(
    "value", [math.nan, math.inf, -math.inf, 2147483648, -2147483648.5, 2**40, True, "1", None]
)
def test_format_number_refuses(value: object) -> None:
    with pytest.raises(InvalidArgument):
        format_number(value)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("value", "fmt", "lz", "text"),
    [
        (21, "10.0", False, "0000000021"),
        (21, "10.0", True, "21"),
        (-9, "10.0", False, "-0000000009"),
        (-9, "10.0", True, "-9"),
        (10, "10.4", False, "0000000010.0000"),
        (10, "10.4", True, "10.0000"),
        (100, "2.0", True, "99"),
        (-100, "2.0", True, "-99"),
        (10, "1.0", True, "9"),
        (123.456, "2.2", False, "99.99"),
        (1 / 3, "10.4", True, "0.3333"),
        (2 / 3, "1.4", True, "0.6667"),
        (255, "-4.0", True, "$00FF"),
        (255.5, "$4.2", True, "$00FF.80"),
        (-1, "-8.0", True, "$FFFFFFFF"),
        (-1, "-4.0", True, "$FFFF"),
        (70000, "-4.0", True, "$FFFF"),
        (0.5, "0.4", True, ".5000"),
    ],
)
def test_format_reply(value: float, fmt: str, lz: bool, text: str) -> None:
    assert format_reply(value, fmt, lz) == text


def test_format_reply_sign_space() -> None:
    assert format_reply(21, "10.0", True, sign_space=True) == " 21"
    assert format_reply(-21, "10.0", True, sign_space=True) == "-21"


@pytest.mark.parametrize("fmt", ["11.0", "10.5", "-9.0", "x", "1.2.3"])
def test_parse_format_refuses(fmt: str) -> None:
    with pytest.raises(InvalidArgument):
        parse_format(fmt)


@settings(max_examples=200, deadline=None)
@given(FIXED)
def test_fixed_round_trip(raw: int) -> None:
    assert to_fixed(from_fixed(raw)) == raw


@settings(max_examples=200, deadline=None)
@given(st.integers(min_value=-(2**31), max_value=2**31 - 1), st.integers(0, 9999))
def test_format_then_parse_round_trip(whole: int, frac: int) -> None:
    value = whole + (frac / 10_000 if whole >= 0 else -frac / 10_000)
    if not -2147483648 <= value <= 2147483647.9999:
        return
    assert parse_number(format_number(value)) == pytest.approx(value, abs=5e-5)


@settings(max_examples=200, deadline=None)
@given(FIXED, st.sampled_from(["10.0", "10.4", "8.2", "5.1"]), st.booleans(), st.booleans())
def test_reply_round_trip_within_format(raw: int, fmt: str, lz: bool, space: bool) -> None:
    value = from_fixed(raw)
    _, m, n = parse_format(fmt)
    text = format_reply(value, fmt, lz, sign_space=space)
    parsed = parse_number(text)
    if abs(value) < 10**m - 1:
        assert parsed == pytest.approx(value, abs=0.5 * 10**-n + 1e-9)
    else:
        assert abs(parsed) == pytest.approx(10**m - 10**-n if n else 10**m - 1)


@settings(max_examples=200, deadline=None)
@given(FIXED, st.integers(1, 8), st.integers(0, 4))
def test_hex_round_trip(raw: int, m: int, n: int) -> None:
    value = from_fixed(raw)
    text = format_reply(value, f"-{m}.{n}")
    whole = raw >> 16
    if m == 8 or 0 <= whole < 16**m:
        parsed = parse_number(text)
        truncated = math.floor(value * 16**n) / 16**n  # hex shows the top n fraction nibbles
        assert parsed == truncated


@settings(max_examples=300, deadline=None)
@given(
    whole=st.integers(-(2**31), 2**31 - 1),
    fmt=st.sampled_from(["10.4", "10.0", "4.2", "1.0", "8.1", "0.4"]),
    lz=st.booleans(),
    sign_space=st.booleans(),
)
def test_a_whole_float_prints_as_the_fixed_point_path_prints_it(
    whole: int, fmt: str, lz: bool, sign_space: bool
) -> None:
    # np.float64 is not exactly float: it takes the fixed-point path, the reference here.
    fast = format_reply(float(whole), fmt, lz, sign_space=sign_space)
    assert fast == format_reply(np.float64(whole), fmt, lz, sign_space=sign_space)
    assert format_reply(-0.0, fmt, lz, sign_space=sign_space) == format_reply(
        np.float64(-0.0), fmt, lz, sign_space=sign_space
    )
