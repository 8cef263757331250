"""Limits: soft limits (``FL``/``BL``), limit and home switches, ``CN``, and ``TS``.

Soft limits act on the reference position (``RP``) and stop at DC, like a limit switch, and
only motion *outwards* is stopped, so an axis beyond a limit can always be moved back (decision
0003). A step of the servo loop ends where the previewed path first crosses a limit outwards.

Switches live in the machine's fixed frame (:attr:`~galil.sim.servo.Axis.physical`: the encoder
plus an origin that moves when a position is defined). A limit switch is *tripped* when the
test hook presses it (:meth:`Limits.set_switch`) or the motor is at or beyond the position it
was placed at (:meth:`Limits.place`; none are placed by default). A tripped switch pulls its
input low; ``CN`` field 1 says which level is *active* (-1, the default: low), so with ``CN 1``
an untripped switch reads active, as on a real controller. ``_LFx``/``_LRx`` are 0 and the TS
bits 3/2 are 0 while a switch is active. An active switch stops an axis in motion whose
profiler's velocity points at it, at the first sample both hold, however the axis moves (a
move, a jog, a contour, a sequence, a gear): a motion that has ended when its motor reaches a
placed switch (the servo lag) is not stopped; the switch reads active and the next motion
towards it is refused or stopped at its first sample (decision 0054). A watch ends a servo
step at the sample an axis runs into a placed switch; while placed switches are about, a step
also ends where such an axis turns back, so a path cannot enter a switch and leave it again
inside one step unseen; and a step ends at the sample an axis starts towards a switch active
already (a jog reversed, a follower's master or a path turning), so one long advance stops it
where stepping sample by sample does. The home switch is a flag on one side of an edge
(default: below -10,000 counts) that pulls the home input (TS bit 1, ``_HMx``) low; index
pulses come every 4,000 counts from 0 (:class:`HomeGeometry`). Decision 0015. A test may
hold the home switch tripped or released whatever the position (:meth:`Limits.set_home`); the
home input then reads that level, and HM/FE see that same input (:meth:`Limits.home_switch`, the
one switch TS, ``_HMx``, the record and the homing room read): they start from it and find the
edge only when the hold ends, or never while it lasts (decision 0088).

``LD`` disables a limit switch per axis (1 forward, 2 reverse, 3 both; decision 0046): a
disabled switch neither stops motion towards it nor refuses a start towards it, so no
#LIMSWI runs for it ("LD can be used to disable the limit operation", #LIMSWI), and the
watches and horizon pass it by. Its input still reads: ``_LFx``/``_LRx`` (the reference's LD
example reads ``_LFA`` as an input after ``LDA=1``), ``TS`` and the data record's switch bits
(unsourced for TS; EPICS: "The controller still reports the limit switch status"). The soft
limits stay ("LD does not disable software limits set by BL and FL"). A model without LD
refuses the command and ``_LDx`` with TC 1, as any command it does not know.

Contour axes are stopped by switches and soft limits on the same rules (the reference's
#LIMSWI: a limit event is "Motion profiling in the direction of the given limit. I.E. RPm
increasing for forward switch"). Such a stop ends the whole contour at once, at the sample the
path reaches the limit: that axis reports 2 or 3, the other contour axes 51, and contour mode
is left with its buffer dropped (decision 0041).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.models import INT32_MAX, INT32_MIN
from galil.predict.engine import KinematicPlan
from galil.predict.homing import HomeSwitch
from galil.sim.interpreter import int32
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.tuning import Tuning
from galil.sim.servo import Axis, turns_back

__all__ = ["DEFAULT_HOME_EDGE", "DEFAULT_INDEX_PERIOD", "HomeGeometry", "Limits"]

#: Where the home flag ends by default (fixed frame, counts): the flag covers what is below.
DEFAULT_HOME_EDGE = -10_000
#: Counts between index pulses by default (one motor turn of a 1000-line encoder).
DEFAULT_INDEX_PERIOD = 4_000
#: Beyond any position a motor reaches (counts): a held home switch's edge is put there, so
#: the input reads one level wherever the motor is and no motion meets an edge.
_OUT_OF_REACH = 2**62


@dataclass(frozen=True)
class HomeGeometry:
    """Where an axis's home flag and index pulses are, in the machine's fixed frame.

    Attributes:
        edge: where the home flag ends.
        side: -1 when the flag covers positions below ``edge``, +1 above (at ``edge`` too).
        index_period: counts between index pulses.
        index_offset: where one index pulse is (the others every ``index_period``).
    """

    edge: int = DEFAULT_HOME_EDGE
    side: int = -1
    index_period: int = DEFAULT_INDEX_PERIOD
    index_offset: int = 0

    def on_flag(self, physical: int) -> bool:
        """Whether the home switch is tripped at ``physical``."""
        return physical < self.edge if self.side < 0 else physical >= self.edge

    def next_index(self, physical: int, direction: int) -> int:
        """The first index pulse strictly beyond ``physical`` in ``direction``."""
        p, off = self.index_period, self.index_offset
        k = (physical - off) // p
        if direction > 0:
            return off + (k + 1) * p
        below = off + k * p
        return below if below < physical else below - p

    def input(self, pressed: bool | None) -> HomeSwitch:
        """The switch the home input follows: this geometry, or (``pressed`` not ``None``) one
        held tripped or released everywhere, its edge out of reach, the index pulses kept."""
        if pressed is None:
            return HomeSwitch(self.edge, self.side, self.index_period, self.index_offset)
        edge = _OUT_OF_REACH if pressed else -_OUT_OF_REACH  # (side -1: tripped below)
        return HomeSwitch(edge, -1, self.index_period, self.index_offset)


_FREE_HOME = HomeGeometry().input(None)


@dataclass
class _AxisLimits:
    fl: int = INT32_MAX
    bl: int = INT32_MIN
    forward: bool = False  # forward limit switch pressed by the test hook
    reverse: bool = False
    forward_at: int | None = None  # placed: tripped at or beyond this (fixed frame)
    reverse_at: int | None = None
    home: HomeGeometry = field(default_factory=HomeGeometry)
    home_pressed: bool | None = None  # the test hook holds the home switch (None: geometry)
    home_input: HomeSwitch = _FREE_HOME  # what the home input follows (the two above)
    ld: int = 0  # LD: 1 the forward switch disabled, 2 the reverse one, 3 both


class Limits(Room):
    """Soft limits, limit switches and what stops an axis at them."""

    requires = (Tuning,)

    def reset(self) -> None:
        self.axes = {letter: _AxisLimits() for letter in self.machine.spec.axes}
        self._switched = False  # any switch may be active: the service hook has work
        self._placed = False  # any switch placed: the horizon hook has work
        self._soft = False  # any soft limit set: the horizon hook has work
        #: How many times a limit has stopped an axis (set its ``limit_stop``): a room that
        #: reacts to those stops looks at the axes only when this has changed.
        self.stops = 0
        #: CN fields: limit polarity (-1 active low), home direction, latch edge, two more.
        self.cn = [-1.0, -1.0, -1.0, 0.0, 1.0]

    def burn(self, name: str) -> object | None:
        # The BN table: FL BL LD CN (the switches themselves are the machine's, not burned).
        if name != "BN":
            return None
        return {c: (a.fl, a.bl, a.ld) for c, a in self.axes.items()}, list(self.cn)

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, tuple)
        axes, self.cn = saved
        for c, (fl, bl, ld) in axes.items():
            a = self.axes[c]
            a.fl, a.bl, a.ld = fl, bl, ld
        self._soft_limits_changed()
        self._switched = True  # (a switch may be active and now enabled: look again)

    # ---- switch states -----------------------------------------------------------------
    def tripped(self, ax: Axis, which: str) -> bool:
        """Whether the forward or reverse limit switch is physically tripped."""
        s = self.axes[ax.letter]
        if which == "forward":
            return s.forward or (s.forward_at is not None and ax.physical >= s.forward_at)
        return s.reverse or (s.reverse_at is not None and ax.physical <= s.reverse_at)

    def active(self, ax: Axis, which: str) -> bool:
        """Whether the controller sees the switch active (tripped pulls low; CN picks the level)."""
        return self.tripped(ax, which) != (self.cn[0] > 0)

    def halts(self, ax: Axis, which: str) -> bool:
        """Whether the switch stops motion towards it: active, and not disabled by ``LD``."""
        bit = 1 if which == "forward" else 2
        return not self.axes[ax.letter].ld & bit and self.active(ax, which)

    def home_level(self, ax: Axis) -> int:
        """The home input: 0 (low) while the home switch is tripped, 1 otherwise."""
        return self.axes[ax.letter].home_input.level(ax.physical)

    def home_switch(self, letter: str) -> HomeSwitch:
        """The switch the home input of ``letter`` follows, in the fixed frame: the one TS
        and ``_HMx`` read and HM/FE/FI search (a held switch's edge is out of reach). A new
        object whenever :meth:`set_home` changes it, the same one until then."""
        return self.axes[letter].home_input

    def place(self, letter: str, forward: int | None, reverse: int | None) -> None:
        """Place the limit switches of ``letter`` at fixed-frame positions (``None``: none)."""
        s = self.axes[letter]
        s.forward_at, s.reverse_at = forward, reverse
        self._update_switched()

    def set_home(self, letter: str, geometry: HomeGeometry, pressed: bool | None = None) -> None:
        """Set where the home flag and index pulses are; ``pressed`` holds the switch."""
        s = self.axes[letter]
        s.home, s.home_pressed = geometry, pressed
        s.home_input = geometry.input(pressed)

    def _update_switched(self) -> None:
        self._placed = any(
            a.forward_at is not None or a.reverse_at is not None for a in self.axes.values()
        )
        pressed = any(a.forward or a.reverse for a in self.axes.values())
        self._switched = self.cn[0] > 0 or self._placed or pressed

    # ---- used by other rooms -----------------------------------------------------------
    def check_start(self, ax: Axis, direction: float) -> None:
        """Refuse a start towards an active switch (not disabled by LD) or beyond a soft limit.

        Raises:
            Refused: TC 22.
        """
        s = self.axes[ax.letter]
        ref = ax.m.reference
        if direction > 0 and (self.halts(ax, "forward") or ref > s.fl):
            raise Refused(22, "forward limit")
        if direction < 0 and (self.halts(ax, "reverse") or ref < s.bl):
            raise Refused(22, "reverse limit")

    def switch_bits(self, ax: Axis) -> int:
        """The home input (bit 1) and the limit bits (3 forward, 2 reverse; set while inactive)."""
        if not self._switched and self.home_level(ax):
            return 0x0E
        forward = 0 if self.active(ax, "forward") else 0x08
        reverse = 0 if self.active(ax, "reverse") else 0x04
        return 0x02 * self.home_level(ax) | forward | reverse

    def set_switch(self, letter: str, which: str, active: bool) -> None:
        """Set a limit switch; an active one stops motion towards it (SC 2/3).

        Raises:
            InvalidArgument: ``which`` is not ``"forward"`` or ``"reverse"``.
        """
        if which not in ("forward", "reverse"):
            raise InvalidArgument(f"which must be 'forward' or 'reverse', not {which!r}")
        s = self.axes[letter]
        if which == "forward":
            s.forward = bool(active)
        else:
            s.reverse = bool(active)
        self._update_switched()
        self._check_switch(self.machine.servo.axes[letter])

    # ---- servo-loop hooks --------------------------------------------------------------
    def horizon(self, k: int) -> int:
        if self._switched:
            k = self._towards_active(self._until_reversal(k))
        if not self._soft:
            return k
        for ax in self.machine.servo.axes.values():
            s = self.axes[ax.letter]
            if (s.fl < INT32_MAX or s.bl > INT32_MIN) and ax.m.moving and not ax.limit_stop:
                prof = ax.m.profiler
                now = prof.reference
                # Beyond a limit already (one set under the axis): moving outwards is the
                # profiler's velocity, as after_step reads it, not the reference growing. A
                # contour's samples may stand still inside a moving segment (its floor
                # rounding), where after_step reads that segment's speed: always so there.
                outside = ax.contour or not s.bl <= now <= s.fl
                v = prof.preview_velocity(k) if outside else None
                k = min(k, self._crossing(s, now, prof.preview(k), v))
        return k

    def _until_reversal(self, k: int) -> int:
        """End the step where an axis watched for a placed switch turns back (a jog reversed,
        an arc): the watch compares where the step began and ended, which holds only while
        the axis keeps one direction (it could enter a switch and leave it again unseen)."""
        for ax in self.machine.servo.axes.values():
            if self._watched(ax):
                k = turns_back(ax.m.profiler, k)
        return k

    def _towards_active(self, k: int) -> int:
        """End the step at the first sample where an axis moves towards a switch active
        already (pressed, or placed and reached) that LD leaves on: a jog reversed, a follower
        whose master turns, a contour's or a sequence's path that turns (``CM`` moves
        nothing; ``BG S`` checked only each axis's first direction: decision 0050). The
        service then stops it there, as it would sample by sample (decision 0054)."""
        for ax in self.machine.servo.axes.values():
            if not ax.m.moving or ax.limit_stop:
                continue
            forward, reverse = self.halts(ax, "forward"), self.halts(ax, "reverse")
            if not (forward or reverse):
                continue
            prof = ax.m.profiler
            plan = prof.plan  # (None on a contour's or a driven axis's path)
            if plan is None or _heads(plan, forward, reverse):
                v = prof.preview_velocity(k)
                hits = np.flatnonzero((v > 0) & forward | (v < 0) & reverse)
                if hits.size:
                    k = min(k, int(hits[0]) + 1)
        return k

    def _watched(self, ax: Axis) -> bool:
        """Whether ``ax`` may run into a placed switch LD leaves on (the watch looks for it)."""
        if not ax.m.moving or ax.limit_stop:
            return False
        s = self.axes[ax.letter]
        return (s.forward_at is not None and not s.ld & 1) or (
            s.reverse_at is not None and not s.ld & 2
        )

    @staticmethod
    def _crossing(
        s: _AxisLimits,
        now: int,
        refs: npt.NDArray[np.int64],
        v: npt.NDArray[np.float64] | None = None,
    ) -> int:
        """Samples until the path is beyond a soft limit moving outwards (large if never).

        ``now`` is the reference before the first sample of ``refs``; ``v`` the profiler's
        velocity at each sample. Without it, moving outwards is the reference growing away,
        which it does at the first sample beyond a limit, so ``v`` is needed only when
        ``now`` is beyond one already.
        """
        r = np.asarray(refs)
        if v is None:
            prev = np.concatenate(([now], r[:-1]))
            out, back = r > prev, r < prev
        else:
            out, back = v > 0, v < 0
        beyond = ((r > s.fl) & out) | ((r < s.bl) & back)
        hits = np.flatnonzero(beyond)
        return int(hits[0]) + 1 if hits.size else r.size + 1

    def after_step(self) -> None:
        for ax in self.machine.servo.axes.values():
            prof = ax.m.profiler
            if not prof.moving or ax.limit_stop:
                continue
            s = self.axes[ax.letter]
            v = prof.velocity
            if v > 0 and prof.reference > s.fl:
                self._stop(ax, 2)
            elif v < 0 and prof.reference < s.bl:
                self._stop(ax, 3)

    def _stop(self, ax: Axis, code: int) -> None:
        """A limit stops ``ax`` (stop code ``code``, 2 or 3). In contour mode the whole
        contour stops at once, the other contour axes as by ``ST`` (51), and leaves contour
        mode with its buffer dropped (decision 0041)."""
        ax.limit_stop = True
        self.stops += 1
        ax.m.profiler.limit_stop(code)
        if ax.contour:
            for other in self.machine.servo.axes.values():
                if other.contour and other is not ax:
                    other.m.profiler.stop()

    def watches(self, out: list[Callable[[], bool]]) -> None:
        if not self._switched:
            return
        for ax in self.machine.servo.axes.values():
            if self._watched(ax):
                out.append(functools.partial(self._fires, ax, ax.physical))

    def _fires(self, ax: Axis, start: int) -> bool:
        """Whether ``ax`` has run into a switch since the step began at ``start`` (fixed
        frame): it moves towards an active switch now, or it has entered a placed switch's
        side since (a step may end where the motion does, at rest beyond the switch; the
        bisection then finds the sample it entered, still moving)."""
        if self._runs_into(ax):
            return True
        s, now = self.axes[ax.letter], ax.physical
        if s.forward_at is not None and not s.ld & 1 and start < s.forward_at <= now:
            return True
        return s.reverse_at is not None and not s.ld & 2 and start > s.reverse_at >= now

    def _runs_into(self, ax: Axis) -> int:
        """2 or 3 when ``ax`` moves towards an active limit switch LD leaves on, else 0."""
        v = ax.m.profiler.velocity
        if v > 0 and self.halts(ax, "forward"):
            return 2
        if v < 0 and self.halts(ax, "reverse"):
            return 3
        return 0

    def service(self) -> None:
        if self._switched:
            for ax in self.machine.servo.axes.values():
                self._check_switch(ax)

    def _check_switch(self, ax: Axis) -> None:
        if not ax.m.moving or ax.limit_stop:
            return
        code = self._runs_into(ax)
        if code:
            self._stop(ax, code)

    # ---- commands and operands ---------------------------------------------------------
    @handler("FL", Args.VALUES)
    def fl(self, fields: list[tuple[Axis, str]]) -> str:
        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].fl = int(v)
            self._soft_limits_changed()

        i = self.machine.interp
        return i.parameters(fields, self.forward_limit, lambda ax, v: int32(v), apply, i.pnum)

    @handler("BL", Args.VALUES)
    def bl(self, fields: list[tuple[Axis, str]]) -> str:
        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].bl = int(v)
            self._soft_limits_changed()

        i = self.machine.interp
        return i.parameters(fields, self.reverse_limit, lambda ax, v: int32(v), apply, i.pnum)

    def _soft_limits_changed(self) -> None:
        self._soft = any(a.fl < INT32_MAX or a.bl > INT32_MIN for a in self.axes.values())

    @handler("LD", Args.VALUES, every=True)
    def ld(self, fields: list[tuple[Axis, str]]) -> str:
        """LD: limit disable per axis, 0 .. 3 (DMC-4103 reference: "Valid while in motion";
        a switch enabled again under an axis moving into it stops it at once)."""
        self._has_ld()

        def check(ax: Axis, v: float) -> float:
            if v not in (0, 1, 2, 3):
                raise Refused(6, "LD is 0, 1, 2 or 3")
            return v

        def apply(ax: Axis, v: float) -> None:
            self.axes[ax.letter].ld = int(v)
            self._check_switch(ax)

        i = self.machine.interp
        return i.parameters(fields, self.limit_disable, check, apply, lambda v: i.num(v, "1.0"))

    def _has_ld(self) -> None:
        if not self.machine.spec.has_limit_disable:
            raise Refused(1, f"no LD on {self.machine.spec.name}")

    @operand("LD", kind=OperandKind.AXIS)
    def limit_disable(self, ax: Axis) -> float:
        self._has_ld()
        return self.axes[ax.letter].ld

    @handler("TS", Args.AXES)
    def ts(self, axes: list[Axis]) -> str:
        i = self.machine.interp
        return i.report(axes, self.status_byte, lambda v: i.num(v, "3.0"))

    @operand("FL", kind=OperandKind.AXIS)
    def forward_limit(self, ax: Axis) -> float:
        return self.axes[ax.letter].fl

    @operand("BL", kind=OperandKind.AXIS)
    def reverse_limit(self, ax: Axis) -> float:
        return self.axes[ax.letter].bl

    @operand("LF", kind=OperandKind.AXIS)
    def forward_switch(self, ax: Axis) -> float:
        return 0 if self.active(ax, "forward") else 1

    @operand("LR", kind=OperandKind.AXIS)
    def reverse_switch(self, ax: Axis) -> float:
        return 0 if self.active(ax, "reverse") else 1

    @operand("HM", kind=OperandKind.AXIS)
    def home_input(self, ax: Axis) -> float:
        return self.home_level(ax)

    @operand("CN", kind=OperandKind.INDEX)
    def configuration(self, index: str) -> float:
        """``_CN0`` .. ``_CN4``: the CN fields (an assumption: no source shows the operand)."""
        if not index.isdigit() or not 0 <= int(index) < len(self.cn):
            raise Refused(4, "CN field 0..4")
        return self.cn[int(index)]

    @handler("CN")
    def cn_command(self, args: str) -> str:
        """CN m,n,o,p,q: limit polarity, home direction, latch edge (each 1 or -1), two more."""
        fields = split_fields(args)
        if any(f.strip() == "?" for f in fields):
            i = self.machine.interp
            return ", ".join(i.num(v, "2.0") for v in self.cn[:3]) + "\r\n"
        if len(fields) > len(self.cn):
            raise Refused(50, "CN has five fields")
        new = list(self.cn)
        for k, text in enumerate(fields):
            if not text.strip():
                continue
            value = self.machine.interp.evaluate(text)
            if k < 3 and value not in (-1, 1):
                raise Refused(6, "CN fields 1-3 are 1 or -1")
            new[k] = value
        self.cn = new
        self._update_switched()
        return ""

    @operand("TS", kind=OperandKind.AXIS)
    def status_byte(self, ax: Axis) -> float:
        """``TS``: moving, error beyond ER, motor off, the limit bits, home input high, latch
        not armed.

        Bit 6, "Position error exceeds error limit" (DMC-4103 reference, TS): ``|TE| > ER``,
        the comparison #POSERR makes (decision 0029); ER -1 "disables Error output", so
        never then (decision 0037).
        """
        m = ax.m
        value = 0x01 | self.switch_bits(ax)
        if m.moving:
            value |= 0x80
        er = self.machine.room(Tuning).axes[ax.letter].er
        if er >= 0 and abs(m.error) > er:
            value |= 0x40
        if not m.motor_on:
            value |= 0x20
        return value


def _heads(plan: KinematicPlan, forward: bool, reverse: bool) -> bool:
    """Whether ``plan`` moves forward (``forward``) or in reverse (``reverse``) anywhere: its
    velocity is linear in each segment, so at a segment's ends if at all (a cheap look that
    spares the preview of a jog running away from its active switch, at every step)."""
    for seg in plan.segments:
        if math.isfinite(seg.duration):
            end = seg.velocity + seg.accel * seg.duration
        else:  # (a jog's open-ended cruise)
            end = seg.velocity if seg.accel == 0 else math.copysign(math.inf, seg.accel)
        for v in (seg.velocity, end):
            if (forward and v > 0) or (reverse and v < 0):
                return True
    return False
