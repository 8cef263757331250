"""Helpers shared by the axis tests (a module of its own: conftest is not importable)."""

from __future__ import annotations

import threading
import time

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


class RunningClock:
    """A simulator's real-time clock, sped up ``speed`` times, that counts only the time this
    process runs: a gap of more than :attr:`MAX_GAP` seconds between two readings counts as
    :attr:`MAX_GAP`.

    A served simulator's thread reads its clock at every tick (every 2 ms at most, its select
    timeout), so a longer gap is a pause of that thread, on a loaded machine of the whole
    process (the host's thread with it). A :class:`~galil.sim.clock.RealTimeClock` counts the
    pause as controller time: the simulator catches it up before it reads the bytes the host
    wrote before the pause, and a contour buffer (4 s of controller time at DT 3, 0.5 s of
    real time at 8x) ran dry although the host had kept it fed. What the host's own thread
    does late while the simulator runs is still counted.
    """

    MAX_GAP = 0.05

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self._lock = threading.Lock()
        self._last = time.monotonic()
        self._now = 0.0

    def now(self) -> float:
        """Simulated seconds since the clock was made, pauses of this process left out."""
        with self._lock:
            wall = time.monotonic()
            self._now += min(wall - self._last, self.MAX_GAP) * self.speed
            self._last = wall
            return self._now
