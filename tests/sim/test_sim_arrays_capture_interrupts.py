"""The simulator's arrays, variables, RA/RD/RC capture and UI/EI interrupts."""

from __future__ import annotations

import pytest
from engine_expect import move, references

import galil
from galil.protocol import commands as cmds
from galil.protocol.interrupts import InterruptParser
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController


def ask(sim: SimController, text: str, port: int = 0) -> bytes:
    return sim.feed(text.encode() + b"\r", port)


def tc(sim: SimController) -> int:
    return int(float(ask(sim, "MG _TC")[:-1]))


def values(reply: bytes) -> list[float]:
    assert reply.endswith(b"\r\n\x1a:")
    return [float(v) for v in reply[:-4].replace(b"\r\n", b",").split(b",")]


def test_arrays_are_dimensioned_read_and_written_in_expressions(sim: SimController) -> None:
    assert ask(sim, "DM sq[5],cube[2]") == b":"
    assert ask(sim, "sq[2]=1.5*3") == b":"
    assert ask(sim, "x=sq[2]+1") == b":"
    assert ask(sim, "MG sq[2],x,sq[0]") == b" 4.5000 5.5000 0.0000\r\n:"
    assert ask(sim, "LA") == b"cube[2]\r\nsq[5]\r\n:"
    assert ask(sim, "LV") == b"x= 5.5000\r\n:"
    assert ask(sim, "MG _DM") == f" {24_000 - 7}.0000\r\n:".encode()


def test_element_minus_one_is_an_arrays_size_as_in_the_firmware(sim: SimController) -> None:
    ask(sim, "DM sq[5],cube[2]")
    assert ask(sim, "MG sq[-1],cube[-1]") == b" 5.0000 2.0000\r\n:"
    assert ask(sim, "n=sq[-1]*2") == b":"
    assert ask(sim, "MG n") == b" 10.0000\r\n:"


def test_a_program_fills_an_array_in_a_loop(sim: SimController) -> None:
    ask(sim, "DM sq[10]")
    program = "#SQ\ri=0\r#LOOP\rsq[i]=i*i\ri=i+1\rJP #LOOP,i<10\rEN\r\\"
    assert sim.feed(b"DL\r" + program.encode()) == b"::"
    ask(sim, "XQ #SQ,1")
    assert ask(sim, "MG _XQ1") != b"-1.0000\r\n:"
    sim.advance(0.05)
    assert ask(sim, "MG _XQ1") == b"-1.0000\r\n:"
    assert values(ask(sim, "QU sq[],0,9,1")) == [float(i * i) for i in range(10)]


def test_qu_separates_by_comma_or_cr_lf_and_qd_takes_either(sim: SimController) -> None:
    ask(sim, "DM a[4]")
    # The data may come in pieces; the ':' comes after the backslash.
    assert sim.feed(b"QD a[],1,3\r1.5,\r") == b""
    assert sim.feed(b"-2\r\n3") == b""
    assert sim.feed(b"\\") == b":"
    assert ask(sim, "QU a[],0,3,1") == b" 0.0000, 1.5000,-2.0000, 3.0000\r\n\x1a:"
    assert ask(sim, "QU a[],2,3,0") == b"-2.0000\r\n 3.0000\r\n\x1a:"


@pytest.mark.parametrize(
    ("commands", "code"),
    [
        (["DM a[2]", "DM a[3]"], 4),  # exists: DA it first
        (["DM big[24001]"], 66),
        (["DM a[0]"], 6),
        (["DM a[2]", "a[2]=1"], 56),
        (["DM a[2]", "a[-1]=5"], 56),  # the size is read-only
        (["MG nope[-1]"], 82),
        (["b[0]=1"], 82),
        (["MG nope[0]"], 82),
        (["QU nope[],0,1,1"], 82),
        (["DA nope[]"], 82),
        (["DM a[2]", "QU a[],0,5,1"], 56),
        (["RC 1"], 81),
        (["DM a[4]", "RA a[]", "RD _RPA", "RC 1,5"], 84),
        (["DM a[4]", "RA a[]", "RD _RPA", "RC 9"], 6),
        (["DM a[4]", "RA a[]", "RD _RPA", "RC 1", "RC 1"], 80),
        (["RA nope[]"], 82),
        (["RD _XXA"], 1),
        (["UI 16"], 6),
        (["EI 1,,5"], 126),  # no handle F open
    ],
)
def test_refusals_carry_the_controllers_codes(
    sim: SimController, commands: list[str], code: int
) -> None:
    *setup, last = commands
    for c in setup:
        assert ask(sim, c) == b":"
    assert ask(sim, last) == b"?"
    assert tc(sim) == code


def test_qd_refuses_too_many_or_bad_values(sim: SimController) -> None:
    ask(sim, "DM a[2]")
    assert sim.feed(b"QD a[],0,1\r1,2,3\\") == b"?"
    assert tc(sim) == 84
    assert sim.feed(b"QD a[],0,1\r1,x\\") == b"?"
    assert tc(sim) == 83
    assert values(ask(sim, "QU a[],0,1,1")) == [0.0, 0.0]  # nothing was written


def test_thirty_arrays_at_most(sim: SimController) -> None:
    for i in range(30):
        assert ask(sim, f"DM a{i}[1]") == b":"
    assert ask(sim, "DM z[1]") == b"?"
    assert tc(sim) == 67
    assert ask(sim, "DA *[]") == b":"
    assert ask(sim, "LA") == b":"


def test_capture_records_exactly_what_the_engine_commanded(sim: SimController) -> None:
    ask(sim, "DM ref[200],enc[200]")
    ask(sim, "RA ref[],enc[]")
    ask(sim, "RD _RPA,_TPA")
    assert ask(sim, "PRA=3000;BG A;RC 1,200;MG TIME") == b"::: 0.0000\r\n:"
    assert ask(sim, "MG _RC") == b" 1.0000\r\n:"
    sim.advance(0.5)
    assert ask(sim, "MG _RC,_RD") == b" 0.0000 200.0000\r\n:"
    expected = [0, *references(move(3000))]
    expected += [expected[-1]] * 400
    assert values(ask(sim, "QU ref[],0,199,1")) == [float(v) for v in expected[0:400:2]]
    encoder = values(ask(sim, "QU enc[],0,199,1"))
    assert encoder[-1] == 3000  # the motor followed, with its lag
    assert encoder[10] < expected[20]


def test_circular_capture_wraps_and_rc_0_stops(sim: SimController) -> None:
    ask(sim, "DM t[4]")
    ask(sim, "RA t[]")
    ask(sim, "RD TIME")
    ask(sim, "RC 2,-4")
    sim.advance(40 / 1024)  # eleven values (samples 0, 4 ... 40) into four elements
    assert ask(sim, "MG _RD") == b" 3.0000\r\n:"
    assert ask(sim, "RC 0") == b":"
    assert ask(sim, "RC ?") == b" 0\r\n:"
    assert values(ask(sim, "QU t[],0,3,1")) == [32.0, 36.0, 40.0, 28.0]


def test_user_interrupts_and_motion_complete_reach_the_ei_handle(sim: SimController) -> None:
    handle = sim.open_port("interrupts")
    assert ask(sim, "MG _WH", handle) == b" 0.0000\r\n:"  # handle A
    ask(sim, "UI 1")  # no handle named yet: dropped
    assert ask(sim, "EI 257,,0") == b":"  # axis A complete, all complete; handle A
    sim.feed(b"DL\r#U\rUI 2\rUI 15\rEN\r\\")
    ask(sim, "XQ #U,3")
    ask(sim, "PRA=100;BG A")
    sim.advance(0.2)
    events = InterruptParser().feed(sim.poll(handle))
    assert [str(e) for e in events] == ["UI 2", "UI 15", "axis A done", "all done ($D8)"]
    ask(sim, "EI 0")
    ask(sim, "PRA=100;BG A")
    sim.advance(0.2)
    assert sim.poll(handle) == b""


# -- a download the program memory cannot hold (TC 60) ---------------------------------------


def _ul(sim: SimController) -> bytes:
    return ask(sim, "UL")


def test_a_download_of_more_lines_than_the_program_memory_is_refused_with_tc_60(
    sim: SimController,
) -> None:
    assert sim.feed(b"DL\r#OLD\rEN\r\\") == b"::"
    before = _ul(sim)
    lines = ["#A", *[f"MG {i}" for i in range(2000)], "EN"]  # 2002: a DMC-4040 holds 2000
    reply = sim.feed(b"DL\r" + "\r".join(lines).encode() + b"\r\\")
    assert reply == b"?:"  # the line that does not fit, then the end of the download
    assert tc(sim) == 60
    assert _ul(sim) == before  # the program in memory is as it was
    assert ask(sim, "MG 1") == b" 1.0000\r\n:"  # in step


def test_a_downloaded_line_longer_than_the_models_is_refused_with_tc_60(
    sim: SimController,
) -> None:
    assert sim.feed(b"DL\r#A\rMG " + b"1" * 77 + b"\rEN\r\\") == b"::"  # 80 characters
    assert sim.feed(b"DL\r#A\rMG " + b"1" * 78 + b"\rEN\r\\") == b"?:"  # 81
    assert tc(sim) == 60


def test_a_raw_download_the_memory_cannot_hold_is_a_command_error() -> None:
    lines = ["#A", *[f"MG {i}" for i in range(2500)], "EN"]
    with galil.connect("sim://DMC-4040") as dmc:
        with pytest.raises(galil.CommandError) as info:
            dmc.send(cmds.dl(lines, model=dmc.model))
        assert info.value.code == 60
        assert dmc.query_number("MG 2") == 2


@pytest.mark.parametrize("end", [b"\\", b"\x1a", b"\x11", b"\x04"])
def test_a_download_ends_at_a_backslash_or_ctrl_z_q_or_d(end: bytes) -> None:
    # "terminate with \ (also ^Z, ^Q, ^D accepted)" (galil-wave2-facts.md, DL)
    sim = SimController("DMC-4040", ManualClock())
    assert sim.feed(b"DL\r#A\rEN\r" + end + b"\rTPA\r") == b":: 0\r\n:"
    assert sim.feed(b"UL\r") == b"#A\r\nEN\r\n\x1a:"
