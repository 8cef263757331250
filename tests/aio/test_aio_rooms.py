"""galil.aio speaks the rooms the sync controller grew: I/O, programs, arrays, variables,
interrupts, capture, the watchdog, switches and flash, homing, settings, gearing and vector
motion, against in-process simulators on their manual clock (interrupts over TCP, which
they need).
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import threading
from typing import Any

import numpy as np
import pytest
from aio_helpers import commands_of, run, sim

import galil
import galil.aio as aio
from galil import Arc, Line
from galil.arrays import Arrays, Variables
from galil.capture import Capture
from galil.controller import Controller
from galil.gearing import Gearing
from galil.interrupts import Interrupts
from galil.io import IO, AnalogInputs, AnalogOutputs, DigitalInputs, DigitalOutputs
from galil.motion import MoveHandle
from galil.programs import Programs
from galil.records import RecordStream
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.rooms.tuning import Tuning
from galil.sim.server import SimTcpServer
from galil.testing import sim_of
from galil.units import ureg
from galil.vector import VectorHandle
from galil.watchdog import Watchdog

mm, s, V = ureg.mm, ureg.s, ureg.volt


# -- the whole vocabulary ------------------------------------------------------------------

#: Sync names with no twin on purpose: the parts a facade is made of, the life cycle that has
#: an async name of its own, and what the library calls on a handle from inside.
NOT_TWINNED = {
    "link", "tracker", "messages_room", "records_room", "routines", "close",  # Controller
    "track", "add_event", "follow", "preset", "record",  # MoveHandle, VectorHandle internals
    "on_cancel", "take_cancel",
    "queue", "reopen",  # Interrupts: the sync queue, the reconnect hook
    "start",  # Capture, Watchdog: the async ones come started
    "reopened", "recheck", "hand_over",  # Watchdog: the controller's hooks (a reconnect, a new one)
    "reused",  # Capture: the controller's hook (a new capture took its arrays)
    "end_wait",  # IO: the controller's hook (close)
    "operand", "bank_bits", "function",  # the bank layout of the digital I/O rooms
}  # fmt: skip
#: Per room, sync names with no twin on purpose: the async variables are no mapping (their
#: reads are awaited; ``await variables.list()`` is the dict), so the mixins of the sync
#: ``MutableMapping`` have none (decision 0060).
NOT_TWINNED_IN: dict[type, set[str]] = {
    Variables: {"get", "items", "keys", "pop", "popitem", "setdefault", "update", "values"},
}
#: Where the async twin of a sync name has another name.
RENAMED = {"close": "aclose"}


def _public(cls: type) -> dict[str, Any]:
    names = {n for n in dir(cls) if not n.startswith("_")}
    return {n: inspect.getattr_static(cls, n) for n in names}


PAIRS = [
    (Controller, aio.AsyncController),
    (galil.Axis, aio.AsyncAxis),
    (MoveHandle, aio.AsyncMoveHandle),
    (VectorHandle, aio.AsyncVectorHandle),
    (IO, aio.AsyncIO),
    (DigitalInputs, aio.AsyncDigitalInputs),
    (DigitalOutputs, aio.AsyncDigitalOutputs),
    (AnalogInputs, aio.AsyncAnalogInputs),
    (AnalogOutputs, aio.AsyncAnalogOutputs),
    (Programs, aio.AsyncPrograms),
    (Arrays, aio.AsyncArrays),
    (Variables, aio.AsyncVariables),
    (Interrupts, aio.AsyncInterrupts),
    (Capture, aio.AsyncCapture),
    (Watchdog, aio.AsyncWatchdog),
    (Gearing, aio.AsyncGearing),
    (RecordStream, aio.AsyncRecordStream),
]


@pytest.mark.parametrize(("sync", "async_"), PAIRS, ids=[p[0].__name__ for p in PAIRS])
def test_every_public_name_of_the_sync_room_has_its_async_twin(sync: type, async_: type) -> None:
    twins = _public(async_)
    missing = []
    for name, member in _public(sync).items():
        if name in NOT_TWINNED or name in NOT_TWINNED_IN.get(sync, ()):
            continue
        if RENAMED.get(name, name) not in twins and name not in twins:  # (a stream's close)
            missing.append(name)
        writable = isinstance(member, property) and member.fset is not None
        talks = (writable or isinstance(member, galil.tuning.Setting)) and name != "timeout"
        if talks and f"set_{name}" not in twins:  # a setter that talks to the controller
            missing.append(f"set_{name}")
    assert missing == []


def test_the_rooms_hang_off_the_async_controller_as_off_the_sync_one() -> None:
    async def body() -> None:
        async with await sim() as c:
            for name in ("io", "programs", "arrays", "variables", "interrupts"):
                assert getattr(c, name).sync is getattr(c.sync, name)

    run(body)


def test_twins_keep_the_sync_docstrings() -> None:
    pairs = [
        (aio.AsyncController.vector_move, Controller.vector_move),
        (aio.AsyncController.save_program, Controller.save_program),
        (aio.AsyncAxis.home, galil.Axis.home),
        (aio.AsyncAxis.position_counts, galil.Axis.position_counts),
        (aio.AsyncPrograms.run, Programs.run),
        (aio.AsyncArrays.download, Arrays.download),
        (aio.AsyncInterrupts.enable, Interrupts.enable),
        (aio.AsyncGearing.set_ratio, Gearing.set_ratio),
    ]
    for twin, sync in pairs:
        assert twin.__doc__ == sync.__doc__


# -- I/O ------------------------------------------------------------------------------------


def test_io_is_read_by_awaiting_an_index_and_written_with_set() -> None:
    async def body() -> None:
        async with await sim() as c:
            io = c.io
            assert len(io.inputs) == 8
            assert list(io.outputs.numbers())[:2] == [1, 2]
            sim_of(c.sync).set_input(3, False)
            assert await io.inputs[3] is False
            assert await io.inputs[1:5] == (True, True, False, True)
            await io.outputs.set(2, True)
            await io.outputs.set(slice(5, 8), [True, False, True])
            assert await io.outputs[1:9] == (False, True, False, False, True, False, True, False)
            assert sim_of(c.sync).output(2)
            sim_of(c.sync).set_analog_input(1, 2.5)
            assert await io.analog_in[1] == 2.5 * V
            assert len(await io.inputs.all()) == 8
            with pytest.raises(galil.InvalidArgument):
                await io.outputs.set(99, True)

    run(body)


def test_wait_for_input_returns_when_the_input_changes() -> None:
    async def body() -> float:
        async with await sim() as c:
            waiting = asyncio.ensure_future(c.io.wait_for_input(2, high=False))
            while await c.query_operands(["_XQ7"]) == [-1.0]:  # the routine starts
                await asyncio.sleep(0.001)
            start = await c.run(c.sync.link.clock)
            sim_of(c.sync).set_input(2, False)
            await waiting
            return await c.run(c.sync.link.clock) - start

    # Within the slice under way: the wait reads the simulator's line between its pauses
    # (the clock runs on meanwhile, for the test's own queries too).
    assert run(body) < 3 * aio.WAIT_SLICE


def test_wait_for_input_times_out_after_the_whole_timeout_not_a_slice() -> None:
    async def body() -> tuple[float, str, list[float]]:
        async with await sim() as c:
            start = await c.run(c.sync.link.clock)
            with pytest.raises(galil.GalilTimeoutError) as raised:
                await c.io.wait_for_input(2, high=False, timeout=1.2)
            took = await c.run(c.sync.link.clock) - start
            return took, str(raised.value), await c.query_operands(["_XQ7"])

    took, text, thread = run(body)
    assert 1.2 <= took < 1.5
    assert "input 2 did not go low within 1.2 s" in text
    assert thread == [-1.0]  # the routine is halted


def test_an_awaited_wait_for_input_beside_a_sync_one_keeps_its_own_timeout() -> None:
    async def body() -> tuple[float, str]:
        async with await sim() as c:

            def wait() -> None:  # another thread of the program waits, the sync way
                with contextlib.suppress(galil.GalilError):
                    c.sync.io.wait_for_input(1, high=False, timeout=30)

            first = threading.Thread(target=wait)
            first.start()
            while await c.query_operands(["_XQ7"]) == [-1.0]:  # its routine runs
                await asyncio.sleep(0.001)
            start = await c.run(c.sync.link.clock)
            with pytest.raises(galil.GalilTimeoutError) as raised:
                await c.io.wait_for_input(2, high=False, timeout=1.2, thread=3)
            took = await c.run(c.sync.link.clock) - start
            sim_of(c.sync).set_input(1, False)
            await asyncio.to_thread(first.join, 10.0)
            return took, str(raised.value)

    took, text = run(body)
    assert 1.2 <= took < 2.0
    assert "input 2 did not go low within 1.2 s" in text


def test_cancelling_a_wait_for_input_frees_its_thread_and_halts_the_routine() -> None:
    async def body() -> None:
        async with await sim() as c:
            waiting = asyncio.ensure_future(c.io.wait_for_input(2, high=False))
            while await c.query_operands(["_XQ7"]) == [-1.0]:
                await asyncio.sleep(0.001)
            waiting.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiting
            for _ in range(2000):  # the slice under way ends within WAIT_SLICE of sim time
                if await c.query_operands(["_XQ7"]) == [-1.0]:
                    break
                await asyncio.sleep(0.001)
            assert await c.query_operands(["_XQ7"]) == [-1.0]
            assert c.sync.routines.threads == {}

    run(body)


def _wire(c: aio.AsyncController, since: int) -> list[str]:
    """The commands the simulator got after the first ``since``, by name (``HX7``: ``HX``)."""
    return [
        text.split(" ")[0].split("=")[0].rstrip("0123456789") for text in commands_of(c)[since:]
    ]


def test_an_awaited_wait_for_input_of_many_slices_costs_the_link_what_the_sync_wait_costs() -> None:
    """The routine is installed (UL) and started (XQ) once per wait, not once per slice."""

    async def body() -> tuple[list[str], list[str]]:
        async with await sim() as c:
            with pytest.raises(galil.GalilTimeoutError):  # the routine installed once
                await c.run(c.sync.io.wait_for_input, 2, high=False, timeout=0.1)
            before = len(commands_of(c))
            with pytest.raises(galil.GalilTimeoutError):
                await c.run(c.sync.io.wait_for_input, 2, high=False, timeout=3.0)
            sync = _wire(c, before)
            before = len(commands_of(c))
            with pytest.raises(galil.GalilTimeoutError, match=r"did not go low within 3\.0 s"):
                await c.io.wait_for_input(2, high=False, timeout=3.0)  # 6 slices
            return sync, _wire(c, before)

    sync, awaited = run(body)
    assert sorted(awaited) == sorted(sync)
    assert awaited.count("UL") == awaited.count("XQ") == awaited.count("HX") == 1


def _set_low_now(c: aio.AsyncController, n: int) -> float:
    """Set input ``n`` low, with no time passing meanwhile: the controller's time then."""
    with c.sync.link.locked():
        sim_of(c.sync).set_input(n, False)
        return c.sync.link.clock()


def test_an_awaited_wait_for_input_hears_its_input_slices_after_its_start() -> None:
    async def body() -> tuple[float, list[str]]:
        async with await sim() as c:
            before = len(commands_of(c))
            clock = c.sync.link.clock
            waiting = asyncio.ensure_future(c.io.wait_for_input(2, high=False, timeout=10))
            while await c.query_operands(["_XQ7"]) == [-1.0]:  # the routine starts
                await asyncio.sleep(0.001)
            start = await c.run(clock)
            while await c.run(clock) < start + 4 * aio.WAIT_SLICE:  # the wait lets it pass
                await asyncio.sleep(0.001)
            changed = await c.run(_set_low_now, c, 2)
            await waiting
            return await c.run(clock) - changed, _wire(c, before)

    took, wire = run(body)
    assert took <= 0.1  # one pause of the wait: the routine's line is heard in its time
    assert wire.count("UL") == 1  # (and the download of the routine, once)
    assert wire.count("XQ") == 1
    assert "HX" not in wire  # it said so and ended by itself


def test_a_wait_for_input_cancelled_slices_after_its_start_halts_its_routine_for_the_next() -> None:
    async def body() -> tuple[list[float], dict[int, str], list[str]]:
        async with await sim() as c:
            clock = c.sync.link.clock
            waiting = asyncio.ensure_future(c.io.wait_for_input(2, high=False))
            while await c.query_operands(["_XQ7"]) == [-1.0]:
                await asyncio.sleep(0.001)
            start = await c.run(clock)
            while await c.run(clock) < start + 3 * aio.WAIT_SLICE:
                await asyncio.sleep(0.001)
            waiting.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiting
            await c.worker.drained()  # the slice under way, then the halt
            halted = await c.query_operands(["_XQ7"])
            threads = c.sync.routines.threads
            before = len(commands_of(c))
            nxt = asyncio.ensure_future(c.io.wait_for_input(3, high=False, timeout=5))
            while await c.query_operands(["_XQ7"]) == [-1.0]:  # the next wait takes it
                await asyncio.sleep(0.001)
            sim_of(c.sync).set_input(3, False)
            await nxt
            return halted, threads, _wire(c, before)

    halted, threads, wire = run(body)
    assert halted == [-1.0]
    assert threads == {}
    assert wire.count("XQ") == 1


# -- programs, arrays, variables ------------------------------------------------------------

SQUARES = "#SQUARES\ni=0\n#LOOP\nsq[i]=i*i\ni=i+1\nWT 100\nJP #LOOP,i<10\nEN"


def test_programs_arrays_and_variables_are_awaited() -> None:
    async def body() -> None:
        async with await sim() as c:
            await c.arrays.define("sq", 10)
            assert (await c.programs.download(SQUARES)).sent
            assert not (await c.programs.download(SQUARES)).sent  # already there
            await c.programs.run("#SQUARES", thread=1)
            assert 1 in await c.programs.threads()
            await c.programs.wait(1, timeout=5)  # about 1 s: two slices and more
            assert await c.programs.threads() == {}
            np.testing.assert_array_equal(await c.arrays.upload("sq"), np.arange(10) ** 2)
            assert await c.arrays.list() == {"sq": 10}
            assert await c.arrays.contains("sq")
            await c.variables.write("gain", 2.5)
            assert await c.variables["gain"] == 2.5
            assert await c.variables.read("i") == 10
            assert (await c.variables.list())["gain"] == 2.5
            assert await c.variables.contains("gain")
            assert "SQUARES" in await c.programs.upload()
            await c.arrays.delete("sq")
            assert not await c.arrays.contains("sq")

    run(body)


def test_an_awaited_upload_outside_the_array_is_refused_after_the_size_query() -> None:
    async def body() -> None:
        async with await sim() as c:
            await c.arrays.define("a", 5)
            before = len(commands_of(c))
            with pytest.raises(galil.InvalidArgument, match=r"outside a\[\] of 5"):
                await c.arrays.upload("a", 0, 10)
            assert commands_of(c)[before:] == ["LA"]
            assert (await c.arrays.upload("a", 3, 4)).tolist() == [0, 0]

    run(body)


def test_waiting_for_a_program_times_out_after_the_whole_timeout() -> None:
    async def body() -> str:
        async with await sim() as c:
            await c.programs.download("#WAIT\nWT 10000\nEN")
            await c.programs.run("#WAIT", thread=0)
            with pytest.raises(galil.GalilTimeoutError) as raised:
                await c.programs.wait(0, timeout=1.2)
            assert await c.programs.threads() == {0: 1}
            await c.programs.halt()
            assert await c.programs.threads() == {}
            return str(raised.value)

    assert "thread 0 still runs after 1.2 s" in run(body)


# -- interrupts (a second Ethernet handle: the simulator over TCP) ---------------------------


def test_interrupts_arrive_as_an_async_iterator_and_reach_subscribers_on_the_loop() -> None:
    async def body() -> tuple[set[str], list[tuple[str, threading.Thread]]]:
        heard: list[tuple[str, threading.Thread]] = []
        with SimTcpServer(model="DMC-4040") as server:
            async with await aio.connect(server.url, timeout=2.0) as c:
                await c.interrupts.subscribe(
                    lambda i: heard.append((str(i), threading.current_thread()))
                )
                await c.interrupts.enable("AB", all_done=True)
                assert c.interrupts.enabled
                assert c.interrupts.mask == 0x103
                await (await c.move({"A": 300, "B": 200}))
                got = set()
                async for interrupt in c.interrupts:
                    got.add(str(interrupt))
                    if len(got) == 3:
                        break
                await c.interrupts.disable()
                assert not c.interrupts.enabled
        return got, heard

    got, heard = run(body)
    assert got == {"axis A done", "axis B done", "all done ($D8)"}
    assert {text for text, _ in heard} == got
    assert {thread for _, thread in heard} == {threading.main_thread()}


# -- capture, watchdog, switches, flash ------------------------------------------------------


def test_a_capture_awaited_beside_a_move_is_its_prediction_at_every_sample() -> None:
    async def body() -> None:
        async with await sim() as c:
            x = c.A.set_scale(2000 / mm)
            await x.set_speed(20 * mm / s)
            plan = await x.plan_to(5 * mm)
            cap = await c.capture(["_RPA", "_TPA"], every=2, seconds=plan.duration)
            assert cap.count == plan.samples // 2 + 1
            move = await x.move_to(5 * mm)
            rec = await cap.wait()
            begin = (await move.begin())["A"]
            assert rec.start == begin
            np.testing.assert_array_equal(rec["_RPA"], move.profile.position[rec.samples - begin])
            assert await c.arrays.list() == {}  # freed once uploaded
            async with await c.capture(["_RPA"], count=1000) as running:
                await c.sleep(0.05)
            assert running.result is not None
            assert 0 < len(running.result) < 1000  # stopped at the end of the block

    run(body)


def test_a_watchdog_runs_beside_the_loop_until_stopped() -> None:
    async def body() -> None:
        async with await sim() as c:
            async with await c.watchdog(0.5) as dog:
                assert (dog.timeout, dog.thread) == (0.5, 7)
                assert await dog.running()
                await c.sleep(2.0)  # heartbeats go out while simulated time passes
                assert not await dog.fired()
            assert not await dog.running()

    run(body)


def test_switch_polarity_and_flash_burns_are_awaited() -> None:
    async def body() -> None:
        async with await sim() as c:
            await c.set_switch_polarity(galil.SwitchPolarity(limit=1, home=-1, latch=1))
            assert await c.switch_polarity() == galil.SwitchPolarity(1, -1, 1)
            await c.save()
            await c.save_program()
            await c.save_variables()
            assert sim_of(c.sync).room(Tuning).burns == {"BN": 1, "BP": 1, "BV": 1}

    run(body)


# -- axes: homing, switches, settings, gearing ----------------------------------------------


def test_homing_is_an_awaitable_move_that_ends_at_the_index() -> None:
    async def body() -> None:
        async with await sim() as c:
            simulator = sim_of(c.sync)
            simulator.set_servo_lag(0.0)
            await c.A.set_home_speed(5000)
            assert await c.A.home_speed() == 5000
            assert not await c.A.homed()
            handle = await c.A.home(switch=simulator.home_switch("A"))
            assert handle.kind == "home"
            assert "exact" in handle.notes["A"]
            result = await handle
            assert result.stop_codes == {"A": 10}
            assert result.deviation == {"A": 0}
            assert await c.A.position() == 0
            assert await c.A.homed()
            switches = await c.A.switches()
            assert not switches.forward_limit

    run(body)


def test_cancelling_the_task_that_awaits_a_homing_stops_the_axis() -> None:
    async def body() -> None:
        async with await sim() as c:
            # Slowly: the simulator's switch is found after about 40 s at this speed, so the
            # waiter's own polls (which advance the simulated clock) cannot reach it before
            # the cancel lands, however late a loaded host lets the test run (at the
            # default speed the edge was found 1 s in, and the axis ended with code 9).
            await c.A.set_speed(250)
            edge = await c.A.find_edge()  # no switch positions: no known end
            assert edge.duration == float("inf")
            waiter = asyncio.ensure_future(edge.wait())
            await c.sleep(0.05)
            waiter.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiter
            assert "ST A" in commands_of(c)
            assert (await c.A.stop_code())[0] == 4

    run(body)


def test_tuning_settings_are_typed_and_refused_before_sending() -> None:
    async def body() -> None:
        async with await sim() as c:
            a = c.A
            await c.motor_off("A")  # MT only with the motor off
            await a.set_motor_type(galil.MotorType.STEPPER_ACTIVE_HIGH_REVERSED)
            assert await a.motor_type() is galil.MotorType.STEPPER_ACTIVE_HIGH_REVERSED
            await a.set_kp(10)
            await a.set_error_limit(500)
            assert (await a.kp(), await a.error_limit()) == (10.0, 500)
            sent = len(commands_of(c))
            with pytest.raises(galil.InvalidArgument):
                await a.set_torque_limit(10)
            with pytest.raises(galil.InvalidArgument):
                await a.set_kd(True)  # type: ignore[arg-type]
            assert len(commands_of(c)) == sent

    run(body)


def test_a_geared_follower_is_predicted_with_its_master() -> None:
    async def body() -> None:
        async with await sim() as c:
            gearing = await c.B.gear_to(c.A, 0.5)
            assert (gearing.follower, gearing.master, gearing.engaged) == ("B", "A", True)
            move = await c.A.move_by(10_000)
            assert move.followers == "B"
            assert move.profiles["B"].end == 5000
            assert (await move).deviation == {"A": 0}
            assert await c.query_operands(["_RPB"]) == [5000]
            await gearing.off()
            assert not gearing.engaged

    run(body)


def test_a_gearing_used_in_async_with_is_turned_off_however_the_block_ends() -> None:
    async def body() -> None:
        async with await sim() as c:
            async with await c.B.gear_to(c.A, 0.5) as gearing:
                assert gearing.engaged
                sent = len(commands_of(c))
            assert not gearing.engaged
            assert any(t.startswith("GR") for t in commands_of(c)[sent:])  # GR 0
            with pytest.raises(RuntimeError, match="in the block"):
                async with await c.B.gear_to(c.A, 0.5) as gearing:
                    raise RuntimeError("in the block")
            assert not gearing.engaged

            async def block(entered: asyncio.Event) -> None:
                async with await c.B.gear_to(c.A, 0.5):
                    entered.set()
                    await asyncio.Event().wait()

            entered = asyncio.Event()
            task = asyncio.ensure_future(block(entered))
            await entered.wait()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            assert await c.query_operands(["_GRB"]) == [0]

    run(body)


# -- coordinated motion ---------------------------------------------------------------------


def test_a_vector_move_is_awaited_and_ends_where_predicted() -> None:
    async def body() -> None:
        async with await sim() as c:
            for a in "AB":
                c.axis(a).set_scale(2000 / mm)
            path = [Line(10 * mm, 0), Arc(5 * mm, 270, 90), Line(0, 10 * mm)]
            speed, accel = 40 * mm / s, 400 * mm / s**2
            plan = await c.plan_vector("AB", path, speed=speed, accel=accel, decel=accel)
            handle = await c.vector_move("AB", path, speed=speed, accel=accel, decel=accel)
            assert isinstance(handle, aio.AsyncVectorHandle)
            assert handle.kind == "vector"
            assert handle.duration == pytest.approx(plan.duration)
            assert handle.vector.unit == "mm"
            result = await handle
            assert result.worst == 0
            assert await c.A.reference_position() == 15 * mm
            assert await c.B.reference_position() == 15 * mm

    run(body)


def test_cancelling_the_task_that_awaits_a_sequence_stops_it_along_its_path() -> None:
    async def body() -> None:
        async with await sim() as c:
            handle = await c.vector_move("AB", [Line(100_000, 50_000)], speed=40_000)
            waiter = asyncio.ensure_future(handle.wait())
            await c.sleep(0.3)
            waiter.cancel()
            with pytest.raises(asyncio.CancelledError):
                await waiter
            assert "ST S" in commands_of(c)
            result = await handle
            assert result.stop_codes == {"A": 4, "B": 4}
            assert result.worst == 0  # the stop is in the prediction
            assert handle.counts.shape == "stopped"

    run(body)


def test_cancelled_while_a_long_path_streams_the_sequence_stops_at_once() -> None:
    """The stop goes out while the path is still streaming on its thread, and the stream
    sends nothing more (no VE): a stop from any thread ends a streamed sequence."""

    async def body() -> None:
        async with await sim() as c:
            zigzag = [Line(37, 19 * (-1) ** k) for k in range(1400)]
            task = asyncio.ensure_future(
                c.vector_move("AB", zigzag, speed=30_000, accel=512_000, decel=512_000)
            )
            while c.sync.tracker.active("A") is None:  # streaming has begun
                await asyncio.sleep(0.001)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
            for _ in range(5000):
                if "ST S" in commands_of(c):
                    break
                await asyncio.sleep(0.001)
            log = commands_of(c)
            assert "ST S" in log
            await c.sleep(1.0)
            assert "VE" not in commands_of(c)  # the stream saw the stop and sent no more
            assert await c.query_operands(["_BGS", "_SCA"]) == [0, 4]
            assert (await c.query_operands(["_RPA"]))[0] < 37 * 1400

    run(body)


# -- the loop stays free --------------------------------------------------------------------


async def _tour(c: aio.AsyncController) -> None:
    """One of everything new, in user units where the sync side takes them."""
    x = c.A
    await c.io.outputs.set(slice(1, 9), [True] * 8)
    await c.io.inputs[1:9]
    await c.programs.download(SQUARES)
    await c.arrays.define("sq", 10, replace=True)
    await c.programs.run("#SQUARES", thread=1)
    await c.programs.wait(1)
    await c.arrays.upload("sq")
    await c.variables.write("gain", 1.5)
    cap = await c.capture(["_RPA"], every=4, seconds=0.3)
    await (await x.move_by(5 * mm))
    await cap.wait()
    sequence = await c.vector_move("AB", PATH, speed=40 * mm / s)
    await sequence
    await x.set_kp(8)
    await x.switches()


PATH = [Line(5 * mm, 5 * mm), Arc(2 * mm, 45, 180)]


def test_the_new_rooms_never_block_the_loop_for_a_millisecond() -> None:
    async def body() -> aio.LoopWatch:
        controllers = await asyncio.gather(*(sim() for _ in range(2)))
        for c in controllers:  # pint's first conversions fill its caches: not galil's work
            c.A.set_scale(2000 / mm)
            c.B.set_scale(2000 / mm)
        try:
            with aio.watch_loop() as watch:
                await asyncio.gather(*(_tour(c) for c in controllers))
        finally:
            await asyncio.gather(*(c.aclose() for c in controllers))
        return watch

    watch = run(body)
    assert watch.steps > 100
    assert watch.max_own_cpu < 1e-3, watch.summary() + " " + watch.slowest


def test_aclose_during_a_cancelled_wait_for_input_halts_its_routine() -> None:
    """The cancelled wait's slice still runs on a worker when aclose() comes: the close
    halts the routine (the slice cannot once the link is closed)."""

    async def body() -> float:
        with SimTcpServer(SimController("DMC-4040", RealTimeClock())) as server:
            async with await aio.connect(server.url) as c:
                task = asyncio.ensure_future(c.io.wait_for_input(1, high=False, timeout=30))
                while await c.query_operands(["_XQ7"]) == [-1.0]:  # its routine runs
                    await asyncio.sleep(0.001)
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
            async with await aio.connect(server.url) as c:
                return await c.query_number("MG _XQ7")

    assert run(body) == -1.0
