"""The mistakes a newcomer makes first get an error that says what to do next.

Each case is one a first afternoon with the library meets: moving an axis that still moves,
jogging one that is stopping, waiting too briefly, using a controller after closing it, a
reversed scale, an analog output the model lacks. The message names the call that helps.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from decimal import Decimal

import numpy as np
import pytest

import galil
import galil.aio
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        yield controller


def test_a_second_move_before_the_first_ends_says_to_wait_or_stop(dmc: galil.Controller) -> None:
    move = dmc.A.move_by(10_000)
    with pytest.raises(galil.InvalidArgument) as info:
        dmc.A.move_by(10_000)
    assert "already moving; wait for its move (handle.wait()) or stop it" in str(info.value)
    move.wait()


def test_jogging_an_axis_that_is_stopping_says_how_to_wait_for_it(dmc: galil.Controller) -> None:
    jog = dmc.A.jog(10_000)
    dmc.sleep(0.2)
    dmc.A.stop()
    with pytest.raises(galil.InvalidArgument) as info:
        dmc.A.jog(5_000)
    assert "is stopping; wait for it before jogging again" in str(info.value)
    assert "handle.wait()" in str(info.value)
    jog.wait()  # what the message says: then the axis jogs again
    dmc.A.jog(5_000)
    dmc.A.stop()


def test_a_wait_that_times_out_says_the_move_goes_on(dmc: galil.Controller) -> None:
    move = dmc.A.move_by(100_000)
    with pytest.raises(galil.GalilTimeoutError) as info:
        move.wait(timeout=0.1)
    assert "it goes on: wait again, or stop it" in str(info.value)
    assert dmc.A.moving  # as it says
    move.wait()


def _wait_too_short_in_a_guard(dmc: galil.Controller) -> None:
    with dmc.motion():
        dmc.A.move_by(100_000).wait(timeout=0.1)


def test_a_wait_that_times_out_in_a_motion_block_says_the_block_stops_the_move(
    dmc: galil.Controller,
) -> None:
    with pytest.raises(galil.GalilTimeoutError) as info:
        _wait_too_short_in_a_guard(dmc)
    assert "it goes on: wait again" in str(info.value)  # (not in a block: as it says)
    assert "a controller.motion() block guarding its axes stops it" in str(info.value)
    assert not dmc.A.moving  # as it says: the guard stopped it
    assert dmc.A.stop_code[0] == 4


def test_an_async_wait_that_times_out_says_the_move_goes_on() -> None:
    async def body() -> None:
        async with await galil.aio.connect("sim://DMC-4040") as c:
            move = await c.A.move_by(100_000)
            with pytest.raises(galil.GalilTimeoutError, match="it goes on: wait again"):
                async for _ in move.watch(timeout=0.1):
                    pass
            assert await c.A.moving()
            await move

    asyncio.run(body())


def test_a_closed_controller_says_how_to_get_a_new_one() -> None:
    with simulated() as dmc:
        pass
    with pytest.raises(galil.GalilConnectionError) as info:
        dmc.A.position  # noqa: B018 (a read)
    assert "link is closed (close(), or the end of its with block)" in str(info.value)
    assert "galil.connect() opens a new one" in str(info.value)


def test_a_closed_async_controller_says_how_to_get_a_new_one() -> None:
    async def body() -> None:
        async with await galil.aio.connect("sim://DMC-4040") as c:
            pass
        with pytest.raises(galil.GalilConnectionError, match=r"galil\.aio\.connect\(\) opens"):
            await c.command("TP")

    asyncio.run(body())


def test_a_negative_scale_points_at_sign(dmc: galil.Controller) -> None:
    with pytest.raises(galil.InvalidArgument, match="sign=-1"):
        dmc.A.set_scale(counts_per=-2000 / mm)
    reversed_axis = dmc.A.set_scale(counts_per=2000 / mm, sign=-1)  # what it points at
    assert reversed_axis.plan_to(1 * mm).position[-1] == -2000


def test_an_output_the_model_has_none_of_says_so(dmc: galil.Controller) -> None:
    with pytest.raises(galil.InvalidArgument) as info:
        dmc.io.analog_out[1] = 2.0
    assert "analog output 1 does not exist: DMC-4040 has no analog outputs" in str(info.value)


@pytest.mark.parametrize("path", [[1 * mm, 2 * mm], [[1 * mm, 0 * mm], [2 * mm, 1 * mm]]])
def test_a_contour_path_given_as_a_list_of_quantities_says_how_to_make_one_array(
    dmc: galil.Controller, path: list[object]
) -> None:
    dmc.A.set_scale(counts_per=2000 / mm)
    dmc.B.set_scale(counts_per=2000 / mm)
    axes = "AB" if isinstance(path[0], list) else "A"
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
        dmc.contour(axes, path, dt=4)
    assert "contour path is a list of Quantities; give one Quantity array instead" in str(
        info.value
    )
    result = dmc.contour("A", np.array([1, 2]) * mm, dt=4)  # what it says works
    assert result.increments.tolist() == [[2000], [2000]]


def test_running_a_label_without_its_hash_suggests_the_label(dmc: galil.Controller) -> None:
    dmc.programs.download("#SQUARES\nEN")
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
        dmc.programs.run("SQUARES")
    assert "(did you mean '#SQUARES'?)" in str(info.value)
    with pytest.raises(galil.InvalidArgument) as info:
        dmc.programs.run("#TOOLONGLABEL")  # no label with a '#' in front either: no guess
    assert "did you mean" not in str(info.value)
    dmc.programs.run("#SQUARES")  # what it suggests runs
    dmc.programs.wait()


def test_a_move_keyed_by_an_axis_object_says_axes_are_named_by_letter(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
        dmc.move({dmc.A: 100})
    assert "axes are named by their letters here: give 'A'" in str(info.value)
    with simulated() as other:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
            dmc.move({other.A: 100})
        assert "is an axis of another controller" in str(info.value)
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
            dmc.vector_move([other.A, other.B], [galil.Line(100, 100)], speed=1000)  # type: ignore[arg-type]
        assert "is an axis of another controller" in str(info.value)
    dmc.move({"A": 100}).wait()  # as it says


@pytest.mark.parametrize("relative", [False, True])
def test_a_move_of_several_axes_names_the_axis_of_a_bad_target(
    dmc: galil.Controller, relative: bool
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
        dmc.move({"A": 1, "B": float("nan")}, relative=relative)
    what = "distance" if relative else "target"
    assert f"{what} of B must be a finite number, got nan" in str(info.value)


_DECIMAL = Decimal("0.5")
_TAKES_A_NUMBER = {
    "speed": lambda d: setattr(d.A, "speed", _DECIMAL),
    "move_to": lambda d: d.A.move_to(_DECIMAL),
    "move": lambda d: d.move({"A": _DECIMAL}),
    "jog": lambda d: d.A.jog(_DECIMAL),
    "kp": lambda d: setattr(d.A, "kp", _DECIMAL),
    "smoothing": lambda d: setattr(d.A, "smoothing", _DECIMAL),
    "variable": lambda d: d.variables.__setitem__("x", _DECIMAL),
    "sleep": lambda d: d.sleep(_DECIMAL),
    "timeout": lambda d: setattr(d, "timeout", _DECIMAL),
    "watchdog": lambda d: d.watchdog(_DECIMAL),
    "Line": lambda d: galil.Line(_DECIMAL, 0),
    "Arc": lambda d: galil.Arc(5, 0, _DECIMAL),
    "analog output": lambda d: d.io.analog_out.__setitem__(1, _DECIMAL),
    "gear ratio": lambda d: d.B.gear_to("A", _DECIMAL),
    "records seconds": lambda d: d.records(seconds=_DECIMAL),
    "vector speed": lambda d: d.plan_vector("AB", [galil.Line(100, 0)], speed=_DECIMAL),
    "a Quantity of one": lambda d: d.A.set_scale(counts_per=2000 / mm).move_to(_DECIMAL * mm),
    "predict tm": lambda d: galil.predict.check_parameter("SP", 100, tm=_DECIMAL),
}


@pytest.mark.parametrize("call", _TAKES_A_NUMBER.values(), ids=_TAKES_A_NUMBER.keys())
def test_a_decimal_where_a_number_is_taken_is_refused_saying_to_float_it(
    dmc: galil.Controller, call: object
) -> None:
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument) as info:
        call(dmc)  # type: ignore[operator]
    assert "a decimal.Decimal is not taken: pass float() of it" in str(info.value)
