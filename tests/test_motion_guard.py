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
    sent: list[str] = field(default_factory=list)
    _queued: bytes = b""

    def write(self, data: bytes) -> None:
        self.sent.append(data.decode("latin-1"))
        if self.refuse(data):
            self._queued += b"?"
        elif not self.swallow(data):
            self.inner.write(data)

    def read(self, timeout: float) -> bytes:
        if self._queued:
            out, self._queued = self._queued, b""
            return out
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
