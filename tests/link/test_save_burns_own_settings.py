"""``controller.save()`` (``BN``) burns the controller's own ``CW`` and ``EO``, not the
``CW 1``/``EO 0`` the link set for itself at connect (decision 0057): after a power-on (``RS``)
the controller comes up as it was before the library connected, while the link stays marked,
echo-free and in step, also when the burn is refused or fails half-way."""

from __future__ import annotations

import asyncio

import pytest

import galil
import galil.aio
import galil.controller
from galil.controller import Controller
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.rooms.tuning import Tuning
from galil.sim.server import SimPtyServer, SimTcpServer
from galil.testing import nothing_sent, sim_of, simulated

_PRINTER = '#P\n#L\nMG "tick"\nWT 5\nJP #L\nEN\n'


def _power_on(sim: SimController) -> None:
    """What a power cycle does to the settings: ``RS`` brings back what was burned."""
    assert sim.feed(b"RS\r").endswith(b":")


def _read(sim: SimController, operand: str) -> float:
    """``MG operand`` straight to the simulator (an echo, if on, is skipped)."""
    reply = sim.feed(f"MG {operand}\r".encode()).decode()
    return float(reply.split("\r")[-2])


def _echoing(clock: ManualClock | RealTimeClock) -> SimController:
    sim = SimController("DMC-4040", clock)
    assert sim.feed(b"EO 1\r") == b":"
    return sim


def _in_step(c: Controller, sim: SimController) -> None:
    """The link's own settings are live: marked output comes as a message, no echo."""
    assert c.command("MG 1") == " 1.0000"
    assert c.query_operands(["_CW", "_EO"]) == [1, 0]
    sim.emit_message("marked")
    assert c.messages.get(timeout=2) == "marked"


def test_save_burns_unmarked_output_not_the_links_cw_1() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        dmc.command("KPA=12")
        dmc.save()
        _in_step(dmc, sim)
    _power_on(sim)
    assert (_read(sim, "_CW"), _read(sim, "_KPA")) == (2, 12)


def test_a_reset_after_save_comes_back_unmarked_and_close_leaves_it_so() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        dmc.save()
        dmc.reset()
        _in_step(dmc, sim)
    assert _read(sim, "_CW") == 2


def test_save_over_serial_burns_the_echo_and_unmarked_output_the_controller_had() -> None:
    sim = _echoing(RealTimeClock())
    with SimPtyServer(sim) as srv, galil.controller.connect(srv.path, timeout=2.0) as c:
        c.command("KPA=7")
        c.save()
        _in_step(c, sim)
    _power_on(sim)
    assert sim.feed(b"MG _EO\r").startswith(b"MG _EO\r")  # it echoes again
    assert (_read(sim, "_EO"), _read(sim, "_CW"), _read(sim, "_KPA")) == (1, 2, 7)


def test_save_with_the_echo_stripped_in_between_on_replies_split_anywhere() -> None:
    from galil.sim.faults import FaultPlan

    sim = _echoing(ManualClock())
    with Controller(SimLink(sim, faults=FaultPlan(split=True, seed=5))) as c:
        c.save()
        c.save()
        _in_step(c, sim)
    _power_on(sim)
    assert (_read(sim, "_EO"), _read(sim, "_CW")) == (1, 2)


def test_save_keeps_an_echo_the_caller_kept() -> None:
    sim = _echoing(ManualClock())
    with Controller(SimLink(sim), echo=True) as c:
        c.save()
        assert c.query_operands(["_CW", "_EO"]) == [1, 1]
    _power_on(sim)
    assert (_read(sim, "_EO"), _read(sim, "_CW")) == (1, 2)


def test_save_on_a_claimed_ethernet_handle_sends_no_cw() -> None:
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim, message_port=None) as srv,
        galil.controller.connect(srv.url, timeout=2.0) as c,
    ):
        with c.wire_log.capture() as wire:
            c.save()
        assert b"CW" not in wire.sent
        assert b"BN\r" in wire.sent
    assert sim.room(Tuning).burns["BN"] == 1


def test_save_is_refused_unsent_while_a_program_prints() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        dmc.programs.download(_PRINTER)
        dmc.programs.run("#P")
        with dmc.wire_log.capture() as wire, pytest.raises(galil.InvalidArgument, match="TC 17"):
            dmc.save()
        assert b"CW" not in wire.sent
        assert b"BN" not in wire.sent
        dmc.sleep(0.05)
        assert dmc.messages.get(timeout=2) == "tick"
        assert dmc.command("MG 1") == " 1.0000"
        assert sim.room(Tuning).burns["BN"] == 0
        dmc.programs.halt()
        dmc.save()
        assert sim.room(Tuning).burns["BN"] == 1


class _InterruptedError(Exception):
    pass


def _fail_once_on(marker: bytes) -> object:
    failed = []

    def hook(direction: str, data: bytes) -> None:
        if direction == "out" and marker in data and not failed:
            failed.append(data)
            raise _InterruptedError(data)

    return hook


def test_a_failure_between_echo_on_and_the_burn_leaves_the_link_marked_and_echo_free() -> None:
    sim = _echoing(ManualClock())
    with Controller(SimLink(sim)) as c:
        c.wire_log.add(_fail_once_on(b"BN\r"))  # CW 2 and EO 1 are live by then
        with pytest.raises(_InterruptedError):
            c.save()
        _in_step(c, sim)
        assert sim.room(Tuning).burns["BN"] == 0
        c.save()
    _power_on(sim)
    assert (_read(sim, "_EO"), _read(sim, "_CW")) == (1, 2)


def test_a_timeout_during_the_burn_leaves_the_link_marked_and_in_step() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        with pytest.raises(galil.GalilTimeoutError):
            dmc.save(timeout=0.05)  # the simulated burn takes 0.25 s
        _in_step(dmc, sim)
        assert sim.room(Tuning).burns["BN"] == 1
    _power_on(sim)
    assert _read(sim, "_CW") == 2


def test_async_save_burns_the_controllers_own_cw() -> None:
    async def body() -> SimController:
        async with await galil.aio.connect("sim://DMC-4040") as c:
            await c.save()
            assert await c.query_number("MG _CW") == 1
            return sim_of(c.sync)

    sim = asyncio.run(asyncio.wait_for(body(), 30))
    _power_on(sim)
    assert _read(sim, "_CW") == 2


@pytest.mark.parametrize("text", ["BN", " BN ", "KPA=5;BN"])
def test_a_raw_bn_is_refused_unsent_and_says_to_use_save(text: str) -> None:
    with simulated() as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=r"controller\.save\(\)"):
            dmc.command(text, allow_compound=True)
        dmc.command("MG _BN")  # the serial number operand still reads


def test_the_terminal_saves_on_bn() -> None:
    from galil.terminal import Terminal

    out: list[str] = []
    with simulated() as dmc:
        Terminal(dmc, write=out.append).feed("BN")
        assert out[-1].startswith("saved (BN)")
        assert sim_of(dmc).room(Tuning).burns["BN"] == 1
    _power_on(sim_of(dmc))
    assert _read(sim_of(dmc), "_CW") == 2
