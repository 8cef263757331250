"""Serve a simulated controller over TCP (127.0.0.1) or a pseudo-terminal.

Both servers run on a background thread, are context managers, and advertise their address::

    with SimTcpServer(model="DMC-4040") as srv:
        sock = socket.create_connection(srv.address)          # the command port (like 23)
        msgs = socket.create_connection(srv.address)          # a second handle ...
        msgs.sendall(b"CF I\r")                               # ... claims unsolicited output
        # or, without CF: socket.create_connection(srv.message_address)

    with SimPtyServer() as srv:
        port = serial.Serial(srv.path)                        # looks like a serial port

By default they run on a :class:`~galil.sim.clock.RealTimeClock`; pass a controller built on a
:class:`~galil.sim.clock.ManualClock` and call :meth:`advance` to make tests independent of time.
``main`` implements ``galil sim``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import math
import os
import re
import selectors
import signal
import socket
import sys
import threading
import time
import tty
from collections.abc import Sequence
from types import TracebackType
from typing import TypeVar

from galil.errors import GalilConnectionError, GalilError, InvalidArgument
from galil.portnumber import check_port
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultHook, apply_faults
from galil.sim.link import check_baud
from galil.sim.parse import LOG

__all__ = ["SimPtyServer", "SimTcpServer", "check_ports", "main"]

#: How often the serving thread runs the servo loop and flushes output (seconds).
_TICK = 0.002
_MAX_BACKLOG = 1 << 16


class _Outbox:
    """Output waiting to be sent, with fault delays honoured in real time."""

    def __init__(self, faults: FaultHook | None) -> None:
        self.faults = faults
        self.items: list[tuple[float, bytes]] = []
        self._last = 0.0

    def put(self, data: bytes) -> None:
        now = time.monotonic()
        for delay, piece in apply_faults(self.faults, data):
            # keep order: a piece is never sent before the one queued ahead of it
            self._last = max(self._last, now + delay)
            self.items.append((self._last, piece))

    def due(self) -> bytes:
        now = time.monotonic()
        out = bytearray()
        while self.items and self.items[0][0] <= now:
            out += self.items.pop(0)[1]
        return bytes(out)


_S = TypeVar("_S", bound="_Server")


class _Server:
    """Thread, lock and lifecycle shared by the TCP and pty servers."""

    def __init__(self, controller: SimController | None, model: str) -> None:
        self.controller = (
            controller if controller is not None else SimController(model, RealTimeClock())
        )
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def start(self) -> None:
        """Start serving on a background thread.

        Raises:
            GalilConnectionError: a port cannot be had (in use, or not ours to take); whatever
                was opened before it is closed again.
        """
        if self._thread is not None:
            return
        try:
            self._open()
        except BaseException:
            self._close()  # what was opened before the failure
            raise
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving and close everything."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self._close()

    def advance(self, seconds: float) -> None:
        """Advance a manual clock (thread-safe; the controller serialises access)."""
        self.controller.advance(seconds)

    def __enter__(self: _S) -> _S:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    self._tick()
                except Exception:
                    # A simulator bug must not end the server: every client would then time
                    # out. Logged; the next tick serves on (after a pause, should it repeat).
                    LOG.error("simulator server error; serving on", exc_info=True)
                    time.sleep(_TICK)
        except BaseException as e:  # surfaced by the owner; a server thread must not vanish
            self._error = e

    def _feed(self, data: bytes, port: int = 0) -> bytes:
        """The controller's reply to ``data``; ``?`` (logged) if the model breaks on it: "just
        ``?`` for a rejected command" (galil-protocol.md §1.1)."""
        try:
            return self.controller.feed(data, port=port)
        except Exception:
            LOG.error("simulator error on %r; answered ?", data[:80], exc_info=True)
            return b"?"

    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _tick(self) -> None:
        raise NotImplementedError


class SimTcpServer(_Server):
    """The simulator on 127.0.0.1: a command port and a port for unsolicited messages.

    Each connection to the command port is one handle, A to H as on the controller (``TH``
    lists them, ``WH`` names the asking one). As on the controller, ``CF I`` sent on a handle
    makes it the destination of unsolicited output (program ``MG``) and ``DR n,h`` streams data
    records to handle ``h``. Until a handle claims it with ``CF``, unsolicited output goes to
    every connection on the message port (a simulator convenience, like a protocol gateway's);
    it is kept (up to 64 KiB) until one connects.

    Args:
        controller: the controller to serve (default: a new one on a real-time clock).
        model: model of the default controller.
        host: address to bind; only loopback addresses are accepted.
        port: command port (0 picks a free one).
        message_port: port for unsolicited messages (0 picks a free one; None: no such port,
            unsolicited output goes to the serial port, i.e. nowhere, until a handle sends
            ``CF I``, as on a controller).
        faults: fault hook applied to everything sent.
    """

    def __init__(
        self,
        controller: SimController | None = None,
        *,
        model: str = "DMC-4040",
        host: str = "127.0.0.1",
        port: int = 0,
        message_port: int | None = 0,
        faults: FaultHook | None = None,
    ) -> None:
        if not host.startswith("127.") and host not in ("localhost", "::1"):
            raise InvalidArgument(f"the simulator serves loopback only, not {host!r}")
        check_port(port, "port", zero=True)
        if message_port is not None:
            check_port(message_port, "message_port", zero=True)
        super().__init__(controller, model)
        self.host = host
        self._want = (port,) if message_port is None else (port, message_port)
        self.faults = faults
        # Without a message port, unsolicited output stays on the (unserved) main port until
        # a handle claims it; that buffer is cleared each tick so it cannot grow.
        self.controller.separate_messages = message_port is not None
        self._sel = selectors.DefaultSelector()
        self._listen: socket.socket | None = None
        self._listen_msg: socket.socket | None = None
        self._clients: dict[socket.socket, tuple[int, _Outbox]] = {}
        self._msg_clients: dict[socket.socket, _Outbox] = {}
        self._backlog = bytearray()
        # UDP handles on the command port's number, as on a controller: one per peer address.
        self._udp: socket.socket | None = None
        self._udp_peers: dict[tuple[str, int], tuple[int, _Outbox]] = {}

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) of the command port."""
        if self._listen is None:
            raise GalilConnectionError("server not started")
        host, port = self._listen.getsockname()[:2]
        return str(host), int(port)

    @property
    def message_address(self) -> tuple[str, int]:
        """(host, port) of the unsolicited-message port."""
        if self._listen_msg is None:
            raise GalilConnectionError("server not started, or started without a message port")
        host, port = self._listen_msg.getsockname()[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        """``tcp://host:port`` of the command port."""
        host, port = self.address
        return f"tcp://{host}:{port}"

    def _open(self) -> None:
        for i, want in enumerate(self._want):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._bind(s, want, "command port" if i == 0 else "message port")
            s.listen(8)
            s.setblocking(False)
            self._sel.register(s, selectors.EVENT_READ, "listen" if i == 0 else "listen_msg")
            if i == 0:
                self._listen = s
                self._open_udp(s.getsockname()[1])
            else:
                self._listen_msg = s

    def _open_udp(self, port: int) -> None:
        u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._bind(u, port, "command port (UDP)")
        u.setblocking(False)
        self._sel.register(u, selectors.EVENT_READ, "udp")
        self._udp = u

    def _bind(self, sock: socket.socket, port: int, what: str) -> None:
        """Bind ``sock``, or close it and say which port could not be had, and why.

        Raises:
            GalilConnectionError: the port is taken (or not ours to take); also an OSError.
        """
        try:
            sock.bind((self.host, port))
        except OSError as e:
            sock.close()
            why = e.strerror or str(e)
            if e.errno == errno.EADDRINUSE:
                why += " (port 0 picks a free one)"
            raise GalilConnectionError(
                f"cannot serve the {what} on {self.host}:{port}: {why}"
            ) from e

    def _datagram(self, sock: socket.socket) -> None:
        """A command on UDP: the peer is a handle of its own (the first datagram opens it)."""
        try:
            data, peer = sock.recvfrom(4096)
        except OSError:
            return
        entry = self._udp_peers.get(peer)
        if entry is not None and not self.controller.has_port(entry[0]):
            entry = None  # closed from the inside (IH...=>-1): the next datagram opens anew
        if entry is None:
            name = f"UDP PORT {self.address[1]} TO IP ADDRESS 127,0,0,1 PORT {peer[1]}"
            try:
                number = self.controller.open_port(name)
            except GalilConnectionError:
                return  # all eight handles taken
            entry = self._udp_peers[peer] = (number, _Outbox(self.faults))
        number, box = entry
        box.put(self._feed(data, port=number))

    def _send_datagrams(self) -> None:
        assert self._udp is not None
        for peer, (number, box) in list(self._udp_peers.items()):
            if not self.controller.has_port(number):
                del self._udp_peers[peer]  # closed from the inside (IH...=>-1)
                continue
            box.put(self.controller.poll(port=number))
            out = box.due()
            if not out:
                continue
            try:
                self._udp.sendto(out, peer)
            except OSError:  # the peer's socket is gone: so is its handle
                del self._udp_peers[peer]
                self.controller.close_port(number)

    def _close(self) -> None:
        for sock in [
            *self._clients,
            *self._msg_clients,
            self._listen,
            self._listen_msg,
            self._udp,
        ]:
            if sock is not None:
                with contextlib.suppress(KeyError, ValueError):
                    self._sel.unregister(sock)
                sock.close()
        self._clients.clear()
        self._msg_clients.clear()
        self._sel.close()

    def _drop(self, sock: socket.socket) -> None:
        self._sel.unregister(sock)
        entry = self._clients.pop(sock, None)
        if entry is not None and self.controller.has_port(entry[0]):
            self.controller.close_port(entry[0])
        self._msg_clients.pop(sock, None)
        sock.close()

    def _tick(self) -> None:
        for key, _ in self._sel.select(timeout=_TICK):
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            if key.data == "udp":
                self._datagram(sock)
                continue
            if key.data in ("listen", "listen_msg"):
                conn, peer = sock.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                conn.setblocking(False)
                if key.data == "listen":
                    name = f"TCP PORT {self.address[1]} TO IP ADDRESS 127,0,0,1 PORT {peer[1]}"
                    try:
                        number = self.controller.open_port(name)
                    except GalilConnectionError:
                        conn.close()  # all eight handles taken: the controller refuses too
                        continue
                    self._clients[conn] = (number, _Outbox(self.faults))
                    self._sel.register(conn, selectors.EVENT_READ, "client")
                else:
                    box = _Outbox(self.faults)
                    box.put(bytes(self._backlog))
                    self._backlog.clear()
                    self._msg_clients[conn] = box
                    self._sel.register(conn, selectors.EVENT_READ, "msg")
                continue
            try:
                data = sock.recv(4096)
            except OSError:
                data = b""
            if not data:
                self._drop(sock)
            elif key.data == "client":
                number, box = self._clients[sock]
                if self.controller.has_port(number):
                    box.put(self._feed(data, port=number))
        for sock, (number, box) in list(self._clients.items()):
            if not self.controller.has_port(number):
                # Closed from the inside (IH...=>-1): the controller ends the connection.
                self._send(sock, box)
                if sock in self._clients:
                    self._drop(sock)
                continue
            box.put(self.controller.poll(port=number))
            self._send(sock, box)
        if self._udp_peers:
            self._send_datagrams()
        if not self.controller.separate_messages:
            self.controller.poll(port=0)  # nobody listens on the serial port here
        messages = self.controller.read_messages()
        if messages:
            if self._msg_clients:
                for box in self._msg_clients.values():
                    box.put(messages)
            else:
                self._backlog += messages
                del self._backlog[:-_MAX_BACKLOG]
        for sock, box in list(self._msg_clients.items()):
            self._send(sock, box)

    def _send(self, sock: socket.socket, box: _Outbox) -> None:
        out = box.due()
        if not out:
            return
        try:
            sock.setblocking(True)
            sock.sendall(out)
            sock.setblocking(False)
        except OSError:
            self._drop(sock)


class SimPtyServer(_Server):
    """The simulator behind a pseudo-terminal: open :attr:`path` as a serial port.

    Unsolicited output is mixed into the replies, as on a serial port.

    A pty moves bytes as fast as the processes at its ends; with ``baud`` the server paces
    both directions as a serial line of that rate does (8N1: ten bits a byte, ``baud / 10``
    bytes a second): it takes the host's bytes off the pty no faster (what the host has
    written waits in the pty's buffer, as in a serial driver's), and its replies go out no
    faster. Scheduling delays are caught up (up to :data:`_CATCH_UP` seconds' worth): the line
    has kept moving while the server was not looking.

    Args:
        controller: the controller to serve (default: a new one on a real-time clock).
        model: model of the default controller.
        faults: fault hook applied to everything sent.
        baud: the line rate to simulate (``None``: as fast as the pty goes).
    """

    def __init__(
        self,
        controller: SimController | None = None,
        *,
        model: str = "DMC-4040",
        faults: FaultHook | None = None,
        baud: float | None = None,
    ) -> None:
        if baud is not None and not (math.isfinite(baud) and baud > 0):
            raise InvalidArgument(f"baud must be a positive number, not {baud!r}")
        super().__init__(controller, model)
        self.controller.separate_messages = False
        self.faults = faults
        self.baud = baud
        self._master = -1
        self._slave = -1
        self.path = ""
        self._box = _Outbox(faults)
        self._sel = selectors.DefaultSelector()
        self._line = None if baud is None else _Line(baud / 10.0)

    def _open(self) -> None:
        self._master, self._slave = os.openpty()
        # Raw: no echo, no CR/LF translation; the slave stays open here so the pty survives
        # clients opening and closing it.
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._sel.register(self._master, selectors.EVENT_READ)

    def _close(self) -> None:
        self._sel.close()
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def _tick(self) -> None:
        line = self._line
        if line is None:
            data = self._read(4096) if self._sel.select(timeout=_TICK) else b""
            if data:
                self._box.put(self._feed(data))
        else:
            self._carry_inward(line)
        self._box.put(self.controller.poll())
        self._send(self._box.due())

    def _read(self, n: int) -> bytes:
        try:
            return os.read(self._master, n)
        except (BlockingIOError, OSError):
            return b""

    def _carry_inward(self, line: _Line) -> None:
        """Take what the host wrote into the line's buffer (bounded, as a serial driver's
        is), and hand the controller what the line has carried by now."""
        line.refill()
        space = _LINE_BUFFER - len(line.sending)
        # With bytes on their way, only look (the line is the pace); else wait for some.
        if space > 0 and self._sel.select(timeout=0 if line.sending else _TICK):
            line.sending += self._read(space)
        carried = line.carry()
        if carried:
            self._box.put(self._feed(carried))
        elif line.sending:
            time.sleep(_TICK)  # the line is busy with them

    def _send(self, out: bytes) -> None:
        line = self._line
        if line is not None:
            line.waiting += out
            out = line.take_outward()
        while out:
            try:
                written = os.write(self._master, out)
            except BlockingIOError:
                time.sleep(_TICK)
                continue
            out = out[written:]


#: The most a paced line catches up after the server was late (seconds of line time).
_CATCH_UP = 0.05
#: Bytes a paced line holds between the host's writes and the wire (a serial driver's buffer).
_LINE_BUFFER = 4096


class _Line:
    """A simulated serial line, both directions at ``rate`` bytes a second.

    ``sending`` holds what the host has written and the line has not carried yet (bounded
    by :data:`_LINE_BUFFER`: a full buffer blocks the host's writes, as a serial driver's
    does); ``waiting`` holds the controller's replies not carried yet. Each direction
    carries bytes only while it has some to carry: a quiet line saves up no time.
    """

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.sending = bytearray()
        self.waiting = bytearray()
        self._inward = 0.0  # bytes carried to the controller since the last carry()
        self._outward = 0.0  # bytes the replies may have carried by now
        self._last = time.monotonic()

    def refill(self) -> None:
        """Count the line time since the last call for the directions that were busy."""
        now = time.monotonic()
        more = (now - self._last) * self.rate
        self._last = now
        cap = max(1.0, self.rate * _CATCH_UP)
        self._inward = min(self._inward + more, cap) if self.sending else 0.0
        self._outward = min(self._outward + more, cap) if self.waiting else 0.0

    def carry(self) -> bytes:
        """The host's bytes the line has delivered by now."""
        n = min(len(self.sending), int(self._inward))
        if n <= 0:
            return b""
        out = bytes(self.sending[:n])
        del self.sending[:n]
        self._inward -= n
        return out

    def take_outward(self) -> bytes:
        """The replies the line carries now (the rest waits for the next tick)."""
        n = min(len(self.waiting), int(self._outward))
        if n <= 0:
            return b""
        out = bytes(self.waiting[:n])
        del self.waiting[:n]
        self._outward -= n
        return out


def check_ports(tcp: str | None, message_port: int | None) -> tuple[str, int]:
    """The host and port of ``--tcp HOST:PORT`` (127.0.0.1:0 when None), both ports checked.

    The one check of the port options of ``galil sim`` and ``python -m galil.sim.server``;
    ``message_port`` None (not given) or -1 (no message port) needs no check.

    Raises:
        InvalidArgument: a port that is no number or outside 0..65535.
    """
    host, _, port = (tcp or "127.0.0.1:0").rpartition(":")
    if not port.isdigit():
        raise InvalidArgument(f"--tcp wants HOST:PORT (port 0 picks a free one), not {tcp!r}")
    if message_port is not None and message_port != -1:
        check_port(message_port, "--message-port (-1: none)", zero=True)
    return host or "127.0.0.1", check_port(int(port), "--tcp port", zero=True)


def main(argv: Sequence[str] | None = None) -> int:
    """``galil sim``: serve a simulated controller until Ctrl-C.

    ``galil sim --model DMC-4040 --tcp 127.0.0.1:0`` or ``galil sim --pty``. A bad option is a
    usage error; a port that cannot be had (in use, not ours) is one line on stderr. Both
    return (or exit with) status 2, without a traceback.
    """
    parser = options()
    return serve(parser, parser.parse_args(argv))


def serve(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Serve what ``args`` (parsed by ``parser``, :func:`options`) describe until Ctrl-C; a
    bad value is ``parser``'s usage error."""
    try:
        host, port = check_ports(args.tcp, args.message_port)
        baud = _baud(args.baud, args.pty)
        controller = _controller(args.model, args.lag, args.limits)
    except (InvalidArgument, ValueError) as e:
        parser.error(str(e))
    server: _Server
    if args.pty:
        server = SimPtyServer(controller, baud=baud)
    else:
        try:
            server = SimTcpServer(
                controller,
                host=host,
                port=port,
                message_port=None if args.message_port < 0 else args.message_port,
            )
        except (InvalidArgument, ValueError) as e:
            parser.error(str(e))
    try:
        server.start()
    except (GalilError, OSError) as e:
        print(f"{parser.prog}: error: {e}", file=sys.stderr)
        return 2
    try:
        _serve(server, announce_messages=args.message_port >= 0)
    finally:
        server.stop()
    return 0


def _serve(server: _Server, *, announce_messages: bool) -> None:
    """Say where the started ``server`` is, then serve until Ctrl-C or SIGTERM."""
    previous = None
    if threading.current_thread() is threading.main_thread():
        # `kill` (a service manager, a CI job ending) stops the server as cleanly as Ctrl-C.
        # Installed before the address is printed: whoever waits for that line may signal at once.
        previous = signal.signal(signal.SIGTERM, _interrupt)
    identity = server.controller.identity
    try:
        if isinstance(server, SimPtyServer):
            print(f"{identity} on serial port {server.path}", flush=True)
        else:
            assert isinstance(server, SimTcpServer)
            print(f"{identity} on {server.url}", flush=True)
            if announce_messages:
                mhost, mport = server.message_address
                print(
                    f"unsolicited messages on tcp://{mhost}:{mport} (or CF I on a handle)",
                    flush=True,
                )
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def options() -> argparse.ArgumentParser:
    """The options of ``galil sim`` (and of ``python -m galil.sim.server``): one parser, so
    the help and the errors show one usage line."""
    parser = argparse.ArgumentParser(
        prog="galil sim",
        description="Serve a simulated Galil DMC until Ctrl-C. With neither --tcp nor --pty it "
        "serves TCP on 127.0.0.1 on a free port, and prints the address (tcp://HOST:PORT).",
    )
    # A value that begins with a minus and a digit is a value (--limits -50000,50000, as the
    # option's own message writes it), as galil plan reads -12.5mm: argparse took it for an
    # unknown option ("expected one argument").
    parser._negative_number_matcher = re.compile(r"-\.?\d")
    parser.add_argument("--model", default="DMC-4040", help="controller model (DMC-4040)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--tcp",
        metavar="HOST:PORT",
        help="serve TCP there (port 0: a free one); the default is 127.0.0.1:0",
    )
    where.add_argument("--pty", action="store_true", help="serve a pseudo-terminal instead")
    parser.add_argument(
        "--message-port",
        type=int,
        default=0,
        help="TCP port for unsolicited messages (0: any free one; -1: none, use CF I)",
    )
    parser.add_argument(
        "--baud",
        help="with --pty: carry bytes no faster than a serial line of this rate (8N1: baud/10"
        " bytes a second; default: as fast as the pty goes)",
    )
    parser.add_argument("--lag", type=float, default=0.003, help="servo lag time constant, s")
    parser.add_argument(
        "--limits",
        metavar="REV,FWD",
        help="put every axis's limit switches at these positions in counts (default: none)",
    )
    return parser


def _baud(text: str | None, pty: bool) -> float | None:
    """``--baud``: a positive, finite line rate (:func:`~galil.sim.link.check_baud`), and only
    for a pty (a serial line)."""
    if text is None:
        return None
    if not pty:
        raise InvalidArgument("--baud paces a serial line: it goes with --pty")
    return check_baud(text)


def _controller(model: str, lag: float, limits: str | None) -> SimController:
    """The served controller, its limit switches placed at ``limits`` ("REV,FWD")."""
    controller = SimController(model, RealTimeClock(), servo_lag=lag)
    if limits:
        try:
            reverse, forward = (int(v) for v in limits.split(","))
        except ValueError:
            raise InvalidArgument(
                f"--limits takes two whole numbers of counts, REV,FWD (e.g. -50000,50000),"
                f" not {limits!r}"
            ) from None
        for letter in controller.spec.axes:
            controller.place_limit_switches(letter, forward=forward, reverse=reverse)
    return controller


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
