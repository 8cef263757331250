"""Array upload (``QU``) and program download (``DL``) against the link's byte rate.

A simulated DMC-4040 on its real-time clock is served by a child process, over TCP and over a
pseudo-terminal paced at 115200 baud (``SimPtyServer(baud=...)``: 11,520 bytes a second each
way). The host, through the public API:

- ``arrays.upload(name)``: ``LA`` (the array's size), then ``QU`` (the values, comma separated);
- ``programs.download(text)``: ``UL`` (the library's routines are kept), the running threads,
  then ``DL`` with the program; the program in memory before is a short one (reading a long
  one back first costs what its size costs: see ``docs/performance.md``).

The figure is the bytes the link carried in the transfer's direction (received for ``QU``,
sent for ``DL``, every command of the operation included) per second, as a share of the
link's byte rate (``link.byte_rate``: 11,520 B/s on the pty, the 64,000 B/s assumed for
Ethernet). Target: >= 80 %. Scaling: 10x the elements or lines.

Run: ``.venv/bin/python benchmarks/transfer.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Callable
from multiprocessing.connection import Connection

import numpy as np
from harness import Figure, Scaling, finish, options

import galil

MODEL = "DMC-4040"
BAUD = 115_200


def serve(kind: str, pipe: Connection) -> None:
    """Child process: serve a simulator over ``kind`` ("tcp" or "pty") until told to stop."""
    from galil.sim.server import SimPtyServer, SimTcpServer

    if kind == "tcp":
        with SimTcpServer(model=MODEL, message_port=None) as tcp:
            pipe.send(tcp.url)
            pipe.recv()
    else:
        with SimPtyServer(model=MODEL, baud=BAUD) as pty:
            pipe.send(pty.path)
            pipe.recv()


def program(lines: int) -> str:
    """A program of ``lines`` lines, about 40 characters each."""
    body = [f"v{i % 500}=v{i % 500}+{i}*2;MG v{i % 500}" for i in range(lines - 2)]
    return "\n".join(["#BENCH", *body, "EN"])


def measure(c: galil.Controller, op: Callable[[], object], received: bool) -> tuple[float, float]:
    """Run ``op``; return (bytes carried in its direction, seconds)."""
    link = c.link
    before = link.bytes_received if received else link.bytes_sent
    t0 = time.perf_counter()
    op()
    spent = time.perf_counter() - t0
    after = link.bytes_received if received else link.bytes_sent
    return float(after - before), spent


Rows = dict[str, list[tuple[int, float, float]]]


def transfers(address: str, sizes: dict[str, tuple[int, ...]]) -> Rows:
    """Upload arrays and download programs of each size; (size, bytes, seconds) per kind."""
    out: Rows = {"QU": [], "DL": []}
    with galil.connect(address, timeout=30.0) as c:
        for n in sizes["QU"]:
            c.arrays.define("bench", n, replace=True)
            c.arrays.download("bench", np.arange(n, dtype=np.float64) * 1.25 - 1000)
            got, spent = measure(c, lambda: c.arrays.upload("bench"), received=True)
            out["QU"].append((n, got, spent))
        for n in sizes["DL"]:
            # A download reads the program in memory first (UL: the library's routines are
            # kept): start from a small one, so that the figure is the download's own.
            c.programs.download("#T\nEN")
            text = program(n)
            got, spent = measure(c, lambda t=text: c.programs.download(t), received=False)
            out["DL"].append((n, got, spent))
        rate = c.link.byte_rate
    assert rate is not None
    for rows in out.values():
        rows.append((0, rate, 0.0))  # the link's byte rate, carried along
    return out


def run_over(kind: str, sizes: dict[str, tuple[int, ...]]) -> Rows:
    ctx = mp.get_context("spawn")
    mine, theirs = ctx.Pipe()
    child = ctx.Process(target=serve, args=(kind, theirs), daemon=True)
    child.start()
    try:
        return transfers(mine.recv(), sizes)
    finally:
        mine.send("stop")
        child.join(10)


def figures_of(kind: str, results: Rows) -> list[Figure]:
    out = []
    for op, label, unit in (
        ("QU", "array upload (QU)", "elements"),
        ("DL", "program download (DL)", "lines"),
    ):
        rows = results[op]
        rate = rows[-1][1]
        rows = rows[:-1]
        n, carried, spent = rows[-1]
        share = carried / spent / rate
        print(
            f"  {kind} {label}: {n} {unit}, {carried:.0f} bytes in {spent * 1e3:.1f} ms ="
            f" {carried / spent:,.0f} B/s, {share * 100:.1f} % of {rate:,.0f} B/s"
        )
        out.append(
            Figure(
                f"{label} over {kind} ({n} {unit})",
                share * 100,
                "% of link rate",
                80,
                anchor="the link's byte rate",
                anchor_value=rate,
                ratio=carried / spent,
                ratio_text=" bytes/s",
                scaling=[Scaling(unit, [(float(m), t) for m, _, t in rows])],
            )
        )
    return out


def main() -> None:
    args = options(__doc__)
    tcp_sizes = {"QU": (240, 2400, 24000), "DL": (20, 200, 2000)}
    if args.quick:
        pty_sizes = {"QU": (100, 1000), "DL": (10, 100)}
    else:
        pty_sizes = {"QU": (200, 2000), "DL": (10, 100, 1000)}
    figures = []
    for kind, sizes in (("tcp", tcp_sizes), ("pty", pty_sizes)):
        print(f"over {kind}" + (f" at {BAUD} baud:" if kind == "pty" else ":"))
        figures += figures_of(kind, run_over(kind, sizes))
    finish(figures, args)


if __name__ == "__main__":
    main()
