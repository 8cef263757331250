"""LD (limit disable) in the simulator: the command and its operand, what a disabled switch
no longer does (stop, refuse a start, run #LIMSWI) and what it still does (read as an input),
and the soft limits that LD leaves on (decision 0046)."""

from __future__ import annotations

import pytest

from galil.sim.controller import SimController

TS = 1 / 1024  # seconds per servo sample at TM 1000


def sim(model: str = "DMC-4040") -> SimController:
    return SimController(model, servo_lag=0.0)


def ask(s: SimController, line: str) -> bytes:
    return s.feed(line.encode() + b"\r")


def values(s: SimController, line: str) -> list[float]:
    reply = ask(s, line)
    assert b"?" not in reply, reply
    assert reply.endswith(b":"), reply
    return [float(v) for v in reply[:-1].replace(b",", b" ").split()]


def test_ld_takes_every_form_and_reads_back_per_axis() -> None:
    s = sim()
    assert ask(s, "LD ?") == b" 0\r\n:"  # default: both switches on
    assert ask(s, "LDA=1") == b":"
    assert ask(s, "LD ,2,3") == b":"
    assert ask(s, "LD ?,?,?,?") == b" 1, 2, 3, 0\r\n:"
    assert values(s, "MG _LDA,_LDB,_LDC,_LDD") == [1, 2, 3, 0]


@pytest.mark.parametrize("bad", ["4", "-1", "1.5"])
def test_ld_outside_0_to_3_is_refused_with_tc_6(bad: str) -> None:
    s = sim()
    assert ask(s, f"LDA={bad}") == b"?"
    assert ask(s, "TC 1").startswith(b" 6 ")
    assert values(s, "MG _LDA") == [0]


@pytest.mark.parametrize("model", ["DMC-2183", "DMC-18x2", "DMC-1700", "DMC-1500"])
def test_a_model_without_ld_refuses_it_and_its_operand_as_unknown(model: str) -> None:
    s = sim(model)
    for line in ("LDA=1", "LD ?", "MG _LDA"):
        assert ask(s, line) == b"?"
        assert ask(s, "TC 1").startswith(b" 1 ")


@pytest.mark.parametrize(("ld", "runs_through"), [(0, False), (1, True), (2, False), (3, True)])
def test_a_jog_into_a_placed_forward_switch_runs_through_it_when_ld_disables_it(
    ld: int, runs_through: bool
) -> None:
    s = sim()
    s.place_limit_switches("A", forward=2000, reverse=-2000)
    ask(s, f"LDA={ld};JG 20000;BG A")
    s.advance(0.5)
    tp, bg, sc, lf, ts = values(s, "MG _TPA,_BGA,_SCA,_LFA,_TSA")
    assert lf == 0  # the input reads active either way
    assert not int(ts) & 0x08
    if runs_through:
        assert (bg, sc) == (1, 0)
        assert tp > 9000
    else:
        assert (bg, sc) == (0, 2)
        assert tp < 3000


def test_a_start_towards_an_active_but_disabled_switch_is_taken() -> None:
    s = sim()
    s.set_limit_switch("A", "reverse", True)
    assert ask(s, "PR -1000;BG A") == b":?"  # enabled: TC 22
    assert ask(s, "TC 1").startswith(b" 22 ")
    assert ask(s, "LDA=2;PR -1000;BG A") == b":::"
    s.advance(0.5)
    assert values(s, "MG _TPA,_SCA,_LRA") == [-1000, 1, 0]


def test_limswi_does_not_run_for_a_disabled_switch_but_does_for_a_soft_limit() -> None:
    s = sim()
    s.place_limit_switches("A", forward=1000)
    program = ["#M", "n=0;LDA=1", "JG 8000;BG A", "AM A", "EN", "#LIMSWI", "n=n+1", "RE 1"]
    assert b"?" not in ask(s, "DL\r" + "\r".join(program) + "\r\\")
    ask(s, "FLA=6000;XQ #M")
    s.advance(0.5)  # through the switch at 1000, not yet at FL
    assert values(s, "MG n,_BGA") == [0, 1]
    s.advance(1.0)
    assert values(s, "MG n,_SCA") == [1, 2]  # the soft limit stops it: LD leaves FL on


def test_ld_0_in_motion_stops_an_axis_moving_into_the_switch_at_once() -> None:
    # LD is "Valid while in motion": enabling the switch under an axis beyond it, moving on
    # into it, stops the axis as the switch tripping would.
    s = sim()
    s.place_limit_switches("A", forward=1000)
    ask(s, "LDA=1;JG 8000;BG A")
    s.advance(0.5)
    assert values(s, "MG _BGA") == [1]
    assert ask(s, "LDA=0") == b":"
    s.advance(0.5)
    assert values(s, "MG _BGA,_SCA") == [0, 2]


def test_off_on_error_2_does_not_turn_the_motor_off_at_a_soft_limit_on_a_disabled_switch() -> None:
    # OE 2 turns the motor off at a limit switch, not at a soft limit: an axis on an active
    # but disabled switch that a soft limit stops keeps its motor on.
    s = sim()
    s.place_limit_switches("A", forward=1000)
    ask(s, "OEA=2;LDA=1;FLA=3000;JG 8000;BG A")
    s.advance(1.0)
    assert values(s, "MG _BGA,_SCA,_MOA,_LFA") == [0, 2, 0, 0]
