"""Every public wait takes its timeout by one rule, on both sides, sync and async: ``None`` (what
it means is the wait's own: for ever, or a default such as a move's predicted duration plus a
margin) or a finite number of seconds >= 0, checked by one function
(:func:`galil.link.check_seconds`, through ``check_wait_timeout`` for a wait and
``check_timeout`` for a reply's timeout). The same bad values are refused with InvalidArgument
naming the parameter, before anything is sent or read: moves, jogs, homing and vector
sequences, a program's thread, an input, a capture, a contour, a record stream, the queues of
unsolicited messages and interrupts, a data record, a command, a burn, the watchdog and a sleep.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, TypeVar

import pytest
from aio_helpers import run, sim

import galil
from galil import Line
from galil.testing import nothing_sent, sim_of, simulated

T = TypeVar("T")

#: Refused by every wait: infinity (``None`` is the way to wait for ever), NaN, a negative
#: number, a string (a numeric one too), a bool, and more than the longest timeout (1e9 s:
#: past what a socket's timeout or a deadline holds, it crashed with OverflowError).
BAD = [math.inf, -math.inf, -1, math.nan, "5", True, 1e10]

Wait = Callable[[Any, object], Any]
#: name -> (what to wait on, made from the controller (it may send: a move, a capture), the
#: wait given a timeout, the parameter the error names)
SyncCase = tuple[Callable[[galil.Controller], Any], Wait, str]
AsyncCase = tuple[Callable[[Any], Awaitable[Any]], Wait, str]


def _home(c: galil.Controller) -> Any:
    return c.A.home(switch=sim_of(c).home_switch("A"))


SYNC: dict[str, SyncCase] = {
    "move.wait": (lambda c: c.A.move_by(1000), lambda h, t: h.wait(t), "timeout"),
    "jog.wait": (lambda c: c.A.jog(1000), lambda h, t: h.wait(t), "timeout"),
    "home.wait": (_home, lambda h, t: h.wait(t), "timeout"),
    "vector.wait": (
        lambda c: c.vector_move("AB", [Line(1000, 500)], speed=40_000),
        lambda h, t: h.wait(t),
        "timeout",
    ),
    "programs.wait": (lambda c: c.programs, lambda p, t: p.wait(0, t), "timeout"),
    "io.wait_for_input": (lambda c: c.io, lambda io, t: io.wait_for_input(2, timeout=t), "timeout"),
    "capture.wait": (
        lambda c: c.capture(["_RPA"], every=2, count=10),
        lambda k, t: k.wait(t),
        "timeout",
    ),
    "records.get": (lambda c: c.records(8), lambda r, t: r.get(t), "timeout"),
    "records.take": (lambda c: c.records(8), lambda r, t: r.take(2, t), "timeout"),
    "messages.get": (lambda c: c.messages, lambda q, t: q.get(t), "timeout"),
    "interrupts.get": (lambda c: c.interrupts, lambda i, t: i.get(t), "timeout"),
    "contour": (lambda c: c, lambda c, t: c.contour("A", [1, 2], dt=1, timeout=t), "timeout"),
    "record": (lambda c: c, lambda c, t: c.record(timeout=t), "timeout"),
    "command": (lambda c: c, lambda c, t: c.command("MG 1", timeout=t), "timeout"),
    "save": (lambda c: c, lambda c, t: c.save(timeout=t), "timeout"),
    "watchdog": (lambda c: c, lambda c, t: c.watchdog(t), "watchdog timeout"),
    "sleep": (lambda c: c, lambda c, t: c.sleep(t), "seconds"),
}


async def _given(thing: T) -> T:
    return thing


async def _home_async(c: Any) -> Any:
    return await c.A.home(switch=sim_of(c.sync).home_switch("A"))


async def _watched(handle: Any, timeout: object) -> None:
    progress: AsyncIterator[Any] = handle.watch(timeout)
    async for _ in progress:
        pass


ASYNC: dict[str, AsyncCase] = {
    "move.wait": (lambda c: c.A.move_by(1000), lambda h, t: h.wait(t), "timeout"),
    "move.watch": (lambda c: c.A.move_by(1000), _watched, "timeout"),
    "jog.wait": (lambda c: c.A.jog(1000), lambda h, t: h.wait(t), "timeout"),
    "home.wait": (_home_async, lambda h, t: h.wait(t), "timeout"),
    "vector.wait": (
        lambda c: c.vector_move("AB", [Line(1000, 500)], speed=40_000),
        lambda h, t: h.wait(t),
        "timeout",
    ),
    "programs.wait": (lambda c: _given(c.programs), lambda p, t: p.wait(0, t), "timeout"),
    "io.wait_for_input": (
        lambda c: _given(c.io),
        lambda io, t: io.wait_for_input(2, timeout=t),
        "timeout",
    ),
    "capture.wait": (
        lambda c: c.capture(["_RPA"], every=2, count=10),
        lambda k, t: k.wait(t),
        "timeout",
    ),
    "records.get": (lambda c: c.records(8), lambda r, t: r.get(t), "timeout"),
    "records.take": (lambda c: c.records(8), lambda r, t: r.take(2, t), "timeout"),
    "records.batch": (lambda c: c.records(8), lambda r, t: r.batch(2, t), "timeout"),
    "messages.get": (lambda c: _given(c.messages), lambda q, t: q.get(t), "timeout"),
    "interrupts.get": (lambda c: _given(c.interrupts), lambda i, t: i.get(t), "timeout"),
    "contour": (_given, lambda c, t: c.contour("A", [1, 2], dt=1, timeout=t), "timeout"),
    "record": (_given, lambda c, t: c.record(timeout=t), "timeout"),
    "command": (_given, lambda c, t: c.command("MG 1", timeout=t), "timeout"),
    "save": (_given, lambda c, t: c.save(timeout=t), "timeout"),
    "watchdog": (_given, lambda c, t: c.watchdog(t), "watchdog timeout"),
    "sleep": (_given, lambda c, t: c.sleep(t), "seconds"),
}


def _verdict(error: BaseException | None, named: str) -> str | None:
    """What is wrong with how a bad timeout was met (``None``: refused as it should be)."""
    if error is None:
        return "accepted"
    if not isinstance(error, galil.InvalidArgument):
        return f"raised {error!r}"
    if named not in str(error):
        return f"the error does not name {named!r}: {error}"
    return None


def _refusals_sync(what: str, values: list[object]) -> dict[str, str]:
    """Each value of ``values`` that the sync wait ``what`` did not refuse, and how."""
    start, wait, named = SYNC[what]
    wrong: dict[str, str] = {}
    with simulated() as dmc:
        target = start(dmc)
        for timeout in values:
            error: BaseException | None = None
            try:
                with nothing_sent(dmc):  # refused before a byte
                    try:
                        wait(target, timeout)
                    except Exception as exc:
                        error = exc
            except AssertionError as exc:
                wrong[repr(timeout)] = str(exc)
                continue
            if (why := _verdict(error, named)) is not None:
                wrong[repr(timeout)] = why
    return wrong


def _refusals_async(what: str, values: list[object]) -> dict[str, str]:
    """Each value of ``values`` that the async wait ``what`` did not refuse, and how."""
    start, wait, named = ASYNC[what]
    wrong: dict[str, str] = {}

    async def body() -> None:
        async with await sim() as c:
            target = await start(c)
            for timeout in values:
                error: BaseException | None = None
                try:
                    with nothing_sent(c.sync):  # refused before a byte
                        try:
                            await wait(target, timeout)
                        except Exception as exc:
                            error = exc
                except AssertionError as exc:
                    wrong[repr(timeout)] = str(exc)
                    continue
                if (why := _verdict(error, named)) is not None:
                    wrong[repr(timeout)] = why

    run(body)
    return wrong


@pytest.mark.parametrize("what", sorted(SYNC.keys() | ASYNC.keys()))
def test_a_bad_wait_timeout_is_refused_alike_sync_and_async(what: str) -> None:
    sync = _refusals_sync(what, BAD) if what in SYNC else {}
    aio = _refusals_async(what, BAD) if what in ASYNC else {}
    assert (sync, aio) == ({}, {})


def test_every_sync_wait_has_its_async_twin_in_the_walk() -> None:
    # The async side has more (watch, batch); every sync wait is walked on both sides.
    assert SYNC.keys() <= ASYNC.keys()
    assert {name: SYNC[name][2] for name in SYNC} == {name: ASYNC[name][2] for name in SYNC}


def test_a_thread_wait_without_an_end_is_refused_sync_and_async() -> None:
    assert _refusals_sync("programs.wait", [None]) == {}
    assert _refusals_async("programs.wait", [None]) == {}


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


@pytest.mark.parametrize("value", [None, 0, *BAD])
def test_the_controllers_reply_timeout_refuses_what_no_reply_can_meet(value: object) -> None:
    # None kept the old value without a word; 0 and the wait's bad values are refused alike.
    with simulated() as dmc:
        before = dmc.timeout
        with pytest.raises(galil.InvalidArgument, match="timeout must be a finite number"):
            dmc.timeout = value  # type: ignore[assignment]
        assert dmc.timeout == before
        dmc.timeout = 2
        assert dmc.timeout == 2.0
