"""Typed axes: units at the edge, every move predicted and checked before a byte is sent.

An :class:`Axis` belongs to a :class:`~galil.client.Controller`; ``controller.axes["A"]`` and
``controller.A`` give the same object. Moves return a :class:`MoveHandle` that knows its
predicted :class:`~galil.predict.Profile`, can wait (with a progress bar), call back, and stop.

Every command that starts or changes a move goes out on one line with ``MG TIME``, so the
handle knows the controller sample at which it took effect and can re-predict the motion
exactly (a speed change, an ``IP``, an ``ST``), instead of guessing from the host's clock.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from galil import codes, predict
from galil.errors import CommandError, GalilError, GalilTimeoutError, InvalidArgument, LimitError
from galil.units import Scale, counts_or_plain, is_quantity

if TYPE_CHECKING:
    from galil.client import Controller

__all__ = [
    "Axis",
    "MoveHandle",
    "MoveParams",
    "MoveResult",
    "abort_all",
    "check_overrides",
    "execute_move",
    "motion_guard",
    "stop_axes",
]

_INT32 = (-2_147_483_648, 2_147_483_647)
# Polling faster than this only loads the link; the controller decodes a command in ~0.5 ms.
_MIN_POLL = 0.005
_MAX_POLL = 0.1
# The program variable a speed schedule stores its BG sample in (8 characters at most).
_SCHEDULE_BEGIN = "gsbegin"


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
        predicted: the predicted final position per axis, counts. Axes whose motion changed
            in a way the predictor cannot follow (a jog stopped by someone else, a limit, a
            change sent behind the library's back) are left out.
        deviation: ``final - predicted`` for the axes in ``predicted``, counts.
        stop_codes: ``_SC`` per axis.
    """

    final: dict[str, int]
    predicted: dict[str, int]
    deviation: dict[str, int]
    stop_codes: dict[str, int]

    @property
    def worst(self) -> int:
        """Largest absolute deviation over the predicted axes, counts."""
        return max((abs(v) for v in self.deviation.values()), default=0)

    def stop_text(self, axis: str) -> str:
        """The text of an axis's stop code."""
        return codes.stop_text(self.stop_codes[axis])


@dataclass
class _Track:
    """What is known of one axis's motion since its BG: enough to predict it again."""

    kind: str  # "position" | "jog" | "schedule"
    start: int
    params: MoveParams
    begin: int | None  # controller sample (TIME) of the BG line; None while unknown
    amount: float = 0.0  # position: distance in counts; jog: the first JG (signed)
    events: list[predict.Event] = field(default_factory=list)
    aborted: int | None = None  # sample of an AB
    stopped: bool = False  # an ST went out (host side): the jog has an end
    exact: bool = True  # False once something happened that the predictor cannot follow
    fixed: predict.Profile | None = None  # a prediction made elsewhere (speed schedule)


def _open_jog(t: _Track) -> bool:
    # A jog has a known end only once the library stopped (or aborted) it.
    return t.kind == "jog" and not t.stopped and t.aborted is None


def _sample_of(reply: str) -> int | None:
    try:
        return round(float(reply.strip()))
    except ValueError:
        return None


def _predict(controller: Controller, t: _Track) -> predict.Profile:
    """Predict one axis's motion from its start and every change recorded since."""
    ts = controller.sample_period
    p = t.params
    if t.fixed is not None:
        profile = t.fixed
    elif t.kind == "jog":
        profile = predict.jog(
            t.amount,
            p.accel,
            p.decel,
            events=t.events,
            sample_period=ts,
            smoothing=p.smoothing,
            start=t.start,
        )
    else:
        profile = predict.move(
            round(t.amount),
            max(p.speed, controller.model.sp_resolution),
            p.accel,
            p.decel,
            sample_period=ts,
            smoothing=p.smoothing,
            start=t.start,
            events=t.events,
        )
    if t.aborted is not None and t.begin is not None:
        # AB stops the profiler where it is: the reference stays at that sample's value.
        k = max(0, min(t.aborted - t.begin, profile.samples))
        profile = predict.Profile.from_samples(
            profile.position[: k + 1],
            profiler=profile.profiler[: k + 1],
            sample_period=ts,
            shape="stopped",
            peak_speed=profile.peak_speed,
            stop_code=7,
        )
    return profile


class MoveHandle:
    """A move in progress on one or more axes.

    Attributes:
        kind: ``"position"``, ``"jog"`` or ``"schedule"``.
        started_at: the controller clock (seconds) when the handle was made.
    """

    def __init__(self, controller: Controller, tracks: Mapping[str, _Track], kind: str) -> None:
        self._controller = controller
        self._tracks = dict(tracks)
        self.kind = kind
        self.started_at = controller._clock()
        self._done = False
        self._result: MoveResult | None = None
        self._callbacks: list[Callable[[MoveHandle], None]] = []
        self._lock = threading.RLock()
        self._cache: dict[str, predict.Profile] = {}
        self._watcher: threading.Thread | None = None
        self._error: BaseException | None = None

    # -- predictions -------------------------------------------------------------------------
    @property
    def axes(self) -> str:
        """The axis letters this move drives."""
        return "".join(self._tracks)

    @property
    def params(self) -> dict[str, MoveParams]:
        """The quantised SP/AC/DC/IT each axis started with."""
        return {a: t.params for a, t in self._tracks.items()}

    @property
    def begin(self) -> dict[str, int | None]:
        """Controller sample (``TIME``) at which each axis's motion began, if known.

        ``profile.position[k]`` is the predicted reference at sample ``begin + k``; use it to
        line recorded data up with the prediction.
        """
        out: dict[str, int | None] = {}
        for a, t in self._tracks.items():
            if t.begin is None and t.kind == "schedule":
                self._schedule_begin(t)
            out[a] = t.begin
        return out

    def _schedule_begin(self, track: _Track) -> None:
        # The downloaded program stores TIME right after its BG; -1 until it has run.
        with contextlib.suppress(GalilError):
            value = round(self._controller.query_operands([_SCHEDULE_BEGIN])[0])
            if value >= 0:
                track.begin = value

    @property
    def profiles(self) -> dict[str, predict.Profile]:
        """Predicted profile per axis letter, including every change sent since the start."""
        with self._lock:
            for a, t in self._tracks.items():
                if a not in self._cache:
                    self._cache[a] = self._predict(a, t)
            return dict(self._cache)

    @property
    def profile(self) -> predict.Profile:
        """The predicted profile of the (first) axis."""
        return next(iter(self.profiles.values()))

    def _predict(self, letter: str, t: _Track) -> predict.Profile:
        return self._controller.axes[letter]._display(_predict(self._controller, t))

    def _add_event(
        self, letter: str, sample: int | None, make: Callable[[float], predict.Event] | None
    ) -> None:
        """Record a change sent at controller ``sample`` (``make`` builds it from its time).

        ``make=None`` is an abort. A change after the predicted end of a position move is
        ignored: the move was over when it arrived.
        """
        with self._lock:
            t = self._tracks.get(letter)
            if t is None or self._done:
                return
            if sample is None or t.begin is None or t.kind == "schedule" or t.aborted is not None:
                t.exact = False
                return
            k = sample - t.begin
            current = self.profiles[letter]
            if t.kind == "position" and k > current.samples:
                return
            if make is None:
                t.aborted = sample
            else:
                event = make(k * self._controller.sample_period)
                t.events.append(event)
                if isinstance(event, predict.Stop):
                    t.stopped = True
            self._cache.pop(letter, None)
            try:
                self._cache[letter] = self._predict(letter, t)
            except (CommandError, InvalidArgument):
                # The predictor refuses what the controller accepted: keep the old prediction.
                if make is not None:
                    t.events.pop()
                t.exact = False
                self._cache[letter] = current

    @property
    def duration(self) -> float:
        """Predicted duration in seconds (``inf`` for a jog that has not been stopped)."""
        if any(
            t.kind == "jog" and not t.stopped and t.aborted is None for t in self._tracks.values()
        ):
            return math.inf
        if not self._tracks:
            return 0.0
        return max(p.duration for p in self.profiles.values())

    # -- completion --------------------------------------------------------------------------
    @property
    def result(self) -> MoveResult | None:
        """The comparison with the prediction, once the move is done."""
        return self._result

    @property
    def done(self) -> bool:
        """True once every axis's profile is complete (``_BG`` is 0); one query per call."""
        if self._done:
            return True
        letters = self.axes
        names = [f"_{op}{a}" for op in ("BG", "RP", "SC") for a in letters]
        values = self._controller._query_ints(names)
        n = len(letters)
        if not any(values[:n]):
            self._finish(values[n : 2 * n], values[2 * n :])
        return self._done

    def _finish(self, rp: Sequence[int], sc: Sequence[int]) -> None:
        with self._lock:
            if self._done:
                return
            letters = self.axes
            final = dict(zip(letters, rp, strict=True))
            stop = dict(zip(letters, sc, strict=True))
            profiles = self.profiles
            predicted: dict[str, int] = {}
            for a, t in self._tracks.items():
                if t.exact and not _open_jog(t) and stop[a] not in (2, 3):
                    predicted[a] = profiles[a].end
            deviation = {a: final[a] - v for a, v in predicted.items()}
            self._result = MoveResult(final, predicted, deviation, stop)
            self._done = True
            callbacks, self._callbacks = self._callbacks, []
        if self._result.worst > 1:
            warnings.warn(
                f"move on {letters} ended {self._result.deviation} counts away from the prediction",
                RuntimeWarning,
                stacklevel=4,
            )
        for cb in callbacks:
            cb(self)

    def wait(self, timeout: float | None = None, progress: bool = False) -> MoveResult:
        """Block until the move is done, polling without holding the link between polls.

        Polls come at about a quarter of the predicted time left (between 5 and 100 ms); on a
        manual-clock simulator each pause advances simulated time instead of sleeping.

        Args:
            timeout: seconds to wait at most (``None``: the predicted duration plus a margin,
                or forever for a jog that has not been stopped).
            progress: show a ``tqdm.auto`` bar driven by the predicted duration.

        Raises:
            GalilTimeoutError: the move did not finish in time (it is NOT stopped).
            LimitError: an axis stopped on a limit switch or soft limit.
        """
        if timeout is not None and not (isinstance(timeout, (int, float)) and timeout >= 0):
            raise InvalidArgument(f"timeout must be a non-negative number, got {timeout!r}")
        duration = self.duration
        if timeout is None and math.isfinite(duration):
            timeout = duration * 1.5 + 2.0
        c = self._controller
        start = c._clock()
        deadline = None if timeout is None else start + timeout
        bar = _progress_bar(self) if progress else None
        try:
            while not self.done:
                now = c._clock()
                if deadline is not None and now >= deadline:
                    raise GalilTimeoutError(
                        f"move on {self.axes} not done after {timeout:.3g} s "
                        f"(predicted {self.duration:.3g} s)",
                        model=c.model.name,
                    )
                elapsed = now - self.started_at
                if bar is not None:
                    bar.n = elapsed if bar.total is None else min(elapsed, bar.total)
                    bar.refresh()
                remaining = self.duration - elapsed
                pause = remaining / 4 if math.isfinite(remaining) else _MAX_POLL
                if deadline is not None:
                    pause = min(pause, deadline - now)
                c._pause(min(max(pause, _MIN_POLL), _MAX_POLL))
        finally:
            if bar is not None:
                if self._done and bar.total is not None:
                    bar.n = bar.total
                bar.refresh()
                bar.close()
        if self._error is not None:
            raise self._error
        assert self._result is not None
        limited = {a: c for a, c in self._result.stop_codes.items() if c in (2, 3)}
        if limited:
            text = ", ".join(f"{a}: {codes.stop_text(c)}" for a, c in limited.items())
            first = next(iter(limited))
            raise LimitError(
                f"move stopped early ({text})",
                name="limit switch" if limited[first] else "limit",
                value=self._result.final[first],
                axis=first,
                model=c.model.name,
            )
        return self._result

    def add_callback(self, callback: Callable[[MoveHandle], None]) -> None:
        """Call ``callback(handle)`` once the move is done (at once if it already is).

        A background thread polls ``_BG`` every 50 ms of real time; it never advances a
        simulator's manual clock (whoever waits does), so a callback may also run on the
        thread that calls :meth:`wait` or reads :attr:`done`.
        """
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
                time.sleep(_MAX_POLL / 2)
        except GalilError as exc:  # the link died: record it, callers see it on wait()
            self._error = exc

    def stop(self) -> None:
        """Decelerate the move's axes to a stop (``ST``) at their DC."""
        stop_axes(self._controller, self.axes)

    def __repr__(self) -> str:
        state = "done" if self._done else "moving"
        return f"<MoveHandle {self.kind} {self.axes} {state}, predicted {self.duration:.4g} s>"


def _progress_bar(handle: MoveHandle) -> Any:
    try:
        from tqdm.auto import tqdm
    except ImportError:  # progress is a nicety; the wait itself does not need it
        return None
    total = handle.duration if math.isfinite(handle.duration) else None
    fmt = "{l_bar}{bar}| {n:.2f}/{total:.2f} s" if total is not None else "{desc}: {n:.2f} s"
    return tqdm(total=total, desc=f"{handle.kind} {handle.axes}", unit="s", bar_format=fmt)


def _notify(
    controller: Controller,
    letters: str,
    sample: int | None,
    make: Callable[[float], predict.Event] | None,
) -> None:
    for a in letters:
        handle = controller.axes[a]._active
        if handle is not None:
            handle._add_event(a, sample, make)


def stop_axes(controller: Controller, letters: str = "") -> None:
    """``ST`` on ``letters`` (default: all axes); the moves' predictions follow the stop."""
    replies = controller.command_line([f"ST {letters}".rstrip(), "MG TIME"])
    _notify(controller, letters or controller.model.axes, _sample_of(replies[-1]), predict.Stop)


def abort_all(controller: Controller) -> None:
    """``AB 1``: stop every axis at once, without deceleration; programs keep running."""
    replies = controller.command_line(["AB 1", "MG TIME"])
    _notify(controller, controller.model.axes, _sample_of(replies[-1]), None)


class Axis:
    """One axis of a controller.

    Properties read the controller's operands (``_TP``, ``_SP``, ...) and return Quantities when
    the axis has a scale, counts otherwise; setters validate and quantise before sending.
    """

    def __init__(self, controller: Controller, letter: str) -> None:
        self._controller = controller
        self.letter = letter
        self._scale: Scale | None = None
        self._active: MoveHandle | None = None  # the last move started through this axis

    # -- units ------------------------------------------------------------------------------
    def set_scale(self, counts_per: Any, offset: Any = None, sign: int = 1) -> Axis:
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

    def _display(self, profile: predict.Profile) -> predict.Profile:
        """``profile`` shown in this axis's unit (its arrays stay in counts)."""
        scale = self._scale
        if scale is None:
            return profile
        return profile.with_units(
            scale.sign * float(scale.counts_per.magnitude),
            f"{scale.unit:~}",
            offset=float(scale.offset.magnitude),
        )

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
        # A rate's sign never flips with the axis: speeds and accelerations are magnitudes.
        counts = self._signed_rate(value, power, what)
        sign = 1 if self._scale is None else self._scale.sign
        if counts * sign < 0:
            # abs() would run a "-5 mm/s" silently at +5 mm/s: the direction of a position
            # move comes from its target, so a negative value is a mistake worth naming.
            hint = " (the direction comes from the target; jog takes a signed speed)"
            raise InvalidArgument(
                f"{what} must not be negative, got {value!r}{hint if power == 1 else ''}"
            )
        return abs(counts)

    def _signed_rate(self, value: Any, power: int, what: str) -> float:
        if self._scale is not None:
            return self._scale.rate_to_counts(value, power, what)
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
        return abs(self._scale.counts_to_rate(counts, power))

    # -- operands ---------------------------------------------------------------------------
    def _operand(self, name: str) -> float:
        return self._controller.query_operands([f"_{name}{self.letter}"])[0]

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
        """Filtered actual velocity ``_TV`` (signed; averaged over ~0.25 s by the controller).

        The average lags: just after a stop it still reads part of the speed before it.
        """
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
        """``_SC`` with its text, e.g. ``(4, "Decelerating or stopped by Stop Command (ST)")``."""
        code = round(self._operand("SC"))
        return code, codes.stop_text(code)

    # -- parameters -------------------------------------------------------------------------
    def _check_parameter(self, cmd: str, counts: float) -> float:
        """Quantise and range-check SP/JG/AC/DC; a refusal also states the range in user units."""
        try:
            return predict.check_parameter(cmd, counts, self._controller.model, axis=self.letter)
        except LimitError as exc:
            scale = self._scale
            if scale is not None and exc.value is not None and exc.limit is not None:
                power = 2 if cmd in ("AC", "DC") else 1
                value = abs(scale.counts_to_rate(exc.value, power))
                limit = abs(scale.counts_to_rate(exc.limit, power))
                exc.args = (f"{exc.args[0]} (in user units: {value:~.6g}, limit {limit:~.6g})",)
            raise

    def _set_param(self, cmd: str, counts: float) -> None:
        value = self._check_parameter(cmd, counts)
        text = f"{cmd}{self.letter}={_fmt(value)}"
        handle = self._active
        if handle is None or handle._done or cmd not in ("SP", "AC"):
            self._controller.command(text)
            return
        # A change in motion: stamp it so the move's prediction can follow it.
        replies = self._controller.command_line([text, "MG TIME"])
        if cmd == "SP":
            jog = handle._tracks.get(self.letter)
            if jog is not None and jog.kind == "jog":
                return  # SP does not touch a jog
            handle._add_event(
                self.letter, _sample_of(replies[-1]), lambda t: predict.SetSpeed(t, value)
            )
        else:
            handle._add_event(
                self.letter, _sample_of(replies[-1]), lambda t: predict.SetAccel(t, value)
            )

    @property
    def speed(self) -> Any:
        """Slew speed ``SP`` (the controller's quantised value); settable in motion."""
        return self._out_rate(self._operand("SP"), 1)

    @speed.setter
    def speed(self, value: Any) -> None:
        self._set_param("SP", self._rate_counts(value, 1, "speed"))

    @property
    def accel(self) -> Any:
        """Acceleration ``AC``; settable in motion."""
        return self._out_rate(self._operand("AC"), 2)

    @accel.setter
    def accel(self, value: Any) -> None:
        self._set_param("AC", self._rate_counts(value, 2, "accel"))

    @property
    def decel(self) -> Any:
        """Deceleration ``DC`` (the controller refuses a change in motion)."""
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
        """Jog speed ``JG`` (signed); setting it while jogging changes the speed in motion."""
        v = self._operand("JG")
        return v if self._scale is None else self._scale.counts_to_rate(v, 1)

    @jog_speed.setter
    def jog_speed(self, value: Any) -> None:
        if self._jogging():
            self.jog(value)
            return
        v = self._check_parameter("JG", self._signed_rate(value, 1, "jog speed"))
        self._controller.command(f"JG{self.letter}={_fmt(v)}")

    def _jogging(self) -> bool:
        h = self._active
        if h is None or h._done:
            return False
        t = h._tracks.get(self.letter)
        return t is not None and t.kind == "jog"

    @property
    def soft_limits(self) -> tuple[Any, Any]:
        """``(low, high)`` soft limits (``BL``, ``FL``); ``None`` on either side removes it."""
        bl, fl = self._controller.query_operands([f"_BL{self.letter}", f"_FL{self.letter}"])
        low, high = self._out_pos(bl), self._out_pos(fl)
        if self._scale is not None and self._scale.sign < 0:
            low, high = high, low
        return low, high

    @soft_limits.setter
    def soft_limits(self, limits: tuple[Any, Any]) -> None:
        try:
            low, high = limits
        except (TypeError, ValueError) as exc:
            raise InvalidArgument(f"soft_limits takes (low, high), got {limits!r}") from exc
        bl = _INT32[0] if low is None else round(self._pos_counts(low, "reverse soft limit"))
        fl = _INT32[1] if high is None else round(self._pos_counts(high, "forward soft limit"))
        if self._scale is not None and self._scale.sign < 0:
            bl, fl = fl, bl  # a negative scale sign swaps the ends
            bl = _INT32[0] if high is None else bl
            fl = _INT32[1] if low is None else fl
        if bl > fl:
            raise InvalidArgument(
                f"soft limits ({_show(low)}, {_show(high)}): low is above high (takes (low, high))"
            )
        for name, v in (("BL", bl), ("FL", fl)):
            if not _INT32[0] <= v <= _INT32[1]:
                raise LimitError(
                    f"{name} {v} outside the 32-bit position range",
                    name=name,
                    value=v,
                    limit=_INT32[1] if v > 0 else _INT32[0],
                    axis=self.letter,
                )
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
        check_overrides("move_to", overrides)
        return execute_move(self._controller, {self.letter: position}, relative=False, **overrides)

    def move_by(self, distance: Any, **overrides: Any) -> MoveHandle:
        """Move by a relative distance (``PR`` then ``BG``)."""
        check_overrides("move_by", overrides)
        return execute_move(self._controller, {self.letter: distance}, relative=True, **overrides)

    def plan_to(self, position: Any, **overrides: Any) -> predict.Profile:
        """Predict and check ``move_to(position)`` without sending anything."""
        check_overrides("plan_to", overrides)
        plan = execute_move(
            self._controller, {self.letter: position}, relative=False, dry_run=True, **overrides
        )
        return plan.profile

    def plan_by(self, distance: Any, **overrides: Any) -> predict.Profile:
        """Predict and check ``move_by(distance)`` without sending anything."""
        check_overrides("plan_by", overrides)
        plan = execute_move(
            self._controller, {self.letter: distance}, relative=True, dry_run=True, **overrides
        )
        return plan.profile

    def jog(self, speed: Any) -> MoveHandle:
        """Jog at ``speed`` (signed).

        Already jogging: the speed changes in motion and the jog's own handle is returned, its
        prediction now including the change (at the controller sample it took effect).

        Raises:
            InvalidArgument: wrong units, a position move in progress, a stopping jog, or the
                motor off.
            LimitError: a speed beyond the model's range.
        """
        c = self._controller
        a = self.letter
        v = self._check_parameter("JG", self._signed_rate(speed, 1, "jog speed"))
        rp, bg, ac, dc, it, mo = c.query_operands(
            [f"_{op}{a}" for op in ("RP", "BG", "AC", "DC", "IT", "MO")]
        )
        handle = self._active
        if bg and self._jogging():
            assert handle is not None
            track = handle._tracks[a]
            if track.stopped or track.aborted is not None:
                raise InvalidArgument(
                    f"axis {a} is stopping; wait for it before jogging again", model=c.model.name
                )
            replies = c.command_line([f"JG{a}={_fmt(v)}", "MG TIME"])
            handle._add_event(a, _sample_of(replies[-1]), lambda t: predict.SetSpeed(t, v))
            return handle
        if bg:
            raise InvalidArgument(
                f"axis {a} is in another move; stop it before jogging", model=c.model.name
            )
        if mo:
            raise InvalidArgument(
                f"axis {a} has its motor off; call controller.servo_here()", model=c.model.name
            )
        params = MoveParams(abs(v), ac, dc, it)
        replies = c.command_line([f"JG{a}={_fmt(v)}", f"BG{a}", "MG TIME"])
        track = _Track("jog", round(rp), params, _sample_of(replies[-1]), amount=v)
        handle = MoveHandle(c, {a: track}, "jog")
        self._active = handle
        return handle

    def increment(self, n: Any) -> MoveHandle:
        """Increment the position by ``n`` (``IP``).

        Idle: the same as ``move_by(n)``. During a position move: the target moves by ``n``
        (same direction only; the controller refuses a reversal with TC 16, so it is refused
        here first). While jogging: an instant step of the reference position. In motion the
        handle of the move in progress is returned, its prediction updated.

        Raises:
            InvalidArgument: wrong units, a reversal, an axis stopping or in contour mode.
        """
        counts = round(self._dist_counts(n, "increment"))
        c = self._controller
        a = self.letter
        rp, bg, pa = c.query_operands([f"_RP{a}", f"_BG{a}", f"_PA{a}"])
        if not bg:
            return execute_move(c, {a: n}, relative=True, command="IP")
        handle = self._active
        track = None if handle is None or handle._done else handle._tracks.get(a)
        if track is not None and (track.stopped or track.aborted is not None):
            raise InvalidArgument(
                f"axis {a} is stopping; the controller refuses IP now (TC 16)", model=c.model.name
            )
        if track is None or track.kind != "jog":
            remaining = round(pa) - round(rp)
            if counts and remaining and (counts > 0) != (remaining > 0):
                raise InvalidArgument(
                    f"IP {counts} would reverse the move in progress on {a} "
                    f"({remaining:+d} counts to go); the controller refuses it (TC 16)",
                    model=c.model.name,
                )
        replies = c.command_line([f"IP{a}={counts}", "MG TIME"])
        if handle is None or track is None:
            # Someone else's move: nothing to follow; a handle that only waits for it.
            params = MoveParams(0.0, 1.0, 1.0, 1.0)
            lone = _Track("position", round(rp), params, None, exact=False)
            lone.fixed = predict.Profile.from_samples(
                [round(rp)], sample_period=c.sample_period, shape="none", peak_speed=0.0
            )
            return MoveHandle(c, {a: lone}, "position")
        handle._add_event(a, _sample_of(replies[-1]), lambda t: predict.Increment(t, counts))
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

        Raises:
            ScheduleError: a change point the profiler cannot honour (nothing is sent).
            InvalidArgument: wrong units, bad values, the axis busy or its motor off.
            LimitError: a speed out of range or a path crossing a soft limit.
        """
        c = self._controller
        a = self.letter
        d = round(self._dist_counts(distance, "distance"))
        pairs = []
        try:
            items = list(changes)
        except TypeError as exc:
            raise InvalidArgument(
                f"changes must be a list of (at, speed), got {changes!r}"
            ) from exc
        for item in items:
            try:
                at, sp = item
            except (TypeError, ValueError) as exc:
                raise InvalidArgument(f"each change is (at, speed), got {item!r}") from exc
            pairs.append(
                (
                    abs(self._dist_counts(at, "trigger distance")),
                    self._check_parameter("SP", self._rate_counts(sp, 1, "speed")),
                )
            )
        chosen = (
            None
            if speed is None
            else self._check_parameter("SP", self._rate_counts(speed, 1, "speed"))
        )
        rp, bg, sp0, ac, dc, it, bl, fl, mo = c.query_operands(
            [f"_{op}{a}" for op in ("RP", "BG", "SP", "AC", "DC", "IT", "BL", "FL", "MO")]
        )
        if bg or mo:
            raise InvalidArgument(f"axis {a} is moving or its motor is off", model=c.model.name)
        first = sp0 if chosen is None else chosen
        schedule = predict.speed_schedule(
            d, first, pairs, ac, dc, sample_period=c.sample_period, start=round(rp), smoothing=it
        )
        predict.check_soft_limits(schedule.profile, low=bl, high=fl, axis=a)
        program = [f"#{label}", f"SP{a}={_fmt(first)}", f"PR{a}={d}", f"BG{a}"]
        program.append(f"{_SCHEDULE_BEGIN}=TIME")
        for trig, new in zip(schedule.triggers, schedule.speeds[1:], strict=True):
            program += [f"AD{a}={trig}", f"SP{a}={_fmt(new)}"]
        program.append("EN")
        from galil.protocol import commands as cmds

        c.send(cmds.dl(program, model=c.model))
        c.command_line([f"{_SCHEDULE_BEGIN}=-1", cmds.xq(f"#{label}")])
        params = MoveParams(first, ac, dc, it)
        track = _Track("schedule", round(rp), params, None, amount=d, fixed=schedule.profile)
        handle = MoveHandle(c, {a: track}, "schedule")
        self._active = handle
        return handle

    def stop(self) -> None:
        """Decelerate to a stop (``ST``) at DC."""
        stop_axes(self._controller, self.letter)

    def __repr__(self) -> str:
        unit = f" in {self._scale.unit:~}" if self._scale is not None else " in counts"
        return f"<Axis {self.letter}{unit} of {self._controller.model.name}>"


def _fmt(value: float) -> str:
    if float(value).is_integer():
        return str(int(value))
    return f"{value:.4f}".rstrip("0").rstrip(".")


def _fields(letters: str, axes: str, values: Mapping[str, str]) -> str:
    # One field per controller axis up to the last one used: "1000,,-200".
    out = [""] * (max(axes.index(a) for a in letters) + 1)
    for a in letters:
        out[axes.index(a)] = values[a]
    return ",".join(out)


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
    (parameters, targets, ``BG``, ``MG TIME``) so the axes start in the same sample and the
    handle knows which. With ``dry_run`` nothing is sent and the handle only carries the
    predictions. ``command="IP"`` sends an idle increment (``IP`` = ``PR`` + ``BG``).

    Raises:
        InvalidArgument: no or unknown axes, wrong units, an axis moving or its motor off.
        LimitError: a value out of range, or a path crossing a soft limit.
    """
    if not isinstance(targets, Mapping) or not targets:
        raise InvalidArgument(
            f"targets must be a non-empty mapping of axis to value, got {targets!r}"
        )
    model = controller.model
    letters = ""
    values: dict[str, Any] = {}
    for name, value in targets.items():
        letter = model.axis_letter(name)
        if letter in letters:
            raise InvalidArgument(f"axis {letter} given twice")
        letters += letter
        values[letter] = value
    letters = "".join(sorted(letters, key=model.axes.index))
    # Units and ranges first: a wrong value is refused before anything goes on the wire.
    params_parts: dict[str, dict[str, str]] = {"SP": {}, "AC": {}, "DC": {}}
    given: dict[str, dict[str, float]] = {}
    amounts: dict[str, float] = {}
    for a in letters:
        axis = controller.axes[a]
        given[a] = {}
        for cmd, val, power in (("SP", speed, 1), ("AC", accel, 2), ("DC", decel, 2)):
            if val is not None:
                counts = axis._rate_counts(val, power, _OVERRIDE_NAMES[cmd])
                given[a][cmd] = axis._check_parameter(cmd, counts)
                params_parts[cmd][a] = _fmt(given[a][cmd])
        if relative:
            amounts[a] = round(axis._dist_counts(values[a], "distance"))
        else:
            amounts[a] = round(axis._pos_counts(values[a], "target"))
        _check_int32("PR" if relative else "PA", amounts[a], a, model.name)
    ops = ("RP", "BG", "SP", "AC", "DC", "IT", "BL", "FL", "MO")
    # One round trip for every axis's state (query_operands packs the MG lines together).
    state = controller.query_operands([f"_{op}{a}" for a in letters for op in ops])
    targets_out: dict[str, str] = {}
    tracks: dict[str, _Track] = {}
    profiles: dict[str, predict.Profile] = {}
    for i, a in enumerate(letters):
        rp, bg, sp, ac, dc, it, bl, fl, mo = state[i * len(ops) : (i + 1) * len(ops)]
        if bg and not dry_run:
            raise InvalidArgument(
                f"axis {a} is already moving; stop it or wait first", model=model.name
            )
        if mo and not dry_run:
            raise InvalidArgument(
                f"axis {a} has its motor off; call controller.servo_here()", model=model.name
            )
        chosen = {"SP": sp, "AC": ac, "DC": dc, **given[a]}
        start = round(rp)
        if relative:
            distance = round(amounts[a])
            target = start + distance
        else:
            target = round(amounts[a])
            distance = target - start
        _check_int32("PA", target, a, model.name)
        if chosen["SP"] <= 0 and distance:
            raise LimitError(
                f"axis {a} has SP 0: set a speed first",
                name="SP",
                value=0,
                limit=model.sp_resolution,
                axis=a,
                model=model.name,
            )
        params = MoveParams(chosen["SP"], chosen["AC"], chosen["DC"], it)
        track = _Track("position", start, params, None, amount=distance)
        profile = _predict(controller, track)
        try:
            predict.check_soft_limits(profile, low=bl, high=fl, axis=a)
        except LimitError as exc:
            _in_user_units(exc, axis._scale, profile.end)
            raise
        tracks[a] = track
        profiles[a] = axis._display(profile)
        targets_out[a] = str(distance if command == "IP" else target)
    parts: list[str] = []
    for cmd, per_axis in params_parts.items():
        if per_axis:
            parts.append(_axis_command(cmd, "".join(per_axis), model.axes, per_axis))
    verb = "IP" if command == "IP" else "PA"
    parts.append(_axis_command(verb, letters, model.axes, targets_out))
    if command != "IP":
        parts.append(f"BG {letters}" if len(letters) > 1 else f"BG{letters}")
    parts.append("MG TIME")
    handle = MoveHandle(controller, tracks, "position")
    handle._cache.update(profiles)
    if not dry_run:
        replies = controller.command_line(parts)
        begin = _sample_of(replies[-1])
        for a in letters:
            tracks[a].begin = begin
            controller.axes[a]._active = handle
    return handle


def _show(value: Any) -> str:
    return f"{value:~}" if is_quantity(value) else repr(value)


_OVERRIDE_NAMES = {"SP": "speed", "AC": "accel", "DC": "decel"}


def check_overrides(where: str, overrides: Mapping[str, Any]) -> None:
    """Refuse keyword overrides a move does not take, naming the public call and the valid ones.

    Without this, a typo (``sped=``) surfaces as a TypeError about an internal function, and
    internal keywords (``dry_run=``, ``command=``) would be accepted from users.

    Raises:
        TypeError: an unknown keyword, as Python itself would raise it.
    """
    unknown = sorted(set(overrides) - set(_OVERRIDE_NAMES.values()))
    if unknown:
        raise TypeError(
            f"{where}() got an unexpected keyword argument {unknown[0]!r}; "
            "a move takes speed=, accel= and decel="
        )


def _in_user_units(exc: LimitError, scale: Scale | None, end: int) -> None:
    # The predictor speaks counts; a user who set limits in mm should read mm too.
    if scale is None or exc.value is None or exc.limit is None:
        return
    if exc.name not in ("FL", "BL"):
        return
    unit_text = ", ".join(
        f"{label} {scale.counts_to_position(v):~.6g}"
        for label, v in (("reaches", exc.value), ("limit", exc.limit), ("end", end))
    )
    exc.args = (f"{exc.args[0]} (in user units: {unit_text})", *exc.args[1:])


def _check_int32(name: str, value: float, axis: str, model: str) -> None:
    if not _INT32[0] <= value <= _INT32[1]:
        raise LimitError(
            f"{name} {value:.0f} on {axis} is outside the 32-bit position range",
            name=name,
            value=value,
            limit=_INT32[1] if value > 0 else _INT32[0],
            axis=axis,
            model=model,
        )


def _axis_command(cmd: str, letters: str, axes: str, values: Mapping[str, str]) -> str:
    if len(letters) == 1:
        return f"{cmd}{letters}={values[letters]}"
    return f"{cmd} {_fields(letters, axes, values)}"


@contextlib.contextmanager
def motion_guard(controller: Controller, axes: str | None = None) -> Iterator[None]:
    """Stop the moving axes (``ST``) and wait for them if the block raises (Ctrl-C included).

    The block's exception is re-raised once the axes have stopped (or after 30 s of trying);
    a failure while stopping never hides it.
    """
    letters = controller.model.axes if axes is None else _letters(controller, axes)
    try:
        yield
    except BaseException:
        with contextlib.suppress(GalilError):
            moving = controller._query_ints([f"_BG{a}" for a in letters])
            busy = "".join(a for a, m in zip(letters, moving, strict=True) if m)
            if busy:
                stop_axes(controller, busy)
                deadline = controller._clock() + 30.0
                while any(controller._query_ints([f"_BG{a}" for a in busy])):
                    if controller._clock() > deadline:
                        break
                    controller._pause(_MIN_POLL * 4)
        raise


def _letters(controller: Controller, axes: str) -> str:
    if not isinstance(axes, str):
        raise InvalidArgument(f"axes must be a string of axis letters, got {axes!r}")
    out = ""
    for name in axes.replace(" ", "").replace(",", ""):
        letter = controller.model.axis_letter(name)
        if letter not in out:
            out += letter
    return out
