"""Fault injection for the simulator's fronts: what a real link does to a reply.

A :class:`FaultPlan` turns each chunk of output into pieces with delays; the link and the
servers apply it to everything they deliver. Any callable with the same shape
(``bytes -> list[tuple[float, bytes]]``) can be used instead, for a scripted fault.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from galil.errors import InvalidArgument

__all__ = ["FaultHook", "FaultPlan", "apply_faults", "check_probability"]

#: ``data -> [(delay_seconds, piece), ...]``: the pieces are delivered in order.
FaultHook = Callable[[bytes], list[tuple[float, bytes]]]


def check_probability(name: str, p: float) -> None:
    """Refuse a probability outside [0, 1] (NaN included) with ``InvalidArgument``."""
    if not 0.0 <= p <= 1.0:
        raise InvalidArgument(f"{name} is a probability in [0, 1], not {p!r}")


@dataclass
class FaultPlan:
    """Random faults applied to every chunk a front delivers.

    Attributes:
        split: cut each chunk into pieces at random byte boundaries.
        delay: seconds each piece waits before it can be read.
        drop: probability that a piece is lost.
        corrupt: probability that one byte of a piece is changed.
        interleave: probability that an unsolicited message is slipped in between two pieces.
        message: the text of an interleaved message; it is sent with the high bit set, as
            under ``CW1``.
        seed: seed of the random generator, for reproducible runs.
    """

    split: bool = False
    delay: float = 0.0
    drop: float = 0.0
    corrupt: float = 0.0
    interleave: float = 0.0
    message: str = "FAULT"
    seed: int | None = None
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "interleave"):
            check_probability(name, getattr(self, name))
        if not self.delay >= 0.0:
            raise InvalidArgument(f"delay must be >= 0 seconds, not {self.delay!r}")
        self._rng = random.Random(self.seed)

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        """Return the pieces ``data`` is delivered as, each with its delay."""
        if not data:
            return []
        rng = self._rng
        pieces: list[bytes] = []
        if self.split and len(data) > 1:
            cuts = sorted(rng.sample(range(1, len(data)), rng.randint(1, min(4, len(data) - 1))))
            edges = [0, *cuts, len(data)]
            pieces = [data[a:b] for a, b in itertools.pairwise(edges)]
        else:
            pieces = [data]
        out: list[tuple[float, bytes]] = []
        marked = bytes(b | 0x80 for b in (self.message + "\r\n").encode("latin-1"))
        for piece in pieces:
            if self.interleave and rng.random() < self.interleave:
                out.append((self.delay, marked))
            if self.drop and rng.random() < self.drop:
                continue
            if self.corrupt and rng.random() < self.corrupt:
                i = rng.randrange(len(piece))
                mutable = bytearray(piece)
                mutable[i] ^= 1 << rng.randrange(7)
                piece = bytes(mutable)
            out.append((self.delay, piece))
        return out


def apply_faults(hook: FaultHook | None, data: bytes) -> list[tuple[float, bytes]]:
    """Run ``data`` through ``hook`` (no faults when ``None``)."""
    if not data:
        return []
    if hook is None:
        return [(0.0, data)]
    return list(hook(data))
