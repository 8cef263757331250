"""Unsolicited output: split out of replies, polled while idle, queued, delivered to subscribers."""

from __future__ import annotations

import queue
import threading

import pytest
from client_fakes import FakeGalil

import galil
from galil.controller import Controller, connect
from galil.errors import (
    InvalidArgument,
)
from galil.testing import simulated


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
