"""``with controller.motion():`` always tries to stop: a failed state query, a timeout or a dead
link does not stop the ``ST``; when it cannot be sent, the error says which axes may move.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest
from client_fakes import SimLinkWrapper

import galil
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink, open_transport


@dataclass
class Gate(SimLinkWrapper):
    """A transport around the simulator's link that can refuse or swallow chosen commands."""

    refuse: Callable[[bytes], bool] = lambda _data: False
    swallow: Callable[[bytes], bool] = lambda _data: False
    # Swallowed, and a long reply keeps arriving (a line per read) until the next write.
    drain: Callable[[bytes], bool] = lambda _data: False
    sent: list[str] = field(default_factory=list)
    _queued: bytes = b""
    _draining: bool = False

    def write(self, data: bytes) -> None:
        self.sent.append(data.decode("latin-1"))
        self._draining = False
        if self.refuse(data):
            self._queued += b"?"
        elif self.drain(data):
            self._draining = True
        elif not self.swallow(data):
            self.inner.write(data)

    def read(self, timeout: float) -> bytes:
        if self._queued:
            out, self._queued = self._queued, b""
            return out
        if self._draining:
            self.inner.let_time_pass(min(timeout, 0.01))
            return b" 0.0000\r\n"
        return self.inner.read(timeout)


@pytest.fixture
def gated() -> Iterator[tuple[galil.Controller, Gate, SimController]]:
    sim = SimController("DMC-4040", ManualClock())
    gate = Gate(SimLink(sim))
    with galil.connect(gate, timeout=0.2) as dmc:  # type: ignore[arg-type]
        yield dmc, gate, sim


def _is_bg_query(data: bytes) -> bool:
    return data.startswith(b"MG _BG")


def _scan(dmc: galil.Controller, axes: str, error: BaseException, kill: bool = False) -> None:
    """A script that starts a move inside the guard, then fails (the link dying first)."""
    with dmc.motion(axes):
        dmc.A.move_by(200_000)
        if kill:
            dmc.transport.close()  # the link dies under the script
        raise error


def test_the_guard_stops_when_the_state_query_is_refused(
    gated: tuple[galil.Controller, Gate, SimController],
) -> None:
    dmc, gate, _ = gated
    gate.refuse = _is_bg_query
    with pytest.raises(RuntimeError, match="scan failed"):
        _scan(dmc, "AB", RuntimeError("scan failed"))
    assert any(line.startswith("ST AB") for line in gate.sent)  # every guarded axis
    gate.refuse = lambda _d: False
    assert dmc.query_operands(["_SCA"]) == [4]


def test_the_guard_stops_when_the_state_query_times_out(
    gated: tuple[galil.Controller, Gate, SimController],
) -> None:
    dmc, gate, _ = gated
    gate.swallow = _is_bg_query
    with pytest.raises(KeyboardInterrupt):
        _scan(dmc, "A", KeyboardInterrupt())
    assert any(line.startswith("ST A") for line in gate.sent)
    gate.swallow = lambda _d: False
    assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]


def test_the_guard_reopens_a_dead_link_once_to_stop() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with galil.connect("sim://DMC-4040", controller=sim, timeout=0.2) as dmc:
        with pytest.raises(RuntimeError, match="link lost"):
            _scan(dmc, "ABCD", RuntimeError("link lost"), kill=True)
        assert not dmc.closed
        assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]
        assert any("ST" in line for _, line in sim.command_log)


def test_the_guard_names_the_axes_it_could_not_stop() -> None:
    sim = SimController("DMC-4040", ManualClock())
    opened = []

    def factory() -> SimLink:
        if opened:
            raise galil.GalilConnectionError("the controller is unreachable")
        opened.append(1)
        return open_transport("sim://DMC-4040", controller=sim)

    from galil.controller import Controller

    dmc = Controller(factory, timeout=0.2)
    try:
        with pytest.raises(galil.MotionError, match="may still be moving") as info:
            _scan(dmc, "AB", RuntimeError("link lost"), kill=True)
        assert info.value.moving == "AB"
        assert isinstance(info.value.__cause__, RuntimeError)
        assert sim.motion("A").moving  # nothing could reach it
    finally:
        dmc.close()


@dataclass
class DiesAfter(SimLinkWrapper):
    """A transport around the simulator's link that dies once a line with ``mark`` went out
    (the controller got it; its reply is lost with the link)."""

    mark: bytes = b"BG"

    def write(self, data: bytes) -> None:
        self.inner.write(data)
        if self.mark in data:
            self.inner.close()


def _reopening(sim: SimController, mark: bytes) -> galil.Controller:
    """A controller whose first link dies after the line with ``mark``; later links work."""
    from galil.controller import Controller

    links: list[SimLink] = []

    def factory() -> SimLink:
        inner = SimLink(sim)
        links.append(inner)
        return DiesAfter(inner, mark=mark) if len(links) == 1 else inner  # type: ignore[return-value]

    return Controller(factory, timeout=0.2)


def test_a_stop_whose_link_dies_goes_out_on_the_reopened_link_and_returns(
    caplog: pytest.LogCaptureFixture,
) -> None:
    sim = SimController("DMC-4040", ManualClock())
    with _reopening(sim, b"ST") as dmc:
        dmc.A.jog(50_000)
        with caplog.at_level("WARNING", logger="galil.motion"):
            dmc.A.stop()  # the first ST dies with the link: it is sent again, and that is all
        assert not sim.motion("A").moving
        assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]  # the link works
        assert "it was reopened and they are stopped" in caplog.text
        assert [line for _, line in sim.command_log].count("ST A") == 2


def test_a_start_cut_short_by_a_dead_link_says_the_link_works_again() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with _reopening(sim, b"BG") as dmc:
        with pytest.raises(galil.GalilConnectionError) as info:
            dmc.A.move_by(200_000)  # the line goes out, the link dies before its reply
        text = str(info.value)
        assert "reconnect()" not in text
        assert "it was reopened and A stopped, so the link works again" in text
        assert "may or may not have taken effect" in text
        assert isinstance(info.value.__cause__, galil.GalilConnectionError)
        assert not sim.motion("A").moving
        assert dmc.query_operands(["_BGA"]) == [0]


def test_a_motion_block_whose_link_died_says_the_link_works_again() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with _reopening(sim, b"MG 7") as dmc:
        dmc.B.jog(20_000)
        with pytest.raises(galil.GalilConnectionError) as info, dmc.motion("AB"):
            dmc.command("MG 7")  # the link dies under the block
        assert "reconnect()" not in str(info.value)
        assert "it was reopened and AB stopped" in str(info.value)
        assert not sim.motion("B").moving


def test_a_wait_whose_link_dies_stops_the_move_and_says_the_link_works_again() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with _reopening(sim, b"MG _BGA,_RPA,_SCA") as dmc:  # (the wait's poll)
        handle = dmc.A.move_by(200_000)  # 8 s at SP 25 000
        with pytest.raises(galil.GalilConnectionError) as info:
            handle.wait(timeout=1.0)  # (its first poll comes after 1 s, mid-move)
        # The stop went out through the handle's stop, whose own guard reopened the link:
        # the wait's error says so too rather than advising reconnect().
        text = str(info.value)
        assert "reconnect()" not in text
        assert "it was reopened and A stopped, so the link works again" in text
        assert not dmc.link.dead
        dmc.sleep(1.0)
        assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]
        assert dmc.query_operands(["_RPA"])[0] < 200_000


@pytest.mark.parametrize("axes", [None, "", " ", ","])
def test_a_guard_of_no_named_axes_guards_every_axis(axes: str | None) -> None:
    # As stop(""), motor_off("") and servo_here(""): no axes named means all of them.
    def jog_then_fail(dmc: galil.Controller) -> None:
        with dmc.motion(axes):
            dmc.A.jog(5000)
            dmc.D.jog(-5000)
            raise RuntimeError("boom")

    with galil.connect("sim://DMC-4040") as dmc:
        with pytest.raises(RuntimeError, match="boom"):
            jog_then_fail(dmc)
        assert not dmc.A.moving
        assert not dmc.D.moving
        assert dmc.query_operands(["_SCA", "_SCD"]) == [4, 4]


def _first(mark: bytes) -> Callable[[bytes], bool]:
    """True for the first write with ``mark`` in it only."""
    seen: list[bytes] = []

    def first(data: bytes) -> bool:
        if mark in data and not seen:
            seen.append(data)
            return True
        return False

    return first


@pytest.mark.parametrize(
    ("lost", "out_of_step"),
    [
        (b"ST", False),  # the ST's reply never comes: a timeout
        # The link does not resynchronise in time (a long reply still draining, decision 0081):
        # a GalilConnectionError, the link still open (a silent one is dead: 0089).
        (b"SYNC", True),
    ],
)
def test_a_stop_whose_first_try_fails_but_whose_guard_stops_the_axes_returns(
    gated: tuple[galil.Controller, Gate, SimController],
    caplog: pytest.LogCaptureFixture,
    lost: bytes,
    out_of_step: bool,
) -> None:
    dmc, gate, sim = gated
    dmc.A.jog(50_000)
    if out_of_step:
        gate.swallow = _first(b"MG 7")
        with pytest.raises(galil.GalilTimeoutError):
            dmc.command("MG 7")  # the link is out of step: the stop resynchronises first
    if out_of_step:
        gate.drain = _first(lost)
    else:
        gate.swallow = _first(lost)
    with caplog.at_level("WARNING", logger="galil.motion"):
        dmc.A.stop()  # its first try fails; the guard sends ST again and sees A stop
    assert not sim.motion("A").moving
    assert dmc.query_operands(["_BGA", "_SCA"]) == [0, 4]
    assert "the stop was sent again and they are stopped" in caplog.text
    assert not dmc.link.dead
