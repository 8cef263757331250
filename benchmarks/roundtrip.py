"""Command round trip over TCP loopback: the library against a raw socket.

A minimal server thread answers ``:`` to every CR-terminated command. The same exchange
(``SHA`` CR -> ``:``) runs through ``Controller.command`` and through a bare socket doing the
least possible work; the script prints both figures and their ratio (target: 1.3 or less).

Run: ``.venv/bin/python benchmarks/roundtrip.py [round_trips]``
"""

from __future__ import annotations

import socket
import statistics
import sys
import threading
import time

import galil.client


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
    """Seconds per round trip through galil.client.Controller.command."""
    c = galil.client.connect(f"tcp://127.0.0.1:{port}", handshake=False, model="DMC-4040")
    try:
        command = c.command
        start = time.perf_counter()
        for _ in range(n):
            command("SHA")
        return (time.perf_counter() - start) / n
    finally:
        c.close()


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5000
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    threading.Thread(target=serve, args=(server,), daemon=True).start()
    raw_round_trips(port, 500)  # warm up both paths
    library_round_trips(port, 500)
    raw, lib = [], []
    for _ in range(5):  # interleaved, so drifts in machine load hit both alike
        raw.append(raw_round_trips(port, n))
        lib.append(library_round_trips(port, n))
    server.close()
    r, m = statistics.median(raw), statistics.median(lib)
    print(f"round trips per run   {n}")
    print(f"raw socket            {r * 1e6:8.1f} us  (best {min(raw) * 1e6:.1f})")
    print(f"galil Controller      {m * 1e6:8.1f} us  (best {min(lib) * 1e6:.1f})")
    print(f"ratio library / raw   {m / r:8.2f}  (target <= 1.30)")


if __name__ == "__main__":
    main()
