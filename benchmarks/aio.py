"""Many controllers from one event loop: poll latency, CPU per controller, loop blocking.

Simulated DMC-4080s (8 axes each) are served over TCP on 127.0.0.1 by child processes (so
their servo loops do not count as the client's CPU). One asyncio loop connects to N of them
with ``galil.aio`` and polls every controller at 10 Hz (``_TP`` and ``_SC`` of its 8 axes in
one round trip), while axis A of every controller moves back and forth. The script prints,
for each N:

Each N runs twice: polls alone, then polls while axes move. It prints:

- poll latency percentiles (from the poll's start to its reply, milliseconds);
- how late polls started against their 10 Hz schedule (the loop's responsiveness);
- CPU of the client process per controller (percent of one core), from getrusage;
- loop blocking: wall and CPU time of every loop callback (``galil.aio.watch_loop``).

The simulators share the machine's cores with the client: latencies include their 2 ms
servo tick and their scheduling. Run: ``.venv/bin/python benchmarks/aio.py [seconds] [N ...]``
(default: 5 s for N = 4 8 16 32).
"""

from __future__ import annotations

import asyncio
import multiprocessing as mp
import os
import resource
import statistics
import sys
import time
from multiprocessing.connection import Connection

import galil.aio as aio

MODEL = "DMC-4080"
RATE = 10.0  # polls per second per controller
SIM_PROCESSES = 2


def serve(count: int, pipe: Connection) -> None:
    """Child process: serve ``count`` simulators and send their URLs; stop when told."""
    from galil.sim.server import SimTcpServer

    servers = [SimTcpServer(model=MODEL, message_port=None) for _ in range(count)]
    for srv in servers:
        srv.start()
    pipe.send([srv.url for srv in servers])
    pipe.recv()  # anything: stop
    for srv in servers:
        srv.stop()


def start_simulators(total: int) -> tuple[list[str], list[tuple[mp.Process, Connection]]]:
    ctx = mp.get_context("spawn")
    children = []
    urls: list[str] = []
    per = -(-total // SIM_PROCESSES)
    for i in range(SIM_PROCESSES):
        count = min(per, total - i * per)
        if count <= 0:
            break
        ours, theirs = ctx.Pipe()
        proc = ctx.Process(target=serve, args=(count, theirs), daemon=True)
        proc.start()
        children.append((proc, ours))
    for _, pipe in children:
        urls.extend(pipe.recv())
    return urls, children


async def poll(
    c: aio.AsyncController, stop_at: float, latencies: list[float], late: list[float]
) -> None:
    names = [f"_{op}{a}" for a in c.model.axes for op in ("TP", "SC")]
    loop = asyncio.get_running_loop()
    due = loop.time()
    while due < stop_at:
        now = loop.time()
        if due > now:
            await asyncio.sleep(due - now)
        started = loop.time()
        late.append(started - due)
        await c.query_operands(names)
        latencies.append(loop.time() - started)
        due += 1.0 / RATE


async def shuttle(c: aio.AsyncController, stop_at: float) -> int:
    axis = c.A
    await axis.set_speed(50_000)
    loop = asyncio.get_running_loop()
    moves = 0
    while loop.time() < stop_at:
        move = await axis.move_to(20_000 if moves % 2 == 0 else 0)
        await move
        moves += 1
    return moves


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1)))]


def cpu_of(pids: list[int]) -> float:
    """CPU seconds (user + system) the processes used so far (Linux /proc)."""
    total = 0.0
    tick = os.sysconf("SC_CLK_TCK")
    for pid in pids:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


async def run(urls: list[str], seconds: float, moves: bool, sims: list[int]) -> None:
    controllers = await asyncio.gather(*(aio.connect(u, threads=2) for u in urls))
    latencies: list[float] = []
    late: list[float] = []
    try:
        loop = asyncio.get_running_loop()
        stop_at = loop.time() + seconds
        before = resource.getrusage(resource.RUSAGE_SELF)
        sim_before = cpu_of(sims)
        wall0 = time.perf_counter()
        with aio.watch_loop() as watch:
            results = await asyncio.gather(
                *(poll(c, stop_at, latencies, late) for c in controllers),
                *(shuttle(c, stop_at) for c in controllers if moves),
            )
        wall = time.perf_counter() - wall0
        after = resource.getrusage(resource.RUSAGE_SELF)
        sim_cpu = cpu_of(sims) - sim_before
    finally:
        await asyncio.gather(*(c.aclose() for c in controllers))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    moved = sum(r for r in results if isinstance(r, int))
    n = len(controllers)
    ms = 1e3
    what = f"{moved} moves" if moves else "no motion"
    print(f"{n:3d} controllers ({n * 8} axes), {what}: {len(latencies)} polls in {wall:.1f} s")
    print(
        f"    poll latency ms: p50 {pct(latencies, 50) * ms:.2f}  p90 {pct(latencies, 90) * ms:.2f}"
        f"  p99 {pct(latencies, 99) * ms:.2f}  max {max(latencies) * ms:.2f}"
    )
    print(
        f"    poll start late ms: p50 {pct(late, 50) * ms:.2f}  p99 {pct(late, 99) * ms:.2f}"
        f"  max {max(late) * ms:.2f}"
    )
    print(
        f"    client CPU: {cpu / wall * 100:.1f} % of a core in all, "
        f"{cpu / wall / n * 100:.2f} % per controller (simulators: {sim_cpu / wall * 100:.0f} %)"
    )
    print(
        f"    loop blocking: {watch.summary()}; callbacks over 1 ms: wall {watch.over(1e-3)}, "
        f"CPU {watch.over(1e-3, cpu=True)} (GC included)"
    )
    print(f"    mean poll {statistics.fmean(latencies) * ms:.2f} ms")


def main(argv: list[str]) -> None:
    seconds = float(argv[0]) if argv else 5.0
    counts = [int(a) for a in argv[1:]] or [4, 8, 16, 32]
    urls, children = start_simulators(max(counts))
    try:
        print(f"galil.aio: {MODEL} simulators over TCP, polled at {RATE:g} Hz, {seconds:g} s each")
        sims = [proc.pid for proc, _ in children if proc.pid is not None]
        for n in counts:
            for moves in (False, True):
                asyncio.run(run(urls[:n], seconds, moves, sims))
    finally:
        for proc, pipe in children:
            pipe.send("stop")
            proc.join(10)


if __name__ == "__main__":
    main(sys.argv[1:])
