"""An arc on axes whose scales are reversed turns as the user sees it, in user units."""

from __future__ import annotations

import pytest

from galil import Arc
from galil.errors import InvalidArgument
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm = ureg.mm


@pytest.mark.parametrize(("sign_a", "sign_b"), [(1, 1), (1, -1), (-1, -1)])
def test_an_arc_ends_where_the_user_expects_whichever_scales_are_reversed(
    sign_a: int, sign_b: int
) -> None:
    with simulated() as dmc:
        dmc.A.set_scale(counts_per=1000 / mm, sign=sign_a)
        dmc.B.set_scale(counts_per=1000 / mm, sign=sign_b)
        # From 90 degrees a clockwise quarter turn: +r in x, -r in y, as the user sees them.
        arc = Arc(10 * mm, 90, -90)
        dmc.vector_move("AB", [arc], speed=20 * mm / ureg.s, accel=500 * mm / ureg.s**2).wait()
        assert dmc.A.reference_position == 10 * mm
        assert dmc.B.reference_position == -10 * mm
        assert dmc.query_operands(["_RPA", "_RPB"]) == [10_000 * sign_a, -10_000 * sign_b]


def test_an_arc_whose_sweep_rounds_to_nothing_is_refused_before_a_byte() -> None:
    with simulated() as dmc:
        dmc.A.set_scale(counts_per=1000 / mm, sign=-1)
        dmc.B.set_scale(counts_per=1000 / mm, sign=-1)
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="rounds to 0"):
            dmc.vector_move("AB", [Arc(10 * mm, 0, 1e-6)], speed=20_000)
