"""Decision 0105: a move that an ``ST`` or ``AB`` the library did not send (a raw command,
another host, a program) ended early is a MotionError from ``wait()``, naming the stop and
where the axis ended against where it was going; the library's own stops end quietly, and a
jog's end is its stop, whoever sends it. In-process simulators on a manual clock."""

from __future__ import annotations

import asyncio
import warnings

import pytest

import galil
import galil.aio as aio
from galil import Line
from galil.errors import MotionError
from galil.units import ureg

mm = ureg.mm


def test_a_raw_st_during_a_move_makes_wait_raise_naming_the_stop(dmc: galil.Controller) -> None:
    x = dmc.A.set_scale(counts_per=2000 / mm)
    handle = x.move_to(10 * mm)
    dmc.sleep(0.1)
    dmc.command("STA")
    with pytest.raises(MotionError) as info:
        handle.wait()
    at = round(float(dmc.command("MG _RPA")))
    said = str(info.value)
    assert "A by ST (stop code 4)" in said
    assert f"at {at} counts, going to 20000" in said
    assert "did not send" in said
    assert info.value.stop_codes == {"A": 4}
    assert handle.result is not None
    assert handle.result.final == {"A": at}


def test_a_raw_ab_during_a_move_makes_wait_raise_naming_the_abort(dmc: galil.Controller) -> None:
    handle = dmc.A.move_to(20_000)
    dmc.sleep(0.1)
    dmc.command("AB")
    with pytest.raises(MotionError, match=r"A by AB \(stop code 7\)"):
        handle.wait()


@pytest.mark.parametrize(
    "stop",
    [
        lambda dmc, h: h.stop(),
        lambda dmc, h: dmc.A.stop(),
        lambda dmc, h: dmc.stop(),
        lambda dmc, h: dmc.stop("A"),
        lambda dmc, h: dmc.abort(),
    ],
    ids=["handle.stop", "axis.stop", "controller.stop", "controller.stop(A)", "abort"],
)
def test_the_librarys_own_stops_still_end_a_move_quietly(
    dmc: galil.Controller, stop: object
) -> None:
    handle = dmc.A.move_to(20_000)
    dmc.sleep(0.1)
    stop(dmc, handle)  # type: ignore[operator]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = handle.wait()
    assert result.stop_codes["A"] in (4, 7)


def test_a_jog_stopped_by_a_raw_st_ends_quietly(dmc: galil.Controller) -> None:
    jog = dmc.A.jog(5000)
    dmc.sleep(0.1)
    dmc.command("STA")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert jog.wait(timeout=5).stop_codes == {"A": 4}


def test_a_vector_move_stopped_by_a_raw_st_s_makes_wait_raise(dmc: galil.Controller) -> None:
    handle = dmc.vector_move("AB", [Line(40_000, 20_000)], speed=20_000)
    dmc.sleep(0.2)
    dmc.command("STS")
    with pytest.raises(MotionError, match="stopped early by a stop this library did not send"):
        handle.wait()


def test_a_vector_move_the_library_stops_ends_quietly(dmc: galil.Controller) -> None:
    handle = dmc.vector_move("AB", [Line(40_000, 20_000)], speed=20_000)
    dmc.sleep(0.2)
    handle.stop()
    handle.wait()


def test_a_homing_stopped_by_a_raw_st_makes_wait_raise(dmc: galil.Controller) -> None:
    handle = dmc.A.home()
    dmc.sleep(0.05)
    dmc.command("STA")
    with pytest.raises(MotionError, match=r"home move on A .* A by ST \(stop code 4\)"):
        handle.wait(timeout=10)
    assert not dmc.A.homed


def test_a_speed_schedule_stopped_by_a_raw_ab_makes_wait_raise(dmc: galil.Controller) -> None:
    schedule = dmc.B.speed_schedule(12000, [(4000, 8000)], speed=15000)
    dmc.sleep(0.3)
    dmc.command("AB")
    with pytest.raises(MotionError, match=r"B by AB \(stop code 7\)"):
        schedule.wait()


def test_an_async_wait_raises_for_a_raw_st_and_not_for_its_own_stop() -> None:
    async def body() -> None:
        async with await aio.connect("sim://DMC-4040") as c:
            move = await c.A.move_to(20_000)
            await c.sleep(0.1)
            await c.command("STA")
            with pytest.raises(MotionError, match=r"A by ST \(stop code 4\)"):
                await move.wait()
            move = await c.A.move_to(0)
            await c.sleep(0.1)
            await move.stop()
            await move

    asyncio.run(asyncio.wait_for(body(), 30))


def test_a_deviation_without_a_stop_warns_at_the_callers_line(dmc: galil.Controller) -> None:
    handle = dmc.A.move_by(20_000)
    dmc.sleep(0.1)
    dmc.link.command_line(["IPA=1000"])  # behind the library's back: the prediction is wrong
    with pytest.warns(RuntimeWarning, match=r"counts away from the prediction") as said:
        result = handle.wait()
    assert said[0].filename == __file__
    assert result.stop_codes == {"A": 1}
    assert result.deviation == {"A": 1000}
