"""Today's controllers and the day-one API, in process (fast): models, homing, switches, I/O,
settings, the sample period, refusals before any byte."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import galil
from galil.models import get_model, parse_identity
from galil.notebook import compare
from galil.sim.controller import SimController
from galil.sim.rooms import Tuning
from galil.testing import nothing_sent, sim_of, simulated, transcript
from galil.units import ureg


@pytest.mark.parametrize(
    ("reply", "name", "family", "axes"),
    [
        ("DMC50040 Rev 1.2a", "DMC-50040", "DMC-500x0", "ABCD"),
        ("DMC50080 Rev 1.2a", "DMC-50080", "DMC-500x0", "ABCDEFGH"),
        ("DMC4240 Rev 1.2f", "DMC-4240", "DMC-42x0", "ABCD"),
        ("DMC4280 Rev 1.2f", "DMC-4280", "DMC-42x0", "ABCDEFGH"),
        ("RIO47120 Rev 1.1j", "RIO-47120", "RIO-47xxx", ""),
        ("RIO47102 Rev 1.1j", "RIO-47100", "RIO-47xxx", ""),
        ("RIO47122 Rev. 1.0", "RIO-47120", "RIO-47xxx", ""),
    ],
)
def test_current_families_are_known(reply: str, name: str, family: str, axes: str) -> None:
    spec = parse_identity(reply).model
    assert (spec.name, spec.family, spec.axes, spec.generic) == (name, family, axes, False)
    assert spec.assumptions  # every unconfirmed fact is listed
    assert spec.record_size is not None


def test_every_family_says_where_its_io_starts_and_how_much_it_has() -> None:
    assert get_model("DMC-4040").io_first == 1
    assert get_model("RIO-47120").io_first == 0
    assert get_model("DMC-4080").digital_inputs == 16
    assert get_model("RIO-47300").digital_outputs == 24
    assert get_model("DMC-50040").motor_types > get_model("DMC-4040").motor_types


@pytest.mark.parametrize(
    ("identity", "axes", "family"),
    [("DMC9940 Rev 1.0a", "ABCD", "generic"), ("DMC57060 Rev 1.0", "ABCDEF", "generic")],
)
def test_an_unknown_galil_connects_as_a_generic_model_with_a_warning(
    identity: str, axes: str, family: str
) -> None:
    sim = SimController("DMC-4040", identity=identity)
    with pytest.warns(RuntimeWarning, match="conservative limits"):
        dmc = galil.connect("sim://DMC-4040", controller=sim)
    with dmc:
        assert (dmc.model.family, dmc.model.axes, dmc.model.generic) == (family, axes, True)
        assert dmc.model.qz is None  # no record layout is guessed
        assert dmc.A.position == 0


def test_model_given_for_an_unknown_identity_picks_that_family() -> None:
    sim = SimController("DMC-4040", identity="DMC9940 Rev 1.0a")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with galil.connect("sim://DMC-4040", controller=sim, model="DMC-4040") as dmc:
            assert dmc.model.name == "DMC-4040"


BLISS_QUERIES = [
    "MG _BN",
    "QZ",
    "TPA",
    "MG _TPA",
    "TSA",
    "MG _SCA",
    "MG _BGA",
    "MG _LFA,_LRA,_HMA",
    "MG _MOA",
    "KP ?,?",
    "KD ?",
    "KI ?",
    "MT ?,?,?,?",
    "CN ?",
    "AC ?",
    "SP ?",
    "TL ?",
    "ER ?",
    "OE ?",
    "MG _TC",
    "MG @IN[1],@OUT[1]",
    "MG _TI0",
]


def test_a_50040_answers_bliss_style_queries_as_a_4040_does() -> None:
    old, new = SimController("DMC-4040"), SimController("DMC-50040")
    for text in BLISS_QUERIES:
        a = old.feed(text.encode() + b"\r")
        b = new.feed(text.encode() + b"\r")
        assert a == b, text
    assert new.feed(b"\x12\x16\r").startswith(b"DMC50040 Rev")


def test_home_predicts_from_the_simulators_switch_and_ends_at_zero() -> None:
    with simulated("DMC-4040") as dmc:
        sim = sim_of(dmc)
        sim.set_servo_lag(0.0)
        dmc.A.home_speed = 5000
        handle = dmc.A.home(switch=sim.home_switch("A"))
        assert handle.kind == "home"
        assert "exact" in handle.notes["A"]
        assert 0 < handle.duration < 10
        result = handle.wait()
        assert result.stop_codes == {"A": 10}
        assert result.deviation == {"A": 0}
        assert dmc.A.position == 0
        assert dmc.A.homed.homed


@pytest.mark.parametrize("start", ["home", "find_index"])
def test_an_accel_change_while_homing_is_followed_by_the_prediction(start: str) -> None:
    # (an AC in a homing left the prediction of BG's: a wait gave up at 1.5x it + 2 s)
    with simulated("DMC-4040") as dmc:
        sim = sim_of(dmc)
        sim.set_servo_lag(0.0)
        a = dmc.A
        a.speed, a.accel, a.decel, a.home_speed, a.jog_speed = 25_000, 20_480, 256_000, 256, 25_000
        began = dmc.link.clock()
        handle = getattr(a, start)(switch=sim.home_switch("A"))
        before = handle.duration
        dmc.sleep(0.05)
        a.accel = 1_024_000  # at speed sooner: further past the edge or index, back at HV
        assert handle.duration > before + 0.5
        if start == "find_index":  # (beyond the wait's default timeout for the old one)
            assert handle.duration > 1.5 * before + 2
        assert "exact" in handle.notes["A"]
        result = handle.wait()
        assert handle.duration <= dmc.link.clock() - began < handle.duration + 0.1
        assert result.stop_codes == {"A": 10}
        assert result.deviation == {"A": 0}
        assert a.position == 0


def test_homed_says_how_it_knows() -> None:
    with simulated("DMC-4040") as dmc:
        assert not dmc.A.homed
        assert "not 10" in dmc.A.homed.how
        dmc.command("HMA;BGA", allow_compound=True)  # behind the library's back
        while dmc.A.moving:
            dmc.sleep(0.5)
        assert dmc.A.homed
        assert "not started by this Controller" in dmc.A.homed.how


def test_a_homing_without_switch_positions_has_no_known_end() -> None:
    with simulated("DMC-4040") as dmc:
        handle = dmc.A.find_edge()
        assert handle.duration == float("inf")
        assert "unknown" in handle.notes["A"]
        assert handle.wait(timeout=30).stop_codes == {"A": 9}


def test_homing_refusals_send_nothing_but_the_state_query() -> None:
    with simulated("DMC-4040") as dmc:
        dmc.command("HVA=0")
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="HV 0"),
        ):
            dmc.A.home()
        dmc.command("HVA=256;JGA=0", allow_compound=True)
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="JG"),
        ):
            dmc.A.find_index()
        sim_of(dmc).set_limit_switch("A", "reverse", True)
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="reverse limit"),
        ):
            dmc.A.find_edge()  # the home input is high: FE drives in reverse


def test_switches_follow_cn_polarity_so_true_always_means_tripped() -> None:
    with simulated("DMC-4040") as dmc:
        sim = sim_of(dmc)
        sim.set_limit_switch("A", "forward", True)
        assert dmc.A.switches.forward_limit
        assert dmc.switch_polarity == galil.SwitchPolarity()
        dmc.switch_polarity = galil.SwitchPolarity(limit=1)  # the wiring says otherwise now
        assert dmc.switch_polarity.limit == 1
        assert not dmc.A.switches.forward_limit
        assert dmc.A.switches.reverse_limit


def test_io_slices_take_one_line_each() -> None:
    with simulated("DMC-4080") as dmc:
        sim_of(dmc).set_input(12, False)
        with transcript(dmc) as t:
            values = dmc.io.inputs[1:17]
            dmc.io.outputs[1:4] = [True, True, False]
        t.assert_sent(["MG _TI0,_TI1", "SB 1;SB 2;CB 3"])
        assert values == tuple(n != 12 for n in range(1, 17))
        assert [sim_of(dmc).output(n) for n in (1, 2, 3)] == [True, True, False]


def test_io_and_programs_say_what_the_model_has_without_asking_it() -> None:
    with simulated("RIO-47100") as rio, nothing_sent(rio):
        assert repr(rio.io) == "<IO of RIO-47100: 16 inputs, 16 outputs, 8 analog in, 8 analog out>"
        m = rio.link.model
        assert (
            repr(rio.programs)
            == f"<Programs of RIO-47100: {m.threads} threads, {m.program_lines} lines>"
        )


def test_io_refuses_channels_and_values_the_model_lacks_before_sending() -> None:
    with simulated("RIO-47100") as rio, nothing_sent(rio):
        with pytest.raises(galil.InvalidArgument):
            rio.io.inputs[16]
        with pytest.raises(galil.LimitError):
            rio.io.analog_out[0] = -1  # the RIO-47100's outputs are 0-5 V
        with pytest.raises(galil.InvalidArgument, match="not a voltage"):
            rio.io.analog_out[0] = 1 * ureg.mm
        with pytest.raises(galil.InvalidArgument):
            rio.io.outputs[0:2] = [True]


@pytest.mark.parametrize(
    "call",
    [
        lambda d: d.io.inputs["a":3],
        lambda d: d.io.inputs[1.0:3],
        lambda d: d.io.inputs[1:3.0],
        lambda d: d.io.outputs.__setitem__(slice(1, 3), True),
    ],
)
def test_io_refuses_wrong_types_as_invalid_argument_before_sending(call: object) -> None:
    with simulated() as dmc, nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        call(dmc)  # type: ignore[operator]


def test_io_takes_numpy_integers_and_bools() -> None:
    with simulated() as dmc:
        sim_of(dmc).set_input(2, False)
        assert dmc.io.inputs[np.int64(2)] is False
        assert dmc.io.inputs[np.int32(1) : np.int64(3)] == (True, False)
        dmc.io.outputs[np.int64(1)] = np.True_
        dmc.io.outputs[2:4] = np.array([True, False])
        dmc.io.outputs[np.int16(4)] = np.int64(1)
        assert [sim_of(dmc).output(n) for n in (1, 2, 3, 4)] == [True, True, False, True]
        dmc.io.wait_for_input(np.int64(2), high=np.False_, timeout=1)


def test_wait_for_input_returns_when_the_input_changes() -> None:
    with simulated("DMC-4040") as dmc:
        with pytest.raises(galil.GalilTimeoutError):
            dmc.io.wait_for_input(2, high=False, timeout=0.3)
        sim_of(dmc).set_input(2, False)
        start = dmc.link.clock()
        dmc.io.wait_for_input(2, high=False, timeout=5)
        assert dmc.link.clock() - start < 1.0


def test_settings_are_typed_and_refused_before_sending() -> None:
    with simulated("DMC-4040") as dmc:
        a = dmc.A
        dmc.motor_off("A")  # MT only with the motor off
        a.motor_type = galil.MotorType.STEPPER_ACTIVE_HIGH_REVERSED
        assert a.motor_type is galil.MotorType.STEPPER_ACTIVE_HIGH_REVERSED
        assert a.motor_type.stepper
        a.stepper_smoothing = 4
        a.integrator_limit, a.brush = 2.5, -1
        assert (a.stepper_smoothing, a.integrator_limit, a.brush) == (4.0, 2.5, -1)
        with nothing_sent(dmc):
            for name, bad in (
                ("motor_type", galil.MotorType.ETHERCAT_POSITION),  # a 500x0 type
                ("stepper_smoothing", 100),
                ("torque_limit", 10),
                ("off_on_error", 4),
                ("brush", 2),
                ("kd", True),
            ):
                with pytest.raises(galil.InvalidArgument):
                    setattr(a, name, bad)


def test_save_waits_as_long_as_a_flash_write_takes() -> None:
    with simulated("DMC-4040", timeout=0.1) as dmc:
        dmc.save()  # held 0.25 s: longer than the link timeout, within burn_timeout
        dmc.save_program()
        dmc.save_variables()
        assert sim_of(dmc).room(Tuning).burns == {"BN": 1, "BP": 1, "BV": 1}


def test_sample_period_follows_tm() -> None:
    with simulated("DMC-4040") as dmc:
        dmc.command("TM 500")
        assert dmc.sample_period == 500 / 1_024_000
        dmc.command_line(["TM 1000"])
        assert dmc.sample_period == 1000 / 1_024_000
        profile = dmc.A.plan_by(1000)
        assert profile.sample_period == 1000 / 1_024_000


def test_speed_and_accel_are_stored_in_the_steps_of_the_tm_in_force() -> None:
    # SP stays in counts/s under another TM, its step becomes 2*(1000/TM); AC's 1024*(1000/TM)**2
    # (DMC-4103 command reference; docs/decisions/0025). Host and simulator agree.
    with simulated("DMC-4040") as dmc:
        dmc.command("TM 250")
        dmc.A.speed = 25_005
        dmc.A.accel = 40_000
        assert (dmc.A.speed, dmc.A.accel) == (25_000, 32_768)
        assert sim_of(dmc).feed(b"MG _SPA,_ACA\r") == b" 25000.0000 32768.0000\r\n:"
        dmc.command("TM 1000")
        dmc.A.speed = 25_005
        assert dmc.A.speed == 25_004


@pytest.mark.parametrize("tm", [1500, 375, 187.5])
def test_a_jog_on_a_step_four_decimals_cannot_write_is_stored_as_predicted(tm: float) -> None:
    # (at TM 1500 SP/JG step by 4/3 counts/s: the host planned 111325.3333... and sent
    # "111325.3333", just short of the step, which the controller rounded down to the step
    # below: a 10 s jog then ended 14 counts from its prediction)
    step = 2 * 1000 / tm
    speed = step * 83_494
    with simulated("DMC-4040") as dmc, warnings.catch_warnings():
        warnings.simplefilter("error")  # (a deviation from the prediction warns)
        dmc.command(f"TM {tm}")
        handle = dmc.A.jog(speed)
        dmc.sleep(10.0)
        handle.stop()
        assert handle.wait().deviation == {"A": 0}
        dmc.A.speed = speed  # SP too, read back at four decimals
        assert dmc.A.speed == pytest.approx(speed, abs=1e-4)  # (as the controller writes it)
        assert dmc.A.move_by(-5_000_000).wait().deviation == {"A": 0}


@pytest.mark.parametrize(("model", "tm"), [("DMC-30010", 19875), ("DMC-41x3", 1156.25)])
def test_a_speed_read_back_and_set_again_stays_on_its_step(model: str, tm: float) -> None:
    # (the controller holds SP in 32.16 fixed point and prints it at four decimals: at TM
    # 19875 the step 1038.79245... prints as 1038.7924, 5.3e-5 short of it, which the host
    # took for the step below: `x.speed = x.speed` slowed the axis by a step)
    with simulated(model) as dmc:
        dmc.command(f"TM {tm}")
        a = dmc.A
        a.speed, a.accel, a.decel = 1038.875, 68_059, 20_044.4
        before = dmc.query_operands(["_SPA", "_ACA", "_DCA"])
        a.speed, a.accel, a.decel = a.speed, a.accel, a.decel
        assert dmc.query_operands(["_SPA", "_ACA", "_DCA"]) == before


def test_a_move_below_tm_1000s_speed_step_is_predicted_at_its_own_speed() -> None:
    # (at TM 4000 SP steps by 0.5 counts/s, but the move was predicted at no less than TM
    # 1000's 2 counts/s: SP 1.5 over 6 counts ended 1 s early, the reference 2 counts ahead)
    with simulated("DMC-4040") as dmc, warnings.catch_warnings():
        warnings.simplefilter("error")
        dmc.command("TM 4000")
        a = dmc.A
        a.speed, a.accel, a.decel = 1.5, 300.0, 300.0
        plan = a.plan_by(6)
        assert plan.peak_speed == pytest.approx(1.5)
        capture = dmc.capture(["_RPA"], every=2, seconds=plan.duration + 0.5)
        move = a.move_by(6)
        assert move.wait().deviation == {"A": 0}
        assert compare(move, capture.wait())["A"].worst == 0


def test_motion_planned_with_read_back_values_uses_the_stored_steps() -> None:
    # (a move, a jog, a schedule and a homing read SP/AC/DC/JG/HV back at four decimals and
    # planned with that text: at TM 1656.25, SP 2.41509... read 2.4151 and DC 9705.58063...
    # read 9705.5806, and the reference reached the target a sample before the controller's)
    with simulated("DMC-4040") as dmc:
        dmc.command("TM 1656.25")
        a = dmc.A
        a.speed, a.accel, a.decel = 3.0, 142_225.0, 10_000.0
        sim = sim_of(dmc)
        t0 = sim.start_trace("A")
        move = a.move_by(6)
        move.wait()
        trace = sim.stop_trace("A")["A"]
        k = move.begin["A"] - t0
        p = move.profiles["A"].position
        assert (trace[k : k + p.size] == p).all()
        params = move._tracks["A"].params  # (what the host planned with: the stored steps)
        step, accel_step = 2 * 1000 / 1656.25, 1024 * (1000 / 1656.25) ** 2
        assert params.speed == pytest.approx(2 * step, abs=1e-9)
        assert params.decel == pytest.approx(int(10_000 / accel_step) * accel_step)


def test_the_30010s_two_analog_outputs_and_inputs_are_driven_and_recorded() -> None:
    with simulated("DMC-30010") as dmc:
        dmc.io.analog_out[2] = -2.5 * ureg.volt
        assert dmc.io.analog_out[2].to("V").magnitude == -2.5
        assert sim_of(dmc).analog_output(2) == -2.5
        sim_of(dmc).set_analog_input(2, 1.5)
        assert dmc.io.analog_in[2].to("V").magnitude == pytest.approx(1.5, abs=1e-3)
        record = dmc.record()
        assert record["analog_out"].tolist() == [0, round(-2.5 * 3276.8)]
        assert record["analog_in"] == round(1.5 * 13107.2)  # (input 2: 0-5 V, unsigned)
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.io.analog_out[3] = 1.0  # it has two


def test_an_analog_input_reads_the_range_its_aq_code_sets_and_the_record_follows() -> None:
    # (the simulator kept AQ but read every input over its power-on range: 7.5 V at AQ 1)
    with simulated("DMC-4040") as dmc:
        sim, analog_in = sim_of(dmc), dmc.io.analog_in
        sim.set_analog_input(1, 7.5)
        assert analog_in[1].to("V").magnitude == 7.5
        dmc.command("AQ 1,1")  # ±5 V
        assert dmc.query_number("MG _AQ1") == 1
        assert analog_in[1].to("V").magnitude == 5.0
        assert dmc.record()["A"]["analog_in"] == 0x7FFF  # the top count of ±5 V
        dmc.command("AQ 1,4")  # 0-10 V
        sim.set_analog_input(1, -3.0)
        assert analog_in[1].to("V").magnitude == 0.0
        assert dmc.record()["A"]["analog_in"] == 0
        assert dmc.model.analog_input_range(1) == (-10.0, 10.0)  # (at the default AQ)


def test_the_rio_47100_reads_by_aq_0_and_1_and_refuses_the_others() -> None:
    with simulated("RIO-47100") as rio:
        sim_of(rio).set_analog_input(3, -2.5)
        assert rio.io.analog_in[3].to("V").magnitude == 0.0  # AQ 0: 0-5 V
        rio.command("AQ 3,1")  # ±5 V (RIO-47xxx user manual p.44)
        assert rio.io.analog_in[3].to("V").magnitude == -2.5
        with pytest.raises(galil.CommandError) as caught:
            rio.command("AQ 3,2")
        assert caught.value.code == 6
        rio.command("AQ 3,0")
        assert rio.query_number("MG _AQ3") == 0


def test_the_30010s_second_analog_input_reads_0_to_5_volts_and_its_first_10() -> None:
    # (the simulator clipped both to ±10 V: input 2 read 7 V, and -2 V)
    with simulated("DMC-30010") as dmc:
        sim, analog_in = sim_of(dmc), dmc.io.analog_in
        for volts, seen in [(7.0, 5.0), (-2.0, 0.0), (5.0, 5.0), (3.25, 3.25)]:
            sim.set_analog_input(2, volts)
            assert analog_in[2].to("V").magnitude == pytest.approx(seen, abs=1e-4)
        assert dmc.record()["analog_in"] == round(3.25 * 13107.2)
        sim.set_analog_input(2, 5.0)
        assert dmc.record()["analog_in"] == 0xFFFF  # (the top count, not a wrap to 0)
        sim.set_analog_input(1, -12.0)
        assert analog_in[1].to("V").magnitude == -10.0
        sim.set_analog_input(1, 7.0)
        assert analog_in[1].to("V").magnitude == 7.0
        assert dmc.model.analog_input_range(2) == (0.0, 5.0)  # (the one place it is said)
        assert dmc.model.analog_input_range(1) == (-10.0, 10.0)
