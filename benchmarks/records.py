"""Data records: batch decoding into numpy, and a live ``DR`` stream against its targets.

1. Decode: a ``DR`` stream's bytes (DMC-4040 records of 226 bytes, end to end) decoded at once
   (``decode_records``: every header checked), their 16-bit sample counters extended
   (``follow_samples``) and joined as a ``time`` field (``with_times``): a structured numpy
   array owning its data. Target: >= 5 M records/s. Anchor: numpy copying the same bytes into
   an array (the least work that ends with the records in an array of one's own). Scaling from
   1 k to 1 M records.
2. Live: a simulated DMC-4040 served over TCP by a child process (on its real-time clock), the
   host streaming ``DR`` at the model's fastest period (``DR 2``: the 40x0 takes no period
   below 2 samples) for 60 s at TM 1000 (512 records/s) and at TM 250 (2,048 records/s),
   reading every record with ``get()``. Targets: 0 records missed or dropped, and under 5 %
   of one core on the host side (this process's CPU time, all threads, over wall time).

Run: ``.venv/bin/python benchmarks/records.py [--quick] [--json PATH]`` (quick: 10 s streams).
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import resource
import time
from multiprocessing.connection import Connection

import numpy as np
from harness import Figure, Scaling, best, finish, interleaved, options

import galil
from galil.models import get_model
from galil.protocol.records import (
    decode_records,
    follow_samples,
    record_dtype,
    with_times,
)

MODEL = "DMC-4040"
PERIOD = 2  # the 40x0's smallest DR period, in samples


def stream_bytes(n: int) -> bytes:
    """``n`` DMC-4040 records as a DR stream sends them, two samples apart."""
    spec = get_model(MODEL)
    dtype = record_dtype(spec)
    recs = np.zeros(n, dtype=dtype)
    recs["header"] = 0x87
    recs["axes_present"] = 0x0F
    recs["size"] = dtype.itemsize
    recs["sample"] = (np.arange(n, dtype=np.int64) * PERIOD) % 65536
    recs["A"]["position"] = np.arange(n, dtype=np.int64) % 1_000_000
    return recs.tobytes()


def decode(data: bytes) -> np.ndarray:
    spec = get_model(MODEL)
    records = decode_records(data, spec)
    times = follow_samples(records["sample"], 0, PERIOD)
    return with_times(records, times)


def decoding(quick: bool) -> Figure:
    n = 1_000_000
    data = stream_bytes(n)
    out = decode(data)
    assert out.size == n
    assert np.all(np.diff(out["time"]) == PERIOD)
    pairs = 3 if quick else 7

    def ours() -> float:
        return best(lambda: decode(data), repeat=1)

    def anchor() -> float:
        return best(lambda: np.frombuffer(data, np.uint8).copy(), repeat=1)

    t_anchor, t_ours, ratio = interleaved(anchor, ours, pairs)
    rate = n / t_ours
    print(
        f"  decode + times, 1 M records: {t_ours * 1e3:.1f} ms = {rate / 1e6:.2f} M records/s;"
        f" numpy's copy of the bytes {t_anchor * 1e3:.1f} ms"
    )
    points = []
    for m in (1_000, 10_000, 100_000, 1_000_000):
        chunk = data[: m * (len(data) // n)]
        points.append((float(m), best(lambda c=chunk: decode(c), repeat=3 if m < n else 1)))
    return Figure(
        "records decode + time (DMC-4040)",
        rate / 1e6,
        "M records/s",
        5,
        anchor="numpy copy of the bytes",
        anchor_value=n / t_anchor / 1e6,
        ratio=ratio,
        ratio_text="x the copy's time",
        scaling=[Scaling("records", points)],
    )


def serve(pipe: Connection) -> None:
    """Child process: a simulator on its real-time clock, over TCP, until told to stop."""
    from galil.sim.server import SimTcpServer

    with SimTcpServer(model=MODEL, message_port=None) as srv:
        pipe.send(srv.url)
        pipe.recv()


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def live(url: str, tm: int, seconds: float) -> dict[str, float]:
    """Stream DR for ``seconds`` at TM ``tm``; every record read with get()."""
    with galil.connect(url, timeout=2.0) as c:
        c.command(f"TM {tm}")
        rate = 1 / (c.link.sample_period * PERIOD)
        with c.records(PERIOD, method="DR", maxlen=100_000) as stream:
            got = 0
            first = last = None
            c0, t0 = cpu(), time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                try:
                    rec = stream.get(timeout=1.0)
                except queue.Empty:
                    continue
                got += 1
                last = int(rec["time"])
                if first is None:
                    first = last
            wall = time.perf_counter() - t0
            spent = cpu() - c0
            missed, dropped = stream.missed, stream.dropped
        c.command("TM 1000")
    span = 0 if first is None or last is None else (last - first) // PERIOD + 1
    return {
        "rate": rate,
        "records": got,
        "span": span,
        "missed": missed,
        "dropped": dropped,
        "cpu": spent / wall,
        "cpu_per_record_us": spent / max(got, 1) * 1e6,
    }


def streaming(quick: bool) -> list[Figure]:
    seconds = 10.0 if quick else 60.0
    ctx = mp.get_context("spawn")
    mine, theirs = ctx.Pipe()
    child = ctx.Process(target=serve, args=(theirs,), daemon=True)
    child.start()
    try:
        url = mine.recv()
        runs = {tm: live(url, tm, seconds) for tm in (1000, 250)}
    finally:
        mine.send("stop")
        child.join(10)
    figures = []
    points = []
    for tm, r in runs.items():
        lost = r["missed"] + r["dropped"] + (r["span"] - r["records"])
        print(
            f"  TM {tm}: {r['records']:.0f} records in {seconds:g} s ({r['rate']:.0f}/s),"
            f" missed {r['missed']:.0f}, dropped {r['dropped']:.0f},"
            f" host CPU {r['cpu'] * 100:.2f} % of a core"
            f" ({r['cpu_per_record_us']:.1f} us a record)"
        )
        points.append((r["rate"], r["cpu"]))
        name = f"DR {PERIOD} stream, TM {tm} ({r['rate']:.0f} records/s, {seconds:g} s)"
        figures.append(Figure(f"{name}: host CPU", r["cpu"] * 100, "% of a core", 5, higher=False))
        figures.append(
            Figure(
                f"{name}: records lost",
                lost,
                "records",
                0,
                higher=False,
                note=f"{r['records']:.0f} read of {r['span']:.0f} sent; missed (gaps in time)"
                f" {r['missed']:.0f}, dropped (queue full) {r['dropped']:.0f}",
            )
        )
    figures[0].scaling.append(Scaling("CPU a second at records/s", points))
    return figures


def main() -> None:
    args = options(__doc__)
    print("batch decoding (DMC-4040 records, 226 bytes each):")
    figures = [decoding(args.quick)]
    print(f"live DR streams from a simulated {MODEL} over TCP (a child process):")
    figures += streaming(args.quick)
    finish(figures, args)


if __name__ == "__main__":
    main()
