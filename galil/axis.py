"""Typed axes: units at the edge, operands, parameters and thin motion methods.

An :class:`Axis` belongs to a controller; ``controller.axes["A"]`` and ``controller.A`` give
the same object. Values go in and come out in the axis's user units when it has a
:class:`~galil.units.Scale` (counts otherwise); everything below this room works in counts.
Moves return a :class:`~galil.motion.MoveHandle` that knows its predicted profile.
"""

from __future__ import annotations

import contextlib
import numbers
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, NoReturn, TypeAlias, TypedDict, cast, overload

import numpy as np
import numpy.typing as npt
import pint

from galil import codes, predict
from galil.errors import (
    FixedAttributes,
    InvalidArgument,
    LimitError,
    ReadOnly,
    decimal_hint,
    missing_attribute,
)
from galil.gearing import Gearing, gear_off, gear_to
from galil.homing import AxisHoming, Homed, Switches, read_switches
from galil.link import CommandLink
from galil.models import INT32_MAX, INT32_MIN, ModelSpec, tm_of
from galil.motion import (
    Display,
    MotionTracker,
    MoveHandle,
    change_line,
    refuse_in_motion,
    sample_of,
    stop_axes,
    stop_on_error,
)
from galil.moves import (
    AxisMove,
    check_int32,
    execute_move,
    increment,
    jog,
    schedule_label,
    set_jog_speed,
    speed_schedule,
)
from galil.predict.counts import whole_counts
from galil.protocol import commands as cmds
from galil.routines import Routines
from galil.tuning import EncoderConfig, Setting, limit_disable_of, motor_type, whole
from galil.units import (
    Amount,
    QuantityLike,
    Reading,
    Scale,
    counts_or_plain,
    get_registry,
    is_quantity,
    rate_magnitude_counts,
    signed_rate_counts,
    state_in_units,
)

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # (typing_extensions: a dependency on Python 3.10)
    from typing_extensions import Unpack

__all__ = [
    "OVERRIDES",
    "Axis",
    "MoveOverrides",
    "MoveTargets",
    "ProfileQuantities",
    "SpeedChanges",
    "UnitProfile",
    "check_overrides",
    "in_user_units",
    "limits_by_axis",
    "resolve_moves",
    "user_units",
]

#: The keyword overrides a move takes, and the command each sets.
OVERRIDES = {"speed": "SP", "accel": "AC", "decel": "DC"}


#: Each axis's target (or distance) of a move of several axes, by letter or alias.
MoveTargets: TypeAlias = Mapping[str, Amount]
#: A speed schedule's changes: ``[(at, new_speed), ...]`` (:meth:`Axis.speed_schedule`).
SpeedChanges: TypeAlias = Iterable[Sequence[Amount]]


class MoveOverrides(TypedDict, total=False):
    """The keyword overrides of a move (:data:`OVERRIDES`; ``**overrides`` of
    :meth:`Axis.move_to`, :meth:`Controller.move <galil.Controller.move>` ...), in the axis's
    units: sent with the move, they stay set. ``None`` leaves the setting as it is."""

    speed: Amount | None
    accel: Amount | None
    decel: Amount | None


_POWER = {"SP": 1, "JG": 1, "AC": 2, "DC": 2}
_SETTERS = {"SP": cmds.sp, "AC": cmds.ac, "DC": cmds.dc, "IT": cmds.it, "JG": cmds.jg}
#: The settings a move's prediction follows when they change in motion, and how.
_FOLLOWED: dict[str, Callable[[float, float], predict.Event]] = {
    "SP": predict.SetSpeed,
    "AC": predict.SetAccel,
    "DC": predict.SetDecel,
}


@dataclass(frozen=True, eq=False, repr=False)  # (Profile's own equality and concise repr)
class UnitProfile(predict.Profile):
    """A predicted profile of a scaled axis: everything a :class:`~galil.predict.Profile` has
    (arrays in counts, for comparing with the controller), and :attr:`q`, the same motion in
    the axis's units."""

    scale: Scale | None = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        if self.scale is None:
            return super().__repr__()
        q = self.q
        return (
            f"UnitProfile(shape={self.shape!r}, duration={self.duration:.6g}, samples="
            f"{self.samples}, start={q.start:~.6g}, end={q.end:~.6g}, peak_speed="
            f"{q.peak_speed:~.6g}, counts {self.start} -> {self.end})"
        )

    @property
    def q(self) -> ProfileQuantities:
        """Times, positions, speeds and accelerations as pint Quantities in the axis's units.

        Raises:
            InvalidArgument: the profile is of an axis without a scale (it is in counts).
        """
        if self.scale is None:
            raise InvalidArgument(
                "this profile is of an axis without a scale: it is in counts (set one with "
                "axis.set_scale(counts_per=...) before planning, to read it in units)"
            )
        return ProfileQuantities(self, self.scale)


@dataclass(frozen=True)
class ProfileQuantities:
    """A profile read in an axis's units (``plan.q.peak_speed`` -> ``20 mm/s``)."""

    profile: predict.Profile
    scale: Scale

    @property
    def t(self) -> pint.Quantity[npt.NDArray[np.float64]]:
        """Sample times, seconds."""
        t: Any = self.profile.t * get_registry().second  # (pint types its arithmetic as Any)
        return cast("pint.Quantity[npt.NDArray[np.float64]]", t)

    @property
    def duration(self) -> pint.Quantity[float]:
        """Duration, seconds."""
        duration: Any = self.profile.duration * get_registry().second
        return cast("pint.Quantity[float]", duration)

    @property
    def position(self) -> pint.Quantity[npt.NDArray[np.float64]]:
        """Reference position at each sample."""
        return self.scale.counts_to_position(self.profile.position.astype(np.float64))

    @property
    def velocity(self) -> pint.Quantity[npt.NDArray[np.float64]]:
        """Velocity at each sample (signed, in the user's direction)."""
        return self.scale.counts_to_rate(self.profile.velocity, 1)

    @property
    def acceleration(self) -> pint.Quantity[npt.NDArray[np.float64]]:
        """Per-sample change of velocity (signed)."""
        return self.scale.counts_to_rate(self.profile.acceleration, 2)

    @property
    def peak_speed(self) -> pint.Quantity[float]:
        """Largest speed."""
        return _abs(self.scale.counts_to_rate(self.profile.peak_speed, 1))

    @property
    def start(self) -> pint.Quantity[float]:
        """Position at sample 0."""
        return self.scale.counts_to_position(self.profile.start)

    @property
    def end(self) -> pint.Quantity[float]:
        """Position at the last sample."""
        return self.scale.counts_to_position(self.profile.end)

    @property
    def distance(self) -> pint.Quantity[float]:
        """End minus start."""
        return self.scale.counts_to_distance(self.profile.distance)

    @overload
    def at(self, t: float) -> pint.Quantity[float]: ...
    @overload
    def at(
        self, t: npt.ArrayLike
    ) -> pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]]: ...
    def at(
        self, t: float | npt.ArrayLike
    ) -> pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]]:
        """The reference position at time(s) ``t`` in the axis's unit: seconds, or a time
        Quantity (``200 * ureg.ms``, or an array of times), as :meth:`Profile.at
        <galil.predict.Profile.at>` interpolates it.

        Raises:
            InvalidArgument: ``t`` is not seconds nor a time Quantity, or is NaN.
        """
        return self.scale.counts_to_position(self.profile.at(t))


def _planned(profile: predict.Profile) -> UnitProfile:
    """A plan as a :class:`UnitProfile` (an axis without a scale: one whose ``.q`` says so)."""
    if isinstance(profile, UnitProfile):
        return profile
    return profile.recast(UnitProfile, scale=None)


def _abs(q: pint.Quantity[float]) -> pint.Quantity[float]:
    """``abs(q)``, typed as it is (pint types it as its base class's)."""
    return cast("pint.Quantity[float]", abs(q))


def check_overrides(where: str, overrides: Mapping[str, object]) -> None:
    """Refuse keyword overrides a move does not take, naming the public call and the valid ones.

    Raises:
        TypeError: an unknown keyword, as Python itself would raise it.
    """
    if not overrides:
        return
    unknown = sorted(set(overrides) - set(OVERRIDES))
    if unknown:
        raise TypeError(
            f"{where}() got an unexpected keyword argument {unknown[0]!r}; "
            "a move takes speed=, accel= and decel="
        )


def _show(value: object) -> str:
    return f"{value:~}" if is_quantity(value) else repr(value)


def limits_by_axis(
    model: ModelSpec, limits: Mapping[str, object], what: str, letters: str | None = None
) -> dict[str, object]:
    """A mapping of axis letters or aliases to limits, keyed by axis letter.

    Raises:
        InvalidArgument: a key that is no axis of ``model``, an axis given twice, or (with
            ``letters``) an axis not among ``letters``, whose limit would be ignored.
    """
    found: dict[str, object] = {}
    for key, value in limits.items():
        try:
            name = model.axis_letter(key)
        except InvalidArgument as exc:
            raise InvalidArgument(f"{what}: {exc.args[0]}", model=model.name) from None
        if name in found:
            raise InvalidArgument(
                f"{what}: axis {name} given twice (an alias names the same axis)",
                model=model.name,
            )
        if letters is not None and name not in letters:
            raise InvalidArgument(
                f"{what}: axis {name} is not one of the contour's axes ({letters})",
                model=model.name,
            )
        found[name] = value
    return found


def _smoothing_value(value: object, model: ModelSpec) -> float:
    """IT as a float: numpy's numbers too; a bool or an int no float holds refused."""
    low, high = model.it_range
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InvalidArgument(
            f"smoothing must be a number in [{low}, {high}], got {value!r}{decimal_hint(value)}"
        )
    try:
        return float(value)
    except OverflowError:  # 10**400
        raise InvalidArgument(f"smoothing must be in [{low}, {high}], got {value!r:.40}") from None


class AxisGearing:
    """Electronic gearing of an :class:`Axis` (a class of its own only to keep each class
    short): :meth:`gear_to` and :meth:`gear_off` (see :mod:`galil.gearing`)."""

    letter: str
    _letter: str
    _link: CommandLink
    _tracker: MotionTracker
    _scale: Scale | None

    @property
    def _display(self) -> Display | None:
        raise NotImplementedError

    def gear_to(self, master: Axis | str, ratio: float) -> Gearing:
        """Follow ``master`` (an axis, or ``"S"``: the S sequences' path) at ``ratio`` (``GA``
        its commanded position, ``GR``); its moves then predict this axis too. See
        :mod:`galil.gearing`.

        Raises:
            InvalidArgument: ``master`` an axis of another controller (nothing sent), and
                :func:`galil.gearing.gear_to`'s refusals.
        """
        if isinstance(master, Axis) and master._link is not self._link:
            raise InvalidArgument(
                f"master {master!r} is an axis of another controller: a follower follows an "
                "axis of its own controller only",
                model=self._link.model.name,
            )
        name = master.letter if isinstance(master, Axis) else master
        return gear_to(
            self._link, self._tracker, self._letter, name, ratio,
            display=self._display, scale=self._scale,
        )  # fmt: skip

    def gear_off(self) -> None:
        """Turn off this axis's gearing (``GR 0``; it stays where it is), whoever set it up:
        the library (as :meth:`Gearing.off <galil.gearing.Gearing.off>`), or something else,
        found geared at connect or after a reset, whose own motion the library refuses until
        then (decision 0055). Sent even when the library knows of no gearing."""
        gear_off(self._link, self._tracker, self._letter)


class AxisPosition:
    """Defining the position of an :class:`Axis` (a class of its own only to keep each class
    short): :meth:`define_position` (``DP``)."""

    letter: str
    _letter: str
    _link: CommandLink
    _homing: AxisHoming

    def position_counts(self, value: object, what: str = "position") -> float:
        raise NotImplementedError

    def define_position(self, position: Amount = 0, *, shift_limits: bool = True) -> None:
        """Call the present position ``position`` (``DP``): in the axis's units, like
        :meth:`~Axis.move_to` (counts without a scale; a plain 0, the default, is 0 in any
        unit; a scale's offset stays as it is, so ``axis.position`` then reads ``position``).
        Nothing moves: the encoder (``TP``) and the reference (``RP``) both read ``position``
        after it (on a stepper, whose ``DP`` sets its step count, ``DE`` sets the encoder too:
        the library counts a stepper's encoder in its steps). Not burned: a power cycle
        starts again at 0.

        The soft limits stay where they are on the machine: ``BL`` and ``FL`` move by the same
        amount (a limit that is off stays off), so ``soft_limits`` reads new numbers. With
        ``shift_limits=False`` they keep their numbers, and so move on the machine; the call
        is then refused if the axis would be beyond one of them.

        ``axis.homed`` stays true after a home or index (the coordinate is moved by a known
        amount), its reason saying 0 was redefined; a move started after it is predicted in
        the new counts, and a move nobody waited for ends in the old ones.

        Raises:
            InvalidArgument: not a position, wrong units; the axis moves (the controller takes
                DP only at rest), it is geared to a master, or an axis is geared to it (a
                follower would jump with it: turn the gearing off first).
            LimitError: beyond the 32-bit position range, or a soft limit shifted beyond it;
                with ``shift_limits=False``, the axis beyond a soft limit.
        """
        if not isinstance(shift_limits, (bool, np.bool_)):
            raise InvalidArgument(f"shift_limits must be True or False, not {shift_limits!r:.40}")
        assert isinstance(self, Axis)
        scale = self._scale
        given: object = position  # (what the caller gave: any type, checked below)
        if scale is not None and type(given) is int and given == 0:
            position = 0 * scale.unit  # (the default: 0 in the axis's units)
        counts = count_of(self, self.position_counts(position, "position"), "position")
        with user_units({self._letter: self}):
            check_int32("DP", counts, self._letter, self._link.model.name)
            self._homing.define(counts, bool(shift_limits))


#: What is the controller's, not an axis's: said when a user reaches for it on an axis.
_CONTROLLERS = {
    "motor_off": "turn a motor off through the controller: controller.motor_off('{letter}')",
    "servo_here": "turn a motor on through the controller: controller.servo_here('{letter}')",
    "motor_on": "turn the motor off or on through the controller: "
    "controller.motor_off('{letter}') or controller.servo_here('{letter}')",
}


class Axis(AxisGearing, AxisPosition, FixedAttributes):
    """One axis of a controller.

    Properties read the controller's operands (``_TP``, ``_SP``, ...) and return Quantities when
    the axis has a scale, counts otherwise; setters validate and quantise before sending.
    """

    letter: ReadOnly[str] = ReadOnly()
    _elsewhere: ClassVar[dict[str, str]] = _CONTROLLERS

    if not TYPE_CHECKING:  # (a type checker still says an attribute is unknown)

        def __getattr__(self, name: str) -> NoReturn:
            raise missing_attribute(type(self), name, self)

    def __init__(
        self, link: CommandLink, letter: str, tracker: MotionTracker, routines: Routines
    ) -> None:
        self._link = link
        self._tracker = tracker
        self._routines = routines
        self._letter = letter
        self._scale: Scale | None = None
        self._homing = AxisHoming(link, letter, tracker)

    # -- units ------------------------------------------------------------------------------
    def set_scale(
        self, counts_per: QuantityLike | None, offset: QuantityLike | None = None, sign: int = 1
    ) -> Axis:
        """Give the axis a scale, e.g. ``counts_per=2000 / ureg.mm``; ``None`` removes it.

        Args:
            counts_per: counts per user unit (a length, or an angle for a rotary axis).
            offset: the user position at count 0.
            sign: -1 when the user's positive direction is the motor's negative one.

        Returns:
            The axis, so ``x = dmc.A.set_scale(...)`` reads well.
        """
        self._scale = None if counts_per is None else Scale(counts_per, offset, sign)
        return self

    @property
    def scale(self) -> Scale | None:
        """The axis's :class:`~galil.units.Scale`, if any."""
        return self._scale

    def display(self, profile: predict.Profile) -> predict.Profile:
        """``profile`` in this axis's unit: summaries and plots in it, and ``profile.q`` (a
        :class:`UnitProfile`) for positions, speeds and times as Quantities; the arrays
        themselves stay in counts."""
        scale = self._scale
        if not isinstance(profile, predict.Profile):
            raise InvalidArgument(f"profile must be a galil.Profile, not {profile!r:.60}")
        if scale is None:
            return profile
        return profile.recast(UnitProfile, display=scale.display, scale=scale)

    @property
    def _display(self) -> Display | None:
        return None if self._scale is None else self.display

    def position_counts(self, value: object, what: str = "position") -> float:
        """A position in this axis's units (or counts) as counts."""
        if self._scale is not None:
            return self._scale.position_to_counts(cast("QuantityLike", value), what)
        return counts_or_plain(value, what, self._letter)

    def distance_counts(self, value: object, what: str = "distance") -> float:
        """A distance in this axis's units (or counts) as counts."""
        if self._scale is not None:
            return self._scale.distance_to_counts(cast("QuantityLike", value), what)
        return counts_or_plain(value, what, self._letter)

    def rate_counts(self, value: object, power: int, what: str) -> float:
        """A speed (power 1) or acceleration (power 2) magnitude as counts/s^power.

        Raises:
            InvalidArgument: a negative value (the direction of a move comes from its target).
        """
        # abs() would run a "-5 mm/s" silently at +5 mm/s: the direction of a position move
        # comes from its target, so a negative value is a mistake worth naming.
        hint = " (the direction comes from the target; jog takes a signed speed)"
        return rate_magnitude_counts(
            self._scale, value, power, what, self._letter, hint if power == 1 else ""
        )

    def signed_rate_counts(self, value: object, power: int, what: str) -> float:
        """A signed speed or acceleration as counts/s^power."""
        return signed_rate_counts(self._scale, value, power, what, self._letter)

    def limit_counts(self, limit: object, power: int, what: str) -> float | None:
        """A user's speed (power 1) or acceleration (2) limit for this axis, in counts.

        ``limit`` is ``None``, one value, or a mapping of axis letters (or names) to values.
        """
        if isinstance(limit, Mapping):
            limit = limits_by_axis(self._link.model, limit, what).get(self._letter)
        if limit is None:
            return None
        counts = self.rate_counts(limit, power, what)
        if not counts > 0:
            raise InvalidArgument(f"{what} must be positive, got {limit!r}")
        return counts

    def _out_pos(self, counts: float) -> Reading:
        return counts if self._scale is None else self._scale.counts_to_position(counts)

    def _out_rate(self, counts: float, power: int) -> Reading:
        return counts if self._scale is None else _abs(self._scale.counts_to_rate(counts, power))

    # -- operands ---------------------------------------------------------------------------
    def _operand(self, name: str) -> float:
        return self._link.query_operands([f"_{name}{self._letter}"])[0]

    @property
    def position(self) -> Reading:
        """Encoder position ``_TP``."""
        return self._out_pos(self._operand("TP"))

    @property
    def reference_position(self) -> Reading:
        """Commanded (reference) position ``_RP``."""
        return self._out_pos(self._operand("RP"))

    @property
    def velocity(self) -> Reading:
        """Filtered actual velocity ``_TV`` (signed; averaged over ~0.25 s by the controller).

        The average lags: just after a stop it still reads part of the speed before it.
        """
        v = self._operand("TV")
        return v if self._scale is None else self._scale.counts_to_rate(v, 1)

    @property
    def error(self) -> Reading:
        """Position error ``_TE``."""
        e = self._operand("TE")
        return e if self._scale is None else self._scale.counts_to_distance(e)

    @property
    def moving(self) -> bool:
        """True while the profiler is running (``_BG``)."""
        return bool(self._operand("BG"))

    @property
    def motor_on(self) -> bool:
        """True when the servo is enabled (``_MO`` is 0)."""
        return not bool(self._operand("MO"))

    @property
    def stop_code(self) -> tuple[int, str]:
        """``_SC`` with its text, e.g. ``(4, "Decelerating or stopped by Stop Command (ST)")``."""
        code = round(self._operand("SC"))
        return code, codes.stop_text(code)

    # -- parameters -------------------------------------------------------------------------
    def check_parameter(self, cmd: str, counts: float) -> float:
        """Quantise and range-check SP/JG/HV/AC/DC/IT; a refusal also gives the user's units.

        Raises:
            LimitError: outside the model's range; a speed (SP, JG, HV) above 0 but under one
                step, which the controller would store as 0.
        """
        tm = tm_of(self._link.sample_period)  # the TM in force: SP/AC steps
        try:
            stored = predict.check_parameter(
                cmd, counts, self._link.model, axis=self._letter, tm=tm
            )
            if stored == 0 and counts != 0 and cmd in _SPEEDS:
                raise _under_one_step(cmd, counts, self._link.model, tm, self._letter)
        except LimitError as exc:
            state_in_units(exc, self._scale, _KIND[_POWER.get(cmd, 1)])
            raise
        return stored

    def _set_param(self, cmd: str, counts: float) -> None:
        value = self.check_parameter(cmd, counts)
        command = _SETTERS[cmd](model=self._link.model, **{self._letter: value})
        with self._tracker.lock:  # (a move another thread starts gets the change stamped)
            if cmd == "DC":
                refuse_in_motion(self._link, self._tracker, self._letter, cmd)
            self._send_param(cmd, command, value)

    def _send_param(self, cmd: str, command: cmds.Command, value: float) -> None:
        handle = self._tracker.active(self._letter)
        track = None if handle is None else handle.track(self._letter)
        if (
            handle is None
            or cmd not in _FOLLOWED
            or self._letter in handle._ended
            or (cmd == "SP" and track is not None and track.kind == "jog")  # (SP: not a jog's)
        ):
            self._link.command_line([command])  # (nothing in motion for it to change)
            return
        # A change in motion: stamp it so the move's prediction can follow it. Interrupted,
        # the prediction cannot know whether it took effect: the motion is stopped (decision
        # 0028). DC gets here in a jog, a stop ramping down, or (unseen by the handle, whose
        # prediction then refuses it and stops claiming to be exact) a limit's stop:
        # refuse_in_motion let it out.
        with stop_on_error(self._link, self._tracker, self._letter):
            replies = change_line(self._link, handle, self._letter, [command, cmds.time_stamp()])
        event = _FOLLOWED[cmd]
        handle.add_event(self._letter, sample_of(replies[-1]), lambda t: event(t, value))

    @property
    def speed(self) -> Reading:
        """Slew speed ``SP`` (the controller's quantised value); settable in motion."""
        return self._out_rate(self._operand("SP"), 1)

    @speed.setter
    def speed(self, value: Amount) -> None:
        self._set_param("SP", self.rate_counts(value, 1, "speed"))

    @property
    def accel(self) -> Reading:
        """Acceleration ``AC``; settable in motion."""
        return self._out_rate(self._operand("AC"), 2)

    @accel.setter
    def accel(self, value: Amount) -> None:
        self._set_param("AC", self.rate_counts(value, 2, "accel"))

    @property
    def decel(self) -> Reading:
        """Deceleration ``DC``: not in a PA/PR move (refused while the library's runs), but
        in a jog, or while an ``ST`` ramps down (the command reference); the motion's
        prediction follows it from the next sample."""
        return self._out_rate(self._operand("DC"), 2)

    @decel.setter
    def decel(self, value: Amount) -> None:
        self._set_param("DC", self.rate_counts(value, 2, "decel"))

    @property
    def smoothing(self) -> float:
        """Independent time constant ``IT`` (1 = no smoothing)."""
        return self._operand("IT")

    @smoothing.setter
    def smoothing(self, value: float) -> None:
        self._set_param("IT", _smoothing_value(value, self._link.model))

    @property
    def jog_speed(self) -> Reading:
        """Jog speed ``JG`` (signed). Setting it never starts a jog: while the controller runs
        one it changes the speed in motion, otherwise it is kept for the next jog. (``JG``
        also selects jog mode: a program's ``BG`` after it, with no ``PR``/``PA`` between,
        jogs.)"""
        v = self._operand("JG")
        return v if self._scale is None else self._scale.counts_to_rate(v, 1)

    @jog_speed.setter
    def jog_speed(self, value: Amount) -> None:
        # Never a BG: the controller is asked whether a jog runs (see moves.set_jog_speed).
        v = self.check_parameter("JG", self.signed_rate_counts(value, 1, "jog speed"))
        set_jog_speed(self._link, self._tracker, self._letter, v)

    @property
    def soft_limits(self) -> tuple[Reading | None, Reading | None]:
        """``(low, high)`` soft limits (``BL``, ``FL``); ``None`` on either side removes it,
        and reads back for a side that is off (``BL`` -2147483648, ``FL`` 2147483647: the
        values that disable them)."""
        bl, fl = self._link.query_operands([f"_BL{self._letter}", f"_FL{self._letter}"])
        low = None if bl <= INT32_MIN else self._out_pos(bl)
        high = None if fl >= INT32_MAX else self._out_pos(fl)
        if self._scale is not None and self._scale.sign < 0:
            low, high = high, low
        return low, high

    @soft_limits.setter
    def soft_limits(self, limits: tuple[Amount | None, Amount | None]) -> None:
        bl, fl = _soft_limit_counts(self, limits)
        model = self._link.model
        a = self._letter
        self._link.command_line([cmds.bl(model=model, **{a: bl}), cmds.fl(model=model, **{a: fl})])

    # -- moves ------------------------------------------------------------------------------
    def _move(
        self, value: object, relative: bool, dry_run: bool, **overrides: Unpack[MoveOverrides]
    ) -> MoveHandle:
        a = self._letter
        moves = [resolve_move(self, value, relative, overrides)]  # (resolve_moves of one axis)
        try:
            return execute_move(
                self._link,
                self._tracker,
                moves,
                relative=relative,
                dry_run=dry_run,
                display={a: self.display},
            )
        except LimitError as exc:  # user_units() as a plain handler: cheaper on every move
            in_user_units(exc, {a: self})
            raise

    def move_to(self, position: Amount, **overrides: Unpack[MoveOverrides]) -> MoveHandle:
        """Move to an absolute position (``PA`` then ``BG``).

        Keyword overrides ``speed``, ``accel``, ``decel`` apply to this move (they are sent
        with it and stay set on the controller).

        Raises:
            InvalidArgument: wrong units, bad values, axis busy or motor off.
            LimitError: a value out of the model's range, or a path crossing a soft limit.
        """
        check_overrides("move_to", overrides)
        return self._move(position, False, False, **overrides)

    def move_by(self, distance: Amount, **overrides: Unpack[MoveOverrides]) -> MoveHandle:
        """Move by a relative distance (``PR`` then ``BG``)."""
        check_overrides("move_by", overrides)
        return self._move(distance, True, False, **overrides)

    def plan_to(self, position: Amount, **overrides: Unpack[MoveOverrides]) -> UnitProfile:
        """Predict and check ``move_to(position)`` without sending anything. The profile's
        ``.q`` reads it in the axis's units (on an axis with a scale)."""
        check_overrides("plan_to", overrides)
        return _planned(self._move(position, False, True, **overrides).profile)

    def plan_by(self, distance: Amount, **overrides: Unpack[MoveOverrides]) -> UnitProfile:
        """Predict and check ``move_by(distance)`` without sending anything. The profile's
        ``.q`` reads it in the axis's units (on an axis with a scale)."""
        check_overrides("plan_by", overrides)
        return _planned(self._move(distance, True, True, **overrides).profile)

    def jog(self, speed: Amount) -> MoveHandle:
        """Jog at ``speed`` (signed).

        Already jogging: the speed changes in motion and the jog's own handle is returned, its
        prediction now including the change (at the controller sample it took effect).

        Raises:
            InvalidArgument: wrong units, a position move in progress, a stopping jog, or the
                motor off.
            LimitError: a speed beyond the model's range.
        """
        v = self.check_parameter("JG", self.signed_rate_counts(speed, 1, "jog speed"))
        with user_units({self._letter: self}):  # (a start beyond FL/BL: in its unit)
            return jog(self._link, self._tracker, self._letter, v, display=self._display)

    def increment(self, n: Amount) -> MoveHandle:
        """Increment the position by ``n`` (``IP``).

        Idle: the same as ``move_by(n)``. During a position move: the target moves by ``n``
        (same direction only; the controller refuses a reversal with TC 16, so it is refused
        here first). While jogging: an instant step of the reference position. In motion the
        handle of the move in progress is returned, its prediction updated.

        Raises:
            InvalidArgument: wrong units, a reversal, an axis stopping, homing, contour or vector.
            CommandError: TC 16, a reversal of a move the library did not start (a program's)
                in its last samples, at its target: nothing shows its direction then.
        """
        counts = count_of(self, self.distance_counts(n, "increment"), "increment")
        with user_units({self._letter: self}):
            return increment(self._link, self._tracker, self._letter, counts, display=self._display)

    def speed_schedule(
        self,
        distance: Amount,
        changes: SpeedChanges,
        *,
        speed: Amount | None = None,
        label: str = "GSCHED",
    ) -> MoveHandle:
        """Move by ``distance``, changing speed at given distances from the start.

        The Galil form of a "distance to change" schedule: each ``(at, new_speed)`` becomes an
        ``AD`` trippoint and an ``SP`` in a small downloaded program, run with ``XQ``. Every
        change point is validated first (the ramp before it must have finished); an invalid
        one raises :class:`~galil.errors.ScheduleError` naming the earliest valid point, and
        nothing is sent.

        Args:
            distance: total relative move.
            changes: ``[(at, new_speed), ...]``, ``at`` measured from the start of the move
                along it (a positive distance, whichever way the move goes).
            speed: initial speed (default: the axis's SP).
            label: the routine's label (up to 7 characters, with or without its ``#``); the
                routine is installed beside the program in memory, which stays as it was.
                The labels of the library's other routines (``GWDOG``, ``GINWAIT`` and
                their inner ones) are refused: the schedule would replace their code.

        Stopped or aborted through the library before its end, it is cancelled: its routine
        halted, ``SP`` back as before it (one run to its end keeps its last speed).

        Raises:
            ScheduleError: a change point the profiler cannot honour (nothing is sent).
            InvalidArgument: wrong units, bad values or label, the axis busy or its motor off,
                another schedule still running (its routine holds thread 0).
            LimitError: a speed out of range, a path crossing a soft limit or taking a
                follower past its soft limits or the model's SP maximum.
        """
        return _speed_schedule(self, distance, changes, speed, label)

    def stop(self) -> None:
        """Decelerate to a stop (``ST``) at DC."""
        stop_axes(self._link, self._tracker, self._letter)

    # -- homing and switches (galil.homing) ------------------------------------------------
    def home(self, *, switch: predict.HomeSwitch | None = None) -> MoveHandle:
        """Home the axis (``HM``): find the home switch's edge, then the index, which becomes
        position 0; stop code 10. ``switch`` (positions in counts) makes a prediction.

        Raises:
            InvalidArgument: moving, motor off, into an active switch or past FL/BL.
            LimitError: SP or HV 0 (JG 0 for find_index), as a move at SP 0 is.
            LimitError: (``switch`` given) the predicted path crosses BL or FL: the controller
                would stop it there, short of the switch (also for find_edge, find_index).
        """
        return self._home("HM", switch)

    def find_edge(self, *, switch: predict.HomeSwitch | None = None) -> MoveHandle:
        """Move at SP to the home switch's edge (``FE``); stop code 9, no position defined."""
        return self._home("FE", switch)

    def find_index(self, *, switch: predict.HomeSwitch | None = None) -> MoveHandle:
        """Move at the jog speed (its sign is the direction) to the next index pulse (``FI``),
        which becomes position 0; stop code 10."""
        return self._home("FI", switch)

    def _home(self, kind: str, switch: predict.HomeSwitch | None) -> MoveHandle:
        with user_units({self._letter: self}):  # (a start beyond FL/BL: in its unit)
            return self._homing.start(kind, switch, display=self._display)

    @property
    def homed(self) -> Homed:
        """Whether the axis is homed, and how the library knows (``bool(axis.homed)``)."""
        return self._homing.homed()

    @property
    def switches(self) -> Switches:
        """Limit and home switches (``TS``, one round trip); True means tripped."""
        return read_switches(self._link, self._letter)

    @property
    def home_speed(self) -> Reading:
        """``HV``: the slow speed of HM's last stages and FI's return; SP's range and step.

        A model without HV (``model.has_hv`` false: the Optima-era cards) reads its fixed
        slow speed, ``model.home_slow_speed``, without a query.

        Raises (setting it):
            InvalidArgument: the model has no HV (nothing is sent).
            LimitError: above the model's SP maximum, or a speed above 0 that is less than
                one step (it would be sent as HV 0, which HM and FI refuse).
        """
        model = self._link.model
        if not model.has_hv:
            return self._out_rate(model.home_slow_speed, 1)
        return self._out_rate(self._operand("HV"), 1)

    @home_speed.setter
    def home_speed(self, value: Amount) -> None:
        cmds.require_hv(self._link.model)  # (no HV on the model: refused first)
        counts = _home_speed_counts(self, value)
        self._link.command_line([cmds.hv(model=self._link.model, **{self._letter: counts})])

    # -- motor and loop settings (galil.tuning; ranges per model) --------------------------
    motor_type = Setting("MT", cmds.mt, motor_type, still=True, motor_off=True)
    """``MT``: a :class:`~galil.tuning.MotorType` (servo, stepper variants ...); only with the
    motor off (:meth:`~galil.Controller.motor_off`) and the axis at rest."""
    kp = Setting("KP", cmds.kp, float)
    """``KP``: proportional gain."""
    ki = Setting("KI", cmds.ki, float)
    """``KI``: integral gain."""
    kd = Setting("KD", cmds.kd, float)
    """``KD``: derivative gain."""
    stepper_smoothing = Setting("KS", cmds.ks, float)
    """``KS``: smoothing of a stepper's step pulses (``model.ks_range``: 0.25 .. 64 on the
    40x0, 0.5 .. 64 on the 41x3)."""
    integrator_limit = Setting("IL", cmds.il, float)
    """``IL``: integrator limit, volts (negative on the 41x3: frozen during a move)."""
    torque_limit = Setting("TL", cmds.tl, float)
    """``TL``: torque (output) limit, volts."""
    error_limit = Setting("ER", cmds.er, whole)
    """``ER``: position-error limit, counts (on the 41x3 also 0, error output on, and -1,
    off)."""
    off_on_error = Setting("OE", cmds.oe, whole)
    """``OE``: 0 off, 1 on position error / amplifier error / abort, 2 on limits, 3 all."""
    brush = Setting("BR", cmds.br, whole, still=True)
    """``BR``: -1 external drive, 0 brushless, 1 brush."""
    encoder_config = Setting("CE", cmds.ce, EncoderConfig.of, still=True)
    """``CE``: a :class:`~galil.tuning.EncoderConfig` (main and auxiliary encoder types); at
    rest only. "When using a servo motor, changing the CE type can cause the motor to run
    away" (the command reference): change it with the motor off (not required: decision
    0048) and check the count's direction before ``servo_here()``."""
    limit_disable = Setting("LD", cmds.ld, limit_disable_of, available=cmds.require_limit_disable)
    """``LD``: a :class:`~galil.tuning.LimitDisable`, the limit switches that no longer stop
    motion (NONE, FORWARD, REVERSE, BOTH); for a stage with a switch missing or unwired. The
    soft limits stay, and the switches' inputs still read (``axis.switches``). Refused,
    before anything is sent, on a model without LD (``model.has_limit_disable``; decision
    0046)."""

    def __repr__(self) -> str:
        unit = f" in {self._scale.unit:~}" if self._scale is not None else " in counts"
        return f"<Axis {self._letter}{unit} of {self._link.model.name}>"


def _home_speed_counts(axis: Axis, value: object) -> float:
    """``home_speed = value`` as the HV the controller stores.

    Raises:
        InvalidArgument: not a speed, or a negative one.
        LimitError: above the model's maximum; above 0 but under one step (HV 0, with which
            HM and FI are refused), in the user's units too.
    """
    return axis.check_parameter("HV", axis.rate_counts(value, 1, "home_speed"))


#: The speeds a nonzero request of under one step would silently set to 0, and what 0 does.
_SPEEDS = {
    "SP": "a move at SP 0 is refused",
    "JG": "a jog at JG 0 never moves",
    "HV": "home() and find_index() are refused at HV 0",
}


def _under_one_step(cmd: str, counts: float, model: ModelSpec, tm: float, axis: str) -> LimitError:
    """The refusal of a speed above 0 but under one step: the controller would store 0."""
    step = model.speed_resolution(tm)
    return LimitError(
        f"{cmd} {counts:g} counts/s is less than one step, the smallest speed above 0 "
        f"({step:g} counts/s at TM {tm:g}): it would be {cmd} 0, and {_SPEEDS[cmd]}",
        name=cmd,
        value=counts,
        limit=step,
        axis=axis,
        model=model.name,
        floor=True,
    )


#: What an axis without a scale says when given a fraction of a count.
_WHOLE_HINT = (
    " (an axis without a scale takes whole counts; with a scale, a value in its unit is"
    " rounded to the nearest count)"
)


def count_of(axis: Axis, counts: float, what: str) -> int:
    """``counts`` (``what``, converted from the user's value) as whole counts: rounded to the
    nearest (a half to the even one) on an axis with a scale, whose units rarely land on a
    count; on an axis without one the value is counts, and a fraction of one is refused, as
    the predictor and ``galil plan`` refuse it (decision 0092).

    Raises:
        InvalidArgument: a fraction of a count on an axis without a scale.
    """
    if axis._scale is not None:
        return round(counts)
    return whole_counts(counts, what, _WHOLE_HINT)


def _limit_count(axis: Axis, value: object, what: str) -> int:
    return count_of(axis, axis.position_counts(value, what), what)


def _soft_limit_counts(axis: Axis, limits: Any) -> tuple[int, int]:
    """``BL`` and ``FL`` in counts for ``soft_limits = (low, high)`` (``None``: no limit).

    Raises:
        InvalidArgument: not a pair, wrong units, low above high.
        LimitError: outside the 32-bit position range.
    """
    try:
        low, high = limits
    except (TypeError, ValueError) as exc:
        raise InvalidArgument(f"soft_limits takes (low, high), got {limits!r}") from exc
    bl = INT32_MIN if low is None else _limit_count(axis, low, "reverse soft limit")
    fl = INT32_MAX if high is None else _limit_count(axis, high, "forward soft limit")
    scale = axis._scale
    if scale is not None and scale.sign < 0:
        bl, fl = fl, bl  # a negative scale sign swaps the ends
        bl = INT32_MIN if high is None else bl
        fl = INT32_MAX if low is None else fl
    if bl > fl:
        raise InvalidArgument(
            f"soft limits ({_show(low)}, {_show(high)}): low is above high (takes (low, high))"
        )
    with user_units({axis.letter: axis}):
        for name, v in (("BL", bl), ("FL", fl)):
            check_int32(name, v, axis.letter, axis._link.model.name)
    return bl, fl


def resolve_moves(
    axes: Mapping[str, Axis],
    targets: Mapping[str, object],
    relative: bool,
    overrides: Mapping[str, object],
) -> list[AxisMove]:
    """Turn targets and overrides in user units into counts, refusing bad values first.

    Raises:
        InvalidArgument: no targets, an axis twice, wrong units.
        LimitError: a value outside the model's range or the 32-bit position range.
    """
    if not isinstance(targets, Mapping) or not targets:
        raise InvalidArgument(
            f"targets must be a non-empty mapping of axis to value, got {targets!r}"
        )
    seen: set[str] = set()
    for name in targets:
        if axes[name].letter in seen:
            raise InvalidArgument(f"axis {axes[name].letter} given twice")
        seen.add(axes[name].letter)
    return [
        resolve_move(axes[name], value, relative, overrides, named=True)
        for name, value in targets.items()
    ]


def resolve_move(
    axis: Axis,
    value: object,
    relative: bool,
    overrides: Mapping[str, object],
    *,
    named: bool = False,
) -> AxisMove:
    """One axis's target (or distance) and overrides in counts (:func:`resolve_moves`; with
    ``named``, a refusal of the target names its axis: one of several).

    Raises:
        InvalidArgument: wrong units.
        LimitError: a value outside the model's range or the 32-bit position range.
    """
    given: dict[str, float] = {}
    if overrides:
        for key, cmd in OVERRIDES.items():
            if overrides.get(key) is not None:
                counts = axis.rate_counts(overrides[key], _POWER[cmd], key)
                given[key] = axis.check_parameter(cmd, counts)
    what = ("distance" if relative else "target") + (f" of {axis.letter}" if named else "")
    if relative:
        amount = count_of(axis, axis.distance_counts(value, what), what)
    else:
        amount = count_of(axis, axis.position_counts(value, what), what)
    if not INT32_MIN <= amount <= INT32_MAX:
        with user_units({axis.letter: axis}):
            check_int32("PR" if relative else "PA", amount, axis.letter, axis._link.model.name)
    if given:
        return AxisMove(axis.letter, amount, **given)
    return AxisMove(axis._letter, amount)


@contextlib.contextmanager
def user_units(axes: Mapping[str, Axis]) -> Iterator[None]:
    """Add the user's units to a refusal raised in counts inside the block: positions (soft
    limits, the 32-bit range) and the speed and acceleration a path implies."""
    try:
        yield
    except LimitError as exc:
        in_user_units(exc, axes)
        raise


def in_user_units(exc: LimitError, axes: Mapping[str, Axis]) -> None:
    """Add the user's units to ``exc`` (raised in counts) when its axis has a scale."""
    axis = axes.get(exc.axis) if exc.axis else None
    if axis is not None:
        state_in_units(exc, axis.scale, "distance" if exc.name == "IP" else None)


_KIND = {1: "speed", 2: "acceleration"}


def _speed_schedule(
    axis: Axis, distance: Amount, changes: SpeedChanges, speed: Amount | None, label: str
) -> MoveHandle:
    """:meth:`Axis.speed_schedule`: everything checked (the label first), then started."""
    label = schedule_label(label)  # a bad label is refused before anything else
    d = count_of(axis, axis.distance_counts(distance, "distance"), "distance")
    pairs = _schedule_pairs(axis, changes)
    first = None
    if speed is not None:
        first = axis.check_parameter("SP", axis.rate_counts(speed, 1, "speed"))
    with user_units({axis.letter: axis}):
        return speed_schedule(
            axis._link,
            axis._tracker,
            axis._routines,
            axis.letter,
            d,
            pairs,
            speed=first,
            label=label,
            display=axis._display,
        )


def _schedule_pairs(axis: Axis, changes: Any) -> list[tuple[float, float]]:
    """A speed schedule's ``(at, new_speed)`` pairs in counts: trigger distances measured
    along the move (positive), speeds checked as SP."""
    try:
        if isinstance(changes, (str, bytes, Mapping)):
            raise TypeError("a string or a mapping")
        items = list(changes)
    except TypeError as exc:
        raise InvalidArgument(
            f"changes must be a list of (at, speed), got {changes!r:.60}"
        ) from exc
    pairs = []
    sign = 1 if axis.scale is None else axis.scale.sign
    for i, item in enumerate(items):
        try:
            at, sp = item
        except (TypeError, ValueError) as exc:
            raise InvalidArgument(f"each change is (at, speed), got {item!r}") from exc
        counts = axis.distance_counts(at, "trigger distance")
        if counts * sign < 0:  # (the scale's sign turns a user's positive one negative)
            raise InvalidArgument(
                f"change {i}: trigger distance {at!r} is negative; it is measured from the "
                "start of the move along it, a positive distance whichever way it goes"
            )
        pairs.append((abs(counts), axis.check_parameter("SP", axis.rate_counts(sp, 1, "speed"))))
    return pairs
