"""Several threads on one controller, the link dying under them now and then.

Four threads share a ``sim://DMC-4040`` for a moment: each, at random, starts a move (and
waits for it, or not), a jog, a vector move or a homing step, stops an axis, sets a speed,
waits for another thread's move, reads operands, pulls the cable (closes the transport under
the link) or, finding the link dead, reconnects. Then the threads stop and the controller is
closed. Checked, for each trial:

- no call raised anything but a ``GalilError``;
- every thread ended (no deadlock between starts, waits, stops, reconnects);
- ``close()`` returned within a few seconds, and left no axis moving (decision 0024): every
  motion the library started was stopped, even after a reconnect failed (decision 0075).

Half the trials run with the controller's own reconnect (``reconnect=True``). Deterministic in
what each thread asks for (seeded); the threads' interleaving is not. Run it long with
``GALIL_THREAD_TRIALS=800 pytest --timeout=0 tests/test_threads_share_a_controller.py``.
"""

from __future__ import annotations

import contextlib
import os
import random
import threading
import time
import traceback

import pytest

import galil
from galil.errors import GalilError
from galil.testing import sim_of

TRIALS = int(os.environ.get("GALIL_THREAD_TRIALS", "6"))
THREADS = 4
SECONDS = 0.3  # of real time per trial, the threads at work
OPS = ("move", "jog", "stop", "query", "wait", "drop", "reconnect", "speed", "vector", "home")


pytestmark = pytest.mark.usefixtures("quiet")  # (tests/conftest.py)


def _step(dmc: galil.Controller, rnd: random.Random) -> None:
    op, a = rnd.choice(OPS), rnd.choice("ABCD")
    if op == "move":
        handle = dmc.axes[a].move_by(rnd.randint(-5000, 5000))
        if rnd.random() < 0.5:
            handle.wait(timeout=3)
    elif op == "jog":
        dmc.axes[a].jog(rnd.choice([-5000, 5000]))
    elif op == "stop":
        dmc.axes[a].stop()
    elif op == "query":
        dmc.query_operands([f"_RP{a}", f"_BG{a}"])
    elif op == "wait":
        running = dmc.tracker.active(a)
        if running is not None:
            running.wait(timeout=1)
    elif op == "drop":
        transport = dmc.link.transport
        if transport is not None and rnd.random() < 0.3:
            transport.close()  # the cable pulled, whatever another thread is doing
    elif op == "reconnect":
        if dmc.link.dead:
            dmc.reconnect()
    elif op == "speed":
        dmc.axes[a].speed = rnd.choice([10_000, 20_000])
    elif op == "vector":
        handle = dmc.vector_move("AB", [galil.Line(2000, 1000)], speed=20_000)
        if rnd.random() < 0.5:
            handle.wait(timeout=3)
    else:
        dmc.axes[a].find_edge()


def _work(dmc: galil.Controller, seed: float, done: threading.Event, errors: list[str]) -> None:
    rnd = random.Random(seed)
    while not done.is_set():
        try:
            _step(dmc, rnd)
        except GalilError:
            if dmc.link.dead:
                with contextlib.suppress(GalilError):  # (the next step tries again)
                    dmc.reconnect()
        except Exception:
            errors.append(traceback.format_exc())


@pytest.mark.parametrize("seed", range(TRIALS))
def test_threads_sharing_a_controller_leave_nothing_moving_after_close(seed: int) -> None:
    rnd = random.Random(seed)
    dmc = galil.connect("sim://DMC-4040", reconnect=bool(seed % 2))
    sim = sim_of(dmc)
    for a in "ABCD":
        sim.set_home_switch(a, edge=-3000, index_period=2000)
    done, errors = threading.Event(), []
    threads = [
        threading.Thread(target=_work, args=(dmc, rnd.random(), done, errors), daemon=True)
        for _ in range(THREADS)
    ]
    for t in threads:
        t.start()
    time.sleep(SECONDS)  # (real time: the threads at work, not motion to wait for)
    done.set()
    for t in threads:
        t.join(20)
    assert not [t for t in threads if t.is_alive()], "a thread never ended"
    assert not errors, errors[0]
    began = time.monotonic()
    dmc.close()
    assert time.monotonic() - began < 5
    sim.advance(5.0)  # (every stop's ramp)
    before = [sim.motion(a).reference for a in "ABCD"]
    sim.advance(1.0)
    moved = [a for a, x in zip("ABCD", before, strict=True) if sim.motion(a).reference != x]
    assert not moved, f"{moved} still moving after close()"
