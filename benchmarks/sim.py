"""Simulated seconds per wall-clock second, and what the rooms' hooks cost.

Loads (every axis moving, 1024 Hz):

- DMC-4080, 8 axes jogging, a host polling ``TP`` every 10 ms of simulated time (many small
  servo steps, like a server): the target load, >= 100x real time;
- DMC-4040, 4 axes: long jogs (no events), back-to-back position moves held by ``AM``
  trippoints (an event every move), and jogs polled every 10 ms.

Each figure is the median over several runs. The 8-axis polled load is also run with every
servo-loop hook of the rooms (``horizon``, ``watches``, ``after_step``, ``service``) timed:
the share of the time they take, room by room. Scaling: a jog of 1 s to 1 h of simulated
time, unpolled.

Run: ``.venv/bin/python benchmarks/sim.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import collections
import statistics
import time
from collections.abc import Callable
from typing import Any

from harness import Figure, Scaling, finish, options

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

TARGET = 100.0
JOG4 = b"JG 10000,-20000,30000,-40000;BG\r"
JOG8 = b"JG 10000,-20000,30000,-40000,10000,-20000,30000,-40000;BG\r"


def jog(seconds: float) -> float:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(JOG4)
    t0 = time.perf_counter()
    sim.advance(seconds)
    return seconds / (time.perf_counter() - t0)


def moves(seconds: float) -> float:
    sim = SimController("DMC-4040", ManualClock())
    sim.feed(b"SP 50000,60000,70000,80000;AC 512000,512000,512000,512000\r")
    sim.feed(b"DL\r#W\rAM\rMG 1\rEN\r\\\r")  # AM waits in a program (decision 0044)
    t0 = time.perf_counter()
    start = sim.time
    sign = 1
    while sim.time - start < seconds:
        pr = f"PR {sign * 20000},{sign * 25000},{sign * 30000},{sign * 35000}"
        sim.feed(f"{pr};BG;XQ #W\r".encode())
        sim.advance_until_output(10.0)
        sign = -sign
    return (sim.time - start) / (time.perf_counter() - t0)


def polled_sim(model: str, line: bytes) -> SimController:
    sim = SimController(model, ManualClock())
    sim.feed(line)
    return sim


def poll(sim: SimController, seconds: float, period: float = 0.01) -> float:
    t0 = time.perf_counter()
    for _ in range(round(seconds / period)):
        sim.advance(period)
        sim.feed(b"TP\r")
    return seconds / (time.perf_counter() - t0)


def polled4(seconds: float) -> float:
    return poll(polled_sim("DMC-4040", JOG4), seconds)


def polled8(seconds: float) -> float:
    return poll(polled_sim("DMC-4080", JOG8), seconds)


def hook_costs(seconds: float) -> tuple[float, dict[str, float]]:
    """The 8-axis polled load with each room's servo-loop hooks timed: (total s, per hook)."""
    sim = polled_sim("DMC-4080", JOG8)
    spent: collections.Counter[str] = collections.Counter()

    def timed(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        clock = time.perf_counter

        def run(*args: Any) -> Any:
            t0 = clock()
            out = fn(*args)
            spent[name] += clock() - t0
            return out

        return run

    machine = sim._m  # the core's hook lists (a benchmark may look inside)
    servo = machine.servo
    for kind, hooks in (
        ("horizon", servo.horizon_hooks),
        ("watches", servo.watch_hooks),
        ("after_step", servo.after_step_hooks),
        ("service", machine._service_hooks),
    ):
        for i, hook in enumerate(hooks):
            owner = type(getattr(hook, "__self__", None)).__name__
            hooks[i] = timed(f"{owner}.{kind}", hook)
    t0 = time.perf_counter()
    poll(sim, seconds)
    return time.perf_counter() - t0, dict(spent)


def main() -> None:
    args = options(__doc__)
    seconds = 5.0 if args.quick else 20.0
    repeats = 3 if args.quick else 5
    print(f"1024 Hz, median of {repeats} runs; target {TARGET:g} x real time")
    loads: list[tuple[str, Callable[[float], float], float]] = [
        ("8 axes (DMC-4080), jog, host polls every 10 ms", polled8, seconds / 2),
        ("4 axes (DMC-4040), jog, no events", jog, seconds),
        ("4 axes (DMC-4040), moves + AM trippoints", moves, seconds),
        ("4 axes (DMC-4040), jog, host polls every 10 ms", polled4, seconds / 2),
    ]
    figures = []
    for name, fn, span in loads:
        speed = statistics.median(fn(span) for _ in range(repeats))
        print(f"  {name:48s} {speed:10.0f} x real time   ({speed / TARGET:6.2f} x target)")
        figures.append(Figure(f"sim {name}", speed, "x real time", TARGET))
    total, spent = hook_costs(seconds / 2)
    share = sum(spent.values()) / total
    top = sorted(spent.items(), key=lambda kv: -kv[1])
    print(f"  rooms' servo-loop hooks, 8 axes polled: {share * 100:.1f} % of the time")
    for hook, t in top[:8]:
        print(f"    {hook:28s} {t / total * 100:5.1f} %")
    figures[0].note = (
        f"rooms' hooks take {share * 100:.0f} % of it (largest: "
        + ", ".join(f"{h} {t / total * 100:.1f} %" for h, t in top[:3])
        + ")"
    )
    points = []
    for span in (1.0, 10.0, 100.0, 1000.0, 3600.0):
        if args.quick and span > 100:
            break
        points.append((span, span / jog(span)))
    figures[1].scaling.append(Scaling("s simulated", points))
    finish(figures, args)


if __name__ == "__main__":
    main()
