"""Notebook helpers: the comparison plot and the jog widget, against the simulator."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import galil
from galil import predict
from galil.notebook import compare, compare_plot, jog_widget
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


def test_jog_widget_takes_the_latest_speed_once_a_stop_is_over() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        axis = dmc.A.set_scale(counts_per=2000 / ureg.mm)
        box = jog_widget(axis, max_speed=50)
        slider, status = box.children[0].children[0], box.children[1]
        slider.value = 10.0
        dmc.sleep(0.5)
        jogging_again = threading.Event()

        def seen(change: dict[str, str]) -> None:
            if change["new"] == "jogging at 7 mm/s":
                jogging_again.set()

        status.observe(seen, names="value")
        slider.value = 0.0  # ST: the axis ramps down (no simulated time passes meanwhile)
        slider.value = 5.0
        assert status.value.startswith("axis A is stopping"), status.value
        slider.value = 7.0  # the latest request is the one applied
        assert status.value == "axis A is stopping; then jogging at 7 mm/s"
        dmc.sleep(0.5)  # the stop ends on the controller
        assert jogging_again.wait(timeout=10), status.value
        dmc.sleep(0.5)
        assert axis.velocity.to("mm/s").magnitude == pytest.approx(7, rel=0.05)
        slider.value = 0.0
        dmc.sleep(0.5)
        assert not axis.moving
        assert status.value == "stopped"


def test_jog_widget_refuses_a_speed_beyond_the_model_while_jogging_without_waiting() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        box = jog_widget(dmc.A, max_speed=1e9)
        slider, status = box.children[0].children[0], box.children[1]
        slider.value = 1000.0
        slider.value = 1e9  # refused: nothing is stopping, so nothing is kept for later
        assert status.value.startswith("refused:"), status.value
        dmc.sleep(0.5)
        assert dmc.A.velocity == pytest.approx(1000, rel=0.05)  # still jogging as before
        assert status.value.startswith("refused:")
        slider.value = 0.0
        dmc.sleep(0.5)
        assert not dmc.A.moving


def test_jog_widget_shows_a_refusal_instead_of_raising() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        box = jog_widget(dmc.A, max_speed=1e9)
        slider, status = box.children[0].children[0], box.children[1]
        slider.value = 1e9  # above the model's maximum jog speed
        assert status.value.startswith("refused:")
        assert not dmc.A.moving


def test_jog_widget_takes_its_range_as_a_speed_and_refuses_a_nonsense_one() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        axis = dmc.A.set_scale(counts_per=2000 / ureg.mm)
        slider = jog_widget(axis, max_speed=5 * ureg.cm / ureg.s).children[0].children[0]
        assert (slider.min, slider.max) == pytest.approx((-50, 50))
        reversed_axis = dmc.B.set_scale(counts_per=2000 / ureg.mm, sign=-1)
        slider = jog_widget(reversed_axis, max_speed=50 * ureg.mm / ureg.s).children[0].children[0]
        assert slider.max == pytest.approx(50)
        for bad in (-5, 0, 5 * ureg.mm, float("nan"), True):
            with pytest.raises(galil.InvalidArgument):
                jog_widget(axis, max_speed=bad)


def test_jog_widget_of_an_axis_without_a_scale_takes_its_range_in_counts_per_second() -> None:
    pytest.importorskip("ipywidgets")
    with simulated() as dmc:
        slider = jog_widget(dmc.A, max_speed=8000 * ureg.count / ureg.s).children[0].children[0]
        assert (slider.min, slider.max) == (-8000, 8000)
        with pytest.raises(galil.InvalidArgument, match="expected count / second"):
            jog_widget(dmc.A, max_speed=8000 * ureg.count)  # a distance, not a speed


def test_compare_refuses_a_misspelt_field_and_a_jog_still_running() -> None:
    with simulated() as dmc:
        move = dmc.A.move_by(1000)
        move.wait()
        with pytest.raises(galil.InvalidArgument, match="field"):
            compare(move, {"A": ([0.0], [0.0])}, field="positon")
        jog = dmc.A.jog(1000)
        with pytest.raises(galil.InvalidArgument, match="still running"):
            compare(jog, {"A": ([0.0], [0.0])})
        dmc.A.stop()
        dmc.sleep(0.5)
        t = jog.profiles["A"].t[:2]  # (two values within the motion: fewer are refused)
        assert compare(jog, {"A": (t, [1000.0, jog.profiles["A"].position[1]])})["A"].worst == 0
        assert jog.profiles["A"].position[0] == 1000  # it began at 1000
