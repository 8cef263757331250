"""Predictions hold at any TM (docs/decisions/0025, "Predictions at any TM").

SP/JG step by 2·1000/TM counts/s and AC/DC by 1024·(1000/TM)² (decision 0025); at TMs such as
187.5, 375 and 1500 those steps have no four-decimal form. For a random TM on the model's grid
(31.25 µs steps within ``ModelSpec.tm_range``) and awkward values set through the public API,
every kind of motion the library predicts must end where it was predicted (``deviation`` 0, no
``RuntimeWarning``), and what the controller stores, read back and quantised again, must be
the value the host planned with.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import galil
from galil import Arc, Line, predict
from galil.contour import sample_path
from galil.controller import Controller
from galil.models import get_model
from galil.notebook import compare
from galil.testing import sim_of, simulated

MODELS = ("DMC-4040", "DMC-41x3", "DMC-2183", "DMC-30010")
#: TMs whose SP/JG step (2·1000/TM) has no four-decimal form, and TM 1000 itself.
AWKWARD_TMS = (187.5, 375.0, 1500.0, 1000.0)
GRID = 31.25

SETTINGS = settings(
    deadline=None,
    max_examples=25,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)


@st.composite
def model_and_tm(draw: st.DrawFn) -> tuple[str, float]:
    name = draw(st.sampled_from(MODELS))
    lo, hi = get_model(name).tm_range
    awkward = [tm for tm in AWKWARD_TMS if lo <= tm <= hi]
    steps = round((hi - lo) / GRID)
    on_grid = st.integers(0, steps).map(lambda k: lo + k * GRID)
    # (mostly the short TMs, where a move has many samples and the steps are coarse)
    short = st.integers(0, round((min(hi, 2500.0) - lo) / GRID)).map(lambda k: lo + k * GRID)
    tm = draw(st.one_of(st.sampled_from(awkward), short, on_grid))
    return name, tm


def awkward_value(step: float, lo: float, hi: float) -> st.SearchStrategy[float]:
    """A value in ``lo .. hi``: a multiple of ``step`` (often one with no four-decimal form),
    just short of or beyond one, or any float."""
    n = st.integers(max(1, math.ceil(lo / step)), max(1, math.floor(hi / step)))
    nudge = st.sampled_from([0.0, -0.4e-4, -0.6e-4, 0.3e-4, 1e-9, -1e-9, 0.5, -0.5])
    near = st.builds(lambda k, d: k * step + d, n, nudge)
    return st.one_of(near, st.floats(lo, hi)).filter(lambda v: lo <= v <= hi)


@contextmanager
def controller(name: str, tm: float) -> Iterator[Controller]:
    with simulated(name) as dmc, warnings.catch_warnings():
        warnings.simplefilter("error")  # (a deviation from the prediction warns)
        dmc.command(f"TM {tm}")
        assert dmc.sample_period == tm / 1_024_000
        yield dmc


def speeds(tm: float, lo: float = 500.0, hi: float = 400_000.0) -> st.SearchStrategy[float]:
    return awkward_value(2 * 1000 / tm, lo, hi)


def accels(tm: float, lo: float = 20_000.0, hi: float = 2e7) -> st.SearchStrategy[float]:
    return awkward_value(1024 * (1000 / tm) ** 2, lo, hi)


def settle(name: str, tm: float, cmd: str, value: float) -> float:
    """``value`` as the host plans with it at ``tm``."""
    return float(predict.check_parameter(cmd, value, name, tm=tm))


def set_motion(dmc: Controller, letter: str, sp: float, ac: float, dc: float) -> None:
    """Set SP/AC/DC through the API and check that what the controller stores, read back
    and quantised again, is what the host plans with."""
    tm = dmc.sample_period * 1_024_000
    axis = dmc.axes[letter]
    axis.speed, axis.accel, axis.decel = sp, ac, dc
    name = dmc.model.name
    for cmd, value, back in (
        ("SP", sp, axis.speed),
        ("AC", ac, axis.accel),
        ("DC", dc, axis.decel),
    ):
        planned = settle(name, tm, cmd, value)
        assert settle(name, tm, cmd, float(back)) == planned, (cmd, value, back)
        assert float(back) == pytest.approx(planned, abs=1e-4)


def ends_as_predicted(dmc: Controller, handle: galil.MoveHandle, *, exact: bool = True) -> None:
    result = handle.wait()
    if not exact:  # (FE: the motor meets the edge with its servo lag, docs/homing.md)
        assert not result.deviation
        return
    assert result.deviation, result
    assert not any(result.deviation.values()), result
    for letter, profile in handle.profiles.items():
        final = result.final.get(letter, result.follower_final.get(letter))
        assert final is not None, letter
        assert int(profile.position[-1]) == final, (letter, profile.position[-1], final)


#: ``data.draw``: a value from a strategy.
Draw = Callable[[st.SearchStrategy[Any]], Any]
Scenario = Callable[[Draw, Controller, float], None]


def scenario_moves(draw: Draw, dmc: Controller, tm: float) -> None:
    a = dmc.A
    set_motion(dmc, "A", draw(speeds(tm)), draw(accels(tm)), draw(accels(tm)))
    ends_as_predicted(dmc, a.move_by(draw(st.integers(-300_000, 300_000))))
    speed = draw(speeds(tm))
    ends_as_predicted(dmc, a.move_to(draw(st.integers(-300_000, 300_000)), speed=speed))
    assert settle(dmc.model.name, tm, "SP", float(a.speed)) == settle(
        dmc.model.name, tm, "SP", speed
    )


def scenario_jog(draw: Draw, dmc: Controller, tm: float) -> None:
    a = dmc.A
    set_motion(dmc, "A", draw(speeds(tm)), draw(accels(tm)), draw(accels(tm)))
    v = draw(speeds(tm)) * draw(st.sampled_from([1, -1]))
    handle = a.jog(v)
    dmc.sleep(draw(st.floats(0.05, 1.5)))
    if draw(st.booleans()):  # a change of speed in motion
        a.jog(draw(speeds(tm)) * (1 if v > 0 else -1))
        dmc.sleep(draw(st.floats(0.05, 1.0)))
    if draw(st.booleans()):  # an increment while jogging: a step of the reference
        a.increment(draw(st.integers(-500, 500)))
    handle.stop()
    ends_as_predicted(dmc, handle)


def scenario_increment(draw: Draw, dmc: Controller, tm: float) -> None:
    a = dmc.A
    set_motion(dmc, "A", draw(speeds(tm, 2000.0)), draw(accels(tm)), draw(accels(tm)))
    distance = draw(st.integers(50_000, 300_000)) * draw(st.sampled_from([1, -1]))
    handle = a.move_by(distance)
    dmc.sleep(draw(st.floats(0.0, 0.5)))
    if not handle.done:
        a.increment(int(math.copysign(draw(st.integers(1, 50_000)), distance)))
    ends_as_predicted(dmc, handle)


def scenario_schedule(draw: Draw, dmc: Controller, tm: float) -> None:
    a = dmc.A
    ac = draw(accels(tm, 2e5, 2e7))
    set_motion(dmc, "A", draw(speeds(tm)), ac, draw(accels(tm, 2e5, 2e7)))
    v0, v1, v2 = (draw(speeds(tm, 1000.0, 100_000.0)) for _ in range(3))
    distance = draw(st.integers(100_000, 400_000))
    changes = [(distance // 3, v1), (2 * distance // 3, v2)]
    try:
        handle = a.speed_schedule(distance, changes, speed=v0)
    except galil.ScheduleError:
        return  # (a change point the ramps leave no room for: refused, nothing sent)
    ends_as_predicted(dmc, handle)
    assert settle(dmc.model.name, tm, "SP", float(a.speed)) == settle(dmc.model.name, tm, "SP", v2)


def scenario_vector(draw: Draw, dmc: Controller, tm: float) -> None:
    vs, va, vd = draw(speeds(tm, 1000.0)), draw(accels(tm)), draw(accels(tm))
    if len(dmc.model.axes) < 2:
        handle = dmc.vector_move(
            "A",
            [Line(draw(st.integers(-200_000, 200_000).filter(bool)))],
            speed=vs,
            accel=va,
            decel=vd,
        )
    else:
        r = draw(st.integers(2000, 20_000))
        path = [
            Line(draw(st.integers(1000, 100_000)), draw(st.integers(-100_000, 100_000))),
            Arc(r, 270, draw(st.sampled_from([90, -90, 180]))),
            Line(draw(st.integers(-100_000, 100_000)), draw(st.integers(1000, 100_000))),
        ]
        handle = dmc.vector_move("AB", path, speed=vs, accel=va, decel=vd)
    ends_as_predicted(dmc, handle)
    stored = dmc.query_operands(["_VSS", "_VAS", "_VDS"])
    name = dmc.model.name
    q = predict.quantise_vector(name, speed=vs, accel=va, decel=vd, tm=tm)
    back = predict.quantise_vector(name, speed=stored[0], accel=stored[1], decel=stored[2], tm=tm)
    assert (back.speed, back.accel, back.decel) == (q.speed, q.accel, q.decel)


def scenario_contour(draw: Draw, dmc: Controller, tm: float) -> None:
    lo, hi = dmc.model.dt_range
    dt = draw(st.integers(max(lo, 1), min(hi, 6)))
    ts = dmc.sample_period
    # a trapezoid in time (up at `acc`, `flat` s at `v`, down), sampled at the segment ends
    top = min(100_000.0, 25_000 / ((1 << dt) * ts))  # (a segment within CD's range)
    v: float = draw(st.floats(min(1000.0, top), top)) * draw(st.sampled_from([1, -1]))
    acc: float = draw(st.floats(1e5, 2e6))
    flat: float = draw(st.floats(0.0, 0.2))
    ramp = abs(v) / acc

    def trapezoid(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        up = np.minimum(t, ramp)
        cruise = np.clip(t - ramp, 0.0, flat)
        down = np.clip(t - ramp - flat, 0.0, ramp)
        return v * (up**2 / (2 * ramp) + cruise + down - down**2 / (2 * ramp))

    path = sample_path(trapezoid, duration=2 * ramp + flat, dt=dt, sample_period=ts)
    start = dmc.A.reference_position
    result = dmc.contour("A", path, dt=dt)
    profile = result.profiles["A"]
    assert profile.sample_period == ts
    assert len(profile.position) - 1 == len(path) << dt
    assert int(profile.position[-1]) == round(dmc.A.reference_position)
    assert dmc.A.reference_position == start + result.increments.sum()


def scenario_gearing(draw: Draw, dmc: Controller, tm: float) -> None:
    if len(dmc.model.axes) < 2:
        return
    a, b = dmc.A, dmc.B
    set_motion(dmc, "A", draw(speeds(tm)), draw(accels(tm)), draw(accels(tm)))
    ratio = draw(st.floats(-3, 3).filter(lambda g: abs(g) > 1e-3))
    gearing = b.gear_to(a, ratio)
    ends_as_predicted(dmc, a.move_by(draw(st.integers(-100_000, 100_000))))
    jog = a.jog(draw(speeds(tm, 500.0, 100_000.0)))
    dmc.sleep(draw(st.floats(0.05, 0.5)))
    jog.stop()
    ends_as_predicted(dmc, jog)
    gearing.off()


def scenario_homing(draw: Draw, dmc: Controller, tm: float) -> None:
    a = dmc.A
    set_motion(dmc, "A", draw(speeds(tm, 2000.0, 50_000.0)), draw(accels(tm)), draw(accels(tm)))
    hv = draw(speeds(tm, 200.0, 5000.0))
    a.home_speed = hv
    planned = settle(dmc.model.name, tm, "SP", hv)
    assert settle(dmc.model.name, tm, "SP", float(a.home_speed)) == planned
    kind = draw(st.sampled_from(["home", "find_edge", "find_index"]))
    if kind == "find_index":
        a.jog(draw(speeds(tm, 500.0, 5000.0)) * draw(st.sampled_from([1, -1]))).stop()
        dmc.sleep(1.0)
    switch = sim_of(dmc).home_switch("A")
    handle = getattr(a, kind)(switch=switch)
    ends_as_predicted(dmc, handle, exact=kind != "find_edge")


def scenario_capture(draw: Draw, dmc: Controller, tm: float) -> None:
    """Sample by sample (RC at servo rate), speeds down to the step at the TM in force."""
    a = dmc.A
    step = 2 * 1000 / tm
    sp = draw(st.one_of(speeds(tm, step, 10 * step), speeds(tm)))
    set_motion(dmc, "A", sp, draw(accels(tm, 1e4, 2e6)), draw(accels(tm, 1e4, 2e6)))
    reach = max(2, min(100_000, int(2 * sp)))  # (a move of at most about 2 s at speed)
    distance = draw(st.integers(1, reach)) * draw(st.sampled_from([1, -1]))
    plan = a.plan_by(distance)
    every = 2 ** draw(st.integers(1, 4))
    capture = dmc.capture(["_RPA"], every=every, seconds=plan.duration + 0.05)
    move = a.move_by(distance)
    recording = capture.wait()
    assert compare(move, recording)["A"].worst == 0
    ends_as_predicted(dmc, move)


def scenario_records(draw: Draw, dmc: Controller, tm: float) -> None:
    """A DR stream at its period in samples, compared with a jog sample by sample."""
    a = dmc.A
    set_motion(dmc, "A", draw(speeds(tm)), draw(accels(tm)), draw(accels(tm)))
    lo, hi = dmc.model.dr_range
    period = draw(st.integers(lo, min(hi, 64)))
    with dmc.records(period=period) as stream:
        jog = a.jog(draw(speeds(tm)) * draw(st.sampled_from([1, -1])))
        records = stream.take(draw(st.integers(5, 40)))
        jog.stop()
        ends_as_predicted(dmc, jog)
    assert stream.period == period
    assert stream.missed == 0
    assert (np.diff(records["time"]) == period).all()
    assert compare(jog, records)["A"].worst == 0


SCENARIOS: dict[str, Scenario] = {
    "moves": scenario_moves,
    "jog": scenario_jog,
    "increment": scenario_increment,
    "schedule": scenario_schedule,
    "vector": scenario_vector,
    "contour": scenario_contour,
    "gearing": scenario_gearing,
    "homing": scenario_homing,
    "capture": scenario_capture,
    "records": scenario_records,
}


@pytest.mark.parametrize("kind", sorted(SCENARIOS))
@SETTINGS
@given(data=st.data())
def test_predictions_hold_at_any_tm(kind: str, data: st.DataObject) -> None:
    name, tm = data.draw(model_and_tm(), label="model, tm")
    with controller(name, tm) as dmc:
        SCENARIOS[kind](data.draw, dmc, tm)
