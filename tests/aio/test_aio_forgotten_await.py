"""A forgotten ``await`` in galil.aio: Python's "coroutine ... was never awaited" names the
async method (``AsyncAxis.stop``), and the close that stops a move nobody waited for says how
to wait for it from a coroutine. In-process simulators on a manual clock."""

from __future__ import annotations

import gc
import logging
from collections.abc import Callable

import pytest
from aio_helpers import run, sim

import galil.aio as aio


def _forget(call: Callable[[], object]) -> None:
    call()  # (the coroutine is dropped un-awaited here: Python warns at once)
    gc.collect()


@pytest.mark.parametrize(
    ("name", "forgotten"),
    [
        ("AsyncAxis.stop", lambda c: c.A.stop()),
        ("AsyncAxis.move_to", lambda c: c.A.move_to(1000)),
        ("AsyncController.stop", lambda c: c.stop()),
    ],
)
def test_a_forgotten_await_names_the_async_method(
    name: str, forgotten: Callable[[aio.AsyncController], object]
) -> None:
    async def body() -> None:
        async with await sim() as c:
            with pytest.warns(RuntimeWarning, match=f"coroutine '{name}' was never awaited"):
                _forget(lambda: forgotten(c))

    run(body)


def test_closing_an_async_controller_over_a_move_not_waited_for_says_await(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async def body() -> None:
        async with await sim() as c:
            await c.A.move_to(100_000)

    with caplog.at_level(logging.WARNING, logger="galil"):
        run(body)
    said = caplog.text
    assert "stopped axes A mid-motion" in said
    assert "await handle.wait(), or await handle" in said
    assert "call wait()" not in said
