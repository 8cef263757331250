"""Jupyter helpers: plots of predicted against recorded motion, and a jog widget.

Heavy imports (matplotlib, ipywidgets) happen inside the functions, so importing this module is
cheap. Nothing in the library imports it; notebooks do.
"""

from __future__ import annotations

import math
import numbers
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from galil.axis import Axis
from galil.capture import Recording
from galil.contour import ContourResult
from galil.errors import GalilError, InvalidArgument, decimal_hint, missing_extra
from galil.motion import MoveHandle
from galil.predict import Profile
from galil.predict.profile import shown_position
from galil.units import Amount, counts_or_plain, get_registry, is_quantity

if TYPE_CHECKING:
    from ipywidgets import VBox
    from matplotlib.figure import Figure

__all__ = ["Comparison", "compare", "compare_plot", "jog_widget"]

FloatArray = npt.NDArray[np.float64]
#: The operand a capture records for each data-record field compared: positions, as the
#: prediction is (a stepper's ``TD`` counts its steps; a servo's is its auxiliary encoder).
_OPERANDS = {"reference": "RP", "position": "TP", "aux_position": "TD"}
#: Fields a recording has that are not positions: compared with one, they would be off by
#: the whole motion (``error`` is the following error, ``_TE``: 0 for an ideal servo).
_NOT_POSITIONS = {"error": "_TE", "velocity": "_TV", "torque": "_TT"}
Predicted = MoveHandle | ContourResult | Mapping[str, Profile]
#: Data records: a structured array (``RecordStream.take``).
Records = npt.NDArray[np.void]
Recorded = Recording | Records | Mapping[str, tuple[npt.ArrayLike, npt.ArrayLike]]


@dataclass(frozen=True)
class Comparison:
    """One axis's recording next to its prediction, in counts.

    Attributes:
        t: seconds from the start of the prediction (the sample it began on).
        recorded: the recorded positions.
        predicted: the prediction at the same times (it holds its start before and its end
            after, as the axis does).
    """

    t: FloatArray
    recorded: FloatArray
    predicted: FloatArray

    @property
    def difference(self) -> FloatArray:
        """``recorded - predicted``, counts."""
        out: FloatArray = self.recorded - self.predicted
        return out

    @property
    def worst(self) -> float:
        """Largest ``|recorded - predicted|``, counts (0 for an exact prediction)."""
        return float(np.max(np.abs(self.difference))) if self.t.size else 0.0


def _predictions(predicted: Predicted) -> tuple[dict[str, Profile], dict[str, int | None]]:
    if isinstance(predicted, MoveHandle):
        if not math.isfinite(predicted.duration):
            raise InvalidArgument(
                "a jog still running has no predicted end to compare with: stop it first"
                " (its handle then predicts the whole motion)"
            )
        return predicted.profiles, predicted.begin
    if isinstance(predicted, ContourResult):
        return dict(predicted.profiles), dict.fromkeys(predicted.profiles, predicted.begin)
    if isinstance(predicted, Mapping):
        return dict(predicted), dict.fromkeys(predicted)
    raise InvalidArgument(
        "predicted is a MoveHandle, a ContourResult or a mapping of axis to Profile, "
        f"not {type(predicted).__name__}"
    )


def _recorded(
    recorded: Recording | Records, letter: str, field: str
) -> tuple[npt.NDArray[np.int64], FloatArray] | None:
    """(controller samples, positions) of ``letter`` in a recording, or None if absent."""
    if isinstance(recorded, Recording):
        source = f"_{_OPERANDS.get(field, '')}{letter}"
        if source not in recorded.values:
            return None
        return recorded.samples, recorded.values[source]
    names = recorded.dtype.names or ()
    if "time" not in names:
        raise InvalidArgument("these data records carry no time (take them from records())")
    if letter not in names:
        return None
    block = recorded[letter]
    if field not in (block.dtype.names or ()):
        raise InvalidArgument(f"data records have no field {field!r} (try 'reference')")
    return np.asarray(recorded["time"], dtype=np.int64), np.asarray(block[field], dtype=float)


def _lined_up(
    recorded: Recorded, letter: str, field: str, begin: int | None, ts: float
) -> tuple[FloatArray, FloatArray] | None:
    """(seconds from the prediction's start, positions) of ``letter``, or None if absent."""
    if isinstance(recorded, (Recording, np.ndarray)):
        found = _recorded(recorded, letter, field)
        if found is None:
            return None
        if begin is None:
            raise InvalidArgument(
                f"the prediction of {letter} does not know the controller sample it began "
                "on; give (t, positions) instead"
            )
        samples, pos = found
        return np.multiply(samples - begin, ts, dtype=np.float64), pos
    if not isinstance(recorded, Mapping):
        raise InvalidArgument(
            "recorded is a capture's Recording, data records (with their time), or a "
            f"mapping of axis to (t, positions), not {type(recorded).__name__}"
        )
    if letter not in recorded:
        return None
    t, pos = (np.asarray(v, dtype=float) for v in recorded[letter])
    return t, pos


def compare(
    predicted: Predicted, recorded: Recorded, *, field: str = "reference"
) -> dict[str, Comparison]:
    """Line a recording up with its prediction, sample by sample, per axis.

    Args:
        predicted: a :class:`~galil.motion.MoveHandle` (a move, a jog, a schedule), a
            :class:`~galil.contour.ContourResult`, or profiles by axis.
        recorded: what the controller did: a :class:`~galil.capture.Recording` (from
            ``controller.capture``), data records (from ``controller.records(...)``, which
            carry their controller ``time``), or ``(t, positions)`` per axis with ``t`` in
            seconds from the prediction's start.
        field: what is compared: ``"reference"`` (what the profiler commanded: a data
            record's ``reference``, a capture's ``_RPx``), ``"position"`` (the encoder:
            ``position``, ``_TPx``) or ``"aux_position"`` (``_TDx``: a stepper's step count).

    Returns:
        A :class:`Comparison` per axis found in both.

    Raises:
        InvalidArgument: a field that is not a position (``"error"``: the following error
            ``_TE`` is no position to hold against a prediction); no axis of the prediction
            recorded in ``field`` (the message names what was recorded); an axis with fewer
            than two recorded values within its predicted motion (a recording that ended
            before the motion began, or began after it ended: nothing would be compared);
            a recording given by controller samples while the prediction does not know the
            sample it began on.
    """
    _check_field(field)
    profiles, begins = _predictions(predicted)
    out: dict[str, Comparison] = {}
    for letter, prof in profiles.items():
        found = _lined_up(recorded, letter, field, begins.get(letter), prof.sample_period)
        if found is None:
            continue
        t, pos = found
        _check_overlap(letter, prof, t)
        # Compare at the recorded times, not index by index: records every few samples or
        # a polling loop must not be misaligned. The prediction holds its end after it
        # finishes, and its start before it begins, as the axis does.
        if prof.t.size:
            expected = np.interp(t, prof.t, prof.position.astype(float))
        else:
            expected = np.full(t.size, float(prof.end))
        out[letter] = Comparison(t, pos, expected)
    if not out:
        raise InvalidArgument(
            f"nothing to compare in field {field!r}: the prediction is of"
            f" {', '.join(profiles) or 'no axis'}, and {_what_was_recorded(recorded, profiles)}"
        )
    return out


def _check_field(field: str) -> None:
    if field in _NOT_POSITIONS:
        raise InvalidArgument(
            f"field {field!r} ({_NOT_POSITIONS[field]}) is not a position: a prediction is"
            " compared with 'reference' or 'position' (read the recording's own values for"
            f" {field})"
        )
    if field not in _OPERANDS:
        raise InvalidArgument(f"field is one of {', '.join(_OPERANDS)}, not {field!r}")


def _check_overlap(letter: str, prof: Profile, t: FloatArray) -> None:
    """Refuse a recording of ``letter`` with fewer than two values within its predicted
    motion (0 .. duration s): it would compare as exact whatever the axis did. A prediction
    of no motion (0 samples) is compared wherever it was recorded."""
    if prof.samples < 1:
        return
    inside = int(np.count_nonzero((t >= 0) & (t <= prof.duration)))
    if inside >= 2:
        return
    held = f"{t[0]:.4g} .. {t[-1]:.4g} s" if t.size else "no values"
    raise InvalidArgument(
        f"the recording of {letter} has {inside} value(s) within its predicted motion"
        f" (0 .. {prof.duration:.4g} s from its start; the recording holds {held}):"
        " record while the motion runs (start the capture or the records just before it)"
    )


def _what_was_recorded(recorded: Recorded, letters: Iterable[str]) -> str:
    """What a recording holds, for the message of a comparison that found nothing (and the
    fields a capture's sources could be compared in)."""
    if isinstance(recorded, Recording):
        fields = [
            repr(f)
            for f, op in _OPERANDS.items()
            if any(f"_{op}{a}" in recorded.sources for a in letters)
        ]
        hint = f" (compare with field={' or '.join(fields)})" if fields else ""
        return f"the capture recorded {', '.join(recorded.sources)}{hint}"
    if isinstance(recorded, np.ndarray):
        names = [n for n in recorded.dtype.names or () if len(n) == 1 and n.isalpha()]
        return f"the data records hold axes {', '.join(names) or 'none'}"
    return f"the recording holds axes {', '.join(map(str, recorded)) or 'none'}"


def compare_plot(
    predicted: Predicted,
    recorded: Recorded,
    *,
    title: str = "predicted vs recorded",
    field: str = "reference",
) -> Figure:
    """Plot predicted positions against recorded ones, and their difference in counts.

    Positions are drawn in each profile's unit (millimetres for a move of a scaled axis,
    see :meth:`~galil.predict.Profile.with_units`), counts otherwise. What can be compared
    is what :func:`compare` takes: a move handle or contour result against a capture or data
    records (lined up by controller sample), or profiles against ``(t, positions)``.

    Returns:
        The matplotlib Figure.
    """
    # A plain Figure (not pyplot): nothing global is touched, no backend is chosen, and the
    # figure shows in Jupyter the same way Profile.plot()'s does.
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise missing_extra(exc, "compare_plot()") from exc

    profiles, _ = _predictions(predicted)
    pairs = compare(predicted, recorded, field=field)
    fig = Figure(figsize=(9, 6), layout="constrained")
    ax_pos, ax_diff = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    units = {_display(p)[2] for p in profiles.values()}
    for letter, prof in profiles.items():
        suffix = "" if len(units) == 1 else f" ({_display(prof)[2]})"
        _plot_axis(ax_pos, ax_diff, letter, prof, pairs.get(letter), suffix)
    shown = next(iter(units)) if len(units) == 1 else "each axis's unit"
    ax_pos.set_ylabel(f"position ({shown})")
    ax_pos.legend(loc="best", fontsize="small")
    ax_pos.set_title(title)
    ax_pos.grid(True, alpha=0.3)
    ax_diff.set_ylabel("recorded - predicted\n(counts)")
    ax_diff.set_xlabel("time (s)")
    ax_diff.grid(True, alpha=0.3)
    if len(ax_diff.lines) > 1:
        ax_diff.legend(loc="best", fontsize="small")
    return fig


def _plot_axis(
    ax_pos: Any, ax_diff: Any, letter: str, prof: Profile, pair: Comparison | None, suffix: str
) -> None:
    """One axis of :func:`compare_plot`: its prediction, its recording (same colour, dashed:
    each reads as the twin of the other) and their difference (in counts: an exact prediction
    is 0 counts off)."""
    (line,) = ax_pos.plot(
        prof.t,
        shown_position(prof.display, prof.position.astype(np.float64)),
        label=f"{letter} predicted{suffix}",
        linewidth=2,
        alpha=0.6,
    )
    if pair is None:
        return
    ax_pos.plot(
        pair.t,
        shown_position(prof.display, pair.recorded.astype(np.float64)),
        "--",
        color=line.get_color(),
        label=f"{letter} recorded",
    )
    ax_diff.plot(pair.t, pair.difference, color=line.get_color(), label=letter)


def _display(profile: Profile) -> tuple[float, float, str]:
    """(counts per unit, offset, unit) the profile is shown in; counts without a scale."""
    return profile.display if profile.display is not None else (1.0, 0.0, "counts")


def _slider_limit(axis: Axis, max_speed: object) -> float:
    """The slider's range: ``max_speed`` in the axis's units per second (a Quantity or a
    number), 10,000 by default.

    Raises:
        InvalidArgument: not a positive speed.
    """
    if max_speed is None:
        return 10_000.0
    if is_quantity(max_speed):
        if axis.scale is None:
            value = counts_or_plain(max_speed, "max_speed", axis.letter, power=1)
        else:  # counts/s back to the axis's unit per second (display: sign * counts/unit)
            value = axis.scale.rate_to_counts(max_speed, 1, "max_speed") / axis.scale.display[0]
    elif isinstance(max_speed, bool) or not isinstance(max_speed, numbers.Real):
        raise InvalidArgument(f"max_speed is a speed, not {max_speed!r}{decimal_hint(max_speed)}")
    else:
        value = float(max_speed)
    if not (math.isfinite(value) and value > 0):
        raise InvalidArgument(f"max_speed must be a positive speed, not {max_speed!r}")
    return value


class _JogControl:
    """What the jog widget does with the speeds asked for, on whichever thread asks.

    A speed asked for while the widget's jog ramps down from a stop (the controller takes no
    new jog then) is kept, not refused: once the stop is over (the stopped jog's handle calls
    back, from its watcher thread), the slider's value at that moment is applied. Nothing here
    waits: the UI thread only sends commands and sets labels.
    """

    def __init__(self, axis: Axis, slider: Any, status: Any, unit: str) -> None:
        self.axis = axis
        self.slider = slider
        self.status = status
        self.unit = unit
        self._lock = threading.RLock()  # the callback may run on the thread that asks
        self._handle: MoveHandle | None = None  # the widget's jog, until seen stopped
        self._waiting = False  # a callback is due once that jog has stopped

    def apply(self, value: float) -> None:
        """Jog at ``value`` (axis units per second; 0 stops), or as soon as a stop is over."""
        with self._lock:
            if value != 0:
                self._jog(value)
                return
            try:
                self.axis.stop()
                self.status.value = "stopped"
            except GalilError as exc:
                self.status.value = f"refused: {exc}".splitlines()[0]

    def _jog(self, value: float) -> None:
        speed: Any = value
        if self.axis.scale is not None:
            reg = get_registry()
            speed = reg.Quantity(value, self.axis.scale.unit / reg.second)
        try:
            handle = self.axis.jog(speed)
        except GalilError as exc:
            if not self._after_stop(value):
                self.status.value = f"refused: {exc}".splitlines()[0]
            return
        self._handle, self._waiting = handle, False
        self.status.value = f"jogging at {value:g} {self.unit}"

    def _after_stop(self, value: float) -> bool:
        """After a refusal: jog at ``value`` once the widget's jog has stopped, if it is
        ramping down from a stop (``_SC`` not 0); ``False`` when it is not."""
        handle = self._handle
        if handle is None or handle.finished:
            return False
        try:
            done = handle.done
            stopping = not done and self.axis.stop_code[0] != 0
        except GalilError:
            return False
        if done:  # the stop ended after the jog's own query: once more, now
            if self._handle is handle:  # (unless its callback has just done so)
                self._handle = None
                self._jog(value)
            return True
        if not stopping:
            return False
        self.status.value = (
            f"axis {self.axis.letter} is stopping; then jogging at {value:g} {self.unit}"
        )
        if not self._waiting:
            self._waiting = True
            handle.add_callback(self._stopped)  # called here at once if it stopped meanwhile
        return True

    def _stopped(self, handle: MoveHandle) -> None:
        with self._lock:
            if handle is not self._handle or not self._waiting:
                return  # a jog started since then: nothing to catch up
            self._handle, self._waiting = None, False
            value = float(self.slider.value)
            if value == 0:
                self.status.value = "stopped"
            else:
                self._jog(value)


def jog_widget(axis: Axis, *, max_speed: Amount | None = None) -> VBox:
    """A slider that jogs ``axis`` at the chosen speed, and a Stop button; needs ipywidgets.

    Moving the slider jogs (or changes the jog speed in motion); 0 or Stop decelerates to a
    stop. A speed chosen while the axis still ramps down from a stop is applied once the stop
    is over (the latest one chosen by then). A refused speed shows its error under the slider
    instead of raising in a callback.

    Args:
        axis: the axis to jog.
        max_speed: slider range in the axis's units per second (counts/s without a scale).

    Returns:
        The widget box (``.children``: slider, stop button, status label).
    """
    try:
        import ipywidgets as widgets
    except ImportError as exc:
        raise missing_extra(exc, "jog_widget()") from exc

    limit = _slider_limit(axis, max_speed)
    unit = "counts/s" if axis.scale is None else f"{axis.scale.unit:~}/s"
    slider = widgets.FloatSlider(
        value=0.0, min=-limit, max=limit, description=f"jog {axis.letter}", continuous_update=False
    )
    stop = widgets.Button(description="Stop", button_style="danger")
    status = widgets.Label(value="stopped")
    control = _JogControl(axis, slider, status, unit)

    def on_change(change: Mapping[str, Any]) -> None:
        control.apply(float(change["new"]))

    def on_stop(_button: Any) -> None:
        if slider.value != 0:
            slider.value = 0.0  # observing the change sends the stop
        else:
            control.apply(0.0)

    slider.observe(on_change, names="value")
    stop.on_click(on_stop)
    return widgets.VBox([widgets.HBox([slider, stop]), status])
