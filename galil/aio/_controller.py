"""The async controller: a twin of :class:`galil.Controller`, its axes and its rooms.

Every method that talks to the controller runs the sync method on the controller's worker
threads; nothing here converts a unit, predicts a move or builds a command.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import itertools
import sys
import warnings
import weakref
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from galil.aio._axis import AsyncAxis
from galil.aio._capture import AsyncCapture, AsyncWatchdog
from galil.aio._facade import AsyncLinkFacade
from galil.aio._interrupts import AsyncInterrupts
from galil.aio._io import AsyncIO
from galil.aio._motion import AsyncVectorHandle, Starting, motion_twin, settle_abandoned
from galil.aio._programs import AsyncArrays, AsyncPrograms, AsyncVariables
from galil.aio._streams import AsyncMessages, LoopQueue
from galil.aio._worker import Worker, shielded, twin
from galil.axis import MoveOverrides, MoveTargets
from galil.capture import Capture
from galil.contour import ContourResult
from galil.controller import (
    AxisMap,
    Controller,
    CoordinatedMotion,
    close_after,
    close_collected,
    no_axis_attribute,
)
from galil.controller import connect as connect_sync
from galil.errors import GalilError, InvalidArgument
from galil.homing import SwitchPolarity
from galil.link import check_count, check_wait_timeout
from galil.motion import MotionTracker, MoveHandle
from galil.predict import MultiProfile
from galil.protocol.interrupts import Interrupt
from galil.segments import Segment, VectorPlan
from galil.transport import Transport
from galil.units import Amount, Amounts
from galil.vector import VectorOptions

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # (typing_extensions: a dependency on Python 3.10)
    from typing_extensions import Unpack

__all__ = ["AsyncController", "connect"]

_names = itertools.count(1)


# Methods that take **overrides cannot bind ``self`` positionally for mypy; these forwarders
# only make it positional-only (the sync methods do the work and hold the docstrings).
def _move(
    c: Controller,
    /,
    targets: MoveTargets,
    *,
    relative: bool = False,
    **overrides: Unpack[MoveOverrides],
) -> MoveHandle:
    return c.move(targets, relative=relative, **overrides)


def _plan(
    c: Controller,
    /,
    targets: MoveTargets,
    *,
    relative: bool = False,
    **overrides: Unpack[MoveOverrides],
) -> MultiProfile:
    return c.plan(targets, relative=relative, **overrides)


def _plan_vector(
    c: Controller, /, axes: str, segments: Sequence[Segment], **options: Unpack[VectorOptions]
) -> VectorPlan:
    return c.plan_vector(axes, segments, **options)


for _f, _sync in (
    (_move, Controller.move),
    (_plan, Controller.plan),
    (_plan_vector, Controller.plan_vector),
):
    _f.__doc__ = _sync.__doc__
    _f.__name__ = _sync.__name__


def _polarity(c: Controller) -> SwitchPolarity:
    return c.switch_polarity


def _set_polarity(c: Controller, polarity: SwitchPolarity) -> None:
    c.switch_polarity = polarity


def _capture(
    c: Controller, sources: list[str], every: int, count: int | None, seconds: float | None
) -> tuple[Capture, float]:
    capture = c.capture(sources, every=every, count=count, seconds=seconds)
    return capture, c.link.clock()


def _stop_capture(started: tuple[Capture, float]) -> None:
    started[0].stop()


def _stop_sequence_started(controller: CoordinatedMotion, starting: Starting) -> None:
    """Stop (``ST S``) the sequence a cancelled ``vector_move`` has started, even one still
    streaming on its thread; never one that ran before it (decision 0061)."""
    handle = starting.sequence_started()
    if handle is not None:
        with contextlib.suppress(GalilError):
            handle.stop()


def _guard_exit(
    tracker: MotionTracker, guard: contextlib.AbstractContextManager[None], exc: BaseException
) -> None:
    """The ``motion()`` guard's exit on an exception: after the starts it cancelled (decision
    0061), so that their motion is stopped and waited for too."""
    settle_abandoned(tracker)
    guard.__exit__(type(exc), exc, exc.__traceback__)


class AsyncController(AsyncLinkFacade):
    """A connected controller for coroutines. Build it with :func:`connect`.

    The vocabulary is the sync :class:`~galil.Controller`'s (:attr:`sync`) with ``await``:
    ``await c.command("TPA")``, ``c.A`` (an :class:`AsyncAxis`), ``await c.move({...})``,
    ``await c.vector_move(...)``, ``await c.contour(...)``, ``async for rec in await
    c.records(8)``, ``async for line in c.messages``; the rooms ``c.io``, ``c.programs``,
    ``c.arrays``, ``c.variables`` and ``c.interrupts`` (``async for i in c.interrupts``).
    Close it with :meth:`aclose` (or ``async with``).

    Attributes:
        io: digital and analog I/O (:class:`~galil.aio.AsyncIO`).
        programs: the user's program and threads (:class:`~galil.aio.AsyncPrograms`).
        arrays: the controller's arrays (:class:`~galil.aio.AsyncArrays`).
        variables: the controller's variables (:class:`~galil.aio.AsyncVariables`).
        interrupts: ``UI``/``EI`` interrupts (:class:`~galil.aio.AsyncInterrupts`).
    """

    def __init__(
        self,
        sync: Controller,
        worker: Worker,
        messages: AsyncMessages,
        interrupts: LoopQueue[Interrupt],
        unsubscribe: Callable[[], None],
    ) -> None:
        super().__init__(sync, worker, messages)
        self._axes: dict[str, AsyncAxis] | None = None
        self._unsubscribe = unsubscribe
        link = sync.link
        self._io = AsyncIO(sync.io, worker, link)
        self._programs = AsyncPrograms(sync.programs, worker, link)
        self._arrays = AsyncArrays(sync.arrays, worker)
        self._variables = AsyncVariables(sync.variables, worker)
        self._interrupts = AsyncInterrupts(sync.interrupts, worker, interrupts)
        # Dropped unclosed: a ResourceWarning, and its link and threads are closed.
        self._finalizer = weakref.finalize(self, _collected, sync, worker, repr(self))
        self._finalizer.atexit = False

    @property
    def io(self) -> AsyncIO:
        """Digital and analog I/O."""
        return self._io

    @property
    def programs(self) -> AsyncPrograms:
        """The user's program and threads."""
        return self._programs

    @property
    def arrays(self) -> AsyncArrays:
        """The controller's arrays."""
        return self._arrays

    @property
    def variables(self) -> AsyncVariables:
        """The controller's variables."""
        return self._variables

    @property
    def interrupts(self) -> AsyncInterrupts:
        """``UI``/``EI`` interrupts."""
        return self._interrupts

    @property
    def closed(self) -> bool:
        """Whether :meth:`aclose` was called (or the link is closed)."""
        return self._worker.closed or self.sync.closed

    @property
    def worker(self) -> Worker:
        """The threads this controller's blocking calls run on."""
        return self._worker

    reconnect = twin(Controller.reconnect)
    reset = twin(Controller.reset, shield=True)  # once RS went out, the set-up must follow

    # -- axes -------------------------------------------------------------------------------
    @property
    def axes(self) -> dict[str, AsyncAxis]:
        """The model's axes by letter (``c.axes["A"]``; also ``c.A``)."""
        if self._axes is None:
            self._axes = AxisMap(
                {
                    a: AsyncAxis(ax, self._worker, self._link, self.sync.tracker)
                    for a, ax in self.sync.axes.items()
                },
                self.model,
            )
        return self._axes

    def axis(self, name: str) -> AsyncAxis:
        """The axis called ``name`` (``"A"``, or ``"X"`` where the model aliases it)."""
        return self.axes[self.model.axis_letter(name)]

    if not TYPE_CHECKING:

        def __getattr__(self, name: str) -> AsyncAxis:
            sync = self.__dict__.get("_sync")
            if len(name) == 1 and name.isupper() and sync is not None:
                with contextlib.suppress(InvalidArgument):
                    return self.axis(name)
            # As the sync controller says it: the axes the model has, or that it has none.
            model = None if sync is None else sync.link._model
            raise no_axis_attribute(type(self).__name__, name, model)

    A: AsyncAxis
    B: AsyncAxis
    C: AsyncAxis
    D: AsyncAxis
    E: AsyncAxis
    F: AsyncAxis
    G: AsyncAxis
    H: AsyncAxis
    X: AsyncAxis
    Y: AsyncAxis
    Z: AsyncAxis
    W: AsyncAxis

    # -- motion ---------------------------------------------------------------------------
    move = motion_twin(_move)
    plan = twin(_plan)
    vector_move = motion_twin(Controller.vector_move, AsyncVectorHandle).on_cancel(
        _stop_sequence_started
    )
    plan_vector = twin(_plan_vector)
    stop = twin(Controller.stop, urgent=True)  # asked for, a stop goes out even if cancelled
    abort = twin(Controller.abort, urgent=True)
    servo_here = twin(Controller.servo_here)
    motor_off = twin(Controller.motor_off)

    async def contour(
        self,
        axes: str,
        path: Amounts,
        *,
        dt: int,
        progress: bool = False,
        timeout: float | None = None,
        speed_limit: Amount | Mapping[str, Amount] | None = None,
        accel_limit: Amount | Mapping[str, Amount] | None = None,
    ) -> ContourResult:
        """Run a contour path on ``axes`` (see ``Controller.contour``) and return when done.

        Cancelling the awaiting task stops the contour's axes (``ST``) before the
        cancellation ends; the stream then leaves contour mode on its thread. A contour
        cancelled while it is still being checked sends no segment.

        Raises:
            InvalidArgument: a bad timeout (refused before anything is sent), and the sync
                method's errors.
        """
        timeout = check_wait_timeout(timeout)
        starting = Starting(self.sync.tracker)
        call = functools.partial(
            self.sync.contour,
            axes,
            path,
            dt=dt,
            progress=progress,
            timeout=timeout,
            speed_limit=speed_limit,
            accel_limit=accel_limit,
        )
        future = self._worker.submit(starting.run, call)
        try:
            return await shielded(future)
        except asyncio.CancelledError:
            if not future.cancel():
                # Under the tracker's lock: a contour that has not entered contour mode yet
                # never sends a segment; one that has is stopped (ST, and no CD after it).
                with contextlib.suppress(GalilError):
                    stop = functools.partial(self.sync.stop, axes)
                    await self._worker.run_urgent(starting.cancel, stop)
            raise

    @contextlib.asynccontextmanager
    async def motion(self, axes: str | None = None) -> AsyncIterator[None]:
        """A block in which an exception (cancellation included) stops the guarded axes
        (default or ``""``: all) and waits for them, as ``Controller.motion`` does; a start in
        the block that the cancellation left running on its worker thread is let end first, so
        its motion is stopped and waited for too (decision 0061)."""
        guard = self.sync.motion(axes)
        guard.__enter__()
        try:
            yield
        except BaseException as exc:
            # A start the exception cancelled still running on its thread ends first, then
            # the sync guard stops, waits and re-raises (or raises MotionError from exc).
            await self._worker.run_shielded(_guard_exit, self.sync.tracker, guard, exc)
            raise
        else:
            guard.__exit__(None, None, None)

    async def watchdog(
        self, timeout: float, *, thread: int | None = None, interval: float | None = None
    ) -> AsyncWatchdog:
        """Start a dead-man switch: the controller stops every axis (``ST``) when the host has
        been silent for ``timeout`` seconds (see ``Controller.watchdog``; the heartbeat runs
        on a thread of the sync core). :meth:`aclose` stops it. One watchdog guards a
        controller: a new one replaces the running one, on any thread (decision 0082); a call
        cancelled while it starts stops the new one, and the one it replaced stays stopped.

        Raises:
            InvalidArgument: a bad timeout, interval or thread, a busy thread, a user program
                running while the routine must be installed.
        """
        dog = await self._worker.run_or_undo(
            _stop_watchdog, self.sync.watchdog, timeout, thread=thread, interval=interval
        )
        return AsyncWatchdog(dog, self._worker)

    async def capture(
        self,
        sources: list[str],
        *,
        every: int = 2,
        count: int | None = None,
        seconds: float | None = None,
    ) -> AsyncCapture:
        """Start recording ``sources`` on the controller, every ``every`` samples, at servo
        rate (``RA``/``RD``/``RC``); see ``Controller.capture``. ``await cap.wait()`` (or
        leaving an ``async with`` block, or ``await cap.stop()``) uploads them.

        Raises:
            InvalidArgument: a source ``RD`` cannot record, ``every`` not allowed, too many
                values for the array space (nothing is sent), or a recording running
                already.
        """
        capture, started = await self._worker.run_or_undo(
            _stop_capture, _capture, self.sync, sources, every, count, seconds
        )
        return AsyncCapture(capture, self._worker, self._link, started)

    # -- switches and flash -----------------------------------------------------------------
    async def switch_polarity(self) -> SwitchPolarity:
        """``CN``: limit polarity, home direction and latch edge (``MG _CN0,_CN1,_CN2``)."""
        return await self._worker.run(_polarity, self.sync)

    async def set_switch_polarity(self, polarity: SwitchPolarity) -> None:
        """Send ``CN`` (every field validated before the byte goes out)."""
        await self._worker.run(_set_polarity, self.sync, polarity)

    save = twin(Controller.save)
    save_program = twin(Controller.save_program)
    save_variables = twin(Controller.save_variables)

    # -- life cycle -------------------------------------------------------------------------
    async def aclose(self) -> None:
        """Close the sync controller (restoring what connect changed; watchdogs, record
        streams and interrupts stop) and end the worker's threads; idempotent."""
        await self._aclose(None)

    async def _aclose(self, error: BaseException | None) -> None:
        if self._worker.closed:
            return
        self._finalizer.detach()
        self._messages.close()
        self.interrupts.queue.close()
        self._unsubscribe()
        try:
            await self._worker.run_shielded(close_after, self.sync, error)
        finally:
            self._worker.close()

    async def __aenter__(self) -> AsyncController:
        return self

    async def __aexit__(self, kind: object, error: BaseException | None, tb: object) -> None:
        await self._aclose(error)

    def __repr__(self) -> str:
        return f"<AsyncController of {self.sync!r}>"


def _collected(sync: Controller, worker: Worker, name: str) -> None:
    warnings.warn(
        f"{name} was never closed: await aclose() or use `async with await "
        "galil.aio.connect(...)`; its link and worker threads are closed now (motion it "
        "started is not stopped)",
        ResourceWarning,
        stacklevel=1,
    )
    worker.close()
    close_collected(sync)


def _stop_watchdog(dog: Any) -> None:
    dog.stop()


def _close_controller(controller: Controller, worker: Worker) -> None:
    try:
        controller.close()
    finally:
        worker.close()


async def connect(
    address: str | Transport, *, threads: int = 4, **options: object
) -> AsyncController:
    """Connect to a controller from a coroutine: ``c = await galil.aio.connect(address)``.

    The address and options are those of :func:`galil.connect`; the connection (and every
    later call) runs on ``threads`` worker threads of this controller, never on the loop.
    Cancelled while connecting, the connection is closed as soon as it is made.

    Raises:
        InvalidArgument: the address or an option is not understood.
        GalilConnectionError: the link cannot be opened or the controller does not answer.
    """
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 64:
        raise InvalidArgument(f"threads must be an integer 1..64, not {threads!r}")
    maxlen = check_count(options.get("max_messages", 1000), "max_messages")
    messages = AsyncMessages(maxlen)
    interrupts: LoopQueue[Interrupt] = LoopQueue(1000, "interrupt")
    worker = Worker(str(next(_names)), threads)
    future = worker.submit(_open, address, options, messages.deliver, interrupts.deliver)
    try:
        sync, unsubscribe = await shielded(future)
    except asyncio.CancelledError:
        if future.cancel():
            worker.close()
        else:
            future.add_done_callback(lambda f: _close_if_opened(f, worker))
        raise
    except BaseException:
        worker.close()
        raise

    async def revive() -> bool:  # (a get() that finds the link dead: the automatic reconnect)
        return await worker.run(sync.link.revive)

    messages._follow(sync.messages_room.queue.ended, revive)
    interrupts._follow(sync.interrupts.queue.ended, revive)
    return AsyncController(sync, worker, messages, interrupts, unsubscribe)


def _close_if_opened(
    future: concurrent.futures.Future[tuple[Controller, Callable[[], None]]], worker: Worker
) -> None:
    if future.cancelled() or future.exception() is not None:
        worker.close()
        return
    worker.submit(_close_controller, future.result()[0], worker)


def _open(
    address: str | Transport,
    options: dict[str, object],
    deliver: Callable[[str], None],
    interrupt: Callable[[Interrupt], None],
) -> tuple[Controller, Callable[[], None]]:
    controller = connect_sync(address, **options)
    controller.tracker.wait_hint = "await a move's handle (await handle.wait(), or await handle)"
    try:
        quiet = controller.subscribe(deliver)
        deaf = controller.interrupts.subscribe(interrupt)
    except BaseException:
        controller.close()
        raise

    def unsubscribe() -> None:
        quiet()
        deaf()

    return controller, unsubscribe
