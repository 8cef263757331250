"""Typed axes: units at the edge, every move predicted and checked before a byte is sent.

An :class:`Axis` belongs to a :class:`~galil.client.Controller`; ``controller.axes["A"]`` and
``controller.A`` give the same object. Moves return a :class:`MoveHandle` that knows its
predicted :class:`~galil.predict.Profile`, can wait (with a progress bar), call back, and stop.
"""

from __future__ import annotations

import contextlib
import math
import threading
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from galil import predict
from galil.errors import GalilError, InvalidArgument, LimitError
from galil.protocol import codes
from galil.units import Scale, counts_or_plain, is_quantity

if TYPE_CHECKING:
    from galil.client import Controller

__all__ = ["Axis", "MoveHandle", "MoveResult", "execute_move", "motion_guard"]

_INT32 = (-2_147_483_648, 2_147_483_647)
# Polling faster than this only loads the link; the controller decodes a command in ~0.5 ms.
_MIN_POLL = 0.005
_MAX_POLL = 0.1


@dataclass(frozen=True)
class MoveParams:
    """The quantised values a move was planned (and sent) with, counts and seconds."""

    speed: float
    accel: float
    decel: float
    smoothing: float


@dataclass(frozen=True)
class MoveResult:
    """How a finished move compares with its prediction.

    Attributes:
        final: final reference position (``_RP``) per axis, counts.
        predicted: the predicted final position per axis, counts.
        deviation: ``final - predicted`` per axis, counts.
        stop_codes: ``_SC`` per axis.
    """

    final: dict[str, int]
    predicted: dict[str, int]
    deviation: dict[str, int]
    stop_codes: dict[str, int]

    @property
    def worst(self) -> int:
        """Largest absolute deviation over the axes, counts."""
        return max((abs(v) for v in self.deviation.values()), default=0)


class MoveHandle:
    """A move in progress on one or more axes.

    Attributes:
        profile: the prediction for the first axis (``profiles`` has them all).
        profiles: predicted profile per axis letter.
        kind: ``"position"``, ``"jog"``, ``"increment"`` or ``"contour"``.
    """

    def __init__(
        self,
        controller: Controller,
        profiles: Mapping[str, predict.Profile],
        kind: str,
        *,
        expect_final: bool = True,
        params: Mapping[str, MoveParams] | None = None,
    ) -> None:
        self._controller = controller
        self.profiles = dict(profiles)
        self.kind = kind
        self.params = dict(params or {})
        self._expect_final = expect_final
        self.started_at = controller._clock()
        self._done = False
        self._result: MoveResult | None = None
        self._callbacks: list[Callable[[MoveHandle], None]] = []
        self._lock = threading.Lock()
        self._watcher: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def axes(self) -> str:
        """The axis letters this move drives."""
        return "".join(self.profiles)

    @property
    def profile(self) -> predict.Profile:
        """The predicted profile of the (first) axis."""
        return next(iter(self.profiles.values()))

    @property
    def duration(self) -> float:
        """Predicted duration in seconds (``inf`` for a jog, which runs until stopped)."""
        if self.kind == "jog" or not self.profiles:
            return math.inf
        return max(p.duration for p in self.profiles.values())

    @property
    def result(self) -> MoveResult | None:
        """The comparison with the prediction, once the move is done."""
        return self._result

    @property
    def done(self) -> bool:
        """True once every axis's profile is complete (``_BG`` is 0)."""
        if self._done:
            return True
        moving = self._controller._query_ints([f"_BG{a}" for a in self.axes])
        if not any(moving):
            self._finish()
        return self._done

    def _finish(self) -> None:
        with self._lock:
            if self._done:
                return
            names = [f"_RP{a}" for a in self.axes] + [f"_SC{a}" for a in self.axes]
            values = self._controller._query_ints(names)
            n = len(self.axes)
            final = dict(zip(self.axes, values[:n], strict=True))
            stop = dict(zip(self.axes, values[n:], strict=True))
            predicted = {a: int(p.position[-1]) for a, p in self.profiles.items()}
            deviation = {a: final[a] - predicted[a] for a in self.axes}
            self._result = MoveResult(final, predicted, deviation, stop)
            self._done = True
            callbacks, self._callbacks = self._callbacks, []
        if self._expect_final and self._result.worst > 1 and all(c == 1 for c in stop.values()):
            warnings.warn(
                f"move on {self.axes} ended {self._result.deviation} counts away from the "
                "prediction",
                RuntimeWarning,
                stacklevel=3,
            )
        for cb in callbacks:
            cb(self)

    def wait(self, timeout: float | None = None, progress: bool = False) -> MoveResult:
        """Block until the move is done, polling without holding the link between polls.

        Args:
            timeout: seconds to wait at most (``None``: the predicted duration plus a margin,
                or forever for a jog).
            progress: show a ``tqdm.auto`` bar driven by the predicted duration.

        Raises:
            GalilTimeoutError: the move did not finish in time (it is NOT stopped).
            LimitError: an axis stopped on a limit switch or soft limit.
        """
        from galil.errors import GalilTimeoutError

        if timeout is None and self.kind != "jog" and math.isfinite(self.duration):
            timeout = self.duration * 1.5 + 2.0
        deadline = None if timeout is None else self._controller._clock() + timeout
        bar = _progress_bar(self) if progress else None
        start = self._controller._clock()
        try:
            while not self.done:
                now = self._controller._clock()
                if deadline is not None and now >= deadline:
                    raise GalilTimeoutError(
                        f"move on {self.axes} not done after {timeout:.3g} s "
                        f"(predicted {self.duration:.3g} s)",
                        model=self._controller.model.name,
                    )
                if bar is not None:
                    bar.n = min(now - start, bar.total)
                    bar.refresh()
                remaining = self.duration - (now - start)
                pause = remaining / 4 if math.isfinite(remaining) and remaining > 0 else _MAX_POLL
                self._controller._pause(min(max(pause, _MIN_POLL), _MAX_POLL))
        finally:
            if bar is not None:
                bar.n = bar.total if self._done else bar.n
                bar.refresh()
                bar.close()
        assert self._result is not None
        limited = {a: c for a, c in self._result.stop_codes.items() if c in (2, 3)}
        if limited:
            text = ", ".join(f"{a}: {codes.stop_text(c)}" for a, c in limited.items())
            raise LimitError(f"move stopped early ({text})", name="limit switch")
        return self._result

    def add_callback(self, callback: Callable[[MoveHandle], None]) -> None:
        """Call ``callback(handle)`` once the move is done (at once if it already is)."""
        with self._lock:
            if not self._done:
                self._callbacks.append(callback)
                if self._watcher is None:
                    self._watcher = threading.Thread(
                        target=self._watch, name=f"galil-move-{self.axes}", daemon=True
                    )
                    self._watcher.start()
                return
        callback(self)

    def _watch(self) -> None:
        try:
            while not self.done:
                self._controller._pause(_MAX_POLL / 2)
        except GalilError as exc:  # the link died: record it, callers see it on wait()
            self._error = exc

    def stop(self) -> None:
        """Decelerate the move's axes to a stop (``ST``) at their DC."""
        self._controller.command(f"ST {self.axes}")

    def __repr__(self) -> str:
        state = "done" if self._done else "moving"
        return f"<MoveHandle {self.kind} {self.axes} {state}, predicted {self.duration:.4g} s>"


def _progress_bar(handle: MoveHandle) -> Any:
    try:
        from tqdm.auto import tqdm
    except ImportError:  # progress is a nicety; the wait itself does not need it
        return None
    total = handle.duration if math.isfinite(handle.duration) else None
    return tqdm(
        total=total,
        desc=f"{handle.kind} {handle.axes}",
        unit="s",
        bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s",
    )


class Axis:
    """One axis of a controller.

    Properties read the controller's operands (``_TP``, ``_SP``, ...) and return Quantities when
    the axis has a scale, counts otherwise; setters validate and quantise before sending.
    """

    def __init__(self, controller: Controller, letter: str) -> None:
        self._controller = controller
        self.letter = letter
        self._scale: Scale | None = None
        self._jog_speed: float | None = None
        self._active: MoveHandle | None = None  # the last move started through this axis

    # -- units ------------------------------------------------------------------------------
    def set_scale(self, counts_per: Any, offset: Any = None, sign: int = 1) -> Axis:
        """Give the axis a scale, e.g. ``counts_per=2000 / ureg.mm``; ``None`` removes it."""
        self._scale = None if counts_per is None else Scale(counts_per, offset, sign)
        return self

    @property
    def scale(self) -> Scale | None:
        """The axis's :class:`~galil.units.Scale`, if any."""
        return self._scale

    def _pos_counts(self, value: Any, what: str) -> float:
        if self._scale is not None:
            return self._scale.position_to_counts(value, what)
        return counts_or_plain(value, what)

    def _dist_counts(self, value: Any, what: str) -> float:
        if self._scale is not None:
            return self._scale.distance_to_counts(value, what)
        return counts_or_plain(value, what)

    def _rate_counts(self, value: Any, power: int, what: str) -> float:
        if self._scale is not None:
            # A rate's sign never flips with the axis: speeds and accelerations are magnitudes.
            return abs(self._scale.rate_to_counts(value, power, what))
        if is_quantity(value):
            raise InvalidArgument(
                f"{what}: {value} has units but axis {self.letter} has no scale; "
                "call axis.set_scale(counts_per=...) or pass counts"
            )
        return counts_or_plain(value, what)

    def _out_pos(self, counts: float) -> Any:
        return counts if self._scale is None else self._scale.counts_to_position(counts)

    def _out_rate(self, counts: float, power: int) -> Any:
        if self._scale is None:
            return counts
        return abs(self._scale.counts_to_rate(counts, power)) if power else counts

    # -- operands ---------------------------------------------------------------------------
    def _operand(self, name: str) -> float:
        return self._controller._query_numbers([f"_{name}{self.letter}"])[0]

    @property
    def position(self) -> Any:
        """Encoder position ``_TP``."""
        return self._out_pos(self._operand("TP"))

    @property
    def reference_position(self) -> Any:
        """Commanded (reference) position ``_RP``."""
        return self._out_pos(self._operand("RP"))

    @property
    def velocity(self) -> Any:
        """Filtered actual velocity ``_TV`` (averaged over ~0.25 s by the controller)."""
        v = self._operand("TV")
        return v if self._scale is None else self._scale.counts_to_rate(v, 1)

    @property
    def error(self) -> Any:
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
        """``_SC`` with its text, e.g. ``(1, "Stopped at commanded independent position")``."""
        code = int(self._operand("SC"))
        return code, codes.stop_text(code)

    # -- parameters -------------------------------------------------------------------------
    def _set_param(self, cmd: str, counts: float) -> None:
        value = predict.check_parameter(cmd, counts, self._controller.model, axis=self.letter)
        self._controller.command(f"{cmd}{self.letter}={_fmt(value)}")

    @property
    def speed(self) -> Any:
        """Slew speed ``SP`` (the controller's quantised value)."""
        return self._out_rate(self._operand("SP"), 1)

    @speed.setter
    def speed(self, value: Any) -> None:
        self._set_param("SP", self._rate_counts(value, 1, "speed"))

    @property
    def accel(self) -> Any:
        """Acceleration ``AC``."""
        return self._out_rate(self._operand("AC"), 2)

    @accel.setter
    def accel(self, value: Any) -> None:
        self._set_param("AC", self._rate_counts(value, 2, "accel"))

    @property
    def decel(self) -> Any:
        """Deceleration ``DC``."""
        return self._out_rate(self._operand("DC"), 2)

    @decel.setter
    def decel(self, value: Any) -> None:
        self._set_param("DC", self._rate_counts(value, 2, "decel"))

    @property
    def smoothing(self) -> float:
        """Independent time constant ``IT`` (1 = no smoothing)."""
        return self._operand("IT")

    @smoothing.setter
    def smoothing(self, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidArgument(f"smoothing must be a number in [0.004, 1], got {value!r}")
        self._set_param("IT", float(value))

    @property
    def jog_speed(self) -> Any:
        """The last jog speed set through this axis (``JG``), or ``None``."""
        if self._jog_speed is None:
            return None
        v = self._jog_speed
        return v if self._scale is None else self._scale.counts_to_rate(v, 1)

    @property
    def soft_limits(self) -> tuple[Any, Any]:
        """``(BL, FL)`` reverse and forward soft limits."""
        bl, fl = self._controller._query_numbers([f"_BL{self.letter}", f"_FL{self.letter}"])
        return self._out_pos(bl), self._out_pos(fl)

    @soft_limits.setter
    def soft_limits(self, limits: tuple[Any, Any]) -> None:
        low, high = limits
        bl = _INT32[0] if low is None else round(self._pos_counts(low, "reverse soft limit"))
        fl = _INT32[1] if high is None else round(self._pos_counts(high, "forward soft limit"))
        if bl > fl:
            bl, fl = fl, bl  # a negative scale sign swaps the ends
        for name, v in (("BL", bl), ("FL", fl)):
            if not _INT32[0] <= v <= _INT32[1]:
                raise LimitError(f"{name} {v} outside the 32-bit position range", name=name)
        self._controller.command_line([f"BL{self.letter}={bl}", f"FL{self.letter}={fl}"])

    # -- moves ------------------------------------------------------------------------------
    def move_to(self, position: Any, **overrides: Any) -> MoveHandle:
        """Move to an absolute position (``PA`` then ``BG``).

        Keyword overrides ``speed``, ``accel``, ``decel`` apply to this move (they are sent
        with it and stay set on the controller).

        Raises:
            InvalidArgument: wrong units, bad values, axis busy or motor off.
            LimitError: a value out of the model's range, or a path crossing a soft limit.
        """
        return execute_move(self._controller, {self.letter: position}, relative=False, **overrides)

    def move_by(self, distance: Any, **overrides: Any) -> MoveHandle:
        """Move by a relative distance (``PR`` then ``BG``)."""
        return execute_move(self._controller, {self.letter: distance}, relative=True, **overrides)

    def plan_to(self, position: Any, **overrides: Any) -> predict.Profile:
        """Predict and check ``move_to(position)`` without sending anything."""
        plan = execute_move(
            self._controller, {self.letter: position}, relative=False, dry_run=True, **overrides
        )
        return plan.profile

    def plan_by(self, distance: Any, **overrides: Any) -> predict.Profile:
        """Predict and check ``move_by(distance)`` without sending anything."""
        plan = execute_move(
            self._controller, {self.letter: distance}, relative=True, dry_run=True, **overrides
        )
        return plan.profile

    def jog(self, speed: Any) -> MoveHandle:
        """Jog at ``speed`` (signed); changes speed in motion when already jogging."""
        c = self._controller
        v = predict.check_parameter(
            "JG", self._signed_rate(speed, "jog speed"), c.model, axis=self.letter
        )
        state = c._query_numbers(
            [
                f"_RP{self.letter}",
                f"_BG{self.letter}",
                f"_AC{self.letter}",
                f"_DC{self.letter}",
                f"_IT{self.letter}",
            ]
        )
        rp, bg, ac, dc, it = state
        previous = self._jog_speed if bg else None
        jogging = previous is not None
        if bg and not jogging:
            raise InvalidArgument(
                f"axis {self.letter} is in a position move; stop it before jogging",
                model=c.model.name,
            )
        profile = predict.jog(
            v,
            ac,
            dc,
            start=int(rp),
            # The prediction assumes the last jog ramp has reached its speed.
            initial_speed=previous if previous is not None else 0.0,
            sample_period=c.sample_period,
            smoothing=it,
        )
        if jogging:
            c.command(f"JG{self.letter}={_fmt(v)}")
        else:
            c.command_line([f"JG{self.letter}={_fmt(v)}", f"BG{self.letter}"])
        self._jog_speed = v
        handle = MoveHandle(c, {self.letter: profile}, "jog", expect_final=False)
        self._active = handle
        return handle

    def _signed_rate(self, value: Any, what: str) -> float:
        if self._scale is not None:
            return self._scale.rate_to_counts(value, 1, what)
        return self._rate_counts(value, 1, what)

    def increment(self, n: Any) -> MoveHandle:
        """Increment the position by ``n`` (``IP``).

        Idle: the same as ``move_by(n)``. During a position move: the target moves by ``n``
        (same direction only; the controller refuses a reversal with TC 16). While jogging: an
        instant step of the reference position.
        """
        counts = round(self._dist_counts(n, "increment"))
        c = self._controller
        rp, bg, pa = c.query_operands(
            [f"_RP{self.letter}", f"_BG{self.letter}", f"_PA{self.letter}"]
        )
        active = self._active
        if not bg:
            return execute_move(c, {self.letter: n}, relative=True, command="IP")
        if self._jog_speed is not None:
            c.command(f"IP{self.letter}={counts}")
            assert active is not None
            return active
        remaining = int(pa) - int(rp)
        if counts and remaining and (counts > 0) != (remaining > 0):
            raise InvalidArgument(
                f"IP {counts} would reverse the move in progress on {self.letter} "
                f"({remaining:+d} counts to go); the controller refuses it (TC 16)",
                model=c.model.name,
            )
        profile = None
        if active is not None and active.kind == "position" and self.letter in active.profiles:
            old = active.profiles[self.letter]
            elapsed = max(0.0, c._clock() - active.started_at)
            params = active.params[self.letter]
            profile = predict.move(
                old.distance,
                params.speed,
                params.accel,
                params.decel,
                sample_period=c.sample_period,
                smoothing=params.smoothing,
                start=old.start,
                events=[predict.Increment(elapsed, counts)],
            )
        c.command(f"IP{self.letter}={counts}")
        if profile is None:
            return MoveHandle(c, {}, "increment", expect_final=False)
        handle = MoveHandle(c, {self.letter: profile}, "increment")
        self._active = handle
        return handle

    def speed_schedule(
        self, distance: Any, changes: Any, *, speed: Any = None, label: str = "GSCHED"
    ) -> MoveHandle:
        """Move by ``distance``, changing speed at given distances from the start.

        The Galil form of a "distance to change" schedule: each ``(at, new_speed)`` becomes an
        ``AD`` trippoint and an ``SP`` in a small downloaded program, run with ``XQ``. Every
        change point is validated first (the ramp before it must have finished); an invalid
        one raises :class:`~galil.predict.ScheduleError` naming the earliest valid point, and
        nothing is sent.

        Args:
            distance: total relative move.
            changes: ``[(at, new_speed), ...]``, ``at`` measured from the start of the move.
            speed: initial speed (default: the axis's SP).
            label: program label to download (the program replaces what is in memory).
        """
        c = self._controller
        a = self.letter
        d = round(self._dist_counts(distance, "distance"))
        pairs = []
        for item in changes:
            try:
                at, sp = item
            except (TypeError, ValueError) as exc:
                raise InvalidArgument(f"each change is (at, speed), got {item!r}") from exc
            pairs.append(
                (
                    abs(self._dist_counts(at, "trigger distance")),
                    predict.check_parameter(
                        "SP", self._rate_counts(sp, 1, "speed"), c.model, axis=a
                    ),
                )
            )
        rp, bg, sp0, ac, dc, it, bl, fl, mo = c.query_operands(
            [f"_{op}{a}" for op in ("RP", "BG", "SP", "AC", "DC", "IT", "BL", "FL", "MO")]
        )
        if bg or mo:
            raise InvalidArgument(f"axis {a} is moving or its motor is off", model=c.model.name)
        first = (
            sp0
            if speed is None
            else predict.check_parameter(
                "SP", self._rate_counts(speed, 1, "speed"), c.model, axis=a
            )
        )
        schedule = predict.speed_schedule(
            d, first, pairs, ac, dc, sample_period=c.sample_period, start=int(rp), smoothing=it
        )
        predict.check_soft_limits(schedule.profile, low=bl, high=fl, axis=a)
        program = [f"#{label}", f"SP{a}={_fmt(first)}", f"PR{a}={d}", f"BG{a}"]
        for trig, new in zip(schedule.triggers, schedule.speeds[1:], strict=True):
            program += [f"AD{a}={trig}", f"SP{a}={_fmt(new)}"]
        program.append("EN")
        from galil.protocol import commands as cmds

        c.send(cmds.dl(program, model=c.model))
        c.send(cmds.xq(f"#{label}"))
        handle = MoveHandle(c, {a: schedule.profile}, "schedule")
        self._active = handle
        return handle

    def stop(self) -> None:
        """Decelerate to a stop (``ST``) and forget the jog speed."""
        self._controller.command(f"ST {self.letter}")
        self._jog_speed = None

    def __repr__(self) -> str:
        unit = f" in {self._scale.unit:~}" if self._scale is not None else " in counts"
        return f"<Axis {self.letter}{unit} of {self._controller.model.name}>"


def _fmt(value: float) -> str:
    if float(value).is_integer():
        return str(int(value))
    return f"{value:.4f}".rstrip("0").rstrip(".")


def execute_move(
    controller: Controller,
    targets: Mapping[str, Any],
    *,
    relative: bool = False,
    speed: Any = None,
    accel: Any = None,
    decel: Any = None,
    dry_run: bool = False,
    command: str = "PA",
) -> MoveHandle:
    """Predict, check and send a position move on one or more axes, begun together.

    Everything is validated and predicted first; the move goes out as one command line
    (parameters, targets, then ``BG``) so the axes start in the same sample. With
    ``dry_run`` nothing is sent and the handle only carries the predictions. ``command="IP"``
    sends an idle increment (``IP`` = ``PR`` + ``BG`` on the controller).
    """
    if not targets:
        raise InvalidArgument("no axes to move")
    model = controller.model
    letters = ""
    values: dict[str, Any] = {}
    for name, value in targets.items():
        letter = model.axis_letter(name)
        if letter in letters:
            raise InvalidArgument(f"axis {letter} given twice")
        letters += letter
        values[letter] = value
    ops = ("RP", "BG", "SP", "AC", "DC", "IT", "BL", "FL", "MO")
    state = controller.query_operands([f"_{op}{a}" for a in letters for op in ops])
    parts: list[str] = []
    profiles: dict[str, predict.Profile] = {}
    params: dict[str, MoveParams] = {}
    for i, a in enumerate(letters):
        axis = controller.axes[a]
        rp, bg, sp, ac, dc, it, bl, fl, mo = state[i * len(ops) : (i + 1) * len(ops)]
        if bg and not dry_run:
            raise InvalidArgument(
                f"axis {a} is already moving; stop it or wait first", model=model.name
            )
        if mo and not dry_run:
            raise InvalidArgument(
                f"axis {a} has its motor off; call controller.servo_here()", model=model.name
            )
        chosen = {"SP": sp, "AC": ac, "DC": dc}
        for cmd, val, power in (("SP", speed, 1), ("AC", accel, 2), ("DC", decel, 2)):
            if val is not None:
                counts = axis._rate_counts(val, power, cmd.lower())
                chosen[cmd] = predict.check_parameter(cmd, counts, model, axis=a)
                parts.append(f"{cmd}{a}={_fmt(chosen[cmd])}")
        if relative:
            distance = round(axis._dist_counts(values[a], "distance"))
            target = int(rp) + distance
        else:
            target = round(axis._pos_counts(values[a], "target"))
            distance = target - int(rp)
        if not _INT32[0] <= target <= _INT32[1]:
            raise LimitError(
                f"target {target} outside the 32-bit position range",
                name="PA",
                value=target,
                limit=_INT32[1] if target > 0 else _INT32[0],
                axis=a,
            )
        if chosen["SP"] <= 0 and distance:
            raise LimitError(
                f"axis {a} has SP 0: set a speed first",
                name="SP",
                value=0,
                limit=model.sp_resolution,
                axis=a,
            )
        profile = predict.move(
            distance,
            max(chosen["SP"], model.sp_resolution),
            chosen["AC"],
            chosen["DC"],
            sample_period=controller.sample_period,
            smoothing=it,
            start=int(rp),
        )
        predict.check_soft_limits(profile, low=bl, high=fl, axis=a)
        profiles[a] = profile
        params[a] = MoveParams(chosen["SP"], chosen["AC"], chosen["DC"], it)
        parts.append(f"IP{a}={distance}" if command == "IP" else f"PA{a}={target}")
    if command != "IP":
        parts.append(f"BG {letters}")
    handle = MoveHandle(controller, profiles, "position", params=params)
    if not dry_run:
        controller.command_line(parts)
        for a in letters:
            ax = controller.axes[a]
            ax._active = handle
            ax._jog_speed = None
    return handle


@contextlib.contextmanager
def motion_guard(controller: Controller, axes: str | None = None) -> Iterator[None]:
    """Stop the moving axes (``ST``) and wait for them if the block raises (Ctrl-C included)."""
    try:
        yield
    except BaseException:
        letters = axes or controller.model.axes
        with contextlib.suppress(GalilError):
            moving = controller._query_ints([f"_BG{a}" for a in letters])
            busy = "".join(a for a, m in zip(letters, moving, strict=True) if m)
            if busy:
                controller.command(f"ST {busy}")
                deadline = controller._clock() + 30.0
                while any(controller._query_ints([f"_BG{a}" for a in busy])):
                    if controller._clock() > deadline:
                        break
                    controller._pause(_MIN_POLL * 4)
        raise
