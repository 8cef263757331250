"""Coordinated motion, host side: a path checked and predicted, then sent and streamed.

A path is a list of :class:`~galil.segments.Line` and :class:`~galil.segments.Arc` segments
in each axis's user units. It becomes the predictor's counts-level segments through each axis's
scale (:mod:`galil.segments`), is predicted and checked as a whole
(:func:`galil.predict.check_vector`: buffer depth, TC 30/31/33, each axis's speed and
acceleration along the path, soft limits over the whole path) before a byte is sent, and then
goes out as one sequence:

- vector mode (``CA S``, ``CS S``, ``VM``, ``VP``/``CR``, ``VE``) for lines and arcs in a
  plane of two axes, or linear interpolation (``LM``, ``LI``, ``LE``) for lines on one to
  eight axes;
- ``VS``/``VA``/``VD`` (and ``VT`` where the model has it) for the plane, the first segments
  (as many as the buffer holds), then ``BG S`` with ``MG TIME`` on its line;
- the rest streamed as buffer slots free up (``_LMS``), each line stamped with ``MG TIME``,
  so the handle re-predicts the sequence exactly as the controller ran it
  (:func:`galil.predict.vector.replay`), even if the host was late.
"""

from __future__ import annotations

import contextlib
import numbers
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from galil import predict
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    ProtocolError,
    decimal_hint,
)
from galil.link import CommandLink, check_flag
from galil.models import tm_of
from galil.motion import (
    SWITCH_BITS,
    GearLink,
    LineSlicer,
    MotionTracker,
    MoveHandle,
    MoveParams,
    Track,
    held,
    line_timeout,
    refuse_motor_off,
    sample_of,
    stop_on_error,
    switch_blocks,
)
from galil.moves import check_followers, follower_limits, follower_operands
from galil.predict.path import first_directions
from galil.predict.vector import SequenceEvent, replay
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.segments import (
    PathAxis,
    PathInCounts,
    Segment,
    VectorPlan,
    describe_scales,
    show,
    to_counts,
)
from galil.units import (
    Amount,
    counts_or_plain,
    is_quantity,
    rate_magnitude_counts,
    state_in_units,
)

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # (typing_extensions: a dependency on Python 3.10)
    from typing_extensions import Unpack

__all__ = ["StreamOptions", "VectorHandle", "VectorOptions", "VectorStream"]


class _VectorSpeed(TypedDict):
    speed: Amount


class VectorOptions(_VectorSpeed, total=False):
    """The keyword arguments of a path (:meth:`Controller.vector_move
    <galil.controller.CoordinatedMotion.vector_move>`, ``**options`` of ``plan_vector``):
    ``speed`` (required), and what it documents."""

    accel: Amount | None
    decel: Amount | None
    smoothing: float | None
    mode: str | None
    stream: bool
    axis_speed: Mapping[str, Amount] | None
    axis_accel: Mapping[str, Amount] | None


class StreamOptions(VectorOptions, total=False):
    """:class:`VectorOptions` and what the controller adds: the link's ``byte_rate``."""

    byte_rate: float | None


#: The coordinate system the library's sequences use.
PLANE = "S"


# --------------------------------------------------------------------------- sending


@dataclass
class _Sequence:
    """What is known of one sent sequence: enough to predict it again, exactly."""

    initial: tuple[predict.PathSegment, ...]
    settings: tuple[float, float, float, float]  # VS, VA, VD, smoothing (quantised)
    sample_period: float
    start: tuple[int, ...]
    angle_resolution: float
    ended: bool
    begin: int | None = None
    events: list[SequenceEvent] = field(default_factory=list)
    _profile: predict.VectorProfile | None = None

    def profile(self) -> predict.VectorProfile:
        if self._profile is None:
            vs, va, vd, vt = self.settings
            self._profile = replay(
                self.initial,
                vs,
                va,
                vd,
                events=self.events,
                ended=self.ended,
                sample_period=self.sample_period,
                start=self.start,
                smoothing=vt,
                angle_resolution=self.angle_resolution,
            )
        return self._profile

    def event(
        self, sample: int | None, kind: str, segments: Sequence[predict.PathSegment] = ()
    ) -> bool:
        """Record what went out at controller ``sample``; False if it cannot be placed."""
        if sample is None or self.begin is None:
            return False
        if kind in ("stop", "abort") and any(e.kind == kind for e in self.events):
            return True  # the first ST (or AB) is the one that counts
        self.events.append(SequenceEvent(max(0, sample - self.begin), kind, tuple(segments)))
        self._profile = None
        return True


class VectorHandle(MoveHandle):
    """A sequence in progress on its axes: a :class:`~galil.motion.MoveHandle` whose
    prediction is the whole path's (``profiles`` per axis, :attr:`vector` in user units).

    ``stop()`` sends ``ST S``; ``controller.stop()``, ``AB`` and the ``motion()`` guard reach
    it through the tracker. The prediction follows every segment streamed, ``VE``, ``ST`` and
    ``AB`` at the controller sample it took effect.
    """

    def __init__(
        self,
        link: CommandLink,
        sequence: _Sequence,
        axes: Sequence[PathAxis],
        path: PathInCounts,
        *,
        tracker: MotionTracker | None = None,
    ) -> None:
        vs, va, vd, vt = sequence.settings
        params = MoveParams(vs, va, vd, vt)
        tracks = {
            a.letter: Track("vector", sequence.start[i], params, sequence.begin)
            for i, a in enumerate(axes)
        }
        displays = {a.letter: a.display for a in axes if a.display is not None}
        super().__init__(link, tracks, "vector", display=displays, tracker=tracker)
        self._sequence = sequence
        self._path_axes = tuple(axes)
        self._path = path
        self._stopped = False

    @property
    def counts(self) -> predict.VectorProfile:
        """The prediction in counts, with everything sent so far."""
        with self._lock:
            return self._sequence.profile()

    @property
    def vector(self) -> VectorPlan:
        """The prediction in the axes' user units (path, speed along it, ``plot()``)."""
        return show(self.counts, self._path_axes, self._path)

    def _master_positions(self, gear: GearLink) -> predict.Profile:
        if gear.master != PLANE:
            return super()._master_positions(gear)
        return _path_master(self.counts, gear)

    def _finish(
        self, rp: Sequence[int], sc: Sequence[int], followers: Mapping[str, tuple[int, int]]
    ) -> None:
        with self._lock:
            if not self._done:
                for gear in self._followers.values():
                    if gear.master == PLANE:
                        gear.travelled += int(self.counts.path[-1])
        super()._finish(rp, sc, followers)

    def _predict(self, letter: str, t: Track) -> predict.Profile:
        i = self._path.letters.index(letter)
        profile = self.counts.axis(i)
        show_in = self._display.get(letter)
        return profile if show_in is None else show_in(profile)

    def add_event(
        self, letter: str, sample: int | None, make: Callable[[float], predict.Event] | None
    ) -> None:
        """A stop (``ST``) or abort (``AB``) sent at controller ``sample`` (other changes,
        SP or AC of an axis, do not touch a sequence)."""
        with self._lock:
            if self._done:
                return
            if letter not in self._tracks:
                # A follower's ST: its gearing is off (the tracker marks it released), and the
                # sequence it followed runs on; only the follower's prediction changes.
                self._forget_followers(letter)
                return
            if make is None:
                kind = "abort"
            elif isinstance(make(0.0), predict.Stop):
                kind = "stop"
            else:
                return
            self._stopped = True  # whoever sent it: nothing more is streamed
            for t in self._tracks.values():  # (the library's own stop: decision 0105)
                t.stop_sent = True
            if not self._sequence.event(sample, kind):
                for t in self._tracks.values():
                    t.exact = False
            self._cache.clear()

    @property
    def stopped(self) -> bool:
        """Whether an ``ST`` or ``AB`` reached the sequence (from any thread)."""
        return self._stopped

    def record(
        self, sample: int | None, kind: str, segments: Sequence[predict.PathSegment]
    ) -> None:
        """Segments or the end sent during the sequence, at controller ``sample``."""
        with self._lock:
            if not self._sequence.event(sample, kind, segments):
                for t in self._tracks.values():
                    t.exact = False
            self._cache.clear()

    @property
    def _stop_letters(self) -> str:
        return PLANE

    def stop(self) -> None:
        """Decelerate the sequence to a stop along its path at VD (``ST S``).

        ``ST S`` reaches the sequence that runs on S now, whichever it is: once this one is
        over (seen done, an axis of it read at rest by a later start, or a sequence started
        since), nothing is sent, so a late stop never ends a newer sequence. While this one
        may still run (not waited for, a dead link), ``ST S`` goes out."""
        link = self._link
        if self._tracker is None:
            if not self._done:
                replies = link.command_line([cmds.st(PLANE, model=link.model), cmds.time_stamp()])
                self.add_event(self.axes[0], sample_of(replies[-1]), predict.Stop)
            return
        # Interrupted, the stop goes out again to what still moves (decision 0028; on a link
        # that died, reopened once), and the sequence no longer claims an exact prediction.
        guard = stop_on_error(link, self._tracker, PLANE + self.axes, stop=self._st, is_stop=True)
        with self._tracker.lock:  # (between a streamed line and the next: see _feed)
            if self._on_plane():
                with guard:
                    self._st()

    def _st(self) -> None:
        """``ST S``, told to this sequence, unless it is over (:meth:`_on_plane`)."""
        assert self._tracker is not None
        link = self._link
        with self._tracker.lock:
            if self._on_plane():
                replies = link.command_line([cmds.st(PLANE, model=link.model), cmds.time_stamp()])
                self._tracker.notify(self.axes, sample_of(replies[-1]), predict.Stop)

    def _on_plane(self) -> bool:
        """Whether this sequence may still run on S: the last one the library started, and
        not over (seen done, or an axis of it read at rest by a later start: decision 0030)."""
        assert self._tracker is not None
        return self._tracker.last_sequence() is self and not self._done and not self._ended


def _path_master(counts: predict.VectorProfile, gear: GearLink) -> predict.Profile:
    """What a ``GA S`` follower follows: the distance along the path, counted on from the
    sequences before (``gear.travelled``)."""
    return predict.Profile.from_samples(
        gear.travelled + counts.path,
        sample_period=counts.sample_period,
        shape="vector",
        peak_speed=counts.peak_speed,
        stop_code=counts.stop_code,
    )


#: ``TS`` in place of ``_MO``: its bit 5 is "motor off", and its bits 3 and 2 the limit
#: switches (set while inactive), with one operand per axis (the state query stays one line).
_STATE = ("RP", "BG", "TS", "FL", "BL", "SC")
#: What a line of streamed segments ends with: the sample it ran in.
_STAMP_SIZE = len(cmds.time_stamp().text) + 1


@dataclass(frozen=True)
class _State:
    start: tuple[int, ...]
    forward: list[float | None]
    backward: list[float | None]
    accel: float
    decel: float
    smoothing: float
    follower_limits: dict[str, tuple[float, float, int]]  # (BL, FL, TS switch bits)
    switches: tuple[int, ...]  # each axis's TS limit bits (a change: prepared again)


class VectorStream:
    """One sequence: :meth:`prepare` (one state query, the prediction, every check; nothing
    sent) and :meth:`start` (send, begin, stream the rest, return the handle).

    Args:
        link: the command link.
        axes: the path's axes (letter, scale, display), in the order of its components.
        segments: :class:`Line` and :class:`Arc` segments in user units.
        speed: along the path; a Quantity needs a scale common to every axis, a plain
            number is counts/s.
        accel: along the path, likewise (``None``: the controller's VA).
        decel: along the path, likewise (``None``: the controller's VD).
        smoothing: VT (on models that have it); ``None``: the controller's (VT, or the first
            axis's IT on models without VT).
        mode: ``"vector"``, ``"linear"`` or ``None`` (see :func:`to_counts`).
        stream: send segments during the motion when the path is longer than the buffer; with
            ``False`` such a path is refused (TC 32).
        byte_rate: the link's bytes per second where it is slow (a serial port): a streamed
            path it cannot deliver in time is refused.
        followers: axes geared to the path's axes or to ``S``: the handle predicts them too.
        axis_speed: the most each axis may move along the path, by letter, in its unit per
            second (counts/s without a scale); default: the model's SP maximum.
        axis_accel: the same for acceleration (tangential and centripetal), default the
            model's AC maximum.
    """

    def __init__(
        self,
        link: CommandLink,
        axes: Sequence[PathAxis],
        segments: Sequence[Segment],
        *,
        speed: object,
        accel: object = None,
        decel: object = None,
        smoothing: float | None = None,
        mode: str | None = None,
        stream: bool = True,
        byte_rate: float | None = None,
        followers: Mapping[str, GearLink] | None = None,
        axis_speed: Mapping[str, object] | None = None,
        axis_accel: Mapping[str, object] | None = None,
    ) -> None:
        self.link = link
        self.byte_rate = byte_rate
        self.axes = tuple(axes)
        model = link.model
        self.path = to_counts(
            segments, self.axes, mode=mode, angle_resolution=model.cr_angle_resolution
        )
        self.speed = self._rate(speed, 1, "speed")
        self.accel = None if accel is None else self._rate(accel, 2, "accel")
        self.decel = None if decel is None else self._rate(decel, 2, "decel")
        if smoothing is not None and _not_a_number(smoothing):  # (True is not VT 1: 0026)
            raise InvalidArgument(
                f"smoothing (VT) must be a number, not {smoothing!r:.60}" + decimal_hint(smoothing)
            )
        if smoothing is not None and not model.vt:
            raise InvalidArgument(
                f"{model.name} has no VT: its sequences are smoothed by the first axis's IT "
                "(axis.smoothing)",
                model=model.name,
            )
        self.smoothing = smoothing
        self.stream = check_flag(stream, "stream")
        self.speed_limits = self._limits(axis_speed, 1, "axis_speed", model.sp_max)
        self.accel_limits = self._limits(axis_accel, 2, "axis_accel", model.ac_max)
        letters = self.path.letters
        self.followers = {f: g for f, g in (followers or {}).items() if f not in letters}
        self.profile: predict.VectorProfile | None = None
        self._state: _State | None = None
        self._tracker: MotionTracker | None = None  # (forgets a follower a limit dropped)

    @classmethod
    def prepared(
        cls,
        link: CommandLink,
        axes: Sequence[PathAxis],
        segments: Sequence[Segment],
        tracker: MotionTracker,
        **options: Unpack[StreamOptions],
    ) -> VectorStream:
        """A stream for ``axes``, already prepared (:meth:`prepare`), its followers from
        ``tracker``."""
        for ax in axes:  # (before any byte, as a move of a follower is refused)
            tracker.refuse_geared(ax.letter, "a path on it", link.model.name)
        masters = "".join(a.letter for a in axes) + PLANE
        run = cls(link, axes, segments, followers=tracker.followers(masters), **options)
        run._tracker = tracker
        run.prepare()
        return run

    def _rate(self, value: object, power: int, what: str) -> float:
        """A speed or acceleration along the path, counts/s**power (> 0)."""
        scaled = [a.scale for a in self.axes if a.scale is not None]
        if is_quantity(value) and scaled:
            if self.path.per_unit is None:
                raise InvalidArgument(
                    f"{what} along the path in user units needs the same counts per unit on "
                    f"every axis ({describe_scales(self.axes)}); give it in counts"
                )
            # (in the user's direction: a reversed axis's scale makes a rate's counts negative)
            counts = scaled[0].sign * scaled[0].rate_to_counts(value, power, what)
        elif scaled and self.path.per_unit is not None:
            raise InvalidArgument(
                f"{what}: {value!r} has no units but the axes have scales; give a Quantity"
                f" such as 10 * ureg.{self.path.unit}/s" + ("²" if power == 2 else "")
            )
        else:
            counts = counts_or_plain(value, what, self.path.letters, power=power)
        if not counts > 0:
            raise InvalidArgument(f"{what} along the path must be positive, got {value!r}")
        return counts

    def _limits(
        self, given: Mapping[str, object] | None, power: int, what: str, default: float
    ) -> list[float | None]:
        """Per-axis limits in counts, in the path's axis order (the model's by default)."""
        if given is not None and not isinstance(given, Mapping):
            raise InvalidArgument(f"{what} must be a mapping of axis to value, not {given!r:.60}")
        out: list[float | None] = [float(default)] * len(self.axes)
        by_letter = {a.letter: i for i, a in enumerate(self.axes)}
        for name, value in (given or {}).items():
            letter = self.link.model.axis_letter(name)
            if letter not in by_letter:
                raise InvalidArgument(f"{what}: {name!r} is not an axis of the path")
            scale = self.axes[by_letter[letter]].scale
            counts = rate_magnitude_counts(scale, value, power, f"{what} of {letter}", letter)
            out[by_letter[letter]] = min(counts, float(default))
        return out

    # ---- prepare -------------------------------------------------------------------------
    def _read_state(self) -> _State:
        link = self.link
        model = link.model
        letters = self.path.letters
        names = [f"_{op}{a}" for a in letters for op in _STATE] + ["_BGS"]
        extra = []
        if self.accel is None:
            extra.append("_VAS")
        if self.decel is None:
            extra.append("_VDS")
        if self.smoothing is None:
            extra.append("_VTS" if model.vt else f"_IT{letters[0]}")
        followers = "".join(self.followers)
        of_followers = follower_operands(followers, self._tracker)
        values = link.query_operands(names + extra + list(of_followers))
        n = len(_STATE)
        rows = [values[i * n : (i + 1) * n] for i in range(len(letters))]
        if values[len(letters) * n]:
            raise InvalidArgument(
                "a sequence is running on S; wait for it or stop it", model=model.name
            )
        for a, (rp, bg, ts, _, _, sc) in zip(letters, rows, strict=True):
            if not bg and self._tracker is not None:
                self._tracker.ended(a, rp, sc)
            if bg:
                raise InvalidArgument(f"axis {a} is moving; stop it or wait", model=model.name)
            refuse_motor_off(link, a, round(ts))
        tail = len(values) - len(of_followers)
        limits = follower_limits(link, self._tracker, self.followers, values[tail:])
        rest = iter(values[len(letters) * n + 1 : tail])
        return _State(
            start=tuple(round(r[0]) for r in rows),
            forward=[r[3] for r in rows],
            backward=[r[4] for r in rows],
            accel=self.accel if self.accel is not None else next(rest),
            decel=self.decel if self.decel is not None else next(rest),
            smoothing=self.smoothing if self.smoothing is not None else next(rest),
            follower_limits=limits,
            switches=tuple(round(r[2]) & SWITCH_BITS for r in rows),
        )

    def prepare(self) -> predict.VectorProfile:
        """Read where the axes are (one query), predict, and check everything.

        Raises:
            InvalidArgument: an axis moving or its motor off, a sequence running, an axis
                whose first motion on the path heads into its active limit switch (TC 22), or
                an axis geared to a path axis or to ``S`` whose first motion does (0053).
            MotionError: a limit stopped an axis geared to a path axis or to ``S`` during a
                move nobody waited for (its gearing is off: :func:`~galil.motion.refuse_dropped`).
            LimitError: a check failed (named segment and sample): VS/VA/VD ranges, TC 30,
                31, the buffer (``stream=False``, or a link too slow to keep it fed), an
                axis's speed or acceleration along the path, a soft limit; or an axis
                geared to a path axis or to ``S`` taken past its soft limits or beyond the
                model's SP maximum.
        """
        link = self.link
        model = link.model
        state = self._read_state()
        segs = self.path.segments
        self._refuse_blocked(state.switches)
        with self._in_user_units():
            profile = predict.check_vector(
                segs,
                self.speed,
                state.accel,
                state.decel,
                model=model,
                start=state.start,
                smoothing=state.smoothing,
                tm=tm_of(link.sample_period),
                forward_limits=state.forward,
                backward_limits=state.backward,
                speed_limits=self.speed_limits,
                accel_limits=self.accel_limits,
                streaming=self.stream,
                axes=self.path.letters,
            )
        if self.stream and len(segs) > model.vector_buffer:
            self._check_link_rate(profile)
        self._check_followers(profile, state.follower_limits)
        self.profile = profile
        self._state = state
        return profile

    def _refuse_blocked(self, switches: Sequence[int]) -> None:
        """Refuse a path on which an axis first moves towards its active limit switch (one
        ``LD`` leaves on: :func:`~galil.motion.switch_blocks`): ``BG S`` would be refused
        with TC 22 once the setup and the segments had gone out (decision 0050). Only the
        first direction counts: a switch active now stops later motion towards it anyway."""
        if all(ts == SWITCH_BITS for ts in switches):
            return  # (no switch active: the path's directions are not needed)
        link = self.link
        path = self.path
        res = link.model.cr_angle_resolution
        directions = first_directions(path.segments, len(path.letters), res)
        for a, direction, ts in zip(path.letters, directions, switches, strict=True):
            if direction and switch_blocks(link, a, direction, ts):
                side = "forward" if direction > 0 else "reverse"
                raise InvalidArgument(
                    f"axis {a} would start towards its active {side} limit switch on this "
                    "path (the controller refuses BG S with TC 22); move off the switch first",
                    model=link.model.name,
                )

    def _check_followers(
        self, profile: predict.VectorProfile, limits: Mapping[str, tuple[float, float, int]]
    ) -> None:
        """The axes geared to a path axis or to ``S``, over the whole path, against their soft
        limits and the model's SP maximum (as for a position move of their master).

        Raises:
            LimitError: naming the follower.
        """
        if not self.followers:
            return
        letters = self.path.letters
        profiles = {
            f: gear.profile(
                _path_master(profile, gear)
                if gear.master == PLANE
                else profile.axis(letters.index(gear.master))
            )
            for f, gear in self.followers.items()
        }
        check_followers(self.link, self.followers, profiles, limits)

    @contextlib.contextmanager
    def _in_user_units(self) -> Iterator[None]:
        """Add the unit to a refusal in counts: an axis's own (its speed or acceleration along
        the path), or the path's (VS, VA, VD, lengths) when every axis has the same scale."""
        try:
            yield
        except LimitError as exc:
            axis = next((a for a in self.axes if a.letter == exc.axis), None)
            if axis is not None:
                state_in_units(exc, axis.scale)
            elif exc.axis is None and self.path.per_unit is not None:
                state_in_units(exc, self.axes[0].scale)  # (None without scales: counts)
            raise

    def _check_link_rate(self, profile: predict.VectorProfile) -> None:
        rate = self.byte_rate
        if rate is None or rate <= 0:
            return  # Ethernet or the simulator: far faster than any segment
        deadlines = predict.segment_deadlines(profile)
        texts = self._texts(profile)
        depth = self.link.model.vector_buffer
        sizes = np.array([len(t.text) + 1 + _STAMP_SIZE for t in texts[depth:]], dtype=float)
        arrival = np.cumsum(sizes) / rate  # seconds after BG S, at best
        ts = profile.sample_period
        late = np.flatnonzero(arrival > deadlines[depth:] * ts)
        if late.size:
            i = depth + int(late[0])
            k = int(deadlines[i])
            raise _buffer_error(
                f"segment {i} must be in the buffer by t={k * ts:.6g} s (sample {k}) for the"
                f" motion to keep its speed, but the link ({rate:g} bytes/s) delivers it at"
                f" t={arrival[late[0]]:.6g} s at best: slow the path down or use Ethernet",
                k,
                ts,
                i,
            )

    # ---- send ----------------------------------------------------------------------------
    def _texts(self, profile: predict.VectorProfile) -> list[Command]:
        model = self.link.model
        out: list[Command] = []
        ends = profile.layout.end
        for i, seg in enumerate(self.path.segments):
            if isinstance(seg, predict.Line):
                out.append(cmds.vp(int(ends[i][0]), int(ends[i][1])))
            elif isinstance(seg, predict.Arc):
                out.append(cmds.cr(seg.radius, seg.start, seg.sweep, model=model))
            else:
                incs = dict(zip(self.path.letters, seg.increments, strict=True))
                out.append(cmds.li(model=model, **incs))
        return out

    def _setup(self, state: _State) -> list[Command]:
        model = self.link.model
        letters = self.path.letters
        mode = (
            cmds.vm(letters, model=model)
            if self.path.kind == "vector"
            else cmds.lm(letters, model=model)
        )
        assert self.profile is not None
        vs, va, vd, vt = self.profile.speed_settings
        out = [
            cmds.ca(PLANE),
            cmds.cs(PLANE),
            mode,
            cmds.vs(vs, PLANE, model=model),
            cmds.va(va, PLANE, model=model),
            cmds.vd(vd, PLANE, model=model),
        ]
        if model.vt and self.smoothing is not None:
            out.append(cmds.vt(vt, PLANE, model=model))
        return out

    def _end(self) -> Command:
        return cmds.ve() if self.path.kind == "vector" else cmds.le()

    def start(self, tracker: MotionTracker | None) -> VectorHandle:
        """Send the sequence and begin it; stream what the buffer cannot hold yet.

        Returns once every segment and ``VE``/``LE`` are in the controller (at once for a
        path that fits the buffer). Whatever goes wrong while streaming, the sequence is
        stopped (``ST S``) before the error is raised.
        """
        lock = held(tracker)
        link = self.link
        with lock:  # no other thread's motion from the state read to the handle
            if tracker is not None:
                tracker.refuse_cancelled(link.model.name)  # (before the state read: 0100)
            texts, first = self._load(tracker)  # (nothing moves before BG S)
            with stop_on_error(link, tracker, PLANE):
                handle = self._begin(tracker, texts, first)
        if first < len(texts):
            with stop_on_error(link, tracker, PLANE, stop=handle.stop, running=True):
                self._feed(handle, texts, first, lock)
        return handle

    def _load(self, tracker: MotionTracker | None) -> tuple[list[Command], int]:
        """Read the state again under the tracker's lock (a stream is prepared without it,
        the prediction of a long path being too slow to hold up another thread's stop or a
        cancellation: another thread may have moved the axes since), send the setup and the
        first segments; the segments' commands and how many went out.

        Raises:
            GalilTimeoutError, GalilConnectionError, ProtocolError: the setup's line failed
                (:meth:`_not_started`): ``BG S`` was not sent, nothing moves.
        """
        if self.profile is None or self._state is None:
            self.prepare()
        elif tracker is not None and self._read_state() != self._state:
            self.prepare()  # another thread moved the axes since (read under the lock)
        profile, state = self.profile, self._state
        assert profile is not None
        assert state is not None
        link = self.link
        texts = self._texts(profile)
        first = min(len(texts), link.model.vector_buffer)
        setup = self._setup(state) + texts[:first] + ([self._end()] if first == len(texts) else [])
        # Up to 511 segments: kilobytes, seconds on a serial line: short lines (a watchdog's
        # heartbeat gets through), each with a transfer's timeout (decision 0100).
        wait = line_timeout(link, setup)  # (the resynchronisation's, after a failure)
        try:
            LineSlicer(link).send_all(setup)
        except (InvalidArgument, CommandError):
            raise  # (refused: BG S not sent, the link in step; the next setup's CS clears S)
        except GalilError as exc:
            error = self._not_started(exc, wait)
            if error is exc:
                raise
            raise error from exc
        return texts, first

    def _not_started(self, exc: GalilError, wait: float) -> GalilError:
        """The error of a setup line that failed (``exc``: no reply in time, a dead link, a
        garbled reply): ``BG S`` was not sent and the axes were read at rest, so nothing
        moves and nothing is to be stopped. The link resynchronises first (within ``wait``:
        the rest of a long line may still be on its way on a slow line), so that it is left
        in step when it can be (``exc`` itself for an error of another kind)."""
        link = self.link
        try:
            link.query_operands([f"_BG{PLANE}"], timeout=wait)
            after = ""
        except GalilError:
            after = "; the link is still out of step (it resynchronises before the next command)"
        kinds = (GalilTimeoutError, GalilConnectionError, ProtocolError)
        kind = next((k for k in kinds if isinstance(exc, k)), None)
        if kind is None:
            return exc  # (no other error comes of a line: as it is)
        text = exc.args[0] if exc.args else type(exc).__name__
        return link.error(
            kind,
            f"{text}; the sequence was not started: BG S was not sent and the axes "
            f"{self.path.letters} were at rest{after}",
        )

    def _begin(
        self, tracker: MotionTracker | None, texts: list[Command], first: int
    ) -> VectorHandle:
        """``BG S`` (the setup and the first ``first`` of ``texts`` are in); the handle."""
        profile, state = self.profile, self._state
        assert profile is not None
        assert state is not None
        link = self.link
        ended = first == len(texts)
        replies = link.command_line([cmds.bg(PLANE, model=link.model), cmds.time_stamp()])
        sequence = _Sequence(
            initial=self.path.segments[:first],
            settings=profile.speed_settings,
            sample_period=profile.sample_period,
            start=state.start,
            angle_resolution=link.model.cr_angle_resolution,
            ended=ended,
            begin=sample_of(replies[-1]),
            _profile=profile if ended else None,
        )
        handle = VectorHandle(link, sequence, self.axes, self.path, tracker=tracker)
        handle.follow(self.followers)
        if tracker is not None:
            tracker.started(handle)
        return handle

    def _groups(self, start: int, stop: int, texts: Sequence[Command]) -> list[tuple[int, int]]:
        """Runs of segments that fit one line with ``MG TIME`` after them."""
        limit = self.link.model.line_length
        out: list[tuple[int, int]] = []
        i = start
        while i < stop:
            j, size = i, _STAMP_SIZE
            while j < stop and (j == i or size + len(texts[j].text) + 1 <= limit):
                size += len(texts[j].text) + 1
                j += 1
            out.append((i, j))
            i = j
        return out

    def _feed(
        self,
        handle: VectorHandle,
        texts: Sequence[Command],
        sent: int,
        held: contextlib.AbstractContextManager[object],
    ) -> None:
        """Stream the rest as room frees up; nothing more once a stop reached the sequence
        (``held``, the tracker's lock, keeps a stop from falling between the check and a
        line)."""
        link = self.link
        profile = self.profile
        assert profile is not None
        segs = self.path.segments
        depth = link.model.vector_buffer
        refill = max(1, depth // 4)
        deadlines = predict.segment_deadlines(profile)
        begin = handle.begin[self.path.letters[0]] or 0
        ts = link.sample_period
        slicer = LineSlicer(link)  # (a watchdog's heartbeat on the lines when it is due)
        while sent < len(texts):
            free, now, running = link.query_operands([f"_LM{PLANE}", "TIME", f"_BG{PLANE}"])
            if not round(running):
                return  # stopped (ST, AB, a limit) from wherever: stream nothing more
            room = round(free) - 1  # one spare: whether the running segment counts is unsure
            if _stopped(handle):  # (an ST or AB through the library, while it ramps down)
                return
            if room >= min(refill, len(texts) - sent):
                stop = sent + min(room, len(texts) - sent)
                for i, j in self._groups(sent, stop, texts):
                    with held:
                        if _stopped(handle):
                            return
                        replies = slicer.send([*texts[i:j], cmds.time_stamp()])
                        handle.record(sample_of(replies[-1]), "add", segs[i:j])
                sent = stop
            else:
                left = (deadlines[sent] - (now - begin)) * ts
                link.pause(min(0.05, max(4 * ts, left / 4)))
        with held:
            if _stopped(handle):
                return
            replies = link.command_line([self._end(), cmds.time_stamp()])
            handle.record(sample_of(replies[-1]), "end", ())


def _not_a_number(value: object) -> bool:
    """Whether ``value`` is no real number (a bool is none either: decision 0092)."""
    return isinstance(value, bool) or not isinstance(value, numbers.Real)


def _stopped(handle: VectorHandle) -> bool:
    """Whether a stop reached ``handle`` (another thread may set it at any time)."""
    return handle.stopped


def _buffer_error(text: str, sample: int, ts: float, segment: int) -> LimitError:
    """A refusal for the segment buffer, at ``sample``."""
    return LimitError(
        text, name="segment buffer", value=segment, limit=None, time=sample * ts, sample=sample
    )
