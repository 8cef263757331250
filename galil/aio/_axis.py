"""The async axis: a twin of :class:`galil.Axis`, and of the :class:`~galil.gearing.Gearing`
it makes.

Every method that talks to the controller runs the sync method (or property) on the
controller's worker threads; nothing here converts a unit, predicts a move or builds a
command. Sync properties that read the controller become methods (``await axis.speed()``),
their setters ``set_`` methods (``await axis.set_speed(v)``); the tuning settings too
(``await axis.kp()``, ``await axis.set_kp(10)``).
"""

from __future__ import annotations

import sys
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any, ClassVar, Generic, NoReturn, TypeVar, cast, overload

from galil.aio._motion import MotionRoom, motion_twin
from galil.aio._worker import Room, same, twin
from galil.axis import Axis, MoveOverrides, UnitProfile
from galil.errors import missing_attribute
from galil.gearing import Gearing
from galil.homing import Homed, Switches
from galil.motion import MoveHandle
from galil.tuning import Setting
from galil.units import Amount, QuantityLike, Reading, Scale

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # (typing_extensions: a dependency on Python 3.10)
    from typing_extensions import Unpack

__all__ = ["AsyncAxis", "AsyncGearing", "read_setting", "write_setting"]

T = TypeVar("T")


# Methods that take **overrides cannot bind ``self`` positionally for mypy; these forwarders
# only make it positional-only (the sync methods do the work and hold the docstrings).
def _move_to(axis: Axis, /, position: Amount, **overrides: Unpack[MoveOverrides]) -> MoveHandle:
    return axis.move_to(position, **overrides)


def _move_by(axis: Axis, /, distance: Amount, **overrides: Unpack[MoveOverrides]) -> MoveHandle:
    return axis.move_by(distance, **overrides)


def _plan_to(axis: Axis, /, position: Amount, **overrides: Unpack[MoveOverrides]) -> UnitProfile:
    return axis.plan_to(position, **overrides)


def _plan_by(axis: Axis, /, distance: Amount, **overrides: Unpack[MoveOverrides]) -> UnitProfile:
    return axis.plan_by(distance, **overrides)


for _f, _sync in (
    (_move_to, Axis.move_to),
    (_move_by, Axis.move_by),
    (_plan_to, Axis.plan_to),
    (_plan_by, Axis.plan_by),
):
    _f.__doc__ = _sync.__doc__
    _f.__name__ = _sync.__name__


def _read(setting: Setting[T], axis: Axis) -> T:
    return setting.__get__(axis, Axis)


def _write(setting: Setting[T], axis: Axis, value: float) -> None:
    setting.__set__(axis, value)


class read_setting(Generic[T]):  # noqa: N801 - used like a decorator
    """``await axis.kp()``: reads a :class:`~galil.tuning.Setting` of the sync axis (one
    query, on the worker)."""

    def __init__(self, setting: Setting[T]) -> None:
        self._setting = setting
        self.__doc__ = (
            f"``{setting.mnemonic}`` as the controller has it (``_{setting.mnemonic}``; see "
            f":attr:`galil.Axis.{setting.name}`)."
        )

    @overload
    def __get__(self, room: None, owner: type[object]) -> read_setting[T]: ...
    @overload
    def __get__(self, room: Room[Axis], owner: type[object]) -> Callable[[], Awaitable[T]]: ...
    def __get__(
        self, room: Room[Axis] | None, owner: type[object]
    ) -> read_setting[T] | Callable[[], Awaitable[T]]:
        if room is None:
            return self
        setting, axis, worker = self._setting, room.sync, room._worker

        async def call() -> T:
            return await worker.run(_read, setting, axis)

        call.__doc__ = self.__doc__
        return call


class write_setting(Generic[T]):  # noqa: N801 - used like a decorator
    """``await axis.set_kp(10)``: sets a :class:`~galil.tuning.Setting` of the sync axis
    (checked against the model, then sent, on the worker)."""

    def __init__(self, setting: Setting[T]) -> None:
        self._setting = setting
        self.__doc__ = (
            f"Set ``{setting.mnemonic}`` (range-checked for the model before it is sent; see "
            f":attr:`galil.Axis.{setting.name}`)."
        )

    @overload
    def __get__(self, room: None, owner: type[object]) -> write_setting[T]: ...
    @overload
    def __get__(
        self, room: Room[Axis], owner: type[object]
    ) -> Callable[[float], Awaitable[None]]: ...
    def __get__(
        self, room: Room[Axis] | None, owner: type[object]
    ) -> write_setting[T] | Callable[[float], Awaitable[None]]:
        if room is None:
            return self
        setting, axis, worker = self._setting, room.sync, room._worker

        async def call(value: float) -> None:
            await worker.run(_write, setting, axis, value)

        call.__doc__ = self.__doc__
        return call


class AsyncGearing(Room[Gearing]):
    """A follower geared to its master (``await follower.gear_to(master, ratio)``), the twin
    of :class:`~galil.gearing.Gearing`: what needs no I/O is read at once, ``set_ratio`` and
    ``off`` are awaited; ``async with await follower.gear_to(...)`` turns it off at the end of
    the block (the sync ``with``)."""

    @property
    def follower(self) -> str:
        """The geared axis."""
        return self.sync.follower

    @property
    def master(self) -> str:
        """The master axis (its commanded position), or ``"S"``."""
        return self.sync.master

    @property
    def ratio(self) -> float:
        """GR as the controller stores it (truncated to 1/65536)."""
        return self.sync.ratio

    @property
    def engaged(self) -> bool:
        """Whether the gearing holds (no ``GR 0``, ``ST``, limit or ``AB`` since)."""
        return self.sync.engaged

    predict = same(Gearing.predict)
    set_ratio = twin(Gearing.set_ratio)
    off = twin(Gearing.off)

    async def __aenter__(self) -> AsyncGearing:
        return self

    async def __aexit__(self, *exc: object) -> None:  # (Gearing.__exit__'s parameters)
        """Turn the gearing off (``GR 0``) however the block ends, as the sync ``with`` does;
        a cancellation of the task meanwhile still lets it go out."""
        await self._worker.run_shielded(self.sync.off)

    def __repr__(self) -> str:
        return f"<AsyncGearing of {self.sync!r}>"


class AsyncAxis(MotionRoom[Axis]):
    """One axis, awaited: ``await axis.position()``, ``handle = await axis.move_to(5 * mm)``.

    Values go in and come out in the axis's user units, exactly as on the sync
    :class:`~galil.axis.Axis` (:attr:`sync`), which does the work.
    """

    _elsewhere: ClassVar[dict[str, str]] = {
        "motor_off": "turn a motor off through the controller: "
        "await controller.motor_off('{letter}')",
        "servo_here": "turn a motor on through the controller: "
        "await controller.servo_here('{letter}')",
    }

    if not TYPE_CHECKING:  # (a type checker still says an attribute is unknown)

        def __getattr__(self, name: str) -> NoReturn:
            raise missing_attribute(type(self), name, self)

    @property
    def letter(self) -> str:
        """The axis letter."""
        return self.sync.letter

    def set_scale(
        self, counts_per: QuantityLike | None, offset: QuantityLike | None = None, sign: int = 1
    ) -> AsyncAxis:
        """Give the axis a scale (no I/O; see :meth:`galil.Axis.set_scale`)."""
        self.sync.set_scale(counts_per, offset, sign)
        return self

    @property
    def scale(self) -> Scale | None:
        """The axis's :class:`~galil.units.Scale`, if any."""
        return self.sync.scale

    # -- units (no I/O: the sync axis's conversions, called as they are) -------------------
    display = same(Axis.display)
    position_counts = same(Axis.position_counts)
    distance_counts = same(Axis.distance_counts)
    rate_counts = same(Axis.rate_counts)
    signed_rate_counts = same(Axis.signed_rate_counts)
    limit_counts = same(Axis.limit_counts)
    check_parameter = same(Axis.check_parameter)

    async def _get(self, name: str) -> Any:  # (private: each caller says what it reads)
        return await self._worker.run(getattr, self.sync, name)

    async def _reading(self, name: str) -> Reading:
        """A sync property that reads a :data:`~galil.units.Reading` (on the worker)."""
        return cast("Reading", await self._get(name))

    async def _set(self, name: str, value: object) -> None:
        await self._worker.run(setattr, self.sync, name, value)

    # -- operands (one query each; see the sync properties) ---------------------------------
    async def position(self) -> Reading:
        """Encoder position ``_TP``."""
        return await self._reading("position")

    async def reference_position(self) -> Reading:
        """Commanded (reference) position ``_RP``."""
        return await self._reading("reference_position")

    async def velocity(self) -> Reading:
        """Filtered actual velocity ``_TV`` (signed)."""
        return await self._reading("velocity")

    async def error(self) -> Reading:
        """Position error ``_TE``."""
        return await self._reading("error")

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
    async def speed(self) -> Reading:
        """Slew speed ``SP``."""
        return await self._reading("speed")

    async def set_speed(self, value: Amount) -> None:
        """Set ``SP`` (in motion too: the move's prediction follows)."""
        await self._set("speed", value)

    async def accel(self) -> Reading:
        """Acceleration ``AC``."""
        return await self._reading("accel")

    async def set_accel(self, value: Amount) -> None:
        """Set ``AC`` (in motion too)."""
        await self._set("accel", value)

    async def decel(self) -> Reading:
        """Deceleration ``DC``."""
        return await self._reading("decel")

    async def set_decel(self, value: Amount) -> None:
        """Set ``DC`` (the controller refuses a change in motion)."""
        await self._set("decel", value)

    async def smoothing(self) -> float:
        """Independent time constant ``IT``."""
        return float(await self._get("smoothing"))

    async def set_smoothing(self, value: float) -> None:
        """Set ``IT``."""
        await self._set("smoothing", value)

    async def jog_speed(self) -> Reading:
        """Jog speed ``JG`` (signed)."""
        return await self._reading("jog_speed")

    async def set_jog_speed(self, value: Amount) -> None:
        """Set ``JG`` (while jogging: the speed changes in motion)."""
        await self._set("jog_speed", value)

    async def soft_limits(self) -> tuple[Reading | None, Reading | None]:
        """``(low, high)`` soft limits (``BL``, ``FL``); ``None`` for a side that is off."""
        low, high = cast("tuple[Reading | None, Reading | None]", await self._get("soft_limits"))
        return low, high

    async def set_soft_limits(self, limits: tuple[Amount | None, Amount | None]) -> None:
        """Set ``(low, high)``; ``None`` on either side removes it."""
        await self._set("soft_limits", limits)

    # -- motor and loop settings (galil.tuning; ranges per model) --------------------------
    motor_type = read_setting(Axis.motor_type)
    set_motor_type = write_setting(Axis.motor_type)
    kp = read_setting(Axis.kp)
    set_kp = write_setting(Axis.kp)
    ki = read_setting(Axis.ki)
    set_ki = write_setting(Axis.ki)
    kd = read_setting(Axis.kd)
    set_kd = write_setting(Axis.kd)
    stepper_smoothing = read_setting(Axis.stepper_smoothing)
    set_stepper_smoothing = write_setting(Axis.stepper_smoothing)
    integrator_limit = read_setting(Axis.integrator_limit)
    set_integrator_limit = write_setting(Axis.integrator_limit)
    torque_limit = read_setting(Axis.torque_limit)
    set_torque_limit = write_setting(Axis.torque_limit)
    error_limit = read_setting(Axis.error_limit)
    set_error_limit = write_setting(Axis.error_limit)
    off_on_error = read_setting(Axis.off_on_error)
    set_off_on_error = write_setting(Axis.off_on_error)
    brush = read_setting(Axis.brush)
    set_brush = write_setting(Axis.brush)
    encoder_config = read_setting(Axis.encoder_config)
    set_encoder_config = write_setting(Axis.encoder_config)
    limit_disable = read_setting(Axis.limit_disable)
    set_limit_disable = write_setting(Axis.limit_disable)

    # -- motion -------------------------------------------------------------------------------
    move_to = motion_twin(_move_to)
    move_by = motion_twin(_move_by)
    jog = motion_twin(Axis.jog)
    increment = motion_twin(Axis.increment)
    speed_schedule = motion_twin(Axis.speed_schedule)
    plan_to = twin(_plan_to)
    plan_by = twin(_plan_by)
    stop = twin(Axis.stop, urgent=True)  # asked for, a stop goes out even if cancelled

    async def gear_to(self, master: AsyncAxis | Axis | str, ratio: float) -> AsyncGearing:
        """Follow ``master`` (an axis, or ``"S"``: the S sequences' path) at ``ratio`` (``GA``
        its commanded position, ``GR``); its moves then predict this axis too. See
        :meth:`galil.Axis.gear_to`."""
        chosen = master.sync if isinstance(master, AsyncAxis) else master
        gearing = await self._worker.run(self.sync.gear_to, chosen, ratio)
        return AsyncGearing(gearing, self._worker)

    gear_off = twin(Axis.gear_off)

    # -- homing and switches (galil.homing) ------------------------------------------------
    home = motion_twin(Axis.home)
    find_edge = motion_twin(Axis.find_edge)
    find_index = motion_twin(Axis.find_index)
    define_position = twin(Axis.define_position)

    async def homed(self) -> Homed:
        """Whether the axis is homed, and how the library knows (``bool(await
        axis.homed())``)."""
        found: Homed = await self._get("homed")
        return found

    async def switches(self) -> Switches:
        """Limit and home switches (``TS``, one round trip); True means tripped."""
        found: Switches = await self._get("switches")
        return found

    async def home_speed(self) -> Reading:
        """``HV``: the slow speed of HM's last stages and FI's return."""
        return await self._reading("home_speed")

    async def set_home_speed(self, value: Amount) -> None:
        """Set ``HV`` (checked as a speed against the model's SP range)."""
        await self._set("home_speed", value)

    def __repr__(self) -> str:
        return f"<AsyncAxis of {self.sync!r}>"
