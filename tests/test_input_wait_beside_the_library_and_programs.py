"""wait_for_input beside the rest of a session (decision 0086): the watchdog and the input
wait take threads apart by default, a thread this session's routine runs on is refused with
the feature named (never with advice to halt it raw), the routine's own line never reaches the
user's messages, and a running program of the user's is never refused a wait: the input is
read first, and polled when the routine cannot be added without a download."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

import pytest
from program_helpers import input_wait_started

import galil
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, sim_of, simulated

LOOP = "#MAIN\nn=0\n#L\nn=n+1\nWT 10\nJP #L\nEN\n"  # a program of the user's that runs on


@contextlib.contextmanager
def goes_low_after_a_pause(dmc: galil.Controller, n: int) -> Iterator[None]:
    """Input ``n`` goes low once the wait has paused once (its routine runs by then, or its
    first poll is done): an edge at a known point, with no thread and no sleep."""
    pause = dmc.link.pause

    def pause_then_low(seconds: float) -> None:
        pause(seconds)
        sim_of(dmc).set_input(n, False)

    dmc.link.pause = pause_then_low  # type: ignore[method-assign]
    try:
        yield
    finally:
        del dmc.link.pause


def _sent_since(dmc: galil.Controller, before: int) -> list[str]:
    return [text for _, text in list(sim_of(dmc).command_log)[before:]]


def _words(lines: list[str]) -> list[str]:
    return [line.split(" ")[0].split("=")[0].rstrip("0123456789") for line in lines]


# -- 1. the watchdog and the input wait never collide by default ---------------------------


def test_an_input_wait_beside_the_watchdog_takes_another_thread_by_default() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # (before: thread 7 ... HX7)
        assert dog.thread == 7
        assert dog.running
        assert not dog.fired
        with pytest.raises(galil.GalilTimeoutError, match="did not go high"):
            dmc.io.wait_for_input(1, high=True, timeout=0.2)  # its routine ran, and halted
        assert dog.running
        dog.stop()


def test_a_watchdog_started_while_an_input_wait_runs_takes_another_thread_by_default() -> None:
    with simulated() as dmc:
        waiting, ended = input_wait_started(dmc, timeout=30)
        dog = dmc.watchdog(0.5)  # (before: "left running by an earlier session; ... HX7")
        assert dog.thread == 6
        assert dog.running
        sim_of(dmc).set_input(1, False)
        waiting.join(10.0)
        assert ended == [None]
        dog.stop()


def test_a_watchdog_timeout_under_two_samples_is_refused_before_its_thread_is_chosen() -> None:
    with simulated() as dmc, nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        dmc.watchdog(0.0001)  # (the default thread takes a query: the refusal comes first)


def test_a_thread_named_that_this_sessions_watchdog_runs_on_is_refused_naming_the_watchdog() -> (
    None
):
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        before = len(sim_of(dmc).command_log)
        with pytest.raises(galil.InvalidArgument) as refused:
            dmc.io.wait_for_input(1, high=False, timeout=0.2, thread=7)
        assert set(_words(_sent_since(dmc, before))) <= {"MG", "gwbeat"}  # (queries, beats)
        text = str(refused.value)
        assert "thread 7 runs the watchdog (#GWDOG), started in this session" in text
        assert "thread=" in text
        assert "HX" not in text
        assert "halt" not in text
        assert "earlier session" not in text
        assert dog.running
        dog.stop()


def test_a_watchdog_named_onto_a_running_input_waits_thread_is_refused_naming_the_wait() -> None:
    with simulated() as dmc:
        waiting = threading.Thread(
            target=lambda: dmc.io.wait_for_input(1, high=False, timeout=30), daemon=True
        )
        waiting.start()
        deadline = time.monotonic() + 10.0
        while dmc.routines.threads.get(7) != "#GINWAIT" and time.monotonic() < deadline:
            time.sleep(0.001)
        with pytest.raises(galil.InvalidArgument) as refused:
            dmc.watchdog(0.5, thread=7)
        text = str(refused.value)
        assert "thread 7 runs wait_for_input (#GINWAIT), started in this session" in text
        assert "HX" not in text
        sim_of(dmc).set_input(1, False)
        waiting.join(10.0)
        assert not waiting.is_alive()


def test_a_thread_whose_input_wait_saw_its_input_is_free_for_the_users_program() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # its routine said so, and ended
        assert dmc.routines.threads == {}
        dmc.programs.run("#MAIN", thread=7)  # (before: "thread 7 runs the library's #GINWAIT")
        assert 7 in dmc.programs.threads
        dmc.programs.halt(7)


# -- 2. the routine's line is the library's ------------------------------------------------


def test_the_input_waits_line_never_reaches_the_users_messages_nor_callbacks() -> None:
    with simulated() as dmc:
        heard: list[str] = []
        dmc.subscribe(heard.append)
        with goes_low_after_a_pause(dmc, 2):
            dmc.io.wait_for_input(2, high=False, timeout=5)
        dmc.programs.download('#P\nMG "mine"\nEN\n')
        dmc.programs.run("#P")
        dmc.programs.wait()
        assert dmc.messages.get(timeout=2) == "mine"  # (before: 'galil-input  2' first)
        with pytest.raises(galil.GalilTimeoutError):
            dmc.messages.get(timeout=0.1)
        assert heard == ["mine"]


def test_the_input_waits_line_never_reaches_the_users_messages_over_tcp() -> None:
    with SimTcpServer(model="DMC-4040") as server:
        host, port = server.address
        with galil.connect(f"tcp://{host}:{port}") as dmc:
            sim_of_server = server.controller
            pause = dmc.link.pause

            def pause_then_low(seconds: float) -> None:
                pause(seconds)
                sim_of_server.set_input(1, False)

            dmc.link.pause = pause_then_low  # type: ignore[method-assign]
            dmc.io.wait_for_input(1, high=False, timeout=5)
            del dmc.link.pause
            with pytest.raises(galil.GalilTimeoutError):
                dmc.messages.get(timeout=0.5)  # (before: 'galil-input  1')


def test_the_watchdogs_line_stays_the_users_to_read() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        sim_of(dmc).advance(1.0)  # the host silent: it fires
        assert dog.fired
        assert dmc.messages.get(timeout=1) == "galil watchdog: motion stopped"
        dog.stop()


# -- 3. a running program of the user's is never refused a wait ----------------------------


def test_a_wait_whose_input_is_at_the_level_returns_at_once_beside_a_running_program() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        dmc.programs.run("#MAIN")
        before = len(sim_of(dmc).command_log)
        dmc.io.wait_for_input(1, high=True, timeout=1)  # (before: "a program runs on ...")
        assert _sent_since(dmc, before) == ["MG @IN[1]"]  # one query
        assert list(dmc.programs.threads) == [0]


def test_a_wait_polls_its_input_while_a_program_runs_and_its_routine_is_not_in_memory() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        dmc.programs.run("#MAIN")
        counted = dmc.variables["n"]
        before = len(sim_of(dmc).command_log)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # (before: "a program runs ...")
        sent = _sent_since(dmc, before)
        assert all(line == "UL" or line.startswith("MG ") for line in sent)  # reads only
        assert sent.count("MG @IN[1]") >= 2  # (read first, then polled)
        assert list(dmc.programs.threads) == [0]  # undisturbed: it counts on
        dmc.sleep(0.1)
        assert dmc.variables["n"] > counted


def test_a_polling_wait_that_times_out_says_it_polled_and_leaves_the_program_running() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        dmc.programs.run("#MAIN")
        start = dmc.link.clock()
        with pytest.raises(galil.GalilTimeoutError, match="so this wait polled its input"):
            dmc.io.wait_for_input(1, high=False, timeout=0.5)
        assert 0.5 <= dmc.link.clock() - start < 1.0
        assert list(dmc.programs.threads) == [0]
        assert "#GINWAIT" not in dmc.routines.upload()


def test_a_routine_in_memory_from_an_earlier_wait_starts_beside_a_running_program() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        with pytest.raises(galil.GalilTimeoutError):  # (installs the routine: input 1 is high)
            dmc.io.wait_for_input(1, high=False, timeout=0.1)
        dmc.programs.run("#MAIN")
        before = len(sim_of(dmc).command_log)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)
        words = _words(_sent_since(dmc, before))
        assert "DL" not in words
        assert words.count("XQ") == 1  # the routine, started by XQ alone
        assert list(dmc.programs.threads) == [0]


def test_a_wait_beside_a_program_on_the_last_thread_takes_another_thread_by_default() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        with pytest.raises(galil.GalilTimeoutError):  # (installs the routine: input 1 is high)
            dmc.io.wait_for_input(1, high=False, timeout=0.1)
        dmc.programs.run("#MAIN", thread=7)
        before = len(sim_of(dmc).command_log)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # (before: "thread 7 runs a program")
        assert "XQ #GINWAIT,6" in _sent_since(dmc, before)
        assert list(dmc.programs.threads) == [7]  # undisturbed


def test_a_wait_beside_a_program_on_the_last_thread_polls_when_its_routine_is_not_in_memory() -> (
    None
):
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        dmc.programs.run("#MAIN", thread=7)
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # (before: "thread 7 runs a program")
        with pytest.raises(galil.GalilTimeoutError, match="so this wait polled its input"):
            dmc.io.wait_for_input(1, high=True, timeout=0.2)
        assert list(dmc.programs.threads) == [7]
        before = len(sim_of(dmc).command_log)
        with pytest.raises(galil.InvalidArgument, match="thread 7 runs a program"):
            dmc.io.wait_for_input(1, high=True, timeout=0.2, thread=7)  # named: refused
        assert all(line == "UL" or line.startswith("MG ") for line in _sent_since(dmc, before))


def test_a_wait_with_every_thread_running_a_program_polls_and_says_why() -> None:
    with simulated() as dmc:
        dmc.programs.download(LOOP)
        with pytest.raises(galil.GalilTimeoutError):  # (installs the routine: input 1 is high)
            dmc.io.wait_for_input(1, high=False, timeout=0.1)
        for thread in range(8):
            dmc.programs.run("#MAIN", thread=thread)
        before = len(sim_of(dmc).command_log)
        with pytest.raises(galil.GalilTimeoutError, match="every thread ran a program of yours"):
            dmc.io.wait_for_input(1, high=False, timeout=0.2)
        assert "XQ" not in _words(_sent_since(dmc, before))
        with goes_low_after_a_pause(dmc, 1):
            dmc.io.wait_for_input(1, high=False, timeout=5)  # polled, and seen
        assert list(dmc.programs.threads) == list(range(8))
        dmc.programs.halt()
