"""Trippoints: commands that hold their ``:`` (or their thread) until something happens.

``AM`` (profile complete), ``MC`` (motor in position, or ``TW`` samples after the profile
ended: stop code 99 and ``#MCTIME``), ``AD`` (distance from the move's start), ``AR``
(distance from the last ``AD``/``AR`` of the same move), ``AP`` (the encoder crosses a
position), ``AS`` (the profile is at its slew speed, or its speed moves away from it), ``MF``
and ``MR`` (the encoder crosses a position forwards, backwards; decision 0042), ``AV`` (path
distance of a coordinated sequence from its start or the last ``AV``), ``WT`` (time; ``WT n,1``
in samples), ``AT`` (time from the thread's reference; decision 0037) and ``WC`` (the
previous contour segment is done: at most the running one is left).
Each returns a :class:`~galil.sim.registry.Wait`; the servo loop releases it at the exact
sample its condition turns true. Choices where the command reference is silent are in
decision 0029: distances are magnitudes (``AR -500`` is 500 counts, as ``AD`` takes them),
every trippoint also releases when the motion it watches is over, ``AP`` on several axes
waits for all of them. ``MF``/``MR`` are the exception the reference makes: they watch the
encoder alone, release on the first of their axes to cross, and never for a move's end.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from galil.models import INT32_MAX, INT32_MIN
from galil.predict.engine import ramping
from galil.sim.driven import DrivenProfiler
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.programs import Thread
from galil.sim.registry import Args, OperandKind, Wait, handler, operand
from galil.sim.rooms.contour import Contour
from galil.sim.rooms.motion import Motion
from galil.sim.rooms.vector import Vector
from galil.sim.servo import Axis, Servo, turns_back

__all__ = ["TW_DEFAULT", "Trippoints"]

#: TW's default (DMC-4103 command reference: -1 .. 32,767, default 32,766). Counted in servo
#: samples: TM's "NOT automatically scaled" list names TW (decision 0042).
TW_DEFAULT = 32766.0
#: WT's n0 ("WT   Wait": Min 2, Max 2,147,483,646, resolution 2).
WT_MIN, WT_MAX = 2, INT32_MAX - 1


@dataclass(eq=False)
class _Crossing:
    """What ``MF`` (``direction`` 1) or ``MR`` (-1) waits for: the encoder of one of the axes
    of ``goal`` crossing its position in that direction.

    An axis is armed once its encoder has been on the near side of its position (below it for
    ``MF``) at a step boundary since the command; an armed axis at or past its position
    releases the wait. The arming happens only where a step is final (:meth:`arm`, from the
    room's ``service`` and the step's ``cut``), never inside a bisection's probe.
    """

    servo: Servo
    goal: dict[str, float]
    direction: int
    armed: set[str] = field(default_factory=set)

    def arm(self) -> None:
        for c, p in self.goal.items():
            if (self.servo.axes[c].m.encoder - p) * self.direction < 0:
                self.armed.add(c)

    def crossed(self) -> bool:
        axes = self.servo.axes
        return any((axes[c].m.encoder - self.goal[c]) * self.direction >= 0 for c in self.armed)

    def cut(self, k: int) -> int:
        """End the step at the first sample an axis arms or an armed one gets to its position
        (the encoder's preview): the watch turns true at most once in a step."""
        self.arm()
        for c, p in self.goal.items():
            m = self.servo.axes[c].m
            if not m.motor_on or (not m.moving and m.actual == m.profiler.position):
                continue  # the encoder stays where it is
            past = (m.preview_encoder(k) - p) * self.direction >= 0
            hits = np.flatnonzero(past if c in self.armed else ~past)
            if hits.size:
                k = min(k, int(hits[0]) + 1)
        return k


class Trippoints(Room):
    """AM, MC (and TW), AD, AR, AP, AS, MF, MR, AV, WT, AT and WC."""

    requires = (Motion, Contour, Vector)

    def reset(self) -> None:
        axes = self.machine.spec.axes
        self.tw = dict.fromkeys(axes, TW_DEFAULT)
        #: The sample each axis's profile last completed (MC's timeout counts from there).
        self.done_at = dict.fromkeys(axes, 0)
        self._moving = [False] * len(axes)  # each axis's profiler moving, at the last look
        # Per axis: (the move, by Motion's count of BGs; the distance its last AD/AR reached).
        self._relative: dict[str, tuple[int, float]] = {}
        # Per plane: (the sequence, by Vector's count of starts; the distance of the last AV).
        self._vector: dict[str, tuple[int, float]] = {}
        # MF/MR waits a thread holds (or has put on its stack), and the waits themselves.
        self._crossings: list[tuple[Wait, _Crossing]] = []

    def service(self) -> None:
        if self._crossings:
            self._arm_crossings()
        # At every step of the servo loop: one pass over the flags, more only on a change.
        axes = self.machine.servo.axes
        moving = [ax.m.profiler.moving for ax in axes.values()]
        if moving != self._moving:
            now = self.machine.servo.sample
            for c, was, still in zip(axes, self._moving, moving, strict=True):
                if was and not still:
                    self.done_at[c] = now
            self._moving = moving

    @handler("AM", Args.AXES)
    def am(self, axes: list[Axis]) -> Wait:
        all_axes = self.machine.servo.axes
        letters = [ax.letter for ax in axes]

        def exact() -> bool:
            # A profile's end is a step boundary (see Servo); a jog without a stop never ends.
            for c in letters:
                prof = all_axes[c].m.profiler
                if prof.moving and prof.end_sample is None and prof.mode != "jog":
                    return False
            return True

        return Wait(lambda: not any(all_axes[c].m.moving for c in letters), exact=exact)

    @handler("AM", Args.PLANES_AND_AXES)
    def am_planes(self, letters: list[str]) -> Wait:
        """``AM S``, ``AM ST``, and planes with axes (``AM SA``; the AM entry: "Any
        combination of axes or a motion sequence may be specified", its mask the axes and
        S, T): released when every sequence named and every axis named is done (decision
        0048)."""
        vector = self.machine.room(Vector)
        chosen = [vector.planes[c] for c in letters if c in vector.planes]
        named = "".join(c for c in letters if c not in vector.planes)
        axes = self.am(self.machine.interp.axis_list(named)) if named else None

        def done() -> bool:
            if any(vector.busy(plane) for plane in chosen):
                return False
            return axes is None or axes.predicate is None or axes.predicate()

        return Wait(done)

    def _samples(self, ms: float) -> int:
        """The whole servo samples ``ms`` milliseconds take at the TM in force (rounded up:
        WT and AT hold at least that long). WT and AT are "Scaled By TM": ms of real time, a
        sample being TM / 1,024,000 s (decision 0042)."""
        return math.ceil(ms / 1000 / self.machine.servo.ts - 1e-9)

    # ---- MC and its timeout ------------------------------------------------------------
    def _tw_samples(self, letter: str) -> int | None:
        # TW is not scaled by TM (TM's list; decision 0042): TW n is n servo samples.
        n = self.tw[letter]
        return None if n < 0 else int(n)

    def _late(self, letters: list[str]) -> list[str]:
        """The axes of ``letters`` whose profile ended ``TW`` ago without reaching position."""
        servo = self.machine.servo
        out = []
        for c in letters:
            m, n = servo.axes[c].m, self._tw_samples(c)
            due = n is not None and servo.sample >= self.done_at[c] + n
            if due and not m.moving and not m.in_position:
                out.append(c)
        return out

    @handler("MC", Args.AXES)
    def mc(self, axes: list[Axis]) -> Wait:
        servo = self.machine.servo
        all_axes = servo.axes
        letters = [ax.letter for ax in axes]

        def exact() -> bool:
            # An axis still running a profile with a known end is not in position before
            # that end, which is a step boundary (see Servo): no need to bisect the step.
            for c in letters:
                m = all_axes[c].m
                if m.motor_on and m.profiler.moving and m.profiler.end_sample is not None:
                    return True
            return False

        def cut(k: int) -> int:
            # The step ends where a timeout is due (an event at a known sample).
            for c in letters:
                m, n = all_axes[c].m, self._tw_samples(c)
                if n is not None and not m.moving and not m.in_position:
                    due = self.done_at[c] + n - servo.sample
                    if due > 0:
                        k = min(k, due)
            return k

        def done() -> bool:
            return all(all_axes[c].m.in_position for c in letters) or bool(self._late(letters))

        return Wait(done, exact=exact, cut=cut, then=lambda: self._timed_out(letters))

    def _timed_out(self, letters: list[str]) -> str:
        """On MC's release: a timeout sets stop code 99 and runs ``#MCTIME`` (a program
        running)."""
        late = self._late(letters)
        if late:
            for c in late:
                prof = self.machine.servo.axes[c].m.profiler
                if not isinstance(prof, DrivenProfiler):
                    prof.stop_code = 99
            if self.machine.programs.threads:
                self.machine.programs.interrupt("MCTIME")
        return ""

    @handler("TW", Args.VALUES)
    def tw_command(self, fields: list[tuple[Axis, str]]) -> str:
        def check(ax: Axis, v: float) -> float:
            if v != int(v) or not -1 <= v <= 32767:
                raise Refused(6, "TW is -1 to 32767 ms")
            return v

        def apply(ax: Axis, v: float) -> None:
            self.tw[ax.letter] = v

        i = self.machine.interp
        return i.parameters(fields, self.timeout, check, apply, lambda v: i.num(v, "5.0"))

    @operand("TW", kind=OperandKind.AXIS)
    def timeout(self, ax: Axis) -> float:
        return self.tw[ax.letter]

    # ---- distances ---------------------------------------------------------------------
    @handler("AD")
    def ad(self, args: str) -> Wait:
        """Hold until each named axis's profile has gone the distance from the move's start.

        Like the controller, AD watches the profiler (before IT smoothing); distances are
        magnitudes, and a move that ends first releases the wait.
        """
        goal = self._distances(args, "AD")
        motion = self.machine.room(Motion)
        for c, d in goal.items():
            self._relative[c] = (motion.axes[c].starts, d)
        return self._after_distance(goal)

    @handler("AR")
    def ar(self, args: str) -> Wait:
        """Hold until each named axis has gone the distance from where the last AD or AR of
        the same move was to trip (from the move's start if there was none)."""
        step = self._distances(args, "AR")
        motion = self.machine.room(Motion)
        goal: dict[str, float] = {}
        for c, d in step.items():
            move = motion.axes[c].starts
            last_move, reached = self._relative.get(c, (-1, 0.0))
            goal[c] = (reached if last_move == move else 0.0) + d
        for c, g in goal.items():
            self._relative[c] = (motion.axes[c].starts, g)
        return self._after_distance(goal)

    def _after_distance(self, goal: dict[str, float]) -> Wait:
        all_axes = self.machine.servo.axes
        motion = self.machine.room(Motion)

        def reached() -> bool:
            for c, d in goal.items():
                prof = all_axes[c].m.profiler
                if prof.moving and abs(prof.position - motion.axes[c].move_start) < d:
                    return False
            return True

        return Wait(reached, cut=self._one_way(list(goal)))

    def _one_way(self, letters: list[str]) -> Callable[[int], int]:
        all_axes = self.machine.servo.axes

        def cut(k: int) -> int:
            # A distance or a position turns non-monotone where an axis turns back (a jog
            # reversed): a step ends there, so the bisection finds the first sample it trips.
            for c in letters:
                k = turns_back(all_axes[c].m.profiler, k)
            return k

        return cut

    def _values(self, args: str, command: str) -> dict[str, float]:
        """``n,n,...`` by axis position or ``AB=n``: axis letter -> value."""
        i = self.machine.interp
        fields = split_fields(args.partition("=")[2] if "=" in args else args)
        if "=" in args:
            letters = [i.axis(c).letter for c in args.partition("=")[0].strip()]
            values = [i.evaluate(fields[0])] * len(letters)
        else:
            axes = self.machine.servo.axes
            letters = [a for a, f in zip(axes, fields, strict=False) if f.strip()]
            values = [i.evaluate(f) for f in fields if f.strip()]
        if not letters:
            raise Refused(4, f"{command} needs a value")
        return dict(zip(letters, values, strict=True))

    def _distances(self, args: str, command: str) -> dict[str, float]:
        goal = self._values(args, command)
        for c, v in goal.items():
            if not (0 if command == "AD" else INT32_MIN) <= v <= INT32_MAX:
                raise Refused(6, f"{command} distance out of range")
            goal[c] = abs(v)
        return goal

    # ---- AP: the encoder crosses a position --------------------------------------------
    @handler("AP")
    def ap(self, args: str) -> Wait:
        """Hold until each named axis's encoder has crossed its position, its profile is
        complete, or it moves away from the position."""
        goal = self._positions(args, "AP")
        all_axes = self.machine.servo.axes
        side: dict[str, int] = {}
        for c, p in goal.items():
            enc = all_axes[c].m.encoder
            side[c] = (p > enc) - (p < enc)

        def reached() -> bool:
            for c, p in goal.items():
                m = all_axes[c].m
                s = side[c]
                if s == 0 or not m.moving or (m.encoder - p) * s >= 0:
                    continue
                if m.profiler.velocity * s < 0:
                    continue  # moving away from it
                return False
            return True

        return Wait(reached, cut=self._one_way(list(goal)))

    def _positions(self, args: str, command: str) -> dict[str, float]:
        goal = self._values(args, command)
        if not all(INT32_MIN <= p <= INT32_MAX for p in goal.values()):
            raise Refused(6, f"{command} position out of range")
        return goal

    # ---- MF, MR: the encoder crosses a position forwards, backwards --------------------
    @handler("MF")
    def mf(self, args: str) -> Wait:
        """Hold until one of the named axes' encoders moves forward across its position."""
        return self._crossing(self._positions(args, "MF"), 1)

    @handler("MR")
    def mr(self, args: str) -> Wait:
        """Hold until one of the named axes' encoders moves backward across its position."""
        return self._crossing(self._positions(args, "MR"), -1)

    def _crossing(self, goal: dict[str, float], direction: int) -> Wait:
        crossing = _Crossing(self.machine.servo, goal, direction)
        crossing.arm()
        wait = Wait(crossing.crossed, cut=crossing.cut)
        self._crossings.append((wait, crossing))
        return wait

    def _arm_crossings(self) -> None:
        """Arm the MF/MR waits at a step boundary; forget those no thread holds any more."""
        held: set[int] = set()
        for th in self.machine.programs.threads.values():
            held.add(id(th.wait))
            held.update(id(f.wait) for f in th.stack)
        self._crossings = [(w, x) for w, x in self._crossings if id(w) in held]
        for _, crossing in self._crossings:
            crossing.arm()

    # ---- AS: at slew speed ----------------------------------------------------------------
    @handler("AS")
    def at_speed(self, args: str) -> Wait:
        """Hold until each named axis's profile (each plane's path, ``S``/``T``) has reached
        its slew speed, or its speed has begun to move away from it (a triangle's peak, a
        stop); an axis at rest or driven by a sequence or a master does not hold it."""
        letters = args.replace(" ", "").replace(",", "")
        axes: list[str] = []
        planes: list[str] = []
        for c in letters or self.machine.servo.axes:
            if c in "ST":
                planes.append(c)
            else:
                axes.append(self.machine.interp.axis(c).letter)
        all_axes = self.machine.servo.axes
        vector = self.machine.room(Vector)

        def reached() -> bool:
            if any(ramping(all_axes[c].m.profiler) for c in axes):
                return False
            for p in planes:
                feed = vector.feed(vector.planes[p])
                if feed is not None and feed.eng.ramping:
                    return False
            return True

        return Wait(reached)

    # ---- AV: path distance of a coordinated sequence -----------------------------------
    @handler("AV")
    def av(self, args: str) -> Wait:
        vector = self.machine.room(Vector)
        fields = split_fields(args) if args.strip() else ["0"]
        if len(fields) > 2:
            raise Refused(6, "AV takes S and T distances")
        goal: dict[str, float] = {}
        for letter, text in zip("ST", fields, strict=False):
            if not text.strip():
                continue
            v = self.machine.interp.evaluate(text)
            if not 0 <= v <= INT32_MAX:
                raise Refused(6, "AV distance out of range")
            starts = vector.planes[letter].starts
            last, gone = self._vector.get(letter, (-1, 0.0))
            goal[letter] = (gone if last == starts else 0.0) + v
        for letter, g in goal.items():
            self._vector[letter] = (vector.planes[letter].starts, g)

        def reached() -> bool:
            for letter, g in goal.items():
                plane = vector.planes[letter]
                feed = vector.feed(plane)
                if feed is not None and vector.busy(plane) and feed.eng.distance < g:
                    return False
            return True

        return Wait(reached)

    # ---- time and contour ---------------------------------------------------------------
    @handler("WT")
    def wt(self, args: str) -> Wait:
        """``WT n0[,n1]``: hold the thread n0 ms (n1 = 1: n0 samples). The reference gives n0
        as 2 .. 2,147,483,646 and n1 as 0 or 1; anything else is TC 6 (decision 0051). Its
        resolution of 2 is not enforced: an odd n0 waits n0 ms, rounded up to samples."""
        i = self.machine.interp
        fields = split_fields(args)
        ms = i.evaluate(fields[0]) if fields[0].strip() else 0.0
        unit = i.evaluate(fields[1]) if len(fields) > 1 and fields[1].strip() else 0.0
        if len(fields) > 2 or unit not in (0, 1) or not WT_MIN <= ms <= WT_MAX:
            raise Refused(6, f"WT n0 is {WT_MIN} .. {WT_MAX}, n1 0 (ms) or 1 (samples)")
        n = round(ms) if unit else self._samples(ms)
        return Wait(wake=self.machine.servo.sample + n)

    @handler("AT")
    def at(self, args: str) -> Wait | str:
        """``AT n[,1]``: hold the thread until n ms (samples with ``,1``) after its reference
        time. ``AT 0`` sets the reference to now; ``AT -n`` waits for ``|n|`` and, once that
        has passed, moves the reference on by ``|n|`` (a loop paced by it does not drift)."""
        th = self.machine.interp.caller
        if not isinstance(th, Thread):
            raise Refused(2, "AT only in a program")
        servo = self.machine.servo
        i = self.machine.interp
        fields = split_fields(args)
        n = i.evaluate(fields[0]) if fields[0].strip() else 0.0
        unit = i.evaluate(fields[1]) if len(fields) > 1 and fields[1].strip() else 0.0
        if len(fields) > 2 or unit not in (0, 1) or not INT32_MIN <= n <= INT32_MAX:
            raise Refused(6, "AT n0 (ms or samples), n1 0 or 1")
        if n == 0:
            th.at = servo.sample
            return ""
        k = round(abs(n)) if unit else self._samples(abs(n))
        due = th.at + k

        def moved() -> str:
            th.at = due
            return ""

        return Wait(wake=due, then=moved if n < 0 else None)

    @handler("WC")
    def wc(self, args: str) -> Wait:
        contour = self.machine.room(Contour)
        return Wait(lambda: all(ax.m.profiler.queued_segments <= 1 for ax in contour.axes()))
