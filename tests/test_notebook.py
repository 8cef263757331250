"""Notebook helpers: the comparison plot and the jog widget, against the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from galil import predict
from galil.notebook import compare_plot, jog_widget
from galil.testing import simulated, transcript
from galil.units import ureg


def test_compare_plot_draws_prediction_recording_and_difference() -> None:
    prof = predict.move(1000, 10_000, 102_400, 102_400)
    recorded = (prof.t, prof.position + 1)
    fig = compare_plot({"A": prof}, {"A": recorded}, title="t")
    top, diff = fig.axes
    assert len(top.lines) == 2
    assert np.all(diff.lines[0].get_ydata() == 1)


def test_jog_widget_jogs_changes_speed_and_stops() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        axis = dmc.A.set_scale(counts_per=2000 / ureg.mm)
        box = jog_widget(axis, max_speed=50)
        (slider, stop), status = box.children[0].children, box.children[1]
        with transcript(dmc) as sent:
            slider.value = 10.0
        assert any("JGA=20000" in line for line in sent.lines)
        dmc.sleep(0.5)
        assert axis.velocity.to("mm/s").magnitude == pytest.approx(10, rel=0.05)
        slider.value = -5.0
        dmc.sleep(0.5)
        assert axis.velocity.to("mm/s").magnitude == pytest.approx(-5, rel=0.05)
        stop.click()
        assert slider.value == 0
        assert status.value == "stopped"
        dmc.sleep(0.5)
        assert not axis.moving


def test_jog_widget_shows_a_refusal_instead_of_raising() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        box = jog_widget(dmc.A, max_speed=1e9)
        slider, status = box.children[0].children[0], box.children[1]
        slider.value = 1e9  # above the model's maximum jog speed
        assert status.value.startswith("refused:")
        assert not dmc.A.moving
