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

Devices on the same address share one :class:`~galil.aio.AsyncController` per event loop, and
its axes' scales: a device whose scale differs from the one an axis already has is refused at
``connect()``. :meth:`GalilMotor.disconnect` stops the moves of its ``set()`` calls in
progress and lets go of the controller (the last one closes it); ``connect()`` after it, or
after :func:`release_all`, connects again. Everything goes through :mod:`galil.aio`, so the
units, predictions and checks are the sync core's.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
import numbers
import time
import weakref
from collections.abc import AsyncGenerator, AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from bluesky.protocols import (
    Checkable,
    Flyable,
    Locatable,
    Location,
    Pausable,
    Preparable,
    Reading,
    Stageable,
    Stoppable,
)
from event_model import DataKey
from event_model.documents.event import PartialEvent
from ophyd_async.core import (
    CALCULATE_TIMEOUT,
    DEFAULT_TIMEOUT,
    AsyncStatus,
    CalculatableTimeout,
    Callback,
    Device,
    DeviceConnector,
    DeviceMock,
    NotConnectedError,
    SignalR,
    SignalRW,
    SoftSignalBackend,
    StandardReadable,
    WatchableAsyncStatus,
    WatcherUpdate,
)
from ophyd_async.core import StandardReadableFormat as Format

from galil.aio import AsyncAxis, AsyncController, AsyncMoveHandle, AsyncRecordStream
from galil.aio import connect as aio_connect
from galil.aio._motion import Starting
from galil.aio._worker import shielded
from galil.axis import Axis, user_units
from galil.contour import ContourResult, ContourStream
from galil.controller import Controller, contour_stream
from galil.errors import (
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    MotionError,
    decimal_hint,
)
from galil.link import check_count, check_flag, check_seconds, check_wait_timeout
from galil.motion import held
from galil.predict import Profile
from galil.predict.profile import shown_position
from galil.protocol import commands as cmds
from galil.protocol.records import RecordSplitter, decode_records
from galil.records import RecordStream
from galil.units import Amounts, QuantityLike, Scale, get_registry

if TYPE_CHECKING:
    from galil.sim import SimController

__all__ = ["POLL_PERIOD", "ContourPath", "GalilContourFlyer", "GalilMotor", "release_all"]

#: Model of the simulator a device connects to in mock mode (unless its address is sim://).
MOCK_MODEL = "DMC-4040"

#: Seconds between reads of a motor's ``readback`` and ``setpoint`` while something is
#: subscribed to them (``bps.monitor``, ``observe_value``, ``wait_for_value``): one query
#: each a poll, and none when nothing is subscribed.
POLL_PERIOD = 0.1


# ----------------------------------------------------------------------------- connections


@dataclass
class _Shared:
    connecting: asyncio.Task[AsyncController]
    users: int = 0


_shared: dict[tuple[asyncio.AbstractEventLoop, str], _Shared] = {}
_motors: weakref.WeakSet[GalilMotor] = weakref.WeakSet()  # (release_all() stops their moves)


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
        if entry.users == 0 and not entry.connecting.done():
            # Nobody waits for it any more (a connect's timeout, a cancellation): cancelled,
            # galil.aio.connect closes the connection should it still be made.
            entry.connecting.cancel()
        if _shared.get(key) is entry and (entry.connecting.done() or entry.users == 0):
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
    """Close every controller the devices of this event loop share (end of a session).

    The moves of motors' ``set()`` calls in progress are stopped first, and their statuses
    end (failed, saying so) once the axes are at rest. A device's ``connect()`` after it
    connects again (a new connection)."""
    loop = asyncio.get_running_loop()
    closing = [
        entry.connecting.result()
        for key, entry in _shared.items()
        if key[0] is loop and entry.connecting.done() and not _unusable(entry.connecting)
    ]
    for motor in list(_motors):
        if any(motor._connector.controller is c for c in closing):
            await motor._end_moves("release_all()")
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
        controller = await _acquire(self.address, mock)
        try:
            device._attached(controller)
        except BaseException:
            await _release(controller)  # (refused: the device holds nothing)
            raise
        self.controller = controller

    async def connect_real(self, device: Device, timeout: float, force_reconnect: bool) -> None:
        """Connect (``timeout`` s at most for the controller) then the signals.

        Raises:
            GalilTimeoutError: no connection within ``timeout`` (the attempt is given up:
                a connection made after it is closed).
        """
        assert isinstance(device, _GalilDevice)
        try:
            await asyncio.wait_for(self._attach(device, mock=False), timeout)
        except asyncio.TimeoutError as exc:
            if isinstance(exc, GalilError):  # (the link's own, from inside)
                raise
            raise GalilTimeoutError(
                f"{device.name or type(device).__name__}: no connection to the controller at "
                f"{self.address} within {timeout:g} s (connect(timeout=...)): the link did "
                "not open or the controller did not answer; the attempt was given up"
            ) from None
        await super().connect_real(device, timeout, force_reconnect)

    async def connect_mock(self, device: Device, mock: DeviceMock[Any]) -> None:
        assert isinstance(device, _GalilDevice)
        await self._attach(device, mock=True)
        await super().connect_mock(device, mock)


class _GalilDevice(Device):
    """What GalilMotor and GalilContourFlyer share: the controller, and letting go of it."""

    _connector: _GalilConnector

    def _attached(self, controller: AsyncController) -> None:
        """The controller is connected: take what the device needs from it (no I/O).

        Raises:
            InvalidArgument: the device cannot use this controller as it is (a scale).
        """

    def _not_connected(self) -> NotConnectedError:
        return NotConnectedError(
            f"{self.name or type(self).__name__} is not connected: await its connect() "
            "(again after disconnect() or galil.bluesky.release_all())"
        )

    @property
    def _live(self) -> bool:
        c = self._connector.controller
        return c is not None and not c.closed

    @property
    def controller(self) -> AsyncController:
        """The shared :class:`~galil.aio.AsyncController` (after ``connect()``).

        Raises:
            NotConnectedError: the device is not connected.
        """
        c = self._connector.controller
        if c is None or c.closed:
            raise self._not_connected()
        return c

    async def connect(
        self,
        mock: bool | DeviceMock[Any] = False,
        timeout: float = DEFAULT_TIMEOUT,
        force_reconnect: bool = False,
    ) -> None:
        """Connect the device (see ophyd-async's ``Device.connect``). After
        :meth:`disconnect`, :func:`release_all` or its controller's close, it connects
        again: ophyd-async would return at once, remembering the earlier connect."""
        earlier = self._connect_task
        if not mock and earlier is not None and earlier.done() and not self._live:
            force_reconnect = True
        await super().connect(mock, timeout, force_reconnect)

    async def disconnect(self) -> None:
        """Let go of the shared controller (closed when its last device lets go);
        ``connect()`` connects again."""
        c = self._connector.controller
        self._connector.controller = None
        if c is not None:
            await _release(c)


def _scale_of(
    counts_per: QuantityLike | None, offset: QuantityLike | None, sign: int
) -> Scale | None:
    """A motor's scale; ``offset`` and ``sign`` only with ``counts_per`` (they would be
    dropped silently on an axis counted in counts).

    Raises:
        InvalidArgument: a bad scale, or an offset or a sign without one.
    """
    if counts_per is not None:
        return Scale(counts_per, offset, sign)
    if offset is not None or not _plain_sign(sign):
        raise InvalidArgument(
            f"offset and sign belong to a scale: give scale= too (got offset={offset!r:.40}, "
            f"sign={sign!r:.40}, no scale: positions in counts)"
        )
    return None


def _plain_sign(sign: object) -> bool:
    """Whether ``sign`` is the default +1 (an int; not True)."""
    return not isinstance(sign, bool) and isinstance(sign, numbers.Integral) and sign == 1


def _same_scale(a: Scale, b: Scale) -> bool:
    """Whether two scales map positions onto the same counts (units may differ)."""
    try:
        per = float(b.counts_per.m_as(a.counts_per.units))
        offset = float(b.offset.m_as(a.offset.units))
    except Exception:  # (pint: another dimension; an angle for a length)
        return False
    close = functools.partial(math.isclose, rel_tol=1e-12, abs_tol=1e-12)
    same = close(per, float(a.counts_per.magnitude))
    return same and a.sign == b.sign and close(offset, float(a.offset.magnitude))


def _claim_scale(axis: AsyncAxis, scale: Scale | None, device: str) -> None:
    """Give the shared ``axis`` the device's ``scale``; refuse a device whose scale is not
    the one the axis already has (another device on the address gave it: it would change
    what that device's numbers mean). A device without a scale (counts) needs an axis
    without one.

    Raises:
        InvalidArgument: the axis has another scale, or one and the device none.
    """
    have = axis.scale
    if have is None:
        if scale is not None:
            axis.set_scale(scale.counts_per, scale.offset, scale.sign)
        return
    if scale is not None and _same_scale(have, scale):
        return
    wanted = "no scale (counts)" if scale is None else f"scale {_scale_text(scale)}"
    raise InvalidArgument(
        f"{device}: axis {axis.letter} already has the scale {_scale_text(have)}, given by "
        f"another device on this address; this one asks for {wanted}. Devices on one "
        "controller share its axes' scales: give them all the same one"
    )


def _scale_text(scale: Scale) -> str:
    text = f"{scale.counts_per:~}"
    if float(scale.offset.magnitude):
        text += f", offset {scale.offset:~}"
    return text + (", sign -1" if scale.sign < 0 else "")


def _unit_and_precision(scale: Scale | None) -> tuple[str, int]:
    """The axis's unit and the decimals that show one count."""
    if scale is None:
        return "counts", 0
    per = float(scale.counts_per.magnitude)
    return f"{scale.unit:~}", max(0, math.ceil(math.log10(per) - 1e-9))


class _ControllerBackend(SoftSignalBackend[float]):
    """A signal whose value is read from the controller (``getter``) on every read, and
    whose ``source`` names what is read (``galil://<address>/_TPA``), not ``soft://``.

    A subscriber's first value is read from the controller too (a soft backend would give
    it the value cached at the last read: 0.0 before any), then one every ``poll`` seconds
    while it is subscribed (none without ``poll``). With a ``setter`` the signal is
    writable: ``put`` sets the controller, then reads it back. Nothing else sets the value:
    ``set_mock_value`` (mock mode is a simulator, read as the controller) is refused.
    """

    def __init__(
        self,
        source: Callable[[], str],
        getter: Callable[[], Awaitable[float]],
        *,
        setter: Callable[[float], Awaitable[None]] | None = None,
        poll: float | None = None,
        units: str,
        precision: int | None = None,
    ) -> None:
        self._source = source
        self._read = getter
        self._write = setter
        self._period = poll
        self._follower: asyncio.Task[None] | None = None
        self._written: float | None = None
        super().__init__(float, 0.0, units=units, precision=precision)

    def source(self, name: str, read: bool) -> str:
        return self._source()

    def set_value(self, value: float) -> None:
        """Refused once constructed: the value is the controller's (``set_mock_value``)."""
        if getattr(self, "reading", None) is None:  # (the soft backend's own first value)
            super().set_value(value)
            return
        raise InvalidArgument(
            f"{self._source()} is read from the controller (in mock mode an in-process "
            "simulator): set_mock_value cannot set it; move or set the simulated axis "
            "instead (the motor's set(), its velocity signal, or motor.axis)"
        )

    def show(self, value: float) -> None:
        """Give the subscribers ``value`` (what the controller holds)."""
        SoftSignalBackend.set_value(self, value)

    async def _fresh(self) -> None:
        self.show(await self._read())

    async def get_reading(self) -> Reading[float]:
        await self._fresh()
        return self.reading

    async def get_value(self) -> float:
        await self._fresh()
        return self.reading["value"]

    async def get_setpoint(self) -> float:
        return self._written if self._written is not None else await self.get_value()

    async def put(self, value: float | None) -> None:
        if self._write is None:
            raise InvalidArgument(f"{self._source()} is read-only")
        if value is None:
            raise InvalidArgument(f"{self._source()}: a value to set, not None")
        await self._write(value)
        self._written = float(value)
        await self._fresh()

    def set_callback(self, callback: Callback[Reading[float]] | None) -> None:
        if callback is not None and self.callback is not None:
            raise RuntimeError("Cannot set a callback when one is already set")
        if self._follower is not None:
            self._follower.cancel()
            self._follower = None
        self.callback = callback
        if callback is not None:
            self._follower = asyncio.get_running_loop().create_task(self._follow())

    async def _follow(self) -> None:
        """A subscription: the controller's value now, then every ``poll`` seconds (a read
        that fails is tried again a poll later, as ophyd-async's polls are)."""
        while True:
            try:
                await self._fresh()
            except Exception:
                pass
            else:
                if self._period is None:
                    return
            await asyncio.sleep(self._period or POLL_PERIOD)


def _controller_signal(
    source: Callable[[], str],
    getter: Callable[[], Awaitable[float]],
    *,
    units: str,
    precision: int | None = None,
    poll: float | None = None,
) -> tuple[SignalR[float], _ControllerBackend]:
    """A read-only signal read from the controller, and its backend (whose ``show`` gives
    its subscribers a value); ``poll``: seconds between reads while something is
    subscribed."""
    backend = _ControllerBackend(source, getter, units=units, precision=precision, poll=poll)
    return SignalR(backend=backend), backend


def _setting_signal(
    source: Callable[[], str],
    getter: Callable[[], Awaitable[float]],
    setter: Callable[[float], Awaitable[None]],
    *,
    units: str,
) -> SignalRW[float]:
    """A writable signal of a controller setting (``SP``, ``AC``, ``DC``)."""
    return SignalRW(backend=_ControllerBackend(source, getter, setter=setter, units=units))


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
        raise InvalidArgument(
            f"in_position must be a finite number >= 0, not {value!r:.60}{decimal_hint(value)}"
        )
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


class _MoveStatus(WatchableAsyncStatus[float]):
    """A ``set()``'s status. A watcher that raises (``status.watch(cb)``) ends the status's
    loop over the move's updates, and ophyd-async leaves that generator suspended at its
    ``yield`` (closed only when collected): here it is closed first, so its guard stops the
    axis, at rest before the status fails with the watcher's error."""

    async def _notify_watchers_from(self, iterator: AsyncIterator[WatcherUpdate[float]]) -> None:
        try:
            await super()._notify_watchers_from(iterator)
        finally:
            aclose = getattr(iterator, "aclose", None)  # (the move's async generator has one)
            if aclose is not None:
                await aclose()


@dataclass
class _Request:
    """One ``set()`` call, from the call to the end of its status."""

    target: float | None = None  # the target, once the controller has taken the move
    stopped: bool | None = None  # the success flag of a stop() since the call
    by: str = "stop(success=False)"  # what stopped it, when the status fails for a stop
    handle: AsyncMoveHandle | None = None  # the move, once the controller has taken it
    status: WatchableAsyncStatus[float] | None = None


class GalilMotor(_GalilDevice, StandardReadable, Locatable[float], Checkable[float], Stoppable):
    """One Galil axis as an ophyd-async motor.

    Args:
        address: the controller's address (``tcp://...``, ``sim://DMC-4040`` ...).
        axis: the axis letter (or an alias such as ``"X"``).
        name: the device name (its readback is read under this name).
        scale: counts per user unit (``2000 / ureg.mm``); positions are then numbers in that
            unit. Without it they are counts. Devices on one address share the axis's scale:
            one that differs from the scale the axis already has is refused at connect.
        offset, sign: the rest of the axis's :class:`~galil.units.Scale` (with ``scale``
            only: without one they are refused).
        in_position: after the profile ends, ``set()`` waits until the position error
            (``_TE``) is within this distance (the axis's unit; default one count) ...
        settle_timeout: ... or this many seconds have passed (then the readback reports
            where the axis really is): a finite number >= 0, checked as every wait's
            timeout (:func:`~galil.link.check_seconds`).

    Signals (in the axis's unit): ``readback`` (``_TP``, read under the device's name, with
    ``units`` and ``precision`` in ``describe()``), ``setpoint`` (the target of the ``set()``
    in progress, else the controller's commanded position ``_RP``: where the last move,
    made here or not, ended), and the configuration ``velocity`` (``SP``), ``acceleration``
    (``AC``) and ``deceleration`` (``DC``), which a plan can set (``bps.mv(m.velocity, 5)``;
    checked by the axis's setters, in the motor's unit per second or second squared). Every
    read reads the controller, a subscriber's first value too; ``readback`` and ``setpoint``
    then every :data:`POLL_PERIOD` seconds while something is subscribed to them
    (``bps.monitor``, ``observe_value``). In mock mode they read the simulator:
    ``set_mock_value`` on them raises :class:`~galil.errors.InvalidArgument`.

    Raises:
        InvalidArgument: a bad argument (at construction); a scale other than the one
            another device on the address gave the axis (at ``connect()``).
    """

    def __init__(
        self,
        address: str,
        axis: str,
        name: str = "",
        *,
        scale: QuantityLike | None = None,
        offset: QuantityLike | None = None,
        sign: int = 1,
        in_position: float | None = None,
        settle_timeout: float = 0.5,
    ) -> None:
        if not isinstance(address, str) or not isinstance(axis, str) or not axis:
            raise InvalidArgument(f"GalilMotor takes an address and an axis letter, not {axis!r}")
        _check_name(name)
        self._address = address
        self._letter = axis
        self._scale = _scale_of(scale, offset, sign)
        per = 1.0 if self._scale is None else float(self._scale.counts_per.magnitude)
        self._in_position = 1.0 if in_position is None else _distance(in_position) * per
        self._settle_timeout = check_seconds(settle_timeout, "settle_timeout")
        self._axis: AsyncAxis | None = None
        self._requests: list[_Request] = []  # the set() calls whose status is not done
        unit, precision = _unit_and_precision(self._scale)
        self._unit = unit
        self._precision = precision
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            self.readback, _ = _controller_signal(
                self._source("TP"),
                self._read_position,
                units=unit,
                precision=precision,
                poll=POLL_PERIOD,
            )
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.velocity = _setting_signal(
                self._source("SP"), self._read_speed, self._set_speed, units=f"{unit}/s"
            )
            self.acceleration = _setting_signal(
                self._source("AC"), self._read_accel, self._set_accel, units=f"{unit}/s**2"
            )
            self.deceleration = _setting_signal(
                self._source("DC"), self._read_decel, self._set_decel, units=f"{unit}/s**2"
            )
        # Read from the controller, as an ophyd-async EPICS motor reads its setpoint PV: a
        # cached last target would be wrong at connect and after a move made elsewhere.
        self.setpoint, self._setpoint_backend = _controller_signal(
            self._source("RP"),
            self._read_setpoint,
            units=unit,
            precision=precision,
            poll=POLL_PERIOD,
        )
        super().__init__(name=name, connector=_GalilConnector(address))

    def _source(self, operand: str) -> Callable[[], str]:
        def source() -> str:
            letter = self._letter if self._axis is None else self._axis.letter
            return f"galil://{self._address}/_{operand}{letter}"

        return source

    def set_name(self, name: str, *, child_name_separator: str | None = None) -> None:
        """Name the device; its readback is read under the device's own name."""
        super().set_name(name, child_name_separator=child_name_separator)
        self.readback.set_name(name)

    def _attached(self, controller: AsyncController) -> None:
        axis = controller.axis(self._letter)
        _claim_scale(axis, self._scale, self.name or "GalilMotor")
        self._axis = axis
        _motors.add(self)

    @property
    def axis(self) -> AsyncAxis:
        """The :class:`~galil.aio.AsyncAxis` this motor moves (after ``connect()``).

        Raises:
            NotConnectedError: the motor is not connected.
        """
        if self._axis is None or not self._live:
            raise self._not_connected()
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
                f"{value!r:.60}{decimal_hint(value)}"
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

    async def _read_decel(self) -> float:
        return self._rate(await self.axis.decel(), 2)

    def _rate_value(self, value: object, power: int, what: str) -> Any:
        """A ``velocity``/``acceleration``/``deceleration`` signal's value (a number in the
        motor's unit per second, or per second squared) as the axis's setter takes it; the
        setter checks its range (nothing is sent before)."""
        unit = self._unit + ("/s" if power == 1 else "/s**2")
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise InvalidArgument(
                f"{self.name}: {what} is a number (in {unit}), not {value!r:.60}"
                f"{decimal_hint(value)}"
            )
        if not _finite(value):
            raise InvalidArgument(f"{self.name}: {what} is a finite number, not {value!r:.40}")
        if self._scale is None:
            return float(value)
        return get_registry().Quantity(float(value), self._scale.unit / get_registry().s ** power)

    async def _set_speed(self, value: float) -> None:
        await self.axis.set_speed(self._rate_value(value, 1, "velocity"))

    async def _set_accel(self, value: float) -> None:
        await self.axis.set_accel(self._rate_value(value, 2, "acceleration"))

    async def _set_decel(self, value: float) -> None:
        await self.axis.set_decel(self._rate_value(value, 2, "deceleration"))

    async def _read_setpoint(self) -> float:
        for request in reversed(self._requests):  # (the newest move the controller took)
            if request.target is not None:
                return request.target
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
        first, and the status fails once it is at rest (a timeout fails with
        :class:`~galil.errors.GalilTimeoutError` saying so). A ``stop()`` at any point of the
        move, even before it has started, stops it; with ``success=False`` the status then
        fails (:class:`~galil.errors.MotionError`, once the axis is at rest), as it does when
        :meth:`disconnect` or :func:`release_all` stops the move. A ``set()`` the controller
        refuses (the axis is still moving) fails alone, with
        :class:`~galil.errors.InvalidArgument`: the move in progress goes on as it was.
        """
        request = _Request()  # from the call on, not once the move's task runs: stop() counts
        self._requests.append(request)
        request.status = self._move(value, timeout, request)
        return request.status

    @_MoveStatus.wrap
    async def _move(
        self, value: float, timeout: CalculatableTimeout, request: _Request
    ) -> AsyncIterator[WatcherUpdate[float]]:
        try:
            axis = self.axis
            target = self._target(value)
            wait = _watch_timeout(timeout)
            initial = await self.readback.get_value()
            if request.stopped is None:  # else stopped before the move began: it never does
                moved = self._moved(axis, target, float(value), initial, wait, request)
                async with contextlib.aclosing(moved):  # (closed with this one: _MoveStatus)
                    async for update in moved:
                        yield update
            if request.stopped is False:
                raise MotionError(
                    f"{self.name}: the move to {value:g} {self._unit} was stopped ({request.by})",
                    axis=axis.letter,
                    model=self.controller.model.name if self._live else None,
                )
        finally:
            self._requests.remove(request)

    async def _moved(
        self,
        axis: AsyncAxis,
        target: Any,
        value: float,
        initial: float,
        wait: float | None,
        request: _Request,
    ) -> AsyncGenerator[WatcherUpdate[float], None]:
        """The move of one ``set()``, once its arguments are checked: its progress, then the
        settling and the last update."""
        handle = await self._begin(axis, target)
        begun = self.controller.sync.link.clock()
        try:  # (from the start on: a setpoint subscriber that raises stops the move too)
            request.handle = handle
            request.target = value  # (taken: the setpoint is its target until it ends)
            self._setpoint_backend.show(value)
            if request.stopped is not None:  # stop() came while the move was starting
                await handle.stop()
            async for update in self._progress(handle, value, initial, wait):
                yield update
            await handle.wait()
        except GalilTimeoutError as exc:
            error = self._timed_out(exc, handle, value, wait, begun)  # (before the stop
            await _at_rest(handle)  # changes the prediction); no motion outlives it
            raise error from exc
        except BaseException:
            await _at_rest(handle)
            raise
        finally:
            request.target = None
        if request.stopped is False:
            return  # (it fails: no settling)
        await self._settle()
        yield self._update(await self.readback.get_value(), initial, value, 1.0, 0.0)

    async def _begin(self, axis: AsyncAxis, target: Any) -> AsyncMoveHandle:
        """``axis.move_to(target)``; refused because the axis is still moving, the error
        says what a ``set()`` caller can do (the axis's own advice is a handle's)."""
        try:
            return await axis.move_to(target)
        except InvalidArgument as exc:
            if isinstance(exc, LimitError) or not await _still_moving(axis):
                raise
            raise InvalidArgument(
                f"{self.name}: axis {axis.letter} is still moving (an earlier set() whose "
                "status is not done, a stop still decelerating, or motion started outside "
                "this device): wait for that status, or stop() the motor and set() again "
                "once it is at rest",
                model=exc.model,
            ) from exc

    def _timed_out(
        self,
        exc: GalilTimeoutError,
        handle: AsyncMoveHandle,
        value: float,
        wait: float | None,
        begun: float,
    ) -> GalilTimeoutError:
        """The error of a ``set()`` whose move outlasted its timeout: the move was stopped
        (the watch's own error says it goes on, which is true only of a bare watch)."""
        allowed = handle.duration * 1.5 + 2.0 if wait is None else wait  # (as the watch's)
        if self.controller.sync.link.clock() - begun < allowed:
            return exc  # (a reply that did not come: that error says so, and the axis stopped)
        return GalilTimeoutError(
            f"{self.name}: the move to {value:g} {self._unit} was not done after {allowed:.3g} "
            f"s (predicted {handle.duration:.3g} s): the axis was stopped (ST)",
            model=exc.model,
            recent=exc.recent,
        )

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
        """Decelerate to a stop (``ST``); with ``success=False`` a move in progress fails
        (:class:`~galil.errors.MotionError`)."""
        flag = check_flag(success, "success")
        for request in self._requests:
            request.stopped = flag
        await self.axis.stop()

    async def disconnect(self) -> None:
        """Stop the moves of the ``set()`` calls in progress and wait until they are at rest
        (their statuses fail, saying so), then let go of the shared controller (closed when
        its last device lets go); ``connect()`` connects again."""
        await self._end_moves("disconnect()")
        await super().disconnect()

    async def _end_moves(self, why: str) -> None:
        """Stop the moves of the ``set()`` calls in progress (those not begun never begin)
        and wait for their statuses to end: failed, saying ``why``. No motion this device
        started outlives its connection."""
        requests = list(self._requests)
        for request in requests:
            request.stopped, request.by = False, why
        for request in requests:
            if request.handle is not None:
                await request.handle.stop_unless_done()
        tasks = [r.status.task for r in requests if r.status is not None]
        if tasks:
            await asyncio.wait(tasks)


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

    path: Amounts
    dt: int
    record_period: int | None = None


class _Recorder:
    """The data records of one flight, from its kickoff until :meth:`close` (``recorded``:
    every record taken, oldest first)."""

    def __init__(self) -> None:
        self.recorded: list[np.void] = []

    async def finish(self, end: int) -> None:
        """Take the records up to the first one at or after sample ``end`` (the flight's
        end), at most two seconds for them to arrive; then close."""
        raise NotImplementedError

    async def close(self) -> None:
        """Record no more and let go of what recording took (idempotent; the controller
        closed meanwhile too)."""
        raise NotImplementedError


class _StreamRecorder(_Recorder):
    """Records the controller streams (``DR`` to a handle of their own over Ethernet,
    polled with ``QR`` elsewhere), taken by a task of the loop."""

    def __init__(self, stream: AsyncRecordStream) -> None:
        super().__init__()
        self._stream = stream
        self._reader = asyncio.get_running_loop().create_task(self._read())

    async def _read(self) -> None:
        async for rec in self._stream:
            self.recorded.append(rec)

    async def finish(self, end: int) -> None:
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and not _past(self.recorded, end):
            if self._reader.done():
                break
            await asyncio.sleep(0.01)
        await self.close()

    async def close(self) -> None:
        self._reader.cancel()
        await asyncio.gather(self._reader, return_exceptions=True)
        with contextlib.suppress(GalilError):  # (the controller was closed: so is the stream)
            await self._stream.close()


class _SimRecorder(_Recorder):
    """Records of an in-process simulator, streamed by its own ``DR`` to a handle opened on
    it: each at the exact sample it is due, however the simulator's clock is moved (a
    manual one moves only while someone waits, in steps a poller would miss records in)."""

    def __init__(
        self,
        c: AsyncController,
        sim: SimController,
        layout: tuple[int, int, int, int],
        period: int,
    ) -> None:
        super().__init__()
        self._c = c
        self._sim = sim
        self._layout = layout
        self._period = period
        self._splitter = RecordSplitter(layout)
        self._port: int | None = None

    def start(self) -> None:
        """Worker side: open the handle and ``DR period`` on it."""
        port = self._sim.open_port("galil.bluesky records")
        reply = self._sim.feed(f"{cmds.dr(self._period).text}\r".encode(), port)
        if not reply.startswith(b":"):
            self._sim.close_port(port)
            raise InvalidArgument(f"DR {self._period} refused by the simulator: {reply!r:.60}")
        self._port = port
        # The first record now, as a controller's stream over Ethernet has one before the
        # path begins (its DR sent a while before): the start, held, is in the scan too.
        self.recorded.extend(self._decode(self._sim.record()))

    def _take(self, last: bool = False) -> None:
        """The records the simulator has streamed so far (``last``: close the handle)."""
        port = self._port
        if port is None:
            return
        data = self._sim.poll(port)
        if last:
            self._sim.close_port(port)  # (its DR stream ends with it)
            self._port = None
        whole = self._splitter.feed_block(data)
        if whole:
            self.recorded.extend(self._decode(whole))

    def _decode(self, whole: bytes) -> np.ndarray[Any, np.dtype[Any]]:
        """Records in the layout, their axis blocks as the simulator's model has them."""
        return decode_records(whole, self._layout, analog=self._sim.spec.record_axis_analog)

    async def _run(self, fn: Callable[[], None]) -> None:
        if self._c.worker.closed:
            fn()  # (a few in-process calls: the loop can afford them once)
        else:
            await self._c.run(fn)

    async def finish(self, end: int) -> None:
        for _ in range(3):  # (the record at or after the end is at most a period away)
            await self._run(self._take)
            if _past(self.recorded, end):
                break
            await self._c.sleep(self._period * self._c.sample_period)
        await self.close()

    async def close(self) -> None:
        await self._run(functools.partial(self._take, last=True))


def _simulator(c: AsyncController) -> SimController | None:
    """The in-process simulator behind ``c`` (``sim://`` and mock mode), if it is one."""
    from galil.sim import SimController

    sim = getattr(c.transport, "controller", None)
    return sim if isinstance(sim, SimController) else None


#: The record streams flights opened, each with the flyer whose flight it records (a refused
#: kickoff names it: :func:`_dr_taken`).
_flight_streams: weakref.WeakKeyDictionary[RecordStream, str] = weakref.WeakKeyDictionary()


def _flyer_called(flyer: GalilContourFlyer) -> str:
    """A flyer as a message names it: ``flyer 'flyA'``."""
    return f"flyer {flyer.name!r}" if flyer.name else "an unnamed GalilContourFlyer"


def _dr_taken(c: AsyncController, flyer: GalilContourFlyer, exc: InvalidArgument) -> GalilError:
    """The refusal of ``flyer``'s kickoff whose records found the controller's one ``DR``
    taken (``exc``: the records' refusal, decision 0096), saying what a plan can do: wait
    for the flight that has it, or close the user's own stream. ``exc`` itself when no
    ``DR`` stream is open (another refusal)."""
    holder = c.sync.records_room.dr_stream()
    if holder is None:
        return exc
    flying = _flight_streams.get(holder)
    head = (
        f"{_flyer_called(flyer)} cannot kick off: the controller sends its data records to one "
        "DR stream at a time, and "
    )
    if flying is not None:
        return InvalidArgument(
            f"{head}the flight of {flying} has it: one controller flies one path at a time; "
            "wait for that flight's complete() (or stop() it), then kick off "
            f"{flyer.name or 'this flyer'}"
        )
    return InvalidArgument(
        f"{head}a records() stream of yours has it ({holder!r}): close that stream (await "
        "stream.close(), or leave its async for loop) before kickoff()"
    )


async def _recorder(c: AsyncController, period: int, flyer: GalilContourFlyer) -> _Recorder:
    """Start recording ``flyer``'s flight: every ``period`` samples.

    Raises:
        InvalidArgument: the model's ``DR`` refuses the period, or another flight or a
            ``records()`` stream has the controller's one ``DR`` (nothing started).
    """
    sim = _simulator(c)
    if sim is None:
        try:
            stream = await c.records(period)
        except InvalidArgument as exc:
            error = _dr_taken(c, flyer, exc)
            if error is exc:
                raise
            raise error from exc
        _flight_streams[stream.sync] = _flyer_called(flyer)
        return _StreamRecorder(stream)
    if c.model.has_ethernet:  # (the model's range, as its DR stream would refuse it; one
        cmds.dr(period, 0, model=c.model)  # with no Ethernet polls, as `records()` does)
    recorder = _SimRecorder(c, sim, await c.run(c.sync.records_room.layout), period)
    await c.run(recorder.start)
    return recorder


@dataclass
class _Flight:
    """One fly scan's state from prepare to collect."""

    stream: ContourStream
    axes: dict[str, Axis]  # the contour's axes (a refusal in counts adds their units)
    record_period: int
    starting: Starting | None = None  # the contour's start on a worker (what a stop refuses)
    run: asyncio.Task[ContourResult] | None = None  # the contour, then its records closed
    records: _Recorder | None = None
    start_sample: int = 0
    start_time: float = 0.0
    stopped: str = ""  # who stopped it (stop(), a pause ...), once one did
    unstaged: bool = False  # unstage() stopped it: the plan ended first (complete() returns)
    result: ContourResult | None = None
    points: dict[str, npt.NDArray[Any]] = field(default_factory=dict)


def _build_stream(
    controller: Controller, letters: str, path: Amounts, dt: int
) -> tuple[ContourStream, dict[str, Axis]]:
    """Worker side: the stream ``Controller.contour`` would run, checked and predicted, on the
    controller's motion tracker (:func:`_fly` runs it as ``Controller.contour`` does), and
    its axes. A refusal in counts says the user's units too, as ``Controller.contour``'s
    (decision 0063)."""
    chosen = [controller.axis(a) for a in letters]
    axes = {a.letter: a for a in chosen}
    stream = contour_stream(controller, chosen, path, dt)
    with user_units(axes):
        stream.check()
        with held(controller.tracker):  # (a plan: the flight reads the state again before CM)
            stream.prepare()
    return stream, axes


def _fly(stream: ContourStream, axes: Mapping[str, Axis]) -> ContourResult:
    """Worker side: the flight, as ``Controller.contour`` runs a contour (decisions 0023,
    0024): the state read again and ``CM`` under the tracker's lock, so another thread's
    motion takes turns with it (the axes may have moved since ``prepare()``), and a
    :class:`~galil.motion.StopWatch` open while it streams, so ``stop()``, ``abort()`` and
    ``Controller.close()`` reach it (``ST``, and no ``CD`` after it)."""
    with user_units(axes):
        return stream.run()


class GalilContourFlyer(_GalilDevice, Preparable, Flyable, Stoppable, Pausable, Stageable):
    """A contour path on one or more axes as a bluesky flyer.

    ``prepare(ContourPath(...))`` checks and predicts the path (nothing moves), ``kickoff()``
    starts the data records and the contour, ``complete()`` waits for the end, and
    ``collect()`` yields one event per data record taken during the path: the recorded
    reference and encoder positions per axis, and the predicted position at the same sample.

    A flight does not outlive its plan: it is stopped (``ST``) and its records closed when
    the RunEngine pauses (``pause()``, so also before an abort or a halt of the paused
    run), when a plan that staged the flyer ends in any way (``unstage()``), when bluesky
    collects a flyer a failed, aborted or halted run left flying (``collect()`` before
    ``complete()``), on ``stop()``, on ``disconnect()``, and on the next ``prepare()`` or
    ``stage()``. Its ``complete()`` then fails with a :class:`~galil.errors.MotionError`
    saying so; but for ``unstage()``: the plan is over (an abort, a stop or a failure says
    how), and ``complete()`` returns without data.

    One controller flies one path at a time: it sends its data records to one ``DR`` stream
    (decision 0096). Over Ethernet, the ``kickoff()`` of a second flyer on the same
    controller is refused, before anything moves, until the first flight ended (its
    ``complete()``), and so is a ``kickoff()`` while a ``records()`` stream of the user's is
    open; the refusal names the flyer or the stream that holds the records.

    Args:
        address: the controller's address (shared with the motors on it).
        axes: the contour axes, in the order of the path's columns (``"AB"``).
        name: the device name (also the name of the event stream).
        scales: counts per user unit per axis, for axes no motor has scaled (one another
            device on the address gave the axis must be the same: else refused at connect).
    """

    def __init__(
        self,
        address: str,
        axes: str,
        name: str = "",
        *,
        scales: Mapping[str, QuantityLike] | None = None,
    ) -> None:
        if not isinstance(address, str):
            raise InvalidArgument(f"GalilContourFlyer takes an address, not {address!r:.60}")
        if not isinstance(axes, str) or not axes:
            raise InvalidArgument(f"axes is a string of axis letters, not {axes!r}")
        _check_name(name)
        if scales is not None and not isinstance(scales, Mapping):
            raise InvalidArgument(f"scales must map axis letters to scales, not {scales!r:.60}")
        # (refused here, not at connect())
        self._scales = {a: Scale(per) for a, per in (scales or {}).items()}
        self._axes_given = axes
        self._letters = ""
        self._flight: _Flight | None = None
        super().__init__(name=name, connector=_GalilConnector(address))

    def _attached(self, controller: AsyncController) -> None:
        letters = "".join(controller.axis(a).letter for a in self._axes_given)
        for a, scale in self._scales.items():
            _claim_scale(controller.axis(a), scale, self.name or "GalilContourFlyer")
        self._letters = letters

    async def disconnect(self) -> None:
        """End a flight in progress (stopped, its records closed; its ``complete()`` fails,
        saying so), then let go of the shared controller."""
        if self._flight is not None:
            await self._end_flight(self._flight, "disconnect()")
        await super().disconnect()

    @property
    def axes(self) -> str:
        """The contour axes (letters, after ``connect()``)."""
        return self._letters or self._axes_given

    @property
    def _called(self) -> str:
        """The device's name in a message."""
        return self.name or "the flyer"

    def _stream_name(self) -> str:
        return self.name or "contour"

    def _key(self, letter: str, what: str) -> str:
        return f"{self.name or 'contour'}-{letter}-{what}"

    @AsyncStatus.wrap
    async def prepare(self, value: ContourPath) -> None:
        """Check the path and predict it from where the axes are (one state query). A
        flight an earlier ``prepare()`` left is over first (stopped if it still flies)."""
        if not isinstance(value, ContourPath):
            raise InvalidArgument(f"prepare takes a ContourPath, not {value!r}")
        period = value.record_period
        if period is not None and not 1 <= check_count(period, "record_period") <= 65535:
            # as the records of kickoff() would refuse it, but before the path is prepared
            raise InvalidArgument(f"record_period is a number of samples 1..65535, not {period!r}")
        c = self.controller
        if self._flight is not None:
            await self._end_flight(self._flight, "a new prepare()")
            self._flight = None
        stream, axes = await c.run(_build_stream, c.sync, self._letters, value.path, value.dt)
        period = value.record_period or (1 << value.dt)
        self._flight = _Flight(stream, axes, period)

    @property
    def predicted(self) -> dict[str, Profile]:
        """The predicted profile per axis of the prepared path (in the axes' units).

        Raises:
            InvalidArgument: no path was prepared.
        """
        if self._flight is None:
            raise InvalidArgument(f"{self._called}: no path prepared: prepare() one first")
        return dict(self._flight.stream.profiles)

    @AsyncStatus.wrap
    async def kickoff(self) -> None:
        """Start the data records, then the contour; done once both are under way.

        The contour runs as ``Controller.contour`` runs one: its axes' state is read again
        (they may have moved since ``prepare()``) and checked, and motion from other threads
        takes turns with its start; ``stop()``, a stop through the controller and ``close()``
        stop it.

        Raises:
            InvalidArgument: no path prepared, or this one kicked off already; or the
            controller's one ``DR`` record stream is taken, by another flyer's flight on the
            same controller or by a ``records()`` stream of the user's (over Ethernet).
        """
        flight = self._flight
        if flight is None:
            raise InvalidArgument(f"{self._called}: prepare() must come before kickoff()")
        if flight.run is not None:
            raise InvalidArgument(
                f"{self._called}: this path was kicked off already (a prepared path flies "
                "once): prepare() it again for another flight"
            )
        c = self.controller
        records = await _recorder(c, flight.record_period, self)
        try:
            flight.start_sample = round((await c.query_operands(["TIME"]))[0])
        except BaseException:
            await records.close()
            raise
        flight.records = records
        flight.start_time = time.time()
        flight.starting = Starting(c.sync.tracker)
        flight.run = asyncio.get_running_loop().create_task(self._flown(c, flight))
        flight.run.add_done_callback(_retrieved)  # (complete() raises it; none may come)

    async def _flown(self, c: AsyncController, flight: _Flight) -> ContourResult:
        """The flight's task: the contour, then the records up to its end; the records are
        closed however it ends."""
        records = flight.records
        assert records is not None
        try:
            result = await self._contour(c, flight)
            end = round((await c.query_operands(["TIME"]))[0])
            await records.finish(end)
            return result
        finally:
            await records.close()

    async def _contour(self, c: AsyncController, flight: _Flight) -> ContourResult:
        """The contour on a worker thread, started as ``AsyncController.contour`` starts one:
        a stop refuses what it has not started yet (:class:`~galil.aio._motion.Starting`)."""
        starting = flight.starting
        assert starting is not None
        future = c.worker.submit(starting.run, functools.partial(_fly, flight.stream, flight.axes))
        try:
            return await shielded(future)
        except asyncio.CancelledError:  # (complete()'s status cancelled, the loop's end)
            if not future.cancel():
                await self._send_stop(c, starting)
            raise

    async def _send_stop(self, c: AsyncController, starting: Starting) -> None:
        """``ST`` on the contour axes, under the tracker's lock: a flight that has not entered
        contour mode yet never sends a segment; one that has stops (and sends no ``CD``)."""
        stop = functools.partial(c.sync.stop, self._letters)
        with contextlib.suppress(GalilError):  # (a controller closed since: it stopped it)
            await c.worker.run_urgent(starting.cancel, stop)

    async def _halt(self, flight: _Flight, why: str) -> bool:
        """Stop ``flight`` if it is in progress (without waiting for its end); whether it
        was."""
        run, starting = flight.run, flight.starting
        if run is None or starting is None or run.done():
            return False
        flight.stopped = flight.stopped or why
        starting.abandon()  # (a flight not started yet never starts)
        c = self._connector.controller
        if c is not None and not c.closed:
            await self._send_stop(c, starting)
        return True

    async def _end_flight(self, flight: _Flight, why: str) -> None:
        """Stop ``flight`` if it is in progress, and wait for its end (records closed)."""
        await self._halt(flight, why)
        if flight.run is not None:
            await asyncio.gather(flight.run, return_exceptions=True)

    @AsyncStatus.wrap
    async def complete(self) -> None:
        """Wait for the end of the path, stop the records and line them up with the
        prediction.

        A flight that ``unstage()`` stopped returns without data: the plan that staged the
        flyer ended first (``RE.abort()``, ``RE.stop()``, a failure), and its end says how.

        Raises:
            InvalidArgument: no ``kickoff()`` before it.
            MotionError: the flight was stopped (``stop()``, a pause ...) before its end.
        """
        flight = self._flight
        if flight is None or flight.run is None:
            raise InvalidArgument(f"{self._called}: kickoff() must come before complete()")
        try:
            flight.result = await flight.run
        except Exception as exc:
            if not flight.stopped:
                raise
            if flight.unstaged:
                return  # (the plan ended first: its abort, stop or failure says how)
            raise MotionError(
                f"{self._called}: the flight on {self._letters} was stopped "
                f"({flight.stopped}) before the end of its path",
                axis=self._letters[0],
                model=self.controller.model.name if self._live else None,
            ) from exc
        records = flight.records
        assert records is not None
        flight.points = await self.controller.run(
            _line_up, records.recorded, flight.stream.profiles, self._letters, flight.start_sample
        )

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
        """One partial event per data record taken during the path (after ``complete()``).

        Before ``complete()`` nothing: a flight still in progress is stopped (``ST``) and its
        records closed (bluesky collects so a flyer that a failed, aborted or halted run left
        flying)."""
        flight = self._flight
        if flight is None:
            return
        if flight.run is not None and not flight.run.done():
            await self._end_flight(flight, "collect() before complete()")
        if not flight.points:
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
        """Stop the contour's axes (``ST``): a flight in progress is over (its ``complete()``
        fails, saying it was stopped); without one, ``ST`` on the axes all the same."""
        check_flag(success, "success")
        flight = self._flight
        if flight is None or not await self._halt(flight, "stop()"):
            await self.controller.stop(self._letters)

    async def pause(self) -> None:
        """The RunEngine pauses (Ctrl-C twice, ``RE.request_pause``, a suspender): a flight
        in progress is stopped (``ST``) and its records closed; a flight is not resumed
        halfway (its ``complete()`` fails)."""
        if self._flight is not None:
            await self._end_flight(self._flight, "the RunEngine paused")

    async def resume(self) -> None:
        """The RunEngine resumes: nothing to do (a paused flight was stopped)."""

    @AsyncStatus.wrap
    async def stage(self) -> None:
        """Before a plan's flights: a flight an earlier plan left is over (stopped if it
        still flies, its records closed)."""
        if self._flight is not None:
            await self._end_flight(self._flight, "stage()")

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        """At the end of a plan that staged the flyer (bluesky unstages it however the plan
        ends: a failure, an abort, a halt): a flight still in progress is stopped (``ST``)
        and its records closed."""
        flight = self._flight
        if flight is not None:
            flight.unstaged = not flight.stopped
            await self._end_flight(flight, "unstage()")


async def _at_rest(handle: AsyncMoveHandle) -> None:
    """Stop ``handle``'s move unless it was seen done, and wait until its axes are at rest
    (the stop's deceleration): a failing ``set()`` leaves no motion. A wait that fails (a
    dead link, a closed controller: its stop was sent, or close() sent one) ends it."""
    await handle.stop_unless_done()
    with contextlib.suppress(GalilError):
        await handle.wait()


async def _still_moving(axis: AsyncAxis) -> bool:
    """Whether ``axis`` is moving (``False`` when that cannot be read)."""
    try:
        return await axis.moving()
    except GalilError:
        return False


def _retrieved(task: asyncio.Task[ContourResult]) -> None:
    """Mark a flight's outcome seen: a flight nobody completes (stopped, its plan failed)
    is no "exception never retrieved" in the log."""
    if not task.cancelled():
        task.exception()


def _in_unit(profile: Profile, counts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.asarray(shown_position(profile.display, counts), dtype=np.float64)


def _past(recorded: list[np.void], sample: int) -> bool:
    """Whether the last record of ``recorded`` was taken at ``sample`` or after it."""
    if not recorded:
        return False
    last = int(recorded[-1]["sample"])
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
