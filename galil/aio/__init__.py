"""asyncio for galil: the same controller, axes and moves, awaited.

``await galil.aio.connect(address)`` returns an :class:`AsyncController` whose vocabulary is
the sync :class:`galil.Controller`'s::

    async with await galil.aio.connect("tcp://192.168.0.2") as dmc:
        x = dmc.A.set_scale(2000 / ureg.mm)
        move = await x.move_to(12.5 * ureg.mm)     # sent; returns an AsyncMoveHandle
        print(move.duration)                        # the prediction, already known
        result = await move                         # done, compared with the prediction

The sync core is thread-safe and does its I/O in the calling thread, so each controller gets
a few worker threads and the event loop only awaits futures: one copy of the protocol, the
predictions and the checks, and no call that blocks the loop (``docs/decisions/0012``).
Cancelling a task that awaits a move (a homing, a sequence, a contour) stops the axes.

The rooms are there too: ``await dmc.io.inputs[3]``, ``await dmc.programs.run("#A")``,
``await dmc.arrays.upload("sq")``, ``await dmc.variables["gain"]``, ``async for i in
dmc.interrupts``, ``await dmc.capture([...])``, ``await dmc.watchdog(0.5)``, ``await
dmc.vector_move("AB", [Line(...), Arc(...)], speed=...)``, ``await dmc.A.home()``,
``await dmc.A.kp()``. A sync property that reads the controller becomes a method, its
setter a ``set_`` method (``await x.set_speed(v)``); an item assignment a ``set`` call
(``await dmc.io.outputs.set(2, True)``). Assigning a public name of an async object (the sync
idiom ``x.speed = v``) raises :class:`~galil.errors.GalilAttributeError` naming the ``set_``
method, and sets nothing (decision 0091).

No event loop is bound at connect: messages, interrupts and record streams are delivered to
the loop that reads them, and ``subscribe`` calls back on the loop that subscribed, so a
controller connected in one ``asyncio.run`` may be used in the next.
"""

from __future__ import annotations

from galil.aio._axis import AsyncAxis, AsyncGearing
from galil.aio._capture import AsyncCapture, AsyncWatchdog
from galil.aio._controller import AsyncController, connect
from galil.aio._interrupts import AsyncInterrupts
from galil.aio._io import (
    AsyncAnalogInputs,
    AsyncAnalogOutputs,
    AsyncDigitalInputs,
    AsyncDigitalOutputs,
    AsyncIO,
)
from galil.aio._motion import (
    AsyncMoveHandle,
    AsyncVectorHandle,
    MoveProgress,
    MoveWait,
    motion_twin,
)
from galil.aio._programs import AsyncArrays, AsyncPrograms, AsyncVariables
from galil.aio._streams import AsyncMessages, AsyncRecordStream, LoopQueue
from galil.aio._waits import WAIT_SLICE
from galil.aio._worker import Backed, Room, Worker, same, twin
from galil.aio.probe import LoopWatch, watch_loop

__all__ = [
    "WAIT_SLICE",
    "AsyncAnalogInputs",
    "AsyncAnalogOutputs",
    "AsyncArrays",
    "AsyncAxis",
    "AsyncCapture",
    "AsyncController",
    "AsyncDigitalInputs",
    "AsyncDigitalOutputs",
    "AsyncGearing",
    "AsyncIO",
    "AsyncInterrupts",
    "AsyncMessages",
    "AsyncMoveHandle",
    "AsyncPrograms",
    "AsyncRecordStream",
    "AsyncVariables",
    "AsyncVectorHandle",
    "AsyncWatchdog",
    "Backed",
    "LoopQueue",
    "LoopWatch",
    "MoveProgress",
    "MoveWait",
    "Room",
    "Worker",
    "connect",
    "motion_twin",
    "same",
    "twin",
    "watch_loop",
]
