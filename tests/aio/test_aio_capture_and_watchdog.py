"""The awaited capture and watchdog behave as their sync twins: a wait's timeout, an upload that
fails at the end of a block, a capture on a real-time link, what they report about themselves.
"""

from __future__ import annotations

import asyncio
import threading
import time

import pytest
from aio_helpers import run, sim

import galil
import galil.aio as aio
from galil.sim.server import SimTcpServer
from galil.testing import sim_of, simulated


def test_a_capture_wait_that_times_out_raises_at_its_timeout_and_recording_goes_on() -> None:
    # The async wait slept until the recording's end (2 s) whatever its timeout and then
    # returned the whole recording; the sync wait raised at the timeout.
    with simulated() as dmc:
        cap = dmc.capture(["_RPA"], every=8, seconds=2.0)
        t0 = dmc.link.clock()
        with pytest.raises(galil.GalilTimeoutError, match=r"still records after 0\.1 s"):
            cap.wait(0.1)
        sync_waited = dmc.link.clock() - t0
        assert not cap.done
        assert len(cap.wait()["_RPA"]) == cap.count  # it went on

    async def body() -> None:
        async with await sim() as c:
            cap = await c.capture(["_RPA"], every=8, seconds=2.0)
            t0 = c.sync.link.clock()
            with pytest.raises(galil.GalilTimeoutError, match=r"still records after 0\.1 s"):
                await cap.wait(0.1)
            assert c.sync.link.clock() - t0 == pytest.approx(sync_waited, abs=0.02)
            assert not await cap.done()
            with pytest.raises(galil.GalilTimeoutError):
                await cap.wait(0)
            recording = await cap.wait()
            assert len(recording["_RPA"]) == cap.count
            assert await cap.wait() is recording  # uploaded once

    run(body)


def test_an_async_capture_reports_what_its_sync_capture_does() -> None:
    async def body() -> None:
        async with await sim() as c:
            cap = await c.capture(["_RPA", "_TPA"], every=4, count=20)
            sync = cap.sync
            assert cap.sources == ("_RPA", "_TPA")
            assert (cap.every, cap.count) == (4, 20)
            assert cap.duration == pytest.approx(19 * 4 * c.sync.link.sample_period)
            assert cap.start_sample == sync.start_sample is not None
            assert cap.result is None
            assert repr(cap) == f"<AsyncCapture of {sync!r}>"
            assert "recording" in repr(cap)
            recording = await cap.wait()
            assert cap.result is recording
            assert "uploaded" in repr(cap)
            assert await cap.done()

    run(body)


def _lose_the_arrays(dmc: galil.Controller) -> None:
    dmc.command("RC 0")
    dmc.command("DA *[]")  # the upload at the end of the block then fails


def _block(dmc: galil.Controller, error: Exception | None) -> None:
    with dmc.capture(["_RPA"], count=500):
        _lose_the_arrays(dmc)
        if error is not None:
            raise error


async def _async_block(c: aio.AsyncController, error: Exception | None) -> None:
    async with await c.capture(["_RPA"], count=500):
        _lose_the_arrays(c.sync)
        if error is not None:
            raise error


def test_a_capture_whose_upload_fails_at_the_end_of_a_block_says_so() -> None:
    # ... unless the block raised: its own exception matters more.
    with simulated() as dmc:
        with pytest.raises(galil.GalilError, match="no array 'gcap0'"):
            _block(dmc, None)
        with pytest.raises(ValueError, match="the block's own"):
            _block(dmc, ValueError("the block's own"))

    async def body() -> None:
        async with await sim() as c:
            with pytest.raises(galil.GalilError, match="no array 'gcap0'"):
                await _async_block(c, None)
            with pytest.raises(ValueError, match="the block's own"):
                await _async_block(c, ValueError("the block's own"))

    run(body)


def test_a_capture_on_a_real_time_link_is_awaited_with_the_loop_free() -> None:
    async def body() -> None:
        with SimTcpServer(model="DMC-4040") as srv:
            async with await aio.connect(srv.url) as c:
                assert not c.sync.link.simulated_time
                ticks = 0

                async def tick() -> None:
                    nonlocal ticks
                    while True:
                        ticks += 1
                        await asyncio.sleep(0.005)

                ticker = asyncio.create_task(tick())
                cap = await c.capture(["_RPA"], every=2, count=40)  # 78 ms
                recording = await cap.wait()
                ticker.cancel()
                assert len(recording["_RPA"]) == 40
                assert recording.start == cap.start_sample
                assert ticks >= 3  # the loop ran while the capture recorded

    run(body)


def test_an_async_watchdog_reports_its_heartbeat() -> None:
    async def body() -> None:
        async with await sim() as c:
            async with await c.watchdog(0.5) as dog:
                assert dog.interval == dog.sync.interval > 0
                assert dog.interval < dog.timeout
                assert dog.beating
                assert repr(dog) == f"<AsyncWatchdog of {dog.sync!r}>"
                assert "beating" in repr(dog)
            assert not dog.beating
            assert "stopped" in repr(dog)

    run(body)


def test_a_loop_watch_times_only_its_own_thread_and_refuses_a_second_watch() -> None:
    original = asyncio.Handle._run
    other_steps: list[int] = []

    def other_loop() -> None:
        async def steps() -> None:
            await asyncio.sleep(0)
            time.sleep(0.2)  # one slow step of the other loop: not this watch's
            other_steps.append(1)

        asyncio.run(steps())

    async def body() -> aio.LoopWatch:
        with aio.watch_loop() as watch:
            assert watch.percentile(50) == 0.0  # nothing timed yet
            with pytest.raises(RuntimeError, match="already watched"), aio.watch_loop():
                pass
            worker = threading.Thread(target=other_loop)
            worker.start()
            while worker.is_alive():
                await asyncio.sleep(0.001)
            worker.join()
        return watch

    watch = run(body)
    assert asyncio.Handle._run is original  # unwrapped once no loop is watched
    assert other_steps == [1]
    assert watch.steps > 0
    assert watch.max_wall < 0.2  # this loop's steps only
    assert 0 < watch.percentile(50) <= watch.percentile(100) == watch.max_wall
    assert watch.percentile(50, cpu=True) <= watch.max_cpu
    summary = watch.summary()
    assert summary.startswith(f"{watch.steps} loop steps: wall p50 ")
    assert f"max {watch.max_wall * 1e6:.0f} us" in summary


def test_an_async_capture_left_by_a_dead_link_is_stopped_when_the_link_is_reopened() -> None:
    # The block's stop could not go out (decision 0085): the controller recorded on after
    # reconnect(), into arrays nobody was to read, and the next capture was refused.
    async def body() -> None:
        async with await sim() as c:
            simulator = sim_of(c.sync)
            await c.A.jog(20_000)
            started: list[aio.AsyncCapture] = []

            async def block() -> None:
                async with await c.capture(["_RPA"], count=2000) as cap:
                    started.append(cap)
                    await c.sleep(0.5)
                    transport = c.sync.link.transport
                    assert transport is not None
                    transport.close()  # the cable is pulled: the block's stop cannot go out
                    await c.command("MG 1")

            with pytest.raises(galil.GalilConnectionError):
                await block()
            cap = started[0]
            await c.reconnect()
            assert await c.query_operands(["_RC"]) == [0]
            assert not cap.stop_pending
            with pytest.raises(galil.InvalidArgument, match="stopped"):
                await cap.wait()
            recording = await cap.stop()
            assert 200 < len(recording) < 2000  # (0.5 s of 4)
            assert recording["_RPA"][-1] > 0  # recorded, not the arrays' unrecorded zeros
            assert len(await (await c.capture(["_RPA"], count=10)).wait()) == 10
            await c.stop()
            simulator.advance(0.5)

    run(body)


def test_an_async_watchdog_on_another_thread_replaces_the_running_one() -> None:
    async def body() -> tuple[bool, bool, list[float]]:
        async with await sim() as c:
            first = await c.watchdog(0.5, thread=6)
            async with await c.watchdog(2.0) as second:
                threads = await c.query_operands(["_XQ6", "_XQ7"])
                return first.beating, second.beating, threads

    first, second, threads = run(body)
    assert not first
    assert second
    assert threads[0] == -1  # the first's routine halted on its thread
    assert threads[1] >= 0
