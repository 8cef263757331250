"""Homing: HM, FE, FI and HV, run on the shared engine by the predictor's HomingSequence.

``HM``/``FE``/``FI`` arm the axis (Motion's ``next_mode``); ``BG`` starts the sequence through
Motion's mode table. The phases, their speeds and their stop codes are the predictor's
(:mod:`galil.predict.homing`): this room only tells the sequence what the switches say. The
switch and index positions are the :class:`~galil.sim.rooms.limits.Limits` room's, in the
machine's fixed frame; a watch ends a servo step at the exact sample the motor reaches an edge
or an index pulse. At the end of HM and FI the index becomes position 0 (``DP``), so the axis's
origin in the fixed frame moves there.

Status bits for the data record (40x0 user manual): b12 FE in progress, b11 HM in progress,
b10 first phase of HM done, b9 second phase done or FI in progress, b1 third phase of HM.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from galil.errors import LimitError
from galil.predict.checks import quantise_speed
from galil.predict.homing import HomeSwitch, HomingParams, HomingSequence
from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, handler, operand
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.motion import Motion
from galil.sim.rooms.tuning import Tuning
from galil.sim.servo import Axis, engine

__all__ = ["MODES", "Homing"]

#: Motion's ``next_mode`` for each command.
MODES = {"HM": "home", "FE": "edge", "FI": "index"}


class Homing(Room):
    """HM, FE, FI, HV and the sequences in progress."""

    requires = (Motion, Limits, Tuning)

    def reset(self) -> None:
        spec = self.machine.spec
        # No HV on the Optima-era cards: the slow stages at the firmware's own speed
        # (spec.home_slow_speed; the Optima HM page: 256 counts/s for a stepper).
        speed = spec.hv_default if spec.has_hv else spec.home_slow_speed
        self.hv = {letter: speed for letter in spec.axes}
        self.runs: dict[str, HomingSequence] = {}
        motion = self.machine.room(Motion)
        for kind, mode in MODES.items():
            motion.modes[mode] = (
                functools.partial(self._check, kind),
                functools.partial(self._start, kind),
            )

    def burn(self, name: str) -> object | None:
        return self.hv if name == "BN" else None  # (HV is in the BN table)

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, dict)
        self.hv = saved

    def abort(self) -> None:
        self.runs.clear()

    # ---- the geometry the sequence sees --------------------------------------------------
    def switch(self, ax: Axis) -> HomeSwitch:
        """The home switch and index of ``ax`` in the machine's fixed frame, as the home input
        follows them: the input TS reads (a switch the test holds has its edge out of reach;
        decision 0088)."""
        return self.machine.room(Limits).home_switch(ax.letter)

    def _params(self, ax: Axis) -> HomingParams:
        p = self.machine.room(Motion).params(ax)
        return HomingParams(
            speed=p.sp,
            accel=p.ac,
            decel=p.dc,
            home_speed=self.hv[ax.letter],
            jog_speed=p.jg,
            home_direction=1 if self.machine.room(Limits).cn[1] > 0 else -1,
            stepper=self.machine.room(Tuning).stepper(ax),
        )

    # ---- starting (Motion's BG calls these) ----------------------------------------------
    def _check(self, kind: str, ax: Axis) -> None:
        params = self._params(ax)
        if kind == "FI" and params.jog_speed == 0:
            raise Refused(6, "FI needs a JG speed")
        if kind != "FI" and params.speed <= 0:
            raise Refused(6, "SP is 0")
        if kind != "FE" and params.home_speed <= 0:
            raise Refused(6, "HV is 0")
        seq = HomingSequence(kind, ax.m.profiler, params, self.switch(ax), ax.origin)
        self.machine.room(Limits).check_start(ax, seq.direction(ax.physical))

    def _start(self, kind: str, ax: Axis) -> None:
        seq = HomingSequence(kind, ax.m.profiler, self._params(ax), self.switch(ax), ax.origin)
        engine(lambda: seq.start(ax.physical))
        self.runs[ax.letter] = seq

    # ---- servo-loop hooks ----------------------------------------------------------------
    def watches(self, out: list[Callable[[], bool]]) -> None:
        servo = self.machine.servo
        for letter, seq in self.runs.items():
            cross = seq.watch()
            ax = servo.axes[letter]
            if cross is not None and ax.m.moving:
                out.append(lambda ax=ax, cross=cross: cross.hit(ax.physical))  # type: ignore[misc]

    def service(self) -> None:
        if not self.runs:
            return
        servo = self.machine.servo
        for letter, seq in list(self.runs.items()):
            ax = servo.axes[letter]
            seq.prof = ax.m.profiler  # the servo loop may have replaced it (a bisection)
            switch = self.switch(ax)
            if seq.switch is not switch:  # (the test hook held, released or moved it)
                seq.rewire(switch, ax.physical)
            cross = seq.watch()
            if cross is not None and ax.m.moving:
                if cross.hit(ax.physical):
                    seq.fire(ax.physical)
            elif not ax.m.moving:
                seq.settle()
            if seq.done:
                del self.runs[letter]
                if seq.zero_at is not None and ax.m.profiler.stop_code == seq.code:
                    servo.reseat(ax, ax.m.reference - seq.zero_at)
                    self.machine.room(Motion).params(ax).pa = ax.m.reference

    # ---- what the record and TS show ----------------------------------------------------
    def status_bits(self, ax: Axis) -> int:
        """The homing bits of the axis status word."""
        seq = self.runs.get(ax.letter)
        if seq is None:
            return 0
        if seq.kind == "FE":
            return 0x1000
        if seq.kind == "FI":
            return 0x0200
        bits = 0x0800
        if seq.stage >= 2:
            bits |= 0x0400
        if seq.stage >= 3:
            bits |= 0x0200 | 0x0002
        return bits

    def fill_record(self, buf: npt.NDArray[np.void], letters: str) -> None:
        """OR the homing bits into the status word of each axis block of ``buf``."""
        if not self.runs:
            return
        axes = self.machine.servo.axes
        for c in letters:
            if c in self.runs:
                buf[c]["status"] |= self.status_bits(axes[c])

    # ---- commands ------------------------------------------------------------------------
    def _arm(self, kind: str, axes: list[Axis]) -> str:
        if any(ax.m.moving for ax in axes):
            raise Refused(7, f"{kind} while moving")
        motion = self.machine.room(Motion)
        for ax in axes:
            motion.params(ax).next_mode = MODES[kind]
        return ""

    @handler("HM", Args.AXES)
    def hm(self, axes: list[Axis]) -> str:
        return self._arm("HM", axes)

    @handler("FE", Args.AXES)
    def fe(self, axes: list[Axis]) -> str:
        return self._arm("FE", axes)

    @handler("FI", Args.AXES)
    def fi(self, axes: list[Axis]) -> str:
        return self._arm("FI", axes)

    @handler("HV", Args.VALUES)
    def hv_command(self, fields: list[tuple[Axis, str]]) -> str:
        self._refuse_without_hv()

        def check(ax: Axis, v: float) -> float:
            if v < 0:
                raise Refused(6, "negative speed")
            try:
                # (scaled by TM: stored in SP's step at the TM in force)
                return float(quantise_speed(v, self.machine.spec, tm=self.machine.servo.tm))
            except LimitError:
                raise Refused(6, "HV out of range") from None

        def apply(ax: Axis, v: float) -> None:
            self.hv[ax.letter] = v

        i = self.machine.interp
        return i.parameters(fields, self.home_speed, check, apply, lambda v: i.num(v, "10.0"))

    @operand("HV", kind=OperandKind.AXIS)
    def home_speed(self, ax: Axis) -> float:
        self._refuse_without_hv()
        return self.hv[ax.letter]

    def _refuse_without_hv(self) -> None:
        """A model without HV (``has_hv``) does not know it [U: TC 1, the code assumed]."""
        if not self.machine.spec.has_hv:
            raise Refused(1, "no HV on this model")
