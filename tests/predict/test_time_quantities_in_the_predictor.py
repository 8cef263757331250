"""The predictor takes a time Quantity wherever it takes seconds and refuses every other
Quantity with an InvalidArgument (decisions 0092, 0103): never a unit dropped, a raw pint
error or a ValueError."""

from __future__ import annotations

import numpy as np
import pytest

from galil import predict
from galil.errors import InvalidArgument
from galil.units import ureg

mm, s, ms = ureg.mm, ureg.s, ureg.ms


@pytest.fixture
def profile() -> predict.Profile:
    return predict.move(10000, 20000, 256000, 256000)


def test_at_reads_a_time_quantity_in_seconds(profile: predict.Profile) -> None:
    assert profile.at(250 * ms) == profile.at(0.25)
    assert profile.at(0.25 * s) == profile.at(0.25)
    assert profile.at(250 * ms) != profile.end  # (the unit was dropped: 250 s, the end)


def test_at_reads_an_array_of_times(profile: predict.Profile) -> None:
    got = profile.at(np.array([100.0, 200.0]) * ms)
    np.testing.assert_array_equal(got, profile.at(np.array([0.1, 0.2])))


@pytest.mark.parametrize("t", [1 * mm, 5 * ureg.Hz, 0.2 * ureg.dimensionless])
def test_at_refuses_a_quantity_that_is_not_a_time(profile: predict.Profile, t: object) -> None:
    with pytest.raises(InvalidArgument, match="t must be a time"):
        profile.at(t)


def test_events_take_their_time_as_a_quantity() -> None:
    plain = predict.move(50000, 20000, 256000, 256000, events=[predict.Stop(0.3)])
    timed = predict.move(50000, 20000, 256000, 256000, events=[predict.Stop(300 * ms)])
    assert timed.end == plain.end
    assert predict.SetSpeed(500 * ms, 1000).time == 0.5


def test_jog_takes_stop_at_duration_and_change_times_as_quantities() -> None:
    plain = predict.jog(5000, 51200, 51200, changes=[(0.5, -5000)], stop_at=1.0)
    timed = predict.jog(5000, 51200, 51200, changes=[(500 * ms, -5000)], stop_at=1 * s)
    assert (timed.end, timed.duration) == (plain.end, plain.duration)
    run = predict.jog(5000, 51200, 51200, duration=2 * s)
    assert run.duration == predict.jog(5000, 51200, 51200, duration=2.0).duration


def test_sample_period_takes_a_time_quantity() -> None:
    timed = predict.move(1000, 20000, 256000, 256000, sample_period=1 * ms)
    assert timed.sample_period == 0.001
    assert predict.contour([48], 2, sample_period=1 * ms).sample_period == 0.001


@pytest.mark.parametrize(
    "call",
    [
        lambda: predict.move(1000, 20000 * ureg.count / s, 256000, 256000),
        lambda: predict.move(1000, 20 * ureg.kHz, 256000, 256000),
        lambda: predict.move(1000, 20000 * ureg.dimensionless, 256000, 256000),
        lambda: predict.move(1000, 20000, 256000 * ureg.count / s**2, 256000),
        lambda: predict.move(1000 * ureg.count, 20000, 256000, 256000),
        lambda: predict.jog(5000 * ureg.count / s, 51200, 51200, stop_at=1.0),
        lambda: predict.plan_move(1000, 20 * mm / s, 256000, 256000),
        lambda: predict.vector([predict.Line(1000, 0)], 2e4 * ureg.count / s, 256000, 256000),
        lambda: predict.SetSpeed(0.1, 20 * mm / s),
    ],
    ids=[
        "count/s",
        "kHz",
        "dimensionless",
        "accel",
        "distance",
        "jog",
        "plan_move",
        "vector",
        "SetSpeed",
    ],
)
def test_counts_refuse_a_quantity_and_point_to_a_scaled_axis(call: object) -> None:
    with pytest.raises(InvalidArgument, match=r"plain number of counts.*axis with a scale"):
        call()


@pytest.mark.parametrize(
    "call",
    [
        lambda: predict.move(1000, 20000, 256000, 256000, smoothing=10 * ms),
        lambda: predict.contour([48], 2 * ms),
    ],
    ids=["smoothing is IT", "dt is an exponent"],
)
def test_smoothing_and_dt_refuse_a_quantity(call: object) -> None:
    with pytest.raises(InvalidArgument, match=r"plain number of (IT|DT)"):
        call()


@pytest.mark.parametrize(
    "call",
    [
        lambda: predict.move(1000, 20000, 256000, 256000, sample_period=1 * mm),
        lambda: predict.move(50000, 20000, 256000, 256000, events=[predict.Stop(3 * mm)]),
        lambda: predict.jog(5000, 51200, 51200, stop_at=1 * ureg.Hz),
    ],
    ids=["sample_period", "event", "stop_at"],
)
def test_seconds_refuse_a_quantity_that_is_not_a_time(call: object) -> None:
    with pytest.raises(InvalidArgument, match="must be a time"):
        call()
