"""Coordinated motion on the simulator: the sequence is the predictor's, sample for sample."""

from __future__ import annotations

import numpy as np
import pytest

from galil import predict
from galil.link import parse_numbers_reply
from galil.predict import Arc, Line, LinearInterp
from galil.predict.vector import SequenceEvent, replay
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

TS = 1 / 1024
VS, VA, VD = 30_000, 256_000, 512_000
ROUNDED_SQUARE = (
    ("VP 8000,0", Line(8000, 0)),
    ("CR 1000,270,90", Arc(1000, 270, 90)),
    ("VP 9000,9000", Line(0, 8000)),
    ("CR 1000,0,90", Arc(1000, 0, 90)),
    ("VP 0,10000", Line(-8000, 0)),
    ("CR 1000,90,90", Arc(1000, 90, 90)),
    ("VP -1000,1000", Line(0, -8000)),
    ("CR 1000,180,90", Arc(1000, 180, 90)),
)


def ask(sim: SimController, line: str) -> bytes:
    return sim.feed(line.encode() + b"\r")


def stamp(reply: bytes) -> int:
    """The TIME an ``...;MG TIME`` line printed."""
    return round(float(reply.split(b"\r\n")[-2].lstrip(b":")))


def numbers(reply: bytes) -> list[float]:
    return parse_numbers_reply(reply.decode().split("\r\n")[0].lstrip(":"))


def setup(sim: SimController, axes: str = "AB", mode: str = "VM") -> None:
    assert ask(sim, f"CA S;{mode} {axes};VSS={VS};VAS={VA};VDS={VD}") == b":" * 5


def recorded(trace: dict[str, np.ndarray], t0: int, begin: int, n: int, axes: str) -> np.ndarray:
    return np.vstack([trace[a][begin - t0 : begin - t0 + n] for a in axes])


@pytest.fixture
def sim() -> SimController:
    return SimController("DMC-4040", ManualClock())


def test_a_rounded_square_runs_as_the_predictor_says_at_every_sample(sim: SimController) -> None:
    ask(sim, "PRA=1234;PRB=-77;BG AB")
    sim.advance(1)
    setup(sim)
    for text, _ in ROUNDED_SQUARE:
        assert ask(sim, text) == b":"
    assert numbers(ask(sim, "VE;MG _LMS,_CSS,_BGS")) == [503, 0, 0]
    t0 = sim.start_trace("AB")
    begin = stamp(ask(sim, "BG S;MG TIME"))
    assert numbers(ask(sim, "MG _BGS,_BGA,_SCA")) == [1, 1, 100]
    sim.advance(4)
    trace = sim.stop_trace("AB")
    p = predict.vector([s for _, s in ROUNDED_SQUARE], VS, VA, VD, start=(1234, -77))
    np.testing.assert_array_equal(recorded(trace, t0, begin, p.samples + 1, "AB"), p.position)
    assert numbers(ask(sim, "MG _BGS,_BGA,_SCA,_SCB,_CSS,_LMS,_AVS,_RPA,_RPB")) == [
        0,
        0,
        101,
        101,
        8,
        511,
        p.length,
        1234,
        -77,
    ]


@pytest.mark.parametrize("chunk", [TS, 7 * TS, 0.3])
def test_the_sequence_is_the_same_however_time_is_chunked(sim: SimController, chunk: float) -> None:
    assert ask(sim, "DL\r#W\rAM S;MG TIME\rEN\r\\") == b"::"  # AM: a program command (0044)
    setup(sim)
    for text, _ in ROUNDED_SQUARE:
        ask(sim, text)
    ask(sim, "VE")
    t0 = sim.start_trace("AB")
    begin = stamp(ask(sim, "BG S;MG TIME"))
    held = ask(sim, "XQ #W")  # a thread held by a trippoint makes the loop bisect its steps
    assert held == b":"
    for _ in range(round(3.5 / chunk)):
        sim.advance(chunk)
        held += sim.poll()
    trace = sim.stop_trace("AB")
    p = predict.vector([s for _, s in ROUNDED_SQUARE], VS, VA, VD)
    np.testing.assert_array_equal(recorded(trace, t0, begin, p.samples + 1, "AB"), p.position)
    assert stamp(held) == begin + p.samples  # AM S is released where the sequence ends


def test_segments_sent_during_motion_and_a_stop_follow_the_replay(sim: SimController) -> None:
    setup(sim)
    ask(sim, "VP 8000,0;CR 1000,270,90")
    t0 = sim.start_trace("AB")
    begin = stamp(ask(sim, "BG S;MG TIME"))
    sim.advance(0.2)
    k1 = stamp(ask(sim, "VP 9000,9000;MG TIME"))
    sim.advance(0.5)
    k2 = stamp(ask(sim, "CR 1000,0,90;MG TIME"))
    sim.advance(0.05)
    k3 = stamp(ask(sim, "ST S;MG TIME"))
    assert numbers(ask(sim, "MG _BGS,_SCA")) == [1, 4]
    sim.advance(2)
    trace = sim.stop_trace("AB")
    events = [
        SequenceEvent(k1 - begin, "add", (Line(0, 8000),)),
        SequenceEvent(k2 - begin, "add", (Arc(1000, 0, 90),)),
        SequenceEvent(k3 - begin, "stop"),
    ]
    p = replay([Line(8000, 0), Arc(1000, 270, 90)], VS, VA, VD, events=events, ended=False)
    assert p.stop_code == 4
    np.testing.assert_array_equal(recorded(trace, t0, begin, p.samples + 1, "AB"), p.position)
    assert numbers(ask(sim, "MG _BGS,_SCA,_SCB,_RPA,_RPB")) == [0, 4, 4, *p.end]


def test_st_on_one_axis_stops_the_whole_sequence_and_ab_stops_at_once(sim: SimController) -> None:
    setup(sim)
    ask(sim, "VP 50000,50000;VE")
    begin = stamp(ask(sim, "BG S;MG TIME"))
    sim.advance(0.5)
    k = stamp(ask(sim, "ST A;MG TIME"))
    sim.advance(2)
    p = replay([Line(50000, 50000)], VS, VA, VD, events=[SequenceEvent(k - begin, "stop")])
    assert numbers(ask(sim, "MG _RPA,_RPB,_SCA,_SCB,_BGS")) == [*p.end, 4, 4, 0]
    ask(sim, "CS S;VP 50000,50000;VE")
    ask(sim, "BG S")
    sim.advance(0.3)
    at = numbers(ask(sim, "AB 1;MG _RPA,_RPB"))
    sim.advance(0.5)
    assert numbers(ask(sim, "MG _RPA,_RPB,_SCA,_SCB,_BGS,_BGA")) == [*at, 7, 7, 0, 0]


def test_st_on_one_axis_shows_every_axis_of_the_sequence_stopped_together(
    sim: SimController,
) -> None:
    # ST of one axis at the sample the sequence begins (no speed yet: nothing to ramp down):
    # the sequence is over for both axes at once, not for B now and A a sample later.
    setup(sim)
    ask(sim, "VP -195,-87;VE")
    assert numbers(ask(sim, "BG S;ST B;MG _BGA,_BGB,_BGS,_SCA,_SCB")) == [0, 0, 0, 4, 4]
    setup(sim)
    ask(sim, "VP 50000,50000;VE")
    ask(sim, "BG S")
    sim.advance(0.3)
    # In motion both ramp down along the path, together, "decelerating by ST" (code 4).
    assert numbers(ask(sim, "ST A;MG _BGA,_BGB,_BGS,_SCA,_SCB")) == [1, 1, 1, 4, 4]


def test_a_running_sequence_owns_its_axes(sim: SimController) -> None:
    setup(sim)
    ask(sim, "VP 20000,0;VE;BG S")
    sim.advance(0.1)
    for command, code in (("BG A", 21), ("PRB=5;BG B", 21), ("VM AC", 29), ("CS S", 29)):
        assert ask(sim, command).endswith(b"?")
        assert numbers(ask(sim, "MG _TC")) == [code]
    assert ask(sim, "BG S") == b"?"
    assert numbers(ask(sim, "MG _TC")) == [21]
    assert ask(sim, "PRC=100;BG C") == b"::"  # an axis outside the plane moves as it likes


@pytest.mark.parametrize(
    ("commands", "code"),
    [
        ("BG S", 24),  # no segments
        ("VP 0,0", 30),  # no length
        ("VP 2147483647,0", 31),  # longer than two billion counts
        ("LI 5,5", 33),  # LI in a VM sequence
        ("CR 5,0,90", 6),  # radius below 10
        ("VP 1,2<5000", 6),  # per-segment speed: not simulated
        ("VT 0.5", 1),  # no VT on the 4040
        ("CA U", 28),
    ],
)
def test_what_the_controller_refuses_has_its_code(
    sim: SimController, commands: str, code: int
) -> None:
    setup(sim)
    assert ask(sim, commands).endswith(b"?")
    assert numbers(ask(sim, "MG _TC")) == [code]


def test_the_buffer_fills_to_its_depth_then_refuses_and_frees_as_segments_complete(
    sim: SimController,
) -> None:
    setup(sim)
    for i in range(1, 512):
        assert ask(sim, f"VP {i * 10},0") == b":"
    assert numbers(ask(sim, "MG _LMS")) == [0]
    assert ask(sim, "VP 6000,0") == b"?"
    assert numbers(ask(sim, "MG _TC")) == [32]
    ask(sim, "BG S")
    sim.advance(0.1)
    done, free, dist = numbers(ask(sim, "MG _CSS,_LMS,_AVS"))
    assert done > 0
    assert free == done
    assert dist == float(sim.motion("A").reference)
    sim.advance(1)  # no VE: the sequence waits at rest at the end of its segments
    assert numbers(ask(sim, "MG _BGS,_SCA,_RPA")) == [1, 100, 5110]
    ask(sim, "VP 6000,0;VE")
    sim.advance(1)
    assert numbers(ask(sim, "MG _BGS,_SCA,_RPA,_CSS")) == [0, 101, 6000, 512]


def test_linear_interpolation_on_three_axes_matches_the_predictor(sim: SimController) -> None:
    setup(sim, "ABD", "LM")
    for text in ("LI 4000,2000,,1000", "LI 2000,4000,,1000", "LI 2000,2000,,-2000"):
        assert ask(sim, text) == b":"
    assert ask(sim, "LI ,,5") == b"?"  # C is not in the LM axes
    assert ask(sim, "VP 1,1") == b"?"
    t0 = sim.start_trace("ABD")
    begin = stamp(ask(sim, "LE;BG S;MG TIME"))
    sim.advance(2)
    trace = sim.stop_trace("ABD")
    segs = [LinearInterp((4000, 2000, 1000)), LinearInterp((2000, 4000, 1000))]
    segs.append(LinearInterp((2000, 2000, -2000)))
    p = predict.vector(segs, VS, VA, VD)
    np.testing.assert_array_equal(recorded(trace, t0, begin, p.samples + 1, "ABD"), p.position)


def test_vector_parameters_are_quantised_per_plane(sim: SimController) -> None:
    assert ask(sim, "VS 20001;VAT=300000;VD 1000,2048") == b":::"
    assert numbers(ask(sim, "MG _VSS,_VAT,_VDS,_VDT")) == [20000, 299008, 1024, 2048]
    assert ask(sim, "VSS=?").strip(b":\r\n ") == b"20000"
    assert ask(sim, "VS 99999999") == b"?"


def test_a_soft_limit_stops_the_sequence_at_vd_with_the_limit_code(sim: SimController) -> None:
    setup(sim)
    ask(sim, "FLA=20000;VP 40000,10000;VE")
    ask(sim, "BG S")
    sim.advance(3)
    a, b, sca, bgs = numbers(ask(sim, "MG _RPA,_RPB,_SCA,_BGS"))
    assert 20000 < a < 40000
    assert b == pytest.approx(a / 4, abs=1)  # still on the line, stopped along the path
    assert (sca, bgs) == (2, 0)


def test_the_two_planes_run_side_by_side(sim: SimController) -> None:
    setup(sim)
    ask(sim, "VP 3000,4000;VE")
    assert ask(sim, f"CA T;VM CD;VST={VS};VAT={VA};VDT={VD};VP -300,400;VE") == b":" * 7
    ask(sim, "BG ST")
    assert numbers(ask(sim, "MG _BGS,_BGT")) == [1, 1]
    sim.advance(2)
    assert numbers(ask(sim, "MG _RPA,_RPB,_RPC,_RPD,_BGS,_BGT")) == [3000, 4000, -300, 400, 0, 0]


def test_vs_va_and_vd_are_stored_in_the_steps_of_the_tm_in_force() -> None:
    # (assumed as SP's and AC's, docs/decisions/0025 "Predictions at any TM")
    sim = SimController("DMC-4040")
    ask(sim, "TM 250")
    ask(sim, "VSS=80006;VAS=40000;VDS=20000")
    assert numbers(ask(sim, "MG _VSS,_VAS,_VDS")) == [80_000, 32_768, 16_384]
    ask(sim, "VAS=8000")  # below the smallest VA at TM 250: raised to it, as AC
    assert numbers(ask(sim, "MG _VAS")) == [16_384]


@pytest.mark.parametrize("command", ["VS", "VA", "VD"])
def test_a_refused_vector_parameter_line_changes_neither_plane(
    sim: SimController, command: str
) -> None:
    # (the S field was set before the T field was refused out of range)
    before = ask(sim, f"{command} ?,?")
    assert ask(sim, f"{command} 2048,2147483647") == b"?"
    assert ask(sim, f"{command} ?,?") == before
    assert ask(sim, f"{command}S=2048;{command}T=4096") == b"::"


def _plane_and_move(sim: SimController) -> None:
    """A sequence ready on S (B, C) and a position move set up on A (the twin of each)."""
    setup(sim, "BC")
    assert ask(sim, "VP 20000,5000;VE;PRA=12000;SPA=20000") == b":" * 4


@pytest.mark.parametrize("line", ["BG SA", "BG A,S", "BGS A"])
def test_bg_of_a_plane_and_an_axis_starts_both_on_one_sample(line: str) -> None:
    # R4103, BG: "Any combination of Axes, Vector Planes, and Virtual Axes may be mixed to
    # begin motion"; the twin begins them one after the other on the same line.
    mixed, twin = SimController("DMC-4040", ManualClock()), SimController("DMC-4040", ManualClock())
    for s in (mixed, twin):
        _plane_and_move(s)
    assert stamp(ask(mixed, f"{line};MG TIME")) == stamp(ask(twin, "BGS;BGA;MG TIME"))
    read = "MG _RPA,_RPB,_RPC,_BGA,_BGS"
    assert numbers(ask(mixed, read))[3:] == [1, 1]
    for seconds in (0.05, 0.4, 2.0):
        mixed.advance(seconds)
        twin.advance(seconds)
        assert numbers(ask(mixed, read)) == numbers(ask(twin, read))
    assert numbers(ask(mixed, read)) == [12000, 20000, 5000, 0, 0]


@pytest.mark.parametrize(
    ("before", "line", "code"),
    [
        ("CS S", "BG SA", 24),  # (S's buffer cleared: "no sequence defined")
        ("MO A", "BG SA", 20),  # A's motor off
        ("", "BG SB", 21),  # B is S's own axis: as BG S;BG B
        ("", "BG TA", 24),  # T has no sequence
    ],
)
def test_bg_of_a_plane_and_an_axis_starts_neither_when_one_is_refused(
    sim: SimController, before: str, line: str, code: int
) -> None:
    _plane_and_move(sim)
    if before:
        assert ask(sim, before) == b":"
    assert ask(sim, line) == b"?"
    assert numbers(ask(sim, "TC"))[0] == code
    sim.advance(0.1)
    assert numbers(ask(sim, "MG _BGA,_BGB,_BGS,_RPA,_RPB")) == [0, 0, 0, 0, 0]


@pytest.mark.parametrize("line", ["ST SA", "ST A,S", "STS A"])
def test_st_of_a_plane_and_an_axis_stops_both_on_one_sample(line: str) -> None:
    # R4103, ST: mask A .. ABCDEFGHMNST, and "ST SCD;' Stop coordinate plane S, as well as
    # axes C and D"; the twin stops them one after the other on the same line.
    mixed, twin = SimController("DMC-4040", ManualClock()), SimController("DMC-4040", ManualClock())
    for s in (mixed, twin):
        _plane_and_move(s)
        assert ask(s, "BGS;BGA") == b"::"
        s.advance(0.3)
    assert stamp(ask(mixed, f"{line};MG TIME")) == stamp(ask(twin, "STS;STA;MG TIME"))
    read = "MG _RPA,_RPB,_RPC,_SCA,_SCB"
    assert numbers(ask(mixed, read)) == numbers(ask(twin, read))
    for seconds in (0.01, 0.05, 1.0):
        mixed.advance(seconds)
        twin.advance(seconds)
        assert numbers(ask(mixed, read)) == numbers(ask(twin, read))
    final = numbers(ask(mixed, "MG _BGA,_BGS,_SCA,_RPA"))
    assert final[:3] == [0, 0, 4]
    assert 0 < final[3] < 12000  # stopped short of its target


def _after_motion(mask: str, short_a: bool) -> float:
    """The TIME a program's ``AM <mask>`` released, after ``BGS;BGA`` of _plane_and_move."""
    sim = SimController("DMC-4040", ManualClock())
    _plane_and_move(sim)
    if short_a:
        assert ask(sim, "PRA=100") == b":"
    program = ["#W", "BGS;BGA", f"AM {mask}", "t=TIME", "EN"]
    assert b"?" not in ask(sim, "DL\r" + "\r".join(program) + "\r\\")
    ask(sim, "XQ #W")
    sim.advance(5.0)
    assert numbers(ask(sim, "MG _BGA,_BGS,_XQ0")) == [0, 0, -1]
    return numbers(ask(sim, "MG t"))[0]


@pytest.mark.parametrize("short_a", [False, True])
@pytest.mark.parametrize("mask", ["SA", "A,S", "AS"])
def test_am_of_a_plane_and_an_axis_waits_for_the_later_of_the_two(mask: str, short_a: bool) -> None:
    # R4103, AM: "Any combination of axes or a motion sequence may be specified"; mask
    # A .. ABCDEFGH and S, T. AM runs only in a program (decision 0044).
    alone = {c: _after_motion(c, short_a) for c in "AS"}
    assert alone["A"] != alone["S"]
    assert _after_motion(mask, short_a) == max(alone.values())


def test_st_and_am_of_a_plane_with_a_letter_that_is_no_axis_are_refused(sim: SimController) -> None:
    _plane_and_move(sim)
    assert ask(sim, "BGS;ST SX") == b":?"  # X: no axis of the DMC-4040
    assert numbers(ask(sim, "TC"))[0] == 4
    assert numbers(ask(sim, "MG _BGS"))[0] == 1


@pytest.mark.parametrize(
    ("path", "refused"),
    [
        ("VM AB;VP 1000,500", True),  # B forward at once
        ("VM AB;VP 1000,-500", False),  # B away from its switch
        ("VM AB;VP 1000,0;VP 1000,500", True),  # B still, then forward: its first motion
        ("VM AB;CR 1000,0,90", True),  # B's tangent: forward
        ("VM AB;CR 1000,0,-90", False),  # reverse
        ("VM AB;CR 1000,270,90", True),  # tangent 0 for B: the circle bends it forward
        ("VM AB;CR 1000,90,90", False),  # bends it back
        ("LM AB;LI 300,-200", False),
        ("LM AB;LI 300,0;LI 0,200", True),
    ],
)
def test_bg_s_with_an_axis_heading_into_its_active_switch_is_refused_with_tc_22(
    sim: SimController, path: str, refused: bool
) -> None:
    """Before: the sequence began and ran through the active switch (SC 101 at its end).
    Now ``BG S`` is refused as an independent ``BG`` towards the switch is (decision 0050)."""
    sim.set_limit_switch("B", "forward", True)
    assert b"?" not in ask(sim, f"CA S;VSS={VS};VAS={VA};VDS={VD};{path}")
    end = "VE" if path.startswith("VM") else "LE"
    if refused:
        assert ask(sim, f"{end};BG S") == b":?"
        assert numbers(ask(sim, "MG _TC")) == [22]
        assert numbers(ask(sim, "MG _BGS,_RPA,_RPB")) == [0, 0, 0]
        assert ask(sim, "LDB=1;BG S") == b"::"  # the switch disabled: taken
    else:
        assert ask(sim, f"{end};BG S") == b"::"
    sim.advance(1)
    assert numbers(ask(sim, "MG _BGS,_SCA,_SCB")) == [0, 101, 101]


def test_a_sequence_axis_turning_towards_a_switch_active_at_its_start_is_stopped(
    sim: SimController,
) -> None:
    """Before: ``BG S`` checked B's first direction (away) and nothing watched the pressed
    switch after it: B turned and ran through it (SC 101). Now the sequence stops at VD as
    soon as B heads into it (SC 2), as a contour does."""
    setup(sim)
    sim.set_limit_switch("B", "forward", True)
    assert ask(sim, "VP 0,-500;VP 0,500;VE;BG S") == b"::::"
    sim.advance(1)
    rpb, sca, scb, bgs = numbers(ask(sim, "MG _RPB,_SCA,_SCB,_BGS"))
    assert (sca, scb, bgs) == (2, 2, 0)
    assert -500 < rpb < 0  # turned, and stopped on the way back, short of the switch side


@pytest.mark.parametrize("command", ["CA", "CA ST", "CA X", "CS ST"])
def test_a_plane_command_without_one_plane_is_refused(command: str) -> None:
    # One plane, S or T (galil-wave2-facts.md §6); TC 28 "S operand not valid"
    sim = SimController("DMC-4040", ManualClock())
    assert sim.feed(command.encode() + b"\r") == b"?"
    assert sim.feed(b"TC\r") == b" 28\r\n:"
    assert sim.feed(b"VS 1000;CA ?;VS ?\r") == b": 0\r\n: 1000\r\n:"
