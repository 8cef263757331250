"""Unsolicited output: split out of replies, polled while idle, queued, delivered to subscribers."""

from __future__ import annotations

import queue
import socket
import threading
import time
from collections.abc import Callable

import pytest
from client_fakes import FakeGalil
from test_message_handles_tcp import HandleServer

import galil
from galil.controller import Controller, connect
from galil.errors import (
    InvalidArgument,
)
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import sim_of, simulated


def test_unsolicited_inside_a_reply_is_split_out(c: Controller, peer: FakeGalil) -> None:
    peer.extra = lambda cmd: (
        " 4" + "".join(chr(b | 0x80) for b in b"hello\r\n") + "2\r\n:" if cmd == "MG 42" else None
    )
    assert c.command("MG 42") == " 42"
    assert c.messages.get(timeout=1) == "hello"
    assert any("hello" in r and "unsolicited" in r for r in c.recent)


def test_messages_arrive_while_idle(c: Controller, peer: FakeGalil) -> None:
    q = c.messages
    peer.emit("done moving")
    assert q.get(timeout=2) == "done moving"
    with pytest.raises(queue.Empty):
        q.get(timeout=0.01)
    with pytest.raises(queue.Empty):
        q.get_nowait()


def test_a_queue_wait_that_times_out_is_a_galil_timeout_error_and_still_a_queue_empty() -> None:
    with simulated("DMC-4040") as dmc, dmc.records(32) as stream:
        stream.get()  # (the first record is due at once: the next, 32 samples on)
        for get in (
            dmc.messages.get,
            dmc.interrupts.get,
            stream.get,
            lambda timeout: dmc.messages.get_nowait(),
        ):
            with pytest.raises(galil.GalilTimeoutError, match=r"^no \w[\w -]* (within|waiting)"):
                get(timeout=0)
            with pytest.raises(queue.Empty):  # (code written for the stdlib queue's error)
                get(timeout=0)
            with pytest.raises(TimeoutError):
                get(timeout=0)


def test_subscribers_get_lines_and_may_send_commands(c: Controller, peer: FakeGalil) -> None:
    got: list[tuple[str, str]] = []
    event = threading.Event()

    def callback(line: str) -> None:
        got.append((line, c.command("MG 9")))  # no deadlock: called outside the link lock
        event.set()

    def broken(line: str) -> None:
        raise RuntimeError("callback bug")

    unsubscribe = c.subscribe(callback)
    c.subscribe(broken)
    peer.emit("hi")
    assert event.wait(2)
    assert got == [("hi", " 9")]
    unsubscribe()
    peer.emit("again")
    assert c.messages.get(timeout=2) == "hi"
    assert c.messages.get(timeout=2) == "again"
    assert got == [("hi", " 9")]
    with pytest.raises(InvalidArgument):
        c.subscribe("nope")  # type: ignore[arg-type]


def test_message_queue_is_bounded(peer: FakeGalil) -> None:
    c = connect("fakegalil://x", timeout=0.2, max_messages=3)
    for i in range(5):
        peer.emit(f"m{i}", marked=True)
    c.command("MG 0")
    assert c.messages_room.queue.drain() == ["m2", "m3", "m4"]
    assert c.messages_room.queue.dropped == 2
    assert "dropped" in repr(c.messages_room.queue)
    c.close()


# -- a wait for messages when their source dies ----------------------------------------------


class _Waiter:
    """``queue.get(timeout)`` on a thread of its own; ``outcome`` is what it returned or
    raised."""

    def __init__(self, get: Callable[[], object]) -> None:
        self.outcome: object = None
        self.done = threading.Event()
        self._get = get
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.outcome = self._get()
        except BaseException as exc:  # (what the test checks)
            self.outcome = exc
        self.done.set()


def _served(srv: HandleServer) -> Controller:
    c = connect(f"tcp://127.0.0.1:{srv.port}", timeout=0.5)
    assert srv.claimed.wait(2)
    return c


def test_a_message_wait_raises_once_the_controller_goes_away_over_tcp() -> None:
    srv = HandleServer()
    c = _served(srv)
    try:
        waiter = _Waiter(lambda: c.messages.get(timeout=30))
        srv.close()  # the controller goes away: both handles close
        assert waiter.done.wait(5), "messages.get() still waits"
        assert isinstance(waiter.outcome, galil.GalilConnectionError)
        assert "link died" in str(waiter.outcome)
        assert c.link.dead
        assert "dead" in repr(c)
        with pytest.raises(galil.GalilConnectionError, match="link died"):
            c.messages.get(timeout=30)  # at once: none will come
    finally:
        c.close()


def test_a_message_handle_closed_alone_ends_the_wait_and_reconnect_brings_messages_back() -> None:
    srv = HandleServer()
    c = _served(srv)
    try:
        waiter = _Waiter(lambda: c.messages.get(timeout=30))
        assert srv.message_handle is not None
        srv.claimed.clear()
        srv.message_handle.shutdown(socket.SHUT_RDWR)  # the message handle alone closes
        assert waiter.done.wait(5), "messages.get() still waits"
        assert isinstance(waiter.outcome, galil.GalilConnectionError)
        assert "while the command link works; call reconnect()" in str(waiter.outcome)
        assert not c.link.dead
        assert c.command("MG 3") == " 3"  # the command link works
        c.reconnect()
        assert srv.claimed.wait(2)
        srv.emit("back")
        assert c.messages.get(timeout=2) == "back"
    finally:
        c.close()
        srv.close()


def test_a_message_wait_raises_once_a_serial_like_link_dies() -> None:
    with simulated("DMC-4040") as dmc:
        waiter = _Waiter(lambda: dmc.messages.get(timeout=30))
        dmc.transport.close()  # the port goes away under the poll of the idle link
        assert waiter.done.wait(5), "messages.get() still waits"
        assert isinstance(waiter.outcome, galil.GalilConnectionError)
        assert "link died" in str(waiter.outcome)
        assert dmc.link.dead


def test_a_message_wait_on_a_link_that_dies_reconnects_with_reconnect_on() -> None:
    policy = galil.ReconnectPolicy(attempts=3, delay=0.01)
    with simulated("DMC-4040", reconnect=policy) as dmc:
        sim = sim_of(dmc)
        waiter = _Waiter(lambda: dmc.messages.get(timeout=30))
        old = dmc.transport
        old.close()  # the link dies; the waiting get() alone finds it out
        deadline = time.monotonic() + 5
        while dmc.transport is old or dmc.link.dead:
            assert time.monotonic() < deadline, "the link was not reopened"
            time.sleep(0.01)  # (a thread's work, not motion)
        sim.emit_message("after the reconnect")
        assert waiter.done.wait(5), "messages.get() still waits"
        assert waiter.outcome == "after the reconnect"


def test_an_interrupt_wait_raises_once_the_controller_goes_away() -> None:
    sim = SimController("DMC-4040", RealTimeClock())
    with SimTcpServer(sim) as server:
        c = connect(server.url, timeout=0.5)
        try:
            c.interrupts.enable(axes="A")
            waiter = _Waiter(lambda: c.interrupts.get(timeout=30))
            server.stop()  # the controller goes away with every handle
            assert waiter.done.wait(5), "interrupts.get() still waits"
            assert isinstance(waiter.outcome, galil.GalilConnectionError)
        finally:
            c.close()
