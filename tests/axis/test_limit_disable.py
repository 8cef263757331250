"""``axis.limit_disable`` (LD) through the public API on ``sim://``: what it sends and reads,
a disabled switch that no longer stops or refuses motion, the soft limits it leaves on, and a
model without LD refused before any byte (decision 0046)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

import galil
import galil.aio as aio
from galil import LimitDisable
from galil.testing import nothing_sent, sim_of, simulated, transcript


def test_limit_disable_sends_ld_and_reads_the_setting_back(dmc: galil.Controller) -> None:
    with transcript(dmc) as sent:
        dmc.A.limit_disable = LimitDisable.FORWARD
        dmc.B.limit_disable = 3
    assert sent.lines == ["LDA=1", "LDB=3"]
    assert dmc.A.limit_disable is LimitDisable.FORWARD
    assert dmc.B.limit_disable is LimitDisable.BOTH
    assert dmc.C.limit_disable is LimitDisable.NONE
    assert (LimitDisable.REVERSE.forward, LimitDisable.REVERSE.reverse) == (False, True)
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="not one of 0, 1, 2, 3"):
        dmc.A.limit_disable = 4


def test_a_jog_runs_through_a_disabled_switch_and_stops_at_an_enabled_one(
    dmc: galil.Controller,
) -> None:
    sim = sim_of(dmc)
    sim.place_limit_switches("A", forward=2000)
    sim.place_limit_switches("B", forward=2000)
    dmc.A.limit_disable = LimitDisable.FORWARD
    through, stopped = dmc.A.jog(20_000), dmc.B.jog(20_000)
    with pytest.raises(galil.MotionError):
        stopped.wait(timeout=5)
    assert dmc.B.stop_code[0] == 2
    assert dmc.A.moving
    assert dmc.A.position > 5000
    assert dmc.A.switches.forward_limit  # the disabled switch's input still reads tripped
    dmc.A.stop()
    assert through.wait().stop_codes == {"A": 4}


def test_ld_leaves_the_soft_limits_on(dmc: galil.Controller) -> None:
    sim_of(dmc).place_limit_switches("A", forward=2000)
    dmc.A.limit_disable = LimitDisable.BOTH
    dmc.A.soft_limits = (None, 6000)
    with pytest.raises(galil.MotionError, match="FWD limit"):
        dmc.A.jog(20_000).wait(timeout=5)
    assert 6000 < dmc.A.position < 10_000


def _jog_a_while(dmc: galil.Controller) -> None:
    jog = dmc.A.jog(1000)
    dmc.sleep(0.5)
    jog.stop()
    jog.wait()


STARTS: dict[str, Callable[[galil.Controller], object]] = {
    "move_by": lambda dmc: dmc.A.move_by(1000).wait(),
    "increment": lambda dmc: dmc.A.increment(10).wait(),
    "speed_schedule": lambda dmc: dmc.A.speed_schedule(
        40_000, [(20_000, 10_000)], speed=30_000
    ).wait(),
    "jog": _jog_a_while,
}


@pytest.mark.parametrize("start", STARTS.values(), ids=STARTS.keys())
def test_a_start_towards_an_active_but_disabled_switch_is_taken(
    dmc: galil.Controller, start: Callable[[galil.Controller], object]
) -> None:
    sim_of(dmc).set_limit_switch("A", "forward", True)
    dmc.A.limit_disable = LimitDisable.FORWARD
    start(dmc)
    assert dmc.A.position > 0


def test_a_start_towards_an_active_switch_ld_leaves_on_is_still_refused_unsent(
    dmc: galil.Controller,
) -> None:
    sim_of(dmc).set_limit_switch("A", "forward", True)
    dmc.A.limit_disable = LimitDisable.REVERSE
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument, match="22"):
        dmc.A.move_by(1000)


def test_find_index_towards_an_active_but_disabled_switch_is_taken(
    dmc: galil.Controller,
) -> None:
    a, sim = dmc.A, sim_of(dmc)
    a.jog_speed, a.home_speed = 5000, 5000  # FI runs at JG: forward
    sim.set_limit_switch("A", "forward", True)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument, match="22"):
        a.find_index()
    a.limit_disable = LimitDisable.FORWARD
    assert a.find_index(switch=sim.home_switch("A")).wait(timeout=30).stop_codes == {"A": 10}


@pytest.mark.parametrize("model", ["DMC-2183", "DMC-1842"])
def test_a_model_without_ld_refuses_it_before_sending(model: str) -> None:
    with simulated(model) as dmc, nothing_sent(dmc):
        with pytest.raises(galil.InvalidArgument, match=f"{model} has no LD"):
            dmc.A.limit_disable = LimitDisable.BOTH
        with pytest.raises(galil.InvalidArgument, match=f"{model} has no LD"):
            _ = dmc.A.limit_disable


def test_the_async_axis_sets_and_reads_limit_disable() -> None:
    async def body() -> list[object]:
        async with await aio.connect("sim://DMC-4040") as c:
            await c.A.set_limit_disable(LimitDisable.REVERSE)
            sent = [text for _, text in sim_of(c.sync).command_log]
            return [await c.A.limit_disable(), sent[-1]]

    assert asyncio.run(asyncio.wait_for(body(), 30)) == [LimitDisable.REVERSE, "LDA=2"]
