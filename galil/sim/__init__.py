"""The simulated DMC controller: an interpreter, a servo loop on the shared motion engine, and
fronts (in-process link ``sim://``, TCP server, pty).

>>> from galil.sim import SimController
>>> sim = SimController("DMC-4040")
>>> sim.feed(b"PR 1000;BG A\\r")
b'::'
"""

from __future__ import annotations

from galil.sim.clock import Clock, ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.faults import FaultPlan

__all__ = ["Clock", "FaultPlan", "ManualClock", "RealTimeClock", "SimController"]
