"""Long sync waits, awaited in slices so a cancelled awaiter frees its worker thread soon.

A sync wait (``programs.wait``, ``io.wait_for_input``) holds its thread until it returns or its
timeout passes. Awaited as one call, a cancelled task would leave a worker thread waiting for
as long as that timeout (for ever for ``timeout=None``). :func:`in_slices` calls the same sync
wait again and again with a timeout of at most :data:`WAIT_SLICE` seconds of controller time,
until it returns or the caller's own timeout has passed: each slice is the sync call, its
checks and its clean-up on a timeout, and a cancellation takes effect at the end of the slice
under way.

A wait that starts something on the controller keeps it between slices instead:
:func:`in_steps` awaits the steps of a wait taken in steps (:class:`galil.io.InputWatch`: its
routine installed and started once per wait, not once per slice) and, when cancelled, ends it
(the routine halted) once the step under way is over.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import math
from collections.abc import Callable
from typing import Any, TypeVar

from galil.aio._worker import Worker
from galil.errors import GalilConnectionError, GalilTimeoutError
from galil.link import Link

__all__ = ["WAIT_SLICE", "in_slices", "in_steps"]

#: Longest a sliced wait holds a worker thread in one call (seconds of controller time).
WAIT_SLICE = 0.5

R = TypeVar("R")


class _Deadline:
    """One sliced wait's deadline on the controller's clock; every call runs on a worker."""

    def __init__(self, link: Link, timeout: float | None, expired: str) -> None:
        self.link = link
        self.expired = expired
        self.deadline = None if timeout is None else link.clock() + timeout

    def slice(self, wait: Callable[[float], R]) -> tuple[R] | None:
        """One slice: ``(result,)`` when ``wait`` returned, ``None`` when the slice ran out
        with time left.

        Raises:
            GalilTimeoutError: the whole timeout has passed.
        """
        left = math.inf if self.deadline is None else self.deadline - self.link.clock()
        try:
            return (wait(max(0.0, min(WAIT_SLICE, left))),)
        except GalilTimeoutError:
            if left <= WAIT_SLICE:
                raise self.link.error(GalilTimeoutError, self.expired) from None
            return None


async def in_slices(
    worker: Worker, link: Link, wait: Callable[[float], R], timeout: float | None, expired: str
) -> R:
    """Await ``wait(seconds)``, a sync wait that raises :class:`GalilTimeoutError` once
    ``seconds`` pass, in slices of at most :data:`WAIT_SLICE` s until it returns.

    Args:
        worker: runs each slice.
        link: the controller's clock.
        wait: the sync wait, given the slice's timeout.
        timeout: seconds in all (``None``: for ever), checked by the caller first, as its
            sync twin checks it (:func:`~galil.link.check_wait_timeout`).
        expired: the message of the :class:`GalilTimeoutError` once ``timeout`` has passed.

    Raises:
        GalilTimeoutError: ``timeout`` passed.
    """
    deadline = await worker.run(_Deadline, link, timeout, expired)
    while (done := await worker.run(deadline.slice, wait)) is None:
        pass
    return done[0]


async def in_steps(
    worker: Worker, step: Callable[[float], bool], end: Callable[[], object]
) -> None:
    """Await a sync wait taken in steps (:class:`galil.io.InputWatch`) that keeps what it
    started between them: ``step(WAIT_SLICE)`` on a worker until it returns ``True``.

    A step that raises has ended the wait itself. Cancelled (or cut short on the loop),
    ``end()`` runs on the stops' lane once the step under way is over, or at once when it
    had not started (it never does then): what the earlier steps started is undone.

    Raises:
        Whatever ``step`` raises (its timeout, a dead link).
    """
    while True:
        future = worker.submit(step, WAIT_SLICE)
        try:
            if await asyncio.wrap_future(future):
                return
        except BaseException:
            future.add_done_callback(functools.partial(_then, worker, end))
            raise


def _then(worker: Worker, end: Callable[[], object], step: concurrent.futures.Future[Any]) -> None:
    if not step.cancelled() and step.exception() is not None:
        return  # the step raised: it ended the wait itself
    with contextlib.suppress(GalilConnectionError):  # closed: close() halted the routine
        worker.submit_urgent(end)
