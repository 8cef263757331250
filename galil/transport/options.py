"""Checks for transport options, one per kind of value, shared by every opener.

Options arrive as keywords or from a URL query (already turned into ``int``/``float``/``bool``
by :func:`galil.transport.parse_options` where they look like one; otherwise text). Each check
returns the value in its working type or raises :class:`InvalidArgument` naming the option,
so that a bad value is refused before any device is searched for, opened or written to.
Port numbers are checked by :func:`galil.portnumber.check_port`, which the simulator shares.
"""

from __future__ import annotations

import ipaddress
import math
import re
from collections.abc import Collection

from galil.errors import InvalidArgument

__all__ = ["LONGEST_WAIT", "choice", "dotted_quad", "flag", "seconds", "whole_number"]

_DOTTED = re.compile(r"^[0-9.]+$")

#: The longest a transport waits in one call to the OS (seconds, about 11.6 days): what
#: every platform's socket timeout, ``poll`` (milliseconds in a C int: 24.8 days) and USB
#: read (milliseconds in an unsigned int) take. A transport option in seconds is at most this.
LONGEST_WAIT = 1e6


def seconds(value: object, what: str) -> float:
    """``value`` as a positive, finite number of seconds, at most :data:`LONGEST_WAIT`
    (numeric text is accepted)."""
    if not isinstance(value, bool):
        try:
            number = float(value) if isinstance(value, (int, float, str)) else math.nan
        except (ValueError, OverflowError):  # not a number; an int no float holds (10**400)
            number = math.nan
        if math.isfinite(number) and 0 < number <= LONGEST_WAIT:
            return number
    raise InvalidArgument(
        f"{what} must be a positive number of seconds, at most {LONGEST_WAIT:g}, got {value!r}"
    )


def whole_number(value: object, what: str, low: int, high: int) -> int:
    """``value`` as an ``int`` in ``low..high`` (decimal text is accepted)."""
    number: int | None = None
    if isinstance(value, int) and not isinstance(value, bool):
        number = value
    elif isinstance(value, str) and value.strip().isdigit():
        number = int(value)
    if number is None or not low <= number <= high:
        raise InvalidArgument(f"{what} must be a whole number {low}..{high}, got {value!r}")
    return number


def dotted_quad(host: str, what: str) -> None:
    """Refuse a host made only of digits and dots that is no IPv4 address (``999.1.1.1``).

    Such a name is no DNS name either; passed on, it would become a DNS query.
    """
    if _DOTTED.match(host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError as exc:
            raise InvalidArgument(f"{what}: {host!r} is not an IPv4 address") from exc


def flag(value: object, what: str) -> bool:
    """``value`` as a ``bool``: ``True``/``False``, or 1/0 (as a URL query gives them)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise InvalidArgument(f"{what} must be true or false, got {value!r}")


def choice(value: object, what: str, allowed: Collection[object]) -> object:
    """``value`` itself if it is one of ``allowed`` (``True`` is not taken for 1)."""
    if isinstance(value, bool) or value not in allowed:
        shown = ", ".join(str(a) for a in allowed)
        raise InvalidArgument(f"{what} must be one of {shown}, got {value!r}")
    return value
