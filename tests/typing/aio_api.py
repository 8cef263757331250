"""Checked by ``mypy --strict`` in ``make typecheck`` (not run by pytest): galil.aio's types.

The twins keep the sync methods' parameters and return types (``assert_type`` fails the type
check when mypy infers anything else, e.g. ``Any``).
"""

from __future__ import annotations

from typing_extensions import assert_type

import galil
import galil.aio as aio
from galil.contour import ContourResult
from galil.predict import MultiProfile, Profile


async def check(c: aio.AsyncController) -> None:
    assert_type(await aio.connect("sim://DMC-4040"), aio.AsyncController)
    assert_type(await c.command("TPA"), str)
    assert_type(await c.query_operands(["_TPA"]), list[float])
    assert_type(c.A, aio.AsyncAxis)
    assert_type(await c.A.move_to(10), aio.AsyncMoveHandle)
    assert_type(await c.A.jog(1000), aio.AsyncMoveHandle)
    assert_type(await c.move({"A": 1}), aio.AsyncMoveHandle)
    assert_type(await c.A.plan_to(10), Profile)
    assert_type(await c.plan({"A": 1}), MultiProfile)
    assert_type(await (await c.A.move_to(10)), galil.MoveResult)
    assert_type(await c.contour("A", [1.0], dt=2), ContourResult)
    assert_type(await c.records(8), aio.AsyncRecordStream)
    assert_type(await c.messages.get(), str)
    assert_type(await c.A.moving(), bool)
