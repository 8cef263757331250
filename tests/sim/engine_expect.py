"""Exact expected values for simulator tests, computed from the shared motion engine.

The simulator runs :class:`galil.predict.engine.AxisProfiler` in its servo loop and adds a
plant: the encoder follows the reference through a first-order lag, and ``TV`` averages the
encoder over a quarter second. These helpers rebuild those numbers sample by sample, the plain
way, so a test can compare the simulator's answer with one exact value.
"""

from __future__ import annotations

import math

from galil.predict.engine import AxisProfiler
from galil.sim.motion import TV_WINDOW_SECONDS

TS = 1 / 1024


def move(distance: int, sp: float = 25000, ac: float = 256000, dc: float = 256000) -> AxisProfiler:
    """A profiler that has just begun ``PR distance;BG`` (the simulator's defaults)."""
    prof = AxisProfiler(sample_period=TS)
    prof.begin_move(distance, sp, ac, dc)
    return prof


def soft_limit_stop(distance: int, fl: int, **kw: float) -> int:
    """Where a move towards ``FL`` stops: the limit stop starts on the first sample beyond."""
    prof = move(distance, **kw)
    while prof.reference <= fl:
        prof.advance(1)
    prof.limit_stop(2)
    while prof.moving:
        prof.advance(1)
    return int(prof.reference)


def references(prof: AxisProfiler) -> list[int]:
    """Every reference of ``prof`` until its profile is complete (consumes it)."""
    out: list[int] = []
    while prof.moving:
        out.extend(int(r) for r in prof.advance(1))
    return out


def lagged(refs: list[int], lag: float, start: float = 0.0) -> list[int]:
    """The encoder after each sample: ``y += alpha * (r - y)``, ``alpha = 1 - exp(-Ts/lag)``."""
    alpha = 1.0 if lag == 0 else -math.expm1(-TS / lag)
    y = start
    out = []
    for r in refs:
        y += alpha * (r - y)
        out.append(round(y))
    return out


def in_position_after(refs: list[int], lag: float) -> int:
    """Samples until ``MC`` holds: the profile is complete and the encoder is on its end."""
    target = refs[-1]
    held = list(refs)
    while lagged(held, lag)[-1] != target:
        held += [target] * 16
    enc = lagged(held, lag)
    return next(k for k in range(len(refs), len(enc) + 1) if enc[k - 1] == target)


def tv(encoders: list[int]) -> int:
    """``TV`` after ``encoders`` (one per sample from rest at 0): a quarter second's span."""
    window = round(TV_WINDOW_SECONDS / TS)
    history = [0] * (window + 1) + encoders
    return round((history[-1] - history[-(window + 1)]) / (window * TS))
