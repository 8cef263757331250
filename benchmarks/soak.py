"""Fault soak: 4 threads x 5000 set-then-read pairs through a TCP proxy of faults (5 %).

Run: ``python benchmarks/soak.py [pairs_per_thread] [fault_probability]`` (``make soak``).
Prints wrong replies, hangs, and commands reported rejected that executed (all must be 0),
then 100 Ctrl-C trials at random points during ``move.wait()`` inside ``motion()``, over TCP
with a few ms of latency: each must end with ``ST`` on the wire.
"""

from __future__ import annotations

import json
import os
import random
import signal
import sys
import threading
import time
from pathlib import Path

import galil
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.proxy import FaultProxy, MixedFaults
from galil.sim.server import SimTcpServer
from galil.soak import soak


def fault_soak(pairs: int, p: float) -> dict[str, float]:
    faults = MixedFaults(p=p, seed=1)
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address, faults=faults) as proxy,
        galil.connect(proxy.url, timeout=0.25) as dmc,
    ):
        report = soak(dmc, pairs=pairs, threads=4)
    print(f"faults injected: {faults.counts}")
    print(report)
    for line in report.examples:
        print("  e.g.", line)
    return {
        "pairs": report.pairs,
        "wrong": report.wrong,
        "hangs": report.hangs,
        "rejected_but_ran": report.rejected_but_ran,
        "uncertain": report.uncertain,
        "seconds": report.seconds,
    }


def ctrl_c_trials(trials: int, latency: float) -> dict[str, float]:
    """Ctrl-C (a real SIGINT) at a random time during ``wait()`` inside ``motion()``."""
    sim = SimController("DMC-4040", RealTimeClock())
    stopped = 0
    rng = random.Random(7)
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address, latency=latency) as proxy,
        galil.connect(proxy.url, timeout=1.0) as dmc,
    ):
        dmc.A.speed, dmc.A.accel, dmc.A.decel = 200_000, 2_000_000, 2_000_000
        for k in range(trials):
            stopped += _one_trial(dmc, rng.uniform(0.0, 0.15), k)
    print(f"Ctrl-C trials: {stopped} of {trials} stopped with ST on the wire")
    return {"trials": trials, "stopped": stopped}


def _one_trial(dmc: galil.Controller, at: float, k: int) -> int:
    # The move lasts over 0.3 s and the interrupt comes within 0.15 s: always mid-move.
    timer = threading.Timer(at, lambda: os.kill(os.getpid(), signal.SIGINT))
    interrupted = False
    with dmc.wire_log.capture() as wire:
        try:
            with dmc.motion("A"):
                move = dmc.A.move_by(60_000 if k % 2 else -60_000)
                timer.start()
                move.wait()
                time.sleep(1.0)  # not reached in practice: the interrupt comes first
        except KeyboardInterrupt:
            interrupted = True
        finally:
            timer.cancel()
    while dmc.A.moving:
        time.sleep(0.01)
    return int(interrupted and b"ST A" in bytes(wire.sent) and dmc.A.stop_code[0] == 4)


def main() -> None:
    pairs = int(sys.argv[1]) if len(sys.argv) > 1 else 5000
    p = float(sys.argv[2]) if len(sys.argv) > 2 else 0.05
    results = {"soak": fault_soak(pairs, p), "ctrl_c": ctrl_c_trials(100, 0.003)}
    ok = (
        results["soak"]["wrong"] == 0
        and results["soak"]["hangs"] == 0
        and results["soak"]["rejected_but_ran"] == 0
        and results["ctrl_c"]["stopped"] == results["ctrl_c"]["trials"]
    )
    print("soak:", "PASS" if ok else "FAIL")
    Path("benchmarks/results").mkdir(exist_ok=True)
    Path("benchmarks/results/soak.json").write_text(json.dumps(results, indent=2))
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
