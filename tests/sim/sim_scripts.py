"""Scripted simulator runs, played with their time in one advance or one servo sample at a
time: a stop or an event found only at a step boundary lands later in the one advance, so the
two must give the same bytes (the hooks' and horizons' tests)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from galil.sim.controller import SimController

#: Seconds per servo sample at the default TM 1000.
TS = 1 / 1024

#: Command lines to feed, servo samples to let pass, or a test hook to call (switches).
Script = Sequence[str | int | Callable[[SimController], None]]


def play(script: Script, per_sample: bool, lag: float = 0.003) -> bytes:
    """Run ``script`` on a fresh DMC-4040 (servo lag ``lag``); every byte the main port sent."""
    sim = SimController("DMC-4040", servo_lag=lag)
    out = b""
    for step in script:
        if isinstance(step, str):
            out += sim.feed(step.encode() + b"\r")
        elif callable(step):
            step(sim)
        else:
            for n in [1] * step if per_sample else [step]:
                sim.advance(n * TS)
        out += sim.poll()
    return out
