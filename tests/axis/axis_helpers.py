"""Helpers shared by the axis tests (a module of its own: conftest is not importable)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

import galil
from galil.predict import Profile
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def in_unit(q: object, unit: str) -> float:
    """The magnitude of Quantity ``q`` in ``unit``."""
    return float(q.to(unit).magnitude)  # type: ignore[attr-defined]


def scale_in_mm(controller: galil.Controller, letters: str = "AB") -> None:
    """Axes ``letters`` in millimetres (2000 counts/mm), 20 mm/s, 200 mm/s² both ways."""
    for letter in letters:
        axis = controller.axes[letter].set_scale(counts_per=2000 / mm)
        axis.speed = 20 * mm / s
        axis.accel = axis.decel = 200 * mm / s**2


def recorded(trace: npt.NDArray[np.int64], trace_start: int, begin: int, n: int) -> np.ndarray:
    """The ``n`` recorded reference positions from controller sample ``begin`` on."""
    offset = begin - trace_start
    assert offset >= 0, "the trace starts after the motion began"
    out = trace[offset : offset + n]
    assert out.size == n, f"the trace holds {out.size} of the {n} predicted samples"
    return out


def assert_follows(
    trace: npt.NDArray[np.int64], trace_start: int, profile: Profile, begin: int | None
) -> None:
    """The servo loop's reference equals the prediction, sample for sample."""
    assert begin is not None
    got = recorded(trace, trace_start, begin, profile.position.size)
    np.testing.assert_array_equal(got, profile.position)
