"""A TCP proxy of faults: what a bad network does between a host and a controller.

Put it between a client and any TCP controller (the simulator's server, or real hardware on
a bench): every chunk the controller sends back is delivered through a fault plan (splits,
drops, corruption, stray ``:`` or ``?``, injected unsolicited lines), after a fixed latency,
and :meth:`FaultProxy.cut` drops every connection at once, like a pulled cable;
:meth:`FaultProxy.hush` lets nothing more through them but closes none, like a switch or a
controller that restarted with no reset reaching the host. Loopback only.
"""

from __future__ import annotations

import contextlib
import random
import selectors
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field

from galil.errors import InvalidArgument
from galil.sim.faults import FaultHook, apply_faults, check_probability

__all__ = ["FaultProxy", "MixedFaults", "Stray"]


@dataclass
class Stray:
    """A fault hook that slips a stray ``:`` or ``?`` in front of a chunk with probability
    ``p``, then applies ``then`` (another hook) to the chunk itself."""

    p: float
    then: FaultHook | None = None
    seed: int | None = None
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_probability("p", self.p)
        self._rng = random.Random(self.seed)

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        out: list[tuple[float, bytes]] = []
        if data and self._rng.random() < self.p:
            out.append((0.0, self._rng.choice((b":", b"?"))))
        return out + apply_faults(self.then, data)


@dataclass
class MixedFaults:
    """With probability ``p`` per chunk, one fault: a split, a delay, a drop, an unsolicited
    (high-bit) line slipped in, or a stray ``:`` or ``?`` in front. No corruption: nothing a
    protocol without checksums could notice.
    """

    p: float = 0.05
    delay: float = 0.02
    seed: int | None = None
    counts: dict[str, int] = field(default_factory=dict)
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_probability("p", self.p)
        self._rng = random.Random(self.seed)

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        rng = self._rng
        if not data or rng.random() >= self.p:
            return [(0.0, data)]
        kind = rng.choice(("split", "delay", "drop", "message", "stray"))
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if kind == "split" and len(data) > 1:
            cut = rng.randrange(1, len(data))
            return [(0.0, data[:cut]), (self.delay / 4, data[cut:])]
        if kind == "delay":
            return [(self.delay, data)]
        if kind == "drop":
            return []
        if kind == "message":
            line = bytes(b | 0x80 for b in b"NOISE\r\n")
            cut = rng.randrange(0, len(data) + 1)
            return [(0.0, data[:cut] + line + data[cut:])]
        return [(0.0, rng.choice((b":", b"?"))), (0.0, data)]


class _Pair:
    """One client connection and its connection to the controller."""

    def __init__(self, client: socket.socket, upstream: socket.socket) -> None:
        self.client = client
        self.upstream = upstream
        self.pending: deque[tuple[float, bytes]] = deque()  # (due time, bytes) to the client
        self.requests: deque[tuple[float, bytes]] = deque()  # (due time, bytes) upstream
        self.hushed = False  # nothing more passes either way; the sockets stay open


class FaultProxy:
    """Forward ``127.0.0.1:port`` to ``target``, with faults on the way back.

    Args:
        target: (host, port) of the controller (loopback).
        faults: hook applied to each chunk the controller sends (``None``: no faults).
        latency: seconds added to every chunk in each direction.
    """

    def __init__(
        self, target: tuple[str, int], *, faults: FaultHook | None = None, latency: float = 0.0
    ) -> None:
        if not str(target[0]).startswith("127."):
            raise InvalidArgument(f"the fault proxy forwards to loopback only, not {target!r}")
        self.target = target
        self.faults = faults
        self.latency = latency
        self._listen = socket.create_server(("127.0.0.1", 0))
        self._listen.setblocking(False)
        self._pairs: list[_Pair] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="galil-fault-proxy", daemon=True)
        self.connections = 0

    @property
    def url(self) -> str:
        """``tcp://127.0.0.1:port`` of the proxy."""
        return f"tcp://127.0.0.1:{self._listen.getsockname()[1]}"

    def start(self) -> FaultProxy:
        """Start forwarding (a background thread)."""
        self._thread.start()
        return self

    def cut(self) -> None:
        """Drop every connection now, as a pulled cable would; new ones are accepted."""
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for p in pairs:
            for s in (p.client, p.upstream):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()

    def hush(self) -> None:
        """Let nothing more through on every open connection, in either direction, and close
        none: the host's socket stays open and hears nothing, as when a switch or the
        controller restarted and no reset reached the host. New connections are forwarded."""
        with self._lock:
            for p in self._pairs:
                p.hushed = True
                p.requests.clear()
                p.pending.clear()

    def stop(self) -> None:
        """Stop forwarding and close everything; idempotent."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5)
        self.cut()
        self._listen.close()

    def __enter__(self) -> FaultProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._accept()
            with self._lock:
                pairs = list(self._pairs)
            sel = selectors.DefaultSelector()
            for p in pairs:
                with contextlib.suppress(ValueError, OSError):
                    sel.register(p.client, selectors.EVENT_READ, (p, True))
                    sel.register(p.upstream, selectors.EVENT_READ, (p, False))
            events = sel.select(0.002) if pairs else []
            if not pairs:
                time.sleep(0.002)
            for key, _ in events:
                pair, from_client = key.data
                self._forward(pair, from_client)
            sel.close()
            self._deliver(pairs)

    def _accept(self) -> None:
        try:
            client, _ = self._listen.accept()
        except (BlockingIOError, OSError):
            return
        try:
            upstream = socket.create_connection(self.target, timeout=2.0)
        except OSError:
            client.close()
            return
        for s in (client, upstream):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._lock:
            self._pairs.append(_Pair(client, upstream))
            self.connections += 1

    def _forward(self, pair: _Pair, from_client: bool) -> None:
        src = pair.client if from_client else pair.upstream
        try:
            data = src.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._drop(pair)
            return
        if pair.hushed:
            return
        due = time.monotonic() + self.latency
        if from_client:
            pair.requests.append((due, data))
            return
        for delay, piece in apply_faults(self.faults, data):
            pair.pending.append((due + delay, piece))

    def _deliver(self, pairs: list[_Pair]) -> None:
        now = time.monotonic()
        for p in pairs:
            while p.requests and p.requests[0][0] <= now:
                _, data = p.requests.popleft()
                try:
                    p.upstream.sendall(data)
                except OSError:
                    self._drop(p)
                    break
            while p.pending and p.pending[0][0] <= now:
                _, piece = p.pending.popleft()
                try:
                    p.client.sendall(piece)
                except OSError:
                    self._drop(p)
                    break

    def _drop(self, pair: _Pair) -> None:
        with self._lock:
            if pair in self._pairs:
                self._pairs.remove(pair)
        for s in (pair.client, pair.upstream):
            s.close()
