"""Running a downloaded program on the simulator to its end, and reading what it printed."""

from __future__ import annotations

import queue

import galil


def run_program(dmc: galil.Controller, program: str, label: str = "#M") -> list[str]:
    """Download ``program``, run ``label`` on thread 0 until no thread runs; its messages."""
    dmc.programs.download(program)
    dmc.programs.run(label, thread=0)
    for _ in range(50):
        if not dmc.programs.threads:
            break
        dmc.sleep(0.1)
    assert not dmc.programs.threads
    return drain_messages(dmc)


def drain_messages(dmc: galil.Controller) -> list[str]:
    """The messages that have arrived, stripped."""
    lines = []
    while True:
        try:
            lines.append(dmc.messages.get(timeout=0).strip())
        except queue.Empty:
            return lines
