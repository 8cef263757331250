"""Motion in progress: handles that know their prediction, the tracker, stop, abort, the guard.

Every command that starts or changes a move goes out on one line with ``MG TIME``, so a
:class:`MoveHandle` knows the controller sample at which it took effect and re-predicts the
motion exactly (a speed change, an ``IP``, an ``ST``) instead of guessing from the host's clock
(``docs/decisions/0002``). Everything here is in counts and seconds; axes give each handle a
``display`` that shows profiles in their user units.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import logging
import math
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from galil import codes, predict
from galil.errors import (
    CommandError,
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    MotionError,
    ProtocolError,
    ReadOnly,
)
from galil.link import (
    RECONNECT_ADVICE,
    CommandLink,
    check_callable,
    check_flag,
    check_wait_timeout,
    warn_caller,
)
from galil.models import tm_of
from galil.predict.smoothing import stored_it
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.protocol.numbers import read_one
from galil.units import Scale

__all__ = [
    "HOMING_KINDS",
    "SLICE_SECONDS",
    "SWITCH_BITS",
    "Display",
    "GearLink",
    "LineSlicer",
    "MotionTracker",
    "MoveHandle",
    "MoveParams",
    "MoveResult",
    "StopWatch",
    "Track",
    "abort_all",
    "as_stored",
    "change_line",
    "dropped_parts",
    "forget_dropped",
    "held",
    "line_timeout",
    "motion_guard",
    "motors_off",
    "moving_axes",
    "raise_if_limited",
    "raise_if_stopped_elsewhere",
    "refuse_dropped",
    "refuse_endless_wait",
    "sample_of",
    "send_reopening",
    "stop_axes",
    "stop_on_error",
    "switch_blocks",
    "wait_guard",
    "zero_speed",
]

_LOG = logging.getLogger("galil.motion")
_new = object.__new__

# Polling faster than this only loads the link; the controller decodes a command in ~0.5 ms.
MIN_POLL = 0.005
MAX_POLL = 0.1
# The program variable a speed schedule stores its BG sample in (8 characters at most).
SCHEDULE_BEGIN = "gsbegin"
# How long the guard waits for stopped axes to come to rest before giving up.
_GUARD_WAIT = 30.0
_LIMIT_CODES = codes.LIMIT_STOPS
#: Like a limit's, a fault's end (:data:`galil.codes.FAULT_STOPS`) is not the prediction's,
#: and ``wait()`` raises (not a stop the host commanded).
_EARLY_CODES = codes.LIMIT_STOPS | codes.FAULT_STOPS
#: ``ST`` (4) and ``AB`` (7): the end of a move stopped by the library (quiet: its prediction
#: follows the stop), or by a stop it did not send (a raw command, another host, a program):
#: ``wait()`` raises then (decision 0105), but for a jog, which such a stop ends as its own.
_STOP_CODES = frozenset({4, 7})
#: Stop codes of an axis still moving that is being stopped: a limit (2, 3) or an ``ST``
#: (4) the library did not send. The controller takes ``DC`` then (decision 0039).
_STOPPING_CODES = _LIMIT_CODES | {4}

#: Track kinds of HM, FE and FI (:mod:`galil.homing`).
HOMING_KINDS = frozenset({"home", "edge", "index"})

Display = Callable[[predict.Profile], predict.Profile]
"""Shows a profile in an axis's user unit (arrays stay in counts)."""


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
        follower_final: final reference position (``_RP``) of each axis geared to the move's
            axes (see :attr:`MoveHandle.followers`), counts.
        follower_stop_codes: ``_SC`` of each of those followers: 0 while it still follows,
            2 or 3 when a limit stopped it (and turned its gearing off).
    """

    final: dict[str, int]
    predicted: dict[str, int]
    deviation: dict[str, int]
    stop_codes: dict[str, int]
    follower_final: dict[str, int] = field(default_factory=dict)
    follower_stop_codes: dict[str, int] = field(default_factory=dict)

    @property
    def worst(self) -> int:
        """Largest absolute deviation over the predicted axes, counts."""
        return max((abs(v) for v in self.deviation.values()), default=0)

    def stop_text(self, axis: str) -> str:
        """The text of an axis's stop code."""
        return codes.stop_text(self.stop_codes[axis])


@dataclass
class Track:
    """What is known of one axis's motion since its BG: enough to predict it again."""

    kind: str  # "position" | "jog" | "schedule" | "home" | "edge" | "index"
    start: int
    params: MoveParams
    begin: int | None  # controller sample (TIME) of the BG line; None while unknown
    amount: float = 0.0  # position: distance in counts; jog: the first JG (signed)
    events: list[predict.Event] = field(default_factory=list)
    aborted: int | None = None  # sample of an AB
    stopped: bool = False  # an ST went out (host side): the jog has an end
    stop_sent: bool = False  # an ST or AB reached the axis through the library (decision 0105)
    exact: bool = True  # False once something happened that the predictor cannot follow
    fixed: predict.Profile | None = None  # a prediction made elsewhere (schedule, homing)
    note: str = ""  # what is known of the prediction, in words (homing says it here)
    # ``fixed`` made again with the AC changes in ``events`` (a homing with its switches)
    replan: Callable[[Sequence[predict.Event]], predict.Profile] | None = None

    @property
    def open_jog(self) -> bool:
        """A jog (or a homing sequence nobody predicted) has no known end until stopped."""
        kind = self.kind
        if kind == "jog" or (kind in HOMING_KINDS and self.fixed is None):
            return not self.stopped and self.aborted is None
        return False


@dataclass
class GearLink:
    """An axis geared to a master (``GA``/``GR``), as the tracker knows it.

    Attributes:
        follower: the geared axis.
        master: the master axis letter (its commanded position, ``GA CA``) or ``"S"`` (the
            distance along the S sequences).
        ratio: GR as the controller stores it.
        anchor: the follower's fixed-point state since the gearing engaged (or its ratio last
            changed): the follower at any later master position, fraction included.
        display: shows the follower's profiles in its unit.
        scale: the follower's scale (its refusals in its unit), if it has one.
        released: controller sample at which ``ST``, ``AB`` or a limit turned the gearing off
            (``None`` while it holds).
        travelled: for ``"S"``, the master position the next sequence starts from (the S
            distance counted since engagement; each predicted sequence adds its length).
        engaged_code: the follower's ``_SC`` read just after ``GR`` engaged it. What a
            controller's ``_SC`` says while it follows is not documented (the simulator
            answers its master's, 0 while that moves); if it still showed the limit of an
            earlier stop, that code could not tell of a new one (:meth:`dropped_by`).
    """

    follower: str
    master: str
    ratio: float
    anchor: predict.GearFollower
    display: Display | None = None
    released: int | None = None
    travelled: int = 0
    engaged_code: int = 0
    scale: Scale | None = None

    def dropped_by(self, code: int) -> bool:
        """Whether the follower's stop code ``code`` says that a limit stopped it, and so
        turned its gearing off: a limit's code (2, 3) other than the one it showed when the
        gearing engaged (a code kept from before is no news)."""
        return code in _LIMIT_CODES and code != self.engaged_code

    def positions(self, master: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """The follower at each of ``master``'s positions (the anchor is left as it is)."""
        return copy.deepcopy(self.anchor).follow(master)

    def profile(self, master: predict.Profile, *, hold_after: int | None = None) -> predict.Profile:
        """The follower's profile, shown in its unit, for a profile of the master's position
        (counts; for ``"S"``, the distance counted since the gearing engaged).

        Args:
            master: the master's predicted profile.
            hold_after: the sample after which the follower holds where it is (its gearing
                turned off there); ``None``: it follows to the end.
        """
        pos = self.positions(master.position)
        if hold_after is not None and 0 <= hold_after < pos.size:
            pos[hold_after + 1 :] = pos[hold_after]
        profile = predict.Profile.from_samples(
            pos,
            sample_period=master.sample_period,
            shape="geared",
            peak_speed=abs(self.ratio) * master.peak_speed,
            stop_code=master.stop_code,
        )
        return profile if self.display is None else self.display(profile)


def as_stored(link: CommandLink, cmd: str, value: float) -> float:
    """``value`` of ``cmd`` (SP, JG, AC, DC or IT; HV as SP) read back from the controller, as
    the step it holds: the text has four decimals of a 32.16 number, up to 5.8e-5 from the
    step (TM 1656.25: SP 2.41509... reads ``2.4151``; IT 0.1, stored as 26/256, reads
    ``0.1016``), and a plan must run at the step itself. A whole value (every step at TM 1000,
    IT 1) is taken as it is."""
    if value.is_integer() if type(value) is float else float(value).is_integer():
        return value
    if cmd == "IT":  # (1/256 steps, 0.0039 apart: the 4-decimal reading names one)
        return stored_it(value)
    return predict.quantise_value(cmd, value, link.model, tm=tm_of(link.sample_period))


#: No model's SP step exceeds this (2·1000/TM at the shortest TM, 31.25 µs): a faster speed
#: needs no look at the step (planning is a hot path).
_LARGEST_SPEED_STEP = 64.0


def _at_least_a_step(link: CommandLink, speed: float, ts: float) -> float:
    """``speed``, or the SP step at the TM in force if it is slower (SP 0 plans one step)."""
    if speed >= _LARGEST_SPEED_STEP:
        return speed
    return max(speed, link.model.speed_resolution(tm_of(ts)))


def sample_of(reply: str) -> int | None:
    """The controller sample in a ``MG TIME{Z10.4}`` reply (``None`` if it is not one number
    in that format: decision 0032)."""
    try:
        return round(read_one(reply))
    except ProtocolError:
        return None


def predict_track(
    link: CommandLink, t: Track, *, sample_period: float | None = None
) -> predict.Profile:
    """Predict one axis's motion from its start and every change recorded since, at
    ``sample_period`` (default: the link's, the TM in force now)."""
    ts = link.sample_period if sample_period is None else sample_period
    p = t.params
    if t.fixed is not None:
        profile = t.fixed if t.replan is None or not t.events else t.replan(t.events)
    elif t.kind in HOMING_KINDS:
        # Nothing known of the switches: only the start (the handle's note says so).
        profile = predict.Profile.from_samples(
            [t.start], sample_period=ts, shape="unknown", peak_speed=p.speed
        )
    else:
        events = t.events
        aborted = t.aborted is not None and t.begin is not None
        if t.aborted is not None and t.begin is not None:
            # AB stops the profiler where it is (an event: a jog aborted after hours is
            # predicted without keeping its samples, predict.move.KEEP_SAMPLES)
            events = [*events, predict.Abort((t.aborted - t.begin) * ts)]
        if t.kind == "jog":
            profile = predict.jog(
                t.amount,
                p.accel,
                p.decel,
                events=events,
                sample_period=ts,
                smoothing=p.smoothing,
                start=t.start,
            )
        else:
            profile = predict.move(
                round(t.amount),
                _at_least_a_step(link, p.speed, ts),
                p.accel,
                p.decel,
                sample_period=ts,
                smoothing=p.smoothing,
                start=t.start,
                events=events,
            )
        return profile.recast(predict.Profile, shape="stopped", stop_code=7) if aborted else profile
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


class _CancelledStartError(InvalidArgument):
    """A start refused because its task was cancelled (:meth:`MotionTracker.refuse_cancelled`):
    nothing was sent, so the guards pass it untouched."""


class MotionTracker:
    """Which handle drives each axis, so stops and changes reach its prediction.

    Attributes:
        lock: held by whoever starts or changes motion from its state read to its
            registration here (resolve -> check -> send -> :meth:`started`), and by a stop or
            abort from its line to :meth:`notify`, so threads sharing a controller never act
            on a state another thread has changed in between, and a stop never falls between
            a move's line and its handle. It is never held while waiting for motion, nor
            while a stream waits for room, so a stop waits for at most one start.
            Lock order: this lock, then a handle's, then the link's.
    """

    def __init__(self) -> None:
        self._active: dict[str, MoveHandle] = {}
        self._stop_sent: set[str] = set()  # axes of handles the library sent ST or AB to
        self.gears: dict[str, GearLink] = {}  # follower letter -> its gearing, while engaged
        #: Followers geared on the controller by something else (found at connect or after a
        #: reset, decision 0055): letter -> ratio. Their master is unknown.
        self.found: dict[str, float] = {}
        #: Whether the controller answers ``_GR`` (read at connect): a master's start then
        #: reads its followers' ratios too, 0 telling of a gearing turned off unseen.
        self.reads_ratios = False
        self.lock = threading.RLock()
        self._watches: list[StopWatch] = []  # a contour's, while it runs (its letters)
        self._refused: set[int] = set()  # threads whose starts are cancelled (refuse_starts)
        #: Reopens a dead link so that a stop can be sent (:func:`stop_on_error`); ``None``
        #: when the link cannot be reopened (a controller built on a transport object).
        self.reconnect: Callable[[], None] | None = None
        #: Set by a controller's close(), before it stops what the library started itself: a
        #: call that then finds the link closed has nothing left to stop, and a move not
        #: seen done by then is never seen done (:attr:`MoveHandle.done` raises).
        self.closed = False
        #: True while close() sends those stops: a link that dies under them is reopened for
        #: them (decision 0073); a link closed on purpose never is.
        self.closing = False
        #: How many times a guard reopened a dead link (a guard whose stop reopened it
        #: through a guard of its own knows by this that the link works again).
        self.reopens = 0
        #: Axes a guard could not stop (its dead link not reopened): close() stops them too
        #: (decision 0077); a start that drives one again takes it back.
        self.unstopped = ""
        #: What the warning of a close that stopped motion nobody waited for advises (an
        #: async controller's says ``await``).
        self.wait_hint = "call wait() on a move's handle"
        self._schedule: MoveHandle | None = None  # the last speed schedule started
        self._sequence: MoveHandle | None = None  # the last vector sequence started

    def end_watches(self) -> None:
        """The link was closed: every move's :meth:`~MoveHandle.add_callback` watcher ends."""
        with self.lock:
            handles = {id(h): h for h in self._active.values()}
        for h in handles.values():
            h._end_watch()

    def stop_started(self, link: CommandLink) -> tuple[str, BaseException | None]:
        """``ST`` to every move the library started and has not seen done (each handle's own
        stop: ``ST S`` for a vector sequence) and to every contour running (its
        :class:`StopWatch`); what a link about to close must not leave running. No query
        when nothing was started. Each stop is sent whatever interrupted the one before (a
        Ctrl-C: that stop's guard stopped what it could).

        Returns:
            The axes whose stop could not be sent (``""`` when every stop went out), and the
            first exception that was not a :class:`~galil.errors.GalilError` (the caller
            raises it once it is done), if any.
        """
        with self.lock:
            handles = {id(h): h for h in self._active.values() if not h.finished}
            streams = [w.letters for w in self._watches]
        stops: list[tuple[str, Callable[[], None]]] = [(h.axes, h.stop) for h in handles.values()]
        stops += [(s, functools.partial(stop_axes, link, self, s)) for s in streams]
        if unstopped := self.unstopped:  # (what a guard could not stop: decision 0077)
            stops.append((unstopped, functools.partial(stop_axes, link, self, unstopped)))
        failed = ""
        interrupted: BaseException | None = None
        for letters, stop in stops:  # (a stream hears of its ST: no CD after it)
            try:
                stop()
            except GalilError:
                failed += letters
            except BaseException as exc:
                interrupted = interrupted or exc
        return failed, interrupted

    def still_running(self, now: float) -> str:
        """The axes of the motion the library started, has not seen end, has not stopped
        already (its ``ST`` or ``AB`` sent: a cancelled wait's, say) and, by its prediction at
        controller time ``now``, still runs (an open jog always; a contour streaming): what
        closing the link now stops mid-way. No query."""
        with self.lock:
            handles = {id(h): h for h in self._active.values() if not h.finished}
            letters = "".join(w.letters for w in self._watches)
            stopped = set(self._stop_sent)
        for h in handles.values():
            open_jog = any(t.open_jog for t in h._tracks.values())
            if open_jog or now <= h.started_at + h.duration:
                letters += "".join(a for a in h.axes if a not in stopped)
        return "".join(dict.fromkeys(letters))

    def started(self, handle: MoveHandle) -> None:
        """``handle`` now drives its axes (and the axes geared to them); stopped at once when
        its thread's starts are refused (:meth:`refuse_starts`)."""
        with self.lock:
            if self.unstopped:  # (the library drives those again)
                ours = {*handle._tracks, *handle._followers}
                self.unstopped = "".join(a for a in self.unstopped if a not in ours)
            for a in handle._tracks:  # (handle.axes, then handle.followers)
                self._active[a] = handle
                self._stop_sent.discard(a)
            for a in handle._followers:
                self._active[a] = handle
            if handle.kind == "schedule":
                self._schedule = handle
            elif handle.kind == "vector":
                self._sequence = handle
            if self._refused and threading.get_ident() in self._refused:
                with contextlib.suppress(GalilError):  # (whoever refused stops it again)
                    handle.stop()

    def last_sequence(self) -> MoveHandle | None:
        """The vector sequence the library started last (one runs on S at a time: an earlier
        one is over), whether it still runs or not."""
        with self.lock:
            return self._sequence

    def schedule_starting(self) -> None:
        """A speed schedule is about to reset the variable its program stamps its begin in
        (:data:`SCHEDULE_BEGIN`): the last schedule's begin, if nobody read it yet, is read
        now (one query), or its handle would later read the new schedule's."""
        with self.lock:
            earlier = self._schedule
            if earlier is not None:
                earlier._read_begin()

    def refuse_starts(self, thread: int) -> None:
        """Stop the motion ``thread`` starts from now on the moment it registers (a handle
        is stopped in :meth:`started`; a :class:`StopWatch` opens already stopped, so a
        contour sends no segment), until :meth:`allow_starts`.

        For a start cancelled from another thread while it runs (``galil.aio``): a stop
        sent before its motion registers would not reach it, and a streamed path would run
        to its end. Take :attr:`lock` around the check of what is registered and this call:
        the motion is then either registered already, or refused.
        """
        with self.lock:
            self._refused.add(thread)

    def refuse_cancelled(self, model: str) -> None:
        """Refuse a start on a thread whose starts are refused (:meth:`refuse_starts`: its
        task was cancelled) before anything is sent: call it under :attr:`lock`, before the
        start's state read, so a start cancelled while it planned never sends its ``BG``
        (decision 0100).

        Raises:
            InvalidArgument: the start was cancelled; nothing was sent.
        """
        if self._refused and threading.get_ident() in self._refused:
            raise _CancelledStartError(
                "this start was cancelled (its task was) before it sent anything", model=model
            )

    def allow_starts(self, thread: int) -> None:
        """Undo :meth:`refuse_starts` (the cancelled start has returned)."""
        with self.lock:
            self._refused.discard(thread)

    def followers(self, masters: str) -> dict[str, GearLink]:
        """The engaged gearings whose master is one of ``masters`` (letters, or ``"S"``)."""
        with self.lock:
            return {f: g for f, g in self.gears.items() if g.master in masters}

    def engage(self, gear: GearLink) -> None:
        """``gear.follower`` now follows its master."""
        with self.lock:
            self.gears[gear.follower] = gear

    def release(self, gear: GearLink) -> None:
        """``gear`` holds no more (if it is still the follower's gearing)."""
        with self.lock:
            if self.gears.get(gear.follower) is gear:
                del self.gears[gear.follower]

    def watch_stops(self, letters: str) -> StopWatch:
        """A :class:`StopWatch` told of every stop or abort of ``letters`` sent through the
        library from now on (for motion without a handle here: a contour); ``close()`` it."""
        watch = StopWatch(letters, self)
        with self.lock:
            self._watches.append(watch)
            if threading.get_ident() in self._refused:
                watch.stopped_by = "ST"  # (refuse_starts: nothing of it may run)
        return watch

    def _unwatch(self, watch: StopWatch) -> None:
        with self.lock:
            if watch in self._watches:
                self._watches.remove(watch)

    def refuse_geared(self, letter: str, what: str, model: str) -> None:
        """Refuse to move a gear follower by itself (before any byte is sent): one the
        library geared, or one found geared on the controller (:attr:`found`).

        Raises:
            InvalidArgument: ``letter`` follows another axis (``what``: the refused action).
        """
        gear = self.gears.get(letter)
        if gear is not None:
            raise InvalidArgument(
                f"axis {letter} is geared to {gear.master}: turn the gearing off before {what}"
                " (its own motion on top of the gearing is not predicted)",
                model=model,
            )
        if letter in self.found:
            raise InvalidArgument(found_text(letter, self.found[letter], what), model=model)

    def found_geared(self, ratios: Mapping[str, float], readable: bool = True) -> None:
        """The ratios just read from the controller (``_GR``, by letter): the followers the
        library did not gear itself, with a ratio other than 0, are :attr:`found`
        (``readable`` False: the controller refused ``_GR``, and none is found).

        Takes no lock: a reopen of the link runs this while the controller's life lock is held,
        and a start that reopens holds :attr:`lock` and then waits for that one (the copy of
        the gearings and the assignment are each atomic)."""
        own = self.gears.copy()
        self.found = {a: r for a, r in ratios.items() if r != 0 and a not in own}
        self.reads_ratios = readable

    def ended(self, letter: str, rp: float, sc: float) -> None:
        """A start read ``letter`` at rest (``_BG`` 0), ``_RP`` ``rp`` and ``_SC`` ``sc``: the
        motion the library last started on it is over, and its handle, if nobody saw it end,
        keeps that end (:meth:`MoveHandle._end_axis`) rather than the next motion's."""
        handle = self.active(letter)
        if handle is not None:
            handle._end_axis(letter, round(rp), round(sc))

    def active(self, letter: str) -> MoveHandle | None:
        """The handle of the move in progress on ``letter`` (``None`` if none or done)."""
        h = self._active.get(letter)
        return None if h is None or h.finished else h

    def track(self, letter: str) -> Track | None:
        """The motion record of the move in progress on ``letter``."""
        h = self.active(letter)
        return None if h is None else h.track(letter)

    def notify(
        self, letters: str, sample: int | None, make: Callable[[float], predict.Event] | None
    ) -> None:
        """A change sent to ``letters`` at controller ``sample`` (``make=None``: an abort).

        A stop or abort of a follower turns its gearing off (outside gantry mode). A stop or
        abort of a move in progress runs what the move left to undo (:meth:`MoveHandle.on_cancel`).
        """
        stopping = make is None or isinstance(make(0.0), predict.Stop)
        with self.lock:
            undo = self._notify_locked(letters, sample, make, stopping)
            for watch in self._watches:
                if stopping:
                    watch.saw("AB" if make is None else "ST", letters)
            for cancel in undo:  # once every handle knows of the stop
                cancel(sample)

    def _notify_locked(
        self,
        letters: str,
        sample: int | None,
        make: Callable[[float], predict.Event] | None,
        stopping: bool,
    ) -> list[Callable[[int | None], None]]:
        undo: list[Callable[[int | None], None]] = []
        for a in letters:
            gear = self.gears.get(a)
            if gear is not None and stopping:
                gear.released = sample
                del self.gears[a]
            handle = self._active.get(a)
            if handle is not None:
                handle.add_event(a, sample, make)
                if stopping:
                    self._stop_sent.add(a)
                # (a follower's stop leaves its master's move to run on)
                cancel = handle.take_cancel() if stopping and a in handle.axes else None
                if cancel is not None:
                    undo.append(cancel)
        return undo


def found_text(letter: str, ratio: float, what: str) -> str:
    """Why ``what`` is refused on ``letter``, found geared on the controller at ``ratio``."""
    return (
        f"axis {letter} is geared on the controller (ratio {ratio:g}), not through this "
        "library, to a master it cannot read: its own motion would add to the gearing's, "
        f"unpredicted. Turn that gearing off (controller.axis('{letter}').gear_off(), GR 0) "
        f"before {what}; gearing set up through the library (gear_to) is predicted"
    )


def refuse_dropped(
    link: CommandLink,
    tracker: MotionTracker | None,
    gears: Mapping[str, GearLink],
    stop_codes: Mapping[str, int],
    ratios: Mapping[str, float] | None = None,
) -> None:
    """Refuse a master's motion while a follower's ``_SC`` (read with the master's state, before
    anything is sent) says that a limit stopped it: the controller turned its gearing off
    during a move nobody waited for (a wait would have said so); or while its ``_GR`` reads 0
    (turned off unseen, its stop code since overwritten by a move: a program's). The tracker
    forgets those gearings, as :meth:`MoveHandle.wait` does, so the call after this one moves
    the master without them.

    Args:
        gears: the followers read, by letter.
        stop_codes: each follower's ``_SC``.
        ratios: each follower's ``_GR``, where the controller answers it.

    Raises:
        MotionError: naming the followers, their master and their stop codes.
    """
    dropped = forget_dropped(tracker, gears, stop_codes, ratios)
    if not dropped:
        return
    first = next(iter(dropped))
    parts = [f"{f}, geared to {gears[f].master}: {codes.stop_text(c)}" for f, c in dropped.items()]
    if all(gears[f].dropped_by(c) for f, c in dropped.items()):
        what = f"a limit stopped {', '.join(dropped)} during a move nobody waited for, and the "
    else:  # (a ratio of 0: by a limit, ST or AB whose stop code a later move overwrote)
        what = f"{', '.join(dropped)} no longer follow(s) (ratio reads 0): the "
    raise MotionError(
        f"{what}controller turned its gearing off ({'; '.join(parts)}). Nothing was sent; the "
        "library forgets that gearing, so the same call again moves without it (or gear it "
        "again first: gear_to)",
        axis=first,
        stop_codes=dict(dropped),
        model=link.model.name,
        recent=link.recent,
    )


class StopWatch:
    """Stops and aborts of some axes sent through the library (``ST``, ``AB``), from any
    thread: :meth:`MotionTracker.watch_stops`."""

    def __init__(self, letters: str, tracker: MotionTracker) -> None:
        self.letters = letters
        self.stopped_by = ""  # "ST" or "AB" once one reached an axis watched
        self._tracker = tracker

    def saw(self, what: str, letters: str) -> None:
        """``what`` (``"ST"``/``"AB"``) went to ``letters``."""
        if not self.stopped_by and set(letters) & set(self.letters):
            self.stopped_by = what

    def close(self) -> None:
        """Watch no more."""
        self._tracker._unwatch(self)

    def __enter__(self) -> StopWatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@functools.lru_cache(maxsize=256)
def _poll_names(letters: str, followers: str) -> tuple[str, ...]:
    """What :attr:`MoveHandle.done` reads: ``_BG``, ``_RP``, ``_SC`` of ``letters``, then
    ``_RP`` and ``_SC`` of ``followers`` (built once per set: a poll is a hot path)."""
    names = [f"_{op}{a}" for op in ("BG", "RP", "SC") for a in letters]
    names += [f"_{op}{f}" for op in ("RP", "SC") for f in followers]
    return tuple(names)


class _HandleState(FixedAttributes):
    """What a :class:`MoveHandle` holds (its ``__init__`` fills it in one update)."""

    kind: ReadOnly[str] = ReadOnly()
    started_at: ReadOnly[float] = ReadOnly()

    _link: CommandLink
    _tracks: dict[str, Track]
    _display: dict[str, Display]
    _tracker: MotionTracker | None
    _kind: str
    _started_at: float
    # The TM the move ran at: a TM sent once it is over (unseen) must not re-predict it.
    _sample_period: float
    _callbacks: list[Callable[[MoveHandle], None]]
    _lock: threading.RLock
    _cache: dict[str, predict.Profile]
    _followers: dict[str, GearLink]
    _ended: dict[str, tuple[int, int]]  # axis -> (RP, SC) seen at rest since


class MoveHandle(_HandleState):
    """A move in progress on one or more axes.

    Attributes:
        kind: ``"position"``, ``"jog"``, ``"schedule"``, or ``"home"``/``"edge"``/``"index"``
            for HM/FE/FI (stop code 10, 9, 10 at their end).
        started_at: the controller clock (seconds) when the handle was made.
    """

    def __init__(
        self,
        link: CommandLink,
        tracks: Mapping[str, Track],
        kind: str,
        *,
        display: Mapping[str, Display] | None = None,
        tracker: MotionTracker | None = None,
    ) -> None:
        # One dict update, not twelve FixedAttributes.__setattr__ calls: a plan makes a handle.
        vars(self).update(_link=link, _tracks=dict(tracks), _display=dict(display or {}),
                          _tracker=tracker, _kind=kind, _started_at=link.clock(),
                          _sample_period=link.sample_period, _callbacks=[],
                          _lock=threading.RLock(), _cache={}, _followers={}, _ended={})  # fmt: skip

    # Until set on the handle itself, the class's values (a handle is made on every plan).
    _done = False
    _result: MoveResult | None = None
    _watcher: threading.Thread | None = None
    # Set when the link closes: the watcher looks now (made with the watcher: an Event
    # costs microseconds that planning, which makes a handle, should not pay).
    _wake: threading.Event | None = None
    _error: BaseException | None = None
    _cancel: Callable[[int | None], None] | None = None
    # Axes a stop the library did not send ended early, with their stop code (decision 0105).
    _foreign: dict[str, int] | None = None

    # -- predictions -------------------------------------------------------------------------
    @property
    def axes(self) -> str:
        """The axis letters this move drives."""
        return "".join(self._tracks)

    @property
    def finished(self) -> bool:
        """Whether the move was seen done (no query; see :attr:`done`)."""
        return self._done

    def track(self, letter: str) -> Track | None:
        """The motion record of one axis (``None`` if the move does not drive it)."""
        return self._tracks.get(letter)

    @property
    def notes(self) -> dict[str, str]:
        """What is known of each axis's prediction, where the handle has something to say
        (a homing sequence: predicted from given switch positions, or unknown)."""
        return {a: t.note for a, t in self._tracks.items() if t.note}

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
        self._read_begin()
        return {a: t.begin for a, t in self._tracks.items()}

    def _read_begin(self) -> None:
        """Read the begin of a speed schedule's program if it is not known yet (one query;
        none for other moves)."""
        for t in self._tracks.values():
            if t.begin is None and t.kind == "schedule":
                self._schedule_begin(t)

    def _schedule_begin(self, track: Track) -> None:
        # The downloaded program stores TIME right after its BG; -1 until it has run.
        with contextlib.suppress(GalilError):
            value = round(self._link.query_operands([SCHEDULE_BEGIN])[0])
            if value >= 0:
                track.begin = value

    @property
    def profiles(self) -> dict[str, predict.Profile]:
        """Predicted profile per axis letter, including every change sent since the start,
        and the profile of every axis geared to one of them (see :meth:`follow`)."""
        with self._lock:
            return dict(self._filled())

    def _filled(self) -> dict[str, predict.Profile]:
        """The cache of :attr:`profiles`, every axis and follower in it (lock held by the
        caller; the dict itself, not a copy: read it, never change it)."""
        cache = self._cache
        if len(cache) != len(self._tracks) + len(self._followers):  # (not all there yet)
            for a, t in self._tracks.items():
                if a not in cache:
                    cache[a] = self._predict(a, t)
            for f, gear in self._followers.items():
                if f not in cache:
                    cache[f] = self._follower(gear)
        return cache

    @property
    def followers(self) -> str:
        """The axes geared to this move's axes, whose motion it predicts too."""
        return "".join(self._followers)

    def follow(self, gears: Mapping[str, GearLink]) -> None:
        """Predict the axes geared to this move's axes too."""
        with self._lock:
            for f, gear in gears.items():
                if f not in self._tracks:
                    self._followers[f] = gear
                    self._cache.pop(f, None)

    def _master_positions(self, gear: GearLink) -> predict.Profile:
        """The predicted positions of ``gear``'s master (one of this move's axes)."""
        master = gear.master
        if master not in self._cache:
            self._cache[master] = self._predict(master, self._tracks[master])
        return self._cache[master]

    def _follower(self, gear: GearLink) -> predict.Profile:
        begin = next(iter(self._tracks.values())).begin
        hold = None  # gearing off (ST, AB): the follower holds where it was
        if gear.released is not None and begin is not None:
            hold = gear.released - begin
        return gear.profile(self._master_positions(gear), hold_after=hold)

    @property
    def profile(self) -> predict.Profile:
        """The predicted profile of the (first) axis."""
        with self._lock:
            return next(iter(self._filled().values()))

    def _predict(self, letter: str, t: Track) -> predict.Profile:
        profile = predict_track(self._link, t, sample_period=self._sample_period)
        show = self._display.get(letter)
        return profile if show is None else show(profile)

    def on_cancel(self, undo: Callable[[int | None], None]) -> None:
        """Call ``undo(sample)`` once, when the library stops or aborts this move before it
        was seen done (``stop()``, an axis's or the controller's ``stop()``, ``abort()``, the
        ``motion()`` guard), right after the ``ST``/``AB`` line, with the controller sample it
        took effect at (``None`` if unknown). A speed schedule undoes its changes there."""
        with self._lock:
            self._cancel = undo

    def take_cancel(self) -> Callable[[int | None], None] | None:
        """What :meth:`on_cancel` registered, handed out once (``None`` once the move was
        seen done: nothing was cancelled)."""
        with self._lock:
            undo, self._cancel = self._cancel, None
            return None if self._done else undo

    def preset(self, profiles: Mapping[str, predict.Profile]) -> None:
        """Profiles already predicted (and displayed) by whoever made the handle."""
        with self._lock:
            self._cache.update(profiles)

    def add_event(
        self, letter: str, sample: int | None, make: Callable[[float], predict.Event] | None
    ) -> None:
        """Record a change sent at controller ``sample`` (``make`` builds it from its time).

        ``make=None`` is an abort. A change after the predicted end of a position move (or
        of a stopped jog) is ignored: the move was over when it arrived.
        """
        with self._lock:
            self._forget_followers(letter)
            t = self._tracks.get(letter)
            if t is None or self._done:
                return
            if make is None or isinstance(make(0.0), predict.Stop):
                t.stop_sent = True  # (wherever it lands: this stop is the library's own)
            if sample is None or t.begin is None or t.aborted is not None:
                t.exact = False
                return
            k = sample - t.begin
            event = None if make is None else make(k * self._sample_period)
            fixed_plan = t.kind == "schedule" or t.kind in HOMING_KINDS
            # (a homing with its switches follows AC, as the simulator does: decision 0066)
            if fixed_plan and (t.replan is None or not isinstance(event, predict.SetAccel)):
                t.exact = False
                return
            current = self.profiles[letter]
            if (t.kind == "position" or t.stopped or fixed_plan) and k > current.samples:
                return  # (over by then: a stopped jog's end is known)
            if event is None:
                t.aborted = sample
            else:
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
            # (``current`` above predicted the followers again from the old master: again)
            self._forget_followers(letter)

    def _forget_followers(self, letter: str) -> None:
        """Drop the cached profiles of the followers of ``letter`` (or of ``letter`` itself)."""
        for f, gear in self._followers.items():
            if letter in (f, gear.master):
                self._cache.pop(f, None)

    @property
    def duration(self) -> float:
        """Predicted duration in seconds (``inf`` for a jog that has not been stopped)."""
        tracks = self._tracks
        for t in tracks.values():
            if t.kind != "position" and t.open_jog:  # (never a position move's)
                return math.inf
        if not tracks:
            return 0.0
        with self._lock:
            return max([p.duration for p in self._filled().values()])

    # -- completion --------------------------------------------------------------------------
    @property
    def result(self) -> MoveResult | None:
        """The comparison with the prediction, once the move is done."""
        return self._result

    def _end_axis(self, letter: str, rp: int, sc: int) -> None:
        """``letter`` was read at rest at ``rp`` with stop code ``sc`` by the start of other
        motion (:meth:`MotionTracker.ended`): its part of this move ended there, and later
        polls leave it out (they would see the other motion). A schedule whose begin nobody
        read reads it now (one query); one whose program has not yet begun its move is not
        over."""
        with self._lock:
            t = self._tracks.get(letter)
            if self._done or t is None:
                return
            if t.kind == "schedule" and t.begin is None:
                self._schedule_begin(t)
                if t.begin is None:
                    return
            self._ended.setdefault(letter, (rp, sc))  # (a later start reads later motion)

    @property
    def done(self) -> bool:
        """True once every axis's profile is complete (``_BG`` is 0); one query per call
        (the followers' ``_RP`` and ``_SC`` ride on it).

        Raises:
            GalilConnectionError: the controller is closed, or closing: a move not seen done
                when ``close()`` began is never seen done (its stop would end it).
        """
        if self._done:
            return True
        if len(self._tracks) == 1 and not self._ended and not self._followers:
            # The usual handle: one axis, nothing geared to it, not seen at rest by a later
            # start (what the general case below reads and finds, without its bookkeeping).
            (a,) = self._tracks
            bg, rp, sc = self._link.query_operands(list(_poll_names(a, "")))
            _refuse_if_closed(self)
            if not round(bg):
                self._finish([round(rp)], [round(sc)], {})
            return self._done
        ended = dict(self._ended)
        axes = self.axes
        letters = "".join([a for a in axes if a not in ended]) if ended else axes
        followers = "".join(self._followers)
        names = _poll_names(letters, followers)
        values = [round(v) for v in self._link.query_operands(list(names))] if names else []
        _refuse_if_closed(self)
        n, m = len(letters), len(followers)
        if not any(values[:n]):
            rest = values[3 * n :]
            ends = dict(zip(followers, zip(rest[:m], rest[m:], strict=True), strict=True))
            now = zip(values[n : 2 * n], values[2 * n : 3 * n], strict=True)
            ended.update(zip(letters, now, strict=True))
            rp_sc = [ended[a] for a in axes]
            self._finish([e[0] for e in rp_sc], [e[1] for e in rp_sc], ends)
        return self._done

    def _finish(
        self, rp: Sequence[int], sc: Sequence[int], followers: Mapping[str, tuple[int, int]]
    ) -> None:
        """Record the result: ``rp`` and ``sc`` of the move's axes, ``(RP, SC)`` per follower."""
        with self._lock:
            if self._done:
                return
            tracks = self._tracks  # (its keys: the axes)
            final = dict(zip(tracks, rp, strict=True))
            stop = dict(zip(tracks, sc, strict=True))
            profiles = self._filled()
            predicted: dict[str, int] = {}
            deviation: dict[str, int] = {}
            worst = 0  # (MoveResult.worst, known here)
            foreign = _stopped_elsewhere(tracks, stop)
            for a, t in tracks.items():
                open_jog = t.kind != "position" and t.open_jog  # (never a position move's)
                if t.exact and not open_jog and stop[a] not in _EARLY_CODES and a not in foreign:
                    end = predicted[a] = profiles[a].end
                    off = deviation[a] = final[a] - end
                    worst = max(worst, abs(off))
            result = _new(MoveResult)  # (a frozen dataclass, built without its setattrs)
            result.__dict__.update(
                final=final,
                predicted=predicted,
                deviation=deviation,
                stop_codes=stop,
                follower_final={f: e[0] for f, e in followers.items()} if followers else {},
                follower_stop_codes={f: e[1] for f, e in followers.items()} if followers else {},
            )
            self._result = result
            self._foreign = foreign
            self._done = True
            callbacks, self._callbacks = self._callbacks, []
        # (outside the handle's lock: the tracker's lock comes first)
        if followers:
            self._release_limited_followers(self._result.follower_stop_codes)
        if worst > 1:  # (attributed to the caller's line, not to the library's)
            warn_caller(
                f"move on {''.join(tracks)} ended {deviation} counts away from the prediction "
                "(stop codes " + ", ".join(f"{a}: {c}" for a, c in stop.items()) + "): a "
                "change the library did not send, or a prediction it could not follow"
            )
        for cb in callbacks:
            self._call(cb)

    def _call(self, callback: Callable[[MoveHandle], None]) -> None:
        """Run one done-callback; what it raises is logged, never lost nor passed on (the
        other callbacks still run, and ``wait()`` still returns the move's own result)."""
        try:
            callback(self)
        except Exception:
            _LOG.exception("move callback %r on %s failed", callback, self.axes)

    def _release_limited_followers(self, codes: Mapping[str, int]) -> None:
        """A follower a limit stopped is geared no more (the controller turned its gearing
        off, outside gantry mode): the tracker forgets the gearing, as it does after an
        ``ST`` or ``AB`` the library sent (the sample is unknown: the prediction is kept)."""
        forget_dropped(self._tracker, self._followers, codes)

    def wait(self, timeout: float | None = None, progress: bool = False) -> MoveResult:
        """Block until the move is done, polling without holding the link between polls.

        Polls come at about a quarter of the predicted time left (between 5 and 100 ms); on a
        manual-clock simulator each pause advances simulated time instead of sleeping.

        Args:
            timeout: seconds to wait at most (``None``: the predicted duration plus a margin,
                or forever for a jog that has not been stopped).
            progress: show a ``tqdm.auto`` bar driven by the predicted duration.

        Raises:
            InvalidArgument: a timeout that is not ``None`` or a finite number of seconds
                >= 0 (:func:`~galil.link.check_wait_timeout`), or no timeout for a jog not
                stopped on a manual-clock simulator (:func:`refuse_endless_wait`), before
                anything is sent.
            GalilTimeoutError: the move did not finish in time (it is NOT stopped).
            MotionError: an axis stopped on a limit switch or soft limit, or on a fault
                (off-on-error, an abort input, an amplifier or encoder fault: stop codes 6,
                8, 11, 12, 15, 16, 70, 71), or a limit stopped an axis geared to one of them
                (its gearing is then off); or an ``ST`` or ``AB`` this library did not send
                ended the move early (a raw command, another host, a program; not a jog's:
                decision 0105); raised once the move's own axes are done, so nothing of the
                move is left moving (a speed schedule a limit or a fault cut short is undone
                first: its routine halted, ``SP`` put back; docs/speed-schedule.md).

        Anything else that interrupts the wait (Ctrl-C, a dead link, no reply) stops the move
        before it propagates (:func:`stop_on_error`).
        """
        if timeout is not None:
            timeout = check_wait_timeout(timeout)
        if progress is not False:
            check_flag(progress, "progress")
        refuse_endless_wait(self, timeout)  # (a refusal: nothing stopped, nothing changed)
        bar: WaitBar | None = None
        try:
            with wait_guard(self):  # (a stream's prediction is computed here, lazily: guarded)
                duration = self.duration
                if timeout is None and math.isfinite(duration):
                    timeout = duration * 1.5 + 2.0
                bar = WaitBar.open(self.kind, self.axes, duration) if progress else None
                done = self._poll_until_done(timeout, bar)
            if not done:
                raise self._link.error(GalilTimeoutError, not_done_text(self, timeout))
        finally:
            if bar is not None:
                bar.close(self._done)
        if self._error is not None:
            raise self._error
        assert self._result is not None
        _undo_cut_short(self, self._result)
        raise_if_limited(self._link, self._followers, self._result)
        raise_if_stopped_elsewhere(self)
        return self._result

    @property
    def _stop_letters(self) -> str:
        """What ``_BG`` says of this move: the axes it still drives (a sequence's: ``"S"``)."""
        return driven_axes(self)

    def _poll_until_done(self, timeout: float | None, bar: WaitBar | None) -> bool:
        """Poll until the move is done (``True``) or ``timeout`` has passed (``False``)."""
        link = self._link
        deadline = None if timeout is None else link.clock() + timeout
        if link.simulated_time:
            self._pause_to_predicted_end(deadline)
        while not self.done:
            now = link.clock()
            if deadline is not None and now >= deadline:
                return False
            elapsed = now - self.started_at
            if bar is not None:
                bar.show(elapsed)
            remaining = self.duration - elapsed
            pause = remaining / 4 if math.isfinite(remaining) else MAX_POLL
            if deadline is not None:
                pause = min(pause, deadline - now)
            link.pause(min(max(pause, MIN_POLL), MAX_POLL))
        return True

    def _pause_to_predicted_end(self, deadline: float | None) -> None:
        """On a simulator's clock, let the predicted time pass at once (and a sample more).

        Time passes at no cost there and the prediction is the simulator's own motion, so
        polling on the way (as on a real controller, a quarter of the time left each time)
        would only spend round trips: one poll then finds the move done.
        """
        link = self._link
        now = link.clock()
        left = self.duration - (now - self.started_at)
        if not math.isfinite(left) or left <= 0:
            return
        pause = left + link.sample_period
        if deadline is not None:
            pause = min(pause, deadline - now)
        if pause > 0:
            link.pause(pause)

    def add_callback(self, callback: Callable[[MoveHandle], None]) -> None:
        """Call ``callback(handle)`` once the move is done (at once if it already is).

        A background thread polls ``_BG`` every 50 ms of real time; it never advances a
        simulator's manual clock (whoever waits does), so a callback may also run on the
        thread that calls :meth:`wait` or reads :attr:`done`.

        The callbacks run only for a move seen done. A move not seen done when the
        controller's ``close()`` begins is stopped by it and never seen done: its callbacks
        are never called (nor is a poll that finds it at rest meanwhile taken as its end).
        """
        check_callable(callback, "callback")
        with self._lock:
            if not self._done:
                self._callbacks.append(callback)
                if self._watcher is None:
                    self._wake = threading.Event()
                    self._watcher = threading.Thread(
                        target=self._watch, name=f"galil-move-{self.axes}", daemon=True
                    )
                    self._watcher.start()
                return
        self._call(callback)

    def _watch(self) -> None:
        wake = self._wake
        assert wake is not None
        try:
            while not self.done:
                wake.wait(MAX_POLL / 2)
        except GalilError as exc:  # the link died or closed: record it, wait() raises it
            self._error = exc

    def _end_watch(self) -> None:
        """The link was closed: the :meth:`add_callback` watcher looks once more (and ends
        on the closed link) now, not at its next poll; joined."""
        wake = self._wake
        if wake is not None:
            wake.set()
        watcher = self._watcher
        if watcher is not None and watcher is not threading.current_thread():
            watcher.join(timeout=2.0)

    def stop(self) -> None:
        """Decelerate the axes the move still drives to a stop (``ST``) at their DC: none once
        it was seen done, nor those newer motion took (:func:`driven_axes`)."""
        stop_driven(self)

    def __repr__(self) -> str:
        state = "done" if self._done else "moving"
        return f"<MoveHandle {self.kind} {self.axes} {state}, predicted {self.duration:.4g} s>"


def refuse_endless_wait(handle: MoveHandle, timeout: float | None) -> None:
    """Refuse a synchronous wait with no ``timeout`` for a jog not stopped on a simulator
    whose manual clock moves only while the host waits, when nothing on the controller can
    end it: one query (before anything is sent) finds the jog still running, no program
    thread running (a program, the watchdog's routine, could stop it) and no soft limit in
    its way (``FL``/``BL`` at the int32 ends). Another Python thread could still stop it:
    that one gives a timeout. On any other link (and in ``galil.aio``, where another task
    may stop it) a jog's wait with no timeout waits for ever, as documented.

    Raises:
        InvalidArgument: stop the jog first, or give a timeout (nothing is sent).
    """
    if timeout is not None or not handle._link.simulated_time or handle._done:
        return
    link = handle._link
    if not getattr(getattr(link, "transport", None), "manual_clock", False):
        return
    jogs = {a: t for a, t in handle._tracks.items() if t.kind == "jog" and t.open_jog}
    if not jogs or len(jogs) != len(handle._tracks):
        return
    names = [f"_BG{a}" for a in jogs] + [f"_XQ{n}" for n in range(link.model.threads)]
    names += [f"_{'FL' if t.amount > 0 else 'BL'}{a}" for a, t in jogs.items()]
    try:
        values = [round(v) for v in link.query_operands(names)]
    except GalilError:
        return  # (the wait's own polls meet it, under the guard that stops the jog)
    n, m = len(jogs), link.model.threads
    running = all(values[:n]) and all(v < 0 for v in values[n : n + m])
    if not running or any(abs(v) < 2**31 - 1 for v in values[n + m :]):
        return  # (over, or something on the controller may end it: the wait polls)
    raise InvalidArgument(
        f"wait() for the jog on {handle.axes} with no timeout would never end: on a "
        "simulator's manual clock time passes only while this thread waits, and nothing on "
        "the controller will stop the jog (no program runs, no soft limit in its way). Stop "
        "it first (handle.stop(), then wait()), or give a timeout (wait(timeout=2.0) lets "
        "2 s pass, then raises GalilTimeoutError)",
        model=link.model.name,
    )


def driven_axes(handle: MoveHandle) -> str:
    """The axes ``handle`` may still drive, those its ``stop()`` stops: none once it was seen
    done; else its axes but those a later start read at rest (decision 0030) or a newer
    handle took since (:class:`MotionTracker`). When in doubt (a move not waited for, a
    dead link), an axis no newer handle took counts as driven: it is stopped."""
    if handle._done:
        return ""
    tracker, ended = handle._tracker, handle._ended
    drivers = {} if tracker is None else tracker._active
    return "".join(
        [a for a in handle._tracks if a not in ended and drivers.get(a, handle) is handle]
    )


def stop_driven(handle: MoveHandle) -> None:
    """``ST`` on the axes ``handle`` still drives (:func:`driven_axes`); nothing when it
    drives none, so an old handle's stop never ends a newer move on its axes. Under the
    tracker's lock: no start takes an axis between the look and the ``ST``."""
    tracker = handle._tracker
    with held(tracker):
        letters = driven_axes(handle)
        if letters:
            stop_axes(handle._link, tracker, letters)


def not_done_text(handle: MoveHandle, timeout: float | None) -> str:
    """What a wait for ``handle`` that timed out says: the wait leaves the move running,
    unless the error leaves a ``controller.motion()`` block guarding its axes (which stops
    it: the message must not promise it goes on without saying so)."""
    return (
        f"move on {handle.axes} not done after {timeout:.3g} s (predicted "
        f"{handle.duration:.3g} s); it goes on: wait again, or stop it (a controller.motion() "
        "block guarding its axes stops it when this error leaves the block)"
    )


def _undo_cut_short(handle: MoveHandle, result: MoveResult) -> None:
    """A move a limit or a fault stopped before its end undoes what it changed for its
    course, as one the library stops does (:meth:`MoveHandle.on_cancel`: a speed schedule's
    routine is halted and its ``SP`` put back), once, unless a later move drives the axis
    now."""
    if _EARLY_CODES.isdisjoint(result.stop_codes.values()):
        return
    tracker = handle._tracker
    with held(tracker):
        with handle._lock:
            undo, handle._cancel = handle._cancel, None
        later = tracker is not None and any(
            tracker._active.get(a) not in (None, handle) for a in handle._tracks
        )
        if undo is not None and not later:
            undo(None)


def wait_guard(handle: MoveHandle) -> contextlib.AbstractContextManager[None]:
    """The guard of a wait for ``handle``, around its polls and pauses: anything that
    interrupts them (Ctrl-C, a dead link, no reply) stops the move (a dead link reopened once
    for it) before it propagates (:func:`stop_on_error`). ``MoveHandle.wait`` and the async
    handle's ``wait()`` run their polls under it."""
    return stop_on_error(handle._link, handle._tracker, handle._stop_letters, stop=handle.stop)


class _ClosedMeanwhileError(GalilConnectionError):
    """A poll of a move found that ``close()`` had begun (:func:`_refuse_if_closed`):
    close() stops the move, so a wait's guard lets this pass rather than stop it again (its
    stop would be refused by the closing controller, and the caller told, wrongly, that the
    axes could not be stopped)."""


def _refuse_if_closed(handle: MoveHandle) -> None:
    """Raise once ``close()`` has begun (:attr:`MotionTracker.closed`), after a poll's reply
    and before it is taken: close() stops every move not seen done and closes the link, and a
    poll that got in between would see close's own stop end the move (then "done", its
    callbacks called, or not, by the threads' timing). Checked after the reply: ``closed`` is
    set before close() sends a stop, so a poll that passes here was answered before any of
    close()'s stops went out.

    Raises:
        GalilConnectionError: close() has begun.
    """
    tracker = handle._tracker
    if tracker is not None and tracker.closed:
        raise handle._link.error(
            _ClosedMeanwhileError,
            f"the controller was closed (close(), or the end of its with block) before the "
            f"move on {handle.axes} was seen done: close() stopped it",
        )


def forget_dropped(
    tracker: MotionTracker | None,
    followers: Mapping[str, GearLink],
    stop_codes: Mapping[str, int],
    ratios: Mapping[str, float] | None = None,
) -> dict[str, int]:
    """The followers whose stop code (read once their master's motion is over) says that a
    limit stopped them (:meth:`GearLink.dropped_by`), or whose ratio (``ratios``, where read)
    is 0, by letter: the controller turned their gearing off, and ``tracker`` forgets it here."""
    dropped = {
        f: c
        for f, c in stop_codes.items()
        if followers[f].dropped_by(c) or (ratios is not None and ratios.get(f) == 0)
    }
    if tracker is not None:
        for f in dropped:
            tracker.release(followers[f])
    return dropped


def dropped_parts(followers: Mapping[str, GearLink], dropped: Mapping[str, int]) -> list[str]:
    """How a motion's error names each follower a limit stopped (``dropped``: its stop code)."""
    return [
        f"{f}, geared to {followers[f].master}: {codes.stop_text(c)}; its gearing is off"
        for f, c in dropped.items()
    ]


def _stopped_elsewhere(tracks: Mapping[str, Track], stop: Mapping[str, int]) -> dict[str, int]:
    """The axes of ``tracks`` whose stop code ``stop`` says ``ST`` or ``AB`` ended them though
    the library sent neither to them, by letter (decision 0105); a jog's end is its stop,
    whoever sends it."""
    return {
        a: stop[a]
        for a, t in tracks.items()
        if stop[a] in _STOP_CODES and not t.stop_sent and t.kind != "jog"
    }


def raise_if_stopped_elsewhere(handle: MoveHandle) -> None:
    """Raise what :meth:`MoveHandle.wait` raises for a move that a stop the library did not
    send (``ST`` or ``AB``: a raw command, another host, a program) ended early: its axes are
    not where it was going (decision 0105); nothing for any other end."""
    foreign, result = handle._foreign, handle._result
    if not foreign or result is None:
        return
    profiles = handle.profiles
    parts = []
    for a, c in foreign.items():
        name = "ST" if c == 4 else "AB"
        part = f"{a} by {name} (stop code {c}) at {result.final[a]} counts"
        if handle._tracks[a].fixed is not None or handle._tracks[a].kind in ("position", "vector"):
            part += f", going to {profiles[a].end}"
        parts.append(part)
    first = next(iter(foreign))
    link = handle._link
    raise MotionError(
        f"{handle.kind} move on {handle.axes} stopped early by a stop this library did not "
        f"send (a raw command, another host, a program): {'; '.join(parts)}. Its axes are not "
        "where it was going",
        axis=first,
        stop_codes=dict(result.stop_codes),
        position=result.final[first],
        model=link.model.name,
        recent=link.recent,
    )


def raise_if_limited(
    link: CommandLink, followers: Mapping[str, GearLink], result: MoveResult
) -> None:
    """Raise what :meth:`MoveHandle.wait` raises for a move a limit or a fault ended early,
    or a follower a limit stopped (nothing for the usual end); a contour's end raises the
    same for its followers (decision 0049)."""
    if _EARLY_CODES.isdisjoint(result.stop_codes.values()) and not result.follower_stop_codes:
        return  # (the usual end: what the general case below finds, without its dicts)
    limited = {a: c for a, c in result.stop_codes.items() if c in _EARLY_CODES}
    dropped = {f: c for f, c in result.follower_stop_codes.items() if followers[f].dropped_by(c)}
    if not limited and not dropped:
        return
    parts = [f"{a}: {codes.stop_text(c)}" for a, c in limited.items()]
    parts += dropped_parts(followers, dropped)
    first = next(iter(limited or dropped))
    final = {**result.final, **result.follower_final}
    what = "move stopped early" if limited else "a follower stopped early"
    raise MotionError(
        f"{what} ({', '.join(parts)})",
        axis=first,
        stop_codes={**result.stop_codes, **result.follower_stop_codes},
        position=final[first],
        model=link.model.name,
        recent=link.recent,
    )


#: ``TS`` bits 3 and 2: set while the forward and the reverse limit switch are inactive (both
#: set: no switch active, nothing for :func:`switch_blocks` to look at).
SWITCH_BITS = 0x0C
#: ``TS`` bit 5: set while the motor is off (``MO``, or an abort or a position error that
#: turned it off).
MOTOR_OFF_BIT = 0x20


def refuse_motor_off(link: CommandLink, letter: str, ts: int) -> None:
    """Refuse a start on ``letter`` whose ``TS`` (read before anything is sent) says its motor
    is off: the controller would take the profile, and the reference would move without the
    motor.

    Raises:
        InvalidArgument: the motor is off.
    """
    if ts & MOTOR_OFF_BIT:
        raise InvalidArgument(
            f"axis {letter} has its motor off; call controller.servo_here()",
            model=link.model.name,
        )


def switch_blocks(link: CommandLink, letter: str, direction: float, ts: int) -> bool:
    """Whether the limit switch ``direction`` points to blocks a start: active (its ``TS``
    bit clear: 3 forward, 2 reverse) and not disabled by ``LD``. The input of a disabled
    switch still reads active, so ``_LD`` is read (one query) only then, and only on a model
    with LD; a start towards such a switch is taken (decision 0046).
    """
    forward = direction > 0
    if ts & (0x08 if forward else 0x04):
        return False
    if not link.model.has_limit_disable:
        return True
    ld = round(link.query_operands([f"_LD{letter}"])[0])
    return not ld & (1 if forward else 2)


def zero_speed(link: CommandLink, letter: str, name: str, message: str) -> LimitError:
    """The refusal of a start at a speed of 0 (``name``: ``SP``, ``HV`` or ``JG``): ``BG``
    refuses ``SP 0`` (TC 6), HM and FI ``HV 0``, FI ``JG 0``. One type wherever it is met
    (a move, a homing, a speed schedule): :class:`~galil.errors.LimitError`, the speed
    below the model's smallest step."""
    model = link.model
    return LimitError(
        message,
        name=name,
        value=0,
        limit=model.sp_resolution,
        axis=letter,
        model=model.name,
    )


def refuse_in_motion(link: CommandLink, tracker: MotionTracker, letter: str, name: str) -> None:
    """Refuse ``name`` (a command the controller takes only at rest, TC 7 otherwise: ``DC``
    in a position move not stopped by an ``ST``, ``MT``, ``BR``) on an axis the library
    itself knows is moving: a motion it started, not seen over, and by its prediction not
    over yet. Only then is the axis read once (``_BG``, ``_RP``, ``_SC``), before refusing:
    a limit or a fault may have ended the move, or (for ``DC``) a limit's stop may be ramping
    it down, which the library learns at its next poll only. No query otherwise: a motion
    started elsewhere (a program) still gets the controller's refusal.

    Raises:
        InvalidArgument: the axis moves.
    """
    handle = tracker.active(letter)
    track = None if handle is None else handle.track(letter)
    if handle is None or track is None or letter in handle._ended:
        return
    if name == "DC" and (track.kind == "jog" or (track.kind == "position" and track.stopped)):
        # "DC may be changed during a move in Jog mode, but not in a PA or PR move", and
        # "directly following an axis stop (i.e. ST m ...)" while it still decelerates.
        return
    if not track.open_jog and link.clock() > handle.started_at + handle.duration:
        # Over by its prediction, unseen: the controller decides. (Not at the very instant of
        # its end: a move of no length predicts 0 s, and the controller holds _BG 1 until its
        # next sample, so a check in the same instant asks.)
        return
    bg, rp, sc = link.query_operands(list(_poll_names(letter, "")))
    if not round(bg):
        tracker.ended(letter, rp, sc)  # (its handle reports this end, a limit's or a fault's)
        return
    if name == "DC" and track.kind == "position" and round(sc) in _STOPPING_CODES:
        # "directly following an axis stop (i.e. ST m or a limit switch), the DC value of a
        # PA or PR move may be changed": a PA/PR move only (a sequence's ramp is VD's)
        return
    raise InvalidArgument(
        f"{name} is not valid while axis {letter} moves (its {handle.kind} move is in "
        "progress): wait for the move or stop it first",
        model=link.model.name,
    )


class WaitBar:
    """The bar of a wait with ``progress=True``, the sync :meth:`MoveHandle.wait`'s and the
    async handle's alike: a ``tqdm.auto`` bar over the predicted duration, in seconds (a jog
    not yet stopped has no total: the bar counts seconds).

    Made only when asked for: a wait without it neither imports tqdm nor pays a check per poll
    beyond ``bar is not None``. Whoever opens one closes it on every way out of the wait
    (:meth:`close`, in a ``finally``), so tqdm keeps no bar of it.
    """

    __slots__ = ("_bar",)
    _said_missing: ClassVar[bool] = False  # (tqdm missing: warned once per process)

    def __init__(self, bar: Any) -> None:
        self._bar = bar

    @classmethod
    def open(cls, kind: str, axes: str, duration: float) -> WaitBar | None:
        """A bar named ``"<kind> <axes>"`` over ``duration`` seconds (``None`` without tqdm,
        said once per process by a ``RuntimeWarning`` at the caller's line)."""
        try:
            from tqdm.auto import tqdm
        except ImportError:  # progress is a nicety; the wait itself does not need it
            if not WaitBar._said_missing:
                WaitBar._said_missing = True
                warn_caller(
                    "progress=True shows no bar: tqdm is not installed (pip install "
                    "'galil[jupyter]'); the wait goes on without it"
                )
            return None
        total = duration if math.isfinite(duration) else None
        fmt = "{l_bar}{bar}| {n:.2f}/{total:.2f} s" if total is not None else "{desc}: {n:.2f} s"
        return cls(tqdm(total=total, desc=f"{kind} {axes}", unit="s", bar_format=fmt))

    def show(self, elapsed: float) -> None:
        """Show ``elapsed`` seconds of the move (at most the total)."""
        bar = self._bar
        bar.n = elapsed if bar.total is None else min(elapsed, bar.total)
        bar.refresh()

    def close(self, done: bool) -> None:
        """Show the end (the whole total once the move was seen ``done``; else where it got)
        and close the bar, even if showing it fails."""
        bar = self._bar
        try:
            if done and bar.total is not None:
                bar.n = bar.total
            bar.refresh()
        finally:
            bar.close()


# ----------------------------------------------------------------------------------- stopping


def held(tracker: MotionTracker | None) -> contextlib.AbstractContextManager[object]:
    """The tracker's :attr:`~MotionTracker.lock` (nothing to hold without a tracker)."""
    return contextlib.nullcontext() if tracker is None else tracker.lock


def stop_axes(link: CommandLink, tracker: MotionTracker | None, letters: str = "") -> None:
    """``ST`` on ``letters`` (default: all axes); the moves' predictions follow the stop.

    A move another thread is starting is either stopped with its handle told, or starts after
    the stop (:attr:`MotionTracker.lock`), never between the line and its handle. Interrupted
    (Ctrl-C before the line went out, a dead link, no reply), the stop is sent again
    (:func:`stop_on_error`)."""
    send = functools.partial(_send_st, link, tracker, letters)
    guard = stop_on_error(link, tracker, letters or link.model.axes, stop=send, is_stop=True)
    with held(tracker), guard:
        send()


def _send_st(link: CommandLink, tracker: MotionTracker | None, letters: str) -> None:
    with held(tracker):
        replies = link.command_line([cmds.st(letters, model=link.model), cmds.time_stamp()])
        if tracker is not None:
            tracker.notify(letters or link.model.axes, sample_of(replies[-1]), predict.Stop)


def motors_off(link: CommandLink, letters: str, tracker: MotionTracker | None = None) -> None:
    """``MO`` on ``letters`` (``""``: every axis), refused before it is sent while one of them
    moves (``_BG`` 1: a move, a jog, a sequence, a gear follower, a program's motion): the
    controller refuses MO in motion (TC 7; the DMC-4103 reference: "Not Valid while in
    motion"). One query before the line; with ``tracker``, the query and the line under its
    lock (no start from another thread between them).

    Raises:
        InvalidArgument: an axis moving (stop it and wait first); only the query went out.
    """
    command = cmds.mo(letters, model=link.model)
    read = letters or link.model.axes
    with held(tracker):
        bg = link.query_operands([f"_BG{a}" for a in read])
        _refuse_moving(link, read, bg, "motor off", "MO")
        link.command_line([command])


def _refuse_moving(
    link: CommandLink, letters: str, bg: Sequence[float], what: str, mnemonic: str
) -> None:
    """Refuse ``what`` (``mnemonic``, "Not Valid while in motion") when one of ``letters``
    reads ``_BG`` 1 in ``bg``.

    Raises:
        InvalidArgument: an axis moving (nothing sent but the read).
    """
    busy = "".join(a for a, v in zip(letters, bg, strict=True) if round(v))
    if busy:
        raise InvalidArgument(
            f"{what} refused: {busy} moving, and the controller refuses {mnemonic} in motion "
            "(TC 7); stop the motion and wait for it first",
            model=link.model.name,
        )


def servo_here(link: CommandLink, tracker: MotionTracker, letters: str) -> None:
    """``SH`` on ``letters`` (``""``: every axis), refused before it is sent while one of them
    moves: the controller refuses SH in motion (TC 7; the DMC-4103 reference: "Not Valid
    while in motion"). One query before the line (``_BG``, and ``_RP``, ``_SC`` below).

    ``SH`` puts a motor-off axis's reference where its encoder is: whatever the library
    predicted for the motion it last started there is over (an abort, a limit or a position
    error that turned the motor off). Where such a motion's handle was not seen done, the
    same query reads the axes' ``_RP`` and ``_SC``, and the handle keeps that end
    (:meth:`MotionTracker.ended`, decision 0030): a later ``wait()`` reports where and how
    the move ended, not the position ``SH`` took.

    Raises:
        InvalidArgument: an axis moving (stop it and wait first); only the query went out.
    """
    command = cmds.sh(letters, model=link.model)
    read = letters or link.model.axes
    with tracker.lock:  # (no start in another thread between the read and SH)
        open_ = "".join([a for a in read if tracker.active(a) is not None])
        names = [f"_BG{a}" for a in read] + [f"_{op}{a}" for op in ("RP", "SC") for a in open_]
        values = link.query_operands(names)
        n, k = len(read), len(open_)
        _refuse_moving(link, read, values[:n], "servo here", "SH")
        for a, rp, sc in zip(open_, values[n : n + k], values[n + k :], strict=True):
            tracker.ended(a, rp, sc)
        link.command_line([command])


def abort_all(link: CommandLink, tracker: MotionTracker | None) -> None:
    """``AB 1``: stop every axis at once, without deceleration; programs keep running.
    Interrupted, it is sent again (:func:`stop_on_error`)."""
    send = functools.partial(_send_ab, link, tracker)
    with held(tracker), stop_on_error(link, tracker, link.model.axes, stop=send, is_stop=True):
        send()


def _send_ab(link: CommandLink, tracker: MotionTracker | None) -> None:
    with held(tracker):
        replies = link.command_line([cmds.ab(motion_only=True), cmds.time_stamp()])
        if tracker is not None:
            tracker.notify(link.model.axes, sample_of(replies[-1]), None)


@contextlib.contextmanager
def motion_guard(
    link: CommandLink,
    tracker: MotionTracker | None,
    letters: str,
    *,
    reconnect: Callable[[], None] | None = None,
) -> Iterator[None]:
    """Stop the guarded axes (``ST``) and wait for them if the block raises (Ctrl-C included).

    The stop is tried even when the state query fails; a dead link is reopened once (with
    ``reconnect``) to send it. The block's exception is re-raised once the axes have stopped;
    if they could not be stopped (or not confirmed stopped), a :class:`MotionError` naming the
    axes that may still be moving is raised from it.
    """
    try:
        yield
    except BaseException as exc:
        reopen = _Reopen(reconnect, tracker)
        moving = _stop_for_guard(link, tracker, letters, None, reopen.or_none())
        if moving:
            raise _not_stopped(link, tracker, exc, moving, "inside motion()") from exc
        if reopen.reopened and isinstance(exc, GalilConnectionError):
            raise _reopened(link, exc, letters, "the block") from exc
        raise


#: What an operation raises when nothing of it ran, or its motion is over: refused before
#: the first byte (InvalidArgument, LimitError, ScheduleError), refused by the controller
#: (CommandError: it answered '?'), or a motion that ended already (MotionError: a limit, a
#: stop sent from elsewhere). Anything else may have come after the line went out.
_NOTHING_RAN = (InvalidArgument, CommandError, MotionError)


def change_line(
    link: CommandLink, handle: MoveHandle | None, letter: str, line: Sequence[str | Command]
) -> list[str]:
    """Send ``line``, a change to the motion ``handle`` runs on ``letter`` (a new ``JG``, an
    ``IP``, ``SP``/``AC``/``DC`` in motion), and return its replies.

    Interrupted where it may have gone out (anything but a refusal: Ctrl-C, a lost reply, a
    dead link), whether the change took effect is not known, so the handle's prediction of
    ``letter`` no longer claims to be exact (decision 0072). The exception then goes on, to
    the guard that stops the motion (:func:`stop_on_error`).
    """
    try:
        return link.command_line(line)
    except _NOTHING_RAN:
        raise
    except BaseException:
        if handle is not None:
            handle.add_event(letter, None, None)  # (a change at an unknown time: inexact)
        raise


def stop_on_error(
    link: CommandLink,
    tracker: MotionTracker | None,
    letters: str,
    *,
    stop: Callable[[], None] | None = None,
    running: bool = False,
    is_stop: bool = False,
) -> contextlib.AbstractContextManager[None]:
    """The guard of an operation that starts or changes the motion of ``letters`` (``"S"``:
    a vector sequence): if it raises anything that may have come once its line went out (a
    timeout, a dead link, Ctrl-C, a bug), what moves of ``letters`` is stopped, a dead link
    reopened once for it (:attr:`MotionTracker.reconnect`), and waited for, before the
    exception goes on: the caller never gets an exception with the motion running. A
    refusal (:data:`_NOTHING_RAN`) passes untouched: the motion is as it was.

    Args:
        stop: sends the stop (default: ``ST`` on ``letters`` through the tracker).
        running: the motion runs already and the block sends the rest of it (a streamed
            path's later segments): a refusal of one of those stops it too (what follows it
            would never be sent); only a :class:`MotionError` (the motion is over) passes.
        is_stop: the block is itself a stop (``ST``, ``AB``): when it failed with a
            :class:`GalilError` (its link died, its reply was lost, the link out of step did
            not resynchronise in time) and the guard got the stop through (on the reopened
            link if it had died) with the axes confirmed at rest, the block has done its job,
            and the error is logged (WARNING on ``galil.motion``) rather than raised.

    Raises:
        MotionError: from the exception, naming the axes that may still move, when the stop
            could not be sent or confirmed.
        GalilConnectionError: from a dead link's error, once the guard reopened the link and
            stopped the axes (saying so: the link works again).
    """
    return _StopOnError(link, tracker, letters, stop, running, is_stop)


class _StopOnError:
    """:func:`stop_on_error`'s guard: a class, not a generator (it guards every start and
    every wait, a hot path; entering and leaving it costs next to nothing)."""

    __slots__ = ("_is_stop", "_letters", "_link", "_running", "_stop", "_tracker")

    def __init__(
        self,
        link: CommandLink,
        tracker: MotionTracker | None,
        letters: str,
        stop: Callable[[], None] | None,
        running: bool,
        is_stop: bool,
    ) -> None:
        self._link = link
        self._tracker = tracker
        self._letters = letters
        self._stop = stop
        self._running = running
        self._is_stop = is_stop

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> bool:
        if exc is None or isinstance(exc, MotionError if self._running else _NOTHING_RAN):
            return False
        if isinstance(exc, _ClosedMeanwhileError):
            return False  # close() has begun: it stops the motion (even while it closes)
        link, tracker = self._link, self._tracker
        if (
            tracker is not None
            and tracker.closed
            and not tracker.closing
            and isinstance(exc, GalilConnectionError)
        ):
            return False  # close() stopped the motion before it closed the link
        reopen = _Reopen(None if tracker is None else tracker.reconnect, tracker)
        also = ""
        if self._is_stop and tracker is not None:
            # Whether the stop went out is not known: the moves it names no longer claim an
            # exact prediction (decision 0072), and it goes out again for the followers it
            # names, even at rest, whose gearing it turns off (decision 0069).
            _doubt(tracker, self._letters)
            also = _geared_among(tracker, self._letters)
        moving = _stop_for_guard(link, tracker, self._letters, self._stop, reopen.or_none(), also)
        if moving:
            raise _not_stopped(
                link, tracker, exc, moving, "while starting or changing motion"
            ) from exc
        if self._is_stop and isinstance(exc, GalilError):
            # The block was the stop itself, and the guard got it through: done.
            _late_stop(self._letters, exc, reopen.reopened)
            return True
        if reopen.reopened and isinstance(exc, GalilConnectionError):
            raise _reopened(link, exc, self._letters, "the operation") from exc
        return False


def _late_stop(letters: str, exc: GalilError, reopened: bool) -> None:
    """Log (WARNING) a stop whose first try failed and whose guard stopped ``letters``: on
    the reopened link (the link had died), or late (a lost reply, a link out of step that
    took long to resynchronise: decision 0065)."""
    if reopened and isinstance(exc, GalilConnectionError):
        _LOG.warning(
            "the link died while stopping %s (%s); it was reopened and they are stopped",
            letters,
            _died_of(exc),
        )
    else:
        _LOG.warning(
            "stopping %s failed at first (%s: %s); the stop was sent again and they are stopped",
            letters,
            type(exc).__name__,
            exc.args[0] if exc.args else exc,
        )


class _Reopen:
    """A guard's reconnect, noting whether the link was reopened since the guard began:
    by this reconnect, or by another guard's (a stop's own guard, inside this one's stop)."""

    __slots__ = ("_before", "_reconnect", "_tracker", "done")

    def __init__(self, reconnect: Callable[[], None] | None, tracker: MotionTracker | None) -> None:
        self._reconnect = reconnect
        self._tracker = tracker
        self._before = 0 if tracker is None else tracker.reopens
        self.done = False

    @property
    def reopened(self) -> bool:
        tracker = self._tracker
        return self.done or (tracker is not None and tracker.reopens != self._before)

    def or_none(self) -> Callable[[], None] | None:
        return None if self._reconnect is None else self

    def __call__(self) -> None:
        assert self._reconnect is not None
        self._reconnect()
        self.done = True
        if self._tracker is not None:
            self._tracker.reopens += 1


def _died_of(exc: GalilConnectionError) -> str:
    """Why the link died, without the advice to reopen it (it is open again)."""
    text = str(exc.args[0] if exc.args else exc).removesuffix(RECONNECT_ADVICE)
    dead = "the controller link died ("
    return text[len(dead) : -1] if text.startswith(dead) and text.endswith(")") else text


def _reopened(
    link: CommandLink, exc: GalilConnectionError, letters: str, what: str
) -> GalilConnectionError:
    """The error a guard raises once it reopened a dead link and stopped ``letters``: the link
    works again, so the old advice to call reconnect() would mislead."""
    return link.error(
        GalilConnectionError,
        f"the link died ({_died_of(exc)}); it was reopened and {letters} stopped, so the link"
        f" works again, but {what} was cut short and may or may not have taken effect",
    )


def _not_stopped(
    link: CommandLink, tracker: MotionTracker | None, exc: BaseException, moving: str, where: str
) -> MotionError:
    """The error of a guard that could not stop ``moving``; the tracker keeps them for
    close() to stop (decision 0077)."""
    if tracker is not None:
        with tracker.lock:
            tracker.unstopped += "".join(a for a in moving if a not in tracker.unstopped)
    return MotionError(
        f"{type(exc).__name__} {where}; axes {moving} could not be stopped and may still be moving",
        moving=moving,
        axis=moving[0],
        model=link.model.name,
        recent=link.recent,
    )


def _stop_for_guard(
    link: CommandLink,
    tracker: MotionTracker | None,
    letters: str,
    stop: Callable[[], None] | None,
    reconnect: Callable[[], None] | None,
    also: str = "",
) -> str:
    """Stop what moves of ``letters`` (all of them if unknown), and ``also`` those, with
    ``stop`` (default: ``ST`` on those); return what may still move."""
    try:
        busy = moving_axes(link, letters)
    except GalilError:
        busy = letters  # unknown (a dead link among the causes): stop them all
    busy += "".join(a for a in also if a not in busy)
    if not busy:
        return ""
    if stop is None:
        stop = functools.partial(_send_st, link, tracker, busy)
    if not send_reopening(stop, reconnect):
        return busy
    return _wait_stopped(link, busy)


def _doubt(tracker: MotionTracker, letters: str) -> None:
    """The motions the library runs on ``letters`` got a change at an unknown time (or none):
    their predictions are not exact any more."""
    for a in letters:
        handle = tracker.active(a)
        if handle is not None:
            handle.add_event(a, None, None)


def _geared_among(tracker: MotionTracker | None, letters: str) -> str:
    """Those of ``letters`` the tracker counts on as gear followers."""
    gears = {} if tracker is None else tracker.gears
    return "".join(a for a in letters if a in gears)


def moving_axes(link: CommandLink, letters: str) -> str:
    """Those of ``letters`` that read ``_BG`` 1 (one query; none for ``""``)."""
    values = link.query_operands([f"_BG{a}" for a in letters])
    return "".join(a for a, v in zip(letters, values, strict=True) if round(v))


def send_reopening(send: Callable[[], object], reconnect: Callable[[], None] | None) -> bool:
    """Call ``send`` (a stop, or an undo after a failed start); on a dead link reopen it once
    with ``reconnect`` and try again; another error gets one more try too. Never raises a
    :class:`GalilError`.

    Returns:
        Whether ``send`` went through.
    """
    for attempt in range(2):
        try:
            send()
            return True
        except GalilConnectionError:
            if reconnect is None or attempt:
                return False
            try:
                reconnect()
            except GalilError:
                return False
        except GalilError:
            if attempt:
                return False
    return False


#: A part's ``:`` (its reply) and, at most, a time stamp's or a read's number on top.
_REPLY_BYTES = 1
_NUMBER_BYTES = 16


def line_timeout(link: CommandLink, parts: Sequence[Command]) -> float:
    """The reply timeout of ``parts`` sent at once (``command_line``: as many lines as they
    fill, pipelined): a bulk transfer's (decision 0064, :meth:`~galil.link.Link.transfer_timeout`),
    from their bytes both ways at the link's byte rate. A vector sequence's setup and first
    segments, or a contour's refill, is hundreds of segments long: several kilobytes, seconds
    on a serial line, where the link's own timeout (1 s) bounds an ordinary line
    (decision 0100)."""
    size = 0
    for c in parts:  # (a ';' or the CR after each, its ':', a number for a read)
        size += _part_bytes(c)
    return link.transfer_timeout(_EMPTY_LINE, size)


def _part_bytes(c: Command) -> int:
    """A part's bytes on one line, both ways (:func:`line_timeout`)."""
    return len(c.text) + 1 + _REPLY_BYTES + (_NUMBER_BYTES if c.returns_data else 0)


#: The longest one line of a long run of parts (a contour's refill, a sequence's setup) holds
#: the link, in seconds of its bytes at the link's byte rate: the link is free again after
#: each line, and a line's round trip stays a small part of it (decision 0100).
SLICE_SECONDS = 0.25


class LineSlicer:
    """Cuts a long run of parts into lines that hold the link a short time, and puts a
    running watchdog's heartbeat on them (decision 0100).

    A line takes at most :data:`SLICE_SECONDS` of bytes at the link's byte rate, and at most
    half the heartbeat interval of a watchdog that beats on the link (its keepalive); a link
    that does not say its rate is fast: no cut. A thread that streams line after line takes
    the link back as soon as it lets it go (a lock is not fair), and on a simulator time
    passes only with the bytes, so the watchdog's own thread may not get a beat in: the
    heartbeat rides at the head of a line once half its interval has passed since this
    slicer last put one on.
    """

    def __init__(self, link: CommandLink) -> None:
        self._link = link
        self._beaten = -math.inf  # (the link's clock when this slicer last sent the beat)

    def _budget(self) -> float:
        """The bytes one line may carry (infinite on a link that does not say its rate)."""
        link = self._link
        rate = link.byte_rate
        if rate is None or not rate > 0:
            return math.inf
        seconds = SLICE_SECONDS
        keep = link.keepalive
        if keep is not None:
            seconds = min(seconds, keep[1] / 2)
        return seconds * rate

    def cut(self, parts: Sequence[Command], start: int, stop: int, extra: int = 0) -> int:
        """The end of the run of ``parts`` from ``start`` (to ``stop`` at most) one line
        carries, with ``extra`` bytes more on it (a time stamp, a read): one part at least."""
        budget = self._budget() - extra
        size = 0
        end = start
        while end < stop:
            size += _part_bytes(parts[end])
            if size > budget and end > start:
                break
            end += 1
        return end

    def beat(self) -> list[Command]:
        """The heartbeat to put at the head of the next line (empty: no watchdog beats on
        the link, or this slicer put one on less than half its interval ago)."""
        link = self._link
        keep = link.keepalive
        if keep is None:
            return []
        now = link.clock()
        if now - self._beaten < keep[1] / 2:
            return []
        self._beaten = now
        return [keep[0]]

    def send(self, parts: Sequence[Command], timeout: float | None = None) -> list[str]:
        """``command_line(parts)`` with the beat at its head when due; the parts' replies."""
        beat = self.beat()
        return self._link.command_line([*beat, *parts], timeout=timeout)[len(beat) :]

    def send_all(self, parts: Sequence[Command]) -> None:
        """All of ``parts`` in order, a short line at a time (:meth:`send`), each line with
        the reply timeout of its size (:func:`line_timeout`: seconds on a slow line)."""
        sent = 0
        while sent < len(parts):
            end = self.cut(parts, sent, len(parts))
            self.send(parts[sent:end], line_timeout(self._link, parts[sent:end]))
            sent = end


#: What :func:`line_timeout` gives :meth:`~galil.link.Link.transfer_timeout` as the command:
#: the bytes of the parts all count alike (the command's and the reply's add up there).
_EMPTY_LINE = Command("")


def _wait_stopped(link: CommandLink, busy: str) -> str:
    deadline = link.clock() + _GUARD_WAIT
    try:
        while True:
            still = moving_axes(link, busy)
            if not still:
                return ""
            if link.clock() > deadline:
                return still
            link.pause(MIN_POLL * 4)
    except GalilError:
        return ""  # ST went out; the link failed while watching the stop
