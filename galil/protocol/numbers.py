"""Galil numbers: the 32.16 fixed point, reply parsing and PF/VF/LZ formatting.

The controller keeps every value as a signed 32-bit integer plus a 16-bit fraction (1/65536).
It accepts at most four decimals on input and prints replies in the PF (positions), VF
(variables, ``MG``) formats, with or without leading zeros (``LZ``), or in hex (``$``).
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from numbers import Integral, Real

import numpy as np

from galil.errors import InvalidArgument, ProtocolError
from galil.models import INT32_MAX, INT32_MIN

__all__ = [
    "MAX_ARG",
    "MIN_ARG",
    "format_number",
    "format_reply",
    "from_fixed",
    "parse_format",
    "parse_number",
    "parse_numbers",
    "parse_plain_read",
    "parse_read",
    "read_one",
    "to_fixed",
    "whole",
]

#: Largest magnitude an argument may have (the integer range plus four decimals).
MAX_ARG = INT32_MAX + 0.9999
#: Smallest argument: the register's minimum, needed to disable BL (``BLA=-2147483648``).
MIN_ARG = float(INT32_MIN)

_FIX_MIN = -(1 << 47)  # raw 32.16 limits (48-bit two's complement)
_FIX_MAX = (1 << 47) - 1
_POW10 = [10**i for i in range(11)]
_INT_LO, _INT_HI = -(1 << 31), (1 << 31) - 1  # whole numbers inside the 32.16 range

# Reply forms: optional blanks, sign, digits with an optional fraction; or hex with '$'.
_DECIMAL = re.compile(r"[ \t\r\n]*[-+]?(?:\d+(?:\.\d*)?|\.\d+)[ \t\r\n]*")
_HEX = re.compile(r"\s*(?P<sign>-?)\$(?P<int>[0-9A-Fa-f]+)(?:\.(?P<frac>[0-9A-Fa-f]*))?\s*")
_FORMAT = re.compile(r"\s*(?P<hex>[$-]?)(?P<m>\d{1,2})(?:\.(?P<n>\d))?\s*")


def parse_number(text: str) -> float:
    """Parse one number as the controller prints it.

    Accepts leading zeros or not, a leading space, a sign, decimals (``" 0000001000"``,
    ``"-9"``, ``"12.5000"``) and hex (``"$00FF"``, ``"$FFFFFFFF"`` = -1, ``"$0001.8000"``).

    Raises:
        ProtocolError: the text is not a Galil number.
    """
    if _DECIMAL.fullmatch(text) is not None:
        return float(text)
    m = _HEX.fullmatch(text)
    if m is None:
        raise ProtocolError(f"not a Galil number: {text!r}")
    digits = m.group("int")
    if len(digits) > 8:
        raise ProtocolError(f"hex number wider than 32 bits: {text!r}")
    value = float(int(digits, 16))
    if len(digits) == 8 and value >= 2**31:
        value -= 2**32  # eight digits are the full register: two's complement
    frac = m.group("frac") or ""
    if frac:
        if len(frac) > 4:
            raise ProtocolError(f"hex fraction wider than 16 bits: {text!r}")
        value += int(frac, 16) / 16 ** len(frac)
    return -value if m.group("sign") else value


# The reply to the library's own reads (``MG`` with every item in ``{Z10.4}``, decision 0032):
# numbers with exactly four decimals, each after a blank or its sign. The four decimals mark
# where each number ends, so the values read right even without the blank; anything else (the
# 9s or $ of a VF the format did not override, text) is refused rather than misread.
_READ_ITEM = re.compile(r"-?\d{0,10}\.\d{4}")


def _read_items(reply: str) -> list[str] | None:
    """The numbers of ``reply`` as text, or ``None`` if it holds anything besides such numbers
    and blanks (one scan and a length check: cheaper than a full match of the whole reply)."""
    items = _READ_ITEM.findall(reply)
    if not items or sum(map(len, items)) + reply.count(" ") != len(reply):
        return None
    return items


def parse_read(reply: str) -> list[float]:
    """Every number in the reply to the library's own ``MG`` (``" 12.0000-3.5000"``).

    Raises:
        ProtocolError: the reply is not numbers in the read format (``{Z10.4}``).
    """
    items = _read_items(reply)
    if items is None:
        raise ProtocolError(f"not numbers with four decimals: {reply!r}")
    return list(map(float, items))


# A number whose whole part is all nines may be a VF overflow ("the greatest number
# representable": VF 4.4 prints 123456 as 9999.9999): worth asking again in the read format.
_NINES = re.compile(r"(?<![0-9])9+\.\d{4}")


def parse_plain_read(reply: str) -> list[float] | None:
    """The numbers of a reply to ``MG`` items sent without a format (the library's fast read,
    decision 0032), or ``None`` when the reply may not be what the default ``VF 10.4`` prints:
    not numbers with four decimals (another VF: fewer decimals, hex), or a number of nines
    that an overflow would print. ``None`` means: ask again with :data:`READ_FORMAT` on each
    item, which no VF changes (a true 9999 then reads 9999)."""
    items = _read_items(reply)
    if items is None or ("9." in reply and _NINES.search(reply) is not None):
        return None
    return list(map(float, items))


def read_one(reply: str) -> float:
    """The one number in the reply to the library's own ``MG`` of one item (``MG TIME``).

    Raises:
        ProtocolError: not exactly one number in the read format.
    """
    values = parse_read(reply)
    if len(values) != 1:
        raise ProtocolError(f"{len(values)} numbers, not one: {reply!r}")
    return values[0]


def parse_numbers(text: str) -> list[float]:
    """Parse a comma separated reply (``"-9, 5, 0, 7"``, ``"0000000000,0000000000"``).

    Raises:
        ProtocolError: a field is empty or not a number.
    """
    return [parse_number(field) for field in text.split(",")]


def format_number(value: float) -> str:
    """Format an argument: at most four decimals, no trailing zeros (``1000``, ``-2.25``).

    Raises:
        InvalidArgument: NaN, infinity, a non-number, or outside +/-2,147,483,647.9999.
    """
    if type(value) is int:  # the hot path: counts
        if INT32_MIN <= value <= INT32_MAX:
            return str(value)
    elif type(value) is not float and not _is_real(value):
        raise InvalidArgument(f"not a number: {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InvalidArgument(f"{value!r} cannot be sent: the controller has no NaN or infinity")
    if not MIN_ARG <= v <= MAX_ARG:
        raise InvalidArgument(
            f"{value!r} is outside the controller's range -2147483648 .. 2147483647.9999"
        )
    text = f"{v:.4f}".rstrip("0").rstrip(".")
    if text in ("-0", ""):
        return "0"
    return text


def _is_real(value: object) -> bool:
    # bool is an int, but True/False as a count is almost always a bug.
    return isinstance(value, Real) and not isinstance(value, (bool, np.bool_))


def to_fixed(value: float) -> int:
    """Return the raw 32.16 integer the controller stores for ``value`` (rounded).

    Raises:
        InvalidArgument: NaN, infinity or outside the 48-bit range.
    """
    if not math.isfinite(value):
        raise InvalidArgument(f"{value!r} has no fixed-point representation")
    raw = round(value * 65536)
    if not _FIX_MIN <= raw <= _FIX_MAX:
        raise InvalidArgument(f"{value!r} is outside the 32.16 fixed-point range")
    return raw


def from_fixed(raw: int) -> float:
    """Return the value of a raw 32.16 integer.

    Raises:
        InvalidArgument: ``raw`` is outside the 48-bit range.
    """
    if not _FIX_MIN <= raw <= _FIX_MAX:
        raise InvalidArgument(f"{raw!r} is outside the 32.16 fixed-point range")
    return raw / 65536


@lru_cache(maxsize=64)  # a simulator formats every reply with the same few formats
def parse_format(fmt: str) -> tuple[bool, int, int]:
    """Split a PF/VF format (``"10.4"``, ``"-8.2"`` or ``"$8.2"`` for hex) into (hex, m, n).

    Raises:
        InvalidArgument: not a format, or m > 10 (8 for hex) or n > 4.
    """
    m = _FORMAT.fullmatch(fmt)
    if m is None:
        raise InvalidArgument(f"not a PF/VF format: {fmt!r}")
    is_hex = bool(m.group("hex"))
    digits = int(m.group("m"))
    decimals = int(m.group("n") or 0)
    if digits > (8 if is_hex else 10) or decimals > 4:
        raise InvalidArgument(f"format {fmt!r} out of range (m <= 10, 8 for hex; n <= 4)")
    return is_hex, digits, decimals


def format_reply(
    value: float, fmt: str = "10.4", lz: bool = True, *, sign_space: bool = False
) -> str:
    """Render ``value`` as the controller prints it for a PF/VF format.

    ``lz`` is the LZ setting (True = LZ1, leading zeros removed). Overflow prints nines
    (``PF 2`` of 100 gives ``99``); hex overflow prints ``F``s. With ``sign_space`` a positive
    number gets a blank where the minus sign would be, as the controller's replies do
    (``" 21"``); the default leaves it off.

    Examples: ``format_reply(21, "10.0", lz=False) == "0000000021"``,
    ``format_reply(10, "10.4", lz=False) == "0000000010.0000"``, ``format_reply(-9, "10.0")
    == "-9"``.

    Raises:
        InvalidArgument: a bad format or a non-finite value.
    """
    is_hex, digits, decimals = parse_format(fmt)
    if type(value) is int and not decimals and not is_hex and lz and _INT_LO <= value <= _INT_HI:
        # Whole counts (TP, RP, TE ...), the commonest reply: no fixed-point detour.
        if 0 < value < _POW10[digits]:
            return f" {value}" if sign_space else str(value)
        if -_POW10[digits] < value < 0:
            return str(value)
    if (
        type(value) is float
        and lz
        and digits
        and not is_hex
        and value.is_integer()
        and -_POW10[digits] < value < _POW10[digits]
        and _INT_LO <= value <= _INT_HI
    ):
        # A whole number held as a float (MG of an operand): what the fixed-point detour
        # below prints for it, without the detour.
        whole = int(value)
        frac = "." + "0" * decimals if decimals else ""
        if whole < 0:
            return f"-{-whole}{frac}"
        return f" {whole}{frac}" if sign_space else f"{whole}{frac}"
    raw = to_fixed(float(value))
    if is_hex:
        return _format_hex(raw, digits, decimals)
    negative = raw < 0
    scaled = abs(raw) * 10**decimals
    # round half away from zero, in integers so 32.16 values print exactly
    units = (scaled + 32768) >> 16
    whole, frac = divmod(units, 10**decimals)
    if whole >= 10**digits:
        int_text, frac = "9" * digits, 10**decimals - 1
    elif digits == 0:
        int_text = ""
    else:
        int_text = str(whole) if lz else str(whole).rjust(digits, "0")
    text = int_text if decimals == 0 else f"{int_text}.{frac:0{decimals}d}"
    if negative and units:
        return "-" + text
    return " " + text if sign_space else text


def _format_hex(raw: int, digits: int, decimals: int) -> str:
    twos = raw & ((1 << 48) - 1)
    whole, frac16 = twos >> 16, twos & 0xFFFF
    if (raw < 0 and digits < 8) or whole >= 16**digits:
        int_text = "F" * digits  # assumption: hex overflow saturates like decimal 9s
        frac16 = 0xFFFF
    else:
        int_text = f"{whole:0{digits}X}" if digits else ""
    if decimals == 0:
        return "$" + int_text
    return f"${int_text}.{frac16 >> (16 - 4 * decimals):0{decimals}X}"


def whole(value: object) -> int | None:
    """``value`` as an ``int`` if it is one or a numpy integer; ``None`` otherwise (a bool,
    numpy's too, and a float, even a whole one: counts, indices and periods are integers)."""
    if isinstance(value, bool) or not isinstance(value, Integral):
        return None  # (numpy's integers are Integral; numpy's bool is not)
    return int(value)
