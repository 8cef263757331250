"""ophyd-async devices for bluesky (the optional extra ``galil[bluesky]``).

:class:`GalilMotor` is one axis as a ``Movable``, ``Stoppable``, ``Locatable`` readable whose
``set()`` reports progress from the move's prediction (a progress bar knows the time left);
:class:`GalilContourFlyer` flies a contour path (checked and predicted at ``prepare``) and
collects the controller's data records as the scan's data, the prediction alongside::

    from bluesky import RunEngine
    from bluesky.plans import scan

    x = GalilMotor("tcp://192.168.0.2", "A", name="x", scale=2000 / ureg.mm)
    await x.connect()               # or init_devices(); connect(mock=True): a simulator
    RE(scan([det], x, 0, 10, 5))

Devices on the same address share one :class:`~galil.aio.AsyncController` per event loop;
:meth:`GalilMotor.disconnect` lets go of it (the last one closes it). Everything goes through
:mod:`galil.aio`, so the units, predictions and checks are the sync core's.
"""

from __future__ import annotations

import asyncio
import math
import numbers
import time
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from bluesky.protocols import (
    Checkable,
    Flyable,
    Locatable,
    Location,
    Preparable,
    Stoppable,
)
from event_model import DataKey
from event_model.documents.event import PartialEvent
from ophyd_async.core import (
    CALCULATE_TIMEOUT,
    AsyncStatus,
    CalculatableTimeout,
    Device,
    DeviceConnector,
    DeviceMock,
    NotConnectedError,
    StandardReadable,
    WatchableAsyncStatus,
    WatcherUpdate,
    soft_signal_r_and_setter,
)
from ophyd_async.core import StandardReadableFormat as Format

from galil.aio import AsyncAxis, AsyncController, AsyncMoveHandle, AsyncRecordStream
from galil.aio import connect as aio_connect
from galil.contour import ContourResult, ContourStream
from galil.controller import Controller
from galil.errors import InvalidArgument
from galil.link import check_count, check_flag, check_seconds, check_wait_timeout
from galil.motion import held
from galil.predict import Profile
from galil.units import Scale, get_registry, path_to_counts

__all__ = ["ContourPath", "GalilContourFlyer", "GalilMotor", "release_all"]

#: Model of the simulator a device connects to in mock mode (unless its address is sim://).
MOCK_MODEL = "DMC-4040"


# ----------------------------------------------------------------------------- connections


@dataclass
class _Shared:
    connecting: asyncio.Task[AsyncController]
    users: int = 0


_shared: dict[tuple[asyncio.AbstractEventLoop, str], _Shared] = {}


def _mock_address(address: str) -> str:
    return address if address.startswith("sim://") else f"sim://{MOCK_MODEL}"


async def _acquire(address: str, mock: bool) -> AsyncController:
    """The loop's controller at ``address`` (connected once, shared by its devices)."""
    loop = asyncio.get_running_loop()
    key = (loop, f"mock:{address}" if mock else address)
    entry = _shared.get(key)
    if entry is None or (entry.connecting.done() and _unusable(entry.connecting)):
        if entry is not None and _connected(entry.connecting):
            # (its sync side was closed directly: end its worker's threads too)
            await entry.connecting.result().aclose()
        target = _mock_address(address) if mock else address
        entry = _Shared(loop.create_task(aio_connect(target)))
        _shared[key] = entry
    entry.users += 1
    try:
        return await asyncio.shield(entry.connecting)
    except BaseException:
        entry.users -= 1
        if entry.connecting.done() and _shared.get(key) is entry:
            del _shared[key]
        raise


def _connected(task: asyncio.Task[AsyncController]) -> bool:
    """Whether ``task`` (done) connected a controller, closed since or not."""
    return not task.cancelled() and task.exception() is None


def _unusable(task: asyncio.Task[AsyncController]) -> bool:
    return not _connected(task) or task.result().closed


async def _release(controller: AsyncController) -> None:
    for key, entry in list(_shared.items()):
        done = entry.connecting.done() and not _unusable(entry.connecting)
        if done and entry.connecting.result() is controller:
            entry.users -= 1
            if entry.users > 0:
                return
            del _shared[key]
            break
    await controller.aclose()


async def release_all() -> None:
    """Close every controller the devices of this event loop share (end of a session)."""
    loop = asyncio.get_running_loop()
    for key, entry in list(_shared.items()):
        if key[0] is not loop:
            continue
        del _shared[key]
        if entry.connecting.done() and _connected(entry.connecting):
            # (aclose even if the sync side was closed directly: it ends the worker's threads)
            await entry.connecting.result().aclose()


class _GalilConnector(DeviceConnector):
    """Connects a device's controller, real or simulated, then its signals."""

    def __init__(self, address: str) -> None:
        self.address = address
        self.controller: AsyncController | None = None

    async def _attach(self, device: _GalilDevice, mock: bool) -> None:
        if self.controller is not None:
            await _release(self.controller)
            self.controller = None
        self.controller = await _acquire(self.address, mock)
        device._attached(self.controller)

    async def connect_real(self, device: Device, timeout: float, force_reconnect: bool) -> None:
        assert isinstance(device, _GalilDevice)
        await asyncio.wait_for(self._attach(device, mock=False), timeout)
        await super().connect_real(device, timeout, force_reconnect)

    async def connect_mock(self, device: Device, mock: DeviceMock[Any]) -> None:
        assert isinstance(device, _GalilDevice)
        await self._attach(device, mock=True)
        await super().connect_mock(device, mock)


class _GalilDevice(Device):
    """What GalilMotor and GalilContourFlyer share: the controller, and letting go of it."""

    _connector: _GalilConnector

    def _attached(self, controller: AsyncController) -> None:
        """The controller is connected: take what the device needs from it (no I/O)."""

    @property
    def controller(self) -> AsyncController:
        """The shared :class:`~galil.aio.AsyncController` (after ``connect()``).

        Raises:
            NotConnectedError: the device is not connected.
        """
        c = self._connector.controller
        if c is None or c.closed:
            raise NotConnectedError(f"{self.name or type(self).__name__} is not connected")
        return c

    async def disconnect(self) -> None:
        """Let go of the shared controller (closed when its last device lets go)."""
        c = self._connector.controller
        self._connector.controller = None
        if c is not None:
            await _release(c)


def _scale_of(counts_per: Any, offset: Any, sign: int) -> Scale | None:
    return None if counts_per is None else Scale(counts_per, offset, sign)


def _unit_and_precision(scale: Scale | None) -> tuple[str, int]:
    """The axis's unit and the decimals that show one count."""
    if scale is None:
        return "counts", 0
    per = float(scale.counts_per.magnitude)
    return f"{scale.unit:~}", max(0, math.ceil(math.log10(per) - 1e-9))


# ------------------------------------------------------------------------------------ motor


def _check_name(name: object) -> None:
    if not isinstance(name, str):
        raise InvalidArgument(f"a device's name is a string, not {name!r:.60}")


def _finite(value: Any) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an int no float holds
        return False


def _distance(value: object) -> float:
    """``in_position``: a finite number >= 0 in the axis's unit."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not _finite(value):
        raise InvalidArgument(f"in_position must be a finite number >= 0, not {value!r:.60}")
    if value < 0:
        raise InvalidArgument(f"in_position must be a finite number >= 0, not {value!r:.60}")
    return float(value)


def _watch_timeout(timeout: object) -> float | None:
    """``set()``'s timeout as :meth:`AsyncMoveHandle.watch` takes it: ``CALCULATE_TIMEOUT``
    is the watch's own default (``None``: the predicted duration plus a margin), ``None``
    for ever (1e9 s), anything else checked as every wait's (:func:`check_wait_timeout`).

    Raises:
        InvalidArgument: a bad timeout.
    """
    if isinstance(timeout, str) and timeout == CALCULATE_TIMEOUT:
        return None
    seconds = check_wait_timeout(timeout)
    return 1e9 if seconds is None else seconds


class GalilMotor(_GalilDevice, StandardReadable, Locatable[float], Checkable[float], Stoppable):
    """One Galil axis as an ophyd-async motor.

    Args:
        address: the controller's address (``tcp://...``, ``sim://DMC-4040`` ...).
        axis: the axis letter (or an alias such as ``"X"``).
        name: the device name (its readback is read under this name).
        scale: counts per user unit (``2000 / ureg.mm``); positions are then numbers in that
            unit. Without it they are counts.
        offset, sign: the rest of the axis's :class:`~galil.units.Scale`.
        in_position: after the profile ends, ``set()`` waits until the position error
            (``_TE``) is within this distance (the axis's unit; default one count) ...
        settle_timeout: ... or this many seconds have passed (then the readback reports
            where the axis really is): a finite number >= 0, checked as every wait's
            timeout (:func:`~galil.link.check_seconds`).

    Signals (in the axis's unit): ``readback`` (``_TP``, read under the device's name, with
    ``units`` and ``precision`` in ``describe()``), ``setpoint`` (the target of the ``set()``
    in progress, else the controller's commanded position ``_RP``: where the last move,
    made here or not, ended), and the configuration ``velocity`` (``SP``) and
    ``acceleration`` (``AC``).
    """

    def __init__(
        self,
        address: str,
        axis: str,
        name: str = "",
        *,
        scale: Any = None,
        offset: Any = None,
        sign: int = 1,
        in_position: float | None = None,
        settle_timeout: float = 0.5,
    ) -> None:
        if not isinstance(address, str) or not isinstance(axis, str) or not axis:
            raise InvalidArgument(f"GalilMotor takes an address and an axis letter, not {axis!r}")
        _check_name(name)
        self._letter = axis
        self._scale = _scale_of(scale, offset, sign)
        per = 1.0 if self._scale is None else float(self._scale.counts_per.magnitude)
        self._in_position = 1.0 if in_position is None else _distance(in_position) * per
        self._settle_timeout = check_seconds(settle_timeout, "settle_timeout")
        self._axis: AsyncAxis | None = None
        self._stopped: bool | None = None  # success flag of a stop() during set()
        self._moving_to: float | None = None  # the target of the set() in progress
        unit, precision = _unit_and_precision(self._scale)
        self._unit = unit
        self._precision = precision
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            self.readback, _ = soft_signal_r_and_setter(
                float, 0.0, units=unit, precision=precision, getter=self._read_position
            )
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.velocity, _ = soft_signal_r_and_setter(
                float, 0.0, units=f"{unit}/s", getter=self._read_speed
            )
            self.acceleration, _ = soft_signal_r_and_setter(
                float, 0.0, units=f"{unit}/s**2", getter=self._read_accel
            )
        # Read from the controller, as an ophyd-async EPICS motor reads its setpoint PV: a
        # cached last target would be wrong at connect and after a move made elsewhere.
        self.setpoint, _ = soft_signal_r_and_setter(
            float, 0.0, units=unit, precision=precision, getter=self._read_setpoint
        )
        super().__init__(name=name, connector=_GalilConnector(address))

    def set_name(self, name: str, *, child_name_separator: str | None = None) -> None:
        """Name the device; its readback is read under the device's own name."""
        super().set_name(name, child_name_separator=child_name_separator)
        self.readback.set_name(name)

    def _attached(self, controller: AsyncController) -> None:
        axis = controller.axis(self._letter)
        if self._scale is not None:
            s = self._scale
            axis.set_scale(s.counts_per, s.offset, s.sign)
        self._axis = axis

    @property
    def axis(self) -> AsyncAxis:
        """The :class:`~galil.aio.AsyncAxis` this motor moves (after ``connect()``)."""
        if self._axis is None or self._connector.controller is None:
            raise NotConnectedError(f"{self.name or 'GalilMotor'} is not connected")
        return self._axis

    # -- values in the user's unit --------------------------------------------------------
    def _user(self, value: Any) -> float:
        return float(value.m_as(self._scale.unit)) if self._scale is not None else float(value)

    def _rate(self, value: Any, power: int) -> float:
        if self._scale is None:
            return float(value)
        return float(value.m_as(self._scale.unit / get_registry().s ** power))

    def _target(self, value: object) -> Any:
        """``value`` as the axis takes it (any real number, numpy's included; not a bool)."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            unit = "counts" if self._scale is None else f"{self._scale.unit:~}"
            raise InvalidArgument(
                f"{self.name}: a position is a number (in {unit}, the motor's unit), not "
                f"{value!r:.60}"
            )
        if not _finite(value):  # (an int no float holds, 10**400: the setpoint is a float)
            raise InvalidArgument(f"{self.name}: a position is a finite number, not {value!r:.40}")
        number = int(value) if isinstance(value, numbers.Integral) else float(value)
        if self._scale is None:
            return number
        return get_registry().Quantity(float(number), self._scale.unit)

    async def _read_position(self) -> float:
        return self._user(await self.axis.position())

    async def _read_speed(self) -> float:
        return self._rate(await self.axis.speed(), 1)

    async def _read_accel(self) -> float:
        return self._rate(await self.axis.accel(), 2)

    async def _read_setpoint(self) -> float:
        if self._moving_to is not None:
            return self._moving_to
        return self._user(await self.axis.reference_position())

    # -- Movable, Checkable, Locatable, Stoppable ---------------------------------------------
    def set(
        self, value: float, timeout: CalculatableTimeout = "CALCULATE_TIMEOUT"
    ) -> WatchableAsyncStatus[float]:
        """Move to ``value`` (the axis's unit); progress comes from the move's prediction.

        ``timeout``: the default allows the predicted duration with a margin; ``None`` waits
        for ever; else a finite number of seconds >= 0, as every wait's (a bad one fails the
        status with :class:`~galil.errors.InvalidArgument` before anything is sent). A status
        that fails (a timeout, an error, a cancellation) leaves no motion: the axis is stopped
        first. A ``stop()`` at any point of the move, even before it has started, stops it;
        with ``success=False`` the status then fails.
        """
        self._stopped = None  # from the call on, not once the move's task runs: stop() counts
        return self._move(value, timeout)

    @WatchableAsyncStatus.wrap
    async def _move(
        self, value: float, timeout: CalculatableTimeout
    ) -> AsyncIterator[WatcherUpdate[float]]:
        axis = self.axis
        target = self._target(value)
        wait = _watch_timeout(timeout)
        initial = await self.readback.get_value()
        if not self._stop_requested():  # else stopped before the move began: it never does
            self._moving_to = float(value)
            try:
                handle = await axis.move_to(target)
                try:
                    if self._stop_requested():  # stop() came while the move was starting
                        await handle.stop()
                    async for update in self._progress(handle, float(value), initial, wait):
                        yield update
                    await handle.wait()
                except BaseException:
                    await handle.stop_unless_done()  # motion never outlives a failed status
                    raise
            finally:
                self._moving_to = None
            await self._settle()
            yield self._update(await self.readback.get_value(), initial, float(value), 1.0, 0.0)
        if self._stopped is False:
            raise RuntimeError(f"{self.name} was stopped")

    def _stop_requested(self) -> bool:
        """Whether ``stop()`` was called since the last ``set()`` (read again after awaits)."""
        return self._stopped is not None

    async def _progress(
        self, handle: AsyncMoveHandle, value: float, initial: float, wait: float | None
    ) -> AsyncIterator[WatcherUpdate[float]]:
        """The predicted progress of ``handle`` until it is done (or ``wait`` s pass)."""
        letter = handle.axes[0]
        async for p in handle.watch(wait):
            current = p.positions.get(letter, initial)
            yield self._update(current, initial, value, p.fraction, p.remaining, p.elapsed)

    def _update(
        self,
        current: float,
        initial: float,
        target: float,
        fraction: float | None,
        left: float,
        elapsed: float | None = None,
    ) -> WatcherUpdate[float]:
        return WatcherUpdate(
            current=current,
            initial=initial,
            target=target,
            name=self.name,
            unit=self._unit,
            precision=self._precision,
            fraction=fraction,
            time_elapsed=elapsed,
            time_remaining=left,
        )

    async def _settle(self) -> None:
        """Wait (briefly) for the servo to bring the encoder onto the reference."""
        c = self.controller
        query = [f"_TE{self.axis.letter}"]
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self._settle_timeout
        while loop.time() < deadline:
            if abs((await c.query_operands(query))[0]) <= self._in_position:
                break
            await c.sleep(0.002)

    async def check_value(self, value: float) -> None:
        """Refuse a target the move would be refused for (soft limits, ranges); no motion."""
        await self.axis.plan_to(self._target(value))

    async def locate(self) -> Location[float]:
        """Where the motor is going (a ``set()`` in progress) or was commanded to (``_RP``),
        and where it is (``_TP``)."""
        setpoint, readback = await asyncio.gather(
            self.setpoint.get_value(), self.readback.get_value()
        )
        return Location(setpoint=setpoint, readback=readback)

    async def stop(self, success: bool = True) -> None:
        """Decelerate to a stop (``ST``); with ``success=False`` a move in progress fails."""
        self._stopped = check_flag(success, "success")
        await self.axis.stop()


# ----------------------------------------------------------------------------------- flyer


@dataclass(frozen=True)
class ContourPath:
    """What :meth:`GalilContourFlyer.prepare` takes.

    Attributes:
        path: ideal positions relative to where the axes are, one per ``2**dt``-sample segment
            (shape (segments,) or (segments, axes)); a pint Quantity array in the axes' unit,
            or counts.
        dt: the DT exponent.
        record_period: servo samples between data records (default: one per segment).
    """

    path: Any
    dt: int
    record_period: int | None = None


@dataclass
class _Flight:
    """One fly scan's state from prepare to collect."""

    stream: ContourStream
    record_period: int
    run: asyncio.Task[ContourResult] | None = None
    records: AsyncRecordStream | None = None
    reader: asyncio.Task[None] | None = None
    start_sample: int = 0
    start_time: float = 0.0
    recorded: list[np.void] = field(default_factory=list)
    result: ContourResult | None = None
    points: dict[str, npt.NDArray[Any]] = field(default_factory=dict)


def _build_stream(
    controller: Controller, letters: str, path: object, dt: int
) -> tuple[ContourStream, dict[str, Profile]]:
    """Worker side: the stream ``Controller.contour`` would run, checked and predicted, on the
    controller's motion tracker (:func:`_fly` runs it as ``Controller.contour`` does)."""
    chosen = [controller.axis(a) for a in letters]
    counts = path_to_counts(path, [a.scale for a in chosen], letters)
    tracker = controller.tracker
    stream = ContourStream(
        controller.link,
        letters,
        counts,
        dt=dt,
        display={a.letter: a.display for a in chosen},
        byte_rate=controller.link.byte_rate,
        followers=tracker.followers(letters),
        tracker=tracker,
    )
    stream.check()
    with held(tracker):  # (a plan: the flight reads the state again before CM)
        stream.prepare()
    return stream, dict(stream.profiles)


def _fly(stream: ContourStream) -> ContourResult:
    """Worker side: the flight, as ``Controller.contour`` runs a contour (decisions 0023,
    0024): the state read again and ``CM`` under the tracker's lock, so another thread's
    motion takes turns with it (the axes may have moved since ``prepare()``), and a
    :class:`~galil.motion.StopWatch` open while it streams, so ``stop()``, ``abort()`` and
    ``Controller.close()`` reach it (``ST``, and no ``CD`` after it)."""
    return stream.run()


class GalilContourFlyer(_GalilDevice, Preparable, Flyable, Stoppable):
    """A contour path on one or more axes as a bluesky flyer.

    ``prepare(ContourPath(...))`` checks and predicts the path (nothing moves), ``kickoff()``
    starts the data records and the contour, ``complete()`` waits for the end, and
    ``collect()`` yields one event per data record taken during the path: the recorded
    reference and encoder positions per axis, and the predicted position at the same sample.

    Args:
        address: the controller's address (shared with the motors on it).
        axes: the contour axes, in the order of the path's columns (``"AB"``).
        name: the device name (also the name of the event stream).
        scales: counts per user unit per axis, for axes no motor has scaled.
    """

    def __init__(
        self,
        address: str,
        axes: str,
        name: str = "",
        *,
        scales: Mapping[str, Any] | None = None,
    ) -> None:
        if not isinstance(address, str):
            raise InvalidArgument(f"GalilContourFlyer takes an address, not {address!r:.60}")
        if not isinstance(axes, str) or not axes:
            raise InvalidArgument(f"axes is a string of axis letters, not {axes!r}")
        _check_name(name)
        if scales is not None and not isinstance(scales, Mapping):
            raise InvalidArgument(f"scales must map axis letters to scales, not {scales!r:.60}")
        for per in (scales or {}).values():
            Scale(per)  # refused here, not at connect()
        self._axes_given = axes
        self._scales = dict(scales or {})
        self._letters = ""
        self._flight: _Flight | None = None
        super().__init__(name=name, connector=_GalilConnector(address))

    def _attached(self, controller: AsyncController) -> None:
        letters = "".join(controller.axis(a).letter for a in self._axes_given)
        for a, per in self._scales.items():
            controller.axis(a).set_scale(per)
        self._letters = letters

    @property
    def axes(self) -> str:
        """The contour axes (letters, after ``connect()``)."""
        return self._letters or self._axes_given

    def _stream_name(self) -> str:
        return self.name or "contour"

    def _key(self, letter: str, what: str) -> str:
        return f"{self.name or 'contour'}-{letter}-{what}"

    @AsyncStatus.wrap
    async def prepare(self, value: ContourPath) -> None:
        """Check the path and predict it from where the axes are (one state query)."""
        if not isinstance(value, ContourPath):
            raise InvalidArgument(f"prepare takes a ContourPath, not {value!r}")
        period = value.record_period
        if period is not None and not 1 <= check_count(period, "record_period") <= 65535:
            # as the records of kickoff() would refuse it, but before the path is prepared
            raise InvalidArgument(f"record_period is a number of samples 1..65535, not {period!r}")
        c = self.controller
        stream, _ = await c.run(_build_stream, c.sync, self._letters, value.path, value.dt)
        period = value.record_period or (1 << value.dt)
        self._flight = _Flight(stream, period)

    @property
    def predicted(self) -> dict[str, Profile]:
        """The predicted profile per axis of the prepared path (in the axes' units)."""
        if self._flight is None:
            raise RuntimeError(f"{self.name}: prepare() first")
        return dict(self._flight.stream.profiles)

    @AsyncStatus.wrap
    async def kickoff(self) -> None:
        """Start the data records, then the contour; done once both are under way.

        The contour runs as ``Controller.contour`` runs one: its axes' state is read again
        (they may have moved since ``prepare()``) and checked, and motion from other threads
        takes turns with its start; ``stop()``, a stop through the controller and ``close()``
        stop it.
        """
        flight = self._flight
        if flight is None or flight.run is not None:
            raise RuntimeError(f"{self.name}: prepare() must come before kickoff()")
        c = self.controller
        flight.records = await c.records(flight.record_period)
        flight.start_sample = round((await c.query_operands(["TIME"]))[0])
        flight.start_time = time.time()
        flight.reader = asyncio.get_running_loop().create_task(self._read(flight))
        flight.run = asyncio.get_running_loop().create_task(self._run(flight))

    async def _run(self, flight: _Flight) -> ContourResult:
        c = self.controller
        try:
            return await c.run(_fly, flight.stream)
        except asyncio.CancelledError:
            await c.stop(self._letters)
            raise

    async def _read(self, flight: _Flight) -> None:
        records = flight.records
        assert records is not None
        async for rec in records:
            flight.recorded.append(rec)

    @AsyncStatus.wrap
    async def complete(self) -> None:
        """Wait for the end of the path, stop the records and line them up with the
        prediction."""
        flight = self._flight
        if flight is None or flight.run is None:
            raise RuntimeError(f"{self.name}: kickoff() must come before complete()")
        try:
            flight.result = await flight.run
            end = round((await self.controller.query_operands(["TIME"]))[0])
            await self._stop_records(flight, end)
        finally:
            await self._stop_records(flight, None)
        flight.points = await self.controller.run(
            _line_up, flight.recorded, flight.stream.profiles, self._letters, flight.start_sample
        )

    async def _stop_records(self, flight: _Flight, until: int | None) -> None:
        records, reader = flight.records, flight.reader
        if records is None or reader is None or records.closed:
            return
        if until is not None:
            # Let the reader take every record up to the end sample before closing.
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline and not _past(flight, until):
                await asyncio.sleep(0.01)
        reader.cancel()
        await asyncio.gather(reader, return_exceptions=True)
        await records.close()

    def describe_collect(self) -> dict[str, dict[str, DataKey]]:
        """One stream (named after the device): per axis the recorded reference and encoder
        positions and the predicted position, in the axis's unit; and the sample number."""
        keys: dict[str, DataKey] = {
            f"{self._stream_name()}-sample": DataKey(dtype="integer", shape=[], source="TIME")
        }
        profiles = {} if self._flight is None else self._flight.stream.profiles
        for a in self._letters:
            p = profiles.get(a)
            unit = p.display[2] if p is not None and p.display is not None else "counts"
            for what, source in (
                ("reference", "record _RP"),
                ("position", "record _TP"),
                ("predicted", "galil.predict"),
            ):
                keys[self._key(a, what)] = DataKey(
                    dtype="number", shape=[], source=source, units=unit
                )
        return {self._stream_name(): keys}

    async def collect(self) -> AsyncIterator[PartialEvent]:
        """One partial event per data record taken during the path."""
        flight = self._flight
        if flight is None or not flight.points:
            return
        points = flight.points
        ts = self.controller.sample_period
        name = self._stream_name()
        for i, sample in enumerate(points["sample"].tolist()):
            t = flight.start_time + (sample - flight.start_sample) * ts
            data: dict[str, Any] = {f"{name}-sample": sample}
            for a in self._letters:
                for what in ("reference", "position", "predicted"):
                    data[self._key(a, what)] = float(points[f"{a}-{what}"][i])
            yield PartialEvent(data=data, timestamps=dict.fromkeys(data, t), time=t)

    async def stop(self, success: bool = True) -> None:
        """Stop the contour's axes (``ST``); the flight then fails."""
        check_flag(success, "success")
        flight = self._flight
        if flight is not None and flight.run is not None and not flight.run.done():
            flight.run.cancel()
            await asyncio.gather(flight.run, return_exceptions=True)
        else:
            await self.controller.stop(self._letters)


def _in_unit(profile: Profile, counts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    per, offset, _ = profile.display if profile.display is not None else (1.0, 0.0, "")
    return counts / per + offset


def _past(flight: _Flight, sample: int) -> bool:
    if not flight.recorded:
        return False
    last = int(flight.recorded[-1]["sample"])
    return (last - sample) % 65536 < 32768


def _line_up(
    recorded: list[np.void], profiles: Mapping[str, Profile], letters: str, start: int
) -> dict[str, npt.NDArray[Any]]:
    """Worker side: the records taken during the path, with the prediction at each sample.

    ``TIME`` was read before the contour began (``start``); the sample the path began at is
    the one that makes the recorded reference positions match the prediction best (they are
    the profiler's own values, so it is exact on a controller that follows the prediction).
    """
    if not recorded:
        return {}
    base = start - 4096  # records a little older than the TIME stamp unwrap correctly too
    raw = np.array([int(r["sample"]) for r in recorded], dtype=np.int64)
    samples = base + np.mod(raw - base, 65536)
    first = letters[0]
    ref = np.array([int(r[first]["reference"]) for r in recorded], dtype=np.int64)
    begin = _best_begin(samples, ref, profiles[first].position, start)
    n = profiles[first].samples
    # The path, and the last record before it and the first after it (start and end held).
    before, after = samples[samples <= begin], samples[samples >= begin + n]
    low = int(before.max()) if before.size else begin
    high = int(after.min()) if after.size else begin + n
    inside = (samples >= low) & (samples <= high)
    out: dict[str, npt.NDArray[Any]] = {"sample": samples[inside]}
    for a in letters:
        p = profiles[a]
        k = np.clip(samples[inside] - begin, 0, p.samples)
        refs = np.array([int(r[a]["reference"]) for r in recorded], dtype=np.float64)[inside]
        enc = np.array([int(r[a]["position"]) for r in recorded], dtype=np.float64)[inside]
        out[f"{a}-reference"] = _in_unit(p, refs)
        out[f"{a}-position"] = _in_unit(p, enc)
        out[f"{a}-predicted"] = _in_unit(p, p.position[k].astype(np.float64))
    out["begin"] = np.array([begin])
    return out


def _best_begin(
    samples: npt.NDArray[np.int64],
    ref: npt.NDArray[np.int64],
    predicted: npt.NDArray[np.int64],
    start: int,
) -> int:
    moved = np.nonzero(ref != ref[0])[0]
    last = int(samples[moved[0]]) if moved.size else start
    candidates = np.arange(start, max(start, last) + 1, dtype=np.int64)[-20_000:]
    best, best_cost = start, None
    for b in candidates.tolist():
        k = np.clip(samples - b, 0, predicted.size - 1)
        cost = int(np.max(np.abs(predicted[k] - ref)))
        if best_cost is None or cost < best_cost:
            best, best_cost = b, cost
            if cost == 0:
                break
    return best
