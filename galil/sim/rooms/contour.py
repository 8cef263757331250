"""Contour mode: ``CM`` ``DT`` ``CD`` and the contour buffer (``_CM``).

Segments go to each contouring axis's profiler (``CD`` with ``DT n``: 2**n samples). A ``CD``
into a full buffer holds its ``:`` until there is room; ``CD 0=0`` (``DT 0`` then ``CD 0`` on
the models whose ``CD`` takes no ``=n``) ends the stream once the queue drains. ``DT -1``
(buffered models) holds every segment, and the end, until a positive ``DT``. A buffer that
runs dry while contouring (data sent too slowly) sets the error code to 42; the servo loop
watches for it so it happens at its exact sample.
"""

from __future__ import annotations

import functools

from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import Args, Result, Wait, handler, operand
from galil.sim.servo import Axis, Watch, engine

__all__ = ["Contour"]


class Contour(Room):
    """The contour buffer and the axes that run it."""

    def reset(self) -> None:
        self.exponent = 1  # DT: segments of 2**n samples (-1: held, see :meth:`dt`)
        self.fed: set[str] = set()  # contouring axes given segments: an empty queue is an error
        self._active = False  # some axis may be in contour mode: the service hook has work
        # Segments received under DT -1: (increments by axis, own DT or None), oldest first.
        self.held: list[tuple[dict[str, int], int | None]] = []

    def axes(self) -> list[Axis]:
        """The axes in contour mode."""
        return [ax for ax in self.machine.servo.axes.values() if ax.contour]

    def free(self) -> int:
        """Free places in the contour buffer (``_CM``): the segment running takes none."""
        waiting = max((ax.m.profiler.queued_segments for ax in self.axes()), default=0)
        return self.machine.spec.contour_buffer - max(0, waiting - 1) - len(self.held)

    # ---- hooks -------------------------------------------------------------------------
    def abort(self) -> None:
        for ax in self.machine.servo.axes.values():
            ax.contour = False
        self.fed.clear()
        self.held.clear()
        self._active = False

    def watches(self, out: list[Watch]) -> None:
        if self.fed:
            for ax in self.machine.servo.axes.values():
                if ax.contour and ax.letter in self.fed:
                    out.append(functools.partial(_ran_dry, ax.letter, self.machine.servo.axes))

    def service(self) -> None:
        if not self._active:
            return
        active = False
        for ax in self.machine.servo.axes.values():
            if not ax.contour:
                continue
            active = True
            prof = ax.m.profiler
            if prof.mode != "contour":
                ax.contour = False
                self.fed.discard(ax.letter)
            elif ax.letter in self.fed and prof.queued_segments == 0:
                self.fed.discard(ax.letter)
                self.machine.interp.tc = 42  # the buffer ran dry: data sent too slowly
        self._active = active

    # ---- commands ----------------------------------------------------------------------
    @handler("CM", Args.AXES)
    def cm(self, axes: list[Axis]) -> str:
        for ax in axes:
            if ax.m.moving and not ax.contour:
                raise Refused(7, "CM while moving")
        if not any(ax.m.profiler.queued_segments for ax in self.axes()):
            # "Issuing the CM command will clear the contour buffer when contour mode is not
            # running" (DMC-4103 reference, CM): segments held under DT -1 are dropped.
            self.held.clear()
        for ax in axes:
            if not ax.contour:
                engine(ax.m.profiler.begin_contour)
                ax.contour = self._active = True
                ax.limit_stop = False  # (a new start: the limits watch it again)
                self.fed.discard(ax.letter)
        return ""

    @handler("DT")
    def dt(self, args: str) -> str:
        i = self.machine.interp
        a = args.strip()
        if a == "?":
            return i.num(self.exponent, "1.0") + "\r\n"
        value = i.evaluate(a)
        spec = self.machine.spec
        low, high = spec.dt_range
        held = value == -1 and spec.contour_preload
        if (value != 0 and not held and not low <= value <= high) or value != int(value):
            raise Refused(6, "DT out of range")
        self.exponent = int(value)
        if held:
            # DT -1 (40x0): segments are kept in the buffer and not run (preload or pause);
            # a running contour finishes what it has and waits, without running dry.
            self.fed.clear()
        elif value > 0 and self.held:
            held_segments, self.held = self.held, []
            for incs, own in held_segments:  # own 0 is the end of the stream
                self._run_segment(incs, int(value) if own is None else own)
        return ""

    @handler("CD", equals=True)
    def cd(self, args: str) -> Result:
        text, equals, dt_text = args.partition("=")
        if equals and not self.machine.spec.contour_dt_suffix:
            # The DMC-1500/1700/18x2 manuals know no "=n" (DT 0 then CD 0 ends contour mode);
            # refusing it as an unknown form is this simulator's assumption.
            raise Refused(1, "CD takes no =n on this model")
        incs, n = self._segment(text, dt_text)
        if not self.axes():
            raise Refused(8, "not in contour mode")
        if n == 0 and any(incs.values()):
            raise Refused(41, "increment with DT 0")
        low, high = self.machine.spec.dt_range
        if n not in (0, -1) and not low <= n <= high:
            raise Refused(41, "DT out of range")
        if n == -1 and dt_text.strip():
            # "t = -1: Pauses contour buffer at the segment with t=-1. Reissue DT to re-engage
            # contour mode" (DMC-4103 reference, CD; its example sends CD 0,0,0=-1). Taken as
            # DT -1 at that place in the stream; a pause that also moves is refused (the
            # reference shows only zeros: this simulator's assumption).
            if any(incs.values()):
                raise Refused(41, "CD =-1 with an increment")
            self.exponent = -1
            self.fed.clear()
            return ""
        held = self.exponent == -1
        # Under DT -1 every segment (and the end) waits until a positive DT; one without its
        # own DT takes that DT then.
        own = None if n == -1 else n

        def take() -> str:
            if not held and not self.axes():
                # A limit (or ST) ended the contour while this waited for room (decision 0041).
                raise Refused(8, "not in contour mode")
            if held:
                self.held.append((incs, own))
            else:
                self._run_segment(incs, n)
            return ""

        if (n == 0 and not held) or self.free() > 0:
            return take()
        return Wait(lambda: self.free() > 0, then=take)

    def _run_segment(self, incs: dict[str, int], n: int) -> None:
        """Give one segment of 2**n samples to every contouring axis's profiler (n = 0: the
        end of the stream, once the queue drains)."""
        for ax in self.axes():
            if n == 0:
                ax.m.profiler.end_contour()
                self.fed.discard(ax.letter)
            else:
                engine(functools.partial(ax.m.profiler.add_segment, incs.get(ax.letter, 0), n))
                self.fed.add(ax.letter)

    def _segment(self, text: str, dt_text: str) -> tuple[dict[str, int], int]:
        """The increments per axis and the DT exponent of a ``CD``."""
        i = self.machine.interp
        axes = self.machine.servo.axes
        fields = split_fields(text)
        if len(fields) > len(axes):
            raise Refused(4, "more fields than axes")
        n = int(i.evaluate(dt_text)) if dt_text.strip() else self.exponent
        incs: dict[str, int] = {}
        for ax, f in zip(axes.values(), fields, strict=False):
            value = i.evaluate(f) if f.strip() else 0.0
            lo, hi = self.machine.spec.cd_range
            if not lo <= value <= hi or value != int(value):
                raise Refused(41, "CD increment out of range")
            if value and not ax.contour:
                raise Refused(41, "axis is not in contour mode")
            incs[ax.letter] = int(value)
        return incs, n

    # ---- operands ----------------------------------------------------------------------
    @operand("CM")
    def buffer_free(self) -> float:
        return self.free()

    @operand("DT")
    def default_exponent(self) -> float:
        return self.exponent


def _ran_dry(letter: str, axes: dict[str, Axis]) -> bool:
    return axes[letter].m.profiler.queued_segments == 0
