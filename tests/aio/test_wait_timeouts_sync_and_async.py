"""A wait's timeout is checked by one function on both sides, sync and async: the same bad
values are refused with InvalidArgument, before anything is sent or read (a program's thread,
a capture, a record stream, and the queues of unsolicited messages and interrupts).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from aio_helpers import commands_of, run, sim

import galil
from galil.testing import sim_of, simulated

BAD = [math.inf, -math.inf, -1, math.nan, "x", True]

Call = Callable[[Any, object], Any]

SYNC: dict[str, tuple[Callable[[galil.Controller], Any], Call]] = {
    "programs.wait": (lambda c: c.programs, lambda p, t: p.wait(0, t)),
    "capture.wait": (lambda c: c.capture(["_RPA"], every=2, count=10), lambda k, t: k.wait(t)),
    "records.get": (lambda c: c.records(8), lambda r, t: r.get(t)),
    "messages.get": (lambda c: c.messages, lambda q, t: q.get(t)),
    "interrupts.get": (lambda c: c.interrupts, lambda i, t: i.get(t)),
}


async def _programs(c: Any) -> Any:
    return c.programs


async def _capture(c: Any) -> Any:
    return await c.capture(["_RPA"], every=2, count=10)


async def _records(c: Any) -> Any:
    return await c.records(8)


async def _messages(c: Any) -> Any:
    return c.messages


async def _interrupts(c: Any) -> Any:
    return c.interrupts


ASYNC: dict[str, tuple[Callable[[Any], Any], Call]] = {
    "programs.wait": (_programs, lambda p, t: p.wait(0, t)),
    "capture.wait": (_capture, lambda k, t: k.wait(t)),
    "records.get": (_records, lambda r, t: r.get(t)),
    "messages.get": (_messages, lambda q, t: q.get(t)),
    "interrupts.get": (_interrupts, lambda i, t: i.get(t)),
}


def _refused_sync(what: str, timeout: object) -> None:
    make, call = SYNC[what]
    with simulated() as dmc:
        target = make(dmc)
        before = len(sim_of(dmc).command_log)
        with pytest.raises(galil.InvalidArgument):
            call(target, timeout)
        assert len(sim_of(dmc).command_log) == before  # refused before a byte


def _refused_async(what: str, timeout: object) -> None:
    make, call = ASYNC[what]

    async def body() -> None:
        async with await sim() as c:
            target = await make(c)
            before = len(commands_of(c))
            with pytest.raises(galil.InvalidArgument):
                await call(target, timeout)
            assert len(commands_of(c)) == before

    run(body)


@pytest.mark.parametrize("what", sorted(SYNC))
@pytest.mark.parametrize("timeout", BAD, ids=repr)
def test_a_bad_wait_timeout_is_refused_alike_sync_and_async(what: str, timeout: object) -> None:
    _refused_sync(what, timeout)
    _refused_async(what, timeout)


def test_a_thread_wait_without_an_end_is_refused_sync_and_async() -> None:
    _refused_sync("programs.wait", None)
    _refused_async("programs.wait", None)


def test_none_waits_for_ever_for_a_message_sync_and_async() -> None:
    with simulated() as dmc:
        sim_of(dmc).emit_message("hello")
        dmc.command("MG 1")  # the line is read with the next exchange
        assert dmc.messages.get(None) == "hello"

    async def body() -> None:
        async with await sim() as c:
            sim_of(c.sync).emit_message("hello")
            await c.command("MG 1")
            assert await c.messages.get(None) == "hello"

    run(body)


def test_none_waits_the_default_for_a_capture_and_for_ever_for_a_record() -> None:
    with simulated() as dmc:
        assert len(dmc.capture(["_RPA"], every=2, count=10).wait(None)["_RPA"]) == 10
        with dmc.records(8) as stream:
            assert stream.get(None) is not None

    async def body() -> None:
        async with await sim() as c:
            cap = await c.capture(["_RPA"], every=2, count=10)
            assert len((await cap.wait(None))["_RPA"]) == 10
            async with await c.records(8) as stream:
                assert await stream.get(None) is not None

    run(body)
