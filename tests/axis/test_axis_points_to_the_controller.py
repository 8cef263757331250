"""What is the controller's, reached for on an axis, points to the controller's call: an
axis has no ``motor_off()``/``servo_here()`` (``controller.motor_off('A')``), its
``motor_on`` is read-only (the same calls), and an axis given where letters are expected
(``controller.motor_off(x)``) is told to be given as ``'A'``, as ``controller.move({x: ...})``
says. Nothing is sent by any of these."""

from __future__ import annotations

import asyncio
import copy
from collections.abc import Callable

import pytest

import galil
import galil.aio as aio
from galil.errors import GalilAttributeError, InvalidArgument
from galil.testing import nothing_sent


@pytest.mark.parametrize(
    ("name", "call"),
    [("motor_off", "controller.motor_off('B')"), ("servo_here", "controller.servo_here('B')")],
)
def test_an_axis_method_of_the_controller_points_to_it(
    dmc: galil.Controller, name: str, call: str
) -> None:
    x = dmc.B
    with nothing_sent(dmc), pytest.raises(GalilAttributeError) as info:
        getattr(x, name)()
    assert str(info.value).startswith(f"Axis has no attribute {name!r}: ")
    assert call in str(info.value)
    assert isinstance(info.value, AttributeError)


def test_assigning_motor_on_points_to_the_controllers_calls(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(GalilAttributeError) as info:
        dmc.A.motor_on = False  # type: ignore[misc]
    said = str(info.value)
    assert said.startswith("Axis.motor_on is read-only: ")
    assert "controller.motor_off('A') or controller.servo_here('A')" in said


def test_a_misspelt_axis_attribute_suggests_the_name_and_private_names_stay_plain(
    dmc: galil.Controller,
) -> None:
    with pytest.raises(GalilAttributeError, match=r"did you mean 'move_to'\?"):
        dmc.A.mvoe_to(1)  # type: ignore[attr-defined]
    assert not hasattr(dmc.A, "motor_off")
    assert getattr(dmc.A, "__deepcopy_hook__", None) is None
    assert copy.copy(dmc.A).letter == "A"


@pytest.mark.parametrize(
    ("call", "given"),
    [
        (lambda dmc: dmc.motor_off(dmc.A), "'A'"),
        (lambda dmc: dmc.stop(dmc.B), "'B'"),
        (lambda dmc: dmc.servo_here(dmc.A), "'A'"),
        (lambda dmc: dmc.stop([dmc.A, dmc.C]), "'AC'"),
    ],
)
def test_an_axis_given_for_letters_is_told_its_letters(
    dmc: galil.Controller, call: Callable[[galil.Controller], object], given: str
) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument) as info:
        call(dmc)
    assert f"axes are named by their letters here, give {given}" in str(info.value)


def test_the_async_axis_points_to_the_awaited_controller_call() -> None:
    async def body() -> tuple[str, str]:
        async with await aio.connect("sim://DMC-4040") as c:
            with pytest.raises(GalilAttributeError) as missing:
                c.A.motor_off()  # type: ignore[attr-defined]
            with pytest.raises(InvalidArgument) as given:
                await c.motor_off(c.A)  # type: ignore[arg-type]
            return str(missing.value), str(given.value)

    missing, given = asyncio.run(asyncio.wait_for(body(), 30))
    assert "await controller.motor_off('A')" in missing
    assert "give 'A'" in given
