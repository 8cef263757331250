"""Results of a prediction: one axis (:class:`Profile`) or several on one time base."""

from __future__ import annotations

import html
import math
import numbers
import os
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast, overload

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument, decimal_hint, missing_extra
from galil.predict.quantities import is_quantity, seconds

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "MultiProfile",
    "Profile",
    "SampleSource",
    "check_figure_path",
    "shown_position",
    "together",
]

FloatArray = npt.NDArray[np.float64]
Int64Array = npt.NDArray[np.int64]

#: The fields a profile made by :meth:`Profile.planned` fills when one of them is first read.
_ARRAYS = ("t", "position", "velocity", "profiler")

_P = TypeVar("_P", bound="Profile")


class SampleSource(Protocol):
    """The reference positions of a profile, computed when they are first needed.

    ``start``, ``end`` and ``samples`` are known without computing them; ``bounds`` is a pair
    that every position lies within (not necessarily reached).
    """

    @property
    def start(self) -> int: ...

    @property
    def end(self) -> int: ...

    @property
    def samples(self) -> int: ...

    @property
    def bounds(self) -> tuple[int, int]: ...

    def __call__(self) -> Int64Array:
        """The positions at samples 0..N (int64)."""
        ...


def _moving_average(x: FloatArray, window: int) -> FloatArray:
    """Centred moving average with the ends averaged over what exists (a window longer than
    ``x`` is cut to it: ``np.convolve``'s "same" would return the window's length)."""
    window = min(window, x.size)
    if window <= 1:
        return np.asarray(x, dtype=np.float64)
    kernel = np.ones(window)
    total = np.convolve(x, kernel, mode="same")
    count = np.convolve(np.ones(x.size), kernel, mode="same")
    out: FloatArray = total / count
    return out


def _summary_rows(p: Profile) -> list[tuple[str, str]]:
    ends = f"{p.start} → {p.end} counts"
    peak = f"{p.peak_speed:.6g} counts/s"
    if p.display is not None:
        k, offset, unit = p.display
        ends = f"{offset + p.start / k:.6g} → {offset + p.end / k:.6g} {unit} ({ends})"
        peak = f"{p.peak_speed / abs(k):.6g} {unit}/s ({peak})"
    return [
        ("shape", p.shape),
        ("duration", f"{p.duration:.6g} s ({p.samples} samples)"),
        ("start → end", ends),
        ("peak speed", peak),
        ("sample period", f"{p.sample_period * 1e6:.6g} µs"),
    ]


class _Pending:
    """The arrays of planned profiles (one source, shared by their recast copies), computed
    once. Two threads reading at once may both compute them: the values are the same."""

    __slots__ = ("_arrays", "profiler", "source", "start_velocity")

    def __init__(
        self,
        source: SampleSource,
        profiler: Callable[[], Int64Array] | None = None,
        start_velocity: float = 0.0,
    ) -> None:
        self.source = source
        self.profiler = profiler
        self.start_velocity = start_velocity
        self._arrays: dict[str, Any] | None = None

    def arrays(self, sample_period: float) -> dict[str, Any]:
        if self._arrays is None:
            position = self.source()
            full = Profile.from_samples(
                position,
                profiler=None if self.profiler is None else self.profiler(),
                start_velocity=self.start_velocity,
                sample_period=sample_period,
                shape="",
                peak_speed=0.0,
            )
            self._arrays = {name: getattr(full, name) for name in _ARRAYS}
        return self._arrays


def finite_number(value: object, name: str) -> float:
    """``value`` as a float: a real number (not a bool) that is finite; an int no float holds
    (10**400) is refused rather than overflowing.

    Raises:
        InvalidArgument: naming ``name``; a pint Quantity too (it passes for a
            ``numbers.Real``, but the predictor has no scale to take its unit).
    """
    if is_quantity(value):
        raise InvalidArgument(
            f"{name} must be a plain number in galil.predict (it has no scale), not {value!r:.60}"
        )
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InvalidArgument(
            f"{name} must be a finite number, not {value!r:.60}{decimal_hint(value)}"
        )
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise InvalidArgument(f"{name} must be a finite number, not {value!r:.60}")
    return x


def shown_position(
    display: tuple[float, float, str] | None, counts: float | npt.NDArray[np.float64]
) -> float | npt.NDArray[np.float64]:
    """Counts as a position in a profile's display unit (:attr:`Profile.display`; counts
    themselves without one), rounded once: ``(counts + offset * k) / k``, as
    ``galil.units.Scale.counts_to_position`` computes it, so both read the same position."""
    if display is None:
        return counts
    k, offset, _ = display
    out: float | npt.NDArray[np.float64] = (counts + offset * k) / k
    return out


def check_figure_path(path: str, option: str = "png") -> None:
    """Refuse a file a plot cannot be saved to by its name, before anything runs: its
    extension must name a format matplotlib writes (``.png``, ``.svg``, ``.pdf``, ...; with
    none, matplotlib would add ``.png`` to the name).

    Raises:
        InvalidArgument: saying which formats there are (``option`` names the option).
        ModuleNotFoundError: matplotlib is missing (naming the extra that installs it).
    """
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError as exc:
        raise missing_extra(exc, f"--{option}") from exc

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = os.path.splitext(path)[1].lower().removeprefix(".")
    if suffix not in formats:
        what = "no extension" if not suffix else f"an unknown format {suffix!r}"
        raise InvalidArgument(
            f"--{option} {path!r} has {what}: name the file with one of "
            f"{', '.join('.' + f for f in sorted(formats))}"
        )


@dataclass(frozen=True, eq=False)
class Profile:
    """What the controller's profiler will command, one value per servo sample.

    Attributes:
        t: sample times in seconds from the start (``k * sample_period``), k = 0..N.
        position: the reference (after IT smoothing) at each sample, counts (int64).
        velocity: ``(position[k] - position[k-1]) / sample_period`` in counts/s;
            ``velocity[0]`` is the velocity at the start.
        duration: ``N * sample_period``: until the profiler has issued the final position.
        shape: ``"trapezoid"``, ``"triangle"``, ``"none"``, ``"jog"``, ``"contour"``,
            ``"changed"`` (re-planned in motion) or ``"stopped"``; also ``"schedule"``,
            ``"vector"`` (an axis of a sequence), ``"geared"`` (a follower) and ``"HM"``,
            ``"FE"``, ``"FI"`` (homing).
        peak_speed: largest |profiler velocity| (before rounding to counts), counts/s.
        sample_period: seconds per sample.
        profiler: the profiler position ``r`` before smoothing (what AD/AR trippoints watch);
            equal to ``position`` when IT is 1.
        stop_code: the stop code once the profile is over (1 done, 4 ST, 51 contour, ...).
        display: ``(counts_per_unit, offset, unit)`` for showing this profile in a user unit
            (plots and summaries only; every array stays in counts). ``counts_per_unit`` is
            negative when the axis's positive direction is the motor's negative one. Set by
            the axis layer on scaled axes; see :meth:`with_units`.
    """

    t: FloatArray
    position: Int64Array
    velocity: FloatArray
    duration: float
    shape: str
    peak_speed: float
    sample_period: float
    profiler: Int64Array = field(repr=False)
    stop_code: int = 1
    display: tuple[float, float, str] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for arr in (self.t, self.position, self.velocity, self.profiler):
            arr.setflags(write=False)

    @classmethod
    def planned(
        cls,
        source: SampleSource,
        *,
        sample_period: float,
        shape: str,
        peak_speed: float,
        stop_code: int = 1,
        profiler: Callable[[], Int64Array] | None = None,
        start_velocity: float = 0.0,
    ) -> Profile:
        """A profile whose arrays are computed from ``source`` when one is first read.

        Planning a move needs its duration, its ends and whether it stays within the soft
        limits (:meth:`bounds`), not every sample: a move that is only sent and waited for
        never computes them. Once computed they are exactly those of :meth:`from_samples`
        (``profiler``, called after ``source``, gives the profiler positions when they differ
        from the reference: IT smoothing).
        """
        new = object.__new__(cls)
        values = {
            "duration": source.samples * sample_period,
            "shape": shape,
            "peak_speed": float(peak_speed),
            "sample_period": float(sample_period),
            "stop_code": stop_code,
            "display": None,
            "_pending": _Pending(source, profiler, start_velocity),
        }
        new.__dict__.update(values)
        return new

    if not TYPE_CHECKING:  # hidden from type checkers: a typo must stay an error for them

        def __getattr__(self, name: str) -> Any:
            # Reached only for attributes not set: the arrays of a planned profile.
            pending = self.__dict__.get("_pending")
            if name in _ARRAYS and pending is not None:
                arrays = pending.arrays(self.sample_period)
                self.__dict__.update(arrays)
                return arrays[name]
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _source(self) -> SampleSource | None:
        """The source of a :meth:`planned` profile (``None`` for one built whole)."""
        pending = self.__dict__.get("_pending")
        return None if pending is None else pending.source

    def recast(self, cls: type[_P], **changes: object) -> _P:
        """This profile as an instance of ``cls`` (a subclass) with some fields changed.

        Arrays not computed yet stay so (:meth:`planned`), and once computed they are the
        same arrays in both: unlike ``dataclasses.replace``, nothing is read that the caller
        does not ask for.
        """
        new = object.__new__(cls)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        return new

    def bounds(self) -> tuple[int, int]:
        """Two positions every sample lies within: the lowest and highest for a profile
        built whole; for a :meth:`planned` one, a pair known without computing the samples."""
        source = self._source()
        if source is not None:
            low, high = source.bounds
            return int(low), int(high)
        return int(self.position.min()), int(self.position.max())

    @classmethod
    def from_samples(
        cls,
        reference: npt.ArrayLike,
        *,
        sample_period: float,
        shape: str,
        peak_speed: float,
        profiler: npt.ArrayLike | None = None,
        start_velocity: float = 0.0,
        stop_code: int = 1,
    ) -> Profile:
        """Build a profile from the reference positions r[0..N] (r[0] is the start)."""
        pos = np.asarray(reference, dtype=np.int64)
        if pos.ndim != 1 or pos.size == 0:
            raise InvalidArgument("a profile needs at least the start position")
        vel = np.empty(pos.size)
        vel[0] = start_velocity
        np.subtract(pos[1:], pos[:-1], out=vel[1:], casting="unsafe")
        vel[1:] *= 1.0 / sample_period
        raw = pos if profiler is None else np.asarray(profiler, dtype=np.int64)
        n = pos.size - 1
        t = np.arange(pos.size, dtype=np.float64)
        t *= float(sample_period)
        return cls(
            t=t,
            position=pos,
            velocity=vel,
            duration=n * sample_period,
            shape=shape,
            peak_speed=float(peak_speed),
            sample_period=float(sample_period),
            profiler=raw,
            stop_code=stop_code,
        )

    @property
    def samples(self) -> int:
        """N: the index of the last sample (the profile has N + 1 values)."""
        source = self._source()
        if source is not None:
            return int(source.samples)
        return int(self.position.size - 1)

    @property
    def start(self) -> int:
        """Position at sample 0."""
        source = self._source()
        if source is not None:
            return int(source.start)
        return int(self.position[0])

    @property
    def end(self) -> int:
        """Position at the last sample."""
        source = self._source()
        if source is not None:
            return int(source.end)
        return int(self.position[-1])

    @property
    def distance(self) -> int:
        """End minus start, counts."""
        return self.end - self.start

    @property
    def acceleration(self) -> FloatArray:
        """Per-sample change of velocity in counts/s² (first value 0)."""
        acc = np.zeros(self.velocity.size)
        acc[1:] = np.diff(self.velocity) / self.sample_period
        return acc

    def with_units(self, counts_per_unit: float, unit: str, offset: float = 0.0) -> Profile:
        """The same profile, shown in ``unit`` (``counts = (x - offset) * counts_per_unit``)."""
        counts_per_unit = finite_number(counts_per_unit, "counts_per_unit")
        offset = finite_number(offset, "offset")
        if not isinstance(unit, str):
            raise InvalidArgument(f"unit must be a string, not {unit!r:.60}")
        if not (math.isfinite(counts_per_unit) and counts_per_unit != 0):
            raise InvalidArgument(
                f"counts_per_unit must be finite and non-zero, not {counts_per_unit!r}"
            )
        if not math.isfinite(offset):
            raise InvalidArgument(f"offset must be finite, not {offset!r}")
        return self.recast(type(self), display=(float(counts_per_unit), float(offset), str(unit)))

    def _shown(self) -> tuple[float, float, str]:
        """(counts per shown unit, offset, unit name): counts themselves without a display."""
        return self.display if self.display is not None else (1.0, 0.0, "counts")

    @overload
    def at(self, t: float) -> float: ...
    @overload
    def at(self, t: npt.ArrayLike) -> float | npt.NDArray[np.float64]: ...
    def at(self, t: float | npt.ArrayLike) -> float | npt.NDArray[np.float64]:
        """Reference position at time(s) ``t`` (s), linearly interpolated between samples.

        Before 0 it is the start, after the end the final position. ``t`` may be a time
        Quantity (``250 * ureg.ms``, or an array of times), read in seconds.

        Raises:
            InvalidArgument: ``t`` is not a number of seconds (or an array of them), or is NaN;
                a Quantity that is not a time (``1 * ureg.mm``).
        """
        value = seconds(t, "t")
        if value is None or isinstance(value, (bool, np.bool_, str, bytes)):
            raise InvalidArgument(f"t must be seconds, not {t!r:.60}")
        try:
            times = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise InvalidArgument(f"t must be seconds, not {t!r:.60}") from None
        if np.isnan(times).any():
            raise InvalidArgument(f"t must not be NaN, got {t!r:.60}")
        out = np.interp(times, self.t, self.position)
        return float(out) if np.ndim(out) == 0 else out

    def plot(self, *, title: str | None = None, average: float = 0.004) -> Figure:
        """Plot position, velocity and acceleration against time; return the Figure.

        Positions are whole counts, so per-sample velocity jitters by a count per sample and its
        difference is noise; velocity and acceleration are therefore drawn as centred moving
        averages over ``average`` seconds (the raw velocity is shown faintly behind).
        matplotlib is imported here, not at import time (missing: a ModuleNotFoundError
        naming ``galil[jupyter]``).
        """
        try:
            from matplotlib.figure import Figure
        except ImportError as exc:
            raise missing_extra(exc, "Profile.plot()") from exc

        window = max(1, round(average / self.sample_period))
        vel = _moving_average(self.velocity, window)
        acc = np.zeros(vel.size)
        acc[1:] = np.diff(vel) / self.sample_period
        acc = _moving_average(acc, 4 * window)  # a difference of a difference: average longer
        k, offset, unit = self._shown()
        fig = Figure(figsize=(7, 6), layout="constrained")
        axes = fig.subplots(3, 1, sharex=True)
        axes[0].plot(self.t, offset + self.position / k, drawstyle="steps-post")
        axes[0].set_ylabel(f"position ({unit})")
        axes[1].plot(self.t, self.velocity / k, drawstyle="steps-post", color="0.8", linewidth=0.8)
        axes[1].plot(self.t, vel / k)
        axes[1].set_ylabel(f"velocity ({unit}/s)")
        axes[2].plot(self.t, acc / k)
        axes[2].set_ylabel(f"accel ({unit}/s²)")
        axes[2].set_xlabel("time (s)")
        for ax in axes:
            ax.grid(True, alpha=0.3)
        if window > 1:
            axes[1].set_title(f"{window}-sample moving average", fontsize="small", loc="right")
        moved = (
            f"{self.distance} counts" if self.display is None else f"{self.distance / k:.6g} {unit}"
        )
        fig.suptitle(title or f"{self.shape}: {moved} in {self.duration:.4g} s")
        return fig

    def _repr_html_(self) -> str:
        rows = "".join(
            f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
            for k, v in _summary_rows(self)
        )
        return f"<table><caption>Profile</caption>{rows}</table>"

    def _repr_pretty_(self, p: Any, cycle: bool) -> None:
        if cycle:
            p.text("Profile(...)")
            return
        body = ", ".join(f"{k}={v}" for k, v in _summary_rows(self))
        p.text(f"Profile({body})")

    def __str__(self) -> str:
        # print(profile): the summary, in the display unit when there is one.
        body = ", ".join(f"{k} {v}" for k, v in _summary_rows(self))
        return f"Profile: {body}"

    def __repr__(self) -> str:
        return (
            f"Profile(shape={self.shape!r}, duration={self.duration:.6g}, samples={self.samples},"
            f" start={self.start}, end={self.end}, peak_speed={self.peak_speed:.6g})"
        )


@dataclass(frozen=True, eq=False)
class MultiProfile(Mapping[str, Profile]):
    """Several axes on one time base: every profile padded (holding its end) to the longest.

    Attributes:
        t: common sample times, seconds.
        profiles: axis name -> padded :class:`Profile` (each keeps its own duration).
        duration: the longest duration.
        sample_period: seconds per sample.
    """

    t: FloatArray
    profiles: Mapping[str, Profile]
    duration: float
    sample_period: float

    def __getitem__(self, axis: str) -> Profile:
        return self.profiles[axis]

    def __iter__(self) -> Iterator[str]:
        return iter(self.profiles)

    def __len__(self) -> int:
        return len(self.profiles)

    @property
    def position(self) -> Int64Array:
        """Positions as a 2-D array, one row per axis (in mapping order)."""
        return np.vstack([p.position for p in self.profiles.values()])

    def at(self, t: float | npt.ArrayLike) -> dict[str, float | npt.NDArray[np.float64]]:
        """Each axis's reference position at time(s) ``t`` (seconds, or a time Quantity), in
        counts, as :meth:`Profile.at` gives it (after its end, an axis holds its end). In an
        axis's unit: ``plan[axis].q.at(t)`` (a profile of an axis with a scale).

        Raises:
            InvalidArgument: ``t`` is not seconds nor a time Quantity, or is NaN.
        """
        value = seconds(t, "t")  # (once, not once per axis)
        return {name: p.at(cast("npt.ArrayLike", value)) for name, p in self.profiles.items()}

    def plot(self, *, average: float = 0.004) -> Figure:
        """Plot every axis's position and velocity on the common time base, each in its
        display unit (as its own :meth:`Profile.plot`; the legend names the units when they
        differ).

        As in :meth:`Profile.plot`, velocity is drawn as a centred moving average over
        ``average`` seconds: whole-count positions make the per-sample velocity jitter.
        """
        try:
            from matplotlib.figure import Figure
        except ImportError as exc:
            raise missing_extra(exc, "MultiProfile.plot()") from exc

        fig = Figure(figsize=(7, 5), layout="constrained")
        ax_p, ax_v = fig.subplots(2, 1, sharex=True)
        ts = float(self.t[1] - self.t[0]) if self.t.size > 1 else 1.0
        window = max(1, round(average / ts))
        units = {p._shown()[2] for p in self.profiles.values()}
        for name, p in self.profiles.items():  # (each in its axis's unit, as p.plot() is)
            k, offset, unit = p._shown()
            label = name if len(units) == 1 else f"{name} ({unit})"
            ax_p.plot(self.t, offset + p.position / k, label=label, drawstyle="steps-post")
            ax_v.plot(self.t, _moving_average(p.velocity, window) / k, label=label)
        common = units.pop() if len(units) == 1 else None
        ax_p.set_ylabel("position" if common is None else f"position ({common})")
        ax_v.set_ylabel("velocity" if common is None else f"velocity ({common}/s)")
        ax_v.set_xlabel("time (s)")
        for ax in (ax_p, ax_v):
            ax.grid(True, alpha=0.3)
        if window > 1:
            ax_v.set_title(f"{window}-sample moving average", fontsize="small", loc="right")
        ax_p.legend()
        return fig

    def _repr_html_(self) -> str:
        head = "<tr><th>axis</th><th>shape</th><th>duration (s)</th><th>distance</th>"
        head += "<th>peak speed</th></tr>"
        rows = "".join(
            f"<tr><td>{html.escape(k)}</td><td>{html.escape(p.shape)}</td>"
            f"<td>{p.duration:.6g}</td><td>{html.escape(_shown_distance(p))}</td>"
            f"<td>{html.escape(_shown_speed(p))}</td></tr>"
            for k, p in self.profiles.items()
        )
        caption = f"<caption>{len(self)} axes, {self.duration:.6g} s</caption>"
        return f"<table>{caption}{head}{rows}</table>"

    def _repr_pretty_(self, p: Any, cycle: bool) -> None:
        p.text(repr(self) if not cycle else "MultiProfile(...)")

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}: {v.shape} {v.duration:.4g} s" for k, v in self.profiles.items())
        return f"MultiProfile({inner})"


def _shown_distance(p: Profile) -> str:
    """The distance ``p`` moves, in its display unit (counts without one)."""
    k, _, unit = p._shown()
    return f"{p.distance / k:.6g} {unit}"


def _shown_speed(p: Profile) -> str:
    """The peak speed of ``p``, in its display unit per second."""
    k, _, unit = p._shown()
    return f"{p.peak_speed / abs(k):.6g} {unit}/s"


def _pad(p: Profile, n: int) -> Profile:
    extra = n - p.position.size
    if extra <= 0:
        return p
    pos = np.concatenate([p.position, np.full(extra, p.position[-1])])
    raw = np.concatenate([p.profiler, np.full(extra, p.profiler[-1])])
    vel = np.concatenate([p.velocity, np.zeros(extra)])
    return Profile(
        t=np.arange(n, dtype=np.float64) * float(p.sample_period),
        position=pos,
        velocity=vel,
        duration=p.duration,
        shape=p.shape,
        peak_speed=p.peak_speed,
        sample_period=p.sample_period,
        profiler=raw,
        stop_code=p.stop_code,
        display=p.display,  # (shown in the axis's unit, as the profile it pads)
    )


def together(profiles: Mapping[str, Profile]) -> MultiProfile:
    """Put several axes' profiles on one time base (all started on the same sample).

    Raises:
        InvalidArgument: no profiles, or different sample periods.
    """
    if not profiles:
        raise InvalidArgument("together() needs at least one profile")
    periods = {p.sample_period for p in profiles.values()}
    if len(periods) != 1:
        raise InvalidArgument(f"profiles have different sample periods: {sorted(periods)}")
    ts = periods.pop()
    n = max(p.position.size for p in profiles.values())
    padded = {k: _pad(p, n) for k, p in profiles.items()}
    return MultiProfile(
        t=np.arange(n, dtype=np.float64) * float(ts),
        profiles=padded,
        duration=max(p.duration for p in profiles.values()),
        sample_period=ts,
    )
