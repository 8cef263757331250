"""Contour streaming: the host's preparation, and streams against the link's byte capacity.

1. Preparation (no I/O worth counting: a transport that answers at once): a contour of 1 k,
   100 k and 1 M DT 1 segments on 3 axes through ``ContourStream``: increments, the checks
   (ranges, the motion the path implies, the link), the prediction and soft limits, and the
   ``CD`` commands (``cmds.cd_rows``). Reported with its scaling; no target of its own.
2. Over a pseudo-terminal paced at 115200 baud (11,520 bytes a second; a simulated DMC-4040 on
   its real-time clock, in a child process): a DT 1 path on 3 axes whose segments need 90 %
   of the line (512 segments a second of about 20 bytes). The library's own check would
   refuse it (it plans on 80 % of the link), so the benchmark prepares and feeds it without
   that check. It is streamed as the library streams it: pre-loaded under ``DT -1`` (the
   buffer filled before the path starts), then kept full. Figures: the bytes a second of the
   pre-load (a whole buffer sent as fast as the line and the controller take it, from its
   first line's start to its last line's reply: on a serial line a refill goes out in lines
   of at most 0.25 s each, decision 0100) as a share of the line (target >= 90 %; once the
   buffer is full the stream can only send what the path uses, its need), and the fewest
   segments queued at any look after the start (target >= 1: the buffer never empty; the
   margin a stall of the host can use). Without the
   pre-load (``preload=False``) the same path started from an empty buffer with 0.2 ms of
   slack a segment, and a jitter of the pty in its first segments ran it dry (TC 42 after
   510 segments in two of three runs on a quiet machine): decision 0038.
3. Over TCP (64,000 B/s assumed for Ethernet): no DT 1 path of a 4-axis model needs more
   than about a quarter of that, so the figure is the capacity: the bytes a second of the
   first refill (a whole buffer, sent as fast as the link and the controller take it), as a
   share of the assumed rate (target >= 90 %); and a 4-axis path streamed with the buffer
   never empty.

Run: ``.venv/bin/python benchmarks/contour_stream.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from harness import Figure, Scaling, best, finish, options
from host import InstantTransport

import galil
from galil.contour import ContourStream
from galil.protocol.commands import Command

MODEL = "DMC-4040"
BAUD = 115_200


class Watched:
    """A command link that records what a contour stream asks and sends (for the figures)."""

    def __init__(self, link: Any) -> None:
        self._link = link
        self.free: list[int] = []  # _CM at each look
        self.batches: list[tuple[int, int, float, float]] = []  # (segments, bytes, t0, t1)
        self.marks: list[int] = []  # len(batches) at each look at _CM

    def __getattr__(self, name: str) -> Any:
        return getattr(self._link, name)

    def query_operands(self, names: Sequence[str], **kw: Any) -> list[float]:
        values: list[float] = self._link.query_operands(names, **kw)
        if names and names[0] == "_CM":
            self.free.append(round(values[0]))
            self.marks.append(len(self.batches))
        return values

    def command_line(self, parts: Sequence[str | Command], **kw: Any) -> list[str]:
        before = self._link.bytes_sent
        t0 = time.perf_counter()
        replies: list[str] = self._link.command_line(parts, **kw)
        self.batches.append((len(parts), self._link.bytes_sent - before, t0, time.perf_counter()))
        return replies

    def first_refill(self) -> tuple[int, int, float] | None:
        """The first refill (the lines between the first two looks at ``_CM``: a whole
        buffer, sent a short line at a time): segments, bytes, seconds from the first line's
        start to the last one's reply."""
        if len(self.marks) < 2 or self.marks[1] <= self.marks[0]:
            return None
        lines = self.batches[self.marks[0] : self.marks[1]]
        return sum(b[0] for b in lines), sum(b[1] for b in lines), lines[-1][3] - lines[0][2]


def path(seconds: float, sizes: Sequence[float], wobble: Sequence[float] = ()) -> np.ndarray:
    """Ideal positions (relative) of a smooth DT 1 path: each axis moves ``sizes[j]`` counts
    a segment (its sign the direction), wobbling by ``wobble[j]`` of that around it, with
    50-segment ramps from and to rest (the path's acceleration stays within the model's)."""
    n = round(seconds * 512)
    s = np.arange(n, dtype=np.float64)
    ramp = np.clip(np.minimum(s + 1, n - s) / 50, 0, 1)
    ramp = ramp * ramp * (3 - 2 * ramp)
    steps = np.empty((n, len(sizes)))
    for j, size in enumerate(sizes):
        w = wobble[j] if j < len(wobble) else 0.0
        steps[:, j] = size * ramp * (1 + w * np.sin(2 * np.pi * s / 700 + j))
    out: np.ndarray = np.cumsum(steps, axis=0)
    return out


#: 3 axes whose CD lines are 20 or 21 bytes (the third axis's increment 4 or 5 digits,
#: half the time each): about 91 % of 11,520 B/s at DT 1.
PTY_PATH = ((12_000.0, -1_200.0, 10_000.0), (0.0, 0.0, 0.15))
#: 4 axes of 5-digit increments: 30 bytes a segment, 15,360 B/s at DT 1.
TCP_PATH = ((12_000.0, -12_000.0, 12_000.0, -12_000.0), ())


def preparation() -> Figure:
    c = galil.connect(InstantTransport(), handshake=False, model=MODEL)
    link = c.link
    points = []
    for n in (1_000, 100_000, 1_000_000):
        ideal = path(n / 512, (1_000.0, -100.0, 800.0), (0.0, 0.0, 0.15))  # within int32

        def prepare(ideal: np.ndarray = ideal) -> None:
            stream = ContourStream(link, "ABC", ideal, dt=1, byte_rate=11_520.0 * 100)
            stream.check()
            stream.prepare()
            stream.commands()

        points.append((float(n), best(prepare, repeat=3 if n < 1_000_000 else 1)))
        print(f"  {n:>9,} segments: {points[-1][1] * 1e3:9.1f} ms")
    c.close()
    n, t = points[-1]
    return Figure(
        "contour preparation (3 axes, DT 1)",
        n / t / 1e3,
        "k segments/s",
        note="check, predict, soft limits and CD commands of a 1 M-segment path; no target",
        scaling=[Scaling("segments", points)],
    )


def serve(kind: str, pipe: Connection) -> None:
    """Child process: a simulator on its real-time clock over ``kind``, until told to stop."""
    from galil.sim.server import SimPtyServer, SimTcpServer

    if kind == "tcp":
        with SimTcpServer(model=MODEL, message_port=None) as tcp:
            pipe.send(tcp.url)
            pipe.recv()
    else:
        with SimPtyServer(model=MODEL, baud=BAUD) as pty:
            pipe.send(pty.path)
            pipe.recv()


def stream_over(
    address: str, ideal: np.ndarray, letters: str, preload: bool = False
) -> dict[str, Any]:
    """Prepare (no check), feed and finish ``ideal``; what the link saw while streaming."""
    with galil.connect(address, timeout=5.0) as c:
        c.servo_here()
        watched = Watched(c.link)
        stream = ContourStream(watched, letters, ideal, dt=1, preload=preload)
        texts = stream.commands()
        need = (sum(len(t.text) + 1 for t in texts)) / (len(texts) * 2 / 1024)
        stream.prepare()
        before = c.link.bytes_sent
        t0 = time.perf_counter()
        state = stream.feed()
        spent = time.perf_counter() - t0
        sent = c.link.bytes_sent - before
        result = stream.finish(state)
        rate = c.link.byte_rate
    assert rate is not None
    looks = watched.free[2:]  # after the first refill (the first look is an empty buffer)
    return {
        "need": need,
        "sent": sent,
        "seconds": spent,
        "rate": rate,
        "segments": len(texts),
        "emptiest": max(looks) if looks else None,
        "fullest": min(looks) if looks else None,
        "depth": 511,
        "first": watched.first_refill(),
        "duration": result.duration,
    }


def run_over(kind: str, ideal: np.ndarray, letters: str, preload: bool = False) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    mine, theirs = ctx.Pipe()
    child = ctx.Process(target=serve, args=(kind, theirs), daemon=True)
    child.start()
    try:
        return stream_over(mine.recv(), ideal, letters, preload)
    finally:
        mine.send("stop")
        child.join(10)


def pty_figures(quick: bool) -> list[Figure]:
    seconds = 4.0 if quick else 8.0
    ideal = path(seconds, *PTY_PATH)
    r = run_over("pty", ideal, "ABC", preload=True)
    assert r["emptiest"] is not None
    assert r["first"] is not None
    segs, nbytes, t = r["first"]
    capacity = nbytes / t
    share = r["sent"] / r["seconds"] / r["rate"]
    print(
        f"  pty: {r['segments']} segments needing {r['need']:,.0f} B/s"
        f" ({r['need'] / r['rate'] * 100:.1f} % of {r['rate']:,.0f});"
        f" the pre-load {segs} segments, {nbytes:,} bytes in {t:.2f} s = {capacity:,.0f} B/s;"
        f" the whole stream {share * 100:.1f} % of the line;"
        f" buffer free {r['fullest']}..{r['emptiest']} of {r['depth']} after the start"
    )
    least = r["depth"] - r["emptiest"]
    return [
        Figure(
            "contour stream over a 115200-baud pty",
            capacity / r["rate"] * 100,
            "% of link rate",
            90,
            anchor="the path's need",
            anchor_value=r["need"] / r["rate"] * 100,
            ratio=capacity,
            ratio_text=" bytes/s (the pre-load: a whole buffer at once)",
            note=f"{r['segments']} DT 1 segments on 3 axes; over the whole stream"
            f" {share * 100:.1f} % of the line (the path's need, once the buffer is full)",
        ),
        Figure(
            "contour stream over a 115200-baud pty: buffer",
            least,
            "segments queued at least",
            1,
            anchor="the buffer",
            anchor_value=r["depth"],
            ratio=least * 2 / 1024,
            ratio_text=" s of motion in hand at the emptiest (DT 1)",
            note=f"pre-loaded under DT -1, started by its DT; free {r['fullest']}..{r['emptiest']}"
            " of 511 at every look after the start (no TC 42: never empty)",
        ),
    ]


def tcp_figures(quick: bool) -> list[Figure]:
    seconds = 4.0 if quick else 8.0
    ideal = path(seconds, *TCP_PATH)
    r = run_over("tcp", ideal, "ABCD")
    segs, nbytes, t = r["first"]
    capacity = nbytes / t
    print(
        f"  tcp: {r['segments']} segments needing {r['need']:,.0f} B/s"
        f" ({r['need'] / r['rate'] * 100:.1f} % of {r['rate']:,.0f} assumed);"
        f" first refill {segs} segments, {nbytes:,} bytes in {t * 1e3:.1f} ms"
        f" = {capacity:,.0f} B/s; buffer free {r['fullest']}..{r['emptiest']} of {r['depth']}"
    )
    never_empty = r["emptiest"] is not None and r["emptiest"] < r["depth"]
    return [
        Figure(
            "contour stream capacity over TCP",
            capacity / r["rate"] * 100,
            "% of link rate",
            90,
            anchor="the assumed Ethernet rate",
            anchor_value=r["rate"],
            ratio=capacity,
            ratio_text=" bytes/s (a whole buffer at once)",
            note=f"a 4-axis DT 1 path needing {r['need'] / r['rate'] * 100:.0f} % streamed,"
            f" buffer never empty: {never_empty} (free {r['fullest']}..{r['emptiest']})",
        )
    ]


def main() -> None:
    args = options(__doc__)
    print("preparing a contour (3 axes, DT 1), a transport that answers at once:")
    figures = [preparation()]
    print(f"streaming to a simulated {MODEL} in a child process:")
    figures += pty_figures(args.quick)
    figures += tcp_figures(args.quick)
    finish(figures, args)


if __name__ == "__main__":
    main()
