"""``async with c.motion()`` left by a cancellation while a start in it still runs on its
worker thread: the guard waits for that start, then stops and waits for what it left, so
nothing moves once the block is left (decision 0061). In-process simulators on a manual
clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio

import pytest
from aio_helpers import run, sim
from test_cancellation_everywhere import WireTrap

import galil.aio as aio


async def _guarded_move(c: aio.AsyncController) -> None:
    async with c.motion():
        await c.A.move_by(50_000)
        await c.sleep(0.05)


@pytest.mark.parametrize("write", [1, 2])
def test_a_guard_left_while_its_move_starts_leaves_nothing_moving(write: int) -> None:
    async def body() -> None:
        async with await sim() as c:
            for _ in range(40):  # (the start and the guard's queries race on two threads)
                trap = WireTrap(c, write)
                task = asyncio.ensure_future(_guarded_move(c))
                trap.watch(task, task.cancel)
                await asyncio.wait({task})
                await trap.settle()
                assert trap.fired
                assert task.cancelled()
                assert await c.query_operands(["_BGA"]) == [0.0]

    run(body)


def test_an_async_guard_of_no_named_axes_guards_every_axis() -> None:
    async def jog_then_fail(c: aio.AsyncController) -> None:
        async with c.motion(""):
            await c.A.jog(5000)
            raise RuntimeError("boom")

    async def body() -> None:
        async with await sim() as c:
            with pytest.raises(RuntimeError, match="boom"):
                await jog_then_fail(c)
            assert await c.query_operands(["_BGA", "_SCA"]) == [0.0, 4.0]

    run(body)
