"""galil.aio contour: a bad timeout is refused before anything reaches the controller."""

from __future__ import annotations

import math

import pytest
from aio_helpers import commands_of, run, sim

from galil.errors import InvalidArgument


@pytest.mark.parametrize("timeout", ["5", -1, math.nan])
def test_async_contour_with_a_bad_timeout_sends_nothing(timeout: object) -> None:
    async def body() -> None:
        async with await sim() as c:
            before = len(commands_of(c))
            with pytest.raises(InvalidArgument, match="timeout"):
                await c.contour("A", [1, 2], dt=1, timeout=timeout)  # type: ignore[arg-type]
            assert len(commands_of(c)) == before

    run(body)
