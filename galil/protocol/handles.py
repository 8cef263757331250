"""The ``TH`` reply: which Ethernet handles a controller has open, and to whom.

A controller answers ``TH`` with its own address, then one line per handle::

    CONTROLLER IP ADDRESS 10,0,51,82 ETHERNET ADDRESS 00-50-4C-20-01-0F
    IHA TCP PORT 23 TO IP ADDRESS 10,0,51,81 PORT 3297
    IHB UDP PORT 23 TO IP ADDRESS 10,0,51,81 PORT 3298
    IHC AVAILABLE

This is the form of the DMC-4103 command reference's TH example ("IHA TCP PORT 1050 TO IP
ADDRESS 10,51,0,89 PORT 1000", "IHG AVAILABLE"; docs/decisions/0025), and the simulator's.
That the first port is the controller's and the last the peer's is read from the example,
not stated there. A line in any other form (a handle being opened, another firmware's
wording) is left out: a caller that looks for a handle it knows then does not find it, and
leaves it alone. The reference's remark: with no handle AVAILABLE the controller accepts no
more TCP or UDP connections.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["OpenHandle", "parse_th"]

_LINE = re.compile(
    r"IH([A-H])\s+(TCP|UDP)\s+PORT\s+(\d+)\s+TO\s+IP\s+ADDRESS\s+"
    r"(\d{1,3}),(\d{1,3}),(\d{1,3}),(\d{1,3})\s+PORT\s+(\d+)",
    re.IGNORECASE,
)


@dataclass(frozen=True)
class OpenHandle:
    """One handle in use, as ``TH`` lists it.

    Attributes:
        letter: the handle, ``"A"``-``"H"``.
        kind: ``"TCP"`` or ``"UDP"``.
        port: the controller's port it came in on.
        peer: the other end's address and port (the host's), e.g. ``("10.0.51.81", 3298)``.
    """

    letter: str
    kind: str
    port: int
    peer: tuple[str, int]


def parse_th(text: str) -> dict[str, OpenHandle]:
    """The handles in use in a ``TH`` reply, by letter (free handles are left out)."""
    out: dict[str, OpenHandle] = {}
    for line in text.splitlines():
        m = _LINE.fullmatch(line.strip())
        if m is None:
            continue
        letter, kind, port = m.group(1).upper(), m.group(2).upper(), int(m.group(3))
        ip = ".".join(str(int(m.group(i))) for i in range(4, 8))
        out[letter] = OpenHandle(letter, kind, port, (ip, int(m.group(8))))
    return out
