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


def test_a_vector_profile_plots_its_path_in_the_plane_and_its_speed() -> None:
    segments = [predict.Line(4000, 0), predict.Arc(1000, 270, 180), predict.Line(-4000, 0)]
    prof = predict.vector(segments, 20_000, 200_000, 200_000)
    fig = prof.plot()
    plane, speed = fig.axes
    (drawn,) = plane.lines
    np.testing.assert_array_equal(drawn.get_xdata(), prof.position[0])
    np.testing.assert_array_equal(drawn.get_ydata(), prof.position[1])
    assert (plane.get_xlabel(), plane.get_ylabel()) == ("axis 0 (counts)", "axis 1 (counts)")
    assert plane.get_aspect() == 1.0  # a circle looks round
    np.testing.assert_array_equal(speed.lines[0].get_xdata(), prof.t)
    assert speed.lines[0].get_ydata().max() == pytest.approx(20_000)
    assert speed.get_ylabel() == "speed along the path (counts/s)"
    assert fig.get_suptitle() == f"3 segments, {prof.duration:.4g} s"
    assert prof.plot(title="loop").get_suptitle() == "loop"


def test_a_one_axis_vector_profile_plots_its_position_against_time() -> None:
    prof = predict.vector([predict.LinearInterp((3000,))], 20_000, 200_000, 200_000)
    position, _ = prof.plot().axes
    np.testing.assert_array_equal(position.lines[0].get_xdata(), prof.t)
    np.testing.assert_array_equal(position.lines[0].get_ydata(), prof.position[0])
    assert position.lines[0].get_ydata()[-1] == 3000
    assert (position.get_xlabel(), position.get_ylabel()) == ("time (s)", "axis 0 (counts)")


def test_a_vector_plan_plots_in_the_axes_user_units(dmc: galil.Controller) -> None:
    for a in "AB":
        dmc.axis(a).set_scale(counts_per=2000 / mm)
    plan = dmc.plan_vector("AB", [galil.Line(10 * mm, 0), galil.Line(0, 5 * mm)], speed=20 * mm / s)
    fig = plan.plot()
    plane, speed = fig.axes
    assert (plane.get_xlabel(), plane.get_ylabel()) == ("A (mm)", "B (mm)")
    x, y = plane.lines[0].get_xdata(), plane.lines[0].get_ydata()
    assert (x.max(), y.max()) == (pytest.approx(10.0), pytest.approx(5.0))
    assert speed.get_ylabel() == "speed along the path (mm/s)"
    assert speed.lines[0].get_ydata().max() == pytest.approx(20.0)
    assert fig.get_suptitle().startswith("AB: 2 segments, ")


def test_a_one_axis_vector_plan_plots_its_position_against_time(dmc: galil.Controller) -> None:
    dmc.C.set_scale(counts_per=1000 / mm)
    plan = dmc.plan_vector("C", [galil.Line(2 * mm)], speed=10 * mm / s)
    position, _ = plan.plot(title="C alone").axes
    np.testing.assert_array_equal(position.lines[0].get_xdata(), plan.t)
    assert position.lines[0].get_ydata()[-1] == pytest.approx(2.0)
    assert (position.get_xlabel(), position.get_ylabel()) == ("time (s)", "C (mm)")
    assert position.figure.get_suptitle() == "C alone"


def test_a_profile_plot_draws_position_velocity_and_acceleration() -> None:
    prof = predict.move(20_000, 40_000, 256_000, 256_000)
    fig = prof.plot()
    pos, vel, acc = fig.axes
    np.testing.assert_array_equal(pos.lines[0].get_ydata(), prof.position)
    assert [ax.get_ylabel() for ax in fig.axes] == [
        "position (counts)",
        "velocity (counts/s)",
        "accel (counts/s²)",
    ]
    np.testing.assert_array_equal(vel.lines[0].get_ydata(), prof.velocity)  # raw, faint
    assert np.median(vel.lines[1].get_ydata()) == pytest.approx(40_000, rel=0.01)  # averaged
    ramp = slice(20, 140)  # AC lasts 160 samples
    assert np.mean(acc.lines[0].get_ydata()[ramp]) == pytest.approx(256_000, rel=0.02)
    assert fig.get_suptitle().startswith("trapezoid: 20000 counts in ")


def test_a_multiprofile_plot_labels_every_axis(dmc: galil.Controller) -> None:
    both = dmc.plan({"A": 4000, "B": -2000})
    fig = both.plot()
    pos, vel = fig.axes
    assert [line.get_label() for line in pos.lines] == ["A", "B"]
    assert [t.get_text() for t in pos.get_legend().get_texts()] == ["A", "B"]
    assert pos.lines[0].get_ydata()[-1] == 4000
    assert pos.lines[1].get_ydata()[-1] == -2000
    assert (pos.get_ylabel(), vel.get_ylabel()) == ("position (counts)", "velocity (counts/s)")
