"""One simulated axis in the servo loop: the shared profiler, a servo lag and a velocity filter.

The reference ``r``/``y`` comes from :class:`galil.predict.engine.AxisProfiler` (the one motion
engine, shared with the predictor). What the simulator adds is the plant: the encoder ``TP``
follows the reference through a first-order lag (time constant ``lag`` seconds), so the
profiler can be done (``AM``) before the motor is in position (``MC``), and ``TV`` reports the
encoder velocity averaged over 0.25 s as the manuals describe. Everything is evaluated over
whole chunks of samples with numpy.
"""

from __future__ import annotations

import copy
import functools
import math
import operator
from collections import deque

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.predict.engine import AxisProfiler
from galil.predict.smoothing import smooth

__all__ = ["TV_WINDOW_SECONDS", "AxisMotion"]

# Chunks up to this many samples run the servo lag as a scalar recursion.
_SCALAR_MAX = 48
# The longest tail of lag weights a long chunk's closed form uses.
_LAG_TAIL_MAX = 4096

#: The manuals' "special averaging filter (over approximately 0.25 sec)" for TV.
TV_WINDOW_SECONDS = 0.25


class AxisMotion:
    """The servo-loop state of one axis.

    Args:
        sample_period: seconds per servo sample.
        position: initial reference and encoder position, counts.
        lag: servo lag time constant in seconds (0 = the motor follows exactly).
    """

    def __init__(self, sample_period: float, position: int = 0, lag: float = 0.003) -> None:
        self.sample_period = sample_period
        self.profiler = AxisProfiler(sample_period=sample_period, position=int(position))
        self.actual = float(position)
        self.motor_on = True
        self._window = max(1, round(TV_WINDOW_SECONDS / sample_period))
        # Encoder positions of the last window + 1 samples (a deque: short chunks append cheaply).
        self._history: deque[float] = deque(
            [float(position)] * (self._window + 1), maxlen=self._window + 1
        )
        # Short chunks not yet expanded into _history: (lag state before, alpha, references).
        # Only TV reads the history, so a polling host's chunks are expanded when it asks
        # (and the ones the window has left behind never are).
        self._unexpanded: deque[
            tuple[float, float, list[int] | list[float] | npt.NDArray[np.int64]]
        ] = deque()
        self._unexpanded_n = 0
        self.lag = 0.0
        self._alpha = 1.0
        self.set_lag(lag)
        # Reference positions kept while a trace runs (the simulator's answer to RA/RD/RC).
        self._trace: list[npt.NDArray[np.int64]] | None = None

    def __deepcopy__(self, memo: dict[int, object]) -> AxisMotion:
        # The servo loop snapshots every axis before a step a watch may cut short; a generic
        # deep copy would copy every number in the histories one by one. What is shared here
        # is never changed in place (numbers, the chunks' reference lists, trace arrays).
        new = copy.copy(self)
        new.profiler = copy.deepcopy(self.profiler, memo)
        new._history = deque(self._history, maxlen=self._history.maxlen)
        new._unexpanded = deque(self._unexpanded)
        new._trace = None if self._trace is None else list(self._trace)
        return new

    def set_lag(self, lag: float) -> None:
        """Set the servo lag time constant in seconds (>= 0).

        Raises:
            InvalidArgument: negative or not finite.
        """
        if not math.isfinite(lag) or lag < 0.0:
            raise InvalidArgument(f"servo lag must be a finite number of seconds >= 0, not {lag!r}")
        self.lag = float(lag)
        # Exact discretisation of a first-order lag: a step is followed by 1 - exp(-Ts/tau).
        self._alpha = 1.0 if lag == 0.0 else -math.expm1(-self.sample_period / lag)

    @property
    def encoder(self) -> int:
        """``TP``: the encoder position in counts."""
        return round(self.actual)

    @property
    def reference(self) -> int:
        """``RP``: the reference position (after IT smoothing), counts."""
        return int(self.profiler.reference)

    @property
    def error(self) -> int:
        """``TE``: reference minus encoder, counts."""
        return self.reference - self.encoder

    @property
    def velocity(self) -> float:
        """``TV``: encoder velocity averaged over the last 0.25 s, counts/s."""
        if self._unexpanded:
            self._expand()
        span = self._history[-1] - self._history[0]
        return span / (self._window * self.sample_period)

    @property
    def moving(self) -> bool:
        """``_BG``: the profile is not complete."""
        return bool(self.profiler.moving)

    @property
    def in_position(self) -> bool:
        """Profile complete and the encoder on the reference (what ``MC`` waits for)."""
        if not self.motor_on:
            return True
        return not self.profiler.moving and self.encoder == self.reference

    def preview_encoder(self, n: int) -> npt.NDArray[np.int64]:
        """The encoder positions of the next ``n`` samples, without running them (what an
        axis geared to this one's encoder follows)."""
        refs = self.profiler.preview(n)
        if not self.motor_on:
            return np.full(refs.size, self.encoder, dtype=np.int64)
        if self._alpha >= 1.0:
            return refs
        out: npt.NDArray[np.int64] = np.rint(smooth(refs, self._alpha, self.actual)).astype(
            np.int64
        )
        return out

    def start_trace(self) -> None:
        """Start keeping every sample's reference position (drops an earlier trace)."""
        self._trace = [np.array([self.reference], dtype=np.int64)]

    def keep_trace(self, old: AxisMotion) -> None:
        """Go on with ``old``'s trace (a position was defined: the servo loop is new)."""
        self._trace = old._trace

    def stop_trace(self) -> npt.NDArray[np.int64]:
        """Stop tracing; return the reference positions since :meth:`start_trace`.

        The first value is the position when the trace started; one value per sample follows.
        """
        chunks, self._trace = self._trace or [np.zeros(0, dtype=np.int64)], None
        return np.concatenate(chunks)

    def advance(self, n: int) -> npt.NDArray[np.int64]:
        """Run ``n`` samples; return the reference positions of those samples."""
        ref = np.asarray(self.profiler.advance(n), dtype=np.int64)
        if self._trace is not None:
            self._trace.append(ref)
        if not self.motor_on:
            # No servo: the motor stays where it is.
            if self._unexpanded:
                self._expand()
            self._history.extend([float(round(self.actual))] * min(n, self._window + 1))
        elif n <= _SCALAR_MAX:
            self._follow(ref.tolist())
        else:
            self._follow_long(ref)
        return ref

    def step(self, n: int) -> None:
        """Run ``n`` samples, like :meth:`advance`, without handing the references back."""
        prof = self.profiler
        if (
            n > _SCALAR_MAX
            and self._trace is None
            and self.motor_on
            and not prof.moving
            and self.actual == prof.position
        ):
            # At rest, the motor on the reference: the lag's exact answer is that position at
            # every sample (its paged filter would give it within an ulp), and the profiler
            # only counts the samples. No arrays.
            prof.advance_values(n)
            still = [self.actual] * min(n, self._window + 1)
            if self._unexpanded:  # after chunks TV has not read yet: one more of them
                self._unexpanded.append((self.actual, 1.0, still))
                self._unexpanded_n += len(still)
                if self._unexpanded_n > 4 * self._window:
                    self._forget_old_chunks()
            else:
                self._history.extend(still)
            return
        if n > _SCALAR_MAX or self._trace is not None or not self.motor_on:
            self.advance(n)
            return
        self._follow(self.profiler.advance_values(n))

    def _follow(self, refs: list[int]) -> None:
        # A few samples (a host polling): the lag's closed form, a dot product in C, gives the
        # motor's position after the chunk; the per-sample encoder values wait for TV.
        alpha = self._alpha
        y0 = self.actual
        if alpha >= 1.0:
            self.actual = float(refs[-1]) if refs else y0
        else:
            carry, weights = _lag_weights(alpha, len(refs))
            self.actual = carry * y0 + sum(map(operator.mul, weights, refs))
        self._unexpanded.append((y0, alpha, refs))
        self._unexpanded_n += len(refs)
        if self._unexpanded_n > 4 * self._window:
            self._forget_old_chunks()

    def _follow_long(self, refs: npt.NDArray[np.int64]) -> None:
        # A long chunk: the lag's closed form over the samples whose weight is not lost in
        # rounding (a dot product), the encoder values for TV only when TV is read.
        alpha = self._alpha
        y0 = self.actual
        weights = _lag_tail(alpha) if alpha < 1.0 else None
        if weights is None:
            self.actual = float(refs[-1])
        elif refs.size > weights.size == _LAG_TAIL_MAX:
            # A lag slower than the tail covers: the paged filter over the whole chunk.
            self.actual = float(smooth(refs, alpha, y0)[-1])
        else:
            k = min(refs.size, weights.size)
            tail = refs[: -k - 1 : -1].astype(np.float64)  # newest first
            carry = (1.0 - alpha) ** refs.size
            self.actual = carry * y0 + float(np.dot(weights[:k], tail))
        self._unexpanded.append((y0, alpha, refs))
        self._unexpanded_n += refs.size
        if self._unexpanded_n > 4 * self._window:
            self._forget_old_chunks()

    def _forget_old_chunks(self) -> None:
        """Forget the chunks the TV window has left behind (called now and then, once more
        than four windows' samples wait: not at every chunk)."""
        keep = self._window + 1
        chunks = self._unexpanded
        left = self._unexpanded_n
        while left - len(chunks[0][2]) >= keep:
            left -= len(chunks.popleft()[2])
        self._unexpanded_n = left

    def _expand(self) -> None:
        """Put the encoder values of the chunks not yet expanded into the TV history, oldest
        first (a long chunk through the paged filter, its last window's values only)."""
        history = self._history
        keep = self._window + 1
        for y, alpha, refs in self._unexpanded:
            if isinstance(refs, np.ndarray):
                actual = refs.astype(np.float64) if alpha >= 1.0 else smooth(refs, alpha, y)
                history.extend(np.rint(actual[-keep:]).tolist())
            elif alpha >= 1.0:
                history.extend(refs)
            else:
                # round() is half to even, as numpy.rint
                history.extend([round(y := y + alpha * (r - y)) for r in refs])
        self._unexpanded.clear()
        self._unexpanded_n = 0


@functools.lru_cache(maxsize=64)
def _lag_tail(alpha: float) -> npt.NDArray[np.float64]:
    """``alpha * c**j`` for ``j = 0, 1, ...`` (``c = 1 - alpha``) while the weight still counts.

    The newest sample's weight first. Past the last one ``c**j`` is below ``2**-64``: a
    reference of up to ``2**31`` counts would move the sum by less than ``2**-33`` counts. A lag
    too slow for that within ``_LAG_TAIL_MAX`` samples gets no more (see ``_follow_long``).
    """
    c = 1.0 - alpha
    n = _LAG_TAIL_MAX
    if 0.0 < c < 1.0:
        n = min(n, math.ceil(-64.0 * math.log(2.0) / math.log(c)) + 1)
    elif c <= 0.0:
        n = 1
    out = alpha * c ** np.arange(n, dtype=np.float64)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=256)
def _lag_weights(alpha: float, n: int) -> tuple[float, list[float]]:
    """``(c**n, [alpha * c**(n-k) for k in 1..n])`` with ``c = 1 - alpha``.

    After ``n`` samples of ``y += alpha * (r - y)`` from ``y0``, ``y = c**n * y0 + sum(w * r)``.
    """
    c = 1.0 - alpha
    return c**n, [alpha * c ** (n - k) for k in range(1, n + 1)]
