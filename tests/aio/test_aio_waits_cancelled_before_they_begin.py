"""A wait cancelled before its first step stops its move, as one cancelled while it waits does
(decision 0061): ``asyncio.gather``, a ``TaskGroup`` or ``asyncio.wait_for(..., 0)`` cancel
tasks that never ran. A wait closed or dropped without being awaited stops nothing.
In-process simulators on a manual clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
import functools
import sys
import warnings
from collections.abc import Sequence
from typing import Any

import pytest
from aio_helpers import commands_of, run, sim

import galil.aio as aio

FAR = 200_000


async def _moves(c: aio.AsyncController, axes: str) -> list[aio.AsyncMoveHandle]:
    return [await c.axes[a].move_by(FAR) for a in axes]


async def _running(c: aio.AsyncController, axes: str) -> list[bool]:
    """Per axis: whether its motion runs on (stop code 0), not stopping or stopped."""
    codes = await c.query_operands([f"_SC{a}" for a in axes])
    return [round(code) == 0 for code in codes]


def _note_stop_sent_as_each_ends(
    c: aio.AsyncController, waits: Sequence[asyncio.Future[Any]], axes: str, sent: dict[str, bool]
) -> None:
    """Per axis, in ``sent`` as its wait's task ends: whether its ``ST`` had reached the
    simulator by then (a cancelled wait stops its move before its cancellation ends)."""

    def note(axis: str, _: object) -> None:
        sent[axis] = f"ST {axis}" in commands_of(c)

    for task, axis in zip(waits, axes, strict=True):
        task.add_done_callback(functools.partial(note, axis))


async def _each_stopped_its_move(
    c: aio.AsyncController, waits: Sequence[asyncio.Future[Any]], axes: str, sent: dict[str, bool]
) -> None:
    """Once every wait has ended (a cancelled ``gather`` raises as its FIRST child ends
    cancelled, while the others may still be sending their stops): each ended cancelled,
    after its stop, and no axis runs on."""
    await asyncio.wait(waits)
    assert [t.cancelled() for t in waits] == [True] * len(axes)
    assert sent == dict.fromkeys(axes, True)
    assert await _running(c, axes) == [False] * len(axes)


def test_a_gather_of_waits_cancelled_before_any_began_stops_every_move() -> None:
    async def body() -> None:
        async with await sim() as c:
            moves = await _moves(c, "DCA")
            waits = [asyncio.ensure_future(m.wait()) for m in moves]  # (none has run a step)
            sent: dict[str, bool] = {}
            _note_stop_sent_as_each_ends(c, waits, "DCA", sent)
            gathered = asyncio.gather(*waits)
            gathered.cancel()  # every child task is cancelled before its first step
            with pytest.raises(asyncio.CancelledError):
                await gathered
            await _each_stopped_its_move(c, waits, "DCA", sent)

    run(body)


def test_a_gather_cancelled_while_its_first_wait_begins_stops_the_other_moves_too() -> None:
    async def body() -> None:
        async with await sim() as c:
            first, *others = await _moves(c, "DCA")
            outer: list[asyncio.Future[object]] = []

            async def cancel_then_wait() -> object:
                outer[0].cancel()  # lands while the other children have not run yet
                return await first.wait()

            waits: list[asyncio.Future[Any]] = []
            sent: dict[str, bool] = {}

            async def gather_waits() -> None:
                waits.append(asyncio.ensure_future(cancel_then_wait()))
                waits.extend(asyncio.ensure_future(m.wait()) for m in others)
                _note_stop_sent_as_each_ends(c, waits, "DCA", sent)
                await asyncio.gather(*waits)

            task = asyncio.ensure_future(gather_waits())
            outer.append(task)
            with pytest.raises(asyncio.CancelledError):
                await task
            await _each_stopped_its_move(c, waits, "DCA", sent)

    run(body)


async def _group_left_at_once(moves: list[aio.AsyncMoveHandle], error: Exception) -> None:
    """A TaskGroup given a wait per move, left by ``error`` before any wait has run."""
    async with asyncio.TaskGroup() as tg:  # type: ignore[attr-defined]
        for m in moves:
            tg.create_task(m.wait())
        raise error


@pytest.mark.skipif(sys.version_info < (3, 11), reason="asyncio.TaskGroup")
def test_a_task_group_left_by_an_error_before_its_waits_began_stops_their_moves() -> None:
    class BoomError(Exception):
        pass

    async def body() -> None:
        async with await sim() as c:
            moves = await _moves(c, "AB")
            with pytest.raises(BaseExceptionGroup):  # noqa: F821 - 3.11+
                await _group_left_at_once(moves, BoomError())
            assert await _running(c, "AB") == [False, False]

    run(body)


def test_wait_for_with_no_time_stops_the_move() -> None:
    async def body() -> None:
        async with await sim() as c:
            (move,) = await _moves(c, "A")
            with pytest.raises(asyncio.TimeoutError):
                await asyncio.wait_for(move.wait(), 0)
            assert await _running(c, "A") == [False]
            await move.wait()  # (stopped: ends short of its target, as a stopped move does)
            assert await c.A.reference_position() < FAR

    run(body)


def test_a_wait_closed_before_it_was_awaited_stops_nothing() -> None:
    async def body() -> None:
        async with await sim() as c:
            (move,) = await _moves(c, "A")
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                move.wait().close()
            assert await _running(c, "A") == [True]
            assert (await move).final == {"A": FAR}
            assert not [t for t in commands_of(c) if t.startswith("ST")]

    run(body)


def test_a_wait_dropped_without_being_awaited_warns_and_stops_nothing() -> None:
    async def body() -> None:
        async with await sim() as c:
            (move,) = await _moves(c, "A")
            with pytest.warns(RuntimeWarning, match="never awaited"):
                move.wait()
            assert await _running(c, "A") == [True]
            assert (await move).final == {"A": FAR}

    run(body)


def test_a_wait_is_a_coroutine_to_asyncio_and_awaited_once() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_by(1000)
            waiting = move.wait()
            assert asyncio.iscoroutine(waiting)
            assert (await asyncio.create_task(waiting)).final == {"A": 1000}
            with pytest.raises(RuntimeError, match="already awaited"):
                await waiting

    run(body)
