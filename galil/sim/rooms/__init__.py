"""The rooms of the simulated controller: one module per topic, each with its own state.

A room registers its commands and operands with :func:`~galil.sim.registry.handler` and
:func:`~galil.sim.registry.operand` and hooks into the servo loop by overriding the
:class:`~galil.sim.machine.Room` hooks. :data:`ROOMS` is the default set; a controller can be
built with more (``SimController(rooms=(*ROOMS, Homing))``) without touching the core.
"""

from __future__ import annotations

from galil.sim.machine import Room
from galil.sim.rooms.arrays import Arrays
from galil.sim.rooms.automatic import Automatic
from galil.sim.rooms.capture import Capture
from galil.sim.rooms.contour import Contour
from galil.sim.rooms.gearing import Gearing
from galil.sim.rooms.handles import Handles
from galil.sim.rooms.homing import Homing
from galil.sim.rooms.interrupts import Interrupts
from galil.sim.rooms.io import IO
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.motion import Motion
from galil.sim.rooms.programs import ProgramCommands
from galil.sim.rooms.records import Records
from galil.sim.rooms.reports import Reports
from galil.sim.rooms.settings import Settings
from galil.sim.rooms.trippoints import Trippoints
from galil.sim.rooms.tuning import Tuning
from galil.sim.rooms.vector import Vector

__all__ = [
    "IO",
    "ROOMS",
    "Arrays",
    "Automatic",
    "Capture",
    "Contour",
    "Gearing",
    "Handles",
    "Homing",
    "Interrupts",
    "Limits",
    "Motion",
    "ProgramCommands",
    "Records",
    "Reports",
    "Settings",
    "Trippoints",
    "Tuning",
    "Vector",
    "rooms_with",
]

#: The default rooms, in the order their hooks run. Records come first: a record due at a
#: sample shows the state before that sample's limit checks and contour bookkeeping.
ROOMS: tuple[type[Room], ...] = (
    Records,
    Limits,
    Contour,
    Vector,
    Gearing,
    Motion,
    Trippoints,
    Reports,
    Settings,
    Handles,
    ProgramCommands,
    Tuning,
    Homing,
    IO,
    Arrays,
    Capture,
    Interrupts,
    Automatic,
)


def rooms_with(*rooms: type[Room]) -> tuple[type[Room], ...]:
    """The default rooms with ``rooms`` added; one that subclasses a default room replaces it.

    >>> class Quiet(Reports): ...
    >>> rooms_with(Quiet)[ROOMS.index(Reports)] is Quiet
    True
    """
    out = list(ROOMS)
    for room in rooms:
        at = [i for i, r in enumerate(out) if issubclass(room, r)]
        if at:
            out[at[0]] = room
        else:
            out.append(room)
    return tuple(out)
