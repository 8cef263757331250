"""Command round trip over TCP loopback: the library against a raw socket.

A minimal server thread answers ``:`` to every CR-terminated command. The same exchange
(``SHA`` CR -> ``:``) runs through ``Controller.command`` and through a bare socket doing the
least possible work; the script prints both figures and their ratio (target: 1.15 or less).
The two run in short interleaved pairs and the ratio is the median over the pairs, so that
load from other processes (this is a shared machine) does not decide the result. Scaling:
1 to 1,000 commands sent back to back in one exchange (``send_many``, pipelined).

Run: ``.venv/bin/python benchmarks/roundtrip.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import socket
import statistics
import threading
import time

from harness import Figure, Scaling, best, finish, options

import galil.controller
from galil.protocol import commands as cmds


def serve(server: socket.socket) -> None:
    """Answer ':' to each CR; one connection at a time, until the listener closes."""
    while True:
        try:
            conn, _ = server.accept()
        except OSError:
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with conn:
            while True:
                try:
                    data = conn.recv(4096)
                except OSError:
                    break
                if not data:
                    break
                n = data.count(b"\r")
                if n:
                    conn.sendall(b":" * n)


def raw_round_trips(port: int, n: int) -> float:
    """Seconds per round trip for a bare socket: sendall, then recv until ':'."""
    s = socket.create_connection(("127.0.0.1", port))
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    s.settimeout(1.0)
    try:
        start = time.perf_counter()
        for _ in range(n):
            s.sendall(b"SHA\r")
            got = s.recv(4096)
            while not got.endswith(b":"):
                got += s.recv(4096)
        return (time.perf_counter() - start) / n
    finally:
        s.close()


def library_round_trips(port: int, n: int) -> float:
    """Seconds per round trip through galil.controller.Controller.command."""
    c = galil.controller.connect(f"tcp://127.0.0.1:{port}", handshake=False, model="DMC-4040")
    try:
        command = c.command
        start = time.perf_counter()
        for _ in range(n):
            command("SHA")
        return (time.perf_counter() - start) / n
    finally:
        c.close()


def pipelined(port: int) -> list[tuple[float, float]]:
    """Seconds for N commands sent back to back in one exchange (send_many)."""
    c = galil.controller.connect(f"tcp://127.0.0.1:{port}", handshake=False, model="DMC-4040")
    try:
        points = []
        for n in (1, 10, 100, 1000):
            batch = [cmds.sh("A")] * n
            points.append((float(n), best(lambda b=batch: c.send_many(b), repeat=5)))
        return points
    finally:
        c.close()


def main() -> None:
    args = options(__doc__)
    n = 300 if args.quick else 1000
    pairs = 9 if args.quick else 21
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    threading.Thread(target=serve, args=(server,), daemon=True).start()
    raw_round_trips(port, 500)  # warm up both paths
    library_round_trips(port, 500)
    raw, lib, ratios = [], [], []
    for i in range(pairs):
        # Short runs back to back, the order alternating: a burst of load from elsewhere on
        # the machine then hits both sides of a pair alike, and the median drops the rest.
        if i % 2:
            b = library_round_trips(port, n)
            a = raw_round_trips(port, n)
        else:
            a = raw_round_trips(port, n)
            b = library_round_trips(port, n)
        raw.append(a)
        lib.append(b)
        ratios.append(b / a)
    points = pipelined(port)
    server.close()
    r, m = statistics.median(raw), statistics.median(lib)
    ratio = statistics.median(ratios)
    print(f"round trips per run   {n} x {pairs} pairs of runs (raw, library)")
    print(f"raw socket            {r * 1e6:8.1f} us  (best {min(raw) * 1e6:.1f})")
    print(f"galil Controller      {m * 1e6:8.1f} us  (best {min(lib) * 1e6:.1f})")
    print(f"library overhead      {(m - r) * 1e6:8.1f} us per round trip (medians)")
    print(f"ratio library / raw   {ratio:8.2f}  (median of pairs; target <= 1.15)")
    finish(
        [
            Figure(
                "round trip over TCP (SHA -> :)",
                m * 1e6,
                "us",
                anchor="raw socket",
                anchor_value=r * 1e6,
                ratio=ratio,
                ratio_text="x the raw socket (median of interleaved pairs)",
                ratio_target=1.15,
                scaling=[Scaling("commands pipelined", points)],
            )
        ],
        args,
    )


if __name__ == "__main__":
    main()
