"""Interrupts, awaited: the twin of ``controller.interrupts`` (:mod:`galil.interrupts`).

The sync room's reader thread hands every interrupt to the loop that reads it
(``call_soon_threadsafe``; any loop, decision 0091): no thread waits for them, and they come
as an async iterator::

    await dmc.interrupts.enable(axes="A")
    async for interrupt in dmc.interrupts:    # "UI 3", "axis A done" ...
        ...
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from galil.aio._streams import LoopQueue
from galil.aio._worker import Room, Worker, twin
from galil.errors import InvalidArgument
from galil.interrupts import Interrupts
from galil.protocol.interrupts import Interrupt

__all__ = ["AsyncInterrupts"]


class AsyncInterrupts(Room[Interrupts]):
    """``UI``/``EI`` interrupts of one controller, for coroutines.

    Every interrupt received since connect waits in :attr:`queue` (bounded: the oldest drop)
    until read with ``await interrupts.get(timeout)`` or ``async for``; subscribers are
    called on the loop.
    """

    def __init__(
        self,
        sync: Interrupts,
        worker: Worker,
        queue: LoopQueue[Interrupt],
    ) -> None:
        super().__init__(sync, worker)
        self._queue = queue

    @property
    def queue(self) -> LoopQueue[Interrupt]:
        """The interrupts received and not yet read, oldest first."""
        return self._queue

    enable = twin(Interrupts.enable)
    disable = twin(Interrupts.disable)

    @property
    def enabled(self) -> bool:
        """Whether interrupts come (``enable`` was called and not undone)."""
        return self.sync.enabled

    @property
    def mask(self) -> int | None:
        """The ``EI`` mask sent last (``None`` while not enabled)."""
        return self.sync.mask

    async def get(self, timeout: float | None = None) -> Interrupt:
        """The oldest interrupt, waiting up to ``timeout`` seconds (``None``: for ever).

        Raises:
            QueueTimeoutError: none arrived in time (a ``GalilTimeoutError`` that is also a
                ``queue.Empty``).
            GalilConnectionError: the controller was closed.
        """
        return await self.queue.get(timeout)

    async def subscribe(self, callback: Callable[[Interrupt], None]) -> Callable[[], None]:
        """Call ``callback(interrupt)`` on this event loop (the one awaiting ``subscribe``)
        for each interrupt; returns a function that unsubscribes. Interrupts arrive only once
        :meth:`enable` was called."""
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        loop = asyncio.get_running_loop()

        def deliver(interrupt: Interrupt) -> None:
            if not loop.is_closed():
                loop.call_soon_threadsafe(callback, interrupt)

        return await self._worker.run(self.sync.subscribe, deliver)

    def __aiter__(self) -> LoopQueue[Interrupt]:
        return self.queue

    def __repr__(self) -> str:
        return f"<AsyncInterrupts of {self.sync!r}, {self.queue!r}>"
