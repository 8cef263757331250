"""Simulated seconds per wall-clock second: a 4-axis DMC-4040 at 1024 Hz, every axis moving.

Run: ``python benchmarks/sim.py [simulated_seconds] [repeats]``. Prints the median figure of
each load over several runs and its ratio to the target (100x real time). Three loads: long
jogs (no events), back-to-back position moves held by ``AM`` trippoints (events every move),
and jogs polled by a host (``TP``) every 10 ms of simulated time (many small chunks, like a
server).
"""

from __future__ import annotations

import statistics
import sys
import time

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

TARGET = 100.0


def jog(seconds: float) -> float:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(b"JG 10000,-20000,30000,-40000;BG\r")
    t0 = time.perf_counter()
    sim.advance(seconds)
    return seconds / (time.perf_counter() - t0)


def moves(seconds: float) -> float:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(b"SP 50000,60000,70000,80000;AC 512000,512000,512000,512000\r")
    t0 = time.perf_counter()
    start = sim.time
    sign = 1
    while sim.time - start < seconds:
        sim.feed(f"PR {sign * 20000},{sign * 25000},{sign * 30000},{sign * 35000};BG;AM\r".encode())
        sim.advance_until_output(10.0)
        sign = -sign
    return (sim.time - start) / (time.perf_counter() - t0)


def polled(seconds: float, period: float = 0.01) -> float:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(b"JG 10000,-20000,30000,-40000;BG\r")
    t0 = time.perf_counter()
    for _ in range(round(seconds / period)):
        sim.advance(period)
        sim.feed(b"TP\r")
    return seconds / (time.perf_counter() - t0)


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    print(
        f"DMC-4040, 4 axes at 1024 Hz, {seconds:g} simulated seconds per load, "
        f"median of {repeats} runs; target {TARGET:g} x real time"
    )
    for name, fn, span in (
        ("jog, no events", jog, seconds),
        ("moves + AM trippoints", moves, seconds),
        ("jog, host polls every 10 ms", polled, seconds / 2),
    ):
        speed = statistics.median(fn(span) for _ in range(repeats))
        print(f"  {name:30s} {speed:10.0f} x real time   ({speed / TARGET:6.2f} x target)")


if __name__ == "__main__":
    main()
