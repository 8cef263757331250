"""The one check of a TCP/UDP port number, for the transports and the simulator alike.

It lives at the bottom, beside ``models`` and ``codes``, because both sides of an import
contract need it: ``galil.transport`` (connecting to a controller) and ``galil.sim`` (serving
one), and the simulator may not import the transports (``pyproject.toml``; decision 0005).
"""

from __future__ import annotations

from galil.errors import InvalidArgument

__all__ = ["check_port"]


def check_port(port: object, what: str, *, zero: bool = False) -> int:
    """``port`` as a TCP/UDP port number, 1..65535 (0 too with ``zero``: "pick a free one").

    Only an ``int`` is taken, not text (nor ``True``): ports from URLs and options arrive
    converted already.

    Raises:
        InvalidArgument: naming ``what``, the range and the value given.
    """
    low = 0 if zero else 1
    if isinstance(port, bool) or not isinstance(port, int) or not low <= port <= 65535:
        raise InvalidArgument(f"{what} must be {low}..65535, got {port!r}")
    return port
