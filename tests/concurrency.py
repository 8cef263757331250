"""Shared helpers: many threads on one Controller (each must get its own replies), and
waiting for a simulator's Ethernet handles to close."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from galil.controller import Controller
from galil.sim.controller import SimController

HANDLE_WAIT = 10.0


def handles_closed(sim: SimController, left: int = 0) -> None:
    """Wait until the server has seen connections close and ``left`` handles remain."""
    deadline = time.monotonic() + HANDLE_WAIT
    while sim.describe_handles().count("TCP PORT") != left:
        assert time.monotonic() < deadline, sim.describe_handles()
        threading.Event().wait(0.002)  # the server's next tick


def hammer(
    c: Controller,
    *,
    threads: int = 8,
    per_thread: int = 30,
    before: Callable[[int, int], None] | None = None,
) -> list[str]:
    """Run ``MG n`` with a distinct n per call from ``threads`` threads; return the mismatches.

    ``before(k, i)`` runs in thread k before its i-th query (e.g. to emit a message meanwhile).
    """
    errors: list[str] = []
    stride = 10 ** len(str(per_thread))

    def worker(k: int) -> None:
        for i in range(per_thread):
            n = k * stride + i
            if before is not None:
                before(k, i)
            try:
                value = c.query_number(f"MG {n}")
            except Exception as exc:  # collected and reported by the caller
                errors.append(f"{n}: {exc!r}")
                return
            if value != n:
                errors.append(f"{n}: got {value}")

    pool = [threading.Thread(target=worker, args=(k,)) for k in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    return errors
