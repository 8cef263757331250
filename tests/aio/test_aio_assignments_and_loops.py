"""An async object refuses assignments (its settings are awaited ``set_`` methods), and a
controller connected on one event loop is read on another (decision 0091)."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil.sim.server import SimTcpServer
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def test_the_sync_idiom_on_an_async_axis_is_refused_and_names_the_awaited_setter() -> None:
    async def body() -> None:
        async with await sim() as c:
            x = c.A.set_scale(2000 / mm)
            before = len(commands_of(c))
            for name, value, setter in (
                ("soft_limits", (-5 * mm, 5 * mm), "set_soft_limits"),
                ("speed", 10 * mm / s, "set_speed"),
                ("kp", 8, "set_kp"),
            ):
                with pytest.raises(galil.GalilAttributeError) as info:
                    setattr(x, name, value)
                assert isinstance(info.value, AttributeError)
                assert f"`await x.{setter}(...)`" in str(info.value)
                assert info.value.suggestions == (setter,)
            with pytest.raises(galil.GalilAttributeError, match="set_switch_polarity"):
                c.switch_polarity = galil.SwitchPolarity(limit=1)  # type: ignore[assignment,method-assign]
            assert len(commands_of(c)) == before  # nothing was sent
            # The methods are not shadowed, and the limits the user meant are set the
            # awaited way: the move past them is refused.
            await x.set_soft_limits((-5 * mm, 5 * mm))
            with pytest.raises(galil.LimitError):
                await x.move_to(20 * mm)
            assert await c.switch_polarity() == galil.SwitchPolarity()

    run(body)


def test_a_misspelt_name_on_an_async_axis_suggests_the_setter_meant() -> None:
    async def body() -> None:
        async with await sim() as c:
            with pytest.raises(galil.GalilAttributeError) as info:
                c.A.soft_limit = (-5, 5)  # type: ignore[attr-defined]
            assert "set_soft_limits" in info.value.suggestions
            assert "did you mean 'set_soft_limits'" in str(info.value)
            assert "soft_limit" not in vars(c.A)

    run(body)


def _public(obj: object) -> list[str]:
    return [n for n in dir(type(obj)) if not n.startswith("_")]


def test_no_public_name_of_an_async_object_can_be_assigned_but_a_timeout() -> None:
    async def body() -> None:
        async with await sim() as c:
            x = c.A
            move = await x.move_by(1000)
            await move
            async with await c.records(32) as stream:
                objects: list[Any] = [
                    c, x, c.io, c.io.outputs, c.io.analog_in, c.programs, c.arrays,
                    c.variables, c.interrupts, c.messages, move, stream,
                ]  # fmt: skip
                for obj in objects:
                    for name in _public(obj):
                        if obj is c and name == "timeout":
                            continue
                        with pytest.raises(galil.GalilAttributeError):
                            setattr(obj, name, None)
                        assert name not in vars(obj), (obj, name)
            c.timeout = 2.5  # the one setting with no I/O: a property with a setter
            assert c.sync.timeout == 2.5
            x._mine = 1  # (a private name is the object's own business)

    run(body)


# -- a controller used on another event loop than the one it was connected on ----------------


def test_messages_of_a_controller_connected_in_an_earlier_asyncio_run_reach_the_next() -> None:
    c = run(sim)

    async def read() -> str:
        await c.programs.download('#A\nMG "hello"\nEN')
        await c.programs.run("#A")
        await c.programs.wait(0)
        async for line in c.messages:
            return line
        raise AssertionError("the messages ended")

    async def subscribed() -> list[tuple[str, bool]]:
        heard: list[tuple[str, bool]] = []
        me = asyncio.get_running_loop()

        def hear(line: str) -> None:
            heard.append((line, asyncio.get_running_loop() is me))

        await c.subscribe(hear)
        await c.programs.run("#A")
        await c.programs.wait(0)
        while not heard:
            await asyncio.sleep(0.01)
        return heard

    try:
        assert run(read) == "hello"
        assert run(subscribed) == [("hello", True)]  # called on the loop that subscribed
    finally:
        run(c.aclose)


def test_interrupts_of_a_controller_connected_in_an_earlier_asyncio_run_reach_the_next() -> None:
    with SimTcpServer(model="DMC-4040") as server:

        async def connect() -> aio.AsyncController:
            return await aio.connect(server.url, timeout=2.0)

        c = run(connect)

        async def interrupts() -> set[str]:
            await c.interrupts.enable("A")
            await (await c.move({"A": 300}))
            async for interrupt in c.interrupts:
                return {str(interrupt)}
            return set()

        try:
            assert run(interrupts) == {"axis A done"}
        finally:
            run(c.aclose)


def test_a_record_read_cancelled_as_its_loop_ends_leaves_the_next_loop_a_working_stream() -> None:
    c = run(sim)
    held = threading.Event()

    async def start() -> aio.AsyncRecordStream:
        stream = await c.records(32)
        # Every worker thread is held: the read's worker call is queued when its loop ends.
        for _ in range(4):
            c.worker.submit(held.wait, 10)
        reader = asyncio.ensure_future(stream.get())
        for _ in range(3):
            await asyncio.sleep(0)
        reader.cancel()
        return stream

    async def read(stream: aio.AsyncRecordStream) -> int:
        return int((await stream.get(5.0))["time"])

    try:
        stream = run(start)
        held.set()
        assert run(lambda: read(stream)) >= 0  # a record, on the new loop
        run(stream.close)
    finally:
        held.set()
        run(c.aclose)
