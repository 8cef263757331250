"""Limit switches and soft limits stop a contour (decision 0041).

The reference's #LIMSWI: a limit event is "Motion profiling in the direction of the given
limit. I.E. RPm increasing for forward switch", "either a hardware or software limit", and
without #LIMSWI "the controller will issue ST on the axis". The simulator stops the whole
contour at once at the sample the path reaches the limit: that axis reports 2 or 3, the other
contour axes 51, contour mode is left with its buffer dropped. Each run is played twice, its
time in one advance and one servo sample at a time, and must give the same bytes: the stop
comes at its exact sample however the loop steps.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import pytest

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

TS = 1 / 1024
STATE = "MG _SCA,_SCB,_BGA,_BGB,_RPA,_RPB,_CM,_TC"

Script = Sequence[str | int]


def play(script: Script, per_sample: bool, setup: Callable[[SimController], None]) -> bytes:
    sim = SimController("DMC-4040", servo_lag=0.003)
    setup(sim)
    out = b""
    for step in script:
        if isinstance(step, str):
            out += sim.feed(step.encode() + b"\r")
        else:
            for n in [1] * step if per_sample else [step]:
                sim.advance(n * TS)
        out += sim.poll()
    return out


def state(script: Script, setup: Callable[[SimController], None] = lambda sim: None) -> list[float]:
    """``STATE`` after ``script``; the same bytes whether time passed at once or per sample."""
    coarse = play([*script, STATE], False, setup)
    assert play([*script, STATE], True, setup) == coarse
    return numbers(coarse.rstrip(b":").rsplit(b":", 1)[-1])


def numbers(reply: bytes) -> list[float]:
    return [float(v) for v in re.findall(rb"-?\d+\.\d+", reply)]


def segments(a: int, b: int, count: int) -> str:
    return ";".join([f"CD {a},{b}"] * count)


def place(**where: int) -> Callable[[SimController], None]:
    return lambda sim: sim.place_limit_switches("A", **where)


def test_a_contour_into_a_placed_forward_switch_stops_whole_at_once() -> None:
    # 40 segments of 100 counts (DT 3): 4000 counts; the switch is at 1000.
    sc_a, sc_b, bg_a, bg_b, rp_a, rp_b, cm, tc = state(
        ["CM AB;DT 3", segments(100, 50, 40), 700], place(forward=1000)
    )
    assert (sc_a, sc_b, bg_a, bg_b) == (2, 51, 0, 0)
    assert 1000 <= rp_a < 1100  # (the motor trips it; the reference leads by the servo lag)
    assert rp_b == pytest.approx(rp_a / 2, abs=13)  # B stopped on the same sample
    assert (cm, tc) == (511, 0)  # the buffer dropped, no TC 42


def test_a_contour_into_a_placed_reverse_switch_stops_with_code_3() -> None:
    sc_a, sc_b, *_ = state(["CM AB;DT 3", segments(-100, 50, 40), 700], place(reverse=-1000))
    assert (sc_a, sc_b) == (3, 51)


def test_a_contour_past_fl_stops_at_the_first_sample_beyond_it() -> None:
    # 13 counts per 8 samples: many samples stand still inside a moving segment.
    sc_a, sc_b, _, _, rp_a, *_ = state(["FL 1000;CM AB;DT 3", segments(13, 1, 200), 1700])
    assert (sc_a, sc_b) == (2, 51)
    assert rp_a == 1001  # FL n: "The forward limit is activated at n+1"


def test_a_contour_past_bl_stops_with_code_3() -> None:
    sc_a, _, _, _, rp_a, *_ = state(["BL -500;CM AB;DT 2", segments(-40, 0, 40), 200])
    assert (sc_a, rp_a) == (3, -510)  # (steps of 10 counts: the first beyond BL)


def test_a_contour_moving_away_from_a_limit_is_not_stopped() -> None:
    # Beyond FL already (set under the axis) and on an active switch: inwards is allowed.
    sc_a, sc_b, bg_a, _, rp_a, *_ = state(
        ["DP 2000;FL 1000;CM AB;DT 2", segments(-50, 0, 20), "CD 0,0=0", 200],
        lambda sim: sim.set_limit_switch("A", "forward", True),
    )
    assert (sc_a, sc_b, bg_a, rp_a) == (51, 51, 0, 1000)


def test_a_contour_towards_a_switch_active_before_it_started_stops_at_its_first_move() -> None:
    # Standing still for 10 segments, then moving towards the pressed switch.
    sc_a, _, _, _, rp_a, *_ = state(
        ["CM AB;DT 3", segments(0, 0, 10), segments(24, 0, 10), 400],
        lambda sim: sim.set_limit_switch("A", "forward", True),
    )
    assert (sc_a, rp_a) == (2, 3)  # 24 counts over 8 samples: 3 at its first sample


def test_a_contour_that_enters_a_switch_and_leaves_it_within_one_step_is_stopped() -> None:
    # Out to 320 and back to 0 in 32 + 32 samples, the switch at 200: one long advance
    # covers all of it, so the step must end where the path turns back.
    sc_a, _, _, _, rp_a, *_ = state(
        ["CM AB;DT 3", segments(80, 0, 4), segments(-80, 0, 4), 200], place(forward=200)
    )
    assert sc_a == 2
    assert 200 <= rp_a <= 320


def test_after_a_limit_stop_a_cd_is_refused_and_a_new_contour_runs_and_can_stop_again() -> None:
    out = play(
        [
            "CM AB;DT 3",
            segments(100, 0, 40),
            700,
            "CD 100,0",  # the contour is over: refused
            "CM AB;DT 3",
            segments(-100, 0, 5),  # away from the switch
            "CD 0,0=0",
            100,
            "MG _SCA,_RPA",
            "CM A;DT 3",
            segments(100, 0, 20),  # into it again: stopped again (limit_stop was cleared)
            300,
            "MG _SCA",
        ],
        False,
        place(forward=1000),
    )
    assert out.count(b"?") == 1  # the CD after the stop, nothing else
    away, again = [numbers(line) for line in out.split(b"\r\n") if numbers(line)]
    assert away[0] == 51
    assert away[1] < 1000
    assert again == [2]


def test_a_contour_limit_stop_runs_limswi() -> None:
    out = play(
        [
            'DL\r#M\rWT 2000\rEN\r#LIMSWI\rMG "L",_SCA\rRE\r\\',
            "XQ #M",
            "CM A;DT 3",
            segments(100, 0, 40),
            700,
        ],
        False,
        place(forward=1000),
    )
    assert b"L 2.0000" in out


def test_cd0_without_a_space_assigns_a_variable_and_leaves_contour_mode_on() -> None:
    # "CD0=0 would assign a variable named CD0 -- need CD 0=0 with a space" (galil-protocol.md)
    sim = SimController("DMC-4040", ManualClock())
    assert sim.feed(b"CM A;CD 100=2;CD0=0\r") == b":::"
    sim.advance(1.0)
    assert sim.feed(b"MG _SCA,CD0\r") == b" 50.0000 0.0000\r\n:"
    assert sim.feed(b"CD 0=0\r") == b":"
    sim.advance(0.1)
    assert sim.feed(b"MG _SCA\r") == b" 51.0000\r\n:"
