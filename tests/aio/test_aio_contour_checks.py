"""galil.aio contour: a bad timeout is refused before anything reaches the controller; a
follower a limit stopped during the contour is reported by it (decision 0049)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from aio_helpers import commands_of, run, sim

from galil.errors import InvalidArgument, MotionError
from galil.testing import sim_of


@pytest.mark.parametrize("timeout", ["5", -1, math.nan])
def test_async_contour_with_a_bad_timeout_sends_nothing(timeout: object) -> None:
    async def body() -> None:
        async with await sim() as c:
            before = len(commands_of(c))
            with pytest.raises(InvalidArgument, match="timeout"):
                await c.contour("A", [1, 2], dt=1, timeout=timeout)  # type: ignore[arg-type]
            assert len(commands_of(c)) == before

    run(body)


def test_async_contour_reports_a_follower_a_limit_switch_stopped() -> None:
    async def body() -> None:
        async with await sim() as c:
            sim_of(c.sync).place_limit_switches("C", forward=1000)
            c.sync.C.gear_to("A", 2)
            with pytest.raises(MotionError, match="a follower stopped early") as caught:
                await c.contour("A", np.linspace(25, 1000, 40), dt=4)
            assert caught.value.stop_codes == {"A": 51, "C": 2}
            assert c.sync.tracker.followers("A") == {}

    run(body)


def test_async_contour_on_an_axis_with_its_motor_off_sends_no_cm() -> None:
    async def body() -> None:
        async with await sim() as c:
            await c.motor_off("A")
            with pytest.raises(InvalidArgument, match="axis A has its motor off"):
                await c.contour("A", [100, 200, 300], dt=2)
            assert not any(text.startswith(("CM", "CD")) for text in commands_of(c))
            assert await c.query_operands(["_RPA"]) == [0.0]

    run(body)
