"""Clocks that drive the simulator's servo loop.

The simulator never reads the wall clock itself: it asks its clock what time it is and runs the
servo samples that fit. Tests use :class:`ManualClock` and move time explicitly, so nothing ever
sleeps waiting for motion; servers use :class:`RealTimeClock`.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol, runtime_checkable

from galil.errors import InvalidArgument

__all__ = ["Clock", "ManualClock", "RealTimeClock"]


@runtime_checkable
class Clock(Protocol):
    """Anything that tells the simulator the present time in seconds."""

    def now(self) -> float:
        """Return seconds since an arbitrary, fixed origin (monotonic)."""
        ...


class ManualClock:
    """A clock that only moves when told to.

    Attributes:
        manual: always ``True``; lets the simulator tell it may advance this clock itself.
    """

    manual = True

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        """Return the present (simulated) time in seconds."""
        with self._lock:
            return self._now

    def advance(self, seconds: float) -> float:
        """Move time forward by ``seconds`` (>= 0) and return the new time.

        Raises:
            InvalidArgument: ``seconds`` is negative or not finite.
        """
        if not (seconds >= 0.0) or seconds == float("inf"):
            raise InvalidArgument(f"a clock only moves forward by a finite amount, not {seconds!r}")
        with self._lock:
            self._now += float(seconds)
            return self._now

    def __repr__(self) -> str:
        return f"ManualClock(now={self._now:.6f})"


class RealTimeClock:
    """Wall-clock time (``time.monotonic``), optionally sped up.

    Args:
        speed: simulated seconds per real second (1.0 is real time).
    """

    manual = False

    def __init__(self, speed: float = 1.0) -> None:
        if not (speed > 0.0) or speed == float("inf"):
            raise InvalidArgument(f"clock speed must be a positive finite number, not {speed!r}")
        self.speed = float(speed)
        self._origin = time.monotonic()

    def now(self) -> float:
        """Return simulated seconds since this clock was created."""
        return (time.monotonic() - self._origin) * self.speed

    def __repr__(self) -> str:
        return f"RealTimeClock(speed={self.speed})"
