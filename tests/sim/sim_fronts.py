"""Fronts of the simulator for the conformance suite: in-process link, TCP, pty.

They live here, not in conftest.py, so the tests can import them: every test directory has a
``conftest`` module and which one ``import conftest`` finds depends on what pytest loaded last.

Every front is built on a controller with a manual clock, so tests move time explicitly and no
assertion depends on how fast the machine is. Replies are read as raw bytes (sockets, pyserial,
the link), never through the client.
"""

from __future__ import annotations

import socket
import time

import serial

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.server import SimPtyServer, SimTcpServer

WAIT = 5.0  # generous real-time bound for bytes to cross a socket or pty


class Front:
    """Raw byte access to one simulated controller."""

    name = ""
    controller: SimController

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    def read_some(self, timeout: float) -> bytes:
        raise NotImplementedError

    def messages(self, timeout: float) -> bytes:
        """Unsolicited bytes (the message handle on TCP, the same stream otherwise)."""
        return self.read_some(timeout)

    def advance(self, seconds: float) -> None:
        self.controller.advance(seconds)

    def read_terminators(self, n: int, timeout: float = WAIT) -> bytes:
        """Read until ``n`` ':' or '?' have arrived."""
        buf = b""
        deadline = time.monotonic() + timeout
        while buf.count(b":") + buf.count(b"?") < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{self.name}: timed out with {buf!r}")
            buf += self.read_some(min(left, 0.05))
        return buf

    def ask(self, line: bytes, n: int | None = None) -> bytes:
        """Send one line and read the reply of each of its commands."""
        if n is None:
            n = line.count(b";") + 1
        self.write(line + b"\r")
        return self.read_terminators(n)

    def quiet(self, settle: float = 0.05) -> bytes:
        """What arrives within ``settle`` seconds (for checking that nothing does)."""
        return self.read_some(settle)

    def close(self) -> None:
        pass


class InProcess(Front):
    name = "inproc"

    def __init__(self, model: str) -> None:
        self.controller = SimController(model, ManualClock())
        self.link = SimLink(self.controller, auto_advance=False)

    def write(self, data: bytes) -> None:
        self.link.write(data)

    def read_some(self, timeout: float) -> bytes:
        return self.link.read(timeout)


class Tcp(Front):
    name = "tcp"

    def __init__(self, model: str) -> None:
        self.controller = SimController(model, ManualClock())
        self.server = SimTcpServer(self.controller)
        self.server.start()
        self.sock = socket.create_connection(self.server.address, timeout=WAIT)
        self.msg = socket.create_connection(self.server.message_address, timeout=WAIT)

    def write(self, data: bytes) -> None:
        self.sock.sendall(data)

    def _recv(self, sock: socket.socket, timeout: float) -> bytes:
        sock.settimeout(timeout)
        try:
            return sock.recv(65536)
        except TimeoutError:
            return b""

    def read_some(self, timeout: float) -> bytes:
        return self._recv(self.sock, timeout)

    def messages(self, timeout: float) -> bytes:
        return self._recv(self.msg, timeout)

    def close(self) -> None:
        self.sock.close()
        self.msg.close()
        self.server.stop()


class Pty(Front):
    name = "pty"

    def __init__(self, model: str) -> None:
        self.controller = SimController(model, ManualClock())
        self.server = SimPtyServer(self.controller)
        self.server.start()
        self.port = serial.Serial(self.server.path, 115200, timeout=0.05)

    def write(self, data: bytes) -> None:
        self.port.write(data)
        self.port.flush()

    def read_some(self, timeout: float) -> bytes:
        self.port.timeout = timeout
        first = self.port.read(1)
        return first + self.port.read(self.port.in_waiting) if first else b""

    def close(self) -> None:
        self.port.close()
        self.server.stop()


FRONTS = {"inproc": InProcess, "tcp": Tcp, "pty": Pty}
