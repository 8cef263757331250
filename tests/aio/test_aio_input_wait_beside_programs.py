"""The awaited wait_for_input beside the rest of a session (decision 0086): it takes a thread
the watchdog does not hold, its routine's line never reaches ``c.messages``, and a running
program of the user's is never refused a wait (the input read first, then polled)."""

from __future__ import annotations

import asyncio

import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil.testing import sim_of

LOOP = "#MAIN\nn=0\n#L\nn=n+1\nWT 10\nJP #L\nEN\n"


async def _until_running(
    c: aio.AsyncController, thread: int, waiting: asyncio.Future[None]
) -> None:
    """Until the wait's routine runs on ``thread`` (or the wait has ended: a refusal)."""
    while not waiting.done() and await c.query_operands([f"_XQ{thread}"]) == [-1.0]:
        await asyncio.sleep(0.001)


def test_an_awaited_input_wait_beside_the_watchdog_takes_another_thread_by_default() -> None:
    async def body() -> tuple[int, bool]:
        async with await sim() as c:
            dog = await c.watchdog(0.5)
            waiting = asyncio.ensure_future(c.io.wait_for_input(1, high=False, timeout=10))
            await _until_running(c, 6, waiting)  # (before: refused, "thread 7 ... HX7")
            sim_of(c.sync).set_input(1, False)
            await waiting
            running = await dog.running()
            await dog.stop()
            return dog.thread, running

    assert run(body) == (7, True)


def test_the_awaited_input_waits_line_never_reaches_the_users_messages() -> None:
    async def body() -> None:
        async with await sim() as c:
            waiting = asyncio.ensure_future(c.io.wait_for_input(2, high=False, timeout=10))
            await _until_running(c, 7, waiting)
            sim_of(c.sync).set_input(2, False)
            await waiting
            with pytest.raises(galil.GalilTimeoutError):  # (before: 'galil-input  2')
                await c.messages.get(timeout=0.3)

    run(body)


def test_an_awaited_wait_whose_input_is_at_the_level_returns_at_once_beside_a_program() -> None:
    async def body() -> tuple[list[str], dict[int, int]]:
        async with await sim() as c:
            await c.programs.download(LOOP)
            await c.programs.run("#MAIN")
            before = len(commands_of(c))
            await c.io.wait_for_input(1, high=True, timeout=1)  # (before: "a program runs")
            return commands_of(c)[before:], await c.programs.threads()

    sent, threads = run(body)
    assert sent == ["MG @IN[1]"]
    assert list(threads) == [0]


def test_an_awaited_wait_polls_beside_a_program_for_its_whole_timeout() -> None:
    async def body() -> tuple[float, str, list[str], dict[int, int]]:
        async with await sim() as c:
            await c.programs.download(LOOP)
            await c.programs.run("#MAIN")
            before = len(commands_of(c))
            start = await c.run(c.sync.link.clock)
            with pytest.raises(galil.GalilTimeoutError) as raised:
                await c.io.wait_for_input(1, high=False, timeout=1.2)  # 3 slices
            took = await c.run(c.sync.link.clock) - start
            return took, str(raised.value), commands_of(c)[before:], await c.programs.threads()

    took, text, sent, threads = run(body)
    assert 1.2 <= took < 1.5
    assert "so this wait polled its input" in text
    assert sent.count("UL") == 1  # the install tried once, not once per slice
    assert all(line == "UL" or line.startswith("MG ") for line in sent)  # reads only
    assert list(threads) == [0]
