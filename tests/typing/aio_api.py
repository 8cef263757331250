"""Checked by ``mypy --strict`` in ``make typecheck`` (not run by pytest): galil.aio's types.

The twins keep the sync methods' parameters and return types (``assert_type`` fails the type
check when mypy infers anything else, e.g. ``Any``).
"""

from __future__ import annotations

import asyncio

import numpy as np
import numpy.typing as npt
import pint
from typing_extensions import assert_type

import galil
import galil.aio as aio
import galil.units
from galil.axis import UnitProfile
from galil.contour import ContourResult
from galil.predict import MultiProfile, Profile
from galil.programs import Download
from galil.units import ureg


async def check(c: aio.AsyncController) -> None:
    assert_type(await aio.connect("sim://DMC-4040"), aio.AsyncController)
    assert_type(await c.command("TPA"), str)
    assert_type(await c.query_operands(["_TPA"]), list[float])
    assert_type(c.A, aio.AsyncAxis)
    assert_type(await c.A.move_to(10), aio.AsyncMoveHandle)
    assert_type(await c.A.jog(1000), aio.AsyncMoveHandle)
    assert_type(await c.move({"A": 1}), aio.AsyncMoveHandle)
    assert_type(await c.A.plan_to(10), UnitProfile)
    assert_type(await c.plan({"A": 1}), MultiProfile)
    assert_type(await (await c.A.move_to(10)), galil.MoveResult)
    assert_type(await (await c.A.move_to(10)).wait(), galil.MoveResult)
    assert_type(await (await c.A.move_to(10)).wait(5, progress=True), galil.MoveResult)
    assert_type(await asyncio.gather((await c.A.move_to(10)).wait()), tuple[galil.MoveResult])
    assert_type(await asyncio.create_task((await c.A.move_to(10)).wait()), galil.MoveResult)
    assert_type(await c.contour("A", [1.0], dt=2), ContourResult)
    assert_type(await c.records(8), aio.AsyncRecordStream)
    assert_type(await c.messages.get(), str)
    assert_type(await c.A.moving(), bool)


async def check_rooms(c: aio.AsyncController) -> None:
    # I/O: indexing reads (awaited), set() writes.
    assert_type(await c.io.inputs[1], bool)
    assert_type(await c.io.inputs[1:9], tuple[bool, ...])
    assert_type(await c.io.outputs.all(), tuple[bool, ...])
    assert_type(await c.io.outputs.set(2, True), None)
    assert_type(await c.io.wait_for_input(4, high=False, timeout=5), None)
    # Programs, arrays, variables.
    assert_type(await c.programs.download("#A\nEN"), Download)
    assert_type(await c.programs.run("#A", thread=1), None)
    assert_type(await c.programs.threads(), dict[int, int])
    assert_type(await c.programs.wait(1, timeout=5), None)
    assert_type(await c.arrays.upload("sq"), npt.NDArray[np.float64])
    assert_type(await c.arrays.list(), dict[str, int])
    assert_type(await c.variables["gain"], float)
    assert_type(await c.variables.write("gain", 2.5), None)
    # Interrupts: an async iterator.
    assert_type(await c.interrupts.enable("A", all_done=True), None)
    assert_type(await c.interrupts.get(timeout=1), galil.Interrupt)
    async for interrupt in c.interrupts:
        assert_type(interrupt, galil.Interrupt)
    # Capture, watchdog, switches and flash.
    capture = await c.capture(["_RPA"], seconds=1.0)
    assert_type(capture, aio.AsyncCapture)
    assert_type(await capture.wait(), galil.Recording)
    assert_type(await c.watchdog(0.5), aio.AsyncWatchdog)
    assert_type(await c.switch_polarity(), galil.SwitchPolarity)
    assert_type(await c.save(), None)


async def check_motion(c: aio.AsyncController) -> None:
    path = [galil.Line(1000, 0), galil.Arc(500, 270, 90)]
    handle = await c.vector_move("AB", path, speed=20_000)
    assert_type(handle, aio.AsyncVectorHandle)
    assert_type(await handle, galil.MoveResult)
    assert_type(handle.vector, galil.VectorPlan)
    assert_type(await c.plan_vector("AB", path, speed=20_000), galil.VectorPlan)
    assert_type(await c.A.home(), aio.AsyncMoveHandle)
    assert_type(await c.A.find_index(switch=None), aio.AsyncMoveHandle)
    assert_type(await c.A.homed(), galil.Homed)
    assert_type(await c.A.switches(), galil.Switches)
    assert_type(await c.A.kp(), float)
    assert_type(await c.A.error_limit(), int)
    assert_type(await c.A.motor_type(), galil.MotorType | float)
    assert_type(await c.A.limit_disable(), galil.LimitDisable)
    await c.A.set_limit_disable(galil.LimitDisable.BOTH)
    assert_type(await c.A.encoder_config(), galil.EncoderConfig)
    await c.A.set_encoder_config(galil.EncoderConfig(main=galil.EncoderType.QUADRATURE_REVERSED))
    assert_type(await c.A.set_kp(10), None)
    gearing = await c.B.gear_to(c.A, 0.5)
    assert_type(gearing, aio.AsyncGearing)
    assert_type(gearing.predict(await c.A.plan_to(10)), Profile)
    assert_type(await gearing.off(), None)
    assert_type(c.A.position_counts(5), float)


async def check_units(c: aio.AsyncController) -> None:
    # decision 0099: the sync axis's types, awaited.
    assert_type(await c.A.position(), galil.Reading)
    assert_type(await c.A.position(), float | pint.Quantity[float])
    assert_type(await c.A.speed(), galil.Reading)
    assert_type(await c.A.soft_limits(), tuple[galil.Reading | None, galil.Reading | None])
    assert_type(await c.A.set_speed(5 * ureg.mm / ureg.s), None)
    assert_type(await c.A.plan_by(ureg.Quantity(10.0, "mm"), speed=None), UnitProfile)
    assert_type((await c.A.plan_to(10)).q.end, pint.Quantity[float])
    assert_type(await c.A.move_to(np.int64(10), accel=1e5), aio.AsyncMoveHandle)
    assert_type(await c.plan({"A": 1}, relative=True, speed=100), MultiProfile)
    await c.A.move_to("10")  # type: ignore[arg-type]
    await c.A.move_to(10, sped=5)  # type: ignore[call-arg]
    assert_type(c.A.scale, galil.units.Scale | None)
    assert_type(await c.io.analog_in[1], pint.Quantity[float])
    assert_type(await c.io.analog_in[1:3], tuple[pint.Quantity[float], ...])
    assert_type(await c.io.analog_in.all(), tuple[pint.Quantity[float], ...])
    assert_type(await c.io.analog_out[0], pint.Quantity[float])
    assert_type(await c.io.analog_out.set(0, ureg.Quantity(2.5, "V")), None)
