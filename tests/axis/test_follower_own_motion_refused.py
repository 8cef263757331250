"""Every motion of its own on an axis the library has geared to another is refused unsent.

A move, a jog, an increment and homing of a follower were refused before any byte; a
contour, a speed schedule and a vector path on it were not. Once a limit had stopped the
follower (the controller turning its gearing off, unseen: nobody waited), those ran, and the
library went on counting on a gearing the controller had dropped (found by a long run of the
operation-sequence fuzz: a contour on the follower, the library's view then wrong).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil.errors import InvalidArgument
from galil.testing import nothing_sent, sim_of

Start = Callable[[galil.Controller], object]

STARTS: dict[str, Start] = {
    "contour": lambda dmc: dmc.contour("BC", np.zeros((10, 2)), dt=1),
    "speed schedule": lambda dmc: dmc.C.speed_schedule(12_000, [(6_000, 8_000)], speed=30_000),
    "vector path": lambda dmc: dmc.vector_move("BC", [galil.Line(1_000, 1_000)], speed=10_000),
    "move": lambda dmc: dmc.C.move_by(100),
    "jog": lambda dmc: dmc.C.jog(1_000),
}


@pytest.mark.parametrize("start", list(STARTS.values()), ids=list(STARTS))
def test_own_motion_of_a_follower_a_limit_stopped_is_refused_unsent(
    dmc: galil.Controller, start: Start
) -> None:
    sim_of(dmc).place_limit_switches("C", reverse=-500)
    dmc.C.gear_to("A", 0.5)
    dmc.A.jog(-20_000)
    dmc.sleep(1.0)
    assert dmc.query_operands(["_SCC"]) == [3]  # the reverse limit stopped C, unseen
    dmc.A.stop()
    dmc.sleep(0.5)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="geared to A"):
        start(dmc)
