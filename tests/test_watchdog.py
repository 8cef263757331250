"""The controller stops itself when the host dies: ``controller.watchdog(timeout)``."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil.protocol import commands as cmds
from galil.routines import MARKER
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.rooms.tuning import Tuning
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, sim_of, simulated
from galil.watchdog import BEAT, FIRED, LIMIT


def test_heartbeats_keep_motion_going_and_silence_stops_it() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        assert dog.running
        assert not dog.fired
        jog = dmc.A.jog(20_000)
        dmc.sleep(3.0)  # the host waits; its heartbeats go on
        assert dmc.A.moving
        assert not dog.fired
        sim_of(dmc).advance(0.8)  # time passes with the host silent (frozen, unplugged...)
        assert not sim_of(dmc).motion("A").moving
        assert dog.fired
        assert dmc.A.stop_code[0] == 4  # an ST: a deceleration at DC, not an abort
        assert dmc.messages.get(timeout=1).startswith("galil watchdog")
        assert jog.done


def test_the_watchdog_leaves_the_users_program_and_threads_alone() -> None:
    program = ["#MAIN", "uv=1", "#LOOP", "WT 10", "JP #LOOP", "EN"]
    with simulated() as dmc:
        assert dmc.exchange(cmds.dl(program)).ok
        dog = dmc.watchdog(0.5)
        lines = dmc.exchange(cmds.ul()).text.split("\r\n")
        assert lines[: len(program)] == program  # every line of the user's program kept
        assert lines[len(program)] == MARKER
        dmc.command_line([cmds.xq("#MAIN", 0)])
        assert dmc.query_operands(["_XQ0"])[0] >= 0
        with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument):
            dmc.watchdog(0.5, thread=0)  # a thread the user's program runs on
        dog.stop()
        assert not dog.running
        assert dmc.query_operands(["_XQ0"])[0] >= 0  # the user's thread still runs


def test_watchdog_arguments_are_checked_before_anything_is_sent() -> None:
    with simulated() as dmc:
        for bad in (
            {"timeout": 0},
            {"timeout": float("inf")},
            {"timeout": "1"},
            {"timeout": 1.0, "thread": 8},
            {"timeout": 1.0, "interval": 2.0},
        ):
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
                dmc.watchdog(**bad)  # type: ignore[arg-type]


def test_a_clean_close_halts_the_watchdog_instead_of_firing_it() -> None:
    sim = SimController("DMC-4040")
    with galil.connect("sim://DMC-4040", controller=sim) as dmc:
        dmc.watchdog(0.3)
        # Raw commands: close() stops the library's own motion (docs/decisions/0024), not this.
        dmc.command("JG 10000")
        dmc.command("BG A")
    sim.advance(1.0)
    assert sim.motion("A").moving  # leaving on purpose is not dying


_CHILD = textwrap.dedent(
    """
    import sys, time
    import galil
    dmc = galil.connect(sys.argv[1], timeout=2.0)
    dmc.watchdog({timeout})
    dmc.A.jog({speed})
    print("jogging", flush=True)
    time.sleep(60)
    """
)


def test_killing_the_host_mid_jog_stops_the_axis_within_the_timeout(
    spawn: Callable[..., subprocess.Popen[str]],
) -> None:
    # Measured in the controller's own time (servo samples, what TIME counts): the property
    # is the controller's, "at rest within the timeout (and the deceleration) of the last
    # heartbeat it received". The real-time simulator's server thread may run late on a
    # loaded machine and then catch up sample by sample, so a wall-clock bound measured the
    # machine's scheduling, not the watchdog.
    timeout, speed = 0.3, 20_000
    sim = SimController("DMC-4040", RealTimeClock())
    ts = sim.sample_period
    with SimTcpServer(sim) as server, galil.connect(server.url, timeout=2.0) as observer:
        child = spawn(
            [sys.executable, "-c", _CHILD.format(timeout=timeout, speed=speed), server.url],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "jogging"
        limit = round(observer.query_number(f"MG {LIMIT}"))
        assert limit == round(timeout / ts)
        # The child's heartbeat runs (gwbeat, the TIME of the last beat received, moves on
        # twice), not only the stamp the watchdog's start wrote: the kill silences it.
        beats = {_last_beat(observer)}
        waited = time.monotonic()
        while len(beats) < 3:
            assert time.monotonic() - waited < 10.0, "the child's heartbeat does not beat"
            time.sleep(0.005)
            beats.add(_last_beat(observer))
        decel = speed / observer.query_number("MG _DCA")
        t0 = sim.start_trace("A")
        assert observer.A.moving
        child.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        while observer.A.moving:  # (a guard against a hang: the bound is checked below)
            assert time.monotonic() - killed < timeout + decel + 2.0, "the axis kept moving"
            time.sleep(0.005)
        child.wait(10)
        trace = sim.stop_trace("A")["A"]
        last_beat = _last_beat(observer)
        assert observer.A.stop_code[0] == 4
        assert observer.query_number(f"MG {FIRED}") == 1
    # The last sample in which the reference moved (trace[i] is its position at sample t0 + i).
    rest = t0 + int(np.flatnonzero(np.diff(trace))[-1]) + 1
    poll = math.ceil(0.002 / ts) + 1  # the routine looks every WT 2 (2 ms), then runs its JP
    assert limit < rest - last_beat <= limit + poll + math.ceil(decel / ts)


def _last_beat(controller: galil.Controller) -> int:
    """The sample of the last heartbeat the controller received (``gwbeat=TIME``)."""
    return round(controller.query_number(f"MG {BEAT}"))


def test_a_program_error_that_stops_the_routine_is_said_while_the_host_beats_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # Without #CMDERR a program error stops every thread, the watchdog's too: the host's
    # heartbeat would go on guarding nothing, unsaid.
    with caplog.at_level("WARNING", logger="galil.watchdog"), simulated() as dmc:
        dmc.programs.download("#BAD\nWT 5\nKPA=-1\nEN\n")
        dog = dmc.watchdog(0.5)
        dmc.programs.run("#BAD")
        with pytest.raises(galil.ProgramError):
            dmc.programs.wait()
        assert not dog.running
        deadline = time.monotonic() + 10.0  # (the heartbeat thread runs in real time)
        while time.monotonic() < deadline and not caplog.records:
            time.sleep(0.01)
        (record,) = [r for r in caplog.records if "no longer runs" in r.getMessage()]
        assert "thread 7" in record.getMessage()
        time.sleep(dog.interval * 3)  # more beats: said once
        assert len([r for r in caplog.records if "no longer runs" in r.getMessage()]) == 1
        assert dmc.watchdog(0.5).running  # a new one guards again


def _pull_the_cable(dmc: galil.Controller) -> None:
    transport = dmc.link.transport
    assert transport is not None
    transport.close()
    with pytest.raises(galil.GalilConnectionError):
        dmc.command("MG 1")  # (the link finds out)


def test_a_watchdog_stopped_while_the_link_is_dead_is_halted_when_it_is_reopened() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        _pull_the_cable(dmc)
        dog.stop()  # the HX cannot go out: the routine still watches on the controller
        assert dog.halt_pending
        dmc.reconnect()  # back within the timeout
        assert not dog.halt_pending
        assert dmc.query_operands(["_XQ7"]) == [-1]
        jog = dmc.A.jog(20_000)
        dmc.sleep(1.0)  # the stopped watchdog does not fire on the new motion
        assert dmc.A.moving
        assert dmc.query_operands([FIRED]) == [0]
        jog.stop()
        with dmc.watchdog(0.5) as again:  # and the thread is free for a new one
            assert again.running


def test_a_new_watchdog_on_the_thread_of_a_running_one_takes_it_over() -> None:
    with simulated() as dmc:
        first = dmc.watchdog(0.5)
        second = dmc.watchdog(2.0)  # (another timeout, say)
        assert not first.beating
        assert second.beating
        first.stop()  # halts nothing now: the routine is the second's
        assert second.running
        jog = dmc.A.jog(20_000)
        dmc.sleep(1.0)  # beyond the first's timeout: the second's guards
        assert dmc.A.moving
        jog.stop()
        second.stop()
        assert not second.running


def test_stopping_a_replaced_watchdog_leaves_its_successors_heartbeat() -> None:
    with simulated() as dmc:
        first = dmc.watchdog(1.0)
        second = dmc.watchdog(1.0)
        first.stop()
        jog = dmc.A.jog(1000)
        dmc.sleep(3.0)  # the host beats through it: the second's heartbeat goes on
        assert dmc.A.moving
        assert not second.fired
        assert repr(second) == "<Watchdog 1 s on thread 7, beating>"
        jog.stop()
        second.stop()


def test_a_new_watchdog_on_another_thread_replaces_the_running_one() -> None:
    """One watchdog guards a controller (decision 0082): the variables are the controller's."""
    with simulated() as dmc:
        short = dmc.watchdog(0.5, thread=6)
        long = dmc.watchdog(5.0, thread=7)
        assert not short.beating
        assert long.beating
        assert dmc.query_operands(["_XQ6"]) == [-1]  # the replaced one's routine halted
        assert long.running
        short.stop()  # halts nothing, and leaves the new one's heartbeat alone
        assert long.running
        jog = dmc.A.jog(20_000)
        dmc.sleep(6.0)  # the host waits: the heartbeat goes on
        assert dmc.A.moving
        sim_of(dmc).advance(1.0)  # the host silent beyond the replaced one's timeout
        assert sim_of(dmc).motion("A").moving  # the 5 s watchdog guards, as its caller said
        sim_of(dmc).advance(5.0)
        assert not sim_of(dmc).motion("A").moving
        assert long.fired
        assert not short.fired  # its own flag: nothing fired while it guarded
        assert jog.done
        long.stop()


@pytest.mark.parametrize("thread", [6, 7])
def test_a_replaced_watchdog_that_fired_still_says_so(thread: int) -> None:
    with simulated() as dmc:
        first = dmc.watchdog(0.5, thread=thread)
        dmc.A.jog(20_000)
        sim_of(dmc).advance(1.0)  # the host silent: it fires
        second = dmc.watchdog(0.5)  # (on thread 7: the first's, or another)
        assert first.fired  # not the new one's flag, which its routine cleared
        assert not second.fired
        assert repr(first) == f"<Watchdog 0.5 s on thread {thread}, stopped>"
        second.stop()


def test_a_watchdog_whose_replacement_fails_to_start_guards_on_with_its_own_timeout() -> None:
    with simulated() as dmc:
        first = dmc.watchdog(0.5, thread=6)
        transport = dmc.link.transport
        write = transport.write  # type: ignore[union-attr]

        def refused(data: bytes) -> None:  # Ctrl-C as the new routine's XQ would go out
            if b"XQ #GWDOG,7" in data:
                raise KeyboardInterrupt
            write(data)

        transport.write = refused  # type: ignore[method-assign,union-attr]
        with pytest.raises(KeyboardInterrupt):
            dmc.watchdog(5.0)
        transport.write = write  # type: ignore[method-assign,union-attr]
        assert first.beating
        assert first.running
        jog = dmc.A.jog(20_000)
        dmc.sleep(2.0)
        assert dmc.A.moving
        sim_of(dmc).advance(1.0)  # silent beyond the first's timeout, not the failed one's
        assert not sim_of(dmc).motion("A").moving
        assert first.fired
        assert jog.done
        first.stop()


def test_a_watchdog_that_fired_says_so_in_its_repr() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        assert repr(dog) == "<Watchdog 0.5 s on thread 7, beating>"
        dmc.A.jog(20_000)
        sim_of(dmc).advance(2.0)  # the host silent
        assert not dog.running
        assert repr(dog) == "<Watchdog 0.5 s on thread 7, beating, routine not running>"
        assert dog.fired
        assert repr(dog) == "<Watchdog 0.5 s on thread 7, fired>"
        dog.stop()
        assert repr(dog) == "<Watchdog 0.5 s on thread 7, stopped>"


_BURNS: dict[str, Callable[[galil.Controller], None]] = {
    "save": lambda dmc: dmc.save(),
    "save_program": lambda dmc: dmc.save_program(),
    "programs.burn": lambda dmc: dmc.programs.burn(),
}


@pytest.mark.parametrize("burn", sorted(_BURNS))
def test_a_burn_with_the_watchdog_running_halts_it_burns_and_guards_again(
    burn: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The controller refuses BN and BP while any thread runs (TC 17): the watchdog's routine
    is halted for the burn and started again, as for a program download (decision 0087)."""
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        with caplog.at_level("WARNING", logger="galil"):
            _BURNS[burn](dmc)
        command = "BN" if burn == "save" else "BP"
        assert sim_of(dmc).room(Tuning).burns[command] == 1
        assert f"halted for {command}" in caplog.text
        assert dog.running
        assert dog.beating
        assert dmc.programs.threads == {}
        dmc.A.jog(20_000)
        sim_of(dmc).advance(0.8)  # the host silent: the routine, running again, stops the axis
        assert not sim_of(dmc).motion("A").moving
        assert dog.fired


@pytest.mark.parametrize("burn", sorted(_BURNS))
def test_a_burn_while_a_users_program_runs_is_refused_unsent_naming_it(burn: str) -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        dmc.programs.download("#LOOP\nWT 10\nJP #LOOP\nEN\n")
        dmc.programs.run("#LOOP", thread=2)
        command = "BN" if burn == "save" else "BP"
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match=f"{command} is not valid") as info,
        ):
            _BURNS[burn](dmc)
        assert "thread 2" in str(info.value)
        assert "TC 17" in str(info.value)
        assert "programs.halt()" in str(info.value)
        assert sim_of(dmc).room(Tuning).burns[command] == 0
        assert dmc.programs.threads.keys() == {2}
        assert dog.running
        dmc.programs.halt()
        _BURNS[burn](dmc)  # the user's program halted: burned, the watchdog guarding on
        assert sim_of(dmc).room(Tuning).burns[command] == 1
        assert dog.running


@pytest.mark.parametrize("timeout", [0.1, 0.2])
@pytest.mark.parametrize("burn", sorted(_BURNS))
def test_a_burn_longer_than_a_short_timeout_restarts_the_watchdog_with_a_fresh_heartbeat(
    burn: str, timeout: float
) -> None:
    """The burn halts the routine for longer than the timeout (0.25 s in the simulator): it
    starts again measuring the silence from a beat stamped on its XQ's line, not from the
    last beat before the burn (which made it fire at once)."""
    with simulated() as dmc:
        dog = dmc.watchdog(timeout)
        before = dmc.link.clock()
        _BURNS[burn](dmc)
        assert dmc.link.clock() - before > timeout  # (the halt outlasted the timeout)
        dmc.sleep(timeout / 2)
        assert dog.running
        assert not dog.fired
        jog = dmc.A.jog(20_000)
        dmc.sleep(1.0)  # the host beats on: the jog goes on
        assert dmc.A.moving
        sim_of(dmc).advance(timeout / 2)  # the host silent, not yet for the timeout
        assert sim_of(dmc).motion("A").moving
        sim_of(dmc).advance(timeout + 0.3)  # silent beyond it: the routine stops the axis
        assert not sim_of(dmc).motion("A").moving
        assert dog.fired
        assert jog.done
        dog.stop()


def test_a_watchdog_beside_a_program_on_the_last_thread_takes_another_thread_by_default() -> None:
    with simulated() as dmc:
        dmc.programs.download("#LOOP\nWT 10\nJP #LOOP\nEN\n")
        dmc.watchdog(0.5).stop()  # (its routine in memory: no download needed beside a program)
        dmc.programs.run("#LOOP", thread=7)
        dog = dmc.watchdog(0.5)  # (before: "thread 7 runs a program; choose another thread")
        assert dog.thread == 6
        assert dog.running
        assert dmc.programs.threads.keys() == {7}
        dog.stop()
        dmc.programs.halt()
