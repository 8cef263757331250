"""Motion from a coroutine: awaitable handles over the sync :class:`~galil.motion.MoveHandle`.

The sync handle keeps the prediction, the changes sent since the start and the comparison at
the end; here it is only polled, from a worker thread, at the sync handle's own cadence (a
quarter of the predicted time left, between :data:`~galil.motion.MIN_POLL` and
:data:`~galil.motion.MAX_POLL`), with the loop free between polls.

Cancelling a task that awaits a move stops the move (``ST``, sent before the cancellation
completes), and cancelling a task while its move is being started stops the move as soon as
it has started: a cancelled coroutine never leaves an axis running. A start cancelled while it
runs has its motion refused from then on (:class:`Starting`): a streamed path or a contour
whose motion had not registered yet is stopped as it registers, not once it has run
(decision 0027).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import threading
import warnings
import weakref
from collections.abc import AsyncGenerator, Awaitable, Callable, Coroutine, Generator
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Concatenate, Generic, NoReturn, ParamSpec, TypeVar, overload

from galil import predict
from galil.aio._worker import Room, Worker
from galil.errors import FixedAttributes, GalilError, GalilTimeoutError
from galil.link import Link, check_callable, check_flag, check_wait_timeout
from galil.motion import (
    MAX_POLL,
    MIN_POLL,
    MotionTracker,
    MoveHandle,
    MoveParams,
    MoveResult,
    WaitBar,
    held,
    not_done_text,
    wait_guard,
)
from galil.predict.profile import shown_position
from galil.segments import VectorPlan
from galil.vector import VectorHandle

__all__ = [
    "AsyncMoveHandle",
    "AsyncVectorHandle",
    "MotionRoom",
    "MoveProgress",
    "MoveWait",
    "Starting",
    "motion_twin",
    "settle_abandoned",
    "start_motion",
]

_LOG = logging.getLogger("galil.aio")

P = ParamSpec("P")
S = TypeVar("S")
S_co = TypeVar("S_co", covariant=True)
R = TypeVar("R")
H = TypeVar("H")
M = TypeVar("M", bound=MoveHandle)


@dataclass(frozen=True)
class MoveProgress:
    """Where a move is, by its prediction (no position query).

    Attributes:
        elapsed: seconds since the move started, on the controller's clock.
        duration: predicted duration in seconds (``inf`` for a jog not yet stopped).
        positions: predicted position per axis at ``elapsed``, in the axis's unit (counts
            without a scale); empty while the end of a jog is unknown.
        units: the unit of each position (``"mm"``, ``"counts"``).
    """

    elapsed: float
    duration: float
    positions: dict[str, float]
    units: dict[str, str]

    @property
    def remaining(self) -> float:
        """Predicted seconds left (0 once over; ``inf`` for a running jog)."""
        return max(0.0, self.duration - self.elapsed)

    @property
    def fraction(self) -> float | None:
        """Share of the predicted duration gone by (``None`` for a running jog)."""
        if not math.isfinite(self.duration):
            return None
        if self.duration <= 0:
            return 1.0
        return min(1.0, self.elapsed / self.duration)


def shown(profile: predict.Profile, counts: float) -> float:
    """A position in counts in the unit a profile is shown in (its axis's user unit)."""
    return float(shown_position(profile.display, counts))


def _unit(profile: predict.Profile) -> str:
    return profile.display[2] if profile.display is not None else "counts"


def progress_of(handle: MoveHandle, now: float) -> MoveProgress:
    """The predicted state of ``handle`` at controller time ``now`` (worker side)."""
    elapsed = max(0.0, now - handle.started_at)
    duration = handle.duration
    profiles = handle.profiles
    units = {a: _unit(p) for a, p in profiles.items()}
    positions: dict[str, float] = {}
    if math.isfinite(duration):
        positions = {a: shown(p, float(p.at(elapsed))) for a, p in profiles.items()}
    return MoveProgress(elapsed, duration, positions, units)


class _Poll:
    """One wait's deadline and cadence; every call runs on a worker thread.

    ``guarded``: a poll or a pause that fails (a dead link, no reply) stops the move before
    the error goes on, as ``MoveHandle.wait`` does (:func:`~galil.motion.wait_guard`)."""

    def __init__(
        self, handle: MoveHandle, link: Link, timeout: float | None, guarded: bool
    ) -> None:
        self.handle = handle
        self.link = link
        self.guard: Callable[[], contextlib.AbstractContextManager[None]] = (
            functools.partial(wait_guard, handle) if guarded else contextlib.nullcontext
        )
        with self.guard():  # (a stream's prediction is computed here, lazily: guarded)
            duration = handle.duration
        if timeout is None and math.isfinite(duration):
            timeout = duration * 1.5 + 2.0  # as MoveHandle.wait
        self.timeout = timeout
        self.deadline = None if timeout is None else link.clock() + timeout

    def __call__(self) -> tuple[MoveProgress, float] | None:
        """``None`` once done, else the progress and the pause before the next poll.

        Raises:
            GalilTimeoutError: past the deadline (the move is NOT stopped).
        """
        handle, link = self.handle, self.link
        with self.guard():
            if handle.done:
                return None
        now = link.clock()
        if self.deadline is not None and now >= self.deadline:
            raise link.error(GalilTimeoutError, not_done_text(handle, self.timeout))
        progress = progress_of(handle, now)
        remaining = progress.duration - progress.elapsed
        pause = remaining / 4 if math.isfinite(remaining) else MAX_POLL
        if self.deadline is not None:
            pause = min(pause, self.deadline - now)
        return progress, min(max(pause, MIN_POLL), MAX_POLL)

    def pause(self, seconds: float) -> None:
        """Let ``seconds`` of a simulator's manual clock pass."""
        with self.guard():
            self.link.pause(seconds)


class AsyncMoveHandle(FixedAttributes):
    """A move in progress, awaited from a coroutine: ``result = await handle``.

    The prediction is the sync handle's (:attr:`sync`): :attr:`profile`, :attr:`duration`
    and :attr:`params` read what it computed when the move started or changed.

    Attributes:
        sync: the :class:`~galil.motion.MoveHandle` this one polls.
    """

    _awaited = True

    def __init__(self, handle: MoveHandle, worker: Worker, link: Link) -> None:
        self._sync = handle
        self._worker = worker
        self._link = link
        self._callbacks: list[Callable[[AsyncMoveHandle], None]] = []
        self._watcher: asyncio.Task[None] | None = None

    @property
    def sync(self) -> MoveHandle:
        """The :class:`~galil.motion.MoveHandle` this one polls."""
        return self._sync

    # -- the prediction (computed by the sync handle) ----------------------------------------
    @property
    def kind(self) -> str:
        """``"position"``, ``"jog"``, ``"schedule"``, ``"vector"``, or ``"home"``/``"edge"``/
        ``"index"`` for HM/FE/FI."""
        return self.sync.kind

    @property
    def started_at(self) -> float:
        """The controller clock (seconds) when the handle was made."""
        return self.sync.started_at

    @property
    def notes(self) -> dict[str, str]:
        """What is known of each axis's prediction, where the handle has something to say
        (a homing sequence: predicted from given switch positions, or unknown)."""
        return self.sync.notes

    @property
    def followers(self) -> str:
        """The axes geared to this move's axes, whose motion it predicts too."""
        return self.sync.followers

    @property
    def axes(self) -> str:
        """The axis letters this move drives."""
        return self.sync.axes

    @property
    def profiles(self) -> dict[str, predict.Profile]:
        """Predicted profile per axis, in each axis's unit for display."""
        return self.sync.profiles

    @property
    def profile(self) -> predict.Profile:
        """The predicted profile of the (first) axis."""
        return self.sync.profile

    @property
    def duration(self) -> float:
        """Predicted duration in seconds (``inf`` for a jog that has not been stopped)."""
        return self.sync.duration

    @property
    def params(self) -> dict[str, MoveParams]:
        """The quantised SP/AC/DC/IT each axis started with."""
        return self.sync.params

    @property
    def finished(self) -> bool:
        """Whether the move was seen done (no query)."""
        return self.sync.finished

    @property
    def result(self) -> MoveResult | None:
        """The comparison with the prediction, once the move is done."""
        return self.sync.result

    # -- completion ----------------------------------------------------------------------
    async def done(self) -> bool:
        """Whether every axis's profile is complete (one query unless already seen done)."""
        return await self._worker.run(_is_done, self.sync)

    async def begin(self) -> dict[str, int | None]:
        """Controller sample at which each axis's motion began (see ``MoveHandle.begin``)."""
        return await self._worker.run(_begin_of, self.sync)

    async def watch(
        self, timeout: float | None = None, *, stop_on_cancel: bool = True
    ) -> AsyncGenerator[MoveProgress, None]:
        """Yield the predicted progress at every poll until the move is done.

        Polls come at the sync handle's cadence (at most 100 ms apart); on a manual-clock
        simulator each pause lets simulated time pass instead of sleeping.

        Args:
            timeout: seconds to wait at most (``None``: the predicted duration plus a margin,
                or for ever for a jog that has not been stopped).
            stop_on_cancel: stop the move (``ST``) when the task iterating is cancelled, or
                when the generator is closed before the move is done (``aclose()``, or its
                finalisation after the loop was left by ``break``, an exception or a
                cancellation in the loop's body), or when a poll fails (a dead link is
                reopened once for the stop; no reply), as ``MoveHandle.wait`` does;
                ``False`` only watches.

        Raises:
            InvalidArgument: a timeout that is not ``None`` or a finite number of seconds
                >= 0 (:func:`~galil.link.check_wait_timeout`, as ``MoveHandle.wait``), before
                anything is sent.
            GalilTimeoutError: not done in time (the move is NOT stopped).
        """
        timeout = check_wait_timeout(timeout)
        check_flag(stop_on_cancel, "stop_on_cancel")
        worker, link = self._worker, self._link
        try:
            poll = await worker.run(_Poll, self.sync, link, timeout, stop_on_cancel)
            while (step := await worker.run(poll)) is not None:
                progress, pause = step
                yield progress
                if link.simulated_time:
                    await worker.run(poll.pause, pause)
                else:
                    await asyncio.sleep(pause)
        except (asyncio.CancelledError, GeneratorExit):
            # GeneratorExit: closed while suspended at ``yield`` (the consumer left its loop).
            if stop_on_cancel:
                await self.stop_unless_done()
            raise

    def wait(self, timeout: float | None = None, progress: bool = False) -> MoveWait:
        """Wait until the move is done and compare its end with the prediction.

        ``progress=True`` shows the bar of ``MoveHandle.wait(progress=True)`` (a
        ``tqdm.auto`` bar over the predicted duration, moved at each poll on the event loop);
        it is closed however the wait ends (done, a ``MotionError``, a timeout, a
        cancellation).

        Cancelling the waiting task stops the move (``ST``) before the cancellation ends,
        also when the task is cancelled before the wait has begun: the coroutine returned is
        a :class:`MoveWait`, which stops the move when a cancellation is thrown into it
        before its first step (``asyncio.gather(h1.wait(), h2.wait())`` cancelled at once,
        a ``TaskGroup`` cancelling tasks not yet started, ``asyncio.wait_for(h.wait(), 0)``;
        decision 0061). A wait closed or dropped without ever being awaited stops nothing.

        Raises:
            InvalidArgument: a bad timeout (see :meth:`watch`) or a ``progress`` that is not a
                bool, once awaited and before anything is sent.
            GalilTimeoutError: the move did not finish in time (it is NOT stopped).
            MotionError: an axis stopped on a limit switch or soft limit, or a limit stopped
                an axis geared to one of them (see ``MoveHandle.wait``).
        """
        return MoveWait(self, timeout, progress)

    async def _wait(self, timeout: float | None, progress: bool) -> MoveResult:
        if progress is not False:  # (the sync wait's order: the timeout, then the flag)
            timeout = check_wait_timeout(timeout)
            check_flag(progress, "progress")
        sync = self.sync
        try:  # (a prediction the start could not compute is computed here: if it fails, stop)
            bar = WaitBar.open(sync.kind, sync.axes, sync.duration) if progress else None
        except BaseException:
            await self.stop_unless_done()
            raise
        try:
            async for step in self.watch(timeout):
                if bar is not None:
                    bar.show(step.elapsed)
        finally:
            if bar is not None:
                bar.close(sync.finished)
        # Done: the sync handle's own wait returns at once with the result (or raises).
        return await self._worker.run(sync.wait, 0)

    def __await__(self) -> Generator[object, None, MoveResult]:
        return self.wait().__await__()

    async def stop(self) -> None:
        """Decelerate the axes the move still drives to a stop (``ST``) at their DC (none once
        it was seen done, nor those newer motion took: ``MoveHandle.stop``).

        Once asked for, the stop goes out even if the awaiting task is cancelled (before the
        call has started too)."""
        await self._worker.run_urgent(self.sync.stop)

    async def stop_unless_done(self) -> None:
        """Stop the move (``ST``) unless it was seen done: for clean-up on the way out of a
        failure. The stop runs to its end even if the caller is cancelled meanwhile, and its
        own :class:`~galil.errors.GalilError` is suppressed (the caller's error matters more).
        """
        if self.sync.finished:
            return
        with contextlib.suppress(GalilError):
            await self._worker.run_urgent(self.sync.stop)

    def add_callback(self, callback: Callable[[AsyncMoveHandle], None]) -> None:
        """Call ``callback(handle)`` on the event loop once the move is done (at once if it
        already is); the move is watched by a task of this loop, not by a thread.

        The callbacks run only for a move seen done. If watching it fails first (the
        controller is closed, the connection is lost, the move outlasts its predicted
        duration plus the margin of :meth:`watch`), they are never called: the error is
        logged (logger ``galil.aio``) and they are dropped. A move not seen done when
        :meth:`~galil.aio.AsyncController.aclose` begins is never seen done, though the stop
        ``aclose()`` sends ends it and the watcher polls meanwhile. A callback that raises
        is logged (ERROR on ``galil.aio``) and the others still run.

        Raises:
            InvalidArgument: ``callback`` cannot be called.
        """
        check_callable(callback, "callback")
        if self.sync.finished:
            self._call(callback)
            return
        self._callbacks.append(callback)
        if self._watcher is None:
            self._watcher = asyncio.get_running_loop().create_task(self._watch_for_callbacks())

    async def _watch_for_callbacks(self) -> None:
        try:
            async for _ in self.watch(stop_on_cancel=False):
                pass
        except GalilError as exc:
            dropped, self._callbacks = self._callbacks, []
            _LOG.warning(
                "%r: %d callback(s) dropped, the move was not seen done: %s",
                self,
                len(dropped),
                exc,
            )
            return
        callbacks, self._callbacks = self._callbacks, []
        for cb in callbacks:
            self._call(cb)

    def _call(self, callback: Callable[[AsyncMoveHandle], None]) -> None:
        """Run one done-callback; what it raises is logged (ERROR on ``galil.aio``), never
        passed on: the other callbacks still run (as the sync handle's)."""
        try:
            callback(self)
        except Exception:
            _LOG.exception("move callback %r on %s failed", callback, self.axes)

    def __repr__(self) -> str:
        return f"<AsyncMoveHandle of {self.sync!r}>"


class AsyncVectorHandle(AsyncMoveHandle):
    """A coordinated sequence in progress (``await controller.vector_move(...)``): an
    :class:`AsyncMoveHandle` whose prediction is the whole path's.

    ``stop()`` and a cancelled waiter send ``ST S``; the prediction follows every segment
    streamed, ``VE``, ``ST`` and ``AB`` (the sync :class:`~galil.vector.VectorHandle`).
    """

    def __init__(self, handle: VectorHandle, worker: Worker, link: Link) -> None:
        super().__init__(handle, worker, link)
        self._sequence = handle

    @property
    def counts(self) -> predict.VectorProfile:
        """The prediction in counts, with everything sent so far."""
        return self._sequence.counts

    @property
    def stopped(self) -> bool:
        """Whether an ``ST`` or ``AB`` reached the sequence (a flag: no query)."""
        return self._sequence.stopped

    @property
    def vector(self) -> VectorPlan:
        """The prediction in the axes' user units (path, speed along it, ``plot()``)."""
        return self._sequence.vector

    def __repr__(self) -> str:
        return f"<AsyncVectorHandle of {self.sync!r}>"


class MoveWait(Coroutine[object, None, MoveResult]):
    """The coroutine :meth:`AsyncMoveHandle.wait` returns: ``await`` it, or hand it to
    ``asyncio.gather``, ``create_task``, a ``TaskGroup`` or ``wait_for`` as any coroutine.

    Unlike a native coroutine, it stops the move (``ST``, awaited, then the cancellation goes
    on) when a :class:`asyncio.CancelledError` is thrown into it before its first step: a
    task cancelled before it ever ran its wait still stops the move it was to wait for, as a
    task cancelled while waiting does (decision 0061). Closed or garbage-collected without
    ever being started, it stops nothing (a wait never awaited, like no wait at all) and, as a
    native coroutine, warns (:class:`RuntimeWarning`) only when it is dropped unclosed.
    """

    __slots__ = ("_closed", "_handle", "_inner", "_progress", "_timeout")

    def __init__(
        self, handle: AsyncMoveHandle, timeout: float | None, progress: bool = False
    ) -> None:
        self._handle = handle
        self._timeout = timeout
        self._progress = progress
        self._inner: Coroutine[object, None, MoveResult] | None = None
        self._closed = False

    def send(self, value: None) -> object:
        """Run the wait to its next suspension (it begins at the first call)."""
        if self._inner is None:
            if self._closed:
                raise RuntimeError("cannot reuse already awaited coroutine")
            self._inner = self._handle._wait(self._timeout, self._progress)
        return self._inner.send(value)

    def throw(
        self,
        typ: type[BaseException] | BaseException,
        val: BaseException | object = None,
        tb: TracebackType | None = None,
    ) -> object:
        """Raise an exception in the wait; a cancellation before it began stops the move."""
        exc = _thrown(typ, val, tb)
        if self._inner is None and not self._closed:
            self._closed = True  # (begun now: never to be warned about)
            if isinstance(exc, asyncio.CancelledError):
                self._inner = self._abandoned(exc)
                return self._inner.send(None)
        if self._inner is None:
            raise exc
        return self._inner.throw(exc)

    def close(self) -> None:
        """Close the wait (a wait never begun stops nothing)."""
        self._closed = True
        if self._inner is not None:
            self._inner.close()

    def __await__(self) -> Generator[object, None, MoveResult]:
        return _Awaiting(self)

    async def _abandoned(self, exc: BaseException) -> MoveResult:
        await self._handle.stop_unless_done()
        raise exc

    def __del__(self) -> None:
        if self._inner is None and not self._closed:
            warnings.warn(f"{self!r} was never awaited", RuntimeWarning, stacklevel=2)

    def __repr__(self) -> str:
        return f"<MoveWait of {self._handle.sync!r}>"


class _Awaiting(Generator[object, None, MoveResult]):
    """``MoveWait.__await__()``: the iterator ``await`` drives, every call passed on (the
    wait itself is no iterator: typing tools would then take it for a generator)."""

    __slots__ = ("_wait",)

    def __init__(self, wait: MoveWait) -> None:
        self._wait = wait

    def send(self, value: None) -> object:
        return self._wait.send(value)

    def throw(
        self,
        typ: type[BaseException] | BaseException,
        val: BaseException | object = None,
        tb: TracebackType | None = None,
    ) -> object:
        return self._wait.throw(typ, val, tb)

    def close(self) -> None:
        self._wait.close()


def _thrown(
    typ: type[BaseException] | BaseException, val: object, tb: TracebackType | None
) -> BaseException:
    """The exception of a ``throw(typ[, val[, tb]])`` call (the generator protocol's forms)."""
    if isinstance(typ, BaseException):
        exc = typ
    elif isinstance(val, BaseException):
        exc = val
    else:
        exc = typ() if val is None else typ(val)
    return exc if tb is None else exc.with_traceback(tb)


def _is_done(handle: MoveHandle) -> bool:
    return handle.done


def _begin_of(handle: MoveHandle) -> dict[str, int | None]:
    return handle.begin


def _stop(handle: MoveHandle) -> None:
    handle.stop()  # the handle's own stop: ST on its axes, ST S for a sequence


def _started(start: Callable[P, M], /, *args: P.args, **kwargs: P.kwargs) -> M:
    """Start motion, then predict it here on the worker (the loop only reads the result)."""
    handle = start(*args, **kwargs)
    with contextlib.suppress(Exception):  # a prediction that fails fails again where read
        handle.profiles  # noqa: B018 - computed and cached by the sync handle
    return handle


class _DroppedError(Exception):
    """A start cancelled before it began its work: it never sends anything."""


class Starting:
    """A call that starts motion on a worker thread, which the awaiting task may cancel while
    it runs: from :meth:`cancel` on, the motion the call registers is stopped the moment it
    registers (:meth:`~galil.motion.MotionTracker.refuse_starts`), until the call returns.

    A stop sent from another thread reaches only motion already registered; a contour or a
    streamed path still reading the state or predicting when its task was cancelled would
    otherwise run its whole path (only then would the call return, to be undone).

    A call that has not begun when its task is cancelled never begins: :meth:`abandon`, on
    the loop as the cancellation arrives, already refuses it, whichever of the call's thread
    and the thread that runs :meth:`cancel` gets to the tracker's lock first.
    """

    def __init__(self, tracker: MotionTracker | None) -> None:
        self._tracker = tracker
        self._thread: int | None = None
        self._cancelled = False
        self._abandoned = False  # (set on the loop, read under the tracker's lock)
        self._began = False
        self._sequence_before: MoveHandle | None = None  # the last sequence as it began
        self._over = threading.Event()  # set once the call has returned (or was dropped)

    def run(self, call: Callable[[], R]) -> R:
        """Worker side: ``call()``, its motion refused once :meth:`cancel` has run."""
        tracker = self._tracker
        if tracker is None:
            return call()
        with tracker.lock:
            if self._cancelled or self._abandoned:
                self._ended(tracker)
                raise _DroppedError("cancelled before it began")
            self._thread = thread = threading.get_ident()
            self._began = True
            self._sequence_before = tracker.last_sequence()
        try:
            return call()
        finally:
            with tracker.lock:
                tracker.allow_starts(thread)
                self._thread = None
            self._ended(tracker)

    def _ended(self, tracker: MotionTracker) -> None:
        with _ABANDONED_LOCK:
            _ABANDONED.get(tracker, set()).discard(self)
            self._over.set()

    def abandon(self) -> None:
        """Loop side, as the awaiting task is cancelled (before :meth:`cancel` is submitted):
        a call that has not begun never will (without waiting for :meth:`cancel` to run on
        another thread: a start let begin first ran a streamed path to its end); until the
        call is over, :func:`settle_abandoned` finds it."""
        self._abandoned = True  # (no lock on the loop: a call that began already is cancel()'s)
        if self._tracker is None:
            return
        with _ABANDONED_LOCK:
            if not self._over.is_set():
                _ABANDONED.setdefault(self._tracker, set()).add(self)

    def sequence_started(self) -> MoveHandle | None:
        """The vector sequence registered since the call began (by it: one sequence runs on
        S at a time, and a start finding one running is refused), ``None`` when the call has
        not begun or has registered none: what a cancelled ``vector_move`` is to stop, and
        never a sequence that was running before it."""
        if self._tracker is None or not self._began:
            return None
        last = self._tracker.last_sequence()
        return None if last is self._sequence_before else last

    def cancel(self, then: Callable[[], object] | None = None) -> None:
        """Worker side, once the awaiting task is cancelled: refuse what the call has not
        registered yet, and run ``then()`` (stop what it has) under the same lock."""
        with held(self._tracker):
            self._cancelled = True
            if self._tracker is not None and self._thread is not None:
                self._tracker.refuse_starts(self._thread)
            if then is not None:
                then()


_ABANDONED: weakref.WeakKeyDictionary[MotionTracker, set[Starting]] = weakref.WeakKeyDictionary()
_ABANDONED_LOCK = threading.Lock()  # (never held while anything else is)


def settle_abandoned(tracker: MotionTracker, timeout: float = 30.0) -> None:
    """Worker side: let every start whose awaiting task was cancelled end before going on.
    A start that has not begun never will (it is cancelled here, under the tracker's lock);
    one that runs is refused what it has not registered yet and waited for (at most
    ``timeout`` seconds each), so that the motion it has registered can be seen (``_BG``)
    and stopped by whoever calls this next: the ``motion()`` guard (decision 0061)."""
    with _ABANDONED_LOCK:
        pending = list(_ABANDONED.get(tracker, ()))
    for starting in pending:
        starting.cancel()  # (idempotent: the cancelled caller has submitted its own too)
    for starting in pending:
        if starting._began:  # (final once cancel() has run: a start begins under the lock)
            starting._over.wait(timeout)


async def start_motion(
    worker: Worker,
    link: Link,
    wrap: Callable[[M, Worker, Link], H],
    starting: Starting,
    start: Callable[P, M],
    /,
    *args: P.args,
    **kwargs: P.kwargs,
) -> H:
    """Run a sync call that starts motion and wrap the handle it returns; if the caller is
    cancelled meanwhile, the motion it started is stopped as soon as the call returns (a call
    not yet started never runs; see :class:`Starting` for what it starts before it returns).
    """
    call = functools.partial(_started, start, *args, **kwargs)
    handle = await worker.run_or_undo(_stop, starting.run, call)
    return wrap(handle, worker, link)


class MotionRoom(Room[S_co]):
    """A room whose methods start motion: it also knows the link (clock, pauses) and the
    motion tracker (cancelled starts)."""

    def __init__(
        self, sync: S_co, worker: Worker, link: Link, tracker: MotionTracker | None = None
    ) -> None:
        super().__init__(sync, worker)
        self._link = link
        self._tracker = tracker


class motion_twin(Generic[S, P, H]):  # noqa: N801 - used like a decorator
    """The async twin of a sync method that starts motion and returns a ``MoveHandle``:
    ``await room.name(...)`` returns an :class:`AsyncMoveHandle` (or what ``wrap`` makes of
    the handle, e.g. an :class:`AsyncVectorHandle`; see :func:`start_motion`).
    """

    @overload
    def __init__(
        self: motion_twin[S, P, AsyncMoveHandle],
        method: Callable[Concatenate[S, P], MoveHandle],
    ) -> None: ...

    @overload
    def __init__(
        self,
        method: Callable[Concatenate[S, P], M],
        wrap: Callable[[M, Worker, Link], H],
    ) -> None: ...

    def __init__(
        self,
        method: Callable[Concatenate[S, P], object],
        wrap: Callable[[NoReturn, Worker, Link], object] = AsyncMoveHandle,
    ) -> None:
        # (the overloads pair ``method`` and ``wrap``; here either may be any of them)
        self._method: Callable[Concatenate[S, P], Any] = method
        self._wrap: Callable[[Any, Worker, Link], Any] = wrap
        self._at_once: Callable[[Any, Starting], object] | None = None
        self.__doc__ = method.__doc__
        self.__name__ = getattr(method, "__name__", "motion_twin")

    def on_cancel(self, at_once: Callable[[S, Starting], object]) -> motion_twin[S, P, H]:
        """Also run ``at_once(sync, starting)`` on a worker the moment the caller is
        cancelled, while the start is still running (a long path streaming on its thread is
        stopped then, not only once every segment has been sent); under the tracker's lock,
        with the start's motion refused from then on. ``starting`` (:class:`Starting`) tells
        what the start has registered so far: only that is to be stopped. The cancellation
        awaits it (shielded): the caller gets its ``CancelledError`` once the stop went out."""
        self._at_once = at_once
        return self

    @overload
    def __get__(self, room: None, owner: type[object]) -> motion_twin[S, P, H]: ...

    @overload
    def __get__(self, room: MotionRoom[S], owner: type[object]) -> Callable[P, Awaitable[H]]: ...

    def __get__(
        self, room: MotionRoom[S] | None, owner: type[object]
    ) -> motion_twin[S, P, H] | Callable[P, Awaitable[H]]:
        if room is None:
            return self
        method, wrap, at_once = self._method, self._wrap, self._at_once
        sync = room.sync
        worker = room._worker
        link = room._link
        tracker = room._tracker

        async def call(*args: P.args, **kwargs: P.kwargs) -> H:
            starting = Starting(tracker)
            try:
                started: H = await start_motion(
                    worker, link, wrap, starting, method, sync, *args, **kwargs
                )
            except asyncio.CancelledError:
                starting.abandon()
                then = None if at_once is None else functools.partial(at_once, sync, starting)
                # Awaited (shielded, on the stops' lane): when the cancellation reaches the
                # caller, what the start registered is stopped and the rest refused (0085).
                with contextlib.suppress(GalilError):
                    await worker.run_urgent(starting.cancel, then)
                raise
            return started

        call.__doc__ = method.__doc__
        call.__name__ = self.__name__
        # (what "coroutine ... was never awaited" and tracebacks name: AsyncAxis.stop, not
        # motion_twin.__get__.<locals>.call)
        call.__qualname__ = f"{type(room).__name__}.{self.__name__}"
        return call
