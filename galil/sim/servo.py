"""The servo loop: simulated time, the axes, and stepping them sample-exactly between events.

Every axis runs the one motion engine shared with the predictor
(:class:`galil.predict.engine.AxisProfiler`, inside :class:`~galil.sim.motion.AxisMotion`); the
loop only decides how many samples to run at once. Before each step it asks, in this order:

- where a known profile ends (a step ends there, so ``AM`` needs no bisection);
- the ``watch`` hooks, for conditions (a trippoint's, an emptied contour buffer); when one turns
  true inside a step, the loop bisects the step from a snapshot of the axes to find the exact
  sample where it fires;
- the ``horizon`` hooks, which cut the step before an event at a known sample (a thread's
  ``WT`` wakes, a ``DR`` record is due, a soft limit is crossed on the previewed path).

After each step the ``after_step`` hooks run (a soft limit reached starts its stop), and
``service`` runs at every step boundary (releases held replies, runs program threads).

State that rooms change with time must live in the axes (the snapshot covers only them) or be
recomputed in ``after_step``/``service``, which run once the step is final.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from galil.errors import CommandError, InvalidArgument
from galil.models import ModelSpec
from galil.predict.engine import AxisProfiler
from galil.sim.clock import Clock
from galil.sim.motion import AxisMotion
from galil.sim.parse import Refused

__all__ = ["MAX_CHUNK", "Axis", "Servo", "at_rest", "engine", "turns_back"]

#: Longest run of servo samples evaluated in one vectorised step.
MAX_CHUNK = 2048

Watch = Callable[[], bool]


@dataclass(eq=False)
class Axis:
    """One axis of the servo loop, and the status several rooms share.

    Attributes:
        letter: the axis letter.
        m: the servo-loop state (profiler, motor, encoder).
        contour: the axis is in contour mode (the contour room sets it; the others leave the
            axis alone while it is set).
        limit_stop: a limit (switch or soft limit) is stopping the axis; a new start clears it.
        origin: where encoder count 0 is in the machine's fixed frame (the frame switches are
            placed in); defining a position (DP, the end of HM/FI) moves it, motion does not.
        aux: a servo's auxiliary encoder (``TD``) minus its main encoder: ``DE`` sets it, and
            a redefinition of the main position (DP, HM, FI) keeps ``TD`` as it was.
        shift: a stepper's encoder (``TP``) minus its step count: its ``DP`` "will not effect
            the TP register value" (the DMC-4103 reference), its ``DE`` sets the encoder.
    """

    letter: str
    m: AxisMotion
    contour: bool = False
    limit_stop: bool = False
    origin: int = 0
    aux: int = 0
    shift: int = 0

    @property
    def physical(self) -> int:
        """The motor's position in the machine's fixed frame (encoder + origin), counts."""
        return self.m.encoder + self.origin


def engine(call: Callable[[], None]) -> None:
    """Run a command on an axis's profiler; its refusal becomes the controller's ``?``.

    Raises:
        Refused: with the engine's TC code (6 for a bad value).
    """
    try:
        call()
    except CommandError as e:
        raise Refused(e.code or 1, e.text) from None
    except InvalidArgument as e:
        raise Refused(6, str(e)) from None


def at_rest(command: str, then: Callable[[Axis, float], float]) -> Callable[[Axis, float], float]:
    """A value check for ``command`` that refuses it while the axis moves (TC 7, the
    reference's "Not Valid while in motion": PA, PR, DP, MT, BR ...), then checks with
    ``then``."""

    def check(ax: Axis, v: float) -> float:
        if ax.m.moving:
            raise Refused(7, f"{command} while moving")
        return then(ax, v)

    return check


def turns_back(prof: AxisProfiler, k: int) -> int:
    """How many of the next ``k`` samples ``prof`` runs before it first moves against the
    direction it sets out in (``k`` if it never does): a step that ends there keeps one
    direction, so a watch on the position turns true at most once in it."""
    if not prof.moving:
        return k
    v = prof.preview_velocity(k)
    ahead = np.flatnonzero(v)
    if ahead.size:
        back = np.flatnonzero(v * v[ahead[0]] < 0)
        if back.size:
            return int(back[0])
    return k


class Servo:
    """Simulated time and the axes, stepped sample by sample on the shared motion engine.

    Args:
        spec: the model (axes, TM facts).
        clock: where time comes from.
        lag: servo lag time constant (s) of new axes.
    """

    def __init__(self, spec: ModelSpec, clock: Clock, lag: float) -> None:
        self.spec = spec
        self.clock = clock
        self.lag = lag
        self.sample = 0
        self.tm = spec.tm_default
        self.ts = spec.sample_period
        self._time_base = clock.now()
        self._sample_base = 0
        self.axes: dict[str, Axis] = {}
        self._order: list[Axis] = []
        self.horizon_hooks: list[Callable[[int], int]] = []
        self.watch_hooks: list[Callable[[list[Watch]], None]] = []
        self.after_step_hooks: list[Callable[[], None]] = []
        self.service: Callable[[], None] = _nothing

    def reset(self) -> None:
        """Power-on TM and fresh axes at 0; time keeps running."""
        self.set_tm(self.spec.tm_default)
        self.axes = {
            letter: Axis(letter, AxisMotion(self.ts, 0, self.lag)) for letter in self.spec.axes
        }
        self.step_first(())

    def step_first(self, letters: Sequence[str]) -> None:
        """Step the axes ``letters`` before the others, in that order, at every step.

        An axis whose reference follows another axis's (a gear follower) reads that axis's
        preview of the step, so it must step before it: the room that couples them says so.
        """
        first = [self.axes[c] for c in letters]
        self._order = first + [ax for ax in self.axes.values() if ax not in first]

    # ---- time --------------------------------------------------------------------------
    def set_tm(self, tm: float) -> None:
        """Change the sample period; samples already run keep their times."""
        now = self.now()
        self.tm = tm
        self.ts = self.spec.sample_period_for(tm)
        self._time_base = now
        self._sample_base = self.sample

    def now(self) -> float:
        """Simulated time of the last sample run, in clock seconds."""
        return self._time_base + (self.sample - self._sample_base) * self.ts

    def sync(self) -> None:
        """Run the samples up to the clock's time.

        A program may change TM on the way: the run stops there, and the time left is
        counted again in samples of the new period.
        """
        while True:
            ts = self.ts
            elapsed = self.clock.now() - self._time_base
            target = self._sample_base + math.floor(elapsed / ts + 1e-9)
            if target <= self.sample:
                return
            self.run(target - self.sample, stop=functools.partial(self._period_changed, ts))
            if self.ts == ts:
                return

    def _period_changed(self, ts: float) -> bool:
        return self.ts != ts

    def reseat(self, ax: Axis, position: int) -> None:
        """Start a fresh servo loop for ``ax`` at ``position`` (DP, SH, TM)."""
        old = ax.m
        ax.origin += old.encoder - int(position)  # the motor stays where it is
        ax.aux += old.encoder - int(position)  # (and so does a servo's auxiliary encoder)
        ax.m = AxisMotion(self.ts, position, old.lag)
        ax.m.keep_trace(old)
        ax.m.motor_on = old.motor_on
        ax.m.profiler.stop_code = old.profiler.stop_code

    # ---- the loop ----------------------------------------------------------------------
    def run(self, n: int, stop: Callable[[], bool] | None = None) -> int:
        """Run ``n`` samples (events handled at their exact sample); return samples run.

        ``stop`` ends the run early, checked at every step boundary.
        """
        done = 0
        service = self.service
        service()
        while done < n:
            if stop is not None and stop():
                break
            k = self._profile_ends(min(n - done, MAX_CHUNK))
            # Watches are taken before the horizon hooks: a hook that previews a profile may
            # pin its end, which would turn a watch "exact" for a step not cut there.
            watches: list[Watch] = []
            for hook in self.watch_hooks:
                hook(watches)
            for cut in self.horizon_hooks:
                k = max(1, cut(k))
            done += self._step(k, watches)
            service()
        return done

    def _profile_ends(self, k: int) -> int:
        """Shorten a step to end where a profile ends (saves a bisection for AM)."""
        for ax in self.axes.values():
            prof = ax.m.profiler
            if prof.moving:
                end = prof.end_sample
                # A profiler counts its own samples (a reseated axis starts again at 0).
                if end is not None and 0 < end - prof.sample < k:
                    k = end - prof.sample
        return k

    def _step(self, n: int, watches: list[Watch]) -> int:
        """Advance ``n`` samples, or fewer when a watch fires first; return samples run."""
        if not watches:
            for ax in self._order:
                ax.m.step(n)
            self.sample += n
        else:
            n = self._bisect(n, watches)
        for after in self.after_step_hooks:
            after()
        return n

    def _bisect(self, k: int, watches: list[Watch]) -> int:
        """Run ``k`` samples; if a watch fires, stop at the first sample where it does."""
        snap = self._snapshot()
        self._advance(k)
        if not any(w() for w in watches):
            return k
        lo, hi = 0, k  # nothing fires after 0 samples; something fires after hi
        at = k  # where the axes are now
        while hi - lo > 1:
            mid = (lo + hi) // 2
            self._restore(snap)
            self._advance(mid)
            at = mid
            if any(w() for w in watches):
                hi = mid
            else:
                lo = mid
        if at != hi:
            # The last probe may have been a "not yet" one: go back to where it fires.
            self._restore(snap)
            self._advance(hi)
        return hi

    def _advance(self, n: int) -> None:
        for ax in self._order:
            ax.m.step(n)
        self.sample += n

    def _snapshot(self) -> tuple[int, dict[str, AxisMotion]]:
        # One memo for every axis: what several axes share (the sequence that drives the
        # axes of a vector plane) stays shared in the copy.
        memo: dict[int, object] = {}
        return self.sample, {k: copy.deepcopy(a.m, memo) for k, a in self.axes.items()}

    def _restore(self, snap: tuple[int, dict[str, AxisMotion]]) -> None:
        self.sample = snap[0]
        memo: dict[int, object] = {}
        for k, m in snap[1].items():
            self.axes[k].m = copy.deepcopy(m, memo)


def _nothing() -> None:
    return None
