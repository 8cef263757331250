"""Automatic subroutines and off-on-error: ``#LIMSWI``, ``#POSERR``, ``#ININT`` (``II``),
``RE``/``RI``, ``#AUTO``, and what ``OE`` does.

The routines run on thread 0 through :meth:`galil.sim.programs.Programs.interrupt` (``#MCTIME``
comes from ``MC`` in :mod:`~galil.sim.rooms.trippoints`, ``#CMDERR`` from the program core).
What sets them off (DMC-4103 command reference; decision 0029):

- ``#LIMSWI``: an axis is stopped by a limit switch or soft limit it moves towards, while a
  program runs;
- ``#POSERR``: an axis's position error ``|TE|`` grows beyond ``ER`` while a program runs
  (once each time it does). The simulated motor follows its reference through a servo lag, so
  the error is the lag's (about speed × lag): a small ``ER`` or a long lag reaches it. A step of
  the servo loop ends at the sample the error first exceeds ``ER`` (a preview of the step);
- ``#ININT``: the inputs ``II`` selects are all in the state it asks for (by default low); the
  interrupt is then off until ``RI`` (or a new ``II``);
- ``#AUTO``: ``RS`` starts it on thread 0 as ``XQ #AUTO`` would (see
  :mod:`~galil.sim.rooms.settings`; the simulator keeps the program over ``RS``).

``OE`` 1 or 3 turns the motor off (stop code 8 when it was profiling) when the error exceeds
``ER``, and at ``AB``; ``OE`` 2 or 3 turns it off instead of the controlled stop at a limit
*switch* (not a soft limit). A coordinated sequence or contour loses all its axes' motion.
"""

from __future__ import annotations

import numpy as np

from galil.sim.driven import DrivenProfiler
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.programs import Thread
from galil.sim.registry import handler
from galil.sim.rooms.io import IO
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.tuning import Tuning
from galil.sim.servo import Axis

__all__ = ["Automatic"]


class Automatic(Room):
    """II, RE, RI; the events that run automatic subroutines; OE."""

    requires = (IO, Limits, Tuning)

    def reset(self) -> None:
        #: II: (input list indices selected, the level each must be at); None while off.
        self.ii: tuple[list[int], list[bool]] | None = None
        self._armed = False
        self._limited: set[str] = set()  # axes seen stopped by a limit
        self._over: set[str] = set()  # axes seen beyond ER
        self._stops_seen = -1  # Limits.stops when service last looked at the axes
        self._limits = self.machine.room(Limits)
        self._tuning = self.machine.room(Tuning)

    # ---- commands ----------------------------------------------------------------------
    @handler("II")
    def ii_command(self, args: str) -> str:
        """II n0,n1,n2,n3: inputs n0..n1 (or mask n2) in the states of mask n3 run #ININT."""
        io = self.machine.room(IO)
        i = self.machine.interp
        fields = split_fields(args) if args.strip() else ["0"]
        if len(fields) > 4:
            raise Refused(6, "II takes four fields")
        v = [i.evaluate(f) if f.strip() else None for f in fields] + [None] * (4 - len(fields))
        if any(x is not None and (x != int(x) or not 0 <= x <= 255) for x in v):
            raise Refused(6, "II value out of range")
        if not v[0] and v[2] is None:
            self.ii, self._armed = None, False
            return ""
        if v[0]:
            low = int(v[0])
            high = int(v[1]) if v[1] is not None else low
            if high < low:
                raise Refused(6, "II n1 below n0")
            numbers = list(range(low, high + 1))
        else:
            numbers = [io.first + k for k in range(8) if int(v[2] or 0) >> k & 1]
        state = int(v[3] or 0)
        chosen = [io.channel(n, len(io.inputs)) for n in numbers]
        levels = [bool(state >> (n - io.first) & 1) for n in numbers]
        self.ii, self._armed = (chosen, levels), True
        self._check_inputs()
        return ""

    def _return(self, command: str, args: str) -> bool:
        """RE/RI n: return the calling thread (n = 1 restores the interrupted trippoint)."""
        caller = self.machine.interp.caller
        if not isinstance(caller, Thread):
            raise Refused(2, f"{command} only in a program")
        n = self.machine.interp.evaluate(args) if args.strip() else 0
        if n not in (0, 1):
            raise Refused(6, f"{command} takes 0 or 1")
        self.machine.programs.return_from(caller, restore=n == 1)
        return True

    @handler("RE")
    def re(self, args: str) -> str:
        self._return("RE", args)
        return ""

    @handler("RI")
    def ri(self, args: str) -> str:
        self._return("RI", args)
        if self.ii is not None:
            self._armed = True
        return ""

    # ---- events ------------------------------------------------------------------------
    def _poserr(self) -> bool:
        """Whether a program runs that has a ``#POSERR`` to run."""
        programs = self.machine.programs
        return bool(programs.threads) and "POSERR" in programs.labels

    def service(self) -> None:
        if self._armed:
            self._check_inputs()
        # This runs at every step of the servo loop: the axes are looked at only while an
        # event or its reset may be due (a limit stop since the last look, an axis stopped
        # or beyond ER before, or an error that matters); each check below is a no-op else.
        stops = self._limits.stops
        poserr = self._poserr()
        if not (
            self._limited
            or self._over
            or stops != self._stops_seen
            or poserr
            or self._tuning.off_on_error
        ):
            return
        self._stops_seen = stops
        tuning = self._tuning.axes
        for ax in self.machine.servo.axes.values():
            # (each check returns at once unless its event or its reset is due: skipped then,
            # as this runs at every step of the servo loop)
            c = ax.letter
            if ax.limit_stop or c in self._limited:
                self._check_limit(ax)
            if c in self._over or (
                (poserr or tuning[c].oe in (1, 3))
                and ax.m.motor_on
                and 0 <= tuning[c].er < abs(ax.m.error)
            ):
                self._check_error(ax)

    def _check_inputs(self) -> None:
        assert self.ii is not None
        inputs = self.machine.room(IO).inputs
        chosen, levels = self.ii
        if all(inputs[k] == want for k, want in zip(chosen, levels, strict=True)):
            self._armed = False
            self.machine.programs.interrupt("ININT")

    def _check_limit(self, ax: Axis) -> None:
        c = ax.letter
        if not ax.limit_stop:
            self._limited.discard(c)
            return
        if c in self._limited:
            return
        self._limited.add(c)
        code = ax.m.profiler.stop_code
        if self._oe(c) in (2, 3) and self._on_switch(ax, code):
            self._motor_off(ax, code)
        if self.machine.programs.threads:
            self.machine.programs.interrupt("LIMSWI")

    def _on_switch(self, ax: Axis, code: int) -> bool:
        limits = self.machine.room(Limits)
        return limits.halts(ax, "forward" if code == 2 else "reverse")

    def _error_limit(self, ax: Axis) -> float | None:
        """ER when the error matters (a #POSERR to run or OE 1/3), else None."""
        c = ax.letter
        if not ax.m.motor_on or c in self._over:
            return None
        watched = self._oe(c) in (1, 3) or self._poserr()
        er = self._tuning.axes[c].er
        # ER -1 (the DMC-41x3) "disables Error output": no error is beyond it.
        return er if watched and er >= 0 else None

    def _check_error(self, ax: Axis) -> None:
        c = ax.letter
        if c in self._over:
            if abs(ax.m.error) <= self.machine.room(Tuning).axes[c].er or not ax.m.motor_on:
                self._over.discard(c)
            return
        er = self._error_limit(ax)
        if er is None or abs(ax.m.error) <= er:
            return
        self._over.add(c)
        if self._oe(c) in (1, 3):
            self._motor_off(ax, 8)
        if self.machine.programs.threads:
            self.machine.programs.interrupt("POSERR")

    def horizon(self, k: int) -> int:
        """End the step at the first sample an axis's error exceeds ER (a preview)."""
        if not (self._tuning.off_on_error or self._poserr()):
            return k  # no error matters (what _error_limit says of every axis)
        for ax in self.machine.servo.axes.values():
            if not ax.m.moving:
                continue
            er = self._error_limit(ax)
            if er is None:
                continue
            m = ax.m
            error = m.profiler.preview(k) - m.preview_encoder(k)
            beyond = np.flatnonzero(np.abs(error) > er)
            if beyond.size:
                k = min(k, int(beyond[0]) + 1)
        return k

    # ---- off-on-error ------------------------------------------------------------------
    def _oe(self, letter: str) -> int:
        return int(self.machine.room(Tuning).axes[letter].oe)

    def _motor_off(self, ax: Axis, code: int) -> None:
        """Turn ``ax``'s motor off; its motion (a sequence's or contour's: all of it) stops
        at once with stop code ``code``."""
        prof = ax.m.profiler
        axes = self.machine.servo.axes.values()
        if isinstance(prof, DrivenProfiler):
            for other in axes:
                p = other.m.profiler
                if isinstance(p, DrivenProfiler) and p.source is prof.source and p.moving:
                    p.abort()
        elif ax.contour:
            for other in axes:
                if other.contour and other.m.moving:
                    other.m.profiler.halt(code)
        elif prof.moving:
            prof.halt(code)
        ax.m.motor_on = False

    def abort(self) -> None:
        for ax in self.machine.servo.axes.values():
            if self._oe(ax.letter) in (1, 3):
                ax.m.motor_on = False
