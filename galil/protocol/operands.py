"""Operands (``_TPA``, ``_BGA``, ``_TC`` ...) and the replies of axis queries, decoded.

``decode_operand("_TPA", " 1000.0000")`` gives ``1000``; ``decode_operand("_BGA", "1.0000")``
gives ``True``. ``parse_axes_reply(" 5, -9", "AB")`` gives ``{"A": 5.0, "B": -9.0}``.
"""

from __future__ import annotations

import re
from typing import Literal, overload

from galil.errors import InvalidArgument, ProtocolError
from galil.protocol.numbers import parse_number, parse_numbers

__all__ = ["OPERANDS", "decode_operand", "parse_axes_reply"]

#: Operand stem -> (value kind, description). ``count``: integer counts; ``rate``: a number
#: (speeds and accelerations may carry a fraction); ``flag``: 0/1; ``code``: small integer.
OPERANDS: dict[str, tuple[str, str]] = {
    "TP": ("count", "motor position"),
    "TV": ("rate", "filtered velocity, counts/s"),
    "TE": ("count", "position error"),
    "RP": ("count", "reference position"),
    "TD": ("count", "auxiliary encoder / step count"),
    "PA": ("count", "last commanded absolute target"),
    "PR": ("count", "last relative distance"),
    "SP": ("rate", "slew speed, counts/s"),
    "AC": ("rate", "acceleration, counts/s²"),
    "DC": ("rate", "deceleration, counts/s²"),
    "JG": ("rate", "jog speed, counts/s"),
    "IT": ("rate", "smoothing time constant"),
    "BG": ("flag", "motion in progress"),
    "MO": ("flag", "motor off"),
    "LF": ("flag", "forward limit switch state"),
    "LR": ("flag", "reverse limit switch state"),
    "LD": ("code", "limit disable: 1 forward switch off, 2 reverse, 3 both"),
    "SC": ("code", "stop code"),
    "TS": ("code", "switch status byte"),
    "TC": ("code", "last error code"),
    "CM": ("code", "contour buffer space"),
    "DT": ("code", "contour segment time exponent"),
    "NO": ("code", "running threads bitmask"),
    "XQ": ("code", "thread program line, -1 when stopped"),
    "FL": ("count", "forward software limit"),
    "BL": ("count", "reverse software limit"),
    "TM": ("rate", "sample period, µs"),
}

# _TC, _CM, _NO, _TM take no axis; the others take one axis letter (or thread digit for _XQ).
_NAME = re.compile(r"_(?P<stem>[A-Z]{2})(?P<axis>[A-HXYZWST0-7]?)")
_GLOBAL = frozenset({"TC", "CM", "NO", "TM", "DT"})


def decode_operand(name: str, text: str) -> int | float | bool:
    """Decode the reply to ``MG <name>`` (or one field of it) into a typed value.

    Counts and codes come back as ``int``, flags as ``bool``, rates as ``float``; unknown
    operands (``_BN``, variables) as ``float``.

    Raises:
        InvalidArgument: ``name`` is not an operand name.
        ProtocolError: ``text`` is not a number, or a count/flag is not a whole number.
    """
    m = _NAME.fullmatch(name) if isinstance(name, str) else None
    if m is None:
        if isinstance(name, str) and re.fullmatch(r"[A-Za-z][A-Za-z0-9]{0,7}", name):
            return parse_number(text)  # a user variable
        raise InvalidArgument(f"not an operand name: {name!r}")
    stem, axis = m.group("stem"), m.group("axis")
    if stem in _GLOBAL and axis:
        raise InvalidArgument(f"{name}: _{stem} takes no axis")
    value = parse_number(text)
    kind = OPERANDS.get(stem, ("rate", ""))[0]
    if kind == "rate":
        return value
    if not value.is_integer():
        raise ProtocolError(f"{name} should be a whole number, got {text!r}")
    if kind == "flag":
        if value not in (0.0, 1.0):
            raise ProtocolError(f"{name} should be 0 or 1, got {text!r}")
        return value == 1.0
    return int(value)


@overload
def parse_axes_reply(
    text: str, axes: str, *, counts: Literal[False] = False
) -> dict[str, float]: ...
@overload
def parse_axes_reply(text: str, axes: str, *, counts: Literal[True]) -> dict[str, int]: ...
def parse_axes_reply(
    text: str, axes: str, *, counts: bool = False
) -> dict[str, int] | dict[str, float]:
    """Decode the reply to ``TP``, ``TPAB``, ``TV A``, ``MG _TPA`` for the axes asked.

    ``axes`` are the letters in the order the controller answers (for a bare ``TP``, all of
    the model's axes). Values may be comma or comma+space separated, with or without leading
    zeros. With ``counts`` the values must be whole numbers and come back as ``int``.

    Raises:
        ProtocolError: a value is not a number, or their count does not match ``axes``.
    """
    values = parse_numbers(text) if "," in text else [parse_number(text)] if text.strip() else []
    if len(values) != len(axes):
        raise ProtocolError(f"{len(values)} values in {text!r} for axes {axes!r}")
    if not counts:
        return dict(zip(axes, values, strict=True))
    out: dict[str, int] = {}
    for letter, v in zip(axes, values, strict=True):
        if not v.is_integer():
            raise ProtocolError(f"axis {letter}: {v} is not a whole number of counts")
        out[letter] = int(v)
    return out
