"""A refused contour path says what is wrong with its shape (empty; 1-D for several axes; the
wrong number of columns), and a scale given an array of counts per unit is refused with
InvalidArgument (before: a bare TypeError from numpy), as every unit entry point refuses an
array where one value is expected.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil.testing import nothing_sent
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.mark.parametrize(
    ("axes", "path", "says"),
    [
        ("A", [], "the path is empty (shape (0,)): a contour needs at least one segment"),
        ("AB", np.zeros((0, 2)), "the path is empty"),
        ("AB", np.arange(31.0), "a 1-D path (shape (31,)) is for one axis, and AB are 2"),
        ("AB", np.arange(31.0), "give shape (segments, 2), a column per axis"),
        ("A", np.zeros((31, 2)), "the path has 2 columns (shape (31, 2)) but the contour drives 1"),
        ("A", np.zeros((31, 2)), "give shape (segments,) or (segments, 1)"),
        ("ABC", np.zeros((4, 2)), "drives 3 axes"),
        ("AB", np.zeros((3, 2, 2)), "the path has 3 dimensions"),
    ],
)
def test_a_contour_path_of_the_wrong_shape_says_what_is_wrong(
    dmc: galil.Controller, axes: str, path: object, says: str
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
        dmc.contour(axes, path, dt=2)
    assert says in str(info.value)


def test_a_scale_of_an_array_is_refused_as_one_value_expected(dmc: galil.Controller) -> None:
    for bad in (np.array([2000, 1]) / mm, (2000 + 0j) / mm):
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="one real value"):
            dmc.C.set_scale(counts_per=bad)
    assert dmc.C.scale is None  # the axis keeps what it had
    assert dmc.C.set_scale(counts_per=np.array(2000.0) / mm).scale is not None  # 0-d: one value


def test_every_unit_entry_point_refuses_an_array_for_one_value(x: galil.Axis) -> None:
    # (a guard: these were refused before too; set_scale's counts_per was the one left)
    pair = np.array([1.0, 2.0])
    calls: list[Callable[[], object]] = [
        lambda: x.set_scale(counts_per=2000 / mm, offset=pair * mm),
        lambda: setattr(x, "speed", pair * mm / s),
        lambda: setattr(x, "accel", pair * mm / s**2),
        lambda: x.jog(pair * mm / s),
        lambda: setattr(x, "soft_limits", (pair * mm, 5 * mm)),
        lambda: x.define_position(pair * mm),
        lambda: x.increment(pair * mm),
        lambda: x.plan_to(pair * mm),
        lambda: x.plan_to(1 * mm, speed=pair * mm / s),
        lambda: x.speed_schedule(pair * mm, [(1 * mm, 2 * mm / s)]),
    ]
    for call in calls:
        with pytest.raises(galil.InvalidArgument, match="one real value"):
            call()
