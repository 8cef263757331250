"""Jupyter helpers: plots of predicted against recorded motion, and a jog widget.

Heavy imports (matplotlib, ipywidgets) happen inside the functions, so importing this module is
cheap. Nothing in the library imports it; notebooks do.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from galil.axis import Axis
from galil.errors import GalilError
from galil.predict import Profile
from galil.units import get_registry

__all__ = ["compare_plot", "jog_widget"]


def compare_plot(
    predicted: Mapping[str, Profile],
    recorded: Mapping[str, tuple[npt.ArrayLike, npt.ArrayLike]],
    *,
    title: str = "predicted vs recorded",
) -> Any:
    """Plot predicted positions against recorded ones, and their difference in counts.

    Positions are drawn in each profile's unit (millimetres for a profile of a scaled axis,
    see :meth:`~galil.predict.Profile.with_units`), counts otherwise.

    Args:
        predicted: profile per axis letter.
        recorded: ``(t, position)`` per axis letter, positions in counts, ``t`` in seconds
            from the same start; any sampling: the difference is taken against the
            prediction at those times.
        title: figure title.

    Returns:
        The matplotlib Figure.
    """
    # A plain Figure (not pyplot): nothing global is touched, no backend is chosen, and the
    # figure shows in Jupyter the same way Profile.plot()'s does.
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 6), layout="constrained")
    ax_pos, ax_diff = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    units = {_display(p)[2] for p in predicted.values()}
    for letter, prof in predicted.items():
        k, offset, unit = _display(prof)
        suffix = "" if len(units) == 1 else f" ({unit})"
        (line,) = ax_pos.plot(
            prof.t,
            prof.position / k + offset,
            label=f"{letter} predicted{suffix}",
            linewidth=2,
            alpha=0.6,
        )
        if letter in recorded:
            t, pos = (np.asarray(v, dtype=float) for v in recorded[letter])
            # Same colour, dashed: each recording reads as the twin of its prediction.
            ax_pos.plot(
                t, pos / k + offset, "--", color=line.get_color(), label=f"{letter} recorded"
            )
            # Compare at the recorded times, not index by index: a recording taken at another
            # rate (records every few samples, a polling loop) must not be misaligned. The
            # prediction holds its end after it finishes, as the axis does. The difference
            # stays in counts: an exact prediction is 0 counts off.
            if prof.t.size:
                expected = np.interp(t, prof.t, prof.position)
            else:
                expected = np.full(t.size, float(prof.end))
            ax_diff.plot(t, pos - expected, color=line.get_color(), label=letter)
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


def _display(profile: Profile) -> tuple[float, float, str]:
    """(counts per unit, offset, unit) the profile is shown in; counts without a scale."""
    return profile.display if profile.display is not None else (1.0, 0.0, "counts")


def jog_widget(axis: Axis, *, max_speed: float | None = None) -> Any:
    """A slider that jogs ``axis`` at the chosen speed, and a Stop button; needs ipywidgets.

    Moving the slider jogs (or changes the jog speed in motion); 0 or Stop decelerates to a
    stop. A refused speed shows its error under the slider instead of raising in a callback.

    Args:
        axis: the axis to jog.
        max_speed: slider range in the axis's units per second (counts/s without a scale).

    Returns:
        The widget box (``.children``: slider, stop button, status label).
    """
    import ipywidgets as widgets

    limit = max_speed if max_speed is not None else 10_000.0
    unit = "counts/s" if axis.scale is None else f"{axis.scale.unit:~}/s"
    slider = widgets.FloatSlider(
        value=0.0, min=-limit, max=limit, description=f"jog {axis.letter}", continuous_update=False
    )
    stop = widgets.Button(description="Stop", button_style="danger")
    status = widgets.Label(value="stopped")

    def jog(value: float) -> None:
        try:
            if value == 0:
                axis.stop()
                status.value = "stopped"
                return
            speed: Any = value
            if axis.scale is not None:
                reg = get_registry()
                speed = reg.Quantity(value, axis.scale.unit / reg.second)
            axis.jog(speed)
            status.value = f"jogging at {value:g} {unit}"
        except GalilError as exc:
            status.value = f"refused: {exc}".splitlines()[0]

    def on_change(change: Mapping[str, Any]) -> None:
        jog(float(change["new"]))

    def on_stop(_button: Any) -> None:
        if slider.value != 0:
            slider.value = 0.0  # observing the change sends the stop
        else:
            jog(0.0)

    slider.observe(on_change, names="value")
    stop.on_click(on_stop)
    return widgets.VBox([widgets.HBox([slider, stop]), status])
