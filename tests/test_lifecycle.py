"""Life cycle: what a long-lived kernel sees after many connects and closes, after a close()
from another thread, after a controller dropped unclosed, after a `with` block that raised.

Every background thread and socket a controller starts ends with close(); a call waiting on
another thread ends with GalilConnectionError; the motion the library started is stopped.
"""

from __future__ import annotations

import asyncio
import gc
import os
import queue
import re
import threading
import time
import tracemalloc
import warnings
from collections.abc import Callable, Iterator

import numpy as np
import pytest

import galil
import galil.aio
from galil.controller import Controller
from galil.errors import GalilConnectionError, MotionError
from galil.link import Link
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.server import SimPtyServer, SimTcpServer
from galil.testing import sim_of, transcript

CYCLES = 20
JOIN = 5.0  # seconds a thread waiting on a closed controller may take to end (it takes ms)


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _fds_back_to(fds: int) -> bool:
    """Whether the open descriptors come back to ``fds`` (an in-process server closes its
    side of a socket on its next tick)."""
    deadline = time.monotonic() + JOIN
    while _fds() > fds and time.monotonic() < deadline:
        time.sleep(0.01)
    return _fds() <= fds


def _moving(sim: SimController, axis: str) -> bool:
    reply = sim.feed(f"MG _BG{axis}\r".encode())
    return float(reply.split(b"\r")[0]) != 0


def _stops_sent(sim: SimController) -> list[str]:
    return [text for _, text in sim.command_log if text.startswith("ST")]


Opener = tuple[str, Callable[[], Controller], SimController | None]


@pytest.fixture(params=["sim", "tcp", "pty"])
def opener(request: pytest.FixtureRequest) -> Iterator[Opener]:
    """A way to connect, and how: in-process, over TCP and over a pty (manual clocks); the
    served simulator (``None``: a new one in-process for each connect)."""
    if request.param == "sim":
        yield "sim", lambda: galil.connect("sim://DMC-4040"), None
        return
    sim = SimController("DMC-4040", ManualClock())
    server: SimTcpServer | SimPtyServer
    if request.param == "tcp":
        with SimTcpServer(sim) as server:
            url = server.url
            yield "tcp", lambda: galil.connect(url, timeout=2.0), sim
    else:
        with SimPtyServer(sim) as server:
            path = server.path
            yield "pty", lambda: galil.connect(path, timeout=2.0), sim


def _busy_cycle(kind: str, c: Controller, served: SimController | None) -> None:
    """Start everything that runs in the background, then close with all of it running."""
    c.command("SH")
    stream = c.records(period=64, method="DR" if kind == "tcp" else "QR")
    if kind != "tcp":
        stream.get(timeout=0.5)
    c.capture(["_RPA"], every=2, count=50)
    c.A.move_by(1000).add_callback(lambda h: None)
    c.subscribe(lambda line: None)
    assert isinstance(c.messages, galil.MessageQueue)
    c.watchdog(5.0)
    c.close()
    # Let the stop and the capture end (a new in-process simulator has none of them).
    if served is not None:
        served.advance(0.5)


def test_connect_close_cycles_leave_nothing_behind(
    opener: Opener,
) -> None:
    kind, connect, served = opener
    for _ in range(3):  # imports, caches, the server's first handles
        _busy_cycle(kind, connect(), served)
    threads, fds = threading.active_count(), _fds()
    tracemalloc.start()
    try:
        growth = []
        for i in range(CYCLES):
            _busy_cycle(kind, connect(), served)
            assert threading.active_count() == threads, threading.enumerate()
            # (an in-process server closes its side of a socket on its next tick)
            assert _fds() <= fds + 3
            if i in (4, CYCLES - 1):
                gc.collect()
                snap = tracemalloc.take_snapshot().filter_traces(
                    [
                        tracemalloc.Filter(False, "*/galil/sim/*"),
                        tracemalloc.Filter(False, "*/predict/*"),
                        # re's cache of compiled patterns is bounded (512); late in a full
                        # run it is full, and one resize of its table (36 kB, counted once
                        # between the two snapshots) read as 2.4 kB kept per cycle.
                        tracemalloc.Filter(False, re.__file__),
                    ]
                )
                growth.append(sum(s.size for s in snap.statistics("filename")))
    finally:
        tracemalloc.stop()
    assert _fds_back_to(fds)
    per_cycle = (growth[1] - growth[0]) / (CYCLES - 5)
    assert per_cycle < 2048, f"{per_cycle:.0f} bytes kept per connect/close cycle"


def _in_thread(call: Callable[[], object]) -> tuple[threading.Thread, list[BaseException]]:
    raised: list[BaseException] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:
            raised.append(exc)

    t = threading.Thread(target=run, name="lifecycle-waiter")
    t.start()
    return t, raised


def _close_under(
    c: Controller,
    call: Callable[[], object],
    ready: Callable[[], bool],
    expected: tuple[type[Exception], ...] = (GalilConnectionError,),
) -> None:
    """close() while ``call`` blocks on another thread: it ends promptly, typed."""
    t, raised = _in_thread(call)
    deadline = time.monotonic() + JOIN
    while not ready() and time.monotonic() < deadline:
        time.sleep(0.01)  # the other thread reaching its wait (no motion is waited for)
    time.sleep(0.05)
    c.close()
    t.join(JOIN)
    assert not t.is_alive(), "a call waiting on a closed controller did not end"
    assert len(raised) == 1, raised
    assert isinstance(raised[0], expected), raised


@pytest.fixture
def tcp() -> Iterator[tuple[SimController, Controller]]:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as server:
        c = galil.connect(server.url, timeout=2.0)
        try:
            yield sim, c
        finally:
            c.close()


def test_close_ends_a_wait_on_a_move_and_stops_it(tcp: tuple[SimController, Controller]) -> None:
    sim, c = tcp
    c.command("SH")
    move = c.A.move_by(500_000)  # the manual clock stands still: it never ends by itself
    _close_under(c, lambda: move.wait(timeout=30), lambda: True)
    assert _stops_sent(sim) == ["ST A"]
    sim.advance(2.0)
    assert not _moving(sim, "A")


def test_close_ends_a_jog_nobody_waits_for(tcp: tuple[SimController, Controller]) -> None:
    sim, c = tcp
    c.command("SH")
    c.B.jog(20_000)
    c.close()
    assert _stops_sent(sim) == ["ST B"]
    sim.advance(2.0)
    assert not _moving(sim, "B")


def test_close_stops_a_capture_still_recording_so_the_next_one_may_start() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with Controller(SimLink(sim)) as c:
        c.capture(["_RPA"], every=256, count=1000)  # about 250 s: still recording at close
    assert sim.feed(b"MG _RC\r") == b" 0.0000\r\n:"
    with Controller(SimLink(sim)) as c:
        c.capture(["_RPA"], every=2, count=10).wait()  # refused while the first recorded
    with Controller(SimLink(sim)) as c, transcript(c) as sent:
        c.capture(["_RPA"], every=2, count=10).wait()
        c.close()
    assert "RC 0" not in sent.lines  # one read back: nothing to stop


def test_close_leaves_motion_the_library_did_not_start(
    tcp: tuple[SimController, Controller],
) -> None:
    sim, c = tcp
    c.command("SH")
    c.command("JG ,,1000")
    c.command("BG C")  # a raw command: the user's motion, not the library's
    c.close()
    assert _stops_sent(sim) == []
    assert _moving(sim, "C")


def test_close_ends_record_message_and_interrupt_waits(
    tcp: tuple[SimController, Controller],
) -> None:
    _sim, c = tcp
    stream = c.records(period=64)
    c.interrupts.enable("A")
    messages = c.messages
    waits: list[Callable[[], object]] = [
        lambda: stream.get(),
        lambda: messages.get(),
        lambda: c.interrupts.get(),
    ]
    threads = [_in_thread(w) for w in waits]
    time.sleep(0.1)  # each thread reaching its wait
    c.close()
    for t, raised in threads:
        t.join(JOIN)
        assert not t.is_alive()
        assert len(raised) == 1, raised
        assert isinstance(raised[0], GalilConnectionError), raised
    with pytest.raises(GalilConnectionError, match="closed"):
        messages.get(timeout=0)


def test_messages_queue_lives_again_after_a_reconnect() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as server, galil.connect(server.url, timeout=2.0) as c:
        c.reconnect()
        with pytest.raises(queue.Empty):
            c.messages.get(timeout=0)


@pytest.mark.parametrize("address", ["sim://DMC-4040", "sim://DMC-4040?messages=separate"])
def test_a_reconnect_on_sim_finds_the_same_controller(address: str) -> None:
    with galil.connect(address) as c:
        c.A.move_by(1000).wait()
        c.command("gv=42")
        c.programs.download("#A\nEN")
        c.reconnect()  # as a reconnect to a real controller: positions, variables, program
        assert c.query_operands(["_RPA", "gv"]) == [1000, 42]
        assert "#A" in c.programs.upload()
        c.A.move_by(-500).wait()
        assert c.A.reference_position == 500


def test_close_ends_a_program_wait(tcp: tuple[SimController, Controller]) -> None:
    _sim, c = tcp
    c.programs.download("#A\nWT 10\nJP #A\nEN")
    c.programs.run("#A")
    _close_under(c, lambda: c.programs.wait(timeout=3600), lambda: True)


def test_close_ends_a_contour_and_stops_it(tcp: tuple[SimController, Controller]) -> None:
    sim, c = tcp
    c.command("SH")
    path = np.cumsum(np.full(3000, 20.0))  # six buffers: it streams until closed

    def fed() -> bool:
        return any(text.startswith("CD") for _, text in sim.command_log)

    # The stream ends on the closed link, or on the stop close() sent first (MotionError);
    # never on a CD the controller refused after the ST (TC 41).
    _close_under(c, lambda: c.contour("D", path, dt=3), fed, (GalilConnectionError, MotionError))
    assert "ST D" in _stops_sent(sim)
    sim.advance(2.0)
    assert not _moving(sim, "D")


def test_a_stop_of_a_started_contour_does_not_enter_contour_mode_again(
    tcp: tuple[SimController, Controller],
) -> None:
    # A pre-loaded stream drops its held segments with CM when it is stopped, but once the
    # contour has started nothing is held: a CM after the ST only entered contour mode
    # again, and a close() between it and the end left the axis there (_BG 1 for good: the
    # close test above failed so, now and then).
    sim, c = tcp
    c.command("SH")
    path = np.cumsum(np.full(3000, 20.0))  # six buffers: it streams until stopped

    def fed() -> bool:
        return any(text.startswith("CD") for _, text in sim.command_log)

    t, raised = _in_thread(lambda: c.contour("D", path, dt=3))
    deadline = time.monotonic() + JOIN
    while not fed() and time.monotonic() < deadline:
        time.sleep(0.01)  # the stream feeding (its start went out with the first batch)
    time.sleep(0.05)
    c.stop("D")
    t.join(JOIN)
    assert not t.is_alive()
    assert len(raised) == 1, raised
    assert isinstance(raised[0], MotionError), raised
    log = [text for _, text in sim.command_log]
    stop = next(i for i, text in enumerate(log) if text.startswith("ST"))
    assert not [text for text in log[stop:] if text.startswith("CM")]
    sim.advance(2.0)
    assert not _moving(sim, "D")


def test_with_block_left_by_an_exception_stops_the_move_and_closes() -> None:
    with (  # noqa: PT012 - the block is the scan that fails
        pytest.raises(RuntimeError, match="scan failed"),
        galil.connect("sim://DMC-4040") as c,
    ):
        sim = sim_of(c)
        c.command("SH")
        c.A.move_by(100_000)
        raise RuntimeError("scan failed")
    assert c.closed
    assert _stops_sent(sim) == ["ST A"]
    sim.advance(2.0)
    assert not _moving(sim, "A")


def _forget(held: list[Controller]) -> None:
    held.clear()
    gc.collect()


def test_an_unclosed_controller_warns_and_is_closed_when_collected() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as server:
        gc.collect()  # what earlier tests left to the collector
        threads, fds = set(threading.enumerate()), _fds()
        held = [galil.connect(server.url, timeout=2.0, reconnect=True)]
        held[0].subscribe(lambda line: None)
        held[0].records(period=64)
        started = set(threading.enumerate()) - threads
        assert started  # the message and record readers
        with pytest.warns(ResourceWarning, match="never closed"):
            _forget(held)
        for t in set(threading.enumerate()) - threads:
            t.join(JOIN)  # the readers, and the thread that closes them
        assert set(threading.enumerate()) <= threads
        assert _fds_back_to(fds)


def test_a_closed_controller_is_collected_quietly() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = galil.connect("sim://DMC-4040")
        c.close()
        del c
        gc.collect()


@pytest.mark.parametrize("trial", range(24))
def test_async_close_ends_a_watch_and_stops_the_move(trial: int) -> None:
    """Whenever the watch's poll meets close() (before its stops, during them, after), the
    watch ends with close()'s GalilConnectionError, never a MotionError saying the axes could
    not be stopped: close() stops them (the race went wrong in about one run of six, so the
    test runs it two dozen times)."""

    async def main() -> tuple[list[BaseException], SimController]:
        c = await galil.aio.connect("sim://DMC-4040")
        sim = sim_of(c.sync)
        await c.command("SH")
        move = await c.A.jog(20_000)
        raised: list[BaseException] = []

        async def watch() -> None:
            try:
                async for _ in move.watch():
                    pass
            except BaseException as exc:
                raised.append(exc)

        task = asyncio.create_task(watch())
        await asyncio.sleep(0.003 * (trial + 1))  # (close() meets the polls at many points)
        await c.aclose()
        await asyncio.wait_for(task, JOIN)
        for t in c.worker.threads:
            t.join(JOIN)
        return raised, sim

    raised, sim = asyncio.run(main())
    # (its polls let simulated time pass, but one that finds the stop over once close() has
    # begun is not taken as the jog's end)
    assert len(raised) == 1, raised
    assert isinstance(raised[0], GalilConnectionError), raised
    assert "ST A" in _stops_sent(sim)


def _close_waits_for_the_watcher(
    monkeypatch: pytest.MonkeyPatch, c: Controller, watcher_over: Callable[[], bool]
) -> None:
    """Force the interleaving in which a move's watcher polls it between close()'s stop and
    the link closing: close() sends its stops, lets them take effect (simulated time passes,
    as real time would on hardware) and closes the link only once the watcher has ended: its
    polls from then on find the move at rest, and it ends when one is taken as the move's end
    (the race lost) or refused (close() has begun)."""
    stop_started = c.tracker.stop_started

    def stop_then_let_the_watcher_poll(on: Link) -> str:
        failed = stop_started(on)
        c.link.pause(0.5)
        assert watcher_over(), "the move's watcher did not end"
        return failed

    monkeypatch.setattr(c.tracker, "stop_started", stop_then_let_the_watcher_poll)


def test_close_drops_the_callbacks_of_a_move_it_stops_even_if_its_watcher_sees_it_end_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    c = galil.connect("sim://DMC-4040")
    move = c.A.move_to(200_000)
    called: list[object] = []
    move.add_callback(called.append)
    watcher = move._watcher
    assert watcher is not None

    def watcher_over() -> bool:
        assert watcher is not None
        watcher.join(JOIN)  # (it polls every 50 ms of real time)
        return not watcher.is_alive()

    _close_waits_for_the_watcher(monkeypatch, c, watcher_over)
    c.close()
    assert called == []
    assert not move.finished
    with pytest.raises(GalilConnectionError):
        move.wait()


def test_async_close_drops_the_callbacks_of_a_move_it_stops_even_if_its_watcher_sees_it_end_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    async def main() -> tuple[bool, list[object]]:
        c = await galil.aio.connect("sim://DMC-4040")
        move = await c.A.move_to(200_000)
        called: list[object] = []
        move.add_callback(called.append)
        watcher = move._watcher
        assert watcher is not None
        ended = threading.Event()
        watcher.add_done_callback(lambda _: ended.set())
        _close_waits_for_the_watcher(monkeypatch, c.sync, lambda: ended.wait(JOIN))
        await c.aclose()
        await watcher
        return move.finished, called

    assert asyncio.run(main()) == (False, [])


def test_closing_on_motion_nobody_waited_for_warns_naming_the_axes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # A script that leaves its with block without wait() sees its stage barely move: the
    # stop close() sends is said, once, at WARNING.
    with caplog.at_level("WARNING", logger="galil.controller"):
        with galil.connect("sim://DMC-4040") as c:
            c.A.move_by(10_000)
            c.C.jog(1000)
            sim = sim_of(c)
        assert sorted(_stops_sent(sim)) == ["ST A", "ST C"]
    (record,) = [r for r in caplog.records if "mid-motion" in r.getMessage()]
    assert record.levelname == "WARNING"
    assert "axes A, C mid-motion" in record.getMessage()
    assert "wait()" in record.getMessage()


def test_closing_after_an_exception_warns_that_the_exception_stopped_the_motion(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # The block ended with an exception: stopping was the point, and wait() no advice.
    def jog_then_fail(c: galil.Controller) -> None:
        c.A.jog(10_000)
        c.sleep(0.1)
        raise KeyError("boom")

    with caplog.at_level("WARNING", logger="galil.controller"):
        c = galil.connect("sim://DMC-4040")
        sim = sim_of(c)
        with pytest.raises(KeyError), c:
            jog_then_fail(c)
    assert _stops_sent(sim) == ["ST A"]
    (record,) = [r for r in caplog.records if "mid-motion" in r.getMessage()]
    assert "axes A mid-motion" in record.getMessage()
    assert "the with block ended with an exception (KeyError)" in record.getMessage()
    assert "wait()" not in record.getMessage()


def test_leaving_an_async_with_block_on_an_exception_warns_that_it_stopped_the_motion(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async def main() -> None:
        async with await galil.aio.connect("sim://DMC-4040") as c:
            await c.A.jog(10_000)
            await c.sleep(0.1)
            raise KeyError("boom")

    with caplog.at_level("WARNING", logger="galil.controller"), pytest.raises(KeyError):
        asyncio.run(main())
    (record,) = [r for r in caplog.records if "mid-motion" in r.getMessage()]
    assert "the with block ended with an exception (KeyError)" in record.getMessage()
    assert "wait()" not in record.getMessage()


def test_closing_while_a_stopped_move_decelerates_warns_only_of_the_unstopped_axes(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # A wait cancelled or timed out (async) sends the move's ST: nothing was left running
    # unwaited for on that axis, though it still decelerates when close() comes.
    with (
        caplog.at_level("WARNING", logger="galil.controller"),
        galil.connect("sim://DMC-4040") as c,
    ):
        c.C.speed = 200_000
        c.C.decel = 20_000
        stopped = c.C.move_by(2_000_000)
        c.A.move_by(10_000)
        c.sleep(0.05)
        stopped.stop()
        c.sleep(0.05)
        assert c.C.moving  # decelerating
    (record,) = [r for r in caplog.records if "mid-motion" in r.getMessage()]
    assert "axes A mid-motion" in record.getMessage()


@pytest.mark.parametrize("how", ["waited", "over by its prediction", "a jog a limit stopped"])
def test_closing_after_the_motion_is_over_says_nothing(
    how: str, caplog: pytest.LogCaptureFixture
) -> None:
    with (
        caplog.at_level("WARNING", logger="galil.controller"),
        galil.connect("sim://DMC-4040") as c,
    ):
        if how == "a jog a limit stopped":  # (a jog has no predicted end: _BG is read)
            c.A.soft_limits = (-100_000, 500)
            c.A.jog(20_000)
            c.sleep(1.0)
        else:
            h = c.A.move_by(1000)
            if how == "waited":
                h.wait()
            else:
                c.sleep(h.duration + 0.01)
    assert not [r for r in caplog.records if "mid-motion" in r.getMessage()]
