"""Contour mode, host side: turn an ideal path into the integer increments CD sends.

The planner keeps the commanded path within half a count of the ideal one: increment i is
``round(path[i]) - round(path[i-1])``, so the running sum is the rounded ideal position at every
segment end (no drift) and the total is exact.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from galil import codes, predict
from galil.errors import (
    CommandError,
    ContourUnderrunError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    MotionError,
)
from galil.link import CommandLink, check_wait_timeout
from galil.models import INT32_MAX
from galil.motion import (
    SWITCH_BITS,
    Display,
    GearLink,
    LineSlicer,
    MotionTracker,
    MoveResult,
    StopWatch,
    dropped_parts,
    forget_dropped,
    held,
    line_timeout,
    raise_if_limited,
    refuse_motor_off,
    sample_of,
    send_reopening,
    switch_blocks,
)
from galil.moves import check_followers, follower_limits, follower_operands
from galil.predict import Profile
from galil.predict.checks import check_contour
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.protocol.numbers import read_one, whole
from galil.routines import WATCHDOG_FIRED
from galil.units import PathSamples, sampled_values

__all__ = ["ContourResult", "ContourStream", "ContourUnderrunError", "increments", "sample_path"]

#: ``_SC`` of a contour axis while its contour runs ("Contour running").
_RUNNING = 50
#: TC of a ``CD`` refused out of range or out of contour mode ("Contouring record range
#: error"): the library checks the range, so for it the contour mode has ended.
_OUT_OF_CONTOUR = 41
#: TCs of the end of contour mode (``CD 0=0``) refused because the axes had left it: 8 ("not
#: valid when not running") in the simulator (unsourced for a controller), or 41 as a ``CD``.
_END_REFUSED = frozenset({8, _OUT_OF_CONTOUR})


class _ContourOverError(Exception):
    """The controller stopped the contour itself (a limit, decision 0041): ``error`` is what
    to raise; nothing is left to stop."""

    def __init__(self, error: MotionError) -> None:
        super().__init__(str(error))
        self.error = error


def _halted(letters: str, stop_codes: list[float], live: set[str]) -> list[str]:
    """The axes of ``letters`` seen running (in ``live``) that read a stop code of a halt
    (empty: none); the axes reading 50 ("Contour running") join ``live`` on the way."""
    halted = []
    for a, c in zip(letters, stop_codes, strict=True):
        code = round(c)
        if code == _RUNNING:
            live.add(a)
        elif code in codes.HALT_STOPS and a in live:
            halted.append(a)
    return halted


def _refuse_blocked(link: CommandLink, a: str, steps: npt.NDArray[np.int64], ts: int) -> None:
    """Refuse a path on which ``a`` first moves towards its active limit switch (one ``LD``
    leaves on: :func:`~galil.motion.switch_blocks`): the controller would stop the whole
    contour there at once (decision 0041), after ``CM`` and the segments went out. Only the
    first direction counts: moving away, the switch lets go (decision 0071).

    Raises:
        InvalidArgument: the axis would start towards its active switch.
    """
    if ts & SWITCH_BITS == SWITCH_BITS:
        return  # (no switch active: the path's direction is not needed)
    moving = np.flatnonzero(steps)
    if not moving.size:
        return
    direction = float(steps[moving[0]])
    if switch_blocks(link, a, direction, ts):
        side = "forward" if direction > 0 else "reverse"
        raise InvalidArgument(
            f"axis {a} would start towards its active {side} limit switch on this contour (the "
            "controller would stop the whole contour there at once); move off the switch first",
            model=link.model.name,
        )


def _round(x: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    # Half-way values round up (floor(x + 0.5)) so the rule does not depend on parity.
    out: npt.NDArray[np.int64] = np.floor(x + 0.5).astype(np.int64)
    return out


def increments(
    path: npt.ArrayLike, *, start: int = 0, axis: str | None = None
) -> npt.NDArray[np.int64]:
    """Integer CD increments that follow ``path`` (ideal absolute positions at segment ends).

    Args:
        path: ideal positions in counts at the end of each segment (floats allowed).
        start: the (integer) position before the first segment.
        axis: the axis the path is for (named in a refusal).

    Returns:
        int64 increments; ``start + cumsum(increments) == round(path)`` element by element.

    Raises:
        InvalidArgument: the path is not 1-D and finite, or ``start`` is not a whole count.
        LimitError: a point beyond the 32-bit position range (name ``"path point"``).
    """
    x = np.asarray(path, dtype=np.float64)
    if x.ndim != 1:
        raise InvalidArgument(f"path must be 1-D, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InvalidArgument("path holds NaN or infinity")
    if x.size and float(np.max(np.abs(x))) > INT32_MAX:
        i = int(np.argmax(np.abs(x)))
        on = "" if axis is None else f" on {axis}"
        raise LimitError(
            f"path point {i}{on} ({x[i]:.6g} counts) is outside the 32-bit position range",
            name="path point",
            value=float(x[i]),
            limit=INT32_MAX if x[i] > 0 else -INT32_MAX,
            sample=i,
            axis=axis,
        )
    if int(start) != start:
        raise InvalidArgument(f"start must be a whole count, got {start!r}")
    ends = _round(x)
    out: npt.NDArray[np.int64] = np.diff(ends, prepend=np.int64(int(start)))
    return out


def sample_path(
    func: Callable[[npt.NDArray[np.float64]], object],
    duration: float,
    dt: int,
    sample_period: float = 1 / 1024,
) -> PathSamples:
    """Sample ``func(t)`` (t in seconds) at the end of each ``2**dt``-sample segment.

    The last segment end is clipped to ``duration`` so the path ends on ``func(duration)``
    (that segment then moves its whole remainder in ``2**dt`` samples).

    Args:
        func: positions as a function of time, called once with the array of segment-end
            times: one axis (shape ``(n,)``) or several (shape ``(n, axes)``); plain numbers
            (counts) or a pint Quantity array, which stays a Quantity so that
            ``controller.contour`` converts it through each axis's scale (never stripped).
        duration: seconds covered.
        dt: the DT exponent (1..8).
        sample_period: seconds per servo sample.

    Returns:
        Ideal positions at the segment ends, floats (or a Quantity of floats), ready for
        ``controller.contour`` or, in counts, :func:`increments`.

    Raises:
        InvalidArgument: bad duration, DT or sample period, or ``func`` returns a wrong shape
            or something that is not numbers.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise InvalidArgument(f"duration must be positive, got {duration!r}")
    n = whole(dt)
    if n is None or not 1 <= n <= 8:
        raise InvalidArgument(f"DT must be an integer in 1..8, got {dt!r}")
    dt = n
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise InvalidArgument(f"sample_period must be positive, got {sample_period!r}")
    seg = (1 << dt) * sample_period
    count = max(1, math.ceil(duration / seg - 1e-9))
    t = np.minimum(np.arange(1, count + 1, dtype=np.float64) * seg, duration)
    samples = sampled_values(func(t), "the path function's result")
    shape = samples.shape  # a Quantity of an array has its array's shape
    if not (shape == t.shape or (len(shape) == 2 and shape[0] == t.size and shape[1] >= 1)):
        raise InvalidArgument(
            f"func returned shape {shape}; expected ({t.size},) or ({t.size}, axes)"
        )
    return samples


@dataclass(frozen=True)
class ContourResult:
    """A finished contour stream.

    Attributes:
        axes: the contour axes.
        increments: the CD increments sent, shape (segments, axes).
        dt: the DT exponent used.
        profiles: predicted profile per axis.
        low_water: fewest free buffer slots seen while streaming (``_CM``).
        lines: command lines sent for the segments.
        begin: the controller sample (``TIME``) the first ``CD`` ran in, read on its line;
            ``profiles[a].position[k]`` is the reference at sample ``begin + k``.
    """

    axes: str
    increments: npt.NDArray[np.int64]
    dt: int
    profiles: dict[str, Profile]
    low_water: int
    lines: int
    begin: int | None = None

    @property
    def duration(self) -> float:
        """Predicted duration in seconds."""
        return max(p.duration for p in self.profiles.values())

    def __repr__(self) -> str:
        # (the generated one printed every increment row)
        ends = {a: p.end for a, p in self.profiles.items()}
        return (
            f"ContourResult(axes={self.axes!r}, segments={len(self.increments)}, dt={self.dt},"
            f" duration={self.duration:.6g} s, ends={ends}, low_water={self.low_water},"
            f" lines={self.lines}, begin={self.begin})"
        )


def _bar(total: int, letters: str) -> Any:
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=f"contour {letters}", unit="seg")


@dataclass
class _Progress:
    """How far a stream got.

    ``start`` is the ``DT`` that starts a pre-loaded stream (``None``: the stream was entered
    with its own ``DT``, and its first ``CD`` starts it).
    """

    sent: int = 0
    lines: int = 0
    low_water: int = 0
    bar: Any = None
    texts: list[Command] = field(default_factory=list)
    begin: int | None = None
    start: Command | None = None
    #: Axes whose ``_SC`` has read 50 in this stream: only on them is a stop code a stop of
    #: this contour (a controller that kept an older code until the contour ran is not
    #: misread; decision 0041).
    live: set[str] = field(default_factory=set)
    #: Whether the line that starts the contour (and reads ``MG TIME`` there) went out.
    started: bool = False


def _stamped(batch: list[Command], state: _Progress, *, last: bool) -> tuple[list[Command], bool]:
    """``batch`` with ``MG TIME`` where the contour starts, and whether it starts there:
    right after the first ``CD``, or, pre-loaded under ``DT -1``, after the first refill's
    ``last`` line and the ``DT`` that starts it (the pre-load's lines before it are held)."""
    if state.started or (state.start is not None and not last):
        return batch, False
    if state.start is not None:
        return [*batch, state.start, cmds.time_stamp()], True
    return [batch[0], cmds.time_stamp(), *batch[1:]], True


def _note_begin(state: _Progress, replies: list[str]) -> None:
    """The line that started the contour came back (``replies``, its parts'): where it began."""
    state.begin = sample_of(replies[-1] if state.start is not None else replies[1])
    state.started = True


#: Read on the line of every batch, after its last ``CD``: the buffer may run dry after the
#: ``_TC`` read before a batch and before the batch is in (a host late with its last batch
#: left nothing after it to read the 42: the path paused and the stream ended as if on time).
_ERROR_CODE = cmds.mg_operand("_TC")


#: Bytes a refill's line carries besides its segments: ``_ERROR_CODE`` and, on the line that
#: starts the contour, its ``DT`` and ``MG TIME`` (both ways).
_LINE_EXTRA = 64


def _raise_if_ran_dry(link: CommandLink, state: _Progress, reply: str, batch: int) -> None:
    """Raise if the controller's error code, read right after a batch's last ``CD``, says
    the buffer ran dry (TC 42) before the batch was in: the path paused on its way.

    Raises:
        ContourUnderrunError: TC 42.
    """
    if round(read_one(reply)) != 42:
        return
    raise ContourUnderrunError(
        f"contour buffer ran dry before segments {state.sent}..{state.sent + batch - 1} of "
        f"{len(state.texts)} were in (TC 42: contour data sent too slowly)",
        segment=state.sent,
        model=link.model.name,
    )


def _bad_shape(shape: tuple[int, ...], letters: str) -> InvalidArgument:
    """The refusal of a path of ``shape`` for the axes ``letters``, saying what is wrong: no
    segment, a 1-D path for several axes, or the wrong number of columns."""
    n = len(letters)
    wanted = "(segments,) or (segments, 1)" if n == 1 else f"(segments, {n}), a column per axis"
    if len(shape) in (1, 2) and shape[0] == 0:
        return InvalidArgument(
            f"the path is empty (shape {shape}): a contour needs at least one segment"
        )
    if len(shape) == 1:
        why = f"a 1-D path (shape {shape}) is for one axis, and {letters} are {n}"
    elif len(shape) == 2:
        drives = f"{n} axis" if n == 1 else f"{n} axes"
        why = f"the path has {shape[1]} columns (shape {shape}) but the contour drives {drives}"
    else:
        why = f"the path has {len(shape)} dimensions (shape {shape})"
    return InvalidArgument(f"{why}: give shape {wanted}")


def _not_stopped(
    link: CommandLink, tracker: MotionTracker | None, letters: str, cause: BaseException | None
) -> MotionError:
    """The error of a contour's halt whose ``ST`` could not be sent; the tracker keeps the
    axes for ``close()`` to stop (decision 0077)."""
    if tracker is not None:
        with tracker.lock:
            tracker.unstopped += "".join(a for a in letters if a not in tracker.unstopped)
    why = "" if cause is None else f" after {type(cause).__name__}"
    error = MotionError(
        f"contour on {letters} could not be stopped{why}: ST did not go through, so its axes "
        "may still be moving and the segments queued may still run",
        axis=letters[0],
        moving=letters,
        model=link.model.name,
        recent=link.recent,
    )
    error.__cause__ = cause
    return error


def _check_ends(
    link: CommandLink,
    letters: str,
    ends: Mapping[str, int],
    stop_codes: Sequence[float],
    positions: Sequence[float],
    *,
    fired_before: bool,
) -> None:
    """At the end of the contour on ``letters``, no stop code of a halt seen: each axis is
    where its path ends (``ends``), or something else moved it or cut the contour short (a
    limit whose stop code a program's move then overwrote): it did not run as asked
    (decision 0071). An axis short of its end is blamed on the watchdog when one beats on
    the link and its ``gwfire`` reads 1 now, not at the contour's start (``fired_before``):
    one query, on this error's path only.

    Raises:
        MotionError: an axis is not at its path's end.
    """
    at = {a: round(p) for a, p in zip(letters, positions, strict=True)}
    off = [a for a in letters if at[a] != ends[a]]
    if not off:
        return
    stop = {a: round(c) for a, c in zip(letters, stop_codes, strict=True)}
    said = "; ".join(f"{a}: {codes.stop_text(c)}" for a, c in stop.items())
    short = f"{off[0]} at {at[off[0]]}, not at the end of its path ({ends[off[0]]})"
    if _fired_now(link, fired_before):
        text = f"contour on {letters} stopped by {_BY_WATCHDOG}: it ended with {short} ({said})"
    else:
        text = (
            f"contour on {letters} ended with {short}, and the stop codes do not say why "
            f"({said}): something else stopped or moved it (an ST from a program or another "
            "client, or a limit whose stop code a program's move then overwrote)"
        )
    raise MotionError(
        text,
        axis=off[0],
        stop_codes=stop,
        position=at[off[0]],
        model=link.model.name,
        recent=link.recent,
    )


#: Who stopped a contour when the watchdog's ``gwfire`` went from 0 to 1 during it.
_BY_WATCHDOG = "the watchdog (no heartbeat reached it within its timeout: it sent ST)"


def _fired_flag(link: CommandLink) -> bool | None:
    """The watchdog's ``gwfire`` while one beats on the link (one query); ``None`` when none
    beats or the query fails."""
    if link.keepalive is None:
        return None
    try:
        return round(link.query_operands([WATCHDOG_FIRED])[0]) == 1
    except GalilError:
        return None


def _fired_now(link: CommandLink, fired_before: bool) -> bool:
    """Whether the watchdog fired during this contour: ``gwfire`` reads 1 now and did not at
    the contour's start (``fired_before``; the flag stays 1 after a firing until a watchdog
    starts again, so an earlier firing is not this contour's stop)."""
    return not fired_before and bool(_fired_flag(link))


def _how_far(state: _Progress) -> str:
    """How far the contour got when it was stopped: ``after 41 of 512 segments were sent``,
    or, pre-loaded and its ``DT`` not yet gone out, that it never started."""
    total = len(state.texts)
    if state.start is not None and not state.started:
        return f"before it started ({state.sent} of {total} segments pre-loaded, none run)"
    return f"after {state.sent} of {total} segments were sent"


def _ended_elsewhere(
    link: CommandLink, letters: str, state: _Progress, refused: str, *, fired_before: bool
) -> MotionError | None:
    """The contour on ``letters`` stopped by what the library did not send: the controller
    refused ``refused`` (the next ``CD``, whose range the library checked, TC 41; or the end
    of contour mode), its axes out of contour mode (an ``ST`` from the watchdog, a program
    or another client; the axes then read 51, "Contour stopped", also a contour's usual end,
    so only the refusal tells). The watchdog's fired flag is read while one beats on the
    link: it is named only if the flag was not already set at the contour's start
    (``fired_before``). ``moving`` names the axes still moving. ``None`` if the query fails."""
    n = len(letters)
    names = [f"_{op}{a}" for op in ("SC", "BG", "RP") for a in letters]
    dog = [WATCHDOG_FIRED] if link.keepalive is not None else []
    try:
        values = link.query_operands(names + dog)
    except GalilError:
        return None
    stop = {a: round(v) for a, v in zip(letters, values[:n], strict=True)}
    if dog and round(values[-1]) == 1 and not fired_before:
        by = _BY_WATCHDOG
    elif dog:  # (its flag read: not the watchdog, which had not fired or fired before)
        by = "an ST or AB the library did not send (a program or another client)"
    else:
        by = "an ST or AB the library did not send (a program, another client, the watchdog)"
    return MotionError(
        f"contour on {letters} stopped by {by} {_how_far(state)}: the controller refused "
        f"{refused} ({'; '.join(f'{a}: {codes.stop_text(c)}' for a, c in stop.items())})",
        axis=letters[0],
        stop_codes=stop,
        moving="".join(a for a, v in zip(letters, values[n : 2 * n], strict=True) if round(v)),
        position=values[2 * n],
        model=link.model.name,
        recent=link.recent,
    )


class ContourStream:
    """One contour run: :meth:`check` (no I/O), :meth:`prepare` (one state query, the
    predictions, soft limits), :meth:`feed` (CM, DT, segments keeping the buffer fed) and
    :meth:`finish` (``CD 0=0``, wait). :meth:`run` does all four.

    Args:
        link: the command link.
        letters: the contour axes in the controller's order of the path's columns.
        path: ideal positions in counts relative to where each axis is now, one per
            ``2**dt``-sample segment, shape (segments,) or (segments, axes).
        dt: the DT exponent (segments last ``2**dt`` samples).
        display: per-axis display of the predictions in user units.
        followers: the axes geared to contour axes (``MotionTracker.followers``): their
            paths are checked too.
        preload: where the model can (:attr:`~galil.models.ModelSpec.contour_preload`),
            fill the buffer under ``DT -1`` before the contour starts, so the stream begins
            with a whole buffer in hand; ``False`` starts it with its first segment (sooner
            on a slow link, with no margin at first).
    """

    def __init__(
        self,
        link: CommandLink,
        letters: str,
        path: npt.NDArray[np.float64],
        *,
        dt: int,
        display: dict[str, Display] | None = None,
        byte_rate: float | None = None,
        limits: dict[str, tuple[float | None, float | None]] | None = None,
        followers: Mapping[str, GearLink] | None = None,
        tracker: MotionTracker | None = None,
        preload: bool = True,
    ) -> None:
        if not letters or len(set(letters)) != len(letters):
            raise InvalidArgument(f"contour axes must be distinct and non-empty, got {letters!r}")
        exponent = whole(dt)
        if exponent is None:
            raise InvalidArgument(f"dt must be an integer exponent, got {dt!r}")
        dt = exponent
        ideal = path[:, None] if path.ndim == 1 else path
        if ideal.ndim != 2 or ideal.shape[1] != len(letters) or ideal.shape[0] == 0:
            raise _bad_shape(path.shape, letters)
        self.link = link
        self.letters = letters
        self.dt = dt
        self.increments = np.stack(
            [increments(ideal[:, j], axis=a) for j, a in enumerate(letters)], axis=1
        )
        self._display = display or {}
        self._byte_rate = byte_rate
        self._limits = limits or {}
        self._followers = {f: g for f, g in (followers or {}).items() if f not in letters}
        self.profiles: dict[str, Profile] = {}
        self._ends: dict[str, int] = {}  # where each axis ends (counts), once prepared
        self._tracker = tracker
        self._watch: StopWatch | None = None
        if not isinstance(preload, bool):
            raise InvalidArgument(f"preload must be True or False, got {preload!r}")
        self._preload = preload and link.model.contour_preload
        # Segments may be held under DT -1, not started: from the pre-load's CM until the
        # line with the start's DT came back (only then does a stop need _drop_held).
        self._holding = False
        self._line_wait: float | None = None  # (the last batch's reply timeout: _halt)
        self._fired_before = False  # the watchdog's gwfire read 1 at the contour's start
        self._slicer = LineSlicer(link)

    def commands(self) -> list[Command]:
        """The ``CD`` command of every segment, in order (built and checked at once)."""
        return cmds.cd_rows(self.increments, self.letters, model=self.link.model)

    def check(self) -> None:
        """The segments against the model's CD and DT ranges, the speed and acceleration they
        imply on each axis (the model's maxima or the limits given), and the link's speed.

        Raises:
            LimitError: a value out of range or a link too slow for the stream.
        """
        link = self.link
        size = len(cmds.cd_rows(self.increments[:1], self.letters, model=link.model)[0].text) + 1
        for j, a in enumerate(self.letters):
            speed, accel = self._limits.get(a, (None, None))
            check_contour(
                self.increments[:, j],
                self.dt,
                model=link.model,
                axis=a,
                sample_period=link.sample_period,
                bytes_per_segment=size,
                link_rate=self._byte_rate,
                speed_limit=speed,
                accel_limit=accel,
            )

    def prepare(self) -> None:
        """Read where the axes are (one round trip), predict, check the soft limits.

        Raises:
            InvalidArgument: an axis is moving or its motor off, or the library has it geared
                to another axis; an axis would first move towards its active limit switch
                (decision 0071), or an axis geared to a contour axis would (decision 0053).
            LimitError: the path crosses a soft limit, or takes an axis geared to a contour
                axis past its soft limits or beyond the model's SP maximum.
            MotionError: a limit stopped an axis geared to a contour axis during a move
                nobody waited for (its gearing is off: :func:`~galil.motion.refuse_dropped`).
        """
        link = self.link
        if self._tracker is not None:
            for a in self.letters:  # (before any byte, as a move of a follower is refused)
                self._tracker.refuse_geared(a, "a contour on it", link.model.name)
        ops = ("RP", "BG", "BL", "FL", "SC", "TS")
        followers = "".join(self._followers)
        state = link.query_operands(
            [f"_{op}{a}" for a in self.letters for op in ops]
            + list(follower_operands(followers, self._tracker))
        )
        limits = follower_limits(
            link, self._tracker, self._followers, state[len(self.letters) * len(ops) :]
        )
        counts: dict[str, Profile] = {}
        for j, a in enumerate(self.letters):
            rp, bg, bl, fl, sc, ts = state[j * len(ops) : (j + 1) * len(ops)]
            if not bg and self._tracker is not None:  # (a move nobody saw end ends here)
                self._tracker.ended(a, rp, sc)
            if bg:
                raise InvalidArgument(
                    f"axis {a} is moving; stop it before a contour", model=link.model.name
                )
            refuse_motor_off(link, a, round(ts))
            _refuse_blocked(link, a, self.increments[:, j], round(ts))
            prof = predict.contour(
                self.increments[:, j], self.dt, start=round(rp), sample_period=link.sample_period
            )
            # The whole path against FL/BL, as for any move, before CM goes out.
            predict.check_soft_limits(prof, forward_limit=fl, backward_limit=bl, axis=a)
            counts[a] = prof
            self._ends[a] = prof.end
        if followers:  # the followers' paths too (GA C<master>: the contour's reference)
            check_followers(
                link,
                self._followers,
                {f: g.profile(counts[g.master]) for f, g in self._followers.items()},
                limits,
            )
        for a, prof in counts.items():
            show = self._display.get(a)
            self.profiles[a] = prof if show is None else show(prof)

    def feed(self, *, progress: bool = False) -> _Progress:
        """Enter contour mode and send every segment, keeping the buffer fed.

        Whatever goes wrong (an error, a timeout, a ``KeyboardInterrupt``), the contour axes
        are stopped (``ST``) and the controller is left out of contour mode (``CD 0=0``, or
        ``DT 0`` and ``CD 0`` on the models that end it so): the queued segments never run
        on after the exception.

        Raises:
            ContourUnderrunError: the buffer ran dry while streaming (TC 42).
        """
        with held(self._tracker):
            state = self._enter(progress)
        return self._stream(state)

    def _enter(self, progress: bool) -> _Progress:
        """Enter contour mode (``CM``, ``DT``); watch for stops from now on."""
        link = self.link
        model = link.model
        texts = self.commands()
        if self._tracker is not None and self._watch is None:
            self._watch = self._tracker.watch_stops(self.letters)
        # Where DT -1 pre-loads, the buffer is filled before the contour starts: the link's
        # slack then only has to keep it full, not build it up while it runs (decision 0038).
        start = cmds.dt(self.dt, model=model) if self._preload else None
        dog = [WATCHDOG_FIRED] if link.keepalive is not None else []
        try:
            # (gwfire stays 1 after a firing: only a change during this contour names it)
            tc, *fired = link.query_operands(["_TC", *dog])
            self._fired_before = bool(fired) and round(fired[0]) == 1
            if round(tc) == 42:
                link.command_line([cmds.tc(0)])  # a previous stream's code: ours must show
            first = cmds.dt(-1 if start is not None else self.dt, model=model)
            self._holding = start is not None
            link.command_line([cmds.cm(self.letters, model=model), first])
        except BaseException as exc:
            self._halt(end=True, cause=exc)  # (CM may have gone out: contour mode is left again)
            raise
        state = _Progress(low_water=model.contour_buffer, texts=texts, start=start)
        state.bar = _bar(len(texts), self.letters) if progress else None
        return state

    def _stream(self, state: _Progress) -> _Progress:
        link = self.link
        texts = state.texts
        try:
            while state.sent < len(texts):
                self._refill(state)
                if state.bar is not None:
                    state.bar.update(state.sent - state.bar.n)
            # How full the buffer got: the last batch is the fullest moment of a short path.
            state.low_water = min(state.low_water, round(link.query_operands(["_CM"])[0]))
        except _ContourOverError as done:
            raise done.error from None
        except BaseException as exc:
            # A CD refused because a limit ended the contour since the last look (decision
            # 0041) is that stop; anything else stops the axes and leaves contour mode.
            over = self._stop_seen(state, exc)
            if over is None:
                self._halt(end=True, cause=exc)
                raise
            raise over.error from exc
        finally:
            if state.bar is not None:
                state.bar.close()
        return state

    def _halt(self, *, end: bool, cause: BaseException | None = None) -> None:
        """Stop the contour axes (``ST``, as long as the last batch could take: one that
        failed may still be on a slow line, and the link gets in step behind it), then leave
        contour mode if ``end``: after an exception (``cause``) nothing queued may run on.
        Errors on the way out of contour mode are dropped (``cause`` is the one to see).

        Raises:
            MotionError: ``ST`` could not be sent: the axes may still move (from ``cause``).
        """
        link = self.link
        reopen = None if self._tracker is None else self._tracker.reconnect
        stop = [cmds.st(self.letters, model=link.model)]  # (a dead link reopened once for it)
        send = functools.partial(link.command_line, stop, timeout=self._line_wait)
        if not send_reopening(send, reopen):
            raise _not_stopped(link, self._tracker, self.letters, cause)
        if end:
            with contextlib.suppress(GalilError):
                if self._holding:
                    # (once started, nothing is held: a CM now would only enter contour mode
                    # again, left so if the link closes before the end goes out)
                    self._drop_held()
                link.command_line(cmds.contour_end(self.letters, model=link.model))

    def _drop_held(self) -> None:
        """Drop segments a stream pre-loaded under ``DT -1`` and did not start, so that the
        end of contour mode is not held behind them: ``CM`` clears a buffer that is not
        running (DMC-4103 reference, CM); only once ``_CM`` reads it empty does a positive
        ``DT`` go out (a ``DT`` with segments still held would start them)."""
        link = self.link
        model = link.model
        link.command_line([cmds.cm(self.letters, model=model)])
        if round(link.query_operands(["_CM"])[0]) >= model.contour_buffer:
            link.command_line([cmds.dt(self.dt, model=model)])

    def _refill(self, state: _Progress) -> None:
        link = self.link
        model = link.model
        depth = model.contour_buffer
        seg_time = (1 << self.dt) * link.sample_period
        # Refill when a quarter of the buffer is free: few long lines, and most of the buffer
        # still queued (a quarter of 511 segments is 0.25 s even at DT 1).
        refill = max(1, depth // 4)
        texts = state.texts
        free_f, tc, *sc = link.query_operands(["_CM", "_TC", *(f"_SC{a}" for a in self.letters)])
        free = round(free_f)
        if state.sent and round(tc) == 42:
            raise ContourUnderrunError(
                f"contour buffer ran dry after {state.sent} of {len(texts)} segments "
                "(TC 42: contour data sent too slowly)",
                segment=state.sent,
                model=model.name,
            )
        if _halted(self.letters, sc, state.live):  # (stopped: not one more CD goes out)
            self._check_stopped(state)  # (an ST or AB the library sent says so itself)
            over = self._controller_stop(state)
            if over is not None:
                raise over
        state.low_water = min(state.low_water, free)
        room = free - 1  # one spare: models differ in whether _CM counts the running one
        if depth <= 2:
            # A one-deep buffer: WC holds its ':' until the segment before is running.
            self._check_stopped(state)
            line, starts = _stamped([texts[state.sent]], state, last=True)
            replies = self._slicer.send([*line, cmds.wc(), _ERROR_CODE], seg_time * 4 + 1.0)
            self._holding = False
            if starts:
                _note_begin(state, replies[:-2])
            _raise_if_ran_dry(link, state, replies[-1], 1)
            state.sent += 1
            state.lines += 1
        elif room >= min(refill, len(texts) - state.sent):
            stop = min(len(texts), state.sent + room)
            while state.sent < stop:  # (a line at a time, each short: decision 0100)
                self._send_line(state, stop)
        else:
            # Wait for the room one refill needs, but poll at least every 50 ms and well
            # within what is queued: a late look costs more than an early one.
            queued = (depth - free) * seg_time
            need = (refill - max(room, 0)) * seg_time
            link.pause(max(seg_time, min(need, queued / 4, 0.05)))

    def _send_line(self, state: _Progress, stop: int) -> None:
        """The next line of a refill ending at segment ``stop``, short (:class:`LineSlicer`: a
        watchdog's heartbeat rides on the lines), with a transfer's timeout, ``_TC`` after."""
        link = self.link
        end = self._slicer.cut(state.texts, state.sent, stop, _LINE_EXTRA)
        batch = state.texts[state.sent : end]
        line, starts = _stamped(batch, state, last=end == stop)
        line = [*line, _ERROR_CODE]
        self._line_wait = wait = line_timeout(link, line)
        with held(self._tracker):  # (no stop between the check and the line)
            self._check_stopped(state)
            replies = self._slicer.send(line, wait)
        if starts:
            self._holding = False  # (the pre-load's DT went out: nothing is held)
            _note_begin(state, replies[:-1])
        _raise_if_ran_dry(link, state, replies[-1], len(batch))
        state.sent = end
        state.lines += len(cmds.pack(batch, link.model.line_length))

    def _check_stopped(self, state: _Progress) -> None:
        """Refuse to send more once a stop or an abort reached a contour axis.

        Raises:
            MotionError: ``ST`` or ``AB`` went to a contour axis (from another thread).
        """
        watch = self._watch
        if watch is None or not watch.stopped_by:
            return
        link = self.link
        raise link.error(
            MotionError,
            f"contour on {self.letters} stopped ({watch.stopped_by} sent through the library, "
            f"from another thread) after {state.sent} of {len(state.texts)} segments",
        )

    def _stop_seen(self, state: _Progress, exc: BaseException) -> _ContourOverError | None:
        """The stop a refused line (``exc``) met: a limit's, or one the library did not send."""
        if not isinstance(exc, CommandError):
            return None
        over = self._controller_stop(state)
        if over is None and exc.code == _OUT_OF_CONTOUR and exc.command.startswith("CD"):
            over = self._elsewhere(state, exc, "the next segments")
        return over

    def _elsewhere(
        self, state: _Progress, exc: CommandError, refused: str
    ) -> _ContourOverError | None:
        """The contour stopped by what the library did not send (:func:`_ended_elsewhere`),
        the controller having refused ``refused`` with ``exc``: an axis still moving is
        stopped, and segments held under ``DT -1`` are dropped, as after any exception."""
        why = f"{refused} (TC {exc.code}: its axes had left contour mode)"
        seen = _ended_elsewhere(
            self.link, self.letters, state, why, fired_before=self._fired_before
        )
        if seen is None:
            return None
        if seen.moving or self._holding:
            self._halt(end=True)
        return _ContourOverError(seen)

    def _controller_stop(self, state: _Progress) -> _ContourOverError | None:
        """The contour the controller stopped itself, once the ``_SC`` of an axis seen
        running (:attr:`_Progress.live`) reads a stop (:data:`galil.codes.HALT_STOPS`: a limit
        switch or soft limit stops a contour as a whole, 2 or 3 on that axis, decision 0041).
        One query; an axis still moving gets ``ST`` and contour mode is left, as after any
        exception. ``None`` when no such axis reads a stop (or the query fails: the caller's
        own handling stands)."""
        link = self.link
        n = len(self.letters)
        names = [f"_{op}{a}" for op in ("SC", "BG", "RP") for a in self.letters]
        try:
            values = link.query_operands(names + self._follower_names())
        except GalilError:
            return None
        stop = {a: round(v) for a, v in zip(self.letters, values[:n], strict=True)}
        halted = _halted(self.letters, values[:n], state.live)
        if not halted:
            return None
        if any(round(v) for v in values[n : 2 * n]) or self._holding:
            self._halt(end=True)  # (moving, or segments held under DT -1: dropped)
        first = ([a for a in halted if stop[a] in codes.LIMIT_STOPS] or halted)[0]
        # (a follower a limit stopped on the way is named too, and forgotten: decision 0049)
        ends = _follower_codes(self._followers, values[3 * n :])
        dropped = forget_dropped(self._tracker, self._followers, ends)
        parts = [f"{a}: {codes.stop_text(c)}" for a, c in stop.items()]
        parts += dropped_parts(self._followers, dropped)
        error = MotionError(
            f"contour on {self.letters} stopped by the controller {_how_far(state)} "
            f"({'; '.join(parts)})",
            axis=first,
            stop_codes={**stop, **ends},
            position=values[2 * n + self.letters.index(first)],
            model=link.model.name,
            recent=link.recent,
        )
        return _ContourOverError(error)

    def _follower_names(self) -> list[str]:
        """``_RP`` then ``_SC`` of the followers (none without followers): read with the
        contour axes' state at its end, they tell of a follower a limit stopped."""
        return [f"_{op}{f}" for op in ("RP", "SC") for f in self._followers]

    def finish(self, state: _Progress, timeout: float | None = None) -> ContourResult:
        """End contour mode (``CD 0=0``, or ``DT 0`` then ``CD 0``) and wait for the axes to stop.

        Whatever interrupts the wait (the timeout, an error, a ``KeyboardInterrupt``) stops
        the contour axes (``ST``) before it propagates.

        Raises:
            GalilTimeoutError: the contour did not finish in time (the axes are stopped).
        """
        link = self.link
        ended = False
        try:
            with held(self._tracker):
                self._check_stopped(state)
                link.command_line(cmds.contour_end(self.letters, model=link.model))
            ended = True
            self._wait_stopped(state, timeout)
        except _ContourOverError as done:
            raise done.error from None
        except BaseException as exc:
            # (CD 0=0 refused: a limit ended the contour first, decision 0041; or an ST the
            # library did not send, its TC one of _END_REFUSED)
            over = None
            if isinstance(exc, CommandError) and not ended:
                over = self._controller_stop(state)
                if over is None and exc.code in _END_REFUSED:
                    over = self._elsewhere(state, exc, "the end of contour mode")
            if over is None:
                self._halt(end=not ended, cause=exc)
                raise
            raise over.error from exc
        return ContourResult(
            self.letters,
            self.increments,
            self.dt,
            dict(self.profiles),
            state.low_water,
            state.lines,
            state.begin,
        )

    def _wait_stopped(self, state: _Progress, timeout: float | None) -> None:
        """Wait for the axes to stop; their stop codes then say whether the contour ended as
        asked or a limit stopped it first (:class:`_ContourOverError`)."""
        link = self.link
        seg_time = (1 << self.dt) * link.sample_period
        wait = (
            timeout
            if timeout is not None
            else max(p.duration for p in self.profiles.values()) + 2.0
        )
        deadline = link.clock() + wait
        n = len(self.letters)
        names = [f"_{op}{a}" for op in ("BG", "SC", "RP") for a in self.letters]
        names += self._follower_names()  # (on the same polls: no exchange more)
        while True:
            values = link.query_operands(names)
            if not any(round(v) for v in values[:n]):
                if _halted(self.letters, values[n : 2 * n], state.live):
                    over = self._controller_stop(state)
                    if over is not None:
                        raise over
                codes_at_end = dict(zip(self.letters, values[n : 2 * n], strict=True))
                _report_followers(
                    link, self._tracker, self._followers, codes_at_end, values[3 * n :]
                )
                _check_ends(
                    link,
                    self.letters,
                    self._ends,
                    values[n : 2 * n],
                    values[2 * n : 3 * n],
                    fired_before=self._fired_before,
                )
                return
            now = link.clock()
            if now > deadline:
                raise link.error(
                    GalilTimeoutError, f"contour on {self.letters} not finished after {wait:.3g} s"
                )
            link.pause(min(0.05, max(seg_time, 0.005), max(deadline - now, 0.001)))

    def run(self, *, progress: bool = False, timeout: float | None = None) -> ContourResult:
        """Check, prepare, feed and finish: the whole contour, nothing sent if a check fails.

        Raises:
            InvalidArgument: a timeout that is not ``None`` or a finite number >= 0.
        """
        timeout = check_wait_timeout(timeout)
        self.check()
        try:
            with held(self._tracker):  # no other thread's motion from the state read to CM
                if self._tracker is not None:  # (a cancelled task's contour: nothing sent)
                    self._tracker.refuse_cancelled(self.link.model.name)
                self.prepare()
                state = self._enter(progress)
            state = self._stream(state)
            return self.finish(state, timeout)
        finally:
            if self._watch is not None:
                self._watch.close()
                self._watch = None


def _follower_codes(followers: Mapping[str, GearLink], values: Sequence[float]) -> dict[str, int]:
    """Each follower's ``_SC`` from the values of :meth:`ContourStream._follower_names`."""
    m = len(followers)
    return {f: round(c) for f, c in zip(followers, values[m:], strict=True)}


def _report_followers(
    link: CommandLink,
    tracker: MotionTracker | None,
    followers: Mapping[str, GearLink],
    stop_codes: Mapping[str, float],
    values: Sequence[float],
) -> None:
    """At the usual end of a contour (its axes' ``stop_codes``, the ``followers``' ``values``
    of :meth:`ContourStream._follower_names`): what
    :meth:`~galil.motion.MoveHandle.wait` does for a follower a limit stopped, the tracker
    forgetting its gearing and the same :class:`~galil.errors.MotionError` raised (decision
    0049); nothing otherwise.

    Raises:
        MotionError: a limit stopped a follower, and its gearing is off.
    """
    ends = _follower_codes(followers, values)
    if not forget_dropped(tracker, followers, ends):
        return
    at = [round(v) for v in values[: len(ends)]]  # (the followers' _RP)
    result = MoveResult(
        final={},
        predicted={},
        deviation={},
        stop_codes={a: round(c) for a, c in stop_codes.items()},
        follower_final=dict(zip(followers, at, strict=True)),
        follower_stop_codes=ends,
    )
    raise_if_limited(link, followers, result)
