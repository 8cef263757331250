"""How an async move handle ends when its watcher does not see it through: a closed or
abandoned ``watch()`` stops the move, so does a wait whose link dies (as the sync wait does),
and ``add_callback`` callbacks run only for a move seen done. In-process simulators on a
manual clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
import gc

import pytest
from aio_helpers import commands_of, run, sim
from client_fakes import pull_cable_after

import galil
import galil.aio as aio


async def _until_stopped(c: aio.AsyncController) -> None:
    for _ in range(400):
        if not await c.A.moving():
            return
        await c.sleep(0.01)


def test_cancelling_a_task_inside_its_watch_loop_body_stops_the_move() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_to(200_000)
            in_body = asyncio.Event()

            async def watcher() -> None:
                async for _ in move.watch():
                    in_body.set()
                    await asyncio.Event().wait()  # the cancel lands here, not in watch()

            task = asyncio.ensure_future(watcher())
            await in_body.wait()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            del task
            gc.collect()  # the abandoned generator is finalised: aclose() on this loop
            await _until_stopped(c)
            assert any(t.startswith("ST") for t in commands_of(c))
            assert await c.A.reference_position() < 200_000

    run(body)


def test_closing_a_watch_before_the_move_is_done_stops_it() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_to(200_000)
            progress = move.watch()
            await anext(progress)
            await progress.aclose()
            assert any(t.startswith("ST") for t in commands_of(c))  # before aclose returned
            await _until_stopped(c)
            assert await c.A.reference_position() < 200_000

    run(body)


def test_closing_a_watch_that_only_watches_leaves_the_move_running() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_to(20_000)
            progress = move.watch(stop_on_cancel=False)
            await anext(progress)
            await progress.aclose()
            await move
            assert not any(t.startswith("ST") for t in commands_of(c))
            assert await c.A.reference_position() == 20_000

    run(body)


def test_callbacks_are_not_called_when_the_controller_closes_before_the_move_ends() -> None:
    async def body() -> list[object]:
        c = await sim()
        move = await c.A.move_to(200_000)
        called: list[object] = []
        move.add_callback(called.append)
        watcher = move._watcher
        assert watcher is not None
        await c.aclose()
        await watcher
        assert not move.finished
        return called

    assert run(body) == []


def test_callbacks_run_once_the_move_is_done() -> None:
    async def body() -> list[object]:
        async with await sim() as c:
            move = await c.A.move_to(2_000)
            called: list[object] = []
            move.add_callback(called.append)
            await move
            watcher = move._watcher
            assert watcher is not None
            await watcher
            return called

    assert len(run(body)) == 1


def test_a_callback_that_raises_is_logged_and_the_others_still_run(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def buggy(handle: object) -> None:
        raise RuntimeError("bug in a UI callback")

    async def body() -> list[object]:
        async with await sim() as c:
            move = await c.A.move_to(2_000)
            called: list[object] = []
            for cb in (buggy, called.append):
                move.add_callback(cb)
            await move
            watcher = move._watcher
            assert watcher is not None
            await watcher
            for cb in (buggy, called.append):  # done already: called at once
                move.add_callback(cb)
            return called

    assert len(run(body)) == 2
    failed = [r for r in caplog.records if "callback" in r.getMessage()]
    assert [(r.name, r.levelname) for r in failed] == [("galil.aio", "ERROR")] * 2
    assert all("bug in a UI callback" in (r.exc_text or "") for r in failed)


def _dies_after(c: aio.AsyncController, mark: bytes) -> None:
    """The link dies once a line with ``mark`` went out (the controller got it; its reply is
    lost with the link). ``sim://`` reopens onto the same simulator."""
    pull_cable_after(c.sync.link.transport, mark)


def test_a_wait_whose_link_dies_stops_the_move_on_the_reopened_link() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_to(200_000)  # 8 s at SP 25 000
            _dies_after(c, b"MG _BGA,_RPA,_SCA")  # (its first poll)
            with pytest.raises(galil.GalilConnectionError) as info:
                await move.wait()
            text = str(info.value)
            assert "it was reopened and A stopped, so the link works again" in text
            assert "reconnect()" not in text
            assert any(t.startswith("ST") for t in commands_of(c))
            await _until_stopped(c)
            assert await c.A.reference_position() < 200_000

    run(body)


def test_a_watch_whose_link_dies_stops_the_move_unless_it_only_watches() -> None:
    async def body(only_watch: bool) -> int:
        async with await sim() as c:
            move = await c.A.move_to(20_000)
            _dies_after(c, b"MG _BGA,_RPA,_SCA")
            with pytest.raises(galil.GalilConnectionError):
                async for _ in move.watch(stop_on_cancel=not only_watch):
                    pass
            if only_watch:  # nothing reopened it: the move goes on, seen by a new link
                assert c.sync.link.dead
                await c.reconnect()
                await move
            await _until_stopped(c)
            return await c.A.reference_position()

    assert run(lambda: body(only_watch=False)) < 20_000
    assert run(lambda: body(only_watch=True)) == 20_000


def test_a_late_stop_of_an_old_handle_leaves_the_newer_move_on_its_axis_running() -> None:
    async def body() -> None:
        async with await sim() as c:
            old = await c.A.move_by(1000)
            await old.wait()
            new = await c.A.move_by(50_000)
            await c.sleep(0.2)
            before = len(commands_of(c))
            await old.stop()  # (its axis moved on to the newer move: nothing is sent)
            await old.stop_unless_done()
            assert not any(t.startswith("ST") for t in commands_of(c)[before:])
            result = await new.wait()
            assert result.final == {"A": 51_000}
            assert result.stop_codes == {"A": 1}

    run(body)
