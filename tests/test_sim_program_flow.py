"""IF/ELSE/ENDIF, program-only commands and TS bit 6 on ``sim://`` (decision 0037).

Programs are downloaded and run with ``dmc.programs``; the simulated clock passes only while
the test waits (``dmc.sleep``), so a ``TIME`` a program records is the exact servo sample.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from program_helpers import drain_messages, run_program

import galil
from galil.errors import CommandError
from galil.sim.programs import PROGRAM_ONLY
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        yield controller


# ---- IF / ELSE / ENDIF --------------------------------------------------------------------
NESTED = """#M
i=0
#L
a=(i&1);b=(i&2)/2
IF (a=1)
 IF (b=1)
  MG "both",i
 ELSE
  MG "a only",i
 ENDIF
ELSE
 IF ((b=1)|(i=0));MG "b or none",i;ELSE;MG "never",i;ENDIF
ENDIF
IF ((a=1)&(b=1))
 MG "and",i
ENDIF
i=i+1
JP #L,(i<4)
MG "depth",_ZS0
EN
"""


def test_nested_if_else_endif_run_the_branches_their_conditions_choose(
    dmc: galil.Controller,
) -> None:
    assert run_program(dmc, NESTED) == [
        "b or none 0.0000",
        "a only 1.0000",
        "b or none 2.0000",
        "both 3.0000",
        "and 3.0000",
        "depth 0.0000",
    ]


def test_a_false_if_skips_its_lines_within_one_command(dmc: galil.Controller) -> None:
    # Forty skipped lines would take three samples to run (16 commands a sample); skipped,
    # they cost the IF only: the ENDIF is reached in the same sample.
    skipped = "\n".join(f"x{k}=1" for k in range(40))
    program = f"#M\nWT 10,1\nt0=TIME\nIF (0)\n{skipped}\nENDIF\nMG TIME-t0,_XQ0\nEN\n"
    assert run_program(dmc, program) == ["0.0000 45.0000"]


def test_an_if_waits_on_a_trippoint_inside_it_at_the_exact_sample(
    dmc: galil.Controller,
) -> None:
    program = "#M\nt0=TIME\nIF (1)\n WT 100,1\n t=TIME-t0\nELSE\n t=-1\nENDIF\nMG t\nEN\n"
    assert run_program(dmc, program) == ["100.0000"]


@pytest.mark.parametrize(
    ("program", "line"),
    [
        ('#M\nx=1\nENDIF\nMG "after"\nEN\n', 2),
        ('#M\nx=1\nELSE\nMG "after"\nEN\n', 2),
        ('#M\nx=1\nIF (x=2)\nMG "in"\nEN\n', 2),
        ('#M\nx=1\nIF (x=1)\nMG "in"\nELSE\nMG "out"\nEN\n', 4),
    ],
    ids=["stray ENDIF", "stray ELSE", "IF without ENDIF", "ELSE without ENDIF"],
)
def test_unpaired_if_else_endif_halt_the_thread_with_tc_63(
    dmc: galil.Controller, program: str, line: int
) -> None:
    lines = run_program(dmc, program)
    assert "after" not in lines
    assert "out" not in lines
    assert dmc.query_numbers("MG _TC,_ED") == [63.0, float(line)]


# ---- program-only commands ---------------------------------------------------------------
#: One command line for each program-only command (the table in galil.sim.programs).
FROM_HOST = {
    "AD": "AD 100",
    "AI": "AI 1",
    "AM": "AM A",
    "AP": "AP 100",
    "AR": "AR 100",
    "AS": "AS A",
    "AT": "AT 100",
    "AV": "AV 100",
    "EN": "EN",
    "JP": "JP #M",
    "JS": "JS #M",
    "MC": "MC A",
    "MF": "MF 100",
    "MR": "MRB=-100",
    "RE": "RE 1",
    "RI": "RI 1",
    "WT": "WT 10",
    "ZS": "ZS",
    "IF": "IF (1)",
    "ELSE": "ELSE",
    "ENDIF": "ENDIF",
}


def test_every_program_only_command_has_a_host_check() -> None:
    assert set(FROM_HOST) == PROGRAM_ONLY


@pytest.mark.parametrize("name", sorted(FROM_HOST))
def test_a_program_only_command_from_the_host_is_refused_with_tc_2(
    dmc: galil.Controller, name: str
) -> None:
    dmc.programs.download('#M\nMG "ran"\nEN\n')
    with pytest.raises(CommandError) as caught:
        dmc.command(FROM_HOST[name])
    assert caught.value.code == 2
    assert dmc.query_number("MG _BGA") == 0  # nothing started, no thread either
    assert not dmc.programs.threads


def test_the_program_only_commands_run_in_a_program(dmc: galil.Controller) -> None:
    program = """#M
t0=TIME
JG 10000;BG A
AS A
AD 1000
ta=TIME-t0
AR 1000
tb=TIME-t0
MF 2500
AP 3000
IF (1);JS #R;ELSE;MG "no";ENDIF
JS #I
ST A;AM A
VM BC;VP -2000,0;VE;BG S
MRB=-500
AV 1000
tv=TIME-t0
AM S
AI 1
AT 0;AT 10,1
ZS
MG ta,tb,_TPA>=3000,tv>0,_TC
EN
#R
RE 1
#I
RI 0
"""
    lines = run_program(dmc, program)
    # AD/AR watch the profile: 1000 and 2000 counts at 10000 counts/s after the ramp.
    assert len(lines) == 1
    ta, tb, ap, av, tc = (float(v) for v in lines[0].split())
    assert (ap, av, tc) == (1.0, 1.0, 0.0)
    assert 1000 / 10000 * 1024 < ta < tb < 2300 / 10000 * 1024


def test_am_mc_and_wt_hold_a_program_thread(dmc: galil.Controller) -> None:
    # From the host they are refused (decision 0044); in a program they wait as they did.
    program = """#M
PR 1000;BG A
AM A
b=_BGA;r=_RPA
MC A
p=_TPA
t0=TIME;WT 10;w=TIME-t0
MG b,r,p,w
EN
"""
    # WT 10: 10 ms is 11 samples of 1/1024 s, rounded up.
    assert run_program(dmc, program) == ["0.0000 1000.0000 1000.0000 11.0000"]


# ---- AT ---------------------------------------------------------------------------------
def test_at_waits_from_its_reference_and_at_minus_n_moves_the_reference_on(
    dmc: galil.Controller,
) -> None:
    # The reference's own sequence: AT 0; AT 50; AT 100; AT -150; AT 80 (230 after the start),
    # in samples and in ms (a sample is 1/1024 s at TM 1000: 50 ms is 52 samples, rounded up).
    program = """#M
WT 7,1
t0=TIME
AT 0
AT 50,1;a=TIME-t0
AT 100,1;b=TIME-t0
AT -150,1;c=TIME-t0
AT 80,1;d=TIME-t0
AT 0;t0=TIME
AT 50;e=TIME-t0
AT 100;f=TIME-t0
AT -150;g=TIME-t0
AT 80;h=TIME-t0
MG a,b,c,d
MG e,f,g,h
EN
"""
    assert run_program(dmc, program) == [
        "50.0000 100.0000 150.0000 230.0000",
        "52.0000 103.0000 154.0000 236.0000",
    ]


def test_at_in_the_past_goes_on_at_once_and_at_minus_n_keeps_the_pace(
    dmc: galil.Controller,
) -> None:
    # Late by 100 samples, AT -20,1 five times goes on at once; the reference moves on by 20
    # each time, so the next wait ends 120 samples after AT 0.
    program = """#M
AT 0;t0=TIME
WT 100,1
i=0
#L
AT -20,1
i=i+1
JP #L,(i<5)
late=TIME-t0
AT -20,1
MG late>=100,TIME-t0
EN
"""
    assert run_program(dmc, program) == ["1.0000 120.0000"]


# ---- TS bit 6 -----------------------------------------------------------------------------
def test_ts_bit_6_is_set_exactly_while_the_error_exceeds_er() -> None:
    # The servo lag makes an error of about speed x lag; the program watches TS at every
    # command and counts the samples where bit 6 and |TE| > ER disagree. (A DMC-4143: the
    # 4103 family takes ER -1, which "disables Error output".)
    program = """#M
ER 40
bad=0;n=0;t=-1
JG 30000;BG A
#W
e=(@ABS[_TEA]>_ERA);s=((_TSA&64)=64)
bad=bad+(e<>s);n=n+s
IF ((s=1)&(t<0));t=TIME;ENDIF
JP #W,(TIME<(t0+300))
ST A;AM A;WT 200
MG bad,n>0,t>t0,_TSA&64
ER -1;MG _TSA&64
EN
"""
    with simulated("DMC-4143") as dmc:
        dmc.programs.download(program)
        dmc.command("t0=TIME")
        dmc.programs.run("#M", thread=0)
        dmc.sleep(1.0)
        assert not dmc.programs.threads
        assert drain_messages(dmc) == ["0.0000 1.0000 1.0000 0.0000", "0.0000"]
