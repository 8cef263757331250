"""Starting motion, in counts: resolve -> predict -> check -> send.

Every operation reads the state it needs in one round trip (resolve), predicts the motion
sample by sample (predict), checks the whole path against the model's ranges and the soft
limits (check), and only then sends one command line with ``MG TIME`` (send). A failed check
raises before a byte goes out. Units are converted by the axis layer before anything here runs.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from galil import predict
from galil.errors import InvalidArgument, LimitError, ScheduleError
from galil.link import CommandLink
from galil.models import INT32_MAX, INT32_MIN
from galil.motion import (
    HOMING_KINDS,
    SCHEDULE_BEGIN,
    SWITCH_BITS,
    Display,
    GearLink,
    MotionTracker,
    MoveHandle,
    MoveParams,
    Track,
    as_stored,
    change_line,
    predict_track,
    refuse_dropped,
    sample_of,
    send_reopening,
    stop_on_error,
    switch_blocks,
    zero_speed,
)
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.routines import RESERVED, Routine, Routines
from galil.units import state_in_units

__all__ = [
    "AxisMove",
    "check_followers",
    "execute_move",
    "follower_limits",
    "follower_operands",
    "increment",
    "jog",
    "schedule_label",
    "set_jog_speed",
    "speed_schedule",
]

_STATE = ("RP", "BG", "SP", "AC", "DC", "IT", "BL", "FL", "MO", "SC", "TS")
# What a master's state query reads of each follower: its soft limits, its stop code (a
# limit's: the controller turned its gearing off), and its limit switches (TS bits 3, 2).
_FOLLOWER = ("BL", "FL", "SC", "TS")
_FOLLOWER_GR = (*_FOLLOWER, "GR")
_new = object.__new__
_BUILDERS = {"SP": cmds.sp, "AC": cmds.ac, "DC": cmds.dc}
_SCHEDULE_KIND = RESERVED["#GSCHED"]  # what a speed schedule's routine is


@dataclass(frozen=True)
class AxisMove:
    """One axis of a position move in counts, its values converted and range-checked.

    Attributes:
        letter: the axis.
        value: the absolute target, or the distance of a relative move.
        speed, accel, decel: quantised overrides for this move (``None``: the axis's own).
    """

    letter: str
    value: int
    speed: float | None = None
    accel: float | None = None
    decel: float | None = None


class _State(NamedTuple):
    """One axis's state as a start reads it (a named tuple: built on every move)."""

    rp: int
    bg: bool
    sp: float
    ac: float
    dc: float
    it: float
    bl: float
    fl: float
    mo: bool
    sc: int
    ts: int


@functools.lru_cache(maxsize=256)
def _operand_names(letters: str, ops: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"_{op}{a}" for a in letters for op in ops)


def _read_state(
    link: CommandLink,
    tracker: MotionTracker,
    letters: str,
    gears: Mapping[str, GearLink],
    start: bool = True,
) -> tuple[dict[str, _State], dict[str, tuple[float, float, int]]]:
    """Every axis's state and the followers' ``(BL, FL, TS)``, in one round trip
    (query_operands packs the MG lines together). For a ``start`` (not a plan), the axes read
    at rest end the handles nobody waited for (:func:`_seen_at_rest`).

    Raises:
        MotionError: a limit stopped a follower during a move nobody waited for
            (:func:`~galil.motion.refuse_dropped`).
    """
    names = _operand_names(letters, _STATE)
    if not gears:  # (the common move: the cached tuple as it is, nothing more read)
        states = _states(link, letters, link.query_operands(names))
        if start:
            _seen_at_rest(tracker, states)
        return states, {}
    values = link.query_operands(names + follower_operands("".join(gears), tracker))
    states = _states(link, letters, values)
    if start:
        _seen_at_rest(tracker, states)
    limits = follower_limits(link, tracker, gears, values[len(letters) * len(_STATE) :])
    return states, limits


def _states(link: CommandLink, letters: str, values: Sequence[float]) -> dict[str, _State]:
    """Each axis's :class:`_State` from the values of ``_operand_names(letters, _STATE)``
    (more values may follow); SP, AC, DC and IT as the steps the controller holds
    (:func:`~galil.motion.as_stored`)."""
    n = len(_STATE)
    out: dict[str, _State] = {}
    for i, a in enumerate(letters):
        rp, bg, sp, ac, dc, it, bl, fl, mo, sc, ts = values[i * n : (i + 1) * n]
        # (a whole value is the step itself: as_stored's own first look, without the call)
        if not (type(sp) is float and sp.is_integer()):
            sp = as_stored(link, "SP", sp)
        if not (type(ac) is float and ac.is_integer()):
            ac = as_stored(link, "AC", ac)
        if not (type(dc) is float and dc.is_integer()):
            dc = as_stored(link, "DC", dc)
        if it != 1.0:
            it = as_stored(link, "IT", it)
        out[a] = _State(round(rp), bool(bg), sp, ac, dc, it, bl, fl, bool(mo), round(sc), round(ts))
    return out


def _seen_at_rest(tracker: MotionTracker, states: Mapping[str, _State]) -> None:
    """Tell the tracker of the axes a start read at rest (:meth:`MotionTracker.ended`)."""
    for a, state in states.items():
        if not state.bg:
            tracker.ended(a, state.rp, state.sc)


def follower_limits(
    link: CommandLink,
    tracker: MotionTracker | None,
    gears: Mapping[str, GearLink],
    values: Sequence[float],
) -> dict[str, tuple[float, float, int]]:
    """``(BL, FL, TS)`` per follower of ``gears`` from the values of
    :func:`follower_operands` (read in ``gears``' order; of ``TS`` its limit switch bits), once
    their stop codes say that each still follows.

    Raises:
        MotionError: a limit stopped a follower during a move nobody waited for; the tracker
            forgets its gearing (:func:`~galil.motion.refuse_dropped`).
    """
    n = len(_follower_ops(tracker))
    rows = {f: values[i * n : (i + 1) * n] for i, f in enumerate(gears)}
    ratios = {f: r[4] for f, r in rows.items()} if n > len(_FOLLOWER) else None
    refuse_dropped(link, tracker, gears, {f: round(r[2]) for f, r in rows.items()}, ratios)
    return {f: (r[0], r[1], round(r[3]) & SWITCH_BITS) for f, r in rows.items()}


def _follower_error(exc: LimitError, gear: GearLink) -> None:
    """Say in ``exc`` that its axis only moves because it follows ``gear.master``."""
    exc.args = (
        f"axis {gear.follower} is geared to {gear.master} at {gear.ratio:g}: {exc.args[0]}",
        *exc.args[1:],
    )


def _check_geared_speed(
    link: CommandLink, gears: Mapping[str, GearLink], master_speed: float
) -> None:
    """Refuse a master speed that drives an axis geared to it beyond the model's SP maximum.

    Raises:
        LimitError: naming the follower.
    """
    for gear in gears.values():
        _check_follower_speed(link, gear, abs(gear.ratio) * abs(master_speed))


def _check_follower_speed(link: CommandLink, gear: GearLink, speed: float) -> None:
    """Refuse a follower speed (counts/s) beyond the model's SP maximum.

    Raises:
        LimitError: naming the follower.
    """
    model = link.model
    if speed > model.sp_max:
        exc = LimitError(
            f"axis {gear.follower} is geared to {gear.master} at {gear.ratio:g}: it would run "
            f"at {speed:.6g} counts/s, beyond the {model.name} maximum {model.sp_max}",
            name="speed",
            value=speed,
            limit=model.sp_max,
            axis=gear.follower,
            model=model.name,
        )
        state_in_units(exc, gear.scale)
        raise exc


def follower_operands(followers: str, tracker: MotionTracker | None) -> tuple[str, ...]:
    """What a master's state query reads of each follower: ``_BL`` and ``_FL`` (its soft
    limits), ``_SC`` (a limit's stop code: its gearing is off), ``_TS`` (its limit switches)
    and, where the controller answers it, ``_GR`` (0: its gearing was turned off unseen), in
    the order :func:`follower_limits` reads them back (with the same ``tracker``)."""
    return _operand_names(followers, _follower_ops(tracker)) if followers else ()


def _follower_ops(tracker: MotionTracker | None) -> tuple[str, ...]:
    return _FOLLOWER_GR if tracker is not None and tracker.reads_ratios else _FOLLOWER


def _refuse_follower_blocked(link: CommandLink, gear: GearLink, direction: float, ts: int) -> None:
    """Refuse a start of ``gear``'s master that drives the follower (first) in ``direction``
    towards its active limit switch that ``LD`` leaves on (``ts``: its ``_TS``;
    :func:`~galil.motion.switch_blocks`): the controller would stop the follower there and
    turn its gearing off while the master runs on (decision 0053).

    Raises:
        InvalidArgument: naming the follower, its master and the switch.
    """
    f = gear.follower
    if direction and switch_blocks(link, f, direction, ts):
        side = "forward" if direction > 0 else "reverse"
        # (the distance along S only grows: no other way to move it)
        other = "" if gear.master == "S" else f", or move {gear.master} the other way"
        raise InvalidArgument(
            f"axis {f} is geared to {gear.master} at {gear.ratio:g}: it would start towards "
            f"its active {side} limit switch (the controller stops it there and turns its "
            f"gearing off); turn the gearing off and move {f} off the switch first{other}",
            model=link.model.name,
        )


def _first_direction(profile: predict.Profile) -> int:
    """+1 or -1: the way ``profile`` first leaves its start position; 0: it never does."""
    position = profile.position
    moved = np.flatnonzero(position != position[0])
    return 0 if not moved.size else (1 if position[moved[0]] > position[0] else -1)


def check_followers(
    link: CommandLink,
    gears: Mapping[str, GearLink],
    profiles: Mapping[str, predict.Profile],
    limits: Mapping[str, tuple[float, float, int]],
) -> None:
    """The followers' predicted profiles against their limit switches (the first direction
    each moves in: :func:`_refuse_follower_blocked`), their soft limits and the model's SP
    maximum.

    Args:
        gears: the followers to check, by letter.
        profiles: each follower's predicted profile (positions in counts).
        limits: each follower's ``(BL, FL, TS)`` (:func:`follower_limits`).

    Raises:
        InvalidArgument: a follower would start towards its active limit switch.
        LimitError: naming the follower.
    """
    for f, gear in gears.items():
        profile = profiles[f]
        bl, fl, ts = limits[f]
        if ts != SWITCH_BITS:  # (a switch active: which way does the follower go?)
            _refuse_follower_blocked(link, gear, _first_direction(profile), ts)
        try:
            predict.check_soft_limits(profile, forward_limit=fl, backward_limit=bl, axis=f)
        except LimitError as exc:
            exc.end = profile.end
            _follower_error(exc, gear)
            state_in_units(exc, gear.scale)
            raise
        _check_follower_speed(link, gear, profile.peak_speed)


def check_int32(name: str, value: float, axis: str, model: str) -> None:
    """Refuse a position outside the controller's 32-bit registers.

    Raises:
        LimitError: outside ``INT32_MIN .. INT32_MAX``.
    """
    if not INT32_MIN <= value <= INT32_MAX:
        raise LimitError(
            f"{name} {value:.0f} on {axis} is outside the 32-bit position range",
            name=name,
            value=value,
            limit=INT32_MAX if value > 0 else INT32_MIN,
            axis=axis,
            model=model,
        )


def _refuse_blocked(
    link: CommandLink,
    a: str,
    direction: float,
    ts: int,
    limits: tuple[int, float, float] | None,
) -> None:
    """Refuse a start in ``direction`` towards an active limit switch (``_TS``) that ``LD``
    does not disable (:func:`~galil.motion.switch_blocks`), or, given
    ``limits`` ``(RP, BL, FL)``, on past a soft limit the axis is beyond already: the
    controller refuses its ``BG`` with TC 22, after the rest of the line went out (a JG, a PA).

    Raises:
        InvalidArgument: the switch. LimitError: the soft limit.
    """
    if not direction:
        return
    side = "forward" if direction > 0 else "reverse"
    if switch_blocks(link, a, direction, ts):
        raise InvalidArgument(
            f"axis {a} would start towards its active {side} limit switch (the controller "
            "refuses it with TC 22); move off the switch first",
            model=link.model.name,
        )
    if limits is None:
        return
    rp, bl, fl = limits
    name, limit = ("FL", fl) if direction > 0 else ("BL", bl)
    if (rp > fl) if direction > 0 else (rp < bl):
        raise LimitError(
            f"axis {a} is at {rp:g}, beyond {name} {limit:g}: a jog on past it is refused "
            "(the controller: TC 22); move it back inside first",
            name=name,
            value=rp,
            limit=limit,
            axis=a,
            model=link.model.name,
        )


def _ready(link: CommandLink, a: str, state: _State) -> None:
    if state.bg:
        raise InvalidArgument(
            f"axis {a} is already moving; wait for its move (handle.wait()) or stop it "
            "(axis.stop()) first",
            model=link.model.name,
        )
    if state.mo:
        raise InvalidArgument(
            f"axis {a} has its motor off; call controller.servo_here()", model=link.model.name
        )


def _plan_axis(
    link: CommandLink, move: AxisMove, state: _State, relative: bool, command: str = "PA"
) -> tuple[Track, predict.Profile, int]:
    """Predict and check one axis: its track, its profile (counts) and the value to send."""
    a = move.letter
    distance = move.value if relative else move.value - state.rp
    target = state.rp + distance
    if not INT32_MIN <= target <= INT32_MAX:
        if command == "IP":
            _check_ip_end(link, a, distance, target, "moves the axis to")
        check_int32("PA", target, a, link.model.name)
    speed = state.sp if move.speed is None else move.speed
    if speed <= 0:  # (BG refuses SP 0 even for a move of no distance: TC 6)
        raise zero_speed(link, a, "SP", f"axis {a} has SP 0: set a speed first")
    params = _new(MoveParams)  # (a frozen dataclass, built without its setattrs: a hot path)
    params.__dict__.update(
        speed=speed,
        accel=state.ac if move.accel is None else move.accel,
        decel=state.dc if move.decel is None else move.decel,
        smoothing=state.it,
    )
    _refuse_blocked(link, a, distance, state.ts, None)  # (beyond a limit: the path check)
    track = Track("position", state.rp, params, None, amount=distance)
    profile = predict_track(link, track)
    try:
        predict.check_soft_limits(profile, forward_limit=state.fl, backward_limit=state.bl, axis=a)
    except LimitError as exc:
        exc.end = profile.end
        raise
    return track, profile, target


def _axis_values(builder: str, values: Mapping[str, float], link: CommandLink) -> Command:
    return _BUILDERS[builder](model=link.model, **dict(values))


def _move_line(
    link: CommandLink, moves: Sequence[AxisMove], sent: Mapping[str, float], command: str
) -> list[Command]:
    """The move's one line: any SP/AC/DC given, the targets (PA or IP), BG, ``MG TIME``."""
    parts: list[Command] = []
    model = link.model
    if any([m.speed is not None or m.accel is not None or m.decel is not None for m in moves]):
        for name in ("SP", "AC", "DC"):
            values = {m.letter: getattr(m, _FIELD[name]) for m in moves}
            given = {a: v for a, v in values.items() if v is not None}
            if given:
                parts.append(_axis_values(name, given, link))
    if command == "IP":
        parts.append(cmds.ip(model=model, **sent))
    else:
        parts.append(cmds.pa(model=model, **sent))
        parts.append(cmds.bg("".join([m.letter for m in moves]), model=model))
    parts.append(cmds.time_stamp())
    return parts


def execute_move(
    link: CommandLink,
    tracker: MotionTracker,
    moves: Sequence[AxisMove],
    *,
    relative: bool = False,
    dry_run: bool = False,
    command: str = "PA",
    display: Mapping[str, Display] | None = None,
) -> MoveHandle:
    """Predict, check and send a position move on one or more axes, begun together.

    The move goes out as one command line (parameters, targets, ``BG``, ``MG TIME``) so the
    axes start in the same sample and the handle knows which. With ``dry_run`` nothing is sent
    and the handle only carries the predictions. ``command="IP"`` sends an idle increment
    (``IP`` = ``PR`` + ``BG``).

    Raises:
        InvalidArgument: no or repeated axes, an axis moving or its motor off, a start towards
            an active limit switch, the axis's own or (first) an axis geared to one of the
            move's (decision 0053).
        LimitError: a path crossing a soft limit or the 32-bit range, or taking an axis geared
            to one of the move's past its soft limits or beyond the model's SP maximum.
        MotionError: a limit stopped an axis geared to one of the move's axes during a move
            nobody waited for: its gearing is off, and forgotten
            (:func:`~galil.motion.refuse_dropped`).
    """
    letters = moves[0].letter if len(moves) == 1 else "".join([m.letter for m in moves])
    if not letters or (len(letters) > 1 and len(set(letters)) != len(letters)):
        raise InvalidArgument(f"a move needs distinct axes, got {letters!r}")
    if len(moves) > 1:
        order = link.model.axes
        moves = sorted(moves, key=lambda m: order.index(m.letter))
        letters = "".join([m.letter for m in moves])
    # No other thread's motion between the state read and the handle (the tracker's lock).
    if dry_run:  # (nothing is sent: nothing to guard)
        with tracker.lock:
            return _execute_move(link, tracker, moves, letters, relative, True, command, display)
    with tracker.lock, stop_on_error(link, tracker, letters):
        return _execute_move(link, tracker, moves, letters, relative, False, command, display)


def _execute_move(
    link: CommandLink,
    tracker: MotionTracker,
    moves: Sequence[AxisMove],
    letters: str,
    relative: bool,
    dry_run: bool,
    command: str,
    display: Mapping[str, Display] | None,
) -> MoveHandle:
    # (the tracker's lock is held: no gearing changes now)
    if not dry_run:
        tracker.refuse_cancelled(link.model.name)  # (a cancelled task's start: 0100)
    geared = bool(tracker.gears) or bool(tracker.found)
    if geared and not dry_run:
        for a in letters:
            tracker.refuse_geared(a, "moving it", link.model.name)
    gears = tracker.followers(letters) if geared else {}
    others = {f: g for f, g in gears.items() if f not in letters} if gears else gears
    state, limits = _read_state(link, tracker, letters, others, start=not dry_run)
    tracks: dict[str, Track] = {}
    profiles: dict[str, predict.Profile] = {}
    sent: dict[str, float] = {}
    for m in moves:
        a = m.letter
        if not dry_run:
            _ready(link, a, state[a])
        track, profile, target = _plan_axis(link, m, state[a], relative, command)
        tracks[a] = track
        show = None if display is None else display.get(a)
        profiles[a] = profile if show is None else show(profile)
        sent[a] = track.amount if command == "IP" else target
    handle = MoveHandle(link, tracks, "position", display=display, tracker=tracker)
    handle.preset(profiles)
    if gears:
        handle.follow(gears)  # (an axis of the move is skipped)
        if handle.followers:
            check_followers(link, {f: gears[f] for f in handle.followers}, handle.profiles, limits)
    if dry_run:
        return handle
    replies = link.command_line(_move_line(link, moves, sent, command))
    begin = sample_of(replies[-1])
    for t in tracks.values():
        t.begin = begin
    tracker.started(handle)
    return handle


_FIELD = {"SP": "speed", "AC": "accel", "DC": "decel"}


def _stopping(link: CommandLink, a: str, what: str) -> InvalidArgument:
    return InvalidArgument(
        f"axis {a} is stopping; wait for it before {what} (the move's handle.wait(), or "
        "until axis.moving is False)",
        model=link.model.name,
    )


def _change_jog(
    link: CommandLink, tracker: MotionTracker, handle: MoveHandle, a: str, velocity: float
) -> MoveHandle:
    """A new JG for the jog ``handle`` runs on ``a``, stamped so its prediction follows.

    Raises:
        LimitError: an axis geared to ``a`` would run beyond the model's SP maximum.
    """
    _check_geared_speed(link, tracker.followers(a), velocity)
    line = [cmds.jg(model=link.model, **{a: velocity}), cmds.time_stamp()]
    replies = change_line(link, handle, a, line)
    handle.add_event(a, sample_of(replies[-1]), lambda t: predict.SetSpeed(t, velocity))
    return handle


def _open_jog(tracker: MotionTracker, a: str) -> MoveHandle | None:
    """The handle of the library's jog on ``a`` if it has not been stopped (host side)."""
    handle = tracker.active(a)
    track = tracker.track(a)
    if handle is None or track is None or track.kind != "jog" or not track.open_jog:
        return None
    return handle


def jog(
    link: CommandLink,
    tracker: MotionTracker,
    letter: str,
    velocity: float,
    *,
    display: Display | None = None,
) -> MoveHandle:
    """Jog ``letter`` at ``velocity`` counts/s (quantised and range-checked by the caller).

    Already jogging (through the library): the speed changes in motion and the jog's own
    handle is returned, its prediction now including the change.

    Raises:
        InvalidArgument: a position move in progress, a stopping jog, the motor off, or a
            start towards an active limit switch, the axis's own or that of an axis geared to
            ``letter`` (decision 0053).
        LimitError: an axis geared to ``letter`` would run beyond the model's SP maximum.
        MotionError: a limit stopped an axis geared to ``letter`` during a move nobody waited
            for: its gearing is off, and forgotten (:func:`~galil.motion.refuse_dropped`).
    """
    with tracker.lock, stop_on_error(link, tracker, letter):  # (a JG for a jog another
        return _jog(link, tracker, letter, velocity, display)  # thread starts: its speed)


def _jog(
    link: CommandLink,
    tracker: MotionTracker,
    letter: str,
    velocity: float,
    display: Display | None,
) -> MoveHandle:
    a = letter
    tracker.refuse_cancelled(link.model.name)  # (a cancelled task's start: 0100)
    tracker.refuse_geared(a, "jogging it", link.model.name)
    gears = tracker.followers(a)
    rp, bg, sc, ac, dc, it, mo, ts, bl, fl, *ends = link.query_operands(
        [f"_{op}{a}" for op in ("RP", "BG", "SC", "AC", "DC", "IT", "MO", "TS", "BL", "FL")]
        # (a follower a limit dropped: refuse_dropped; one on its switch: a start refused)
        + list(follower_operands("".join(gears), tracker))
    )
    if not bg:
        tracker.ended(a, rp, sc)
    followers = follower_limits(link, tracker, gears, ends)
    track = tracker.track(a)
    if bg and track is not None and track.kind == "jog":
        handle = _open_jog(tracker, a)
        if handle is None or sc:  # ST, AB or a limit: _SC says why while it ramps down
            raise _stopping(link, a, "jogging again")
        return _change_jog(link, tracker, handle, a, velocity)
    if bg:
        raise InvalidArgument(
            f"axis {a} is in another move; stop it before jogging", model=link.model.name
        )
    if mo:
        raise InvalidArgument(
            f"axis {a} has its motor off; call controller.servo_here()", model=link.model.name
        )
    _refuse_blocked(link, a, velocity, round(ts), (round(rp), bl, fl))
    for f, gear in gears.items():
        _refuse_follower_blocked(link, gear, gear.ratio * velocity, followers[f][2])
    _check_geared_speed(link, gears, velocity)
    params = MoveParams(
        abs(velocity),
        as_stored(link, "AC", ac),
        as_stored(link, "DC", dc),
        as_stored(link, "IT", it),
    )
    replies = link.command_line(
        [
            cmds.jg(model=link.model, **{a: velocity}),
            cmds.bg(a, model=link.model),
            cmds.time_stamp(),
        ]
    )
    track = Track("jog", round(rp), params, sample_of(replies[-1]), amount=velocity)
    new = MoveHandle(
        link, {a: track}, "jog", display={a: display} if display else None, tracker=tracker
    )
    new.follow(gears)
    tracker.started(new)
    return new


def set_jog_speed(link: CommandLink, tracker: MotionTracker, letter: str, velocity: float) -> None:
    """``JG`` on ``letter``, never ``BG``: a jog the controller is running changes speed in
    motion (the library's own jog: stamped, so its prediction follows); an idle axis only
    keeps the value for its next jog. The controller is asked (``_BG``, ``_SC``) rather than
    the library's record, which holds a stopped jog until its handle is polled.

    Raises:
        InvalidArgument: the axis is stopping, or in one of the library's position moves (the
            controller takes JG only in jog mode).
        LimitError: an axis geared to ``letter`` would run beyond the model's SP maximum.
    """
    with tracker.lock, stop_on_error(link, tracker, letter):
        _set_jog_speed(link, tracker, letter, velocity)


def _set_jog_speed(link: CommandLink, tracker: MotionTracker, a: str, velocity: float) -> None:
    bg, sc = link.query_operands([f"_BG{a}", f"_SC{a}"])
    command = cmds.jg(model=link.model, **{a: velocity})
    if not bg:
        link.command_line([command])  # a preset: JG alone starts nothing
        return
    if sc:  # a forced stop ramping down (4 ST, 2/3 a limit)
        raise _stopping(link, a, "setting its jog speed")
    handle = _open_jog(tracker, a)
    if handle is not None:
        _change_jog(link, tracker, handle, a, velocity)
        return
    track = tracker.track(a)
    if track is not None and track.kind != "jog":
        raise InvalidArgument(
            f"axis {a} is in a {track.kind} move; the jog speed can be set when it is over "
            "(the controller takes JG only in jog mode)",
            model=link.model.name,
        )
    # Motion the library did not start: the controller changes a jog's speed, refuses the
    # rest (TC 13); either way JG starts nothing.
    link.command_line([command])


def increment(
    link: CommandLink,
    tracker: MotionTracker,
    letter: str,
    counts: int,
    *,
    display: Display | None = None,
) -> MoveHandle:
    """``IP counts`` on ``letter``: an idle move, a longer move in progress, or a jog's step.

    Raises:
        InvalidArgument: a reversal of a move in progress, an axis stopping, or one in a
            vector sequence or homing (the controller: TC 29, TC 16).
        CommandError: TC 16, a reversal of a move the library did not start, at its target in
            its last samples (nothing the library reads shows its direction then).
        LimitError: the new target (or a jog's step) beyond a soft limit or the 32-bit range,
            for the axis or one geared to it; a jog's step too large for one sample.
        MotionError: a limit stopped an axis geared to ``letter`` during a move nobody waited
            for: its gearing is off, and forgotten (:func:`~galil.motion.refuse_dropped`).
    """
    if not INT32_MIN <= counts <= INT32_MAX:  # (the increment itself: before any byte)
        check_int32("IP", counts, letter, link.model.name)
    with tracker.lock, stop_on_error(link, tracker, letter):  # (an IP would extend a move
        return _increment(link, tracker, letter, counts, display)  # another thread starts)


def _increment(
    link: CommandLink,
    tracker: MotionTracker,
    a: str,
    counts: int,
    display: Display | None,
) -> MoveHandle:
    model = link.model
    tracker.refuse_cancelled(model.name)  # (a cancelled task's start or change: 0100)
    tracker.refuse_geared(a, "an increment", model.name)
    gears = tracker.followers(a)
    rp, bg, pa, bl, fl, sc, *rest = link.query_operands(
        [f"_{op}{a}" for op in ("RP", "BG", "PA", "BL", "FL", "SC")]
        + list(follower_operands("".join(gears), tracker))
    )
    limits = follower_limits(link, tracker, gears, rest)
    shows = {a: display} if display else None
    if not bg:
        return execute_move(
            link, tracker, [AxisMove(a, counts)], relative=True, command="IP", display=shows
        )
    handle = tracker.active(a)
    track = tracker.track(a)
    if track is not None and (track.kind == "vector" or track.kind in HOMING_KINDS):
        why = "a coordinated move (TC 29)" if track.kind == "vector" else "homing (TC 16)"
        raise InvalidArgument(
            f"axis {a} is in a {track.kind} move; the controller refuses IP during {why}",
            model=model.name,
        )
    # (_SC says a forced stop ramps down: ST or a limit, whoever sent it; a schedule's or a
    # homing's track does not record the ST)
    if sc or (track is not None and (track.stopped or track.aborted is not None)):
        raise InvalidArgument(
            f"axis {a} is stopping; the controller refuses IP now (TC 16)", model=model.name
        )
    jogging = track is not None and track.kind == "jog"
    if jogging:
        _check_step(link, a, counts)
        _check_geared_speed(link, gears, counts / link.sample_period)
    else:
        heading = 0.0 if track is None else track.amount
        _check_same_direction(link, a, counts, round(pa) - round(rp), heading)
    end = round(rp if jogging else pa) + counts
    what = "steps the jog's reference to" if jogging else "moves the target of the move to"
    _check_reach(link, a, counts, end, (bl, fl), what)
    _check_followers_reach(link, gears, limits, counts, end, what)
    replies = change_line(link, handle, a, [cmds.ip(model=model, **{a: counts}), cmds.time_stamp()])
    if handle is None or track is None:
        # Someone else's move: nothing to follow; a handle that only waits for it.
        lone = Track("position", round(rp), MoveParams(0.0, 1.0, 1.0, 1.0), None, exact=False)
        lone.fixed = predict.Profile.from_samples(
            [round(rp)], sample_period=link.sample_period, shape="none", peak_speed=0.0
        )
        return MoveHandle(link, {a: lone}, "position", display=shows, tracker=tracker)
    handle.add_event(a, sample_of(replies[-1]), lambda t: predict.Increment(t, counts))
    return handle


def _check_followers_reach(
    link: CommandLink,
    gears: Mapping[str, GearLink],
    limits: Mapping[str, tuple[float, float, int]],
    step: int,
    end: int,
    what: str,
) -> None:
    """:func:`_check_reach` for every axis geared to one that an IP takes ``step`` counts to
    ``end``."""
    for f, gear in gears.items():
        f_end = int(gear.positions([end])[-1])
        try:
            _check_reach(link, f, round(step * gear.ratio), f_end, limits[f][:2], what)
        except LimitError as exc:
            _follower_error(exc, gear)
            raise


def _check_same_direction(
    link: CommandLink, a: str, counts: int, remaining: int, heading: float
) -> None:
    """Refuse an IP against the direction of the move in progress (the controller: TC 16).

    ``remaining`` is ``_PA - _RP``; in a move's last samples ``_RP`` reads the target already
    while the profile still moves (its fraction), and the controller still refuses the
    other sign: then the direction is the one the library sent (``heading``, the move's
    distance; 0 for a move it did not start, left to the controller).
    """
    way = remaining or heading
    if counts and way and (counts > 0) != (way > 0):
        to_go = f"{remaining:+d} counts to go" if remaining else "ending"
        raise InvalidArgument(
            f"IP {counts} would reverse the move in progress on {a} "
            f"({to_go}); the controller refuses it (TC 16): wait for the move to end",
            model=link.model.name,
        )


def _check_ip_end(link: CommandLink, a: str, step: int, end: int, what: str) -> None:
    """Refuse an ``IP`` of ``step`` counts that takes ``a`` to ``end`` beyond the 32-bit
    position range, naming the IP (``what`` it does: "moves the target of the move to").

    Raises:
        LimitError: name ``"PA"`` (the position it would reach).
    """
    if not INT32_MIN <= end <= INT32_MAX:
        raise LimitError(
            f"IP {step} on axis {a} {what} {end}, outside the 32-bit position range",
            name="PA",
            value=end,
            limit=INT32_MAX if end > 0 else INT32_MIN,
            axis=a,
            model=link.model.name,
        )


def _check_reach(
    link: CommandLink, a: str, step: int, end: int, limits: tuple[float, float], what: str
) -> None:
    """Refuse an IP that takes ``a`` (``step`` counts) to ``end``: beyond the 32-bit range or
    a soft limit ``(BL, FL)`` in its direction, as a move to ``end`` would be refused.

    Raises:
        LimitError: name ``"PA"``, ``"FL"`` or ``"BL"``.
    """
    model = link.model
    _check_ip_end(link, a, step, end, what)
    bl, fl = limits
    if step > 0 and end > fl:
        name, limit = "FL", fl
    elif step < 0 and end < bl:
        name, limit = "BL", bl
    else:
        return
    raise LimitError(
        f"IP on axis {a} {what} {end}, beyond {name} {limit:g}",
        name=name,
        value=end,
        limit=limit,
        axis=a,
        model=model.name,
        end=end,
    )


def _check_step(link: CommandLink, a: str, counts: int) -> None:
    """An IP while jogging steps the reference by ``counts`` in one sample: refuse a step
    whose speed in that sample is beyond the model's SP maximum.

    Raises:
        LimitError: the step is too large.
    """
    speed = abs(counts) / link.sample_period
    if speed > link.model.sp_max:
        raise LimitError(
            f"IP {counts} while jogging steps axis {a} by {counts} counts in one sample: "
            f"{speed:.6g} counts/s, beyond the {link.model.name} maximum {link.model.sp_max}",
            name="speed",
            value=speed,
            limit=link.model.sp_max,
            sample=1,
            axis=a,
            model=link.model.name,
        )


def schedule_label(label: object) -> str:
    """A speed schedule's ``label=`` as its routine's label line: ``"GSCHED"`` or
    ``"#GSCHED"`` both give ``"#GSCHED"``.

    Raises:
        InvalidArgument: not a string, a label the controller would refuse, or a label of
            another of the library's routines (the watchdog's ``GWDOG``, the input wait's
            ``GINWAIT``, their inner ones: :data:`galil.routines.RESERVED`), which the
            schedule's routine would replace.
    """
    if not isinstance(label, str):
        raise InvalidArgument(f"label must be a string such as 'GSCHED', not {label!r}")
    line = label if label.startswith("#") else f"#{label}"
    cmds.xq(line)  # the controller's label rules
    owner = RESERVED.get(line)
    if owner is not None and owner != _SCHEDULE_KIND:
        raise InvalidArgument(
            f"label {label!r} is the label of {owner}'s routine, which a speed schedule "
            "would replace; choose another label (such as the default 'GSCHED')"
        )
    return line


def speed_schedule(
    link: CommandLink,
    tracker: MotionTracker,
    routines: Routines,
    letter: str,
    distance: int,
    changes: Sequence[tuple[float, float]],
    *,
    speed: float | None,
    label: str,
    display: Display | None = None,
) -> MoveHandle:
    """Move ``letter`` by ``distance``, changing speed at distances from the start (counts).

    Every change point, the label and the program are validated before the first byte; the
    program runs the schedule with ``AD`` trippoints on thread 0, installed beside the user's
    program (:mod:`galil.routines`), never over it. Stopped or aborted through the library
    before its end, the schedule is cancelled (:func:`_cancel_schedule`): its routine is
    halted and ``SP`` is put back as it was before it.

    Raises:
        ScheduleError: a change point the profiler cannot honour.
        InvalidArgument: a bad label, the axis busy or its motor off, a start towards an
            active limit switch (of the axis, or first of one geared to it), thread 0
            running (a schedule in progress, or a program), a label the user's program
            uses, or a user program running (the download would
            disturb it).
        LimitError: a path crossing a soft limit, or taking an axis geared to ``letter`` past
            its soft limits or beyond the model's SP maximum.
        MotionError: a limit stopped an axis geared to ``letter`` during a move nobody waited
            for: its gearing is off, and forgotten (:func:`~galil.motion.refuse_dropped`).
    """
    label = schedule_label(label)  # checked before anything is read or sent
    # Held from the thread 0 check to the handle: another thread's schedule would install
    # its routine over this one's, or take thread 0 in between.
    with tracker.lock, stop_on_error(link, tracker, letter):
        tracker.refuse_cancelled(link.model.name)  # (a cancelled task's start: 0100)
        return _speed_schedule(
            link, tracker, routines, letter, distance, changes, speed, label, display
        )


def _speed_schedule(
    link: CommandLink,
    tracker: MotionTracker,
    routines: Routines,
    a: str,
    distance: int,
    changes: Sequence[tuple[float, float]],
    speed: float | None,
    label: str,
    display: Display | None,
) -> MoveHandle:
    tracker.refuse_geared(a, "a speed schedule on it", link.model.name)
    gears = tracker.followers(a)
    state, limits = _schedule_state(link, tracker, a, gears)
    rp, sp0, ac, dc, it = state.rp, state.sp, state.ac, state.dc, state.it
    _refuse_blocked(link, a, distance, state.ts, None)  # (the program's BG would fail: TC 22)
    first = _first_speed(link, a, sp0 if speed is None else speed)
    try:
        schedule = predict.speed_schedule(
            distance,
            first,
            list(changes),
            ac,
            dc,
            sample_period=link.sample_period,
            start=rp,
            smoothing=it,
        )
    except ScheduleError as exc:  # (the predictor knows no axes: name it)
        exc.axis = a
        exc.args = (f"axis {a}: {exc.args[0]}", *exc.args[1:])
        raise
    predict.check_soft_limits(
        schedule.profile, forward_limit=state.fl, backward_limit=state.bl, axis=a
    )
    if gears:
        geared = {f: g.profile(schedule.profile) for f, g in gears.items()}
        check_followers(link, gears, geared, limits)
    program = _schedule_program(link, a, label, first, distance, schedule)
    # Beside the user's program; a schedule's routine may not take another's label.
    routines.install(Routine(label, tuple(program), kind=_SCHEDULE_KIND))
    tracker.schedule_starting()  # (the line below resets the begin it may not have read)
    link.command_line([cmds.assign(SCHEDULE_BEGIN, -1)])
    run = object()  # this schedule's hold on thread 0
    try:
        routines.start(label, 0, owner=run)
    except BaseException:
        # XQ may have gone out: no change point may run after the stop (stop_on_error), and
        # SP goes back, as for a schedule stopped before its end (_cancel_schedule).
        _undo_start(link, tracker, routines, a, sp0)
        raise
    params = MoveParams(first, ac, dc, it)
    track = Track("schedule", rp, params, None, amount=distance, fixed=schedule.profile)
    handle = MoveHandle(
        link, {a: track}, "schedule", display={a: display} if display else None, tracker=tracker
    )
    handle.follow(gears)
    handle.on_cancel(functools.partial(_cancel_schedule, link, routines, handle, a, sp0, run))
    tracker.started(handle)
    return handle


def _first_speed(link: CommandLink, a: str, speed: float) -> float:
    """A schedule's first speed; refused at 0 as a move's is (its program's BG would refuse
    SP 0: TC 6).

    Raises:
        LimitError: the speed is 0 (:func:`~galil.motion.zero_speed`).
    """
    if speed <= 0:
        raise zero_speed(link, a, "SP", f"axis {a} has SP 0: set a speed first")
    return speed


def _schedule_state(
    link: CommandLink, tracker: MotionTracker, a: str, gears: Mapping[str, GearLink]
) -> tuple[_State, dict[str, tuple[float, float, int]]]:
    """Axis ``a``'s state and the followers' ``(BL, FL)``, in one query that also asks
    whether thread 0 runs.

    Raises:
        InvalidArgument: the axis moving or its motor off, or thread 0 running (a schedule in
            progress, or the user's program).
        MotionError: a limit stopped a follower during a move nobody waited for.
    """
    names = (*_operand_names(a, _STATE), "_XQ0", *follower_operands("".join(gears), tracker))
    values = link.query_operands(names)
    state = _states(link, a, values)[a]
    _seen_at_rest(tracker, {a: state})
    _ready(link, a, state)
    n = len(_STATE)
    if values[n] >= 0:
        raise InvalidArgument(
            "thread 0 runs a program (a speed schedule still in progress, or yours): wait for "
            "the schedule to end or stop it first",
            model=link.model.name,
        )
    return state, follower_limits(link, tracker, gears, values[n + 1 :])


def _undo_start(
    link: CommandLink, tracker: MotionTracker, routines: Routines, a: str, speed: float
) -> None:
    """After a failed ``XQ`` of a schedule: halt thread 0 (checked free under the tracker's
    lock, so only the schedule can run there) and put ``SP`` back to ``speed``; a dead link
    is reopened once for it, and a failure dropped (the caller's exception is the one)."""
    undo = [cmds.hx(0), cmds.sp(model=link.model, **{a: speed})]
    if send_reopening(functools.partial(link.command_line, undo), tracker.reconnect):
        routines.forget(0)


def _cancel_schedule(
    link: CommandLink,
    routines: Routines,
    handle: MoveHandle,
    letter: str,
    speed: float,
    run: object,
    sample: int | None,
) -> None:
    """A speed schedule the library stopped or aborted (``ST``/``AB`` at ``sample``).

    Its routine is halted (``HX0``, only while this schedule holds thread 0): no change point
    may run after the stop (the controller releases a waiting ``AD`` when the motion ends,
    and the ``SP`` after it would run), nor may a trippoint wait on into a later move. If the
    stop came before the schedule's predicted end (or when is unknown), ``SP`` goes back to
    ``speed``, its value before the schedule: the speeds of a schedule that did not run its
    course are not left behind. One that ran to its end keeps its last speed, as a move's
    ``speed=`` stays set.
    """
    routines.halt(0, owner=run)
    begin = handle.begin.get(letter)
    track = handle.track(letter)
    plan = None if track is None else track.fixed
    if sample is None or begin is None or plan is None or sample - begin < plan.samples:
        link.command_line([cmds.sp(model=link.model, **{letter: speed})])


def _schedule_program(
    link: CommandLink,
    a: str,
    label: str,
    first: float,
    distance: int,
    schedule: predict.SpeedSchedule,
) -> list[str]:
    """The program of a speed schedule: SP, PR, BG, stamp the start, then AD/SP pairs."""
    model = link.model
    program = [
        label,
        cmds.sp(model=model, **{a: first}).text,
        cmds.pr(model=model, **{a: distance}).text,
        cmds.bg(a, model=model).text,
        f"{SCHEDULE_BEGIN}=TIME",
    ]
    for trig, new in zip(schedule.triggers, schedule.speeds[1:], strict=True):
        program += [cmds.ad(model=model, **{a: trig}).text, cmds.sp(model=model, **{a: new}).text]
    program.append("EN")
    return program
