"""Motor and loop settings, flash burns, and the sample period that follows TM.

Settings are typed, range-checked per model, and sent through the builders of
:mod:`galil.protocol.commands`; an :class:`~galil.axis.Axis` declares each as one
:class:`Setting` descriptor (``axis.kp = 10`` sends ``KPA=10``; ``axis.kp`` reads ``_KPA``)::

    dmc.motor_off("A")  # MT only with the motor off
    dmc.A.motor_type = MotorType.STEPPER_ACTIVE_LOW
    dmc.A.kp, dmc.A.ki, dmc.A.kd = 10, 0.5, 80
    dmc.save()          # BN: the parameters survive a power cycle

``BN``, ``BP`` and ``BV`` write flash memory and keep the controller busy; they get the
model's ``burn_timeout`` (3 s, as EPICS allows) rather than the link's default.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import re
from collections.abc import Callable, Iterable, Iterator
from typing import Generic, Protocol, TypeVar, overload

from galil.errors import CommandError, GalilError, InvalidArgument, decimal_hint
from galil.link import CommandLink, Link, check_timeout
from galil.models import MOTOR_TYPES, ModelSpec
from galil.motion import MotionTracker, refuse_in_motion
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.protocol.numbers import read_one
from galil.protocol.session import Completed
from galil.routines import Routines

__all__ = [
    "EncoderConfig",
    "EncoderType",
    "LimitDisable",
    "MotorType",
    "Setting",
    "burn",
    "burn_parameters",
    "follow_tm",
    "limit_disable_of",
    "motor_type",
    "whole",
]

_LOG = logging.getLogger("galil.tuning")


class MotorType(float, enum.Enum):
    """``MT`` values (``galil.models.MOTOR_TYPES`` says what each means)."""

    SERVO = 1.0
    SERVO_REVERSED = -1.0
    PWM_SERVO = 1.5
    PWM_SERVO_REVERSED = -1.5
    STEPPER_ACTIVE_HIGH = -2.0
    STEPPER_ACTIVE_LOW = 2.0
    STEPPER_ACTIVE_HIGH_REVERSED = -2.5
    STEPPER_ACTIVE_LOW_REVERSED = 2.5
    SERVO_2PB = 4.0
    SERVO_2PB_REVERSED = -4.0
    ETHERCAT_POSITION = 10.0
    ETHERCAT_TORQUE = 11.0
    ETHERCAT_TORQUE_REVERSED = -11.0

    @property
    def stepper(self) -> bool:
        """Whether this is a stepper type (step and direction outputs)."""
        return abs(self.value) in (2.0, 2.5)

    @property
    def description(self) -> str:
        """What the controller does with it."""
        return MOTOR_TYPES[self.value]


class LimitDisable(enum.IntEnum):
    """``LD``: which limit switches no longer stop motion (decision 0046).

    A disabled switch neither stops motion towards it nor refuses a start towards it, and runs
    no ``#LIMSWI``; its input still reads (``_LF``/``_LR``, ``TS``, ``axis.switches``). The
    soft limits ``FL``/``BL`` stay: "LD does not disable software limits set by BL and FL"
    (DMC-4103 command reference, LD).
    """

    NONE = 0
    FORWARD = 1
    REVERSE = 2
    BOTH = 3

    @property
    def forward(self) -> bool:
        """Whether the forward switch is disabled."""
        return bool(self & 1)

    @property
    def reverse(self) -> bool:
        """Whether the reverse switch is disabled."""
        return bool(self & 2)


class EncoderType(enum.IntEnum):
    """One encoder's type in ``CE`` (the DMC-4103 command reference's CE table)."""

    QUADRATURE = 0
    PULSE_DIRECTION = 1
    QUADRATURE_REVERSED = 2
    PULSE_DIRECTION_REVERSED = 3

    @property
    def reversed(self) -> bool:
        """Whether the encoder's direction is reversed."""
        return self >= 2

    @property
    def pulse_direction(self) -> bool:
        """Whether it is a pulse and direction input (pulse on CHA, direction on CHB)."""
        return bool(self & 1)


def _encoder_type(value: object, which: str) -> EncoderType:
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidArgument(f"EncoderConfig {which} takes an EncoderType, not {value!r}")
    try:
        return EncoderType(value)
    except ValueError:
        raise InvalidArgument(
            f"EncoderConfig {which} is an EncoderType (0 .. 3), not {value!r}"
        ) from None


class EncoderConfig(int):
    """``CE``: the main and the auxiliary encoder's types of one axis (decision 0048).

    The value is an ``int``, the number ``CE`` takes: the main encoder's
    :class:`EncoderType` plus four times the auxiliary encoder's, 0 .. 15 (``CE 10`` is
    both reversed quadrature)::

        EncoderConfig(main=EncoderType.QUADRATURE_REVERSED)  # 2
        int(EncoderConfig(aux=EncoderType.PULSE_DIRECTION))  # 4
        EncoderConfig.of(10).aux                             # QUADRATURE_REVERSED

    Raises:
        InvalidArgument: a type that is not an :class:`EncoderType` (0 .. 3).
    """

    def __new__(
        cls, main: int = EncoderType.QUADRATURE, aux: int = EncoderType.QUADRATURE
    ) -> EncoderConfig:
        return super().__new__(cls, _encoder_type(main, "main") + 4 * _encoder_type(aux, "aux"))

    @classmethod
    def of(cls, value: float) -> EncoderConfig:
        """The configuration of a ``CE`` value (``_CEA``), 0 .. 15.

        Raises:
            InvalidArgument: not a whole number in 0 .. 15.
        """
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidArgument(f"CE is a number 0 .. 15, not {value!r}")
        if value not in range(16):
            raise InvalidArgument(f"CE is a whole number 0 .. 15, not {value!r}")
        n = int(value)
        return cls(n % 4, n // 4)

    @property
    def main(self) -> EncoderType:
        """The main encoder's type."""
        return EncoderType(int(self) % 4)

    @property
    def aux(self) -> EncoderType:
        """The auxiliary encoder's type."""
        return EncoderType(int(self) // 4)

    def __repr__(self) -> str:
        return f"EncoderConfig(main={self.main.name}, aux={self.aux.name})"

    __str__ = int.__repr__


def limit_disable_of(value: float) -> LimitDisable:
    """The :class:`LimitDisable` of an ``_LD`` value."""
    return LimitDisable(round(value))


class _HasLink(Protocol):
    letter: str
    _link: CommandLink
    _tracker: MotionTracker


Builder = Callable[..., Command]
T = TypeVar("T")


def motor_type(value: float) -> MotorType | float:
    """The :class:`MotorType` of an MT value (the number itself for a type without a name)."""
    try:
        return MotorType(value)
    except ValueError:
        return value


def whole(value: float) -> int:
    """An integer setting (ER, OE, BR) as read back."""
    return round(value)


class Setting(Generic[T]):
    """A per-axis setting read from ``_XXa`` and written with its command's builder.

    Args:
        mnemonic: the two letters (``"KP"``).
        builder: the builder in :mod:`galil.protocol.commands` (range-checks per model).
        convert: turns the number read back into the setting's type.
        still: the controller takes it only at rest ("Not Valid while in motion"): refused
            on an axis the library knows is moving (:func:`~galil.motion.refuse_in_motion`),
            the check and the line under the tracker's lock (no start, ``SH`` or ``MO`` of
            the library's from another thread in between).
        motor_off: the controller takes it only with the axis's motor off (``MT``: "The axis
            must be in the motor off state (MO) before setting MT", TC 135 otherwise): the
            setter reads ``_MO`` first (one query, under the tracker's lock with the line)
            and refuses it with the motor on.
        available: raises :class:`~galil.errors.InvalidArgument` for a model without the
            command, before reading or writing it (``LD``).
    """

    def __init__(
        self,
        mnemonic: str,
        builder: Builder,
        convert: Callable[[float], T],
        *,
        still: bool = False,
        motor_off: bool = False,
        available: Callable[[ModelSpec], None] | None = None,
    ) -> None:
        self.mnemonic = mnemonic
        self.available = available
        self.builder = builder
        self.convert = convert
        self.still = still
        self.motor_off = motor_off
        self.name = mnemonic.lower()

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type) -> Setting[T]: ...
    @overload
    def __get__(self, obj: _HasLink, owner: type) -> T: ...
    def __get__(self, obj: _HasLink | None, owner: type) -> Setting[T] | T:
        if obj is None:
            return self
        if self.available is not None:
            self.available(obj._link.model)
        return self.convert(obj._link.query_operands([f"_{self.mnemonic}{obj.letter}"])[0])

    def __set__(self, obj: _HasLink, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidArgument(f"{self.name} takes a number, not {value!r}{decimal_hint(value)}")
        number = float(value.value) if isinstance(value, MotorType) else value
        link = obj._link
        command = self.builder(model=link.model, **{obj.letter: number})
        if not (self.still or self.motor_off):
            link.command_line([command])
            return
        # The checks and the line under the tracker's lock: no start, SH nor MO from another
        # thread between them (the library's own; a program's motion is the controller's).
        with obj._tracker.lock:
            if self.still:
                refuse_in_motion(link, obj._tracker, obj.letter, self.mnemonic)
            if self.motor_off and not round(link.query_operands([f"_MO{obj.letter}"])[0]):
                raise InvalidArgument(
                    f"{self.mnemonic} needs axis {obj.letter}'s motor off (the command "
                    'reference: "The axis must be in the motor off state (MO) before setting '
                    f'MT"): call controller.motor_off("{obj.letter}") first (and '
                    "servo_here() after)",
                    model=link.model.name,
                )
            link.command_line([command])


def burn(
    link: CommandLink,
    what: str,
    timeout: float | None = None,
    tracker: MotionTracker | None = None,
    routines: Routines | None = None,
) -> None:
    """``BN``/``BP``/``BV`` with a timeout that fits a flash write (``model.burn_timeout``).

    ``BP`` is "Not Valid while in motion" (the DMC-4103 reference; TC 7): with ``tracker``,
    it is refused unsent while an axis moves that the library itself started and has not
    seen end (:func:`~galil.motion.refuse_in_motion`: one query of that axis, none
    otherwise). Motion started elsewhere (a program, a raw ``BG``) gets the controller's
    refusal. With ``routines``, ``BP`` (refused while a program runs: TC 17 in the simulator,
    as ``BN``; unsourced for ``BP`` on a controller, decision 0087)
    halts the library's own threads for the burn and starts them again
    (:meth:`~galil.routines.Routines.paused`), and is refused unsent while a program of the
    user's runs.

    Raises:
        InvalidArgument: ``what`` is not BN, BP or BV; a bad ``timeout``; ``BP`` while the
            library's own motion runs, or (``routines``) while a program of the user's runs.
        CommandError: the controller refused (a program running: TC 17; motion: TC 7).
    """
    command = cmds.burn(what)
    wait = check_timeout(timeout, link.model.burn_timeout)
    if tracker is None or command.text != "BP":
        link.command_line([command], timeout=wait)
        return
    with tracker.lock:  # (no start in another thread between the check and BP)
        for letter in link.model.axes:
            refuse_in_motion(link, tracker, letter, "BP")
        with _paused(routines, "BP") as halted:
            link.command_line([command], timeout=wait)
    _say_halted(halted, "BP")


@contextlib.contextmanager
def _paused(routines: Routines | None, what: str) -> Iterator[tuple[int, ...]]:
    """:meth:`Routines.paused <galil.routines.Routines.paused>`, or nothing without
    ``routines``."""
    if routines is None:
        yield ()
        return
    with routines.paused(what) as halted:
        yield halted


def _say_halted(halted: tuple[int, ...], what: str) -> None:
    if halted:
        _LOG.warning(
            "galil: library thread(s) %s halted for %s (refused while a program runs) and "
            "started again",
            list(halted),
            what,
        )


_BN = cmds.burn("BN")
_ECHO_ON = cmds.eo(1).text


def burn_parameters(
    link: Link, timeout: float | None = None, routines: Routines | None = None
) -> None:
    """``BN``, burning the controller's own ``CW`` and ``EO`` rather than the link's
    (decision 0057).

    At connect the link set ``CW 1`` (unsolicited output marked) and ``EO 0`` (no echo) for
    itself where it needed them; ``BN`` saves both. They go back to the values :meth:`close
    <galil.controller.Controller.close>` restores for the burn and the link's right after,
    under the link's lock: ``CW 2`` + ``BN`` + ``CW 1`` as separate lines in one write (each
    runs even if ``BN`` is refused); with the echo, ``EO 1`` first, then ``BN`` + ``EO 0``
    stripped of their echo. Refused unsent while a program thread runs: the controller
    refuses ``BN`` then (TC 17), and the thread's output would be unmarked in between.
    Anything raised in between sends the link's settings again and resynchronises.

    With ``routines``, the library's own threads (the watchdog) are halted for the burn and
    started again (:meth:`~galil.routines.Routines.paused`; decision 0087).

    Raises:
        InvalidArgument: a bad ``timeout``; a program thread runs (nothing is burned).
        CommandError: the controller refused a part.
    """
    wait = check_timeout(timeout, link.model.burn_timeout)
    with _paused(routines, "BN") as halted:
        _burn_parameters(link, wait)
    _say_halted(halted, "BN")


def _burn_parameters(link: Link, wait: float) -> None:
    """:func:`burn_parameters` once ``wait`` is checked (its threads halted, if any)."""
    own = link.own_settings()
    echo = link.echo
    theirs = [c for c, _ in reversed(own) if c.text != _ECHO_ON]
    ours = [m for c, m in own if c.text != _ECHO_ON]
    to_echo = [m for c, m in own if c.text == _ECHO_ON]  # [EO 0] when the link turned it off
    with link.locked():
        _refuse_while_threads_run(link)
        try:
            if not to_echo:
                done = link.roundtrip_locked([*theirs, _BN, *ours], wait)
            else:
                done = _burn_with_echo(link, theirs, [*to_echo, *ours], wait, echo)
        except BaseException:
            if own:
                with contextlib.suppress(GalilError):
                    link.settle_locked([*to_echo, *ours], wait + link.timeout, echo=echo)
            raise
        _explain_first(link, done, wait)


def _burn_with_echo(
    link: Link, theirs: list[Command], ours: list[Command], wait: float, echo: bool
) -> list[Completed]:
    """``EO 1`` (and ``theirs``), then ``BN`` and ``EO 0`` echoed, then the rest of ``ours``
    (``ours[0]`` is ``EO 0``). No line goes out behind a change of the echo in the same
    write: whether the controller echoes such a line is not known."""
    first = link.roundtrip_locked([*theirs, cmds.eo(1)], link.timeout)
    refused = [reply.command.text for reply in first if not reply.ok]
    if refused:  # the echo may be on or off: what TC1 would say cannot be told apart
        raise CommandError(
            None,
            "refused while the controller's own settings were put back for BN; nothing was burned",
            refused[0],
            model=link.model.name,
            recent=link.recent,
        )
    link.set_echo(True)
    done = link.roundtrip_locked([_BN, ours[0]], wait)
    link.set_echo(echo)
    return done + (link.roundtrip_locked(ours[1:], link.timeout) if ours[1:] else [])


def _explain_first(link: Link, done: list[Completed], timeout: float) -> None:
    for reply in done:
        if not reply.ok:
            raise link.explain_locked(reply, timeout)


def _refuse_while_threads_run(link: Link) -> None:
    """``BN`` is refused while a program runs (the TC list: 17 "ED, BN and DL not valid while
    program running"): say so before anything changes (lock held)."""
    asks = [cmds.mg_operand(f"_XQ{t}") for t in range(link.model.threads)]
    done = link.roundtrip_locked(asks, link.timeout) if asks else []
    _explain_first(link, done, link.timeout)
    running = [t for t, reply in enumerate(done) if round(read_one(reply.text)) >= 0]
    if running:
        raise link.error(
            InvalidArgument,
            f"BN is not valid while a program runs (thread {', '.join(map(str, running))}): "
            "the controller refuses it (TC 17); nothing was sent. Stop the threads first "
            "(controller.programs.halt(); a watchdog with its stop())",
        )


#: ``TM n`` with a number, as a whole command (of a compound line split outside quotes): the
#: one grammar both the check before sending and the following after it read.
_TM_SET = re.compile(r"^\s*TM\s*([-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+))\s*$", re.IGNORECASE)


def _tm_values(text: str) -> Iterator[float]:
    """The ``n`` of each ``TM n`` among the commands of ``text`` (split at the ``;`` outside
    quotes: ``MG "a;TM 0"`` holds none)."""
    if "TM" not in text.upper():
        return  # every other command, cheaply (this runs around each raw command)
    for one in cmds.split_commands(text):
        found = _TM_SET.match(one)
        if found is not None:
            yield float(found.group(1))


def refuse_tm(model: ModelSpec, texts: Iterable[str]) -> None:
    """Refuse, before a byte is sent, a ``TM n`` among ``texts`` (command lines, compound
    ones split at ``;`` outside quotes) the library could not follow
    (:meth:`ModelSpec.tm_setting`: a model without TM, ``TM <= 0``, a value off the model's
    step; docs/decisions/0102). ``TM ?`` and a TM of an expression pass (the controller
    judges those; a range error is its).

    Raises:
        InvalidArgument: naming the TM and why.
    """
    for text in texts:
        if isinstance(text, str):
            for tm in _tm_values(text):
                model.tm_setting(tm)


def follow_tm(model: ModelSpec, text: str) -> float | None:
    """The sample period (s) a command line sets, if it holds ``TM <µs>`` (the last, in a
    compound line: the controller runs them in turn); ``None`` otherwise. It reads what
    :func:`refuse_tm` checks (a sign, a part of a compound line), so a TM let through is
    followed.

    The link's ``sample_period`` is set from it after the controller accepted the line, so
    predictions (and a watchdog's limit in samples) follow a ``TM`` sent as a raw command.
    """
    last = None
    for tm in _tm_values(text):
        last = tm
    if last is None or not model.tm_adjustable:
        return None
    return model.sample_period_for(last)
