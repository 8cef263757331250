"""A streamed vector path's prediction is computed lazily, by the first wait that needs its
duration: whatever interrupts that computation (Ctrl-C, a failure) stops the sequence, as it
does the wait's polls (``wait_guard``), for the sync and the async wait alike, with a bar or
without. In-process simulators on a manual clock: nothing sleeps for motion.
"""

from __future__ import annotations

import asyncio
import importlib
from typing import NoReturn

import pytest

import galil
import galil.aio as aio
from galil import Line
from galil.testing import sim_of

PATH = [Line(37, 19 * (-1) ** k) for k in range(600)]  # streamed: more than the buffer holds


def _interrupt_the_prediction(monkeypatch: pytest.MonkeyPatch, error: type[BaseException]) -> None:
    def interrupted(*args: object, **kwargs: object) -> NoReturn:
        raise error  # (stands for a Ctrl-C landing while the wait computes the prediction)

    monkeypatch.setattr(importlib.import_module("galil.vector"), "replay", interrupted)


@pytest.mark.parametrize("progress", [False, True])
def test_ctrl_c_while_a_wait_computes_a_streamed_paths_prediction_stops_the_sequence(
    monkeypatch: pytest.MonkeyPatch, progress: bool
) -> None:
    with galil.connect("sim://DMC-4040") as dmc:
        handle = dmc.vector_move("AB", PATH, speed=3000)
        _interrupt_the_prediction(monkeypatch, KeyboardInterrupt)
        with pytest.raises(KeyboardInterrupt):
            handle.wait(progress=progress)
        monkeypatch.undo()
        sim_of(dmc).advance(0.5)
        assert dmc.query_operands(["_BGA", "_BGB", "_BGS"]) == [0, 0, 0]


@pytest.mark.parametrize("progress", [False, True])
def test_an_async_wait_whose_prediction_fails_stops_the_sequence(
    monkeypatch: pytest.MonkeyPatch, progress: bool
) -> None:
    async def body() -> list[float]:
        async with await aio.connect("sim://DMC-4040") as c:
            # (the start's own prediction, on the worker, lets a failure pass: the wait's fails)
            _interrupt_the_prediction(monkeypatch, RuntimeError)
            handle = await c.vector_move("AB", PATH, speed=3000)
            with pytest.raises(RuntimeError):
                await handle.wait(progress=progress)
            monkeypatch.undo()
            sim_of(c.sync).advance(0.5)
            return await c.query_operands(["_BGA", "_BGB", "_BGS"])

    assert asyncio.run(asyncio.wait_for(body(), 30)) == [0, 0, 0]
