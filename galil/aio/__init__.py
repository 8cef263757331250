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
Cancelling a task that awaits a move (or a contour) stops the axes.
"""

from __future__ import annotations

from galil.aio._controller import AsyncAxis, AsyncController, connect
from galil.aio._motion import AsyncMoveHandle, MoveProgress, motion_twin
from galil.aio._streams import AsyncMessages, AsyncRecordStream
from galil.aio._worker import Room, Worker, twin
from galil.aio.probe import LoopWatch, watch_loop

__all__ = [
    "AsyncAxis",
    "AsyncController",
    "AsyncMessages",
    "AsyncMoveHandle",
    "AsyncRecordStream",
    "LoopWatch",
    "MoveProgress",
    "Room",
    "Worker",
    "connect",
    "motion_twin",
    "twin",
    "watch_loop",
]
