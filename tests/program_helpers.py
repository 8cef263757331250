"""Running a downloaded program on the simulator to its end, and reading what it printed;
waiting for motion from the host."""

from __future__ import annotations

import queue
import threading
import time

import galil
from galil.motion import MIN_POLL


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


def wait_for_motion(dmc: galil.Controller, axes: str = "A", timeout: float = 30.0) -> None:
    """Poll ``_BGm`` of each of ``axes`` until none of them moves, as a host waits for a move
    (AM and MC are program commands: the controller refuses them from a host, decision 0044).

    Between polls the link's ``pause`` lets :data:`~galil.motion.MIN_POLL` pass, the
    simulator's clock on ``sim://``, as :meth:`galil.motion.MoveHandle.wait` does;
    ``timeout`` is in the controller's time.
    """
    query = "MG " + ",".join(f"_BG{a}" for a in axes)
    link = dmc.link
    deadline = link.clock() + timeout
    while any(dmc.query_numbers(query)):
        assert link.clock() < deadline, f"{axes} still moving after {timeout} s"
        link.pause(MIN_POLL)


def input_wait_started(
    dmc: galil.Controller, timeout: float
) -> tuple[threading.Thread, list[BaseException | None]]:
    """``dmc.io.wait_for_input(1, high=False, timeout=timeout)`` on a thread of its own,
    returned once its routine runs on thread 7; the list gets ``None`` when the wait returns,
    or what it raised."""
    ended: list[BaseException | None] = []

    def wait() -> None:
        try:
            dmc.io.wait_for_input(1, high=False, timeout=timeout)
            ended.append(None)
        except BaseException as exc:
            ended.append(exc)

    waiting = threading.Thread(target=wait)
    waiting.start()
    deadline = time.monotonic() + 10.0
    while dmc.routines.threads.get(7) != "#GINWAIT" and time.monotonic() < deadline:
        time.sleep(0.001)  # (the wait's routine starts: not a wait for motion)
    return waiting, ended
