"""Homing and switches, in counts: HM, FE, FI, HV, the switch state, CN and the homed flag.

An :class:`~galil.axis.Axis` holds one :class:`AxisHoming`; ``axis.home()``,
``axis.find_edge()`` and ``axis.find_index()`` call :meth:`AxisHoming.start`, which reads
the axis's state in one round trip, refuses what the controller would refuse, predicts the
sequence when the switch positions are known (:func:`galil.predict.homing`), checks that
path against the soft limits as a move's is, and sends ``HM A;BG A;MG TIME`` (or
``FE``/``FI``) as one line. The :class:`~galil.motion.MoveHandle`
it returns waits, shows progress and stops like any move; its stop code is 10 after HM and
FI, 9 after FE.

Switches (:func:`read_switches`) come from ``TS`` in one round trip: the limit bits of TS
are 0 while a switch is active whatever ``CN``'s polarity, so the booleans mean "tripped".
The home input has no "active" level of its own: ``home`` is true when the input is at the
level CN field 1 calls active (low by default), an assumption recorded in decision 0015.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from galil import predict
from galil.errors import InvalidArgument, LimitError
from galil.link import CommandLink
from galil.models import INT32_MAX, INT32_MIN
from galil.motion import (
    Display,
    MotionTracker,
    MoveHandle,
    MoveParams,
    Track,
    as_stored,
    sample_of,
    stop_on_error,
    switch_blocks,
    zero_speed,
)
from galil.protocol import commands as cmds

__all__ = [
    "AxisHoming",
    "Homed",
    "SwitchPolarity",
    "Switches",
    "read_polarity",
    "read_switches",
    "set_polarity",
]

_KINDS = {"HM": ("home", cmds.hm), "FE": ("edge", cmds.fe), "FI": ("index", cmds.fi)}
_STATE = ("RP", "BG", "MO", "SP", "AC", "DC", "JG", "HV", "TS", "MT", "SC", "BL", "FL")


@dataclass(frozen=True)
class Switches:
    """The switches of one axis, read in one round trip.

    Attributes:
        forward_limit: the forward limit switch is active (tripped), whatever CN's polarity.
        reverse_limit: the reverse limit switch is active.
        home: the home input is at the level CN calls active (see the module docstring).
        home_input: the home input's level as read (``_HM``: 1 high, 0 low).
    """

    forward_limit: bool
    reverse_limit: bool
    home: bool
    home_input: int


@dataclass(frozen=True)
class SwitchPolarity:
    """``CN``: how the controller reads its switches.

    Attributes:
        limit: 1 when a limit switch is active high, -1 active low (the default).
        home: 1 drives forward (HM, FE) while the home input is high, -1 in reverse.
        latch: 1 latches on a rising edge, -1 on a falling one.
    """

    limit: int = -1
    home: int = -1
    latch: int = -1


@dataclass(frozen=True)
class Homed:
    """Whether an axis is homed, and how the library knows (``bool(homed)`` works).

    Attributes:
        homed: the axis's position was defined at a home or index since power-on, as far as
            the library can tell.
        how: where that comes from: a sequence this Controller started and saw end with
            stop code 10, the controller's stop code, or why neither says so.
    """

    homed: bool
    how: str

    def __bool__(self) -> bool:
        return self.homed


def read_switches(link: CommandLink, letter: str) -> Switches:
    """The switches of ``letter`` (``MG _TSx,_CN0``: one round trip)."""
    ts, cn = link.query_operands([f"_TS{letter}", "_CN0"])
    bits = round(ts)
    level = bits >> 1 & 1
    return Switches(
        forward_limit=not bits & 0x08,
        reverse_limit=not bits & 0x04,
        home=level == (1 if cn > 0 else 0),
        home_input=level,
    )


def read_polarity(link: CommandLink) -> SwitchPolarity:
    """``CN`` fields 1-3 (``MG _CN0,_CN1,_CN2``)."""
    values = [round(v) for v in link.query_operands(["_CN0", "_CN1", "_CN2"])]
    return SwitchPolarity(*values)


def set_polarity(link: CommandLink, polarity: SwitchPolarity) -> None:
    """Send ``CN`` (every field validated before the byte goes out)."""
    if not isinstance(polarity, SwitchPolarity):
        raise InvalidArgument(f"switch_polarity takes a SwitchPolarity, not {polarity!r}")
    link.command_line([cmds.cn(polarity.limit, polarity.home, polarity.latch)])


class AxisHoming:
    """Homing of one axis, and what the library knows of its homed state."""

    def __init__(self, link: CommandLink, letter: str, tracker: MotionTracker) -> None:
        self._link = link
        self.letter = letter
        self._tracker = tracker
        self._last: MoveHandle | None = None
        self._confirmed: str | None = None
        self._redefined: str | None = None  # how define_position changed the coordinate

    def start(
        self,
        kind: str,
        switch: predict.HomeSwitch | None = None,
        *,
        display: Display | None = None,
    ) -> MoveHandle:
        """Start HM, FE or FI; predict it when ``switch`` (positions in counts) is given.

        Raises:
            InvalidArgument: the axis moves or its motor is off, it would start into an
                active limit switch that LD leaves on, it is geared to another axis, or
                another axis is geared to it (see :meth:`_refuse_gearing`).
            LimitError: a speed it needs (SP, HV, JG) is 0, as for a move
                (:func:`~galil.motion.zero_speed`); it would start on past a soft limit it is
                beyond already (TC 22), or
                (``switch`` given) its predicted path crosses BL or FL (:meth:`_check_path`).
        """
        if switch is not None and not isinstance(switch, predict.HomeSwitch):
            raise InvalidArgument(f"switch must be a galil.predict.HomeSwitch, not {switch!r}")
        tracker = self._tracker
        with tracker.lock, stop_on_error(self._link, tracker, self.letter):  # (no other
            return self._start(kind, switch, display)  # thread's motion until the handle)

    def _start(
        self, kind: str, switch: predict.HomeSwitch | None, display: Display | None
    ) -> MoveHandle:
        self._tracker.refuse_cancelled(self._link.model.name)  # (a cancelled task's: 0100)
        self._refuse_gearing(kind)
        link, a = self._link, self.letter
        model = link.model
        # (no HV on the model: its HM's slow stages run at the firmware's home_slow_speed)
        state = _STATE if model.has_hv else tuple(op for op in _STATE if op != "HV")
        values = link.query_operands([f"_{op}{a}" for op in state] + ["_CN1"])
        if not model.has_hv:
            values.insert(state.index("TS"), model.home_slow_speed)
        rp, bg, mo, sp, ac, dc, jg, hv, ts, mt, sc, bl, fl, cn_home = values
        if not bg:
            self._tracker.ended(a, rp, sc)
        self._refuse(kind, bool(bg), bool(mo), sp, jg, hv)
        params = predict.HomingParams(
            speed=as_stored(link, "SP", sp),
            accel=as_stored(link, "AC", ac),
            decel=as_stored(link, "DC", dc),
            home_speed=as_stored(link, "SP", hv),
            jog_speed=as_stored(link, "JG", jg),
            home_direction=1 if cn_home > 0 else -1,
            stepper=abs(mt) in (2.0, 2.5),
        )
        self._refuse_limit(kind, round(ts), params, (round(rp), bl, fl))
        track = self._track(kind, round(rp), params, switch, (bl, fl), round(ts) >> 1 & 1)
        mode, build = _KINDS[kind]
        replies = link.command_line(
            [build(a, model=model), cmds.bg(a, model=model), cmds.time_stamp()]
        )
        track.begin = sample_of(replies[-1])
        handle = MoveHandle(
            link, {a: track}, mode, display={a: display} if display else None, tracker=self._tracker
        )
        self._tracker.started(handle)
        self._last = handle
        if kind != "FE":
            self._confirmed = None
            self._redefined = None
        return handle

    def _refuse_gearing(self, kind: str) -> None:
        """Refuse homing a gear master, or a follower (no query: the tracker knows).

        A follower of the axis would move with it, but how far is not known before the
        sequence runs: it searches for a switch (unbounded without switch positions; with
        them, FE's end still depends on the servo lag), so the follower's path cannot be
        checked against its soft limits and the SP maximum as a position move's is. HM and
        FI then define the axis's position at the index, and a follower of the commanded
        position would take that jump at once (the simulator's follower does). So homing a
        master is refused while anything follows it.

        Raises:
            InvalidArgument: naming the followers, or the master of a follower.
        """
        a, tracker, name = self.letter, self._tracker, self._link.model.name
        tracker.refuse_geared(a, kind, name)
        followers = tracker.followers(a)
        if followers:
            who = ", ".join(f"{f} (GR {g.ratio:g})" for f, g in followers.items())
            raise InvalidArgument(
                f"axis {a} is the gear master of {who}: {kind} searches for a switch or an "
                "index, so how far it moves, and its followers with it, is not known before it "
                f"runs (their soft limits cannot be checked), and HM/FI redefine {a}'s position "
                "at the end; turn the gearing off (gearing.off()) and gear again after homing",
                model=name,
            )

    def _refuse(self, kind: str, bg: bool, mo: bool, sp: float, jg: float, hv: float) -> None:
        name, a = self._link.model.name, self.letter
        if bg:
            raise InvalidArgument(f"axis {a} is moving; stop it or wait first", model=name)
        if mo:
            raise InvalidArgument(
                f"axis {a} has its motor off; call controller.servo_here()", model=name
            )
        link = self._link
        if kind != "FI" and sp <= 0:
            raise zero_speed(link, a, "SP", f"axis {a} has SP 0: set a speed first")
        if kind != "FE" and hv <= 0:
            raise zero_speed(link, a, "HV", f"axis {a} has HV 0: set home_speed first")
        if kind == "FI" and jg == 0:
            raise zero_speed(
                link,
                a,
                "JG",
                f"FI runs at JG, which is 0 on {a}: set jog_speed (its sign is the direction)",
            )

    def _refuse_limit(
        self,
        kind: str,
        ts: int,
        params: predict.HomingParams,
        limits: tuple[int, float, float],
    ) -> None:
        """Refuse a start towards an active limit switch ``LD`` does not disable
        (:func:`~galil.motion.switch_blocks`), or on past a soft limit the axis is
        beyond already (``limits``: RP, BL, FL): the controller refuses its BG with TC 22,
        after the HM, FE or FI went out.

        Raises:
            InvalidArgument: the switch. LimitError: the soft limit.
        """
        # The direction of HM/FE comes from the home input (TS bit 1) and CN field 2.
        if kind == "FI":
            direction = 1 if params.jog_speed > 0 else -1
        else:
            high = bool(ts & 0x02)
            direction = 1 if high == (params.home_direction > 0) else -1
        side = "forward" if direction > 0 else "reverse"
        if switch_blocks(self._link, self.letter, direction, ts):
            raise InvalidArgument(
                f"{kind} on {self.letter} would start towards its active {side} limit switch "
                "(the controller refuses it with TC 22); move off the switch first",
                model=self._link.model.name,
            )
        rp, bl, fl = limits
        name, limit = ("FL", fl) if direction > 0 else ("BL", bl)
        if (rp > fl) if direction > 0 else (rp < bl):
            raise LimitError(
                f"{kind} on {self.letter} would start {side} from {rp:g}, beyond {name} "
                f"{limit:g} (the controller refuses it with TC 22); move it back inside first",
                name=name,
                value=rp,
                limit=limit,
                axis=self.letter,
                model=self._link.model.name,
            )

    def _track(
        self,
        kind: str,
        rp: int,
        params: predict.HomingParams,
        switch: predict.HomeSwitch | None,
        limits: tuple[float, float],
        level: int,
    ) -> Track:
        """The handle's record: predicted from ``switch`` when it is given and agrees with the
        home input's ``level`` as TS read it (HM and FE start from that input; decision 0088),
        its path checked against the soft ``limits`` (:meth:`_check_path`).
        """
        move = MoveParams(params.speed, params.accel, params.decel, 1.0)
        mode = _KINDS[kind][0]
        if switch is None:
            note = "no switch positions given: duration and path unknown; the end is read back"
            return Track(mode, rp, move, None, exact=False, note=note)
        if kind != "FI" and switch.level(rp) != level:
            note = (
                f"the home input reads {'high' if level else 'low'}, but the given switch "
                f"positions put it {'low' if level else 'high'} at {rp} (a switch held, or not "
                "where they say): the controller searches from the input, so duration and path "
                "are unknown; the end is read back"
            )
            return Track(mode, rp, move, None, exact=False, note=note)
        ts = self._link.sample_period
        found = predict.homing(kind, params, switch, start=rp, sample_period=ts)
        self._check_path(kind, found, limits)

        def replan(events: Sequence[predict.Event]) -> predict.Profile:
            # (an AC while it runs: the phase in progress re-plans; decision 0066)
            again = predict.homing(kind, params, switch, start=rp, sample_period=ts, events=events)
            return again.profile

        note = "predicted from the given switch positions, on the reference position"
        if found.zero_at is None:
            # FE ends where the motor met the edge: later than the reference by the servo lag
            # (speed x lag counts), which the predictor does not model.
            note += "; the end is approximate (the edge is met by the lagging motor)"
            return Track(
                mode, rp, move, None, fixed=found.profile, note=note, exact=False, replan=replan
            )
        note += f"; position 0 at {found.zero_at} (old counts), exact"
        return Track(mode, rp, move, None, fixed=found.profile, note=note, replan=replan)

    def _check_path(
        self, kind: str, found: predict.HomingPrediction, limits: tuple[float, float]
    ) -> None:
        """Refuse a predicted sequence whose path crosses ``BL`` or ``FL`` (``limits``)
        outwards, as a move's is (decision 0003): the controller would stop it there with stop
        code 2 or 3, short of its switch or index. HM and FI define position 0 only when they
        end, so the path is checked in the counts at the start (the prediction's profile is in
        the frame the sequence ends with).

        Raises:
            LimitError: naming the command, where the path crosses and where it would end.
        """
        profile = found.profile
        if found.zero_at:
            profile = predict.Profile.from_samples(
                profile.position + found.zero_at,
                sample_period=profile.sample_period,
                shape=profile.shape,
                peak_speed=profile.peak_speed,
            )
        bl, fl = limits
        try:
            predict.check_soft_limits(
                profile, forward_limit=fl, backward_limit=bl, axis=self.letter
            )
        except LimitError as exc:
            exc.end = profile.end
            exc.model = self._link.model.name
            exc.args = (
                f"{kind} on {self.letter} (predicted from the given switch positions) would be "
                f"stopped by the controller short of its switch or index: {exc.args[0]}; widen "
                "the soft limits (soft_limits) or start it from elsewhere",
                *exc.args[1:],
            )
            raise

    def forget(self) -> None:
        """The controller was reset (``RS``): a homing seen before defines nothing now."""
        self._last = None
        self._confirmed = None
        self._redefined = None

    # -- defining the position (DP) ---------------------------------------------------------
    def define(self, counts: int, shift_limits: bool) -> None:
        """``DP counts`` (a stepper's ``DE counts`` too), the axis at rest and no follower of
        it engaged; ``BL``/``FL`` shifted with the coordinate, or (``shift_limits`` False) kept,
        the present position then inside them (decision 0058).

        Raises:
            InvalidArgument: the axis moves, is a gear follower, or has followers.
            LimitError: a shifted limit outside the 32-bit range, or (kept) the present
                position beyond one.
        """
        link, a, tracker = self._link, self.letter, self._tracker
        model = link.model
        with tracker.lock:  # (no other thread's motion between the read and the DP)
            tracker.refuse_geared(a, "define_position", model.name)
            followers = tracker.followers(a)
            if followers:
                who = ", ".join(f"{f} (GR {g.ratio:g})" for f, g in followers.items())
                raise InvalidArgument(
                    f"axis {a} is the gear master of {who}: DP changes {a}'s position at once, "
                    "and a follower would take that jump times its ratio; turn the gearing off "
                    "(gearing.off()) and gear again after define_position",
                    model=model.name,
                )
            rp, bg, sc, mt, bl, fl = link.query_operands(
                [f"_{op}{a}" for op in ("RP", "BG", "SC", "MT", "BL", "FL")]
            )
            if bg:
                raise InvalidArgument(
                    f"define_position (DP) is not valid while axis {a} moves: wait for its "
                    "motion or stop it first",
                    model=model.name,
                )
            self._refuse_unknown_followers()
            tracker.ended(a, rp, sc)  # (a handle nobody waited for ends in the old counts)
            parts = [cmds.dp(model=model, **{a: counts})]
            if abs(mt) in (2.0, 2.5):  # a stepper's DP leaves its encoder (TP): DE sets it
                parts.append(cmds.de(model=model, **{a: counts}))
            parts += self._limits(counts, round(rp), (round(bl), round(fl)), shift_limits)
            link.command_line(parts)
            self._redefined = (
                f"its position was redefined since (define_position: DP {counts} where RP was "
                f"{rp:g}), so 0 is no longer where the home or index set it"
            )

    def _refuse_unknown_followers(self) -> None:
        """Refuse ``DP`` while another axis follows a master the library does not know: a
        gearing found at connect, or set up since by a program or another host (``_GR`` read
        now; ``GA`` has no operand, so its master may be this axis, which would jump).

        Raises:
            InvalidArgument: naming the followers and how to turn them off.
        """
        link, a, tracker = self._link, self.letter, self._tracker
        others = [x for x in link.model.axes if x != a and x not in tracker.gears]
        if not others or not tracker.reads_ratios:
            return  # (no _GR on this firmware: no gearing is looked for, as at connect)
        ratios = link.query_operands([f"_GR{x}" for x in others])
        unknown = [f"{x} (GR {r:g})" for x, r in zip(others, ratios, strict=True) if r != 0]
        if unknown:
            raise InvalidArgument(
                f"axis {a} may be the gear master of {', '.join(unknown)}, geared outside this "
                f"Controller (GA has no operand: the master is not known): DP would make a "
                f"follower of {a} jump with it; turn that gearing off first "
                "(axis.gear_off() on the follower)",
                model=link.model.name,
            )

    def _limits(
        self, counts: int, rp: int, limits: tuple[int, int], shift: bool
    ) -> list[cmds.Command]:
        """The ``BL``/``FL`` commands that keep the soft limits where they are on the machine
        (a limit that is off, at the 32-bit end, stays off), or none, the present position
        checked against them (``shift`` False).

        Raises:
            LimitError: a shifted limit outside the 32-bit range (or onto the value that
                turns it off), or the new position beyond a kept one.
        """
        a, model = self.letter, self._link.model
        ends = (("BL", limits[0], INT32_MIN, cmds.bl), ("FL", limits[1], INT32_MAX, cmds.fl))
        parts = []
        for name, limit, off, build in ends:
            if not shift:
                if (counts < limit) if name == "BL" else (counts > limit):
                    raise LimitError(
                        f"define_position({counts}) on {a} would put the axis beyond {name} "
                        f"{limit}, which keeps its number (shift_limits=False); give a position "
                        "inside the soft limits, or let them shift with it",
                        name=name,
                        value=counts,
                        limit=limit,
                        axis=a,
                        model=model.name,
                    )
                continue
            moved = limit + counts - rp
            if limit == off or moved == limit:
                continue
            if not INT32_MIN < moved < INT32_MAX:
                raise LimitError(
                    f"define_position({counts}) on {a} shifts {name} {limit} to {moved}, "
                    "beyond the 32-bit position range (or onto the value that turns it off); "
                    "set the soft limits first (soft_limits), or pass shift_limits=False",
                    name=name,
                    value=moved,
                    limit=INT32_MAX if moved > 0 else INT32_MIN,
                    axis=a,
                    model=model.name,
                )
            parts.append(build(model=model, **{a: moved}))
        return parts

    def homed(self) -> Homed:
        """Whether the axis is homed and how that is known (one query at most); after a
        :meth:`define` the reason says so (the axis stays referenced: DP at rest shifts the
        coordinate by a known amount)."""
        found = self._homed()
        if found.homed and self._redefined is not None:
            return Homed(True, f"{found.how}; {self._redefined}")
        return found

    def _homed(self) -> Homed:
        a = self.letter
        last = self._last
        pending = last is not None and last.kind in ("home", "index") and self._confirmed is None
        if pending and last is not None and last.done:
            result = last.result
            if result is not None and result.stop_codes.get(a) == 10:
                name = "HM" if last.kind == "home" else "FI"
                self._confirmed = (
                    f"{name} started by this Controller ended with stop code 10 "
                    "(it defined position 0)"
                )
        if self._confirmed is not None:
            return Homed(True, self._confirmed)
        code = round(self._link.query_operands([f"_SC{a}"])[0])
        if code == 10:
            return Homed(
                True,
                f"the controller's stop code on {a} is 10: its last motion was an HM or FI "
                "that ended normally (not started by this Controller)",
            )
        return Homed(
            False,
            f"no HM or FI ended on {a} through this Controller, and the controller's stop "
            f"code is {code}, not 10",
        )
