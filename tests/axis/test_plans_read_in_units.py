"""A plan is read in the axis's units: ``plan.q.at(t)``, ``dmc.plan(...).at(t)``; a plan of an
axis without a scale says so rather than failing on ``.q``; a string position says strings are
not parsed."""

from __future__ import annotations

import numpy as np
import pytest

from galil.axis import UnitProfile
from galil.errors import InvalidArgument
from galil.testing import simulated
from galil.units import ureg

mm, s, ms = ureg.mm, ureg.s, ureg.ms


def test_q_at_reads_a_position_at_a_time_in_the_axis_unit() -> None:
    with simulated("DMC-4040") as dmc:
        x = dmc.A.set_scale(counts_per=800 / mm, offset=12.5 * mm, sign=-1)
        plan = x.plan_to(20 * mm)
        expected = 12.5 - plan.at(0.2) / 800  # (sign -1: counts fall as mm rise)
        assert plan.q.at(0.2).m_as("mm") == pytest.approx(expected)
        assert plan.q.at(200 * ms) == plan.q.at(0.2)
        assert plan.q.at(10.0) == 20 * mm
        both = plan.q.at(np.array([0.0, 10.0]) * s)
        assert list(both.m_as("mm")) == [12.5, 20.0]


def test_a_multi_axis_plan_reads_every_axis_at_a_time() -> None:
    with simulated("DMC-4040") as dmc:
        dmc.A.set_scale(counts_per=800 / mm)
        plan = dmc.plan({"A": 20 * mm, "B": 3000})
        at = plan.at(100 * ms)
        assert at == {"A": plan["A"].at(0.1), "B": plan["B"].at(0.1)}
        assert plan.at(100.0) == {"A": 16000.0, "B": 3000.0}
        with pytest.raises(InvalidArgument, match="t must be a time"):
            plan.at(1 * mm)


def test_a_plan_of_an_axis_without_a_scale_says_it_is_in_counts() -> None:
    with simulated("DMC-4040") as dmc:
        plan = dmc.A.plan_to(1000)
        assert isinstance(plan, UnitProfile)
        assert plan.end == 1000
        with pytest.raises(InvalidArgument, match="without a scale: it is in counts"):
            _ = plan.q


@pytest.mark.parametrize("scaled", [True, False], ids=["scaled", "counts"])
def test_a_string_position_is_refused_as_unparsed(scaled: bool) -> None:
    with simulated("DMC-4040") as dmc:
        x = dmc.A.set_scale(counts_per=800 / mm) if scaled else dmc.A
        with pytest.raises(InvalidArgument, match=r"a string is not parsed.*ureg\('10 mm'\)"):
            x.move_to("10 mm")  # type: ignore[arg-type]
        with pytest.raises(InvalidArgument, match="a string is not parsed"):
            x.speed = "5 mm/s"  # type: ignore[assignment]
        assert dmc.query_number("MG _BGA") == 0
