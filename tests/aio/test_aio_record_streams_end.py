"""The async record streams end and refuse as the sync ones do (decision 0096): a second
``DR`` stream is refused while one is open, an ``async for`` left early closes its stream,
and a take the host cannot hold is refused before a record is read."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from aio_helpers import run, sim
from concurrency import handles_closed

import galil.aio as aio
from galil.errors import InvalidArgument
from galil.records import TAKE_MAX
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer


def test_a_second_async_dr_stream_is_refused_while_one_is_open() -> None:
    async def body() -> None:
        with SimTcpServer(SimController("DMC-4040", ManualClock())) as srv:
            async with await aio.connect(srv.url, timeout=2.0) as c:
                first = await c.records(8)
                with pytest.raises(InvalidArgument, match="one DR record stream"):
                    await c.records(16)
                assert await c.query_number("MG _DR") == 8
                srv.advance(0.05)
                assert np.all(np.diff((await first.take(3, timeout=5))["time"]) == 8)
                await first.close()
                async with await c.records(16) as second:
                    assert second.method == "DR"

    run(body)


def test_an_async_for_left_early_closes_its_stream() -> None:
    async def body() -> None:
        with SimTcpServer(SimController("DMC-4040", RealTimeClock())) as srv:
            async with await aio.connect(srv.url, timeout=2.0) as c:
                for _ in range(8):  # more than the handles the controller has left
                    stream = await c.records(8)
                    async for _ in stream:
                        break
                    for _ in range(500):  # the loop's iterator is closed on the event loop
                        if stream.closed:
                            break
                        await asyncio.sleep(0.01)
                    assert stream.closed
                assert await c.query_number("MG _DR") == 0
                handles_closed(srv.controller, 2)

    run(body)


def test_an_async_take_too_large_for_the_host_is_refused_before_a_record_is_read() -> None:
    async def body() -> None:
        async with await sim() as c, await c.records(4) as stream:
            with pytest.raises(InvalidArgument, match="cannot be allocated"):
                await stream.take(TAKE_MAX)
            first, second = (await stream.take(2))["time"].tolist()
            assert second - first == 4
            assert stream.missed == 0

    run(body)
