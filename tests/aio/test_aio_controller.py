"""galil.aio against in-process simulators (manual clock): the sync vocabulary, awaited.

Every wait lets simulated time pass (the worker pauses the simulator's clock), so nothing here
sleeps for motion; a cancellation while a command is on its way is made deterministic by a wire
hook that holds the worker inside the write until the test has cancelled.
"""

from __future__ import annotations

import asyncio
import gc
import itertools
import queue
import re
import threading
import time
import types
from typing import Any

import numpy as np
import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil.aio import probe
from galil.controller import Controller
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.proxy import FaultProxy
from galil.sim.server import SimTcpServer
from galil.testing import sim_of
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def test_commands_and_queries_are_awaited() -> None:
    async def body() -> None:
        async with await sim() as c:
            assert await c.query_number("MG 1+2") == 3.0
            await c.command("SHA")
            assert await c.A.motor_on()
            assert await c.query_operands(["_TPA", "_TPB"]) == [0.0, 0.0]
            assert c.model.name == "DMC-4040"

    run(body)


@pytest.mark.parametrize(
    ("model", "name", "says"),
    [
        ("DMC-4040", "E", "DMC-4040 has axes A, B, C, D"),
        ("DMC-4040", "a", "DMC-4040 has axes A, B, C, D"),
        ("RIO-47120", "A", "RIO-47120 is an I/O controller with no axes"),
    ],
)
def test_a_wrong_axis_attribute_lists_the_axes_as_the_sync_controller_does(
    model: str, name: str, says: str
) -> None:
    async def body() -> None:
        async with await sim(model) as c:
            with pytest.raises(AttributeError, match=says):
                getattr(c, name)
            with pytest.raises(AttributeError, match=says):
                getattr(c.sync, name)
            assert not hasattr(c, "nothing_of_that_name")

    run(body)


def test_a_twin_keeps_the_sync_methods_documentation() -> None:
    assert aio.AsyncController.command.__doc__ == Controller.command.__doc__
    assert aio.AsyncAxis.move_to.__doc__ == galil.Axis.move_to.__doc__


def test_a_move_knows_its_prediction_and_awaiting_it_compares_the_end() -> None:
    async def body() -> None:
        async with await sim() as c:
            x = c.A.set_scale(2000 / mm)
            await x.set_speed(20 * mm / s)
            move = await x.move_to(5 * mm)
            assert move.duration == pytest.approx(0.40625)  # known before it ends
            assert not move.finished
            result = await move
            assert result.final == {"A": 10000}
            assert result.deviation == {"A": 0}
            assert await x.reference_position() == 5 * mm
            assert await move.done()

    run(body)


def test_progress_comes_from_the_prediction_in_user_units() -> None:
    async def body() -> list[aio.MoveProgress]:
        async with await sim() as c:
            x = c.A.set_scale(2000 / mm)
            await x.set_speed(20 * mm / s)
            move = await x.move_to(5 * mm)
            return [p async for p in move.watch()]

    seen = run(body)
    assert len(seen) > 3
    assert all(p.units == {"A": "mm"} for p in seen)
    elapsed = [p.elapsed for p in seen]
    assert elapsed == sorted(elapsed)
    remaining = [p.remaining for p in seen]
    assert remaining == sorted(remaining, reverse=True)
    positions = [p.positions["A"] for p in seen]
    assert positions == sorted(positions)
    assert 0 <= positions[0] < positions[-1] <= 5.0
    assert seen[-1].fraction is not None
    assert seen[-1].fraction > 0.5


def test_cancelling_the_task_that_awaits_a_move_stops_the_axis() -> None:
    async def body() -> None:
        async with await sim() as c:
            x = c.A
            move = await x.move_to(200_000)
            waiting = asyncio.ensure_future(move.wait())
            await c.sleep(0.05)  # simulated time: the move is under way
            waiting.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiting
            assert any(t.startswith("ST") for t in commands_of(c))  # before the cancel ended
            assert (await x.stop_code())[0] == 4
            result = await move  # the stop, as predicted
            assert result.final["A"] < 200_000
            assert result.deviation == {"A": 0}

    run(body)


def test_cancelling_while_a_move_is_being_sent_stops_it_once_it_started() -> None:
    async def body() -> None:
        async with await sim() as c:
            loop = asyncio.get_running_loop()
            writing = asyncio.Event()  # the worker is writing the line with the move's BG
            stop_sent = asyncio.Event()
            go_on = threading.Event()  # lets that write go on

            def hook(direction: str, data: bytes) -> None:
                # Runs on the worker thread, under the link's lock, before the bytes go out.
                if direction != "out":
                    return
                if re.search(rb"(^|;)BG", data) and not go_on.is_set():
                    loop.call_soon_threadsafe(writing.set)
                    go_on.wait(timeout=10)  # bounded: a broken test fails, never hangs
                if re.search(rb"(^|;)ST", data):
                    loop.call_soon_threadsafe(stop_sent.set)

            remove = c.wire_log.add(hook)
            task = asyncio.ensure_future(c.A.move_to(100_000))
            await writing.wait()
            task.cancel()
            await asyncio.sleep(0.01)  # the cancel lands while the write is held...
            go_on.set()  # ...which then goes on (the task ends once the line is sent: it
            with pytest.raises(asyncio.CancelledError):  # waited the hook's 10 s before)
                await task
            await stop_sent.wait()  # the stop follows the move on a worker thread
            remove()
            await c.sleep(2.0)  # through the link's lock: after the stop's whole exchange
            assert not await c.A.moving()
            assert await c.A.reference_position() < 100_000
            sent = commands_of(c)
            begin = next(i for i, t in enumerate(sent) if re.search(r"(^|;)BG", t))
            stop = next(i for i, t in enumerate(sent) if re.search(r"(^|;)ST", t))
            assert begin < stop

    run(body)


def test_a_jog_runs_until_stopped_and_cancelling_its_waiter_stops_it() -> None:
    async def body() -> None:
        async with await sim() as c:
            jog = await c.A.jog(5000)
            assert jog.duration == float("inf")
            waiter = asyncio.ensure_future(jog.wait())
            await c.sleep(0.2)
            assert not waiter.done()
            waiter.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiter
            await jog  # stopped: it ends
            assert (await c.A.stop_code())[0] == 4

    run(body)


def test_the_motion_guard_stops_the_axes_when_the_block_fails() -> None:
    async def body() -> None:
        async with await sim() as c:

            async def fail_while_moving() -> None:
                async with c.motion("A"):
                    await c.A.move_to(100_000)
                    await c.sleep(0.05)
                    raise RuntimeError("boom")

            with pytest.raises(RuntimeError, match="boom"):
                await fail_while_moving()
            assert not await c.A.moving()
            assert (await c.A.stop_code())[0] == 4

    run(body)


def test_a_contour_runs_from_a_coroutine() -> None:
    async def body() -> galil.ContourResult:
        async with await sim() as c:
            c.A.set_scale(1000 / mm)
            result = await c.contour("A", np.linspace(0, 2, 40) * mm, dt=3)
            assert await c.A.reference_position() == 2 * mm
            return result

    result = run(body)
    assert result.increments.sum() == 2000


def test_cancelling_a_contour_stops_its_axes() -> None:
    async def body() -> None:
        async with await sim() as c:
            task = asyncio.ensure_future(c.contour("A", np.arange(1, 401) * 50.0, dt=4))
            for _ in range(2000):  # the worker starts it; a deadline, not an endless poll
                if await c.A.moving():
                    break
                await asyncio.sleep(0.001)
            assert await c.A.moving()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            assert any(t.startswith("ST") for t in commands_of(c))
            await c.sleep(0.5)
            assert not await c.A.moving()
            assert await c.A.reference_position() < 400 * 50

    run(body)


def test_records_arrive_as_an_async_iterator_one_period_apart() -> None:
    async def body() -> list[int]:
        async with await sim() as c:
            samples = []
            async with await c.records(64) as stream:
                assert stream.method == "QR"
                async for rec in stream:
                    samples.append(int(rec["sample"]))
                    if len(samples) == 4:
                        break
                more = await stream.take(2)
            return [*samples, *more["sample"].tolist()]

    samples = run(body)
    assert np.diff(samples).tolist() == [64] * 5


def test_messages_arrive_as_an_async_iterator_and_reach_subscribers_on_the_loop() -> None:
    async def body() -> None:
        async with await sim() as c:
            loop_thread = threading.current_thread()
            seen: list[tuple[str, threading.Thread]] = []
            unsubscribe = await c.subscribe(lambda m: seen.append((m, threading.current_thread())))
            sim_of(c.sync).emit_message("hello")
            await c.command("MG 1")  # the line is read with the next exchange
            assert await c.messages.get(timeout=5) == "hello"
            await asyncio.sleep(0.01)
            assert seen == [("hello", loop_thread)]
            unsubscribe()
            sim_of(c.sync).emit_message("again")
            await c.command("MG 1")
            async for line in c.messages:
                assert line == "again"
                break
            with pytest.raises(queue.Empty):
                await c.messages.get(timeout=0.01)

    run(body)


def test_refusals_surface_as_the_sync_errors() -> None:
    async def body() -> None:
        async with await sim() as c:
            c.A.set_scale(2000 / mm)
            with pytest.raises(galil.InvalidArgument):
                await c.A.move_to(5)  # a bare number on a scaled axis
            with pytest.raises(galil.CommandError):
                await c.command("XYZZY")

    run(body)


def test_bad_wait_timeouts_are_refused_before_waiting() -> None:
    async def body() -> None:
        async with await sim() as c:
            move = await c.A.move_by(1000)
            for bad in (float("inf"), float("nan"), -1, True, "1"):
                with pytest.raises(galil.InvalidArgument, match="timeout"):
                    await move.wait(timeout=bad)  # type: ignore[arg-type]
            assert (await move.wait()).stop_codes == {"A": 1}
            for bad in (float("nan"), -1, True, "1"):
                with pytest.raises(galil.InvalidArgument, match="timeout"):
                    await c.messages.get(timeout=bad)  # type: ignore[arg-type]
            with pytest.raises(queue.Empty):
                await c.messages.get(timeout=0)

    run(body)


def test_an_async_queue_wait_that_times_out_is_a_galil_timeout_error_and_a_queue_empty() -> None:
    async def body() -> None:
        async with await sim() as c:
            stream = await c.records(32)
            await stream.get()  # (the first record is due at once: the next, 32 samples on)
            for get in (c.messages.get, c.interrupts.get, stream.get):
                with pytest.raises(galil.QueueTimeoutError) as info:
                    await get(timeout=0)
                assert isinstance(info.value, queue.Empty)
                assert isinstance(info.value, galil.GalilTimeoutError)
            with pytest.raises(galil.QueueTimeoutError):
                c.messages.get_nowait()
            await stream.close()

    run(body)


def test_closing_ends_the_worker_threads_and_further_calls_fail() -> None:
    async def body() -> None:
        c = await sim()
        threads = c.worker.threads
        assert all(t.is_alive() for t in threads)
        await c.aclose()
        await c.aclose()  # idempotent
        for t in threads:
            t.join(5)
        assert not any(t.is_alive() for t in threads)
        with pytest.raises(galil.GalilConnectionError):
            await c.command("MG 1")

    run(body)


def test_the_loop_watch_sees_a_blocking_callback() -> None:
    async def body() -> aio.LoopWatch:
        with aio.watch_loop() as watch:
            await asyncio.sleep(0)
            time.sleep(0.005)  # a blocking call inside a coroutine step
            await asyncio.sleep(0)
        return watch

    watch = run(body)
    assert watch.max_wall >= 0.005
    assert watch.max_own_cpu < 0.004  # sleeping is not work
    assert watch.over(0.004) == 1
    assert "body" in watch.slowest


def test_the_loop_watch_reads_a_callbacks_cpu_time_inside_its_wall_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Clocks that move only between readings, one tick per reading: what happens between the
    # last readings (on a shared machine the CPU clock's own system call, or an interrupt,
    # once more than the callback's whole wall time) must not count as the callback's CPU.
    ticks = itertools.count()
    clocks = types.SimpleNamespace(
        perf_counter=lambda: float(next(ticks)), thread_time=lambda: float(next(ticks))
    )
    monkeypatch.setattr(probe, "time", clocks)

    async def body() -> aio.LoopWatch:
        with aio.watch_loop() as watch:
            for _ in range(3):
                await asyncio.sleep(0)
        return watch

    watch = run(body)
    assert watch.steps >= 3
    assert all(cpu < wall for cpu, wall in zip(watch.cpu, watch.wall, strict=True))


def test_timing_a_callback_costs_the_same_however_many_were_timed_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    scanned = 0

    def counting_max(values: Any, **kwargs: Any) -> Any:
        nonlocal scanned
        values = list(values)
        scanned += len(values)
        return max(values, **kwargs)

    monkeypatch.setattr(probe, "max", counting_max, raising=False)
    watch = aio.LoopWatch()
    loop = asyncio.new_event_loop()
    try:
        handle = loop.call_soon(print)
        for i in range(2000):
            watch._record(float(i % 7), 0.0, handle)
        handle.cancel()
    finally:
        loop.close()
    assert scanned < 2000  # not the whole history at each callback (2 million values)
    assert watch.max_wall == 6.0
    assert watch.slowest


def test_the_loop_watch_tells_garbage_collection_from_a_callbacks_work() -> None:
    async def body() -> aio.LoopWatch:
        with aio.watch_loop() as watch:
            await asyncio.sleep(0)
            junk = [[i] for i in range(200_000)]
            for a, b in itertools.pairwise(junk):
                a.append(b)  # many objects in cycles-capable containers
            gc.collect()
            await asyncio.sleep(0)
        return watch

    watch = run(body)
    assert max(watch.gc) > 0
    assert watch.max_own_cpu < watch.max_cpu


async def _busy(c: aio.AsyncController, letter: str, n: int) -> list[Any]:
    """Moves one axis back and forth and reads it between moves."""
    axis = c.axis(letter)
    out = []
    for i in range(n):
        move = await axis.move_to(2000 * (i % 2 + 1))
        await move
        out.append(await axis.reference_position())
        out.append(await c.query_operands([f"_TP{letter}", f"_SC{letter}"]))
    return out


def test_four_controllers_in_one_loop_never_block_it_for_a_millisecond() -> None:
    async def body() -> tuple[aio.LoopWatch, list[Any]]:
        controllers = await asyncio.gather(*(sim() for _ in range(4)))
        try:
            for c in controllers:
                for a in "AB":
                    await c.axis(a).set_speed(100_000)
            with aio.watch_loop() as watch:
                results = await asyncio.gather(
                    *(_busy(c, a, 6) for c in controllers for a in "AB"),
                    *(c.records(32) for c in controllers),
                )
                streams = results[8:]
                for stream in streams:
                    await stream.take(5)
                    await stream.close()
        finally:
            await asyncio.gather(*(c.aclose() for c in controllers))
        return watch, results[:8]

    watch, results = run(body)
    for moves in results:
        assert moves[0::2] == [2000, 4000] * 3  # every move arrived, 6 per axis
    assert watch.steps > 200
    # The loop thread's own work per callback (CPU time: what blocking means, free of the
    # OS's and the GIL's scheduling on a shared machine, and of the garbage collector's pauses
    # of the whole process).
    assert watch.max_own_cpu < 1e-3, watch.summary() + " " + watch.slowest


def test_an_async_message_wait_raises_once_the_link_dies_and_the_iteration_says_so() -> None:
    async def body() -> None:
        async with await sim() as c:
            waiting = asyncio.ensure_future(c.messages.get(timeout=20))
            await asyncio.sleep(0.05)  # (the wait begins)
            c.sync.transport.close()  # the link dies under the poll of the idle link
            with pytest.raises(galil.GalilConnectionError, match="link died"):
                await asyncio.wait_for(waiting, 5)
            with pytest.raises(galil.GalilConnectionError, match="link died"):
                async for _ in c.messages:  # not an end as if all were well
                    pass

    run(body)


def test_an_async_message_wait_on_a_link_that_dies_reconnects_with_reconnect_on() -> None:
    async def body() -> str:
        policy = galil.ReconnectPolicy(attempts=3, delay=0.01)
        async with await aio.connect("sim://DMC-4040", reconnect=policy) as c:
            waiting = asyncio.ensure_future(c.messages.get(timeout=20))
            await asyncio.sleep(0.05)
            old = c.sync.transport
            old.close()  # the link dies; the waiting get() alone finds it out
            for _ in range(500):
                if c.sync.transport is not old and not c.sync.link.dead:
                    break
                await asyncio.sleep(0.01)  # (a thread's work, not motion)
            sim_of(c.sync).emit_message("after the reconnect")
            return await asyncio.wait_for(waiting, 5)

    assert run(body) == "after the reconnect"


def test_a_polled_record_read_cancelled_mid_poll_leaves_no_duplicate_for_the_next_read() -> None:
    """A get() cancelled (a timeout) while its QR is on the wire: the next get() waits for
    that poll rather than polling beside it, and the records stay one period apart."""

    async def body() -> list[int]:
        async with await sim() as c, await c.records(32) as stream:
            loop = asyncio.get_running_loop()
            writing = asyncio.Event()
            go_on = threading.Event()

            def hook(direction: str, data: bytes) -> None:
                if direction == "out" and b"QR" in data and not go_on.is_set():
                    loop.call_soon_threadsafe(writing.set)
                    go_on.wait(timeout=10)  # bounded: a broken test fails, never hangs

            remove = c.wire_log.add(hook)
            task = asyncio.ensure_future(stream.get())
            await writing.wait()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            nxt = asyncio.ensure_future(stream.get())
            await asyncio.sleep(0.05)  # (not motion: time for a second poll to begin, if any)
            go_on.set()
            first = await nxt
            remove()
            rest = await stream.take(3)
            assert stream.sync.missed == 0
            return [int(first["time"]), *rest["time"].tolist()]

    assert np.diff(run(body)).tolist() == [32] * 3


def test_an_async_loop_over_a_record_stream_whose_link_dies_raises() -> None:
    async def body() -> None:
        sim_controller = SimController("DMC-4040", RealTimeClock())
        with SimTcpServer(sim_controller) as server, FaultProxy(server.address) as proxy:
            async with await aio.connect(proxy.url, timeout=1.0) as c:
                stream = await c.records(16, method="DR")

                async def pull_after_three() -> None:
                    n = 0
                    async for _ in stream:
                        n += 1
                        if n == 3:
                            proxy.cut()

                with pytest.raises(galil.GalilConnectionError):
                    await pull_after_three()
                assert not stream.closed
                await stream.close()
                async for _ in stream:  # closed by the user: the loop just ends
                    raise AssertionError("a record from a closed stream")

    run(body)


def test_an_async_controller_dropped_unclosed_warns_and_closes_its_link_and_threads() -> None:
    with SimTcpServer(SimController("DMC-4040", ManualClock())) as server:
        gc.collect()  # what earlier tests left to the collector
        before = set(threading.enumerate())

        async def session() -> None:
            c = await aio.connect(server.url, timeout=2.0)
            await c.query_number("MG 1")  # and no aclose()

        def drop_two() -> None:
            for _ in range(2):
                asyncio.run(session())
            gc.collect()

        with pytest.warns(ResourceWarning, match=r"never closed: await aclose\(\)") as seen:
            drop_two()
        said = [str(w.message) for w in seen]
        assert sum("AsyncController" in m for m in said) == 2
        assert not any("call close()" in m for m in said)  # (the sync ones say nothing more)
        for t in set(threading.enumerate()) - before:
            t.join(5)  # the workers, the readers, and the threads that close them
        assert sorted(t.name for t in set(threading.enumerate()) - before) == []


def test_an_async_record_stream_reads_out_what_its_sync_stream_counts() -> None:
    async def body() -> None:
        async with await sim() as c, await c.records(32) as stream:
            seen: list[int] = []
            unsubscribe = await stream.subscribe(lambda rec: seen.append(int(rec["time"])))
            got = [int((await stream.get())["time"])]
            await c.sleep(0.2)  # a poll comes late: records missed
            got += (await stream.take(2))["time"].tolist()
            await asyncio.sleep(0)  # (the callbacks come through the loop)
            unsubscribe()
            assert seen == got
            assert stream.missed == stream.sync.missed > 0
            assert stream.gaps == stream.sync.gaps == [(got[1], stream.missed)]
            assert stream.period_seconds == pytest.approx(32 * c.sync.link.sample_period)
            assert len(stream) == 0

    run(body)


@pytest.mark.parametrize("how", ["axis", "controller", "handle", "abort"])
def test_a_stop_does_not_queue_behind_calls_that_hold_every_worker_thread(how: str) -> None:
    """Every worker thread busy (a long wait for an input, a record read: here calls that
    block until released) and a stop still goes out at once, on the stops' own lane; before,
    it waited for a thread (0.4 s behind input waits, for ever behind these)."""

    async def body() -> list[str]:
        c = await aio.connect("sim://DMC-4040", threads=2)
        release = threading.Event()
        move = await c.A.jog(20_000)
        busy = [asyncio.ensure_future(c.worker.run(release.wait, 10)) for _ in range(2)]
        await asyncio.sleep(0.05)  # (both threads now hold a call that waits for release)
        try:
            stop = {
                "axis": c.A.stop,
                "controller": c.stop,
                "handle": move.stop,
                "abort": c.abort,
            }[how]
            await asyncio.wait_for(stop(), 5)
            assert not release.is_set()  # the stop went out while both threads were held
        finally:
            release.set()
            await asyncio.gather(*busy)
        sent = commands_of(c)
        await c.aclose()
        return sent

    sent = run(body)
    assert ("AB" if how == "abort" else "ST") in " ".join(sent[-4:])
