"""Real loopback peers for the transport tests: a TCP server and pty pairs.

Imported by name (pytest puts this directory on sys.path); fixtures are re-exported by conftest.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
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


@pytest.fixture
def tcp_peer() -> Iterator[TcpPeer]:
    server = socket.create_server(("127.0.0.1", 0))
    peer = TcpPeer(server, server.getsockname()[1])
    acceptor = threading.Thread(target=peer.serve, daemon=True)
    acceptor.start()
    yield peer
    peer.close()
    acceptor.join(timeout=2)


@dataclass
class PtyPair:
    """A pseudo-terminal: the test owns the master; the transport opens ``path``."""

    master: int
    slave: int
    path: str

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


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    master, slave = os.openpty()
    # Raw mode: no echo, no CR->NL translation; bytes pass as they are, like a serial line.
    tty.setraw(slave)
    pair = PtyPair(master, slave, os.ttyname(slave))
    yield pair
    for fd in (master, slave):
        with contextlib.suppress(OSError):
            os.close(fd)


@dataclass
class PtyResponder:
    """A thread answering commands arriving on a pty master."""

    pair: PtyPair
    answerer: LineAnswerer
    stop: threading.Event
    thread: threading.Thread


def run_pty_responder(pair: PtyPair) -> PtyResponder:
    answerer = LineAnswerer()
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            ready, _, _ = select.select([pair.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(pair.master, 4096)
            except OSError:
                return
            reply = answerer.feed(data)
            if reply:
                os.write(pair.master, reply)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return PtyResponder(pair, answerer, stop, thread)


@pytest.fixture
def pty_responder(pty_pair: PtyPair) -> Iterator[PtyResponder]:
    responder = run_pty_responder(pty_pair)
    yield responder
    responder.stop.set()
    responder.thread.join(timeout=2)


def read_until(read: Callable[[float], bytes], end: bytes, timeout: float = 2.0) -> bytes:
    """Read from a transport until the data ends with ``end``."""
    import time

    deadline = time.monotonic() + timeout
    out = b""
    while not out.endswith(end):
        left = deadline - time.monotonic()
        assert left > 0, f"got {out!r}, waiting for {end!r}"
        out += read(left)
    return out
