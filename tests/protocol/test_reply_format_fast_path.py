"""Whole counts skip the fixed-point detour in format_reply; the text stays the same."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument
from galil.protocol.numbers import format_reply

FORMATS = ["10.0", "8.0", "3.0", "1.0", "0.0", "10.4", "5.2", "$8.0", "$4.2"]


def outcome(value: float, fmt: str, lz: bool, space: bool) -> str:
    try:
        return format_reply(value, fmt, lz, sign_space=space)
    except InvalidArgument:
        return "refused"


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        st.integers(-(2**31) - 5, 2**31 + 5),
        st.integers(-(10**12), 10**12),
        st.integers(-1100, 1100),
    ),
    st.sampled_from(FORMATS),
    st.booleans(),
    st.booleans(),
)
def test_int_and_float_give_the_same_text(value: int, fmt: str, lz: bool, space: bool) -> None:
    assert outcome(value, fmt, lz, space) == outcome(float(value), fmt, lz, space)


def test_examples() -> None:
    assert format_reply(21, "10.0", sign_space=True) == " 21"
    assert format_reply(-9, "10.0", sign_space=True) == "-9"
    assert format_reply(0, "10.0", sign_space=True) == " 0"
    assert format_reply(123, "2.0") == "99"
    assert format_reply(-123, "2.0") == "-99"
