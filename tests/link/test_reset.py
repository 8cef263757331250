"""``Controller.reset()`` and the raw commands refused because they would break the link's own
settings (decision 0031), from the outside: over ``sim://``, TCP loopback to a simulator server
(the message handle claimed with ``CF I``), and a pty to a ``galil sim`` child process.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import pytest
from client_fakes import SimLinkWrapper

import galil
from galil.errors import GalilConnectionError, GalilError
from galil.protocol.commands import Command
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import open_transport
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, sim_of, simulated, transcript

AUTO = '#AUTO\nMG "hello"\nEN\n'

REFUSED = [
    "RS",
    "RS -1",
    "RS 0",
    "\x12\x13",
    "CW 2",
    "CW1",
    "CW ,1",
    "EO 1",
    "EO 0",
    "EO",
    "CF S",
    "CFI",
    "IHS=>-1",
    "IHT=>-3",
    "MG 1;RS",
]


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as c:
        yield c


@pytest.mark.parametrize("text", REFUSED)
def test_a_raw_command_that_breaks_the_link_is_refused_unsent_and_says_what_to_use(
    dmc: galil.Controller, text: str
) -> None:
    for send in (
        lambda: dmc.command(text, allow_compound=True),
        lambda: dmc.command_line(text.split(";")),
        lambda: dmc.query_number(text),
        lambda: dmc.send(Command(text)),
        lambda: dmc.send_many([Command(text)]),
        lambda: dmc.link.command(text, allow_compound=True),
    ):
        with (
            nothing_sent(dmc),
            pytest.raises(galil.InvalidArgument, match=r"not sent: .*(use|read it with)"),
        ):
            send()
    assert dmc.query_number("MG _CW") == 1.0  # the link's settings are as they were


@pytest.mark.parametrize(
    "text", ["CW ?", "CW", "CW 0", "EO ?", "MG _CW", "MG _EO", "RSVAL=1", "IHC=>-1"]
)
def test_queries_of_the_link_settings_and_lookalike_names_still_go_out(
    dmc: galil.Controller, text: str
) -> None:
    # (a CommandError is the simulator's own answer, no handle C: the line went out)
    with transcript(dmc) as sent, contextlib.suppress(galil.CommandError):
        dmc.command(text)
    assert sent.lines[0] == text


def test_rs_sent_raw_on_main_broke_replies_now_reset_keeps_them_in_step(
    dmc: galil.Controller,
) -> None:
    dmc.programs.download(AUTO)
    dmc.programs.burn()  # RS brings back the burned program only
    dmc.reset()
    assert dmc.query_number("MG 0") == 0.0  # (on main: ProtocolError 'hello\r\n 0.0000')
    assert dmc.messages.get(timeout=1) == "hello"  # a message, not a reply
    assert dmc.query_number("MG _CW") == 1.0
    dmc.close()
    assert sim_of(dmc).feed(b"MG _CW\r") == b" 2.0000\r\n:"  # close restored the burned CW


def test_reset_ends_the_moves_drops_gearing_and_forgets_homing_and_routines(
    dmc: galil.Controller,
) -> None:
    gear = dmc.B.gear_to("A", 0.5)
    assert gear.engaged
    handle = dmc.A.jog(20_000)
    dmc.sleep(0.1)
    dmc.reset()
    assert handle.finished
    assert handle.result is not None
    assert handle.result.stop_codes == {"A": 4}  # ended as a stop would
    assert not gear.engaged
    assert dmc.tracker.gears == {}
    dmc.servo_here()
    result = dmc.B.move_by(1000).wait()  # not refused as geared; exact
    assert result.deviation == {"B": 0}
    assert dmc.routines.threads == {}
    assert not dmc.A.homed


def test_a_move_after_reset_runs_as_predicted_at_the_burned_sample_time(
    dmc: galil.Controller,
) -> None:
    dmc.command("TM 500")
    assert dmc.sample_period == pytest.approx(500 / 1_024_000)
    dmc.reset()
    assert dmc.sample_period == pytest.approx(1000 / 1_024_000)  # TM read again
    dmc.servo_here()
    handle = dmc.A.move_by(5000)
    assert handle.wait().deviation == {"A": 0}


def test_the_watchdog_guards_again_after_reset(dmc: galil.Controller) -> None:
    dog = dmc.watchdog(1.0)
    dmc.reset()
    assert dog.beating
    assert dog.running
    assert dmc.routines.threads == {dog.thread: "#GWDOG"}
    dog.stop()


def test_reset_refuses_a_bad_timeout_unsent(dmc: galil.Controller) -> None:
    for bad in (-1, float("nan"), "x", True, 0):
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.reset(timeout=bad)  # type: ignore[arg-type]


def test_a_closed_controller_cannot_be_reset() -> None:
    with simulated() as c:
        pass
    with pytest.raises(galil.GalilConnectionError):
        c.reset()


def test_the_terminal_resets_on_rs_and_refuses_the_link_settings(dmc: galil.Controller) -> None:
    from galil.terminal import Terminal

    out: list[str] = []
    term = Terminal(dmc, write=out.append)
    dmc.programs.download(AUTO)
    dmc.programs.burn()  # RS brings back the burned program only
    term.feed("RS")
    assert out[-1].startswith("reset (RS)")
    term.feed("CW 2")
    assert out[-1].startswith("not sent: ")
    assert "MG _CW" in out[-1]
    term.feed("MG 7")
    assert out[-1] == " 7.0000"
    assert dmc.messages.get(timeout=1) == "hello"


def test_over_tcp_the_message_handle_is_claimed_again_after_reset() -> None:
    sim = SimController("DMC-4040", RealTimeClock(speed=8.0))
    with SimTcpServer(sim) as server, galil.connect(server.url, timeout=2.0) as c:
        # What #AUTO prints before CF I is sent again goes to the main port (RS set CF back
        # to S): lost on Ethernet. Printed 4 s later (0.5 s here), it reaches the handle.
        c.programs.download('#AUTO\nWT 4000\nMG "hello"\nEN\n')
        c.programs.burn()
        c.reset()
        assert c.messages.get(timeout=5) == "hello"
        assert c.query_number("MG 2") == 2.0
        c.servo_here()
        assert c.A.move_by(2000).wait(timeout=5).deviation == {"A": 0}


def test_over_a_pty_auto_output_stays_a_message_after_reset(
    galil_sim: Callable[..., str],
) -> None:
    if not hasattr(os, "openpty"):
        pytest.skip("needs a pty")
    with galil.connect(galil_sim("--pty"), timeout=2.0) as c:
        c.programs.download(AUTO)
        c.programs.burn()
        c.reset()
        assert c.messages.get(timeout=5) == "hello"
        assert c.query_number("MG 3") == 3.0
        with pytest.raises(galil.InvalidArgument):
            c.command("EO 1")


@dataclass
class _DiesAtBegin(SimLinkWrapper):
    """The simulator's link; at the first ``BG`` written it calls ``on_death`` (once), then
    fails as a pulled cable does."""

    on_death: Callable[[], None] | None = None

    def write(self, data: bytes) -> None:
        if b"BG" in data and self.on_death is not None:
            hook, self.on_death = self.on_death, None
            hook()
            raise GalilConnectionError("the cable was pulled")
        self.inner.write(data)


def test_a_reset_while_another_threads_start_loses_the_link_does_not_deadlock() -> None:
    # The start holds the tracker's lock and wants the life lock to reopen the link for its
    # stop; reset() holds the life lock and wants the tracker's for its ST.
    sim = SimController("DMC-4040", ManualClock())
    wires: list[_DiesAtBegin] = []

    def opener() -> _DiesAtBegin:
        wires.append(_DiesAtBegin(open_transport("sim://DMC-4040", controller=sim)))
        return wires[-1]

    dmc = galil.Controller(opener, timeout=0.2, reconnect=False)
    resetter = threading.Thread(target=lambda: _quietly(dmc.reset), daemon=True)

    def reset_meanwhile() -> None:
        resetter.start()
        while dmc._life.acquire(blocking=False):  # until reset() holds the life lock
            dmc._life.release()
            time.sleep(0.001)

    wires[-1].on_death = reset_meanwhile
    caught: list[BaseException] = []
    mover = threading.Thread(target=lambda: _quietly(lambda: dmc.A.move_by(1000), caught))
    mover.daemon = True
    mover.start()
    mover.join(5)
    resetter.join(5)
    assert not mover.is_alive(), "deadlocked"
    assert not resetter.is_alive(), "deadlocked"
    assert len(caught) == 1
    assert isinstance(caught[0], GalilError)
    dmc.close()


def _quietly(call: Callable[[], object], caught: list[BaseException] | None = None) -> None:
    try:
        call()
    except GalilError as exc:
        if caught is not None:
            caught.append(exc)


def test_a_start_from_another_thread_during_reset_runs_after_it_not_killed_by_rs(
    dmc: galil.Controller,
) -> None:
    handles: list[galil.MoveHandle] = []
    mover = threading.Thread(target=lambda: handles.append(dmc.B.move_by(1000)))
    suspend = dmc.records_room.suspend

    def start_a_move_meanwhile() -> None:  # (between reset()'s stop and its RS)
        mover.start()
        mover.join(0.5)  # long enough for the start to go out, unless it has to wait
        suspend()

    dmc.records_room.suspend = start_a_move_meanwhile  # type: ignore[method-assign]
    dmc.reset()
    mover.join(5)
    assert not mover.is_alive()
    (handle,) = handles
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a move RS ended would end away from its prediction
        result = handle.wait()
    assert result.final == result.predicted == {"B": 1000}


@pytest.mark.parametrize("other", ["close", "reset"])
def test_the_automatic_reconnect_inside_a_start_does_not_deadlock_a_close_or_reset(
    other: str,
) -> None:
    # The start holds the tracker's lock and its link's automatic reconnect wants the life
    # lock; close() or reset() in another thread holds the life lock and wants the tracker's.
    sim = SimController("DMC-4040", ManualClock())
    wires: list[_DiesAtBegin] = []

    def opener() -> _DiesAtBegin:
        wires.append(_DiesAtBegin(open_transport("sim://DMC-4040", controller=sim)))
        return wires[-1]

    policy = galil.ReconnectPolicy(attempts=2, delay=0.01)
    dmc = galil.Controller(opener, timeout=0.2, reconnect=policy)
    closer = threading.Thread(target=lambda: _quietly(getattr(dmc, other)), daemon=True)

    def close_meanwhile() -> None:
        closer.start()
        while dmc._life.acquire(blocking=False):  # until the other thread holds the life lock
            dmc._life.release()
            time.sleep(0.001)

    wires[-1].on_death = close_meanwhile
    mover = threading.Thread(target=lambda: _quietly(lambda: dmc.A.move_by(1000)), daemon=True)
    mover.start()
    mover.join(10)
    closer.join(10)
    assert not mover.is_alive(), "deadlocked"
    assert not closer.is_alive(), "deadlocked"
    dmc.close()


@pytest.mark.parametrize("failures", [1, 2])
def test_a_reset_interrupted_half_way_leaves_streams_interrupts_and_the_link_working(
    monkeypatch: pytest.MonkeyPatch, failures: int
) -> None:
    # Ctrl-C at the handshake after RS; with 2, again at the handshake that sets the link up
    # after the failure: the stream then ends saying so, rather than waiting for ever.
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as srv, galil.connect(srv.url, timeout=2.0) as c:
        stream = c.records(8)
        c.interrupts.enable("A")
        transport = c.link.transport
        assert transport is not None
        write = transport.write
        hits: list[bytes] = []

        def ctrl_c_at_the_handshake(data: bytes) -> None:
            if data.startswith(b"\x12\x16") and len(hits) < failures:  # ^R^V
                hits.append(data)
                raise KeyboardInterrupt
            write(data)

        monkeypatch.setattr(transport, "write", ctrl_c_at_the_handshake)
        with pytest.raises(KeyboardInterrupt):
            c.reset()
        assert len(hits) == failures
        if failures == 2:
            with pytest.raises(GalilConnectionError, match="a reset failed"):
                stream.get(timeout=2.0)
            assert not c.interrupts.enabled
            c.reconnect()
        assert c.query_number("MG 2") == 2.0
        srv.advance(0.05)
        assert len(stream.take(3, timeout=2.0)) == 3
        assert c.interrupts.enabled
        assert "open" in repr(c)
