"""Refusals before any byte found by a machine builder's review (decision 0100): a Line in
counts with a fraction of a count (decision 0092), ``smoothing=True`` taken as VT 1, ``S`` as
the master of the only axis of a one-axis controller, and ``controller.axes["B"]`` there a
bare ``KeyError``.
"""

from __future__ import annotations

import asyncio

import pytest

import galil
import galil.aio
from galil import Arc, Line
from galil.errors import InvalidArgument, UnknownAxisError
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.mark.parametrize(
    "line",
    [Line(1000.4, 500.6), Line(1000, 500.5), Line(1000.25 * ureg.count, 0)],
    ids=["both", "half", "count quantity"],
)
def test_a_line_in_counts_with_a_fraction_of_a_count_is_refused_unsent(line: Line) -> None:
    with simulated("DMC-4240") as dmc, nothing_sent(dmc):
        for call in (dmc.plan_vector, dmc.vector_move):
            with pytest.raises(InvalidArgument, match="not a whole number of counts"):
                call("AB", [line], speed=5000)


def test_whole_counts_and_lengths_in_user_units_still_run() -> None:
    with simulated("DMC-4240") as dmc:
        ends = dmc.vector_move("AB", [Line(1000.0, 500), Arc(300, 0, 90)], speed=5000).wait()
        assert ends.worst == 0
        dmc.A.set_scale(counts_per=2000 / mm)
        dmc.B.set_scale(counts_per=2000 / mm)
        start = dmc.query_operands(["_RPA", "_RPB"])
        # 0.0003 mm is 0.6 counts: a scale's unit rounds along the path (decision 0092)
        result = dmc.vector_move("AB", [Line(1.0003 * mm, 0.5 * mm)], speed=10 * mm / s).wait()
        assert result.final == {"A": round(start[0]) + 2001, "B": round(start[1]) + 1000}


@pytest.mark.parametrize("smoothing", [True, False, "0.5", [0.5]])
def test_smoothing_that_is_not_a_number_is_refused_unsent(smoothing: object) -> None:
    with simulated("DMC-2143") as dmc, nothing_sent(dmc):
        for call in (dmc.plan_vector, dmc.vector_move):
            with pytest.raises(InvalidArgument, match=r"smoothing \(VT\) must be a number"):
                call("AB", [Line(1000, 1000)], speed=5000, smoothing=smoothing)  # type: ignore[arg-type]


def test_smoothing_as_a_number_is_still_vt() -> None:
    with simulated("DMC-2143") as dmc:
        plan = dmc.plan_vector("AB", [Line(1000, 1000)], speed=5000, smoothing=1)
        assert plan.counts.speed_settings[3] == 1.0


def test_the_only_axis_of_a_one_axis_controller_cannot_follow_s() -> None:
    with simulated("DMC-30010") as dmc, nothing_sent(dmc):
        with pytest.raises(InvalidArgument, match="DMC-30010 has one axis, A: it cannot follow S"):
            dmc.A.gear_to("S", 1)
        assert dmc.tracker.gears == {}


def test_a_follower_of_s_on_a_controller_of_more_axes_is_still_geared() -> None:
    with simulated("DMC-4040") as dmc:
        gearing = dmc.B.gear_to("S", 2)
        assert dmc.query_number("MG _GRB") == 2
        gearing.off()


@pytest.mark.parametrize(
    ("model", "key", "says"),
    [
        ("DMC-30010", "B", "DMC-30010 has no axis 'B': it has axes A"),
        ("DMC-4040", "E", "DMC-4040 has no axis 'E': it has axes A, B, C, D"),
        ("RIO-47120", "A", "RIO-47120 is an I/O controller with no axes"),
    ],
)
def test_an_axis_the_model_lacks_is_an_unknown_axis_error_and_a_key_error(
    model: str, key: str, says: str
) -> None:
    with simulated(model) as dmc, nothing_sent(dmc):
        with pytest.raises(UnknownAxisError, match=says) as caught:
            dmc.axes[key]
        assert isinstance(caught.value, KeyError)
        assert isinstance(caught.value, galil.GalilError)
        assert caught.value.name == key
        assert str(caught.value).startswith(says)  # (not quoted, as a bare KeyError's is)
        assert dmc.axes.get(key) is None
        assert key not in dmc.axes


def test_the_async_axes_mapping_says_the_same() -> None:
    async def body() -> None:
        c = await galil.aio.connect("sim://DMC-30010")
        try:
            with pytest.raises(UnknownAxisError, match="DMC-30010 has no axis 'B'"):
                c.axes["B"]
            assert c.axes["A"] is c.A
        finally:
            await c.aclose()

    asyncio.run(body())
