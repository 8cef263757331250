"""Gearing the library did not set up (decision 0055): found at connect and after a reset by
one read of the ratios (``_GR``), its follower's own motion refused until ``gear_off()``."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

import galil
import galil.aio
from galil.sim import SimController
from galil.testing import nothing_sent, sim_of, simulated, transcript


def _geared_elsewhere(line: str = "GA ,,CA;GR ,,2") -> SimController:
    """A simulator that another host geared (C follows A's commanded position at 2)."""
    sim = SimController("DMC-4040")
    assert sim.feed(f"{line}\r".encode()).endswith(b":")
    return sim


_OWN_MOTION: dict[str, Callable[[galil.Axis], object]] = {
    "move": lambda c: c.move_by(100),
    "jog": lambda c: c.jog(1000),
    "increment": lambda c: c.increment(100),
    "home": lambda c: c.home(),
}


def test_an_axis_geared_before_connect_has_its_own_motion_refused_before_any_byte() -> None:
    with galil.connect("sim://DMC-4040", controller=_geared_elsewhere()) as dmc:
        for what, start in _OWN_MOTION.items():
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
                start(dmc.C)
            assert "axis C is geared on the controller (ratio 2)" in str(info.value), what
            assert "gear_off()" in str(info.value)
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="geared on the"):
            dmc.vector_move("BC", [galil.Line(100, 100)], speed=1000)
        assert dmc.A.move_by(1000).wait().deviation == {"A": 0}  # (its master moves: C follows)
        assert dmc.query_number("MG _RPC") == 2000


def test_gear_off_frees_an_axis_found_geared() -> None:
    with galil.connect("sim://DMC-4040", controller=_geared_elsewhere()) as dmc:
        with transcript(dmc) as sent:
            dmc.C.gear_off()
        assert sent.lines == ["GR ,,0"]
        assert dmc.command("GR ,,?") == " 0.0000"
        assert dmc.C.move_by(300).wait().deviation == {"C": 0}
        # the library's own gearing of it now works as ever
        gearing = dmc.C.gear_to("A", 0.5)
        handle = dmc.A.move_by(1000)
        assert sorted(handle.profiles) == ["A", "C"]
        handle.wait()
        dmc.C.gear_off()  # (the library's own: as gearing.off())
        assert not gearing.engaged


def test_gearing_an_axis_found_geared_or_to_it_is_refused_before_any_byte() -> None:
    with galil.connect("sim://DMC-4040", controller=_geared_elsewhere()) as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=r"ratio 2\)"):
            dmc.C.gear_to("B", 1)
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="TC 46"):
            dmc.D.gear_to("C", 1)


def test_a_gearing_restored_by_reset_from_a_burned_ratio_is_found() -> None:
    with simulated() as dmc:
        dmc.C.gear_to("A", 2)
        dmc.save()
        dmc.reset()
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=r"\(ratio 2\)"):
            dmc.C.move_by(100)
        dmc.C.gear_off()
        dmc.save()  # (burned without the gearing)
        dmc.reset()
        assert dmc.C.move_by(100).wait().deviation == {"C": 0}


def test_a_gearing_engaged_by_raw_commands_is_found_again_after_reset() -> None:
    # (a ratio the library was not told of, and gone at RS: not found afterwards)
    with simulated() as dmc:
        dmc.command("GAD=CB;GRD=1.5", allow_compound=True)
        dmc.reset()
        assert dmc.D.move_by(100).wait().deviation == {"D": 0}


def test_the_librarys_own_gearing_is_not_found_as_foreign_after_a_reconnect() -> None:
    sim = SimController("DMC-4040")
    with galil.connect("sim://DMC-4040", controller=sim) as dmc:
        gearing = dmc.B.gear_to("A", 0.5)
        dmc.reconnect()
        assert gearing.engaged
        handle = dmc.A.move_by(2000)
        assert sorted(handle.profiles) == ["A", "B"]
        handle.wait()
        assert dmc.query_number("MG _RPB") == 1000


def test_connect_reads_every_ratio_in_one_exchange() -> None:
    with simulated() as dmc:
        exchanges = dmc.link.recent
        assert len(exchanges) == 4  # ^R^V, MG _CW, CW 1, and the ratios
        assert exchanges[-1].startswith("-> 'MG _GRA,_GRB,_GRC,_GRD'")
    with simulated("DMC-4080") as dmc:
        assert sum("_GR" in e for e in dmc.link.recent) == 1


def test_a_controller_without_axes_reads_no_ratio() -> None:
    with simulated("RIO-47100") as rio:
        assert not any("_GR" in e for e in rio.link.recent)


def test_the_simulator_reads_each_ratio_as_an_operand() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        assert sim.feed(b"GA ,CA,CA;GR ,0.5,-3\r") == b"::"
        assert [dmc.query_number(f"MG _GR{a}") for a in "ABC"] == [0, 0.5, -3]
        sim.feed(b"ST C\r")  # (ST turns a follower's gearing off: 0, as GR ? says)
        assert [dmc.query_number(f"MG _GR{a}") for a in "BC"] == [0.5, 0]
        assert dmc.command("GR ,?,?") == " 0.5000, 0.0000"


def test_the_async_twin_frees_an_axis_found_geared() -> None:
    async def body() -> None:
        sim = _geared_elsewhere()
        async with await galil.aio.connect("sim://DMC-4040", controller=sim) as c:
            with pytest.raises(galil.InvalidArgument, match=r"\(ratio 2\)"):
                await c.C.move_by(100)
            await c.C.gear_off()
            move = await c.C.move_by(100)
            assert (await move).deviation == {"C": 0}

    asyncio.run(body())


def test_a_controller_without_the_ratio_operand_connects_and_says_gearing_is_not_looked_for(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # Only the DMC-4103 reference lists _GR: firmware that refuses it must still connect.
    sim = SimController("DMC-4040")
    del sim._m.interp.axis_operands["GR"]
    with (
        caplog.at_level("WARNING", logger="galil.gearing"),
        galil.connect("sim://DMC-4040", controller=sim) as dmc,
    ):
        assert dmc.C.move_by(100).wait().deviation == {"C": 0}
        assert not dmc.tracker.reads_ratios
        # nothing else asks it then: a master's moves, a new ratio, define_position
        gearing = dmc.B.gear_to("A", 2)
        assert dmc.A.move_by(100).wait().follower_final == {"B": 200}
        gearing.set_ratio(1)
        assert dmc.A.jog(1000) is not None
        dmc.A.stop()
        dmc.sleep(0.5)
        gearing.off()
        dmc.C.define_position(0)
    assert "gearing set up elsewhere is not looked for" in caplog.text
