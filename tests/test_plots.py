"""Plots compare like with like: recordings at another rate, paired colours, smoothed velocity."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.colors import to_rgba

import galil
from galil import predict
from galil.notebook import compare_plot
from galil.testing import simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        yield controller


@pytest.fixture
def x(dmc: galil.Controller) -> galil.Axis:
    axis = dmc.A.set_scale(counts_per=2000 / mm)
    axis.speed = 20 * mm / s
    axis.accel = axis.decel = 200 * mm / s**2
    return axis


def test_compare_plot_aligns_a_recording_taken_at_another_rate() -> None:
    prof = predict.move(20_000, 40_000, 256_000, 256_000)
    # Records every 4th sample, plus a few samples after the end (the axis holds still).
    t = np.concatenate((prof.t[::4], prof.t[-1] + np.arange(1, 4) * prof.sample_period))
    pos = np.concatenate((prof.position[::4], np.full(3, prof.end)))
    fig = compare_plot({"A": prof}, {"A": (t, pos)})
    diff = fig.axes[1].lines[0].get_ydata()
    assert np.abs(diff).max() == 0


def test_compare_plot_pairs_colours_and_labels_the_difference() -> None:
    a = predict.move(5_000, 40_000, 256_000, 256_000)
    b = predict.move(-3_000, 20_000, 256_000, 256_000)
    fig = compare_plot({"A": a, "B": b}, {"A": (a.t, a.position), "B": (b.t, b.position)})
    top, diff = fig.axes
    colours = [to_rgba(line.get_color()) for line in top.lines]
    assert colours[0] == colours[1]
    assert colours[2] == colours[3]
    assert colours[0] != colours[2]
    assert [to_rgba(line.get_color()) for line in diff.lines] == [colours[0], colours[2]]
    assert diff.get_legend() is not None
    assert "counts" in diff.get_ylabel()


def test_multiprofile_plot_draws_a_smoothed_velocity(dmc: galil.Controller) -> None:
    dmc.A.speed = 40_000
    dmc.B.speed = 10_000
    both = dmc.plan({"A": 40_000, "B": 5_000})
    fig = both.plot()
    velocity = fig.axes[1].lines[0].get_ydata()
    raw = both["A"].velocity
    cruise = slice(raw.size // 3, raw.size // 2)  # A runs at SP here
    assert np.ptp(velocity[cruise]) < np.ptp(raw[cruise])
    assert np.mean(velocity[cruise]) == pytest.approx(40_000, rel=1e-3)


def test_compare_plot_takes_a_handle_and_a_capture_in_the_axis_unit(
    dmc: galil.Controller, x: galil.Axis
) -> None:
    cap = dmc.capture(["_RPA"], every=4, seconds=0.4)
    move = x.move_to(3 * mm)
    fig = compare_plot(move, cap.wait())
    top, diff = fig.axes
    assert top.get_ylabel() == "position (mm)"
    assert top.lines[1].get_ydata().max() == pytest.approx(3.0)  # recorded, in mm
    assert np.all(diff.lines[0].get_ydata() == 0)


def test_compare_plot_takes_data_records_and_needs_their_time(
    dmc: galil.Controller, x: galil.Axis
) -> None:
    with dmc.records(8) as stream:
        move = x.move_to(2 * mm)
        records = stream.take(40)
    fig = compare_plot(move, records, field="reference")
    assert np.all(fig.axes[1].lines[0].get_ydata() == 0)
    with pytest.raises(galil.InvalidArgument, match="field is one of"):
        compare_plot(move, records, field="nope")
    plain = records[[n for n in records.dtype.names if n != "time"]]
    with pytest.raises(galil.InvalidArgument, match="carry no time"):
        compare_plot(move, plain)
    with pytest.raises(galil.InvalidArgument, match="does not know the controller sample"):
        compare_plot({"A": move.profile}, records)


@pytest.mark.parametrize("distance", [1, 10, 40])
def test_a_move_shorter_than_the_smoothing_window_plots(distance: int) -> None:
    # (a 13-sample move: the acceleration's 16-sample window made np.convolve return 16
    # values for 14 times, and matplotlib refused them)
    profile = predict.move(distance, 25_000, 256_000, 256_000)
    fig = profile.plot()
    for ax in fig.axes:
        for line in ax.get_lines():
            assert len(line.get_xdata()) == len(line.get_ydata()) == profile.samples + 1
