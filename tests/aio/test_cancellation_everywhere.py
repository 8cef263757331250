"""Every awaitable of galil.aio, cancelled at each point where it waits (decision 0027).

A cancel point is the Nth call an operation hands to its controller's worker, cancelled
either while the call is **queued** (every worker thread is held busy until the cancelled
task has ended or asks for another call) or while it is **running** (the call is held on its
thread, before it starts its work, until the task has ended: what the cancellation does at
once happens before the call does its work); over TCP, inside the Nth write
to the link. Each point is also reached by an ``asyncio.timeout`` that expires there. The
points are counted on an uncancelled run of the same operation first, so every call is a
cancel point (the first few of each operation, and its last).

After each cancellation:

- ``CancelledError`` (``TimeoutError`` for the timeout) reaches the caller;
- everything the operation left running ends within one second of controller time (the
  simulator's manual clock: what it left running is what makes that clock move), and no axis
  it started moves then; an operation documented to go on (a program, a capture, a watch
  with ``stop_on_cancel=False``) goes on and is stopped by the test;
- the link answers in step (``MG 1`` then ``MG 2``);
- the controller closes, its worker threads end and no task is left on the loop.
"""

from __future__ import annotations

import asyncio
import queue
import sys
import threading
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil import Line
from galil.aio._worker import Worker
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import sim_of

needs_timeout = pytest.mark.skipif(sys.version_info < (3, 11), reason="asyncio.timeout: 3.11+")

HOW = ["cancel", pytest.param("timeout", marks=needs_timeout)]
MODES = ["queued", "running"]
#: Controller time everything a cancelled operation left behind may take to end.
SETTLE = 1.0


class Trap:
    """Counts the calls submitted to a worker from the loop; cancels the awaiting task at
    the ``n``-th (``n=0``: only counts). Every future submitted meanwhile is kept, so the
    test can wait for what the cancellation left on the threads (:meth:`settle`)."""

    def __init__(self, worker: Worker, link: Any, n: int = 0, mode: str = "queued") -> None:
        self.worker, self.link, self.n, self.mode = worker, link, n, mode
        self.real = worker.submit
        self.real_urgent = worker.submit_urgent
        self.loop = asyncio.get_running_loop()
        self.loop_thread = threading.current_thread()
        self.count = 0
        self.fired = False
        self.fired_at: float | None = None  # controller clock when the cancel was asked
        self.gate = threading.Event()
        self.futures: list[Any] = []
        self.cancel: Callable[[], object] = lambda: None
        worker.submit = self.submit  # type: ignore[method-assign]
        worker.submit_urgent = self.submit_urgent  # type: ignore[method-assign]

    def watch(self, task: asyncio.Future[Any], cancel: Callable[[], object]) -> None:
        self.cancel = cancel
        task.add_done_callback(lambda _: self.gate.set())

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        return self._submit(self.real, fn, *args, **kwargs)

    def submit_urgent(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        """A call on the stops' own lane: counted and trapped as any other."""
        return self._submit(self.real_urgent, fn, *args, **kwargs)

    def _submit(
        self, real: Callable[..., Any], fn: Callable[..., Any], /, *args: Any, **kwargs: Any
    ) -> Any:
        on_loop = threading.current_thread() is self.loop_thread
        if on_loop and not self.fired:
            self.count += 1
        if self.fired and self.mode != "running":
            self.gate.set()  # a call made after the cancel: the held threads go on
        if not on_loop or self.fired or self.count != self.n:
            future = real(fn, *args, **kwargs)
            self.futures.append(future)
            return future
        self.fired = True
        if self.mode == "queued":
            # Every thread held (the stops' lane too): the call queues behind them.
            self.fired_at = self.link.clock()
            for _ in self.worker.threads[:-1]:
                self.futures.append(self.real(self.gate.wait, 10))
            self.futures.append(self.real_urgent(self.gate.wait, 10))
            future = real(fn, *args, **kwargs)
            self.cancel()
        else:
            loop, gate, link, cancel = self.loop, self.gate, self.link, self.cancel

            def held() -> Any:
                self.fired_at = link.clock()
                loop.call_soon_threadsafe(cancel)
                gate.wait(10)
                return fn(*args, **kwargs)

            future = real(held)
        self.futures.append(future)
        return future

    async def settle(self) -> None:
        """Wait until every call submitted meanwhile is over; undo the patch."""
        self.gate.set()
        seen = -1
        for _ in range(2000):
            if seen == len(self.futures) and all(f.done() for f in self.futures):
                break  # (twice: a call a done callback submits is in the list by then)
            seen = len(self.futures) if all(f.done() for f in self.futures) else -1
            await asyncio.sleep(0.005)
        assert all(f.done() for f in self.futures), "a worker call never ended"
        for patched in ("submit", "submit_urgent"):
            if patched in vars(self.worker):
                delattr(self.worker, patched)


@dataclass
class Op:
    """An operation a user awaits: ``body(c, setup(c))``.

    Attributes:
        moves: the axes it starts (stopped when it is cancelled).
        goes_on: what it leaves running on purpose when cancelled; ``tidy`` ends it.
        points: how many of its first calls are cancel points (and its last one).
    """

    name: str
    body: Callable[[aio.AsyncController, Any], Awaitable[object]]
    setup: Callable[[aio.AsyncController], Awaitable[Any]] | None = None
    moves: str = ""
    tidy: Callable[[aio.AsyncController, Any], Awaitable[object]] | None = None
    points: int = 3
    goes_on: str = ""
    settle: float = SETTLE
    extra: dict[str, Any] = field(default_factory=dict)


# -- the operations --------------------------------------------------------------------------

LONG = 200_000  # counts: 10 s at SP 20 000, no cancel point comes near its end
ZIGZAG = [Line(37, 19 * (-1) ** k) for k in range(700)]  # longer than the S buffer (511)
PROGRAM = "#SLOW\ni=0\n#LOOP\ni=i+1\nWT 100\nJP #LOOP,i<100\nEN"


async def _slow(c: aio.AsyncController) -> None:
    await c.command("SP 20000,20000,20000,20000")
    await c.command("AC 1000000,1000000,1000000,1000000")
    await c.command("DC 1000000,1000000,1000000,1000000")


async def _start_a(c: aio.AsyncController) -> aio.AsyncMoveHandle:
    await _slow(c)
    return await c.A.move_by(LONG)


async def _move_and_wait(c: aio.AsyncController, _: object) -> object:
    return await (await c.A.move_by(LONG))


async def _multi(c: aio.AsyncController, _: object) -> object:
    return await (await c.move({"A": LONG, "B": -LONG}, relative=True))


async def _wait(c: aio.AsyncController, h: aio.AsyncMoveHandle) -> object:
    return await h.wait()


async def _watch(c: aio.AsyncController, h: aio.AsyncMoveHandle) -> object:
    return [p async for p in h.watch()]


async def _jog(c: aio.AsyncController, _: object) -> object:
    return await (await c.A.jog(20_000))


async def _start_jog(c: aio.AsyncController) -> aio.AsyncMoveHandle:
    await _slow(c)
    return await c.A.jog(20_000)


async def _axis_stop(c: aio.AsyncController, jog: aio.AsyncMoveHandle) -> object:
    await c.A.stop()
    return await jog


async def _controller_stop(c: aio.AsyncController, h: aio.AsyncMoveHandle) -> object:
    await c.stop()
    return await h


async def _handle_stop(c: aio.AsyncController, h: aio.AsyncMoveHandle) -> object:
    await h.stop()
    return await h


async def _guarded(c: aio.AsyncController, _: object) -> object:
    async with c.motion("AB"):
        a = await c.A.move_by(LONG)
        b = await c.B.move_by(LONG)
        await a
        await b
    return None


async def _vector(c: aio.AsyncController, _: object) -> object:
    return await (await c.vector_move("AB", [Line(LONG, LONG // 2)], speed=20_000))


async def _long_path(c: aio.AsyncController, _: object) -> object:
    handle = await c.vector_move("AB", ZIGZAG, speed=3000, accel=512_000, decel=512_000)
    return await handle


async def _contour(c: aio.AsyncController, _: object) -> object:
    return await c.contour("A", np.arange(1, 801) * 50.0, dt=4)


async def _schedule(c: aio.AsyncController, _: object) -> object:
    return await (await c.B.speed_schedule(LONG, [(LONG // 2, 10_000)], speed=20_000))


async def _find_edge(c: aio.AsyncController, _: object) -> object:
    return await (await c.A.find_edge())


async def _query(c: aio.AsyncController, _: object) -> object:
    await c.command("SHA")
    return await c.query_operands(["_TPA", "_TPB"])


async def _arrays(c: aio.AsyncController, _: object) -> object:
    await c.arrays.define("cz", 400, replace=True)
    await c.arrays.download("cz", np.arange(400.0))
    return await c.arrays.upload("cz")


async def _program(c: aio.AsyncController, _: object) -> object:
    await c.programs.download(PROGRAM)
    await c.programs.run("#SLOW", thread=1)
    await c.programs.wait(1, timeout=30)
    return None


async def _halt(c: aio.AsyncController, _: object) -> object:
    await c.programs.halt()
    return None


async def _wait_for_input(c: aio.AsyncController, _: object) -> object:
    return await c.io.wait_for_input(2, high=False, timeout=3.0)


async def _capture(c: aio.AsyncController, _: object) -> object:
    cap = await c.capture(["_TPA"], every=8, seconds=2.0)
    return await cap.wait()


async def _stop_recording(c: aio.AsyncController, _: object) -> object:
    await c.command("RC 0")
    return None


async def _records(c: aio.AsyncController, _: object) -> object:
    async with await c.records(64) as stream:
        return await stream.take(30)


async def _watchdog(c: aio.AsyncController, _: object) -> object:
    async with await c.watchdog(0.5):
        await c.sleep(1.0)
    return None


async def _sleep(c: aio.AsyncController, _: object) -> object:
    await c.sleep(2.0)
    return None


async def _stop_all(c: aio.AsyncController, _: object) -> object:
    await c.stop()
    return None


OPS = [
    Op("query", _query, points=2),
    Op("arrays", _arrays, points=3),
    Op("move_by+await", _move_and_wait, setup=_slow, moves="A"),
    Op("move+await", _multi, setup=_slow, moves="AB"),
    Op("handle.wait", _wait, setup=_start_a, moves="A"),
    Op("handle.watch", _watch, setup=_start_a, moves="A"),
    Op("jog+await", _jog, setup=_slow, moves="A"),
    Op("jog, axis.stop", _axis_stop, setup=_start_jog, moves="A", points=2),
    Op("move, controller.stop", _controller_stop, setup=_start_a, moves="A", points=2),
    Op("move, handle.stop", _handle_stop, setup=_start_a, moves="A", points=2),
    Op("motion guard", _guarded, setup=_slow, moves="AB", points=5),
    Op("vector_move", _vector, setup=_slow, moves="AB"),
    Op("vector_move long path", _long_path, moves="AB", points=2),
    Op("contour", _contour, moves="A", points=1),
    Op("speed_schedule", _schedule, setup=_slow, moves="B"),
    Op("find_edge", _find_edge, setup=_slow, moves="A"),
    Op("programs", _program, goes_on="program", tidy=_halt, points=5),
    Op("wait_for_input", _wait_for_input, points=3),
    Op("capture", _capture, goes_on="capture", tidy=_stop_recording, points=3),
    Op("records", _records, points=3),
    Op("watchdog", _watchdog, points=3),
    Op("sleep", _sleep, points=1, goes_on="the controller's time"),
]


async def _moving(c: aio.AsyncController) -> list[int]:
    return [round(v) for v in await c.query_operands([f"_BG{a}" for a in c.model.axes])]


async def _scenario(c: aio.AsyncController, op: Op, n: int, mode: str, how: str) -> Trap:
    """Run ``op`` once, cancelled at its ``n``-th worker call; check what reaches the caller."""
    ctx = await op.setup(c) if op.setup is not None else None
    loop = asyncio.get_running_loop()
    trap = Trap(c.worker, c.sync.link, n, mode)
    if how == "timeout":
        holder: list[asyncio.Timeout] = []

        async def timed() -> object:
            async with asyncio.timeout(None) as cm:
                holder.append(cm)
                return await op.body(c, ctx)

        task = asyncio.ensure_future(timed())
        trap.watch(task, lambda: holder[0].reschedule(loop.time()))
    else:
        task = asyncio.ensure_future(op.body(c, ctx))
        trap.watch(task, task.cancel)
    try:
        await asyncio.wait({task})
    finally:
        await trap.settle()
    where = f"{op.name}: cancelled {mode} at call {n} of it ({how})"
    if not trap.fired:
        task.result()  # it ended before the point: its own errors come out
        return trap
    if how == "cancel":
        assert task.cancelled(), f"{where}: ended with {task.exception() or task.result()!r}"
    else:
        assert isinstance(task.exception(), TimeoutError), f"{where}: {task.exception()!r}"
    return trap


async def _check_after(c: aio.AsyncController, op: Op, trap: Trap, where: str) -> None:
    clock = c.sync.link.clock
    if trap.fired and trap.fired_at is not None and not op.goes_on:
        took = clock() - trap.fired_at
        assert took <= op.settle, f"{where}: it went on for {took:.3g} s of controller time"
    await c.sleep(op.settle)  # any deceleration is over
    if op.tidy is not None:
        await op.tidy(c, None)
    assert await _moving(c) == [0] * len(c.model.axes), f"{where}: an axis still moves"
    assert await c.query_number("MG 1") == 1, where
    assert await c.query_number("MG 2") == 2, where
    await c.command("DP 0,0,0,0")


async def _calls(op: Op) -> int:
    """How many worker calls an uncancelled run of ``op`` makes (on its own controller)."""
    async with await sim() as c:
        ctx = await op.setup(c) if op.setup is not None else None
        trap = Trap(c.worker, c.sync.link)
        try:
            await asyncio.wait_for(_run_long(c, op, ctx), 20)
        finally:
            await trap.settle()
        return trap.count


async def _run_long(c: aio.AsyncController, op: Op, ctx: Any) -> None:
    if op.name in ("jog+await", "handle.watch", "wait_for_input", "programs"):
        # Endless (a jog), or long: count only the calls of its start and first waits.
        task = asyncio.ensure_future(op.body(c, ctx))
        for _ in range(200):
            await asyncio.sleep(0)
        task.cancel()
        await asyncio.wait({task})
        await c.stop()
        if op.tidy is not None:
            await op.tidy(c, ctx)
        return
    await op.body(c, ctx)


def _points(op: Op, total: int) -> list[int]:
    return sorted({*range(1, min(op.points, total) + 1), total})


async def _all_threads_end(c: aio.AsyncController, before: set[asyncio.Task[Any]]) -> None:
    """No task of the controller's is left on the loop, and its worker threads end. (A move's
    callback watcher ends at its next poll: the call under way when the worker closed.)"""
    for _ in range(400):
        if not asyncio.all_tasks() - before:
            break
        await asyncio.sleep(0.005)
    assert asyncio.all_tasks() - before == set()
    for t in c.worker.threads:
        t.join(5)
        assert not t.is_alive(), t.name


@pytest.mark.parametrize("how", HOW)
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("op", OPS, ids=[op.name for op in OPS])
def test_a_cancelled_operation_leaves_nothing_running_and_the_link_in_step(
    op: Op, mode: str, how: str
) -> None:
    async def body() -> list[int]:
        before = asyncio.all_tasks()
        total = await _calls(op)
        points = _points(op, total)
        if how == "timeout":
            # An expiring timeout is a cancel the loop delivers: the first and the last
            # point show that it is turned into TimeoutError and cleaned up alike.
            points = sorted({points[0], total})
        async with await sim() as c:
            sim_of(c.sync).set_servo_lag(0.0)
            for n in points:
                where = f"{op.name}: cancelled {mode} at call {n} of {total} ({how})"
                trap = await _scenario(c, op, n, mode, how)
                await _check_after(c, op, trap, where)
        await _all_threads_end(c, before)
        return points

    assert run(body)


# -- what the table above cannot drive -------------------------------------------------------


@pytest.mark.parametrize("room", ["messages", "interrupts"])
def test_a_get_cancelled_as_its_item_arrives_is_cancelled_and_the_item_kept(room: str) -> None:
    """Before Python 3.12, ``asyncio.wait_for`` returned the inner result when the cancel and
    the item came in the same loop step: ``get`` returned the item and the cancel was lost."""

    async def body() -> None:
        async with await sim() as c:
            box: aio.LoopQueue[Any] = c.messages if room == "messages" else c.interrupts.queue
            for timeout in (5.0, None):
                task = asyncio.ensure_future(box.get(timeout))
                for _ in range(3):
                    await asyncio.sleep(0)  # it waits for an item
                box._put("late")  # as the reader thread's call_soon_threadsafe does
                task.cancel()  # in the same loop step
                await asyncio.wait({task})
                assert task.cancelled(), f"timeout={timeout}: got {task.result()!r}"
                assert await box.get(0) == "late"  # not lost
            with pytest.raises(queue.Empty):
                await box.get(0.01)

    run(body)


@pytest.mark.parametrize("how", HOW)
def test_a_take_cancelled_part_way_keeps_its_records_for_the_next_read(how: str) -> None:
    async def body() -> list[int]:
        async with await sim() as c:
            async with await c.records(64) as stream:
                first = await stream.get()
                # Each batch call takes what is ready; the third call is cancelled while the
                # first two's records sit in take()'s hands.
                trap = await _scenario_on(c, lambda: stream.take(400), 3, "running", how)
                assert trap.fired
                rest = await stream.take(20)
            return [int(first["sample"]), *rest["sample"].tolist()]

    samples = run(body)
    assert np.diff(samples).tolist() == [64] * 20  # none lost, none twice


async def _scenario_on(
    c: aio.AsyncController, make: Callable[[], Awaitable[object]], n: int, mode: str, how: str
) -> Trap:
    op = Op("call", lambda c, _: make())
    return await _scenario(c, op, n, mode, how)


@pytest.mark.parametrize("how", HOW)
def test_a_watch_that_does_not_stop_on_cancel_leaves_the_move_running(how: str) -> None:
    """``watch(stop_on_cancel=False)`` documents that it only watches: cancelled, the move
    goes on (and the next wait finds it done where predicted)."""

    async def body() -> None:
        async with await sim() as c:
            sim_of(c.sync).set_servo_lag(0.0)
            move = await c.A.move_by(20_000)

            async def watch() -> None:
                async for _ in move.watch(stop_on_cancel=False):
                    pass

            trap = await _scenario_on(c, watch, 2, "queued", how)
            assert trap.fired
            assert await c.A.moving()
            assert "ST A" not in commands_of(c)
            result = await move
            assert result.final == {"A": 20_000}
            assert result.deviation == {"A": 0}

    run(body)


@pytest.mark.parametrize("mode", MODES)
def test_a_cancelled_aclose_still_closes_stops_and_ends_its_threads(mode: str) -> None:
    async def body() -> None:
        before = asyncio.all_tasks()
        c = await sim()
        simulator = sim_of(c.sync)
        await _slow(c)
        await c.A.jog(20_000)
        trap = await _scenario_on(c, c.aclose, 1, mode, "cancel")
        assert trap.fired
        assert c.closed
        assert c.sync.closed
        reference = simulator.motion("A").reference
        simulator.advance(0.5)
        assert simulator.motion("A").reference == reference  # the close stopped the jog
        await c.aclose()  # idempotent
        await _all_threads_end(c, before)

    run(body)


@pytest.mark.parametrize("mode", MODES)
def test_a_cancelled_connect_closes_the_controller_it_opened(
    mode: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    import galil.aio._controller as impl

    opened: list[galil.Controller] = []
    real_open = impl._open

    def spy(*args: Any) -> Any:
        out = real_open(*args)
        opened.append(out[0])
        return out

    monkeypatch.setattr(impl, "_open", spy)
    workers: list[Worker] = []
    real_init = Worker.__init__

    def init(self: Worker, name: str, threads: int = 3) -> None:
        real_init(self, name, threads)
        workers.append(self)

    monkeypatch.setattr(Worker, "__init__", init)

    async def body() -> None:
        before = asyncio.all_tasks()
        task = asyncio.ensure_future(aio.connect("sim://DMC-4040"))
        await asyncio.sleep(0)  # connect has made its worker and submitted the open
        (worker,) = workers
        # Queued: every thread held; running: the open runs once the task has ended.
        gate = threading.Event()
        if mode == "queued":
            for _ in worker.threads:
                worker.submit(gate.wait, 10)
        task.cancel()
        await asyncio.wait({task})
        gate.set()
        assert task.cancelled()
        for t in worker.threads:
            t.join(5)
            assert not t.is_alive(), t.name
        assert all(o.closed for o in opened)
        assert asyncio.all_tasks() - before == set()

    run(body)


# -- over TCP: cancelled inside an exchange --------------------------------------------------


class WireTrap(Trap):
    """Cancels a task from inside the ``n``-th write to the link (the worker thread holds the
    link's lock, the command's bytes about to go out); the write goes on once the task has
    ended or the cancellation asks for another call."""

    def __init__(self, c: aio.AsyncController, n: int) -> None:
        super().__init__(c.worker, c.sync.link, 0, "wire")
        self.writes, self.at = 0, n
        self.remove = c.wire_log.add(self.hook)

    def hook(self, direction: str, data: bytes) -> None:
        if direction != "out" or self.fired:
            return
        self.writes += 1
        if self.writes == self.at:
            self.fired = True
            self.loop.call_soon_threadsafe(self.cancel)
            self.gate.wait(5)

    async def settle(self) -> None:
        self.remove()
        await super().settle()


@pytest.fixture
def tcp_sim() -> Iterator[str]:
    simulator = SimController("DMC-4040", RealTimeClock(speed=8.0))
    with SimTcpServer(simulator, message_port=None) as server:
        yield server.url


TCP_OPS = {
    "query": lambda c: c.query_operands(["_TPA", "_TPB", "_RPA"]),
    "arrays": lambda c: _arrays(c, None),
    "move_by+await": lambda c: _move_and_wait(c, None),
    "contour": lambda c: c.contour("A", np.arange(1, 201) * 200.0, dt=4),
}


@pytest.mark.parametrize("name", list(TCP_OPS))
def test_over_tcp_a_cancel_inside_an_exchange_leaves_the_link_in_step(
    name: str, tcp_sim: str
) -> None:
    async def body() -> None:
        before = asyncio.all_tasks()
        async with await aio.connect(tcp_sim, timeout=2.0) as c:
            await _slow(c)
            fired = 0
            for n in (1, 2, 3, 5):
                wire = WireTrap(c, n)
                task = asyncio.ensure_future(TCP_OPS[name](c))
                wire.watch(task, task.cancel)
                try:
                    await asyncio.wait({task})
                finally:
                    await wire.settle()  # the calls the cancellation left have ended
                if wire.fired:
                    fired += 1
                    assert task.cancelled(), f"{name} at write {n}: {task!r}"
                for _ in range(200):  # a stop's deceleration: 20 ms, 2.5 ms of real time
                    if await _moving(c) == [0, 0, 0, 0]:
                        break
                    await asyncio.sleep(0.005)
                assert await _moving(c) == [0, 0, 0, 0], f"{name} at write {n}"
                for k in range(1, 6):
                    assert await c.query_number(f"MG {k}") == k, f"{name} at write {n}"
            assert fired
        await _all_threads_end(c, before)

    run(body)


def test_aclose_leaves_no_callback_watcher_task_on_the_loop() -> None:
    async def body() -> None:
        before = asyncio.all_tasks()
        c = await sim()
        move = await c.A.move_by(LONG)
        seen: list[object] = []
        move.add_callback(seen.append)
        await asyncio.sleep(0)
        await c.aclose()
        await _all_threads_end(c, before)
        assert seen == []  # the close stopped the move; it was not seen done

    run(body)


@pytest.mark.parametrize("kind", ["contour", "long path", "move"])
def test_a_start_cancelled_before_its_motion_registers_is_refused_before_it_begins(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The start is held inside its sync call, before its motion registers (the contour in
    its checks, the path at its first query), until the cancellation's own call has run: that
    stop finds nothing to stop, and the start is refused before it sends a segment or its
    ``BG S`` (decision 0100: it had started the path, then stopped it)."""
    from galil.contour import ContourStream

    async def body() -> None:
        async with await sim() as c:
            sim_of(c.sync).set_servo_lag(0.0)
            loop = asyncio.get_running_loop()
            holding, go_on = asyncio.Event(), threading.Event()

            def hold() -> None:
                if not go_on.is_set():
                    loop.call_soon_threadsafe(holding.set)
                    go_on.wait(10)

            if kind == "contour":
                check = ContourStream.check

                def held_check(self: ContourStream) -> None:
                    hold()
                    check(self)

                monkeypatch.setattr(ContourStream, "check", held_check)
                start: Awaitable[object] = c.contour("A", np.arange(1, 801) * 50.0, dt=4)
            elif kind == "move":  # (held before the tracker's lock, which its state read takes)
                move = galil.Axis._move

                def held_move(self: galil.Axis, *args: Any, **kwargs: Any) -> Any:
                    hold()
                    return move(self, *args, **kwargs)

                monkeypatch.setattr(galil.Axis, "_move", held_move)
                start = c.A.move_by(LONG)
            else:
                c.wire_log.add(lambda way, _: hold() if way == "out" else None)
                start = c.vector_move("AB", ZIGZAG, speed=3000, accel=512_000, decel=512_000)
            sent = len(commands_of(c))
            trap = Trap(c.worker, c.sync.link)
            task = asyncio.ensure_future(start)
            await holding.wait()
            began = c.sync.link.clock()
            task.cancel()
            await asyncio.wait({task})
            assert task.cancelled()
            for _ in range(2000):  # the cancellation's own call: refuse, stop what runs
                if all(f.done() for f in trap.futures[1:]):
                    break
                await asyncio.sleep(0.001)
            go_on.set()
            await trap.settle()
            assert c.sync.link.clock() - began < 0.5
            log = commands_of(c)[sent:]
            if kind == "contour":
                assert [t for t in log if t.startswith(("CM", "CD"))] == []  # (not even CM)
                assert "ST A" in log
            else:  # (refused under the lock before the state is read (again): 0100)
                assert not [t for t in log if t.startswith(("CA S", "PR", "BG"))], log
            assert await _moving(c) == [0, 0, 0, 0]
            assert await c.query_number("MG 1") == 1

    run(body)
