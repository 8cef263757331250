"""A link that dies says so, and says what to do: reconnect()."""

from __future__ import annotations

import errno
import re
import threading
from dataclasses import dataclass, field

import pytest
from client_fakes import SimLinkWrapper, pull_cable_after

import galil
from galil.controller import Controller
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import open_transport
from galil.sim.server import SimTcpServer


def _until_it_fails(dmc: galil.Controller) -> galil.GalilConnectionError:
    # The first write after the peer left may still land in the socket buffer.
    for _ in range(5):
        try:
            dmc.command("MG 1")
        except galil.GalilConnectionError as exc:
            return exc
    raise AssertionError("the dead link was never reported")


def test_dead_tcp_link_is_reported_and_reconnect_recovers() -> None:
    with SimTcpServer() as server:
        dmc = galil.connect(server.url, timeout=2.0)
        try:
            assert dmc.command("MG 1").strip() == "1.0000"
            server.stop()  # the controller goes away under the client
            assert "reconnect()" in str(_until_it_fails(dmc))
            assert "dead" in repr(dmc)
            with pytest.raises(galil.GalilConnectionError, match="died"):
                dmc.command("MG 2")
        finally:
            dmc.close()
    with SimTcpServer() as again:
        dmc = galil.connect(again.url)
        dmc.close()
        assert "closed" in repr(dmc)


def test_reconnect_after_the_server_returns() -> None:
    server = SimTcpServer()
    server.start()
    host, port = server.address
    dmc = galil.connect(server.url, timeout=2.0)
    try:
        server.stop()
        _until_it_fails(dmc)
        revived = SimTcpServer(host=host, port=port, message_port=None)
        revived.start()
        try:
            dmc.reconnect()
            assert "open" in repr(dmc)
            assert dmc.command("MG 6*7").strip() == "42.0000"
        finally:
            dmc.close()
            revived.stop()
    finally:
        dmc.close()


@dataclass
class _Breaks(SimLinkWrapper):
    """A plug-in transport (no galil base class) whose link breaks after the first ``BG``
    went out: that write and every later call raise the bare ``OSError`` given."""

    error: OSError = field(default_factory=lambda: OSError(errno.EIO, "I/O error"))
    armed: bool = True
    broken: bool = False

    def write(self, data: bytes) -> None:
        if self.broken:
            raise self.error
        self.inner.write(data)
        if self.armed and re.search(rb"(^|;)BG", data):
            self.broken = True
            raise self.error

    def read(self, timeout: float) -> bytes:
        if self.broken:
            raise self.error
        return self.inner.read(timeout)


@pytest.mark.parametrize(
    "error",
    [BrokenPipeError(errno.EPIPE, "Broken pipe"), ConnectionResetError(), OSError(errno.EIO, "")],
    ids=["broken-pipe", "reset", "eio"],
)
def test_a_plug_in_transports_bare_os_error_is_a_dead_link_and_the_move_is_stopped(
    error: OSError,
) -> None:
    clock = ManualClock()
    sim = SimController("DMC-4040", clock)
    links: list[_Breaks] = []

    def factory() -> _Breaks:
        link = open_transport("sim://DMC-4040", controller=sim)
        links.append(_Breaks(link, error=error, armed=not links))
        return links[-1]

    dmc = Controller(factory, timeout=0.5)
    try:
        dmc.command("SP 20000;AC 1000000;DC 1000000", allow_compound=True)
        with pytest.raises(galil.GalilConnectionError, match=type(error).__name__) as info:
            dmc.A.move_by(200_000)  # 10 s of motion, started before the link broke
        causes = []
        cause: BaseException | None = info.value
        while cause is not None:
            causes.append(cause)
            cause = cause.__cause__
        assert error in causes
        # The guard's own error says the link works again, not to call reconnect().
        assert "reconnect()" not in str(info.value)
        # The link was taken for dead, so the guard opened it again to stop the move.
        assert len(links) == 2
        clock.advance(0.25)
        assert not sim.motion("A").moving
        assert dmc.query_operands(["_BGA"]) == [0]
    finally:
        dmc.close()


class _DeadHandle:
    """A plug-in transport's own message handle whose reads fail with a bare ``OSError``."""

    def __init__(self, error: BaseException) -> None:
        self.error = error
        self.tried = threading.Event()

    def write(self, data: bytes) -> None:
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    def read(self, timeout: float) -> bytes:
        self.tried.set()
        raise self.error

    def close(self) -> None:
        pass


@dataclass
class _WithHandle(SimLinkWrapper):
    """A plug-in transport that brings its own message handle."""

    handle: _DeadHandle | None = None

    def __post_init__(self) -> None:
        self.secondary = self.handle  # type: ignore[assignment]


@pytest.mark.parametrize("error", [BrokenPipeError(errno.EPIPE, "Broken pipe"), TimeoutError()])
def test_a_message_handle_raising_a_bare_os_error_ends_its_reader_quietly(
    error: OSError, monkeypatch: pytest.MonkeyPatch
) -> None:
    crashed: list[threading.ExceptHookArgs] = []
    monkeypatch.setattr(threading, "excepthook", crashed.append)
    handle = _DeadHandle(error)
    link = _WithHandle(open_transport("sim://DMC-4040"), handle=handle)
    with Controller(link, timeout=0.5) as dmc:
        assert handle.tried.wait(5.0)  # the reader thread has read (and failed) at least once
        assert dmc.query_operands(["_BGA"]) == [0]  # the command link is untouched
    assert crashed == []  # no reader thread died with a traceback


def _pluggable(sim: SimController) -> tuple[Controller, list[bool]]:
    """A controller on ``sim`` whose links open only while ``reachable[0]`` is true (the
    cable plugged in)."""
    reachable = [True]

    def factory() -> SimLinkWrapper:
        if not reachable[0]:
            raise galil.GalilConnectionError("the controller does not answer")
        return open_transport("sim://DMC-4040", controller=sim)  # type: ignore[return-value]

    return Controller(factory, timeout=0.2), reachable


def _unplugged(sim: SimController) -> tuple[Controller, list[bool]]:
    """A controller on ``sim`` jogging A, whose link then dies with the controller out of
    reach (``reachable[0] = True`` plugs it back in)."""
    dmc, reachable = _pluggable(sim)
    dmc.A.jog(20_000)
    transport = dmc.link.transport
    assert transport is not None
    transport.close()  # the cable is pulled
    reachable[0] = False
    return dmc, reachable


def test_a_failed_reconnect_leaves_the_link_dead_not_closed() -> None:
    sim = SimController("DMC-4040", ManualClock())
    dmc, reachable = _unplugged(sim)
    with pytest.raises(galil.GalilConnectionError, match="does not answer"):
        dmc.reconnect()
    # Not "closed (close(), ...): galil.connect() opens a new one": the user did not close it.
    assert "dead: call reconnect()" in repr(dmc)
    with pytest.raises(galil.GalilConnectionError, match=r"reopening it failed.*reconnect\(\)"):
        dmc.command("MG 1")
    reachable[0] = True
    dmc.reconnect()
    assert dmc.query_number("MG 6*7") == 42
    dmc.A.stop()  # the jog the library started is still its own
    sim.advance(0.5)
    assert not sim.motion("A").moving
    dmc.close()


def test_close_after_a_failed_reconnect_still_stops_the_motion_the_library_started() -> None:
    sim = SimController("DMC-4040", ManualClock())
    dmc, reachable = _unplugged(sim)
    with pytest.raises(galil.GalilConnectionError):
        dmc.reconnect()
    reachable[0] = True  # back by the time the script gives up and closes
    dmc.close()  # (reopened once for its stops, decision 0073)
    sim.advance(0.5)
    assert not sim.motion("A").moving
    assert not dmc.link.is_open


def test_close_stops_what_a_guard_could_not_stop_while_the_controller_was_gone() -> None:
    sim = SimController("DMC-4040", ManualClock())
    dmc, reachable = _pluggable(sim)

    def out_of_reach() -> None:  # (while the guard tries to stop the jog)
        reachable[0] = False

    # The jog goes out, and the cable is pulled before its reply.
    pull_cable_after(dmc.link.transport, b"BG B", then=out_of_reach)
    with pytest.raises(galil.MotionError, match="B could not be stopped") as info:
        dmc.B.jog(20_000)
    assert info.value.moving == "B"
    assert sim.motion("B").moving
    reachable[0] = True  # back by the time the script gives up and closes
    dmc.close()  # (no handle for that jog: the guard's failure is what close() remembers)
    sim.advance(0.5)
    assert not sim.motion("B").moving
