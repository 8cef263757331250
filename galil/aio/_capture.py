"""Capture and the watchdog, awaited: twins of :class:`~galil.capture.Capture` and
:class:`~galil.watchdog.Watchdog`.

::

    async with await dmc.capture(["_RPA", "_TPA"], seconds=1.0) as cap:
        move = await dmc.A.move_to(10 * mm)
        recording = await cap.wait()        # polled on a worker, the loop free meanwhile

    async with await dmc.watchdog(0.5):     # the controller stops the axes if we fall silent
        ...
"""

from __future__ import annotations

import asyncio
from types import TracebackType

from galil.aio._worker import Room, Worker, twin
from galil.capture import Capture, Recording
from galil.errors import GalilError, GalilTimeoutError, InvalidArgument
from galil.link import Link, check_wait_timeout
from galil.motion import MAX_POLL, MIN_POLL
from galil.watchdog import Watchdog

__all__ = ["AsyncCapture", "AsyncWatchdog"]


class _CapturePoll:
    """One wait's deadline and cadence; every call runs on a worker thread."""

    def __init__(self, capture: Capture, link: Link, started: float, timeout: float | None):
        self.capture = capture
        self.link = link
        self.ends = started + capture.duration
        self.limit = capture.duration * 1.5 + 2.0 if timeout is None else timeout
        self.deadline = started + self.limit  # as Capture.wait: from the start

    def __call__(self) -> float | None:
        """``None`` once every value is recorded (one ``_RC`` query), else the pause before
        the next poll.

        Raises:
            GalilTimeoutError: past the deadline (the recording goes on).
        """
        now = self.link.clock()
        if now < min(self.ends, self.deadline):  # a timeout may come before the last value
            return min(max(min(self.ends, self.deadline) - now, MIN_POLL), MAX_POLL)
        if self.capture.done:
            return None
        if now >= self.deadline:
            raise self.link.error(
                GalilTimeoutError, f"the capture still records after {self.limit:.3g} s"
            )
        every = self.capture.every * self.link.sample_period * 4
        return min(max(min(every, self.deadline - now), MIN_POLL), MAX_POLL)


class AsyncCapture(Room[Capture]):
    """A recording on the controller (``await controller.capture(...)``, started): awaited
    with :meth:`wait`, or stopped and uploaded with :meth:`stop` (or at the end of an
    ``async with`` block)."""

    def __init__(self, sync: Capture, worker: Worker, link: Link, started: float) -> None:
        super().__init__(sync, worker)
        self._link = link
        self._started = started

    @property
    def sources(self) -> tuple[str, ...]:
        """The operands recorded, in order."""
        return self.sync.sources

    @property
    def every(self) -> int:
        """Samples between values."""
        return self.sync.every

    @property
    def count(self) -> int:
        """Values recorded per source."""
        return self.sync.count

    @property
    def duration(self) -> float:
        """Seconds from the first value to the last."""
        return self.sync.duration

    @property
    def arrays(self) -> tuple[str, ...]:
        """The controller's arrays it records into (``gcap0`` ...), one per source."""
        return self.sync.arrays

    @property
    def start_sample(self) -> int | None:
        """The controller sample (``TIME``) of the first value."""
        return self.sync.start_sample

    @property
    def result(self) -> Recording | None:
        """The :class:`~galil.capture.Recording`, once uploaded."""
        return self.sync.result

    @property
    def stop_pending(self) -> bool:
        """Whether its stop could not be sent (a dead link): the controller stops it
        (``RC 0``) once the link works again; no I/O."""
        return self.sync.stop_pending

    async def done(self) -> bool:
        """Whether the recording is over (``_RC`` is 0); one query."""
        return await self._worker.run(_is_done, self.sync)

    async def wait(self, timeout: float | None = None) -> Recording:
        """Wait until every value is recorded, then upload them (``QU``); see
        :meth:`galil.capture.Capture.wait`. Polled on a worker (the loop is free between
        polls; on a manual-clock simulator each pause lets simulated time pass).

        Args:
            timeout: seconds from the start at most (default: the duration plus a margin).

        Raises:
            InvalidArgument: as the sync wait: ``timeout`` not ``None`` or a finite number
                >= 0 (:func:`~galil.link.check_wait_timeout`).
            GalilTimeoutError: still recording after ``timeout`` (it goes on; :meth:`stop`).
        """
        timeout = check_wait_timeout(timeout)
        if self.sync.result is not None:
            return self.sync.result
        worker, link = self._worker, self._link
        poll = _CapturePoll(self.sync, link, self._started, timeout)
        while (pause := await worker.run(poll)) is not None:
            if link.simulated_time:
                await worker.run(link.pause, pause)
            else:
                await asyncio.sleep(pause)
        return await worker.run(self.sync.wait)

    stop = twin(Capture.stop)

    async def __aenter__(self) -> AsyncCapture:
        return self

    async def __aexit__(self, kind: object, *exc: object) -> None:  # (Capture.__exit__'s)
        if self.sync.result is None and self.sync.start_sample is not None:
            try:
                await self._worker.run_shielded(self.sync.stop)
            except GalilError:
                if kind is None:
                    raise  # the block's own exception, if any, matters more

    def __repr__(self) -> str:
        return f"<AsyncCapture of {self.sync!r}>"


def _is_done(capture: Capture) -> bool:
    if capture.start_sample is None:
        raise InvalidArgument("start() the capture first")
    return capture.done


def _running(dog: Watchdog) -> bool:
    return dog.running


def _fired(dog: Watchdog) -> bool:
    return dog.fired


class AsyncWatchdog(Room[Watchdog]):
    """The controller-side dead-man switch (``await controller.watchdog(timeout)``); its
    heartbeat runs on a thread of the sync core, never on the loop."""

    @property
    def timeout(self) -> float:
        """Seconds of silence after which the controller stops the axes."""
        return self.sync.timeout

    @property
    def interval(self) -> float:
        """Seconds between heartbeats."""
        return self.sync.interval

    @property
    def thread(self) -> int:
        """The program thread the routine runs on."""
        return self.sync.thread

    @property
    def beating(self) -> bool:
        """Whether the host's heartbeat runs (no I/O)."""
        return self.sync.beating

    @property
    def halt_pending(self) -> bool:
        """Whether the routine still waits for a halt: stopped while the link was dead, it
        is halted when the link is reopened (no I/O)."""
        return self.sync.halt_pending

    stop = twin(Watchdog.stop)

    async def running(self) -> bool:
        """Whether the routine runs on the controller (``_XQn`` is not -1); one query."""
        return await self._worker.run(_running, self.sync)

    async def fired(self) -> bool:
        """Whether the routine stopped the axes for want of a heartbeat; one query."""
        return await self._worker.run(_fired, self.sync)

    async def __aenter__(self) -> AsyncWatchdog:
        return self

    async def __aexit__(  # (Watchdog.__exit__'s parameters)
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self._worker.run_shielded(self.sync.stop)

    def __repr__(self) -> str:
        return f"<AsyncWatchdog of {self.sync!r}>"
