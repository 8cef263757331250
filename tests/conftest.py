"""Guards for every test: nothing a test starts (threads, child processes) outlives it.

A server, reader or watcher thread left running after its test keeps polling while the rest of
the suite runs, steals CPU from the tests that wait in real time, and can answer on a port or
pty that a later test is using; the check below names the test that left it.
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

# Generous: a closed link's threads notice within one poll interval (tens of ms), but a loaded
# CI machine may not schedule them for a while.
THREAD_GRACE = 10.0

# Process-wide helpers of third-party libraries, started once and kept on purpose.
FOREIGN_THREADS = ("tqdm_monitor",)


@pytest.fixture(autouse=True)
def _no_thread_outlives_its_test() -> Iterator[None]:
    before = set(threading.enumerate())
    yield
    new = [t for t in threading.enumerate() if t not in before and t.name not in FOREIGN_THREADS]
    deadline = time.monotonic() + THREAD_GRACE
    for t in new:
        t.join(max(0.0, deadline - time.monotonic()))
    alive = [f"{t.name} (daemon={t.daemon})" for t in new if t.is_alive()]
    assert not alive, f"threads still running {THREAD_GRACE:g} s after the test: {alive}"


@pytest.fixture
def spawn() -> Iterator[Callable[..., subprocess.Popen[str]]]:
    """Start a child process that is killed at teardown if the test left it running.

    The test still stops the child itself and checks how it stopped; this only keeps a failed
    test from leaving a server behind (it would outlive the whole run on CI).
    """
    procs: list[subprocess.Popen[str]] = []

    def start(args: list[str], **kwargs: Any) -> subprocess.Popen[str]:
        proc: subprocess.Popen[str] = subprocess.Popen(args, **kwargs)
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)
        for pipe in (proc.stdin, proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()
