"""contour(speed_limit=/accel_limit=) per axis: keys are axis letters or their aliases, and a key
that names no axis is refused before anything is sent."""

from __future__ import annotations

import numpy as np
import pytest

from galil.errors import InvalidArgument, LimitError
from galil.testing import nothing_sent, simulated


@pytest.mark.parametrize("key", ["X", "x", "A"])
def test_contour_speed_limit_by_alias_applies(key: str) -> None:
    with simulated("DMC-18x2") as c:
        path = np.linspace(0, 20_000, 11)[1:]
        with nothing_sent(c, allow_queries=True), pytest.raises(LimitError):
            c.contour("A", path, dt=3, speed_limit={key: 1000})


def test_contour_limit_naming_no_axis_is_refused() -> None:
    with simulated("DMC-18x2") as c:
        path = np.linspace(0, 20_000, 11)[1:]
        refusal = r"speed_limit: axis 'E' does not exist on DMC-18x2 \(axes: A, B, C, D\)"
        refusal += r" \[DMC-18x2\]$"  # the model named once
        with nothing_sent(c, allow_queries=True), pytest.raises(InvalidArgument, match=refusal):
            c.contour("A", path, dt=3, speed_limit={"E": 1000})
        with nothing_sent(c, allow_queries=True), pytest.raises(InvalidArgument, match="twice"):
            c.contour("A", path, dt=3, accel_limit={"A": 1e6, "X": 1e6})


def test_a_limit_for_an_axis_the_contour_does_not_drive_is_refused_not_ignored() -> None:
    with simulated("DMC-18x2") as c:
        path = np.linspace(0, 20_000, 11)[1:]
        with nothing_sent(c), pytest.raises(InvalidArgument, match="not one of the contour"):
            c.contour("A", path, dt=3, speed_limit={"B": 1000})
        with nothing_sent(c), pytest.raises(InvalidArgument, match="accel_limit: axis B"):
            c.contour("A", path, dt=3, accel_limit={"Y": 1e6})
