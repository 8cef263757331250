"""Per-model controller facts, each in the model's spec and followed by library and simulator
(the review of the facts against the sourced references; docs/decisions/0102)."""

from __future__ import annotations

from typing import Any

import pytest

import galil
from galil.errors import InvalidArgument
from galil.models import MODELS, get_model, parse_identity
from galil.protocol import commands as cmds
from galil.protocol.numbers import parse_number
from galil.sim.controller import SimController
from galil.testing import nothing_sent, sim_of, simulated


def ask(sim: SimController, line: str) -> str:
    return sim.feed(line.encode() + b"\r").decode()


# ---- 1. inputs and outputs 9-16 on boards with more than 4 axes --------------------------


@pytest.mark.parametrize("name", ["DMC-2183", "DMC-1806", "DMC-1700", "DMC-4080", "DMC1886"])
def test_an_eight_axis_board_has_inputs_and_outputs_9_to_16(name: str) -> None:
    spec = get_model(name)
    assert (len(spec.axes), spec.digital_inputs, spec.digital_outputs) == (8, 16, 16)
    with simulated(name) as dmc:
        assert len(dmc.io.inputs) == 16
        dmc.io.outputs[16] = True
        assert dmc.io.outputs[16] is True


def test_every_entry_of_a_banked_family_follows_its_axis_count() -> None:
    for spec in MODELS.values():
        if spec.family.startswith(("DMC-1", "DMC-2", "DMC-4", "DMC-5")) and spec.axes:
            if spec.family in ("DMC-1500",):
                continue
            want = 8 if len(spec.axes) <= 4 else 16
            assert (spec.digital_inputs, spec.digital_outputs) == (want, want), spec.name


# ---- 2. a DMC-30010 before firmware 1.2a has 4 threads ----------------------------------


def test_a_30010_before_firmware_1_2a_has_four_threads_and_from_it_six() -> None:
    assert parse_identity("DMC30010 Rev 1.1b").model.threads == 4
    assert parse_identity("DMC31010 Rev 1.0a").model.threads == 4
    assert parse_identity("DMC30010 Rev 1.2a").model.threads == 6
    assert parse_identity("DMC30010 Rev 1.2c").model.threads == 6
    assert parse_identity("DMC4040 Rev 1.0a").model.threads == 8


def test_the_watchdog_of_an_old_30010_runs_on_a_thread_it_has() -> None:
    with simulated("DMC-30010", firmware="1.1b") as dmc:
        assert dmc.model.threads == sim_of(dmc).spec.threads == 4
        dog = dmc.watchdog(1.0)
        assert dog.thread == 3
        assert dog.running
        dog.stop()
        with pytest.raises(InvalidArgument, match=r"threads 0\.\.3"):
            dmc.programs.run("#A", thread=5)
    sim = SimController("DMC-30010", firmware="1.1b")
    assert ask(sim, "XQ #A,5") == "?"


# ---- 3. TM <= 0 turns the servo loop off: refused before sending -------------------------


@pytest.mark.parametrize("text", ["TM 0", "TM -1", "TM 0.0", "KP 1;TM -250"])
def test_tm_zero_or_negative_is_refused_before_sending_and_keeps_the_sample_period(
    text: str,
) -> None:
    with simulated("DMC-4040") as dmc:
        before = dmc.sample_period
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="servo loop off"):
            dmc.command(text, allow_compound=True)
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="servo loop off"):
            dmc.send(cmds.Command(text.split(";")[-1]))
        assert dmc.sample_period == before
        assert dmc.query_operands(["_TM"]) == [1000.0]


def test_the_simulator_takes_tm_zero_as_the_controller_does_turning_the_loop_off() -> None:
    sim = SimController("DMC-4040")
    assert ask(sim, "SH A") == ":"
    assert ask(sim, "TM 0") == ":"
    assert ask(sim, "MG _TM") == " 0.0000\r\n:"
    assert ask(sim, "MG _MOA") == " 1.0000\r\n:"


# ---- 4. TM's step: 31.25 µs -----------------------------------------------------------------


@pytest.mark.parametrize("model", ["DMC-4143", "DMC-4040"])
def test_a_tm_off_its_step_is_refused_before_sending(model: str) -> None:
    with simulated(model) as dmc:
        before = dmc.sample_period
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match=r"31\.25 µs"):
            dmc.command("TM 333")
        assert dmc.sample_period == before
        with pytest.raises(InvalidArgument, match=r"312\.5 or 343\.75"):
            cmds.tm(333, model=dmc.model)
        dmc.command("TM 312.5")
        assert dmc.sample_period == 312.5 / 1_024_000
        assert parse_number(dmc.command("MG _TM")) == 312.5


@pytest.mark.parametrize(
    "send",
    [
        lambda dmc: dmc.command("TM +500"),
        lambda dmc: dmc.command("TM 500;KP 5", allow_compound=True),
        lambda dmc: dmc.command("KP 5;TM 250;TM 500", allow_compound=True),
        lambda dmc: dmc.command_line(["KP 5", "TM +500"]),
        lambda dmc: dmc.send(cmds.Command("TM +500")),
    ],
    ids=["signed", "compound", "the-last-of-two", "command_line", "send"],
)
def test_every_tm_the_library_lets_through_is_followed(send: Any) -> None:
    # Before: a signed TM or one in a compound line was checked and sent but not followed:
    # the sample period stayed at TM 1000's, and a watchdog then fired at half its timeout.
    with simulated("DMC-4040") as dmc:
        send(dmc)
        assert parse_number(dmc.command("MG _TM")) == 500
        assert dmc.sample_period == 500 / 1_024_000


def test_a_tm_inside_a_quoted_string_is_text_not_a_tm() -> None:
    # Before: the line was split at every ';', quotes or not, and these were refused unsent.
    with simulated("DMC-4040") as dmc:
        before = dmc.sample_period
        assert dmc.command('MG "x;TM 0;y"').strip() == "x;TM 0;y"
        assert dmc.command('MG "set;TM 333;now"').strip() == "set;TM 333;now"
        assert dmc.sample_period == before


def test_the_simulator_takes_a_tm_off_the_step_down_to_it() -> None:
    sim = SimController("DMC-4040")
    assert ask(sim, "TM 333") == ":"
    assert ask(sim, "MG _TM") == " 312.5000\r\n:"


# ---- 5. the DMC-500x0 takes X, Y, Z, W for A-D ------------------------------------------


def test_a_500x0_takes_x_y_z_w_for_a_to_d() -> None:
    spec = get_model("DMC-50040")
    assert [spec.axis_letter(x) for x in "XYZW"] == list("ABCD")
    with simulated("DMC-50040") as dmc:
        dmc.command("PRX=1000")
        assert dmc.query_operands(["_PRA"]) == [1000.0]
        assert dmc.axis("X") is dmc.A


# ---- 6. the DMC-30010 has 4 digital outputs ------------------------------------------------


def test_a_30010_has_eight_inputs_and_four_outputs() -> None:
    spec = get_model("DMC-30010")
    assert (spec.digital_inputs, spec.digital_outputs) == (8, 4)
    with simulated("DMC-30010") as dmc:
        dmc.io.outputs[4] = True
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match=r"1 \.\. 4"):
            dmc.io.outputs[5] = True


# ---- 7. a RIO has no TM ---------------------------------------------------------------------


def test_a_rio_has_no_tm_the_library_refuses_it_and_the_simulator_does_not_know_it() -> None:
    spec = get_model("RIO-47120")
    assert not spec.tm_adjustable
    assert spec.sample_period_fixed == 0.0009765625
    with simulated("RIO-47120") as dmc:
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="fixed sample period"):
            dmc.command("TM 500")
        assert dmc.sample_period == 0.0009765625
        with pytest.raises(InvalidArgument, match="fixed sample period"):
            cmds.tm(500, model=dmc.model)
    sim = SimController("RIO-47120")
    assert ask(sim, "TM 500") == "?"
    assert ask(sim, "TC1") == " 1 Unrecognized command\r\n:"


# ---- 8. MT 4 / -4, "Servo 2PB" ----------------------------------------------------------------


def test_servo_2pb_is_taken_where_the_model_has_it_and_refused_before_sending_elsewhere() -> None:
    with simulated("DMC-4040") as dmc:
        dmc.motor_off("A")
        dmc.A.motor_type = galil.MotorType.SERVO_2PB
        assert dmc.A.motor_type is galil.MotorType.SERVO_2PB
        dmc.A.motor_type = galil.MotorType.SERVO_2PB_REVERSED
        assert dmc.A.motor_type is galil.MotorType.SERVO_2PB_REVERSED
    with simulated("DMC-1700") as dmc:
        dmc.motor_off("A")
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="MT"):
            dmc.A.motor_type = galil.MotorType.SERVO_2PB
    assert 4.0 in get_model("DMC-50040").motor_types
    assert 4.0 not in get_model("DMC-18x2").motor_types


# ---- 11. DR on the PCI DMC-18xx takes an exponent ----------------------------------------


@pytest.mark.parametrize("model", ["DMC-1846", "DMC-1842", "DMC-1806", "DMC-1800"])
def test_dr_is_not_built_as_a_period_for_a_pci_18xx(model: str) -> None:
    with pytest.raises(InvalidArgument, match=r"2\*\*n samples"):
        cmds.dr(2, 0, model=get_model(model))
    assert cmds.dr(8, 0, model=get_model("DMC-4040")).text == "DR 8,0"


# ---- 14. records() with no period says so ----------------------------------------------------


def test_records_with_no_period_asks_for_one_and_with_both_says_not_both() -> None:
    with simulated() as dmc:
        with nothing_sent(dmc), pytest.raises(InvalidArgument) as neither:
            dmc.records()
        assert "not both" not in str(neither.value)
        assert "records(8)" in str(neither.value)
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="not both"):
            dmc.records(8, seconds=0.01)


# ---- 15. TH exists only where Ethernet does --------------------------------------------------


@pytest.mark.parametrize("model", ["DMC-1500", "DMC-1846", "DMC-1700"])
def test_a_model_without_ethernet_does_not_know_th(model: str) -> None:
    sim = SimController(model)
    assert ask(sim, "TH") == "?"
    assert ask(sim, "TC1") == " 1 Unrecognized command\r\n:"
    assert "CONTROLLER IP ADDRESS" in ask(SimController("DMC-4040"), "TH")


# ---- 12, 13. unsourced SP maxima and program memory are listed as assumptions ---------------


@pytest.mark.parametrize(
    ("name", "sp"),
    [("DMC-18x2", "12,000,000"), ("DMC-1806", "22,000,000"), ("DMC-30010", "22,000,000")],
)
def test_an_unsourced_sp_maximum_is_listed_in_the_assumptions(name: str, sp: str) -> None:
    spec = get_model(name)
    assert spec.sp_max == int(sp.replace(",", ""))
    assert any("SP maximum" in a and sp in a for a in spec.assumptions)


def test_program_memory_is_the_familys_or_listed_as_assumed() -> None:
    assert get_model("DMC-2183").variables == 254  # "up to 254 variables" (DMC-2x00 manual)
    for spec in {s.name: s for s in MODELS.values()}.values():
        listed = [a for a in spec.assumptions if "program memory" in a]
        assert listed, f"{spec.name}: program memory neither sourced nor listed as assumed"


# ---- 10. DQ: the RIO-47120's analog output ranges ------------------------------------------


def test_dq_sets_a_rio_outputs_range_and_ao_follows_it() -> None:
    assert get_model("RIO-47120").dq_ranges[1] == (0.0, 5.0)
    with simulated("RIO-47120") as rio:
        rio.command("DQ 0,1")  # output 0 takes 0-5 V
        with pytest.raises(galil.CommandError):
            rio.io.analog_out[0] = -5
        rio.io.analog_out[0] = 4.5
        assert rio.io.analog_out[0].magnitude == 4.5
        rio.io.analog_out[1] = -5  # output 1 keeps ±10 V
        with nothing_sent(rio), pytest.raises(galil.LimitError):
            rio.io.analog_out[1] = 12
    sim = SimController("DMC-30010")
    assert ask(sim, "DQ 1,1") == "?"


# ---- 9. no HV on the Optima-era cards -------------------------------------------------------


@pytest.mark.parametrize("model", ["DMC-1500", "DMC-1700", "DMC-1842"])
def test_a_model_without_hv_refuses_home_speed_and_homes_at_its_own_slow_speed(
    model: str,
) -> None:
    spec = get_model(model)
    assert not spec.has_hv
    assert spec.home_slow_speed == 256
    with simulated(model) as dmc:
        a = dmc.A
        with nothing_sent(dmc), pytest.raises(InvalidArgument, match="has no HV"):
            a.home_speed = 1000
        with nothing_sent(dmc):
            assert a.home_speed == 256
        sim = sim_of(dmc)
        sim.set_servo_lag(0.0)
        homed = a.home(switch=sim.home_switch("A")).wait(timeout=600)
        # predicted at the model's slow speed, as the simulator runs it
        assert (homed.worst, homed.stop_codes) == (0, {"A": 10})
        assert not any("HV" in line for _, line in sim.command_log)
    sim_raw = SimController(model)
    assert ask(sim_raw, "HVA=500") == "?"
    assert ask(sim_raw, "MG _HVA") == "?"
