"""The library's routines in program memory: one copy each, whole, never clashing with the
user's labels (inner labels included), and a watchdog that says it beats only when it runs."""

from __future__ import annotations

import contextlib
import math
import threading
import time

import pytest
from client_fakes import pull_cable_after

import galil
from galil.protocol import commands as cmds
from galil.routines import MARKER, Routine
from galil.sim.parse import split_program_line
from galil.sim.programs import NOT_IN_PROGRAM
from galil.testing import nothing_sent, sim_of, simulated


def _library_labels(dmc: galil.Controller) -> list[str]:
    program = dmc.routines.upload()
    return [line for line in program[program.index(MARKER) + 1 :] if line.startswith("#")]


def test_waiting_for_an_input_twice_keeps_one_copy_of_its_routine() -> None:
    with simulated() as dmc:
        for _ in range(2):
            with pytest.raises(galil.GalilTimeoutError):
                dmc.io.wait_for_input(2, high=False, timeout=0.1)
        assert _library_labels(dmc) == ["#GINWAIT", "#GINLOOP"]


def test_starting_the_watchdog_twice_keeps_one_copy_of_its_routine() -> None:
    with simulated() as dmc:
        dmc.watchdog(0.5).stop()
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(2, high=False, timeout=0.1)
        dog = dmc.watchdog(0.5)
        assert _library_labels(dmc) == ["#GWDOG", "#GWDOGL", "#GINWAIT", "#GINLOOP"]
        dmc.sleep(0.2)
        assert dog.running
        dog.stop()


def test_a_stale_inner_block_left_in_memory_is_replaced_with_the_routine() -> None:
    with simulated() as dmc:
        loop = ["#GINLOOP", "JP #GINLOOP,@IN[ginput]<>ginlevel", "EN"]
        assert dmc.exchange(cmds.dl(["#A", "EN", MARKER, "#GINWAIT", *loop, *loop])).ok
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(2, high=False, timeout=0.1)
        assert _library_labels(dmc) == ["#GINWAIT", "#GINLOOP"]
        assert dmc.programs.upload() == "#A\nEN"


def test_a_user_label_equal_to_a_routines_inner_label_is_refused_before_download() -> None:
    with simulated() as dmc:
        # (put there by other software: programs.download refuses the library's labels)
        assert dmc.exchange(cmds.dl(["#A", "EN", "#GWDOGL", "EN"])).ok
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="GWDOGL"),
        ):
            dmc.watchdog(0.5)
        assert dmc.routines.threads == {}


def test_installing_two_routines_refuses_a_user_label_of_either() -> None:
    with simulated() as dmc:
        dmc.programs.download("#A\nEN\n#RTWOL\nEN")
        one = Routine("#RONE", ("#RONE", "WT 10", "EN"))
        two = Routine("#RTWO", ("#RTWO", "#RTWOL", "JP #RTWOL", "EN"))
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="RTWOL"),
        ):
            dmc.routines.install(one, two)


def test_a_user_program_with_a_routines_inner_label_is_refused_beside_it() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="GWDOGL"),
        ):
            dmc.programs.download("#A\nEN\n#GWDOGL\nEN")
        dmc.sleep(0.2)
        assert dog.running
        dog.stop()


def test_a_routine_whose_inner_label_follows_an_en_is_refused() -> None:
    with pytest.raises(galil.InvalidArgument, match="#GSUB"):
        Routine("#GMAIN", ("#GMAIN", "JS #GSUB", "EN", "#GSUB", "EN"))
    with pytest.raises(galil.InvalidArgument, match="EN"):
        Routine("#GLOOP", ("#GLOOP", "JP #GLOOP"))


def test_a_watchdog_whose_routine_does_not_run_raises_instead_of_beating(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with simulated() as dmc:
        real = dmc.link.command_line

        def swallow_xq(commands: list[cmds.Command], **kw: object) -> list[str]:
            kept = [c for c in commands if not c.text.startswith("XQ #GWDOG")]
            return real(kept, **kw) if kept else []  # type: ignore[arg-type]

        monkeypatch.setattr(dmc.link, "command_line", swallow_xq)
        with pytest.raises(galil.GalilError, match="not running"):
            dmc.watchdog(0.5)
        monkeypatch.undo()
        assert dmc.routines.threads == {}
        dog = dmc.watchdog(0.5)  # nothing left behind: the next start works
        assert "beating" in repr(dog)
        dog.stop()
        assert "stopped" in repr(dog)


def test_waiting_for_an_input_checks_the_thread_before_anything_is_sent() -> None:
    with simulated() as dmc:
        for thread in (99, -1, "7", True):
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="thread"):
                dmc.io.wait_for_input(2, timeout=0.1, thread=thread)  # type: ignore[arg-type]


@pytest.mark.parametrize("timeout", [math.nan, -1, "1", True])
def test_waiting_for_an_input_refuses_a_bad_timeout_before_anything_is_sent(
    timeout: object,
) -> None:
    with simulated() as dmc, nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        dmc.io.wait_for_input(2, timeout=timeout)  # type: ignore[arg-type]


def test_the_librarys_routines_hold_no_command_a_program_may_not_run() -> None:
    # (the reference's "Not Valid in program" commands stop a thread with TC 3: decision 0047)
    with simulated() as dmc:
        dog = dmc.watchdog(0.5, thread=6)
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(2, high=False, timeout=0.1)
        dmc.A.speed_schedule(40_000, [(10_000, 5000)]).wait()
        program = dmc.routines.upload()
        dog.stop()
    library = program[program.index(MARKER) + 1 :]
    labels = [line for line in library if line.startswith("#")]
    assert labels == ["#GWDOG", "#GWDOGL", "#GINWAIT", "#GINLOOP", "#GSCHED"]
    words = [c.strip()[:2] for line in library for c in split_program_line(line)]
    assert {"WT", "AD"} <= set(words)
    assert not NOT_IN_PROGRAM & set(words)


@pytest.mark.parametrize("error", [KeyboardInterrupt, galil.GalilTimeoutError])
def test_a_wait_for_an_input_cut_short_halts_its_routine(error: type[BaseException]) -> None:
    with simulated() as dmc:
        pause = dmc.link.pause

        def cut(seconds: float) -> None:  # Ctrl-C, or a reply lost, while it waits
            pause(seconds)
            raise error("cut short")

        dmc.link.pause = cut  # type: ignore[method-assign]
        with pytest.raises(error):
            dmc.io.wait_for_input(2, high=False)
        del dmc.link.pause
        assert dmc.query_operands(["_XQ7"]) == [-1]  # not left watching the input
        assert dmc.routines.threads == {}


def test_a_wait_for_an_input_whose_link_died_at_its_start_leaves_the_thread_to_the_next() -> None:
    with simulated() as dmc:
        pull_cable_after(dmc.link.transport, b"XQ #GINWAIT")  # (the routine runs)
        with pytest.raises(galil.GalilConnectionError):
            dmc.io.wait_for_input(2, high=False, timeout=0.1)
        dmc.reconnect()
        assert dmc.query_operands(["_XQ7"])[0] >= 0  # its routine watches on for nobody
        # The library still holds the thread: the next wait halts the routine and runs it
        # again (not "thread 7 runs a program", nor XQ's TC 19).
        with pytest.raises(galil.GalilTimeoutError, match="did not go low"):
            dmc.io.wait_for_input(2, high=False, timeout=0.1)
        sim_of(dmc).set_input(2, False)
        dmc.io.wait_for_input(2, high=False, timeout=0.5)


def test_a_routine_may_not_take_a_label_reserved_for_another_kind_of_routine() -> None:
    with pytest.raises(galil.InvalidArgument, match="watchdog"):
        Routine("#GWDOG", ("#GWDOG", "EN"), kind="a speed schedule")
    with pytest.raises(galil.InvalidArgument, match="wait_for_input"):
        Routine("#MINE", ("#MINE", "#GINLOOP", "JP #GINLOOP", "EN"), kind="a speed schedule")
    Routine("#GSCHED", ("#GSCHED", "EN"), kind="a speed schedule")  # its own


def test_a_program_with_a_library_label_is_refused_unsent_with_no_routine_installed() -> None:
    with simulated() as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="GWDOG"):
            dmc.programs.download("#GWDOG\nEN")
        dog = dmc.watchdog(0.5)  # the label is free for the watchdog
        assert dog.running
        dog.stop()


def _waiting_on(dmc: galil.Controller, n: int, timeout: float) -> threading.Thread:
    """A wait for input ``n`` to go low in another thread, once its routine runs."""

    def wait() -> None:
        with contextlib.suppress(galil.GalilError):
            dmc.io.wait_for_input(n, high=False, timeout=timeout)

    waiting = threading.Thread(target=wait)
    waiting.start()
    deadline = time.monotonic() + 10.0
    while dmc.query_operands(["_XQ7"]) == [-1] and time.monotonic() < deadline:
        time.sleep(0.001)
    return waiting


def test_a_second_wait_for_an_input_keeps_its_own_timeout() -> None:
    with simulated() as dmc:
        first = _waiting_on(dmc, 1, timeout=30.0)
        start = dmc.link.clock()
        with pytest.raises(galil.GalilTimeoutError, match="another wait_for_input"):
            dmc.io.wait_for_input(2, high=False, timeout=0.5, thread=3)
        assert 0.5 <= dmc.link.clock() - start < 1.0
        assert dmc.query_operands(["_XQ3"]) == [-1]  # not started on its thread
        sim_of(dmc).set_input(1, False)
        first.join(10.0)
        assert not first.is_alive()


def test_a_second_wait_for_an_input_returns_when_its_input_is_at_the_level() -> None:
    with simulated() as dmc:
        first = _waiting_on(dmc, 1, timeout=30.0)
        sim_of(dmc).set_input(2, False)
        start = dmc.link.clock()
        dmc.io.wait_for_input(2, high=False, timeout=5.0, thread=3)
        assert dmc.link.clock() - start < 0.5
        sim_of(dmc).set_input(1, False)
        first.join(10.0)
        assert not first.is_alive()


def test_a_wait_for_an_input_on_a_simulators_clock_hears_the_change_in_the_time_it_came() -> None:
    """The idle poll reads the routine's line in real time (20 ms), while the wait lets the
    simulator's time run: the wait reads the link between its pauses itself."""
    with simulated() as dmc:
        changed: list[float] = []

        def change_later() -> None:
            deadline = time.monotonic() + 10.0
            while dmc.query_operands(["_XQ7"]) == [-1] and time.monotonic() < deadline:
                time.sleep(0.001)  # the routine starts
            with dmc.link.locked():  # no time passes between the reading and the change
                changed.append(dmc.link.clock())
                sim_of(dmc).set_input(2, False)

        setter = threading.Thread(target=change_later)
        setter.start()
        dmc.io.wait_for_input(2, high=False, timeout=30.0)
        setter.join(10.0)
        assert dmc.link.clock() - changed[0] <= 0.1  # one pause of the wait


def _left_by_an_earlier_session(sim: object, label: str, thread: int = 7) -> None:
    """A session that installed the library's routines and left ``label`` running on
    ``thread`` (as one whose link died, or an older version's close, would)."""
    from galil.controller import Controller
    from galil.sim.link import SimLink

    with Controller(SimLink(sim)) as dmc:  # type: ignore[arg-type]
        dmc.watchdog(0.5, thread=6).stop()
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(1, high=False, timeout=0.1)
        dmc.command(f"ginput=1;ginlevel=0;XQ {label},{thread}", allow_compound=True)


def test_a_new_session_takes_over_an_input_routine_an_earlier_one_left_running() -> None:
    from galil.controller import Controller
    from galil.sim.clock import ManualClock
    from galil.sim.controller import SimController
    from galil.sim.link import SimLink

    sim = SimController("DMC-4040", ManualClock())
    _left_by_an_earlier_session(sim, "#GINWAIT")
    with Controller(SimLink(sim)) as dmc:
        assert dmc.query_number("MG _XQ7") >= 0
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(2, high=False, timeout=0.3)
        assert dmc.query_number("MG _XQ7") == -1  # halted by the timed-out wait


def test_a_thread_running_another_library_routine_says_whose_it_is_and_how_to_halt_it() -> None:
    from galil.controller import Controller
    from galil.sim.clock import ManualClock
    from galil.sim.controller import SimController
    from galil.sim.link import SimLink

    sim = SimController("DMC-4040", ManualClock())
    _left_by_an_earlier_session(sim, "#GWDOG")
    with Controller(SimLink(sim)) as dmc:
        with pytest.raises(galil.InvalidArgument, match=r"#GWDOG \(the watchdog\).*HX7"):
            dmc.io.wait_for_input(2, high=False, timeout=0.3, thread=7)
        with pytest.raises(galil.GalilTimeoutError):  # by default: the next thread, 6
            dmc.io.wait_for_input(2, high=False, timeout=0.3)
        assert "XQ #GINWAIT,6" in [line for _, line in sim.command_log]
        dmc.command("HX7")


def test_a_sync_wait_for_an_input_in_another_thread_ends_when_the_controller_closes() -> None:
    from galil.controller import Controller
    from galil.sim.clock import ManualClock
    from galil.sim.controller import SimController
    from galil.sim.link import SimLink

    sim = SimController("DMC-4040", ManualClock())
    dmc = Controller(SimLink(sim))
    ended: list[BaseException] = []

    def waiter() -> None:
        try:
            dmc.io.wait_for_input(1, high=False)
        except BaseException as exc:
            ended.append(exc)

    t = threading.Thread(target=waiter, daemon=True)
    t.start()
    while dmc.routines.threads.get(7) != "#GINWAIT":  # its routine runs
        time.sleep(0.01)
    dmc.close()
    t.join(5)
    assert not t.is_alive()
    assert isinstance(ended[0], galil.GalilConnectionError)
    with Controller(SimLink(sim)) as again:
        assert again.query_number("MG _XQ7") == -1  # the routine was halted


def test_a_raw_download_refused_says_to_stop_the_librarys_routines_through_the_library() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument) as info:
            dmc.send(cmds.dl(["#A", "EN"]))
        said = str(info.value)
        assert "stop the watchdog (its stop()) first" in said
        assert "HX" not in said  # (before: "halt them first (HX n)", behind the library's back)
        dmc.programs.download("#L\nWT 10\nJP #L\nEN\n")
        dmc.programs.run("#L", thread=2)
        with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument) as info:
            dmc.send(cmds.dl(["#A", "EN"]))
        said = str(info.value)
        assert "stop the watchdog (its stop())" in said
        assert "halt thread(s) [2] (controller.programs.halt(n), or HX n)" in said  # the user's
        dmc.programs.halt()
        dog.stop()
        assert dmc.exchange(cmds.dl(["#A", "EN"])).ok
