"""Long sync waits, awaited in slices so a cancelled awaiter frees its worker thread soon.

A sync wait (``programs.wait``, ``io.wait_for_input``) holds its thread until it returns or its
timeout passes. Awaited as one call, a cancelled task would leave a worker thread waiting for
as long as that timeout (for ever for ``timeout=None``). :func:`in_slices` calls the same sync
wait again and again with a timeout of at most :data:`WAIT_SLICE` seconds of controller time,
until it returns or the caller's own timeout has passed: each slice is the sync call, its
checks and its clean-up on a timeout (a routine halted), and a cancellation takes effect at
the end of the slice under way.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

from galil.aio._worker import Worker
from galil.errors import GalilTimeoutError
from galil.link import Link

__all__ = ["WAIT_SLICE", "in_slices"]

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
