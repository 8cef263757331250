"""What labs' programs use most, on ``sim://`` through the public API (decision 0029).

Trippoints ``AP``/``AR``/``AV``, the subroutine stack (``JS``, ``EN``, ``ZS``), the automatic
subroutines (``#LIMSWI``, ``#POSERR``, ``#ININT``, ``#MCTIME``, ``#CMDERR``, ``#AUTO``) with
``RE``/``RI``, and what ``OE`` does. Programs are downloaded and run with ``dmc.programs``; a
test hook (``galil.testing.sim_of``) only places switches and drives inputs.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from program_helpers import drain_messages, run_program

import galil
from galil.sim.controller import SimController
from galil.testing import sim_of, simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        yield controller


def test_a_limit_switch_runs_limswi_and_re_1_goes_back_to_the_interrupted_am(
    dmc: galil.Controller,
) -> None:
    sim_of(dmc).place_limit_switches("A", forward=1500)
    lines = run_program(
        dmc,
        '#M\nPR 3000;BG A\nAM A\nMG "done",_SCA\nEN\n#LIMSWI\nMG "limit",_SCA,_LFA\nRE 1',
    )
    assert lines == ["limit 2.0000 0.0000", "done 2.0000"]
    assert dmc.A.stop_code[0] == 2


def test_a_soft_limit_runs_limswi_too_and_re_0_drops_the_trippoint(
    dmc: galil.Controller,
) -> None:
    lines = run_program(
        dmc,
        '#M\nFL 1500;JG 5000;BG A\nWT 5000\nMG "after",_BGA\nEN\n#LIMSWI\nMG "soft"\nRE 0',
    )
    # RE 0: the WT was dropped, so "after" comes while the axis is still decelerating.
    assert lines == ["soft", "after 1.0000"]


def test_without_a_running_program_a_limit_runs_no_routine(dmc: galil.Controller) -> None:
    dmc.programs.download('#LIMSWI\nMG "limit"\nRE')
    sim_of(dmc).place_limit_switches("A", forward=1500)
    with pytest.raises(galil.MotionError):
        dmc.A.move_by(3000).wait()
    assert dmc.A.stop_code[0] == 2
    assert dmc.programs.threads == {}
    assert drain_messages(dmc) == []


def test_a_position_error_beyond_er_with_oe_1_turns_the_motor_off_and_runs_poserr(
    dmc: galil.Controller,
) -> None:
    a = dmc.A
    a.error_limit = 40
    a.off_on_error = 1
    lines = run_program(
        dmc,
        '#M\nJG 30000;BG A\nWT 300\nEN\n#POSERR\nMG "poserr",_MOA,_SCA\nRE',
    )
    assert lines == ["poserr 1.0000 8.0000"]
    assert not a.motor_on
    assert a.stop_code[0] == 8
    assert abs(a.error) > 40


def test_with_oe_0_a_position_error_runs_poserr_and_the_motor_stays_on(
    dmc: galil.Controller,
) -> None:
    dmc.A.error_limit = 40
    lines = run_program(dmc, '#M\nJG 30000;BG A\nWT 300\nST A;AM A\nEN\n#POSERR\nMG "E"\nRE 1')
    assert lines == ["E"]
    assert dmc.A.motor_on
    assert dmc.A.stop_code[0] == 4


def test_oe_1_turns_the_motors_off_at_an_abort(dmc: galil.Controller) -> None:
    dmc.A.off_on_error = 1
    dmc.command_line(["JG 5000,5000", "BG AB"])
    dmc.sleep(0.1)
    dmc.command("AB")
    assert not dmc.A.motor_on
    assert dmc.B.motor_on


def test_oe_2_turns_the_motor_off_at_a_limit_switch_instead_of_stopping(
    dmc: galil.Controller,
) -> None:
    sim_of(dmc).place_limit_switches("A", forward=1500)
    dmc.A.off_on_error = 2
    dmc.command_line(["JG 20000", "BG A"])
    dmc.sleep(0.5)
    assert not dmc.A.motor_on
    assert dmc.A.stop_code[0] == 2
    assert dmc.A.position < 1600  # no deceleration ramp past the switch


def test_an_input_interrupt_runs_inint_and_ri_1_goes_back_to_the_wait(
    dmc: galil.Controller,
) -> None:
    # The interrupt is level-triggered: RI 1 arms it again, so the routine waits out the
    # input's bounce (the reference's own example does WT 100).
    program = '#M\nII 1,1,,0\nWT 300\nMG "main"\nEN\n#ININT\nMG "in",@IN[1]\nWT 100\nRI 1'
    dmc.programs.download(program)
    dmc.programs.run("#M", thread=0)
    dmc.sleep(0.1)
    sim_of(dmc).set_input(1, False)
    dmc.sleep(0.05)
    sim_of(dmc).set_input(1, True)
    dmc.programs.wait(0)
    assert drain_messages(dmc) == ["in 0.0000", "main"]


def test_a_command_error_runs_cmderr_and_thread_0_goes_on_after_the_command(
    dmc: galil.Controller,
) -> None:
    lines = run_program(
        dmc,
        '#M\nMG "a"\nPR 9999999999\nMG "b"\nEN\n#CMDERR\nMG "error",_TC,_ED\nEN',
    )
    assert lines == ["a", "error 6.0000 2.0000", "b"]


def test_a_command_error_in_another_thread_stops_it_and_runs_cmderr_on_thread_0(
    dmc: galil.Controller,
) -> None:
    dmc.programs.download('#T\nPR 9999999999\nMG "never"\nEN\n#CMDERR\nMG "error",_ED1\nEN')
    dmc.programs.run("#T", thread=2)
    dmc.programs.wait(2)
    dmc.programs.wait(0)
    assert drain_messages(dmc) == ["error 2.0000"]


def test_an_mc_that_times_out_sets_stop_code_99_and_runs_mctime(dmc: galil.Controller) -> None:
    sim_of(dmc).set_servo_lag(0.05, "A")
    lines = run_program(
        dmc, '#M\nTW 20\nPR 1000;BG A\nMC A\nMG "mc"\nEN\n#MCTIME\nMG "late",_SCA\nEN'
    )
    assert lines == ["late 99.0000", "mc"]


def test_ap_ar_and_av_release_where_the_reference_says(dmc: galil.Controller) -> None:
    lines = run_program(
        dmc,
        "#M\nJG 20000;BG A\nAD 2000\nAR 1000\nAR 1000\nr=_RPA\nAP 6000\np=_TPA\nST A;AM A\n"
        "VM BC;VP 3000,4000;VE;BG S\nAV 2000\nv=_AVS\nAM S\n"
        "MG p>=6000,r>=4000,r<4050,v>=2000,v<2050\nEN",
    )
    assert lines == ["1.0000 1.0000 1.0000 1.0000 1.0000"]


def test_js_calls_a_subroutine_that_returns_a_value_and_zs_leaves_it(
    dmc: galil.Controller,
) -> None:
    lines = run_program(
        dmc,
        '#M\nJS #SQ\nMG _JS\nJS #Z\nMG "not here"\nEN\n#SQ\nEN ,,7*7\n#Z\nZS\nMG "zeroed",_ZS0\nEN',
    )
    assert lines == ["49.0000", "zeroed 0.0000"]


def test_rs_starts_the_auto_label() -> None:
    # Through the simulator's own port: RS sets CW back, so a link would read the message as
    # a reply (as it would from a controller).
    sim = SimController("DMC-4040")
    sim.feed(b'DL\r#AUTO\rMG "auto"\rEN\r\\BP\r')
    assert sim.advance_until_output(1.0) == b":"  # (the burn holds its ':' a while)
    assert sim.feed(b"RS\r") == b":auto\r\n"
