"""Real loopback peers for the transport tests: a TCP server and pty pairs.

Imported by name (pytest puts this directory on sys.path); fixtures are re-exported by conftest.
Each peer also exists as a context manager, so that the contract rigs can build one without a
fixture.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest


def answer(command: bytes) -> bytes:
    """A tiny Galil-like responder: ``MG x`` -> `` x\\r\\n:``, lower case -> ``?``, else ``:``."""
    text = command.strip()
    if text.startswith(b"MG "):
        return b" " + text[3:] + b"\r\n:"
    if text[:1].islower():
        return b"?"
    return b":"


class LineAnswerer:
    """Turns an incoming byte stream into answers, one per CR-terminated command."""

    def __init__(self, respond: Callable[[bytes], bytes] = answer) -> None:
        self.respond = respond
        self.buffer = b""
        self.received = b""

    def feed(self, data: bytes) -> bytes:
        self.received += data
        self.buffer += data
        out = b""
        while b"\r" in self.buffer:
            line, self.buffer = self.buffer.split(b"\r", 1)
            out += self.respond(line)
        return out


@dataclass
class TcpPeer:
    """A loopback TCP server on 127.0.0.1 answering like :func:`answer`."""

    server: socket.socket
    port: int
    connections: list[socket.socket] = field(default_factory=list)
    answerers: list[LineAnswerer] = field(default_factory=list)
    threads: list[threading.Thread] = field(default_factory=list)
    accepted: threading.Semaphore = field(default_factory=lambda: threading.Semaphore(0))
    stop: threading.Event = field(default_factory=threading.Event)

    def serve(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            answerer = LineAnswerer()
            self.connections.append(conn)
            self.answerers.append(answerer)
            t = threading.Thread(target=self._handle, args=(conn, answerer), daemon=True)
            t.start()
            self.threads.append(t)  # only started threads: close() joins them
            self.accepted.release()

    def _handle(self, conn: socket.socket, answerer: LineAnswerer) -> None:
        with conn:
            while True:
                try:
                    data = conn.recv(4096)
                except OSError:
                    return
                if not data:
                    return
                reply = answerer.feed(data)
                if reply:
                    try:
                        conn.sendall(reply)
                    except OSError:
                        return

    def drop_all(self) -> None:
        """Close every accepted connection from the server side."""
        for c in self.connections:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            c.close()

    def close(self) -> None:
        self.stop.set()
        # shutdown() wakes a thread blocked in accept(); close() alone would not on Linux.
        with contextlib.suppress(OSError):
            self.server.shutdown(socket.SHUT_RDWR)
        self.server.close()
        self.drop_all()
        for t in self.threads:
            t.join(timeout=2)


@contextlib.contextmanager
def serving_tcp() -> Iterator[TcpPeer]:
    """A :class:`TcpPeer` accepting on a free loopback port until the block ends."""
    server = socket.create_server(("127.0.0.1", 0))
    peer = TcpPeer(server, server.getsockname()[1])
    acceptor = threading.Thread(target=peer.serve, daemon=True)
    acceptor.start()
    try:
        yield peer
    finally:
        peer.close()
        acceptor.join(timeout=2)


@pytest.fixture
def tcp_peer() -> Iterator[TcpPeer]:
    with serving_tcp() as peer:
        yield peer


@dataclass
class PtyPair:
    """A pseudo-terminal: the test owns the master; the transport opens ``path``."""

    master: int
    slave: int
    path: str
    master_open: bool = True

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def recv(self, n: int, timeout: float = 2.0) -> bytes:
        """Read exactly ``n`` bytes from the master (fails the test on timeout)."""
        out = b""
        while len(out) < n:
            ready, _, _ = select.select([self.master], [], [], timeout)
            assert ready, f"pty peer got {out!r}, wanted {n} bytes"
            out += os.read(self.master, n - len(out))
        return out

    def hang_up(self) -> None:
        """Close the master: the far end of the line goes away."""
        if self.master_open:
            self.master_open = False
            os.close(self.master)

    def close(self) -> None:
        self.hang_up()
        os.close(self.slave)


@contextlib.contextmanager
def open_pty() -> Iterator[PtyPair]:
    """A raw pty pair, closed when the block ends."""
    master, slave = os.openpty()
    # Raw mode: no echo, no CR->NL translation; bytes pass as they are, like a serial line.
    tty.setraw(slave)
    pair = PtyPair(master, slave, os.ttyname(slave))
    try:
        yield pair
    finally:
        pair.close()


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    with open_pty() as pair:
        yield pair


@dataclass
class PtyResponder:
    """A thread answering commands arriving on a pty master."""

    pair: PtyPair
    answerer: LineAnswerer
    wake: int  # write end of a pipe the thread also waits on
    thread: threading.Thread

    def stop(self) -> None:
        """Stop answering (at once: the thread waits on the wake pipe too)."""
        if self.thread.is_alive():
            os.write(self.wake, b"x")
        self.thread.join(timeout=2)


def _answer_loop(pair: PtyPair, answerer: LineAnswerer, woken: int) -> None:
    while True:
        ready, _, _ = select.select([pair.master, woken], [], [])
        if woken in ready:
            return
        try:
            data = os.read(pair.master, 4096)
        except OSError:
            return
        reply = answerer.feed(data)
        if reply:
            os.write(pair.master, reply)


@contextlib.contextmanager
def answering(pair: PtyPair) -> Iterator[PtyResponder]:
    """Answer commands on ``pair`` (like :func:`answer`) until the block ends."""
    woken, wake = os.pipe()
    answerer = LineAnswerer()
    thread = threading.Thread(target=_answer_loop, args=(pair, answerer, woken), daemon=True)
    thread.start()
    responder = PtyResponder(pair, answerer, wake, thread)
    try:
        yield responder
    finally:
        responder.stop()
        os.close(woken)
        os.close(wake)


@pytest.fixture
def pty_responder(pty_pair: PtyPair) -> Iterator[PtyResponder]:
    with answering(pty_pair) as responder:
        yield responder


def read_until(read: Callable[[float], bytes], end: bytes, timeout: float = 2.0) -> bytes:
    """Read from a transport until the data ends with ``end``."""
    deadline = time.monotonic() + timeout
    out = b""
    while not out.endswith(end):
        left = deadline - time.monotonic()
        assert left > 0, f"got {out!r}, waiting for {end!r}"
        out += read(left)
    return out


def read_exactly(read: Callable[[float], bytes], n: int, timeout: float = 5.0) -> bytes:
    """Read from a transport until ``n`` bytes came (fails the test on more, or on timeout)."""
    deadline = time.monotonic() + timeout
    out = b""
    while len(out) < n:
        left = deadline - time.monotonic()
        assert left > 0, f"got {len(out)} of {n} bytes"
        out += read(left)
    assert len(out) == n, f"got {len(out)} bytes, wanted {n}"
    return out
