"""``await handle.wait(progress=True)`` shows the bar of the sync ``MoveHandle.wait(progress=True)``
(one :class:`~galil.motion.WaitBar` for both), and closes it however the wait ends: the move
done, a ``MotionError``, a timeout, a cancellation. In-process simulators on a manual clock:
nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
import tqdm.auto
import tqdm.std
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil.testing import sim_of


def _last_frame(err: str) -> str:
    """The bar as it was left: the last of its redrawn frames (tqdm separates them by CR)."""
    return err.replace("\n", "\r").strip("\r").split("\r")[-1].strip()


class _Bars:
    """Every bar a wait makes (kept alive here, so an unclosed one stays in tqdm's list)."""

    def __init__(self) -> None:
        self.made: list[Any] = []
        base: Any = tqdm.auto.tqdm
        made = self.made

        class Recorded(base):  # type: ignore[misc]
            def __init__(self, *args: Any, **kwargs: Any) -> None:
                super().__init__(*args, **kwargs)
                made.append(self)

        self.kind = Recorded


@pytest.fixture
def bars(monkeypatch: pytest.MonkeyPatch) -> _Bars:
    recorded = _Bars()
    monkeypatch.setattr(tqdm.auto, "tqdm", recorded.kind)
    return recorded


def test_an_async_wait_with_progress_shows_the_bar_of_the_sync_wait(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with galil.connect("sim://DMC-4040") as dmc:
        dmc.A.move_by(30_000).wait(progress=True)
        sync_move = _last_frame(capsys.readouterr().err)
        jog = dmc.B.jog(5000)
        dmc.sleep(0.1)
        jog.stop()
        jog.wait(progress=True)
        sync_jog = _last_frame(capsys.readouterr().err)

    async def body() -> tuple[str, str]:
        async with await sim() as c:
            move = await c.A.move_by(30_000)
            await move.wait(progress=True)
            async_move = _last_frame(capsys.readouterr().err)
            jog = await c.B.jog(5000)
            await c.sleep(0.1)
            await jog.stop()
            await jog.wait(progress=True)
            return async_move, _last_frame(capsys.readouterr().err)

    async_move, async_jog = run(body)
    assert sync_move.startswith("position A: 100%")
    assert async_move == sync_move
    assert sync_jog.startswith("jog B: ")
    assert async_jog == sync_jog


async def _done(c: aio.AsyncController, bars: _Bars) -> None:
    move = await c.A.move_by(30_000)
    result = await move.wait(progress=True)
    assert result.final == {"A": 30_000}


async def _limit(c: aio.AsyncController, bars: _Bars) -> None:
    move = await c.A.move_by(200_000)
    await c.sleep(0.1)
    sim_of(c.sync).set_limit_switch("A", "forward", True)
    with pytest.raises(galil.MotionError, match="FWD limit"):
        await move.wait(progress=True)


async def _timeout(c: aio.AsyncController, bars: _Bars) -> None:
    jog = await c.A.jog(5000)
    with pytest.raises(galil.GalilTimeoutError):
        await jog.wait(timeout=0.3, progress=True)
    await jog.stop()
    await jog


async def _cancel(c: aio.AsyncController, bars: _Bars) -> None:
    move = await c.A.move_by(200_000)
    task = asyncio.ensure_future(move.wait(progress=True))
    await asyncio.sleep(0)  # the task's first step: the wait has begun, its bar is open
    assert len(bars.made) == 1
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert any(t.startswith("ST") for t in commands_of(c))  # the move was stopped


ENDINGS: dict[str, Callable[[aio.AsyncController, _Bars], Awaitable[None]]] = {
    "done": _done,
    "MotionError": _limit,
    "timeout": _timeout,
    "cancel": _cancel,
}


@pytest.mark.parametrize("ending", ENDINGS)
def test_the_bar_of_an_async_wait_is_closed_however_the_wait_ends(
    ending: str, bars: _Bars, capsys: pytest.CaptureFixture[str]
) -> None:
    async def body() -> None:
        async with await sim() as c:
            await ENDINGS[ending](c, bars)

    run(body)
    assert len(bars.made) == 1
    (bar,) = bars.made
    assert bar.desc.startswith("position A") or bar.desc.startswith("jog A")
    assert bar not in tqdm.std.tqdm._instances, "left open in tqdm"  # (alive: in bars.made)
    if ending in ("done", "MotionError"):  # seen done: the bar shows the whole predicted time
        assert bar.n == bar.total
    assert bar.desc in _last_frame(capsys.readouterr().err)  # shown, and left as closed
