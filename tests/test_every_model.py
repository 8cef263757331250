"""Every model family through every room, on the in-process simulator (manual clock).

One representative of each family in :data:`galil.models.MODELS` (the first entry of each
family, so a family added there is walked too), RIO and the one-axis DMC-30010 included. What
a model has is read from its :class:`~galil.models.ModelSpec`, never from a table here; what
it lacks must be refused up front, with a typed error and nothing sent.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

import galil
from galil.models import MODELS, MOTOR_TYPES, ModelSpec
from galil.protocol import commands as cmds
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, sim_of, simulated
from galil.tuning import MotorType
from galil.watchdog import watchdog_routine


def _representatives() -> list[ModelSpec]:
    first: dict[str, ModelSpec] = {}
    for spec in MODELS.values():
        first.setdefault(spec.family, spec)
    return list(first.values())


FAMILIES = _representatives()
MOTION = [s for s in FAMILIES if s.has_axes]
EVERY_NAME = list({s.name: s for s in MODELS.values()}.values())  # each table entry once
EVERY = pytest.mark.parametrize("spec", FAMILIES, ids=lambda s: s.name)
MOVING = pytest.mark.parametrize("spec", MOTION, ids=lambda s: s.name)


@pytest.fixture
def dmc(spec: ModelSpec) -> Iterator[galil.Controller]:
    with simulated(spec.name) as controller:
        sim_of(controller).set_servo_lag(0.0)
        yield controller


def test_the_walk_covers_every_family_rio_and_the_one_axis_model() -> None:
    families = {s.family for s in FAMILIES}
    assert families == {s.family for s in MODELS.values()}
    assert any(not s.has_axes for s in FAMILIES)
    assert any(len(s.axes) == 1 for s in FAMILIES)


@EVERY
def test_every_family_connects_and_names_itself(spec: ModelSpec, dmc: galil.Controller) -> None:
    assert (dmc.model.name, dmc.model.family) == (spec.name, spec.family)
    assert dmc.sample_period == spec.sample_period
    assert dmc.query_operands(["_TM"]) == [spec.tm_default]


@MOVING
def test_settings_land_on_the_models_grid_even_at_the_least_smoothing(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    a = dmc.A
    a.speed, a.accel, a.decel = spec.sp_max, spec.ac_max, spec.ac_min
    assert (a.speed, a.accel, a.decel) == (spec.sp_max, spec.ac_max, spec.ac_min)
    # IT 0.004, the least IT takes, is held as 1/256 (read 0.0039): it was refused
    a.smoothing = spec.it_range[0]
    assert a.smoothing == 0.0039
    a.speed, a.accel, a.decel = 40_000, 1_024_000, 1_024_000
    result = a.move_by(3000).wait()
    assert (result.worst, result.final) == (0, {"A": 3000})
    with nothing_sent(dmc):
        with pytest.raises(galil.LimitError):
            a.speed = spec.sp_max + 1000
        with pytest.raises(galil.LimitError):
            a.smoothing = 0.003


@MOVING
def test_tm_changes_where_the_model_allows_and_predictions_follow_it(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    if not spec.tm_adjustable:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="fixed sample"):
            dmc.send(cmds.tm(500, model=dmc.model))
        return
    tm = max(500.0, spec.tm_range[0])
    dmc.send(cmds.tm(tm, model=dmc.model))  # a prepared TM: predictions followed only raw ones
    assert dmc.sample_period == tm / 1_024_000
    a = dmc.A
    a.speed, a.accel, a.decel = 30_000, 512_000, 512_000
    handle = a.move_by(7777)
    start = dmc.query_operands(["TIME"])[0]
    result = handle.wait()
    assert result.worst == 0
    took = dmc.query_operands(["TIME"])[0] - start
    assert abs(took * dmc.sample_period - handle.duration) < 0.05


@MOVING
def test_moves_jogs_increments_and_schedules_end_where_predicted(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    a = dmc.A
    a.speed, a.accel, a.decel = 50_000, 512_000, 512_000
    moved = a.move_by(10_000).wait()
    assert (moved.worst, moved.stop_codes) == (0, {"A": 1})
    assert a.move_to(-3000).wait().final == {"A": -3000}
    jog = a.jog(20_000)
    dmc.sleep(0.2)
    a.stop()
    stopped = jog.wait()
    assert (stopped.worst, stopped.stop_codes) == (0, {"A": 4})
    assert a.increment(1000).wait().worst == 0
    scheduled = a.speed_schedule(40_000, [(20_000, 10_000)], speed=30_000).wait()
    assert scheduled.worst == 0
    assert scheduled.final == {"A": stopped.final["A"] + 1000 + 40_000}


@MOVING
def test_homing_finds_the_simulated_switch(spec: ModelSpec, dmc: galil.Controller) -> None:
    a, sim = dmc.A, sim_of(dmc)
    if spec.has_hv:  # (the Optima-era cards have none: their own slow speed)
        a.home_speed = 20_000
    homed = a.home(switch=sim.home_switch("A")).wait(timeout=60)
    assert (homed.worst, homed.stop_codes) == (0, {"A": 10})
    assert a.position == 0
    assert a.homed
    assert a.find_edge(switch=sim.home_switch("A")).wait(timeout=60).stop_codes == {"A": 9}
    assert a.find_index(switch=sim.home_switch("A")).wait(timeout=60).stop_codes == {"A": 10}


@MOVING
def test_limit_switches_stop_a_jog_and_soft_limits_refuse_outward_moves(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    a = dmc.A
    a.soft_limits = (-5000, 5000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError):
        a.move_to(6000)
    a.soft_limits = (None, None)
    jog = a.jog(50_000)
    dmc.sleep(0.1)
    sim_of(dmc).set_limit_switch("A", "forward", True)
    with pytest.raises(galil.MotionError):
        jog.wait(timeout=5)
    assert a.stop_code[0] == 2
    assert a.switches.forward_limit
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument):
        a.jog(10_000)  # on into the active switch: refused, not sent to meet TC 22
    a.jog(-10_000).stop()  # off it: fine


@MOVING
def test_limit_disable_where_the_model_has_it_and_refused_unsent_where_not(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    a = dmc.A
    sim_of(dmc).set_limit_switch("A", "forward", True)
    if not spec.has_limit_disable:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="has no LD"):
            a.limit_disable = galil.LimitDisable.FORWARD
        return
    a.limit_disable = galil.LimitDisable.FORWARD
    assert a.limit_disable is galil.LimitDisable.FORWARD
    jog = a.jog(10_000)  # towards the active switch, which no longer stops it
    dmc.sleep(0.1)
    a.stop()
    assert jog.wait().stop_codes == {"A": 4}
    assert a.switches.forward_limit


@MOVING
def test_a_contour_ends_where_its_path_does(spec: ModelSpec, dmc: galil.Controller) -> None:
    path = np.round(2000 * (1 - np.cos(np.linspace(0, np.pi, 20))) / 2)
    result = dmc.contour("A", path, dt=2)
    assert result.begin is not None
    assert dmc.A.reference_position == path[-1]
    low, high = spec.cd_range
    for beyond in (low - 1, high + 1):
        with nothing_sent(dmc), pytest.raises(galil.LimitError):
            dmc.contour("A", [beyond], dt=1)
    with nothing_sent(dmc), pytest.raises(galil.LimitError):
        dmc.contour("A", [1, 2], dt=spec.dt_range[1] + 1)


@MOVING
def test_vector_moves_and_gearing_where_the_model_has_two_axes(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    if len(spec.axes) < 2:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="does not exist"):
            dmc.vector_move("AB", [galil.Line(3000, 4000)], speed=20_000)
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="does not exist"):
            dmc.A.gear_to("B", 0.5)
        return
    smoothing = spec.it_range[0] if spec.vt else None
    line = dmc.vector_move("AB", [galil.Line(3000, 4000)], speed=20_000, smoothing=smoothing)
    assert line.wait().final == {"A": 3000, "B": 4000}
    if not spec.vt:
        with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument):
            dmc.vector_move("AB", [galil.Line(1000, 0)], speed=20_000, smoothing=0.5)
    gearing = dmc.B.gear_to("A", 0.5)
    result = dmc.A.move_by(2000).wait()
    assert result.worst == 0
    assert result.follower_final == {"B": 4000 + 1000}
    gearing.off()


@EVERY
def test_io_within_the_model_and_refused_beyond_it(spec: ModelSpec, dmc: galil.Controller) -> None:
    io, first = dmc.io, spec.io_first
    io.outputs[first] = True
    assert io.outputs[first] is True
    sim_of(dmc).set_input(first + 1, False)
    assert io.inputs[first : first + 3] == (True, False, True)
    sim_of(dmc).set_analog_input(first, 1.5)
    assert io.analog_in[first].to("V").magnitude == pytest.approx(1.5, abs=1e-3)
    if spec.analog_outputs:
        io.analog_out[first] = 1.0
        assert io.analog_out[first].to("V").magnitude == pytest.approx(1.0, abs=1e-3)
    with nothing_sent(dmc):
        with pytest.raises(galil.InvalidArgument):
            io.outputs[first + spec.digital_outputs] = True
        with pytest.raises(galil.InvalidArgument):
            io.inputs[first + spec.digital_inputs]
        with pytest.raises(galil.InvalidArgument):
            io.analog_in[first + spec.analog_inputs]
        with pytest.raises(galil.InvalidArgument):
            io.analog_out[first + spec.analog_outputs] = 1.0


@MOVING
def test_gains_and_motor_types_within_the_models_ranges(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    a = dmc.A
    a.kp, a.ki, a.kd = spec.kp_max, spec.ki_max, spec.kd_max
    assert (a.kp, a.kd) == (spec.kp_max, spec.kd_max)
    assert a.ki == pytest.approx(spec.ki_max, abs=2 * spec.ki_resolution)  # printed to 0.001
    a.integrator_limit, a.torque_limit = spec.il_min, spec.tl_max
    a.error_limit = spec.er_min
    assert (a.integrator_limit, a.torque_limit, a.error_limit) == (
        spec.il_min,
        spec.tl_max,
        spec.er_min,
    )
    dmc.motor_off("A")  # MT only with the motor off
    for mt in sorted(spec.motor_types):
        a.motor_type = MotorType(mt)
        assert a.motor_type == MotorType(mt)
    with nothing_sent(dmc):
        for mt in sorted(set(MOTOR_TYPES) - spec.motor_types):
            with pytest.raises(galil.InvalidArgument):
                a.motor_type = MotorType(mt)
        for name, bad in (("kp", spec.kp_max + 1), ("ki", spec.ki_max + 1)):
            with pytest.raises(galil.LimitError):
                setattr(a, name, bad)


@EVERY
def test_programs_threads_arrays_and_variables(spec: ModelSpec, dmc: galil.Controller) -> None:
    dmc.programs.download("#A\nnzk=5\nEN\n#B\nWT 100\nnzk=nzk+1\nEN\n")
    dmc.programs.run("#A")
    dmc.programs.wait(0)
    last = spec.threads - 1
    dmc.programs.run("#B", thread=last)
    assert list(dmc.programs.threads) == [last]
    dmc.programs.wait(last)
    assert dmc.variables.read("nzk") == 6
    dmc.variables.write("nzj", 3.5)
    assert dmc.variables.read("nzj") == 3.5
    dmc.arrays.define("xs", 10)
    dmc.arrays.download("xs", list(range(10)))
    assert list(dmc.arrays.upload("xs")) == list(range(10))
    with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.InvalidArgument):
        dmc.programs.run("#A", thread=spec.threads)
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="characters"):
        dmc.programs.download("#A\nnzk=" + "1" * spec.line_length + "\nEN\n")


@EVERY
def test_data_records_where_the_model_has_them(spec: ModelSpec, dmc: galil.Controller) -> None:
    if spec.qz is None:  # QZ went out (and was refused) before the refusal
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="no binary data"):
            dmc.record()
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="no binary data"):
            dmc.records(64)
        return
    rec = dmc.record()
    assert rec["size"] == spec.record_size
    period = 4 * spec.dr_range[0]
    with dmc.records(period, method="QR") as stream:
        got = stream.take(3, timeout=5)
    assert np.all(np.diff(got["time"]) == period)


@MOVING
def test_a_capture_is_the_moves_prediction(spec: ModelSpec, dmc: galil.Controller) -> None:
    a = dmc.A
    plan = a.plan_by(2000)
    capture = dmc.capture(["_RPA"], every=2, seconds=plan.duration)
    move = a.move_by(2000)
    recording = capture.wait()
    begin = move.begin["A"]
    assert begin is not None
    k = recording.samples - begin
    inside = (k >= 0) & (k <= plan.samples)
    np.testing.assert_array_equal(recording["_RPA"][inside], plan.position[k[inside]])
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        dmc.capture(["_RPA"], every=2 ** (spec.record_exponents[1] + 1), count=10)


@EVERY
def test_the_watchdog_stops_motion_and_a_rio_has_none_to_stop(
    spec: ModelSpec, dmc: galil.Controller
) -> None:
    if not spec.has_axes:  # its routine's MG line was 49 characters, past the RIO's 40
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="no axes"):
            dmc.watchdog(0.5)
        return
    dog = dmc.watchdog(0.5)
    dmc.A.jog(20_000)
    dmc.sleep(1.0)
    assert not dog.fired
    sim_of(dmc).advance(0.8)  # the host falls silent
    assert dog.fired
    assert dmc.A.stop_code[0] == 4


@pytest.mark.parametrize("spec", EVERY_NAME, ids=lambda s: s.name)
def test_the_watchdog_routine_fits_every_models_lines_and_messages(spec: ModelSpec) -> None:
    if not spec.has_axes:
        return  # refused there
    routine = watchdog_routine(spec.axes)
    assert max(len(line) for line in routine.lines) <= spec.line_length
    for line in routine.lines:
        if line.startswith('MG "'):
            assert len(line) - len('MG ""') <= spec.mg_max  # DMC-1500: 31


@EVERY
def test_interrupts_and_dr_records_come_over_ethernet_only(spec: ModelSpec) -> None:
    with SimTcpServer(model=spec.name) as server, galil.connect(server.url) as dmc:
        if "ethernet" not in spec.transports:
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="Ethernet"):
                dmc.interrupts.enable()
            return
        dmc.interrupts.enable(all_done=bool(spec.axes))
        assert dmc.interrupts.enabled
        if spec.axes:
            dmc.A.move_by(300).wait(timeout=5)
            assert "all done" in str(dmc.interrupts.get(timeout=5))
        dmc.interrupts.disable()
        if spec.qz is not None:
            with dmc.records(spec.dr_range[0] * 4, method="DR") as stream:
                assert len(stream.take(2, timeout=5)) == 2


@EVERY
def test_reset_brings_back_the_power_on_state(spec: ModelSpec, dmc: galil.Controller) -> None:
    dmc.io.outputs[spec.io_first] = True
    if spec.axes:
        dmc.A.speed = 40_000
    dmc.reset()
    assert dmc.io.outputs[spec.io_first] is False
    assert dmc.sample_period == spec.sample_period
    if spec.axes:
        assert dmc.A.speed == spec.default_speed
