"""A cancelled ``vector_move`` stops the sequence it started, and no other (decision 0061):
the sequence already running on S, which the start would have been refused for, goes on; a
start cancelled before it began never begins.
In-process simulators on a manual clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from typing import Any

import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil import Line
from galil.aio._motion import Starting


async def _worker_idle(c: aio.AsyncController) -> None:
    """Return once every call submitted to the worker before is over (each thread takes a
    barrier call: none is busy with anything else then)."""
    await c.worker.drained()


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


async def _streaming(c: aio.AsyncController) -> asyncio.Future[Any]:
    """A vector start on CD whose path is more than the buffer holds, once its sequence has
    registered (it streams on)."""
    path = [Line(400, 100 * (-1) ** i) for i in range(2000)]
    streaming = asyncio.ensure_future(c.vector_move("CD", path, speed=20_000))
    for _ in range(2000):
        if c.sync.tracker.last_sequence() is not None:
            break
        await c.query_operands(["_BGS"])
    return streaming


def test_a_vector_start_cancelled_while_it_streams_stops_its_own_sequence() -> None:
    async def body() -> None:
        async with await sim() as c:
            streaming = await _streaming(c)
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


def test_a_vector_start_cancelled_before_it_began_never_begins_if_its_cancel_runs_late() -> None:
    """Before: a start learnt of its cancellation only from ``Starting.cancel``, a second
    worker call. When the start's own thread got to it first, it began, and a path longer
    than the buffer streamed to its end before anything stopped it (2.65 s of controller time:
    the "vector_move long path" cancelled "running" in test_cancellation_everywhere, 1 run in
    ~300 under CPU load)."""

    async def body() -> None:
        async with await sim() as c:
            loop = asyncio.get_running_loop()
            task_over, start_over = threading.Event(), threading.Event()
            real = c.worker.submit

            def submit(fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
                if not isinstance(getattr(fn, "__self__", None), Starting):
                    return real(fn, *args, **kwargs)
                if fn.__name__ == "run":

                    def held() -> Any:  # on its thread, before its work: cancelled, then on
                        loop.call_soon_threadsafe(task.cancel)
                        task_over.wait(10)
                        try:
                            return fn(*args, **kwargs)
                        finally:
                            start_over.set()

                    return real(held)

                def late() -> Any:  # the cancel's own call: its thread comes last
                    start_over.wait(10)
                    return fn(*args, **kwargs)

                return real(late)

            c.worker.submit = submit  # type: ignore[method-assign]
            before = len(commands_of(c))
            path = [Line(37, 19 * (-1) ** k) for k in range(700)]  # more than the buffer holds
            task = asyncio.ensure_future(c.vector_move("AB", path, speed=3000))
            task.add_done_callback(lambda _: task_over.set())
            with pytest.raises(asyncio.CancelledError):
                await task
            await _worker_idle(c)
            del c.worker.submit
            assert start_over.is_set()  # (the start's call did run, after its task ended)
            assert commands_of(c)[before:] == []  # and sent nothing
            assert await c.query_operands(["_BGS", "_RPA", "_RPB"]) == [0, 0, 0]

    run(body)


def test_a_cancelled_vector_start_has_stopped_its_sequence_when_the_cancellation_arrives() -> None:
    """The cancellation waits for its own stop (decision 0085): before, ``ST S`` was submitted
    and the task ended at once, the stop still queued (here: the stops' lane held a few loop
    steps longer), so a caller that looked right after the ``CancelledError`` found the
    sequence running."""

    async def body() -> None:
        async with await sim() as c:
            streaming = await _streaming(c)
            lane = threading.Event()
            c.worker.submit_urgent(lane.wait, 10)  # the stops' lane busy for a moment

            async def let_go() -> None:
                for _ in range(20):
                    await asyncio.sleep(0)
                lane.set()

            freeing = asyncio.ensure_future(let_go())
            streaming.cancel()
            with pytest.raises(asyncio.CancelledError):
                await streaming
            sent = commands_of(c)  # right away: nothing drained first
            lane.set()
            await freeing
            assert "ST S" in sent
            sequence = c.sync.tracker.last_sequence()
            assert sequence is not None
            assert sequence.stopped
            await _worker_idle(c)

    run(body)
