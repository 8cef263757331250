"""Trippoints: commands that hold their ``:`` (or their thread) until something happens.

``AM`` (profile complete), ``MC`` (motor in position), ``AD`` (distance from the move's start),
``WT`` (time; ``WT n,1`` in samples) and ``WC`` (the previous contour segment is done: at most
the running one is left). Each returns a :class:`~galil.sim.registry.Wait`; the servo loop
releases it at the exact sample its condition turns true.
"""

from __future__ import annotations

import math

from galil.models import INT32_MAX
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import Args, Wait, handler
from galil.sim.rooms.contour import Contour
from galil.sim.rooms.motion import Motion
from galil.sim.servo import Axis, turns_back

__all__ = ["Trippoints"]


class Trippoints(Room):
    """AM, MC, AD, WT and WC."""

    requires = (Motion, Contour)

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

    @handler("MC", Args.AXES)
    def mc(self, axes: list[Axis]) -> Wait:
        all_axes = self.machine.servo.axes
        letters = [ax.letter for ax in axes]

        def exact() -> bool:
            # An axis still running a profile with a known end is not in position before
            # that end, which is a step boundary (see Servo): no need to bisect the step.
            for c in letters:
                m = all_axes[c].m
                if m.motor_on and m.profiler.moving and m.profiler.end_sample is not None:
                    return True
            return False

        return Wait(lambda: all(all_axes[c].m.in_position for c in letters), exact=exact)

    @handler("AD")
    def ad(self, args: str) -> Wait:
        """Hold until each named axis's profile has gone the distance from the move's start.

        Like the controller, AD watches the profiler (before IT smoothing); distances are
        magnitudes, and a move that ends first releases the wait.
        """
        goal = self._distances(args)
        all_axes = self.machine.servo.axes
        motion = self.machine.room(Motion)

        def reached() -> bool:
            for c, d in goal.items():
                ax = all_axes[c]
                prof = ax.m.profiler
                if prof.moving and abs(prof.position - motion.axes[c].move_start) < d:
                    return False
            return True

        def cut(k: int) -> int:
            # The distance turns non-monotone where an axis turns back (a jog reversed): a
            # step ends there, so the bisection finds the first sample it is reached.
            for c in goal:
                k = turns_back(all_axes[c].m.profiler, k)
            return k

        return Wait(reached, cut=cut)

    def _distances(self, args: str) -> dict[str, float]:
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
            raise Refused(4, "AD needs a distance")
        goal: dict[str, float] = {}
        for c, v in zip(letters, values, strict=True):
            if not 0 <= v <= INT32_MAX:
                raise Refused(6, "AD distance out of range")
            goal[c] = v
        return goal

    @handler("WT")
    def wt(self, args: str) -> Wait:
        servo = self.machine.servo
        fields = split_fields(args)
        ms = self.machine.interp.evaluate(fields[0]) if fields[0].strip() else -1
        if not 0 <= ms <= INT32_MAX:
            raise Refused(6, "WT out of range")
        samples = len(fields) > 1 and fields[1].strip() == "1"
        n = round(ms) if samples else math.ceil(ms / 1000 / servo.ts - 1e-9)
        return Wait(wake=servo.sample + n)

    @handler("WC")
    def wc(self, args: str) -> Wait:
        contour = self.machine.room(Contour)
        return Wait(lambda: all(ax.m.profiler.queued_segments <= 1 for ax in contour.axes()))
