"""The async controller and its axes: twins of :class:`galil.Controller` and :class:`galil.Axis`.

Every method that talks to the controller runs the sync method on the controller's worker
threads; nothing here converts a unit, predicts a move or builds a command.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import math
from collections.abc import AsyncIterator, Callable, Mapping
from typing import TYPE_CHECKING, Any

from galil.aio._motion import MotionRoom, motion_twin
from galil.aio._streams import AsyncMessages, AsyncRecordStream
from galil.aio._worker import Worker, shielded, twin
from galil.axis import Axis
from galil.contour import ContourResult
from galil.controller import Controller
from galil.controller import connect as connect_sync
from galil.errors import GalilError, InvalidArgument
from galil.models import Identity, ModelSpec
from galil.motion import MoveHandle
from galil.predict import MultiProfile, Profile
from galil.transport import Transport

__all__ = ["AsyncAxis", "AsyncController", "connect"]

_names = itertools.count(1)


# Methods that take **overrides cannot bind ``self`` positionally for mypy; these forwarders
# only make it positional-only (the sync methods do the work and hold the docstrings).
def _move_to(axis: Axis, /, position: Any, **overrides: Any) -> MoveHandle:
    return axis.move_to(position, **overrides)


def _move_by(axis: Axis, /, distance: Any, **overrides: Any) -> MoveHandle:
    return axis.move_by(distance, **overrides)


def _plan_to(axis: Axis, /, position: Any, **overrides: Any) -> Profile:
    return axis.plan_to(position, **overrides)


def _plan_by(axis: Axis, /, distance: Any, **overrides: Any) -> Profile:
    return axis.plan_by(distance, **overrides)


def _move(
    c: Controller, /, targets: Mapping[str, Any], *, relative: bool = False, **overrides: Any
) -> MoveHandle:
    return c.move(targets, relative=relative, **overrides)


def _plan(
    c: Controller, /, targets: Mapping[str, Any], *, relative: bool = False, **overrides: Any
) -> MultiProfile:
    return c.plan(targets, relative=relative, **overrides)


for _f, _sync in (
    (_move_to, Axis.move_to),
    (_move_by, Axis.move_by),
    (_plan_to, Axis.plan_to),
    (_plan_by, Axis.plan_by),
    (_move, Controller.move),
    (_plan, Controller.plan),
):
    _f.__doc__ = _sync.__doc__
    _f.__name__ = _sync.__name__


class AsyncAxis(MotionRoom[Axis]):
    """One axis, awaited: ``await axis.position()``, ``handle = await axis.move_to(5 * mm)``.

    Values go in and come out in the axis's user units, exactly as on the sync
    :class:`~galil.axis.Axis` (:attr:`sync`), which does the work.
    """

    @property
    def letter(self) -> str:
        """The axis letter."""
        return self.sync.letter

    def set_scale(self, counts_per: Any, offset: Any = None, sign: int = 1) -> AsyncAxis:
        """Give the axis a scale (no I/O; see :meth:`galil.Axis.set_scale`)."""
        self.sync.set_scale(counts_per, offset, sign)
        return self

    @property
    def scale(self) -> Any:
        """The axis's :class:`~galil.units.Scale`, if any."""
        return self.sync.scale

    async def _get(self, name: str) -> Any:
        return await self._worker.run(getattr, self.sync, name)

    async def _set(self, name: str, value: Any) -> None:
        await self._worker.run(setattr, self.sync, name, value)

    # -- operands (one query each; see the sync properties) ---------------------------------
    async def position(self) -> Any:
        """Encoder position ``_TP``."""
        return await self._get("position")

    async def reference_position(self) -> Any:
        """Commanded (reference) position ``_RP``."""
        return await self._get("reference_position")

    async def velocity(self) -> Any:
        """Filtered actual velocity ``_TV`` (signed)."""
        return await self._get("velocity")

    async def error(self) -> Any:
        """Position error ``_TE``."""
        return await self._get("error")

    async def moving(self) -> bool:
        """True while the profiler is running (``_BG``)."""
        return bool(await self._get("moving"))

    async def motor_on(self) -> bool:
        """True when the servo is enabled (``_MO`` is 0)."""
        return bool(await self._get("motor_on"))

    async def stop_code(self) -> tuple[int, str]:
        """``_SC`` with its text."""
        code, text = await self._get("stop_code")
        return int(code), str(text)

    # -- parameters ---------------------------------------------------------------------------
    async def speed(self) -> Any:
        """Slew speed ``SP``."""
        return await self._get("speed")

    async def set_speed(self, value: Any) -> None:
        """Set ``SP`` (in motion too: the move's prediction follows)."""
        await self._set("speed", value)

    async def accel(self) -> Any:
        """Acceleration ``AC``."""
        return await self._get("accel")

    async def set_accel(self, value: Any) -> None:
        """Set ``AC`` (in motion too)."""
        await self._set("accel", value)

    async def decel(self) -> Any:
        """Deceleration ``DC``."""
        return await self._get("decel")

    async def set_decel(self, value: Any) -> None:
        """Set ``DC`` (the controller refuses a change in motion)."""
        await self._set("decel", value)

    async def smoothing(self) -> float:
        """Independent time constant ``IT``."""
        return float(await self._get("smoothing"))

    async def set_smoothing(self, value: float) -> None:
        """Set ``IT``."""
        await self._set("smoothing", value)

    async def jog_speed(self) -> Any:
        """Jog speed ``JG`` (signed)."""
        return await self._get("jog_speed")

    async def set_jog_speed(self, value: Any) -> None:
        """Set ``JG`` (while jogging: the speed changes in motion)."""
        await self._set("jog_speed", value)

    async def soft_limits(self) -> tuple[Any, Any]:
        """``(low, high)`` soft limits (``BL``, ``FL``)."""
        low, high = await self._get("soft_limits")
        return low, high

    async def set_soft_limits(self, limits: tuple[Any, Any]) -> None:
        """Set ``(low, high)``; ``None`` on either side removes it."""
        await self._set("soft_limits", limits)

    # -- motion -------------------------------------------------------------------------------
    move_to = motion_twin(_move_to)
    move_by = motion_twin(_move_by)
    jog = motion_twin(Axis.jog)
    increment = motion_twin(Axis.increment)
    speed_schedule = motion_twin(Axis.speed_schedule)
    plan_to = twin(_plan_to)
    plan_by = twin(_plan_by)
    stop = twin(Axis.stop)

    def __repr__(self) -> str:
        return f"<AsyncAxis of {self.sync!r}>"


class AsyncController(MotionRoom[Controller]):
    """A connected controller for coroutines. Build it with :func:`connect`.

    The vocabulary is the sync :class:`~galil.Controller`'s (:attr:`sync`) with ``await``:
    ``await c.command("TPA")``, ``c.A`` (an :class:`AsyncAxis`), ``await c.move({...})``,
    ``await c.contour(...)``, ``async for rec in await c.records(8)``,
    ``async for line in c.messages``. Close it with :meth:`aclose` (or ``async with``).
    """

    def __init__(
        self,
        sync: Controller,
        worker: Worker,
        loop: asyncio.AbstractEventLoop,
        messages: AsyncMessages,
        unsubscribe: Callable[[], None],
    ) -> None:
        super().__init__(sync, worker, sync.link)
        self._loop = loop
        self._axes: dict[str, AsyncAxis] | None = None
        self._messages = messages
        self._unsubscribe = unsubscribe

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
    def sample_period(self) -> float:
        """Seconds per servo sample."""
        return self.sync.sample_period

    @property
    def closed(self) -> bool:
        """Whether :meth:`aclose` was called (or the link is closed)."""
        return self._worker.closed or self.sync.closed

    @property
    def worker(self) -> Worker:
        """The threads this controller's blocking calls run on."""
        return self._worker

    # -- the link -----------------------------------------------------------------------------
    command = twin(Controller.command)
    command_line = twin(Controller.command_line)
    send = twin(Controller.send)
    exchange = twin(Controller.exchange)
    send_many = twin(Controller.send_many)
    query_number = twin(Controller.query_number)
    query_numbers = twin(Controller.query_numbers)
    query_operands = twin(Controller.query_operands)
    reconnect = twin(Controller.reconnect)

    async def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller: simulated time on a manual-clock
        simulator, ``asyncio.sleep`` otherwise (the loop stays free)."""
        if (
            isinstance(seconds, bool)
            or not isinstance(seconds, (int, float))
            or not math.isfinite(seconds)
            or seconds < 0
        ):
            raise InvalidArgument(f"seconds must be a non-negative finite number, got {seconds!r}")
        if self.sync.link.simulated_time:
            await self._worker.run(self.sync.sleep, float(seconds))
        else:
            await asyncio.sleep(float(seconds))

    # -- unsolicited output and records -----------------------------------------------------
    @property
    def messages(self) -> AsyncMessages:
        """Unsolicited lines as an async iterator (``async for line in c.messages``)."""
        return self._messages

    async def subscribe(self, callback: Callable[[str], None]) -> Callable[[], None]:
        """Call ``callback(line)`` on this event loop for each unsolicited line; returns a
        function that unsubscribes."""
        if not callable(callback):
            raise InvalidArgument(f"callback must be callable, not {callback!r}")
        loop = self._loop

        def deliver(line: str) -> None:
            if not loop.is_closed():
                loop.call_soon_threadsafe(callback, line)

        return await self._worker.run(self.sync.subscribe, deliver)

    record = twin(Controller.record)

    async def records(
        self, period: int, *, method: str = "auto", maxlen: int = 10_000
    ) -> AsyncRecordStream:
        """Stream data records every ``period`` servo samples (see ``Controller.records``)."""
        stream = await self._worker.run_or_undo(
            _close_stream, self.sync.records, period, method=method, maxlen=maxlen
        )
        return AsyncRecordStream(stream, self._worker)

    # -- axes -------------------------------------------------------------------------------
    @property
    def axes(self) -> dict[str, AsyncAxis]:
        """The model's axes by letter (``c.axes["A"]``; also ``c.A``)."""
        if self._axes is None:
            self._axes = {
                a: AsyncAxis(ax, self._worker, self._link) for a, ax in self.sync.axes.items()
            }
        return self._axes

    def axis(self, name: str) -> AsyncAxis:
        """The axis called ``name`` (``"A"``, or ``"X"`` where the model aliases it)."""
        return self.axes[self.model.axis_letter(name)]

    if not TYPE_CHECKING:

        def __getattr__(self, name: str) -> AsyncAxis:
            if len(name) == 1 and name.isupper():
                sync = self.__dict__.get("_sync")
                if sync is not None:
                    with contextlib.suppress(InvalidArgument):
                        return self.axis(name)
            raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

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
    stop = twin(Controller.stop)
    abort = twin(Controller.abort)
    servo_here = twin(Controller.servo_here)
    motor_off = twin(Controller.motor_off)

    async def contour(
        self,
        axes: str,
        path: object,
        *,
        dt: int,
        progress: bool = False,
        timeout: float | None = None,
    ) -> ContourResult:
        """Run a contour path on ``axes`` (see ``Controller.contour``) and return when done.

        Cancelling the awaiting task stops the contour's axes (``ST``) before the
        cancellation ends; the stream then leaves contour mode on its thread.
        """
        future = self._worker.submit(
            self.sync.contour, axes, path, dt=dt, progress=progress, timeout=timeout
        )
        try:
            return await shielded(future)
        except asyncio.CancelledError:
            if not future.cancel():
                with contextlib.suppress(GalilError):
                    await self._worker.run_shielded(self.sync.stop, axes)
            raise

    @contextlib.asynccontextmanager
    async def motion(self, axes: str | None = None) -> AsyncIterator[None]:
        """A block in which an exception (cancellation included) stops the guarded axes
        (default all) and waits for them, as ``Controller.motion`` does."""
        guard = self.sync.motion(axes)
        guard.__enter__()
        try:
            yield
        except BaseException as exc:
            # The sync guard stops, waits and re-raises (or raises MotionError from exc).
            await self._worker.run_shielded(guard.__exit__, type(exc), exc, exc.__traceback__)
            raise
        else:
            guard.__exit__(None, None, None)

    # -- life cycle -------------------------------------------------------------------------
    async def aclose(self) -> None:
        """Close the sync controller (restoring what connect changed) and end the worker's
        threads; idempotent."""
        if self._worker.closed:
            return
        self._messages.close()
        self._unsubscribe()
        try:
            await self._worker.run_shielded(self.sync.close)
        finally:
            self._worker.close()

    async def __aenter__(self) -> AsyncController:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def __repr__(self) -> str:
        return f"<AsyncController of {self.sync!r}>"


def _close_stream(stream: Any) -> None:
    stream.close()


def _close_controller(controller: Controller, worker: Worker) -> None:
    try:
        controller.close()
    finally:
        worker.close()


async def connect(address: str | Transport, *, threads: int = 4, **options: Any) -> AsyncController:
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
    maxlen = options.get("max_messages", 1000)
    if isinstance(maxlen, bool) or not isinstance(maxlen, int) or maxlen < 1:
        raise InvalidArgument(f"max_messages must be a positive integer, not {maxlen!r}")
    loop = asyncio.get_running_loop()
    messages = AsyncMessages(loop, maxlen)
    worker = Worker(str(next(_names)), threads)
    future = worker.submit(_open, address, options, messages.deliver)
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
    return AsyncController(sync, worker, loop, messages, unsubscribe)


def _close_if_opened(
    future: concurrent.futures.Future[tuple[Controller, Callable[[], None]]], worker: Worker
) -> None:
    if future.cancelled() or future.exception() is not None:
        worker.close()
        return
    worker.submit(_close_controller, future.result()[0], worker)


def _open(
    address: str | Transport, options: dict[str, Any], deliver: Callable[[str], None]
) -> tuple[Controller, Callable[[], None]]:
    controller = connect_sync(address, **options)
    try:
        return controller, controller.subscribe(deliver)
    except BaseException:
        controller.close()
        raise
