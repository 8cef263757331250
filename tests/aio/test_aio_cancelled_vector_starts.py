"""A cancelled ``vector_move`` stops the sequence it started, and no other (decision 0061):
the sequence already running on S, which the start would have been refused for, goes on.
In-process simulators on a manual clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
import threading

import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil import Line


async def _worker_idle(c: aio.AsyncController) -> None:
    """Return once every call submitted to the worker before is over (each thread takes a
    barrier call: none is busy with anything else then)."""
    threads = c.worker.threads
    barrier = threading.Barrier(len(threads))
    await asyncio.gather(*(c.worker.run(barrier.wait, 10) for _ in threads))


@pytest.mark.parametrize("ticks", [1, 2, 3])
def test_a_cancelled_vector_start_leaves_the_running_sequence_going(ticks: int) -> None:
    async def body() -> None:
        async with await sim() as c:
            ab = await c.vector_move("AB", [Line(60_000, 0)], speed=20_000)
            stops_before = [t for t in commands_of(c) if t.startswith("ST")]
            task = asyncio.ensure_future(c.vector_move("CD", [Line(1000, 0)], speed=20_000))
            for _ in range(ticks):  # (queued, or running on its thread: the cancel comes then)
                await asyncio.sleep(0)
            task.cancel()
            with pytest.raises((asyncio.CancelledError, galil.InvalidArgument)):
                await task
            await _worker_idle(c)
            assert [t for t in commands_of(c) if t.startswith("ST")] == stops_before
            assert not ab.stopped
            assert (await ab.wait()).final == {"A": 60_000, "B": 0}

    run(body)


def test_a_vector_start_cancelled_while_it_streams_stops_its_own_sequence() -> None:
    async def body() -> None:
        async with await sim() as c:
            path = [Line(400, 100 * (-1) ** i) for i in range(2000)]  # more than the buffer holds
            streaming = asyncio.ensure_future(c.vector_move("CD", path, speed=20_000))
            for _ in range(2000):  # until its sequence has registered: it streams on
                if c.sync.tracker.last_sequence() is not None:
                    break
                await c.query_operands(["_BGS"])
            streaming.cancel()
            with pytest.raises(asyncio.CancelledError):
                await streaming
            await _worker_idle(c)
            sent = commands_of(c)
            assert "ST S" in sent
            # stopped while it streamed, not once its whole path was sent (VE) and returned
            assert not [t for t in sent[: sent.index("ST S")] if t.startswith("VE")]
            sequence = c.sync.tracker.last_sequence()
            assert sequence is not None
            assert sequence.stopped

    run(body)
