"""Several tasks on one async controller, the link dying under them now and then.

The async twin of ``tests/test_threads_share_a_controller.py``: four tasks share an
``await galil.aio.connect("sim://DMC-4040")`` for a moment, each at random starting a move
(awaited or not), a jog, a vector move or a homing step, a start it cancels at once or a
little later, stopping an axis, setting a speed, reading operands, pulling the cable (closing
the transport under the link) or, finding the link dead, reconnecting. Then the controller
is closed. Checked, for each trial: no call raised anything but a ``GalilError``, every task
ended, and ``aclose()`` left no axis moving. Half the trials use the controller's own
reconnect. Run it long with ``GALIL_TASK_TRIALS=400``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import traceback

import pytest
from aio_helpers import run

import galil
import galil.aio as aio
from galil.errors import GalilError
from galil.testing import sim_of

TRIALS = int(os.environ.get("GALIL_TASK_TRIALS", "4"))
SECONDS = 0.3  # of the loop's time per trial, the tasks at work
OPS = ("move", "jog", "stop", "query", "drop", "reconnect", "speed", "vector", "home", "cancel")


pytestmark = pytest.mark.usefixtures("quiet")  # (tests/conftest.py)


async def _cancelled_start(axis: aio.AsyncAxis, rnd: random.Random) -> None:
    task = asyncio.ensure_future(axis.move_by(rnd.randint(-5000, 5000)))
    await asyncio.sleep(rnd.random() * 0.01)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task  # (a start that returned first: its move is the caller's, unawaited)


async def _step(c: aio.AsyncController, rnd: random.Random) -> None:
    op, a = rnd.choice(OPS), rnd.choice("ABCD")
    axis = c.axes[a]
    if op == "move":
        handle = await axis.move_by(rnd.randint(-5000, 5000))
        if rnd.random() < 0.5:
            await handle.wait(timeout=3)
    elif op == "jog":
        await axis.jog(rnd.choice([-5000, 5000]))
    elif op == "stop":
        await axis.stop()
    elif op == "query":
        await c.query_operands([f"_RP{a}", f"_BG{a}"])
    elif op == "drop":
        transport = c.sync.link.transport
        if transport is not None and rnd.random() < 0.3:
            transport.close()  # the cable pulled, whatever another task awaits
    elif op == "reconnect":
        if c.sync.link.dead:
            await c.reconnect()
    elif op == "speed":
        await axis.set_speed(rnd.choice([10_000, 20_000]))
    elif op == "vector":
        handle = await c.vector_move("AB", [galil.Line(2000, 1000)], speed=20_000)
        if rnd.random() < 0.5:
            await handle.wait(timeout=3)
    elif op == "home":
        await axis.find_edge()
    else:
        await _cancelled_start(axis, rnd)


async def _work(c: aio.AsyncController, seed: float, until: float, errors: list[str]) -> None:
    rnd = random.Random(seed)
    while asyncio.get_running_loop().time() < until:
        try:
            await _step(c, rnd)
        except GalilError:
            if c.sync.link.dead:
                with contextlib.suppress(GalilError):  # (the next step tries again)
                    await c.reconnect()
        except Exception:
            errors.append(traceback.format_exc())


async def _trial(seed: int) -> list[str]:
    rnd = random.Random(seed)
    c = await aio.connect("sim://DMC-4040", reconnect=bool(seed % 2))
    sim = sim_of(c.sync)
    for a in "ABCD":
        sim.set_home_switch(a, edge=-3000, index_period=2000)
    errors: list[str] = []
    until = asyncio.get_running_loop().time() + SECONDS
    await asyncio.wait_for(
        asyncio.gather(*(_work(c, rnd.random(), until, errors) for _ in range(4))), 20
    )
    await c.aclose()
    sim.advance(5.0)  # (every stop's ramp)
    before = [sim.motion(a).reference for a in "ABCD"]
    sim.advance(1.0)
    moved = [a for a, x in zip("ABCD", before, strict=True) if sim.motion(a).reference != x]
    return errors + ([f"{moved} still moving after aclose()"] if moved else [])


@pytest.mark.parametrize("seed", range(TRIALS))
def test_tasks_sharing_a_controller_leave_nothing_moving_after_aclose(seed: int) -> None:
    problems = run(lambda: _trial(seed))
    assert not problems, problems[0]
