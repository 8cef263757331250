"""A scriptable Galil-like peer behind a real Transport, for the client's unit tests.

It answers like firmware does (``:``, data + CR LF + ``:``, ``?`` and a ``TC1`` explanation) and
lets a test refuse commands, hold replies back, inject unsolicited output or garbage, and kill
the link. The simulator-backed scenario tests live in tests/transport/test_scenarios.py;
``SimLinkWrapper`` is the base for tests that step between the host and the simulator.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

from galil.errors import GalilConnectionError
from galil.sim.link import SimLink


@dataclass
class SimLinkWrapper:
    """A transport around the simulator's link: subclasses change ``write``/``read``; the
    simulated clock and ``close`` pass through."""

    inner: SimLink
    secondary: None = None
    kind: str = "sim"

    def write(self, data: bytes) -> None:
        self.inner.write(data)

    def read(self, timeout: float) -> bytes:
        return self.inner.read(timeout)

    def controller_time(self) -> float:
        return self.inner.controller_time()

    def let_time_pass(self, seconds: float) -> None:
        self.inner.let_time_pass(seconds)

    def close(self) -> None:
        self.inner.close()


def pull_cable_after(
    transport: object, mark: bytes, then: Callable[[], None] | None = None
) -> None:
    """Make ``transport`` (an open one, in place) close once a write with ``mark`` in it went
    out: the controller got the line, its reply is lost with the link (a cable pulled);
    ``then`` runs after (say, to keep the controller out of reach)."""
    write = transport.write  # type: ignore[attr-defined]

    def dying(data: bytes) -> None:
        write(data)
        if mark in data:
            transport.close()  # type: ignore[attr-defined]
            if then is not None:
                then()

    transport.write = dying  # type: ignore[attr-defined]


class Interrupt(BaseException):
    """Stands for Ctrl-C (a BaseException, like KeyboardInterrupt)."""


@dataclass
class Tripwire(SimLinkWrapper):
    """A transport around the simulator's link that raises at the n-th read or write."""

    at: int = -1  # which call raises (-1: none)
    after: bool = False  # raise after the call did its work (bytes written / read and lost)
    error: type[BaseException] = Interrupt
    calls: int = 0
    log: list[str] = field(default_factory=list)

    def _trip(self) -> bool:
        hit = self.calls == self.at
        self.calls += 1
        return hit

    def write(self, data: bytes) -> None:
        hit = self._trip()
        if hit and not self.after:
            raise self.error("interrupted before the write")
        self.inner.write(data)
        self.log.append(data.decode("latin-1"))
        if hit:
            raise self.error("interrupted after the write")

    def read(self, timeout: float) -> bytes:
        hit = self._trip()
        if hit and not self.after:
            raise self.error("interrupted before the read")
        data = self.inner.read(timeout)
        if hit:
            raise self.error("interrupted after the read (its bytes are lost)")
        return data


TC_TEXT = {
    1: "Unrecognized command",
    6: "Number out of range",
    20: "Begin not valid with motor off",
}


@dataclass
class FakeGalil:
    """Firmware stand-in: state shared by every link opened to it (survives reconnects)."""

    identity: str = "DMC4040 Rev 1.2f"
    refuse: dict[str, int] = field(default_factory=dict)  # command text -> TC code
    hold: set[str] = field(default_factory=set)  # commands whose reply is withheld
    silent: bool = False  # answer nothing at all
    cw: int = 2
    tc: int = 0
    variables: dict[str, float] = field(default_factory=dict)
    log: list[str] = field(default_factory=list)
    links: list[FakeLink] = field(default_factory=list)
    extra: Callable[[str], str | None] | None = None  # custom answers (None: default)
    held: list[bytes] = field(default_factory=list)

    def answer(self, cmd: str) -> bytes:
        self.log.append(cmd)
        if self.silent:
            return b""
        if cmd in self.hold:
            self.held.append(self._answer(cmd))
            return b""
        return self._answer(cmd)

    def _answer(self, cmd: str) -> bytes:
        if cmd in self.refuse:
            self.tc = self.refuse[cmd]
            return b"?"
        if self.extra is not None:
            custom = self.extra(cmd)
            if custom is not None:
                return custom.encode("latin-1")
        if cmd == "\x12\x16":
            return self.identity.encode() + b"\r\n:"
        if cmd == "TC1":
            code, self.tc = self.tc, 0
            return f" {code} {TC_TEXT.get(code, 'whatever')}\r\n:".encode()
        if cmd.startswith("MG "):
            return b" " + self._mg(cmd[3:]).encode() + b"\r\n:"
        if cmd.startswith("CW "):
            self.cw = int(cmd[3:].split(",")[0])
            return b":"
        if "=" in cmd and cmd[:1].isalpha():
            name, value = cmd.split("=", 1)
            try:
                self.variables[name] = float(value)
            except ValueError:
                self.tc = 4  # operand error, as a controller would say
                return b"?"
            return b":"
        if cmd == "\\":
            self.tc = 1
            return b"?"
        if not cmd or not cmd[:2].isupper():
            self.tc = 1
            return b"?"
        return b":"

    def _mg(self, args: str) -> str:
        out = []
        for item in args.split(","):
            a, _, fmt = item.strip().partition("{")  # (the library's reads: "_CW{Z10.4}")
            a = a.strip()
            if a.startswith('"') and a.endswith('"'):
                out.append(a[1:-1])
            elif a == "_CW":
                out.append(f"{self.cw}.0000")
            elif a.startswith("_GR") and a not in self.variables:
                out.append("0.0000")  # (no axis geared: the read at connect, decision 0055)
            elif a in self.variables:
                out.append(f"{self.variables[a]:.4f}")
            elif fmt:
                try:
                    out.append(f"{float(a):.4f}")
                except ValueError:
                    out.append(a)
            else:
                out.append(a)
        return " ".join(out)

    def release_held(self) -> None:
        for link in self.links:
            for data in self.held:
                link.push(data)
        self.held.clear()

    def emit(self, text: str, *, marked: bool = True) -> None:
        """Unsolicited output as a program's MG would print it (bit 7 set with CW1)."""
        data = (text + "\r\n").encode()
        if marked:
            data = bytes(b | 0x80 for b in data)
        for link in self.links:
            link.push(data)

    def open(self) -> FakeLink:
        link = FakeLink(self)
        self.links.append(link)
        return link


class FakeLink:
    """One open link to a :class:`FakeGalil` (satisfies the Transport protocol)."""

    secondary = None

    def __init__(self, peer: FakeGalil) -> None:
        self.peer = peer
        self.inbuf = b""
        self.out = bytearray()
        self.cond = threading.Condition()
        self.closed = False
        self.dead = False

    @property
    def kind(self) -> str:
        return "serial"

    def push(self, data: bytes) -> None:
        with self.cond:
            self.out += data
            self.cond.notify_all()

    def write(self, data: bytes) -> None:
        if self.closed or self.dead:
            raise GalilConnectionError("fake link is closed" if self.closed else "fake link died")
        self.inbuf += data
        while b"\r" in self.inbuf:
            line, self.inbuf = self.inbuf.split(b"\r", 1)
            for cmd in _split(line.decode("latin-1")):
                reply = self.peer.answer(cmd)
                if reply:
                    self.push(reply)

    def read(self, timeout: float) -> bytes:
        with self.cond:
            if self.closed or self.dead:
                raise GalilConnectionError(
                    "fake link is closed" if self.closed else "fake link died"
                )
            if not self.out and timeout > 0:
                self.cond.wait(timeout)
            if self.dead:
                raise GalilConnectionError("fake link died")
            data = bytes(self.out)
            self.out.clear()
            return data

    def close(self) -> None:
        self.closed = True
        with self.cond:
            self.cond.notify_all()


def _split(line: str) -> list[str]:
    """Split a line at ``;`` outside quotes."""
    parts, current, quoted = [], "", False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        if ch == ";" and not quoted:
            parts.append(current)
            current = ""
        else:
            current += ch
    parts.append(current)
    return parts
