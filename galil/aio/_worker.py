"""Where the blocking calls run: a few threads per controller, and twins of sync methods.

The sync core (:mod:`galil.controller` and the rooms below it) is thread-safe and does its
I/O in the calling thread. The async layer never calls it on the event loop: every call goes
to the controller's :class:`Worker` and the loop only awaits a future (``docs/decisions/0012``).

A method of a sync room gets its async twin in one line, without a copy of its logic or its
signature::

    class AsyncThing(Room[Thing]):
        read = twin(Thing.read)          # await async_thing.read(...) runs Thing.read(...)

:func:`twin` keeps the sync method's parameters (mypy checks the calls) and docstring;
:class:`same` passes a method that does no I/O (a conversion, a prediction already made)
straight through, called on the loop as it is.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import queue
import threading
from collections.abc import Awaitable, Callable
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar, overload

from galil.errors import FixedAttributes, GalilConnectionError, InvalidArgument

__all__ = ["Backed", "Room", "Worker", "same", "shielded", "twin"]

P = ParamSpec("P")
R = TypeVar("R")
S = TypeVar("S")
S_co = TypeVar("S_co", covariant=True)

_Job = tuple["concurrent.futures.Future[Any]", Callable[[], Any]]


async def shielded(future: concurrent.futures.Future[R]) -> R:
    """Await a worker's future; cancelling the awaiting task leaves the call running, and
    its outcome (an exception too) is then dropped quietly instead of logged as unretrieved.
    """
    inner = asyncio.wrap_future(future)
    try:
        return await asyncio.shield(inner)
    except asyncio.CancelledError:
        inner.add_done_callback(_retrieve)
        raise


def _nothing() -> None:
    pass


def _retrieve(future: asyncio.Future[Any]) -> None:
    if not future.cancelled():
        future.exception()


class Worker:
    """Threads that run one controller's blocking calls, started once and reused.

    The threads start at construction (a thread start is the one thing here that takes the
    loop's time, so it happens at connect, not in the middle of a scan). Several threads let
    a call through while another (a contour, a polled record) is still running; the link's
    own lock keeps their round trips apart. Stops have a lane of their own (one more thread,
    :meth:`run_urgent`): with every other thread busy (waits for inputs, record reads, each
    holding its thread for up to half a second), a stop does not queue behind them.

    Args:
        name: names the threads (``galil-aio-<name>-<i>``).
        threads: how many calls may run at once.
    """

    def __init__(self, name: str, threads: int = 3) -> None:
        self._jobs: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._urgent: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._closed = False
        self._threads = [
            threading.Thread(
                target=self._serve, args=(self._jobs,), name=f"galil-aio-{name}-{i}", daemon=True
            )
            for i in range(threads)
        ]
        self._threads.append(
            threading.Thread(
                target=self._serve, args=(self._urgent,), name=f"galil-aio-{name}-stop", daemon=True
            )
        )
        for t in self._threads:
            t.start()

    def _serve(self, jobs: queue.SimpleQueue[_Job | None]) -> None:
        while True:
            job = jobs.get()
            if job is None:
                return
            future, call = job
            if not future.set_running_or_notify_cancel():
                continue  # cancelled before it started: it never runs
            try:
                result = call()
            except BaseException as exc:  # handed to whoever awaits it
                future.set_exception(exc)
            else:
                future.set_result(result)
                del result  # (a thread keeps nothing of the last call: not its controller)
            del future, call, job

    def submit(
        self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs
    ) -> concurrent.futures.Future[R]:
        """Queue ``fn(*args, **kwargs)`` for a worker thread; never blocks.

        Raises:
            GalilConnectionError: the worker was closed.
        """
        return self._queue(self._jobs, functools.partial(fn, *args, **kwargs))

    def submit_urgent(
        self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs
    ) -> concurrent.futures.Future[R]:
        """:meth:`submit` on the stops' own lane (a stop, the undoing of a cancelled start):
        it runs as soon as the calls before it on that lane are done, whatever the other
        threads run."""
        return self._queue(self._urgent, functools.partial(fn, *args, **kwargs))

    def _queue(
        self, jobs: queue.SimpleQueue[_Job | None], call: Callable[[], R]
    ) -> concurrent.futures.Future[R]:
        if self._closed:
            raise GalilConnectionError(
                "the async controller is closed (aclose(), or the end of its async with "
                "block); galil.aio.connect() opens a new one"
            )
        future: concurrent.futures.Future[R] = concurrent.futures.Future()
        jobs.put((future, call))
        return future

    async def run(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """Run ``fn(*args, **kwargs)`` on a worker thread and await its result.

        Cancelling the awaiting task drops a call that has not started yet; one already
        running finishes on its thread (callers that start motion stop it, see
        :func:`galil.aio._motion.start_motion`).
        """
        return await asyncio.wrap_future(self.submit(fn, *args, **kwargs))

    async def run_shielded(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """Like :meth:`run`, but the call completes even if the awaiting task is cancelled."""
        return await shielded(self.submit(fn, *args, **kwargs))

    async def run_urgent(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """:meth:`run_shielded` on the stops' own lane (:meth:`submit_urgent`)."""
        return await shielded(self.submit_urgent(fn, *args, **kwargs))

    async def run_or_undo(
        self,
        undo: Callable[[R], object],
        fn: Callable[P, R],
        /,
        *args: P.args,
        **kwargs: P.kwargs,
    ) -> R:
        """Run a call that leaves something behind (motion, a connection); if the awaiting
        task is cancelled while it runs, ``undo(result)`` runs on a worker as soon as it
        returns. A call that had not started never runs."""
        future = self.submit(fn, *args, **kwargs)
        try:
            return await shielded(future)
        except asyncio.CancelledError:
            if not future.cancel():
                future.add_done_callback(functools.partial(self._undo, undo))
            raise

    def _undo(self, undo: Callable[[R], object], future: concurrent.futures.Future[R]) -> None:
        if future.cancelled() or future.exception() is not None:
            return  # nothing was left behind
        with contextlib.suppress(GalilConnectionError):
            self.submit(undo, future.result())

    async def drained(self) -> None:
        """Return once every call submitted before is over: each thread of the calls' lane
        takes a barrier call (none is busy with anything else then), and then the stops' lane
        a call of its own, so a stop that a call ending submitted (a cancelled wait's end) is
        over too (for tests that look at the wire once a cancellation has settled)."""
        lane = len(self._threads) - 1
        barrier = threading.Barrier(lane)
        await asyncio.gather(*(self.run(barrier.wait, 10) for _ in range(lane)))
        await self.run_urgent(_nothing)

    @property
    def threads(self) -> list[threading.Thread]:
        """The worker threads (for tests that check nothing outlives a controller)."""
        return list(self._threads)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def close(self) -> None:
        """Let the threads finish what they run and end; idempotent, never blocks."""
        if self._closed:
            return
        self._closed = True
        for _ in self._threads[:-1]:
            self._jobs.put(None)
        self._urgent.put(None)


class Backed(FixedAttributes, Generic[S_co]):
    """An async twin of one sync object: the object and the worker its calls run on.

    Covariant: a twin of a base class's method (``LinkFacade.command``) serves a room of a
    subclass (``Controller``). Its settings are awaited ``set_`` methods: assigning any of
    its public names (``x.soft_limits = ...``, the sync idiom) raises
    :class:`~galil.errors.GalilAttributeError` naming the ``set_`` method, and nothing is set
    (decision 0091).

    Attributes:
        sync: the sync object (its cheap, I/O-free members may be used directly).
    """

    _awaited = True

    def __init__(self, sync: S_co, worker: Worker) -> None:
        self._sync = sync
        self._worker = worker

    @property
    def sync(self) -> S_co:
        """The sync object (its cheap, I/O-free members may be used directly)."""
        return self._sync


class Room(Backed[S_co]):
    """A twin that also runs any blocking callable on its controller's worker (:meth:`run`),
    for what has no twin. (A twin whose sync object has a ``run`` of its own, such as
    ``programs.run``, is a :class:`Backed` only.)"""

    async def run(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """Run any blocking callable on this controller's worker (a room without a twin).

        Raises:
            InvalidArgument: ``fn`` cannot be called (refused here, not on the worker).
        """
        if not callable(fn):
            raise InvalidArgument(f"fn must be callable, not {fn!r:.60}")
        return await self._worker.run(fn, *args, **kwargs)


class twin(Generic[S, P, R]):  # noqa: N801 - used like a decorator
    """The async twin of a sync method: ``await room.name(...)`` runs ``S.name(room.sync, ...)``
    on the room's worker. Parameters, return type and docstring are the sync method's.

    ``shield=True`` for a call that must happen once asked for: cancelling the awaiting task,
    even before the call has started, leaves it to run (``run_shielded``). ``urgent=True``
    for a stop: shielded, and on the stops' own lane (``run_urgent``).
    """

    def __init__(
        self,
        method: Callable[Concatenate[S, P], R],
        *,
        shield: bool = False,
        urgent: bool = False,
    ) -> None:
        self._method = method
        self._shield = shield
        self._urgent = urgent
        self.__doc__ = method.__doc__
        self.__name__ = getattr(method, "__name__", "twin")

    @overload
    def __get__(self, room: None, owner: type[object]) -> twin[S, P, R]: ...

    @overload
    def __get__(self, room: Backed[S], owner: type[object]) -> Callable[P, Awaitable[R]]: ...

    def __get__(
        self, room: Backed[S] | None, owner: type[object]
    ) -> twin[S, P, R] | Callable[P, Awaitable[R]]:
        if room is None:
            return self
        method = self._method
        sync = room.sync
        worker = room._worker
        run = (
            worker.run_urgent
            if self._urgent
            else worker.run_shielded
            if self._shield
            else worker.run
        )

        async def call(*args: P.args, **kwargs: P.kwargs) -> R:
            return await run(method, sync, *args, **kwargs)

        call.__doc__ = method.__doc__
        call.__name__ = self.__name__
        # (what "coroutine ... was never awaited" and tracebacks name: AsyncAxis.stop, not
        # twin.__get__.<locals>.call)
        call.__qualname__ = f"{type(room).__name__}.{self.__name__}"
        return call


class same(Generic[S, P, R]):  # noqa: N801 - used like a decorator
    """A sync method that does no I/O (a unit conversion, reading a prediction already made),
    called as it is: ``room.name(...)`` is ``S.name(room.sync, ...)``, on the caller's thread.
    Parameters, return type and docstring are the sync method's.
    """

    def __init__(self, method: Callable[Concatenate[S, P], R]) -> None:
        self._method = method
        self.__doc__ = method.__doc__
        self.__name__ = getattr(method, "__name__", "same")

    @overload
    def __get__(self, room: None, owner: type[object]) -> same[S, P, R]: ...

    @overload
    def __get__(self, room: Backed[S], owner: type[object]) -> Callable[P, R]: ...

    def __get__(
        self, room: Backed[S] | None, owner: type[object]
    ) -> same[S, P, R] | Callable[P, R]:
        if room is None:
            return self
        method = self._method
        sync = room.sync

        def call(*args: P.args, **kwargs: P.kwargs) -> R:
            return method(sync, *args, **kwargs)

        call.__doc__ = method.__doc__
        call.__name__ = self.__name__
        # (what "coroutine ... was never awaited" and tracebacks name: AsyncAxis.stop, not
        # twin.__get__.<locals>.call)
        call.__qualname__ = f"{type(room).__name__}.{self.__name__}"
        return call
