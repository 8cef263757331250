"""A controller that echoes (``EO 1``): found at the handshake, switched off or stripped.

Galil's own library sends ``EO0`` when it opens a serial port; the client does the same when
the echo of ``^R^V`` comes back, and restores it at close. With ``echo=True`` it keeps the
echo and the session strips it from every reply. Run over the pty (a serial port) and the
in-process link, with the simulator's echo preset.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator

import numpy as np
import pytest
from concurrency import hammer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import galil.controller
from galil.controller import Controller
from galil.errors import GalilTimeoutError, InvalidArgument
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultPlan
from galil.sim.link import SimLink
from galil.sim.parse import Refused
from galil.sim.rooms import Settings, rooms_with
from galil.sim.server import SimPtyServer


def _echoing(
    model: str = "DMC-4040", clock: ManualClock | RealTimeClock | None = None
) -> SimController:
    sim = SimController(model, clock if clock is not None else RealTimeClock())
    assert sim.feed(b"EO 1\r") == b":"  # the echo starts with the next command
    return sim


def _echo_on(sim: SimController) -> bool:
    reply = sim.feed(b"MG _EO\r")
    return b"1.0000" in reply


@pytest.fixture
def pty_echo() -> Iterator[tuple[SimPtyServer, SimController]]:
    sim = _echoing()
    with SimPtyServer(sim) as srv:
        yield srv, sim


def test_echo_is_switched_off_at_connect_and_restored_at_close(
    pty_echo: tuple[SimPtyServer, SimController],
) -> None:
    srv, sim = pty_echo
    c = galil.controller.connect(srv.path, timeout=2.0)
    assert c.identity is not None
    assert c.identity.raw_model == "DMC4040"
    assert c.echo is False
    assert c.query_number("MG _EO") == 0
    assert c.command("MG 5") == " 5.0000"
    assert c.query_numbers("TP") == [0, 0, 0, 0]
    assert any("echoes" in line for line in c.recent)
    c.close()
    assert _echo_on(sim)


def test_echo_kept_on_request_is_stripped_from_every_reply(
    pty_echo: tuple[SimPtyServer, SimController],
) -> None:
    srv, sim = pty_echo
    with galil.controller.connect(srv.path, timeout=2.0, echo=True) as c:
        assert c.echo is True
        assert c.query_number("MG _EO") == 1
        assert c.command("speed=1234") == ""
        assert c.query_operands(["speed", "_TPA"]) == [1234, 0]
        assert c.command_line(["PRA=10", "MG _PRA"]) == ["", " 10.0000"]
        rec = c.record()  # a binary record behind an echo
        assert rec["A"]["position"] == 0
        assert rec["size"] == 82 + 4 * 36
        sim.emit_message("between")
        assert c.messages.get(timeout=5) == "between"
    assert _echo_on(sim)  # nothing to restore


def test_threads_share_an_echoing_link(pty_echo: tuple[SimPtyServer, SimController]) -> None:
    srv, _ = pty_echo
    with galil.controller.connect(srv.path, timeout=2.0, echo=True) as c:
        errors = hammer(c, threads=4, per_thread=30)
    assert errors == []


def test_no_echo_means_no_eo_sent() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with Controller(SimLink(sim)) as c:
        assert c.echo is False
        assert c.command("MG 1") == " 1.0000"
    assert not [text for _, text in sim.command_log if text.startswith("EO")]


class _StubbornEcho(Settings):
    """Settings whose echo cannot be switched off (EO 0 refused)."""

    def eo(self, args: str) -> str:
        if args.strip() == "0":
            raise Refused(6, "echo is fixed on this port")
        return super().eo(args)


def test_echo_that_cannot_be_switched_off_is_stripped_with_a_warning() -> None:
    sim = SimController("DMC-4040", ManualClock(), rooms=rooms_with(_StubbornEcho))
    sim.feed(b"EO 1\r")
    with pytest.warns(RuntimeWarning, match="refused EO 0"):
        c = Controller(SimLink(sim))
    with c:
        assert c.echo is True
        assert c.query_number("MG 42") == 42
        c.command("PRA=100")
        assert c.query_number("MG _PRA") == 100


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**32 - 1), keep=st.booleans())
def test_echo_survives_replies_split_anywhere(seed: int, keep: bool) -> None:
    sim = _echoing(clock=ManualClock())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = Controller(SimLink(sim, faults=FaultPlan(split=True, seed=seed)), echo=keep)
    with c:
        assert c.echo is keep
        values = [c.query_number(f"MG {n}") for n in range(5)]
        assert values == [0, 1, 2, 3, 4]
        rec = c.record()
        assert np.array_equal(rec["inputs"], [255] * 10)


def test_echo_option_is_checked() -> None:
    with pytest.raises(InvalidArgument, match="echo"):
        galil.controller.connect("sim://DMC-4040", echo="yes")


@pytest.mark.parametrize("keep", [True, False])
def test_timeout_then_resync_with_an_echoing_controller(
    pty_echo: tuple[SimPtyServer, SimController], keep: bool
) -> None:
    srv, _ = pty_echo
    with galil.controller.connect(srv.path, timeout=2.0, echo=keep) as c:
        with pytest.raises(GalilTimeoutError):
            c.command("BV", timeout=0.05)  # the controller holds the ':' while it burns
        # The late ':' of BV (and its echo) must not be taken for the next reply.
        assert c.query_number("MG 77", timeout=3.0) == 77
        assert c.query_number("MG 78") == 78
