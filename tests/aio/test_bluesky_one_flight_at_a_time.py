"""One controller flies one path at a time (decisions 0096 and 0100).

The controller sends its data records to one ``DR`` stream. A flyer's ``kickoff()`` that finds
it taken is refused before anything moves, and the refusal says what a plan can do: wait for
the flight of the flyer that has it, or close the user's own ``records()`` stream; not the
advice a ``records()`` caller gets (poll with ``method='QR'``, a loop closes a stream).
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any

import numpy as np
import pytest

pytest.importorskip("ophyd_async")

from galil.bluesky import ContourPath, GalilContourFlyer, release_all
from galil.errors import InvalidArgument
from galil.sim.server import SimTcpServer
from galil.units import ureg

mm = ureg.mm


def _run(coro: Coroutine[Any, Any, None]) -> None:
    async def wrapped() -> None:
        try:
            await coro
        finally:
            await release_all()

    asyncio.run(asyncio.wait_for(wrapped(), 30))


def _flyers(url: str) -> tuple[GalilContourFlyer, GalilContourFlyer]:
    return (
        GalilContourFlyer(url, "A", name="flyA", scales={"A": 2000 / mm}),
        GalilContourFlyer(url, "B", name="flyB", scales={"B": 2000 / mm}),
    )


_PATH = np.linspace(0.1, 1.0, 16) * mm


def test_a_second_flyer_on_the_controller_is_told_to_wait_for_the_first_flights_complete() -> None:
    async def fly(url: str) -> None:
        first, second = _flyers(url)
        await first.connect()
        await second.connect()
        await first.prepare(ContourPath(_PATH, dt=3))
        await second.prepare(ContourPath(_PATH, dt=3))
        await first.kickoff()
        with pytest.raises(InvalidArgument) as caught:
            await second.kickoff()
        text = str(caught.value)
        assert text.startswith("flyer 'flyB' cannot kick off")
        assert "the flight of flyer 'flyA' has it" in text
        assert "one controller flies one path at a time" in text
        assert "complete()" in text
        assert "QR" not in text
        assert "for loop" not in text
        await first.complete()
        await second.kickoff()  # (the refusal left nothing behind: it flies now)
        await second.complete()

    with SimTcpServer(model="DMC-4040") as server:
        _run(fly(server.url))


def test_a_flyer_refused_for_the_users_records_stream_is_told_to_close_that_stream() -> None:
    async def fly(url: str) -> None:
        flyer, _ = _flyers(url)
        await flyer.connect()
        stream = await flyer.controller.records(64)
        await flyer.prepare(ContourPath(_PATH, dt=3))
        with pytest.raises(InvalidArgument) as caught:
            await flyer.kickoff()
        text = str(caught.value)
        assert text.startswith("flyer 'flyA' cannot kick off")
        assert "a records() stream of yours has it (<RecordStream DR every 64 samples" in text
        assert "close that stream" in text
        assert "QR" not in text
        await stream.close()
        await flyer.kickoff()
        await flyer.complete()

    with SimTcpServer(model="DMC-4040") as server:
        _run(fly(server.url))
