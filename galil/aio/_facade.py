"""What the async controller passes on to the link: commands, queries, time, messages and
data records (the twin of :class:`galil.facade.LinkFacade`; no logic of its own)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from galil.aio._motion import MotionRoom
from galil.aio._streams import AsyncMessages, AsyncRecordStream
from galil.aio._worker import Worker, twin
from galil.controller import Controller
from galil.errors import InvalidArgument
from galil.facade import check_sleep
from galil.link import WireLog
from galil.models import Identity, ModelSpec
from galil.transport import Transport

__all__ = ["AsyncLinkFacade"]


def _close_stream(stream: Any) -> None:
    stream.close()


class AsyncLinkFacade(MotionRoom[Controller]):
    """Commands, queries, time, messages and records of one controller (see
    ``AsyncController``)."""

    def __init__(
        self,
        sync: Controller,
        worker: Worker,
        messages: AsyncMessages,
    ) -> None:
        super().__init__(sync, worker, sync.link, sync.tracker)
        self._messages = messages

    # -- what needs no I/O --------------------------------------------------------------------
    @property
    def model(self) -> ModelSpec:
        """The controller's :class:`~galil.models.ModelSpec`."""
        return self.sync.model

    @property
    def identity(self) -> Identity | None:
        """The parsed ``^R^V`` reply."""
        return self.sync.identity

    @property
    def echo(self) -> bool:
        """Whether the controller echoes (found at the handshake and kept)."""
        return self.sync.echo

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample."""
        return self.sync.sample_period

    @property
    def transport(self) -> Transport:
        """The open :class:`~galil.transport.Transport`."""
        return self.sync.transport

    @property
    def timeout(self) -> float:
        """Default seconds to wait for each reply (settable; no I/O)."""
        return self.sync.timeout

    @timeout.setter
    def timeout(self, seconds: float) -> None:
        self.sync.timeout = seconds

    @property
    def wire_log(self) -> WireLog:
        """Hooks on the raw bytes of the command link (called on the worker threads)."""
        return self.sync.wire_log

    @property
    def bytes_sent(self) -> int:
        """Bytes written to the command link."""
        return self.sync.bytes_sent

    @property
    def bytes_received(self) -> int:
        """Bytes read from the command link."""
        return self.sync.bytes_received

    @property
    def recent(self) -> tuple[str, ...]:
        """The last exchanges on the link, oldest first (what errors carry)."""
        return self.sync.recent

    # -- the link -----------------------------------------------------------------------------
    command = twin(Controller.command)
    command_line = twin(Controller.command_line)
    send = twin(Controller.send)
    exchange = twin(Controller.exchange)
    send_many = twin(Controller.send_many)
    query_number = twin(Controller.query_number)
    query_numbers = twin(Controller.query_numbers)
    query_operands = twin(Controller.query_operands)

    async def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller: simulated time on a manual-clock
        simulator, ``asyncio.sleep`` otherwise (the loop stays free)."""
        seconds = check_sleep(seconds)
        if self.sync.link.simulated_time:
            await self._worker.run(self.sync.sleep, seconds)
        else:
            await asyncio.sleep(seconds)

    # -- unsolicited output and records -----------------------------------------------------
    @property
    def messages(self) -> AsyncMessages:
        """Unsolicited lines as an async iterator (``async for line in c.messages``)."""
        return self._messages

    async def subscribe(self, callback: Callable[[str], None]) -> Callable[[], None]:
        """Call ``callback(line)`` on this event loop (the one awaiting ``subscribe``) for
        each unsolicited line; returns a function that unsubscribes."""
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        loop = asyncio.get_running_loop()

        def deliver(line: str) -> None:
            if not loop.is_closed():
                loop.call_soon_threadsafe(callback, line)

        return await self._worker.run(self.sync.subscribe, deliver)

    record = twin(Controller.record)

    async def records(
        self,
        period: int | None = None,
        *,
        seconds: object = None,
        method: str = "auto",
        maxlen: int = 10_000,
    ) -> AsyncRecordStream:
        """Stream data records every ``period`` servo samples (or every ``seconds``); see
        ``Controller.records``. Close the stream (or use ``async with``) to stop it."""
        stream = await self._worker.run_or_undo(
            _close_stream, self.sync.records, period, seconds=seconds, method=method, maxlen=maxlen
        )
        return AsyncRecordStream(stream, self._worker)
