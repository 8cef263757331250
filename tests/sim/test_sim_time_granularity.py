"""How simulated time is advanced does not change what the simulator does (metamorphic tests).

The servo loop runs in steps of many samples and finds events inside a step (a horizon cuts
the step before a known one; a watch is bisected to the sample where it turns true). Each
scenario here runs twice on a fresh controller, once with its time in one advance per
stretch and once one servo sample at a time (and, for some, in random uneven pieces), and
everything a host could see must be the same: every reply and message byte, the streamed
data records and interrupt packets, positions, stop codes, the ``TIME`` events were seen at,
program variables, outputs and captured arrays, and the sample the controller is at after
each stretch.

The trippoints ``AP``/``AR``/``AV``, the automatic subroutines (``#LIMSWI``, ``#POSERR``,
``#ININT``, ``#MCTIME``) and off-on-error are among the scenarios (decision 0029), as are
``AT``, ``IF``/``ELSE``/``ENDIF`` and ``TS`` bit 6 (decision 0037).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.sim.controller import SimController

#: Seconds per servo sample at the default TM 1000 (1/1024 s: sums of it are exact).
TS = 1 / 1024


@dataclass(frozen=True)
class Cmd:
    """Commands sent to a port (0 is the main port; others are opened by the scenario)."""

    text: str
    port: int = 0


@dataclass(frozen=True)
class Run:
    """Let ``samples`` servo samples (at TM 1000) of time pass."""

    samples: int


@dataclass(frozen=True)
class Hook:
    """A test hook called between stretches of time (a switch placed, an input driven)."""

    call: Callable[[SimController], None]


Step = Cmd | Run | Hook
Split = Callable[[int], Sequence[int]]


@dataclass(frozen=True)
class Scenario:
    steps: tuple[Step, ...]
    lag: float = 0.003
    ports: tuple[str, ...] = ()  # handles opened first: A, B, ... ("UDP..." for EI)


def one_go(n: int) -> list[int]:
    return [n]


def per_sample(n: int) -> list[int]:
    return [1] * n


def play(sc: Scenario, split: Split) -> tuple[list[int], dict[int, bytes]]:
    """Run ``sc``; return the sample after each stretch, and every byte out of each port."""
    sim = SimController("DMC-4040", servo_lag=sc.lag)
    ports = [0] + [sim.open_port(name) for name in sc.ports]
    out = dict.fromkeys(ports, b"")
    after: list[int] = []
    for step in sc.steps:
        if isinstance(step, Cmd):
            out[ports[step.port]] += sim.feed(step.text.encode() + b"\r", ports[step.port])
        elif isinstance(step, Hook):
            step.call(sim)
        else:
            for k in split(step.samples):
                sim.advance(k * TS)
            after.append(sim.sample)  # before anything syncs the servo loop again
        for p in ports:
            out[p] += sim.poll(p)
    return after, out


def program(*lines: str) -> Cmd:
    """Download a program (``DL``)."""
    return Cmd("DL\r" + "\r".join(lines) + "\r\\")


def place(axis: str, forward: int | None = None, reverse: int | None = None) -> Hook:
    return Hook(lambda sim: sim.place_limit_switches(axis, forward=forward, reverse=reverse))


def place_ahead(axis: str, by: int) -> Hook:
    """A forward switch ``by`` counts beyond where the motor is now."""

    def call(sim: SimController) -> None:
        sim.place_limit_switches(axis, forward=sim.machine_position(axis) + by)

    return Hook(call)


def home(axis: str, **geometry: int) -> Hook:
    return Hook(lambda sim: sim.set_home_switch(axis, **geometry))


def drive_input(n: int, high: bool) -> Hook:
    return Hook(lambda sim: sim.set_input(n, high))


STATE = Cmd("MG _TPA,_RPA,_SCA,_BGA,_TPB,_RPB,_SCB,_BGB;MG _TPC,_SCC,_TC,TIME,_OP0")
#: An arc that takes axis A from 0 out to +2000 and back to 0 (B from 0 to -1000, +1000, 0).
CIRCLE = "VM AB;VS 20000;CR 1000,180,360;VE;BG S"

SCENARIOS: dict[str, Scenario] = {
    # ---- homing: edges and index pulses crossed inside one advance ----------------------
    "FE": Scenario(
        (home("A", edge=-3000), Cmd("DR 16,0", 1), Cmd("FEA;BGA"), Run(2500), STATE),
        ports=("TCP records",),
    ),
    "FI": Scenario(
        (Cmd("DR 16,0", 1), Cmd("HV 2000;JG -6000;FIA;BGA"), Run(3000), STATE),
        ports=("TCP records",),
    ),
    "HM": Scenario(
        (
            home("A", edge=-3000),
            Cmd("DR 32,0", 1),
            program("#H", "HV 3000;HM A;BG A", "AM A", "t1=TIME;p1=_TPA", "MC A", "t2=TIME", "EN"),
            Cmd("XQ #H"),
            Run(5000),
            Cmd("MG t1,p1,t2"),
            STATE,
        ),
        ports=("TCP records",),
    ),
    "HM home flag above the edge": Scenario(
        (
            home("B", edge=2500, side=1, index_offset=700),
            Cmd("CN,1;HV,2500;HMB;BGB"),
            Run(5000),
            STATE,
        )
    ),
    # ---- trippoints in a program -------------------------------------------------------
    "AD AM MC WT AI": Scenario(
        (
            program(
                "#M",
                "PR 5000,3000;BG AB",
                "AD 1000",
                "t1=TIME;p1=_RPA",
                "SB 1",
                "AM B",
                "t2=TIME",
                "MC A",
                "t3=TIME",
                "WT 37",
                "t4=TIME",
                "AI -3",
                "t5=TIME",
                "CB 1;SB 2",
                "JG 3000;BG A",
                "WT 10,1",
                "t6=TIME",
                "ST A",
                "AM A",
                "t7=TIME",
                'MG "done",t7',
                "EN",
            ),
            Cmd("XQ #M"),
            Run(700),
            drive_input(3, False),
            Run(300),
            STATE,
            Cmd("MG t1,p1,t2,t3,t4,t5,t6,t7"),
        ),
        lag=0.02,
    ),
    "AD reached while a jog turns back": Scenario(
        (
            program(
                "#M",
                "JG 5000;BG A",
                "WT 200",
                "d=_RPA+20",
                "JG -5000",
                "AD d",
                "t=TIME;p=_RPA",
                "EN",
            ),
            Cmd("XQ #M"),
            Run(1500),
            Cmd("MG d,t,p"),
        )
    ),
    "AM S and WC in threads": Scenario(
        (
            program(
                "#V",
                "VM AB;VP 3000,1000;CR 1000,0,90;VE;BG S",
                "AM S",
                "v=TIME",
                "EN",
                "#C",
                "CM C;DT 4",
                "i=0",
                "#L",
                "CD ,,100",
                "WC",
                "i=i+1;JP #L,i<10",
                "CD 0=0",
                "AM C",
                "c=TIME",
                "EN",
            ),
            Cmd("XQ #V,0;XQ #C,1"),
            Run(2000),
            Cmd("MG v,c,_CSS,_AVS"),
            STATE,
        )
    ),
    "two threads' messages": Scenario(
        (
            program(
                "#A",
                "PR 2000;BG A",
                "AD 500",
                'MG "A1",TIME',
                "AM A",
                'MG "A2",TIME',
                "EN",
                "#B",
                "WT 50",
                'MG "B1",TIME',
                "AI 2",
                'MG "B2",TIME',
                "EN",
            ),
            Cmd("XQ #A,0;XQ #B,1"),
            Run(20),
            drive_input(2, False),
            Run(300),
            drive_input(2, True),
            Run(400),
            STATE,
        )
    ),
    "TM changed by a program": Scenario(
        (
            program("#T", "WT 100", "TM 500", "t1=TIME", "WT 100", "t2=TIME", "EN"),
            Cmd("XQ #T"),
            Run(1024),
            Cmd("MG t1,t2,TIME,_TM"),
        )
    ),
    "AP on the lagging encoder, AR again and again": Scenario(
        (
            program(
                "#M",
                "JG 20000;BG A",
                "AP 3000",
                "t1=TIME;p1=_TPA;r1=_RPA",
                "AR 2500",
                "t2=TIME;r2=_RPA",
                "AR -2500",
                "t3=TIME;r3=_RPA",
                "ST A",
                "EN",
            ),
            Cmd("XQ #M"),
            Run(1000),
            Cmd("MG t1,p1,r1,t2,r2,t3,r3"),
        ),
        lag=0.02,
    ),
    "AV along a sequence": Scenario(
        (
            program(
                "#V",
                "VM AB;VP 3000,4000;CR 1000,0,90;VE;BG S",
                "AV 1000",
                "a=TIME;da=_AVS",
                "AV 1500",
                "b=TIME;db=_AVS",
                "AV 99999",
                "c=TIME;dc=_AVS",
                "EN",
            ),
            Cmd("XQ #V"),
            Run(1500),
            Cmd("MG a,da,b,db,c,dc"),
        )
    ),
    # ---- automatic subroutines and off-on-error -------------------------------------------
    "#LIMSWI, RE 1 back to AM": Scenario(
        (
            place("A", forward=1500),
            program(
                "#M",
                "PR 3000;BG A",
                "AM A",
                "t=TIME",
                "EN",
                "#LIMSWI",
                "l=TIME;s=_SCA;p=_RPA",
                "WT 5",
                "RE 1",
            ),
            Cmd("XQ #M"),
            Run(1500),
            Cmd("MG t,l,s,p"),
            STATE,
        )
    ),
    "#POSERR and OE 1 at the error's first sample": Scenario(
        (
            program(
                "#M",
                "ER 40;OE 1",
                "JG 30000;BG A",
                "WT 300",
                "EN",
                "#POSERR",
                'MG "E",TIME,_TEA,_MOA,_SCA',
                "RE",
            ),
            Cmd("XQ #M"),
            Run(600),
            STATE,
        )
    ),
    "#POSERR with OE 0 while the lag catches up": Scenario(
        (
            program(
                "#M",
                "ER 60",
                "PR 4000;BG A",
                "AM A",
                "EN",
                "#POSERR",
                'MG "E",TIME,_TEA,_MOA',
                "RE 1",
            ),
            Cmd("XQ #M"),
            Run(800),
            STATE,
        ),
        lag=0.005,
    ),
    "#ININT while an input is low, RI 1": Scenario(
        (
            program(
                "#M",
                "II 2,2,,0",
                "c=0",
                "#L",
                "WT 7",
                "c=c+1",
                "JP #L,c<1000",
                "EN",
                "#ININT",
                'MG "I",TIME,c',
                "WT 20",
                "RI 1",
            ),
            Cmd("XQ #M"),
            Run(100),
            drive_input(2, False),
            Run(50),
            drive_input(2, True),
            Run(100),
            Cmd("MG c,TIME"),
        )
    ),
    "#MCTIME after TW": Scenario(
        (
            program(
                "#M",
                "TW 20",
                "PR 1000;BG A",
                "MC A",
                "t=TIME",
                "EN",
                "#MCTIME",
                "m=TIME;s=_SCA",
                "EN",
            ),
            Cmd("XQ #M"),
            Run(1000),
            Cmd("MG t,m,s"),
        ),
        lag=0.05,
    ),
    "OE 2: the motor off at a limit switch": Scenario(
        (place("A", forward=1500), Cmd("OE 2;JG 10000;BG A"), Run(1000), STATE)
    ),
    # ---- limits ------------------------------------------------------------------------
    "forward switch, PR": Scenario(
        (place("A", forward=1500), Cmd("PR 3000;BG A"), Run(2000), STATE)
    ),
    "reverse switch, PR": Scenario(
        (place("A", reverse=-1500), Cmd("PR -3000;BG A"), Run(2000), STATE)
    ),
    "reverse switch, jog": Scenario(
        (place("A", reverse=-1500), Cmd("JG -20000;BG A"), Run(2000), STATE)
    ),
    "FL, PR": Scenario((Cmd("FL 1500;PR 3000;BG A"), Run(2000), STATE)),
    "BL, jog": Scenario((Cmd("BL -1500;JG -20000;BG A"), Run(2000), STATE)),
    "FL lowered under a slow jog": Scenario(
        (Cmd("JG 100;BG A"), Run(3000), Cmd("FL 200"), Run(300), STATE)
    ),
    "BL raised over a slow jog": Scenario(
        (Cmd("JG -70;BG A"), Run(3000), Cmd("BL -100"), Run(300), STATE)
    ),
    "gear follower into a switch": Scenario(
        (place("B", forward=1500), Cmd("GAB=A;GRB=2;PR 3000;BG A"), Run(2000), STATE)
    ),
    "gear follower into a reverse switch": Scenario(
        (place("B", reverse=-1500), Cmd("GAB=A;GRB=-2;PR 3000;BG A"), Run(2000), STATE)
    ),
    "gear follower into FL": Scenario((Cmd("FLB=1500;GAB=A;GRB=2;PR 3000;BG A"), Run(2000), STATE)),
    "path follower (GA S) into a switch": Scenario(
        (place("C", forward=1500), Cmd("GAC=S;GRC=1;VM AB;VP 3000,0;VE;BG S"), Run(2000), STATE)
    ),
    "LI path into a switch": Scenario(
        (place("A", forward=1500), Cmd("LM AB;LI 3000,1000;LE;BG S"), Run(2000), STATE)
    ),
    "arc into FL": Scenario((Cmd("FL 1500;" + CIRCLE), Run(2000), STATE)),
    "arc in and out of a switch": Scenario(
        (place("A", forward=1500), Cmd(CIRCLE), Run(2000), STATE, Cmd("MG _CSS,_AVS"))
    ),
    "follower of an arc in and out of a switch": Scenario(
        (place("C", forward=1500), Cmd("GAC=A;GRC=1;" + CIRCLE), Run(2000), STATE)
    ),
    "jog turned back just short of a switch": Scenario(
        (Cmd("JG 5000;BG A"), Run(200), Cmd("JG -5000"), place_ahead("A", 20), Run(1000), STATE)
    ),
    # ---- DC in motion: a jog's ramps and a stop's ramp re-planned (decision 0039) ---------
    "DC in a jog, mid-ramp, in its stop and in a PR's stop": Scenario(
        (
            Cmd("JG 30000;AC 204800;DC 204800;PR ,50000;SP ,20000;BG AB"),
            Run(150),
            Cmd("DC 20480;JG 5000"),
            Run(150),
            Cmd("DC 102400;ST B"),
            Run(20),
            Cmd("DC ,10240"),
            Run(80),
            Cmd("ST A"),
            Run(30),
            Cmd("DC 10240"),
            Run(2000),
            STATE,
        )
    ),
    # ---- interrupts, record streams, captures --------------------------------------------
    "EI and UI": Scenario(
        (
            place("A", forward=1500),
            home("B", edge=-2000),
            Cmd("EI 259,,1", 1),
            Cmd("HV 3000;PR 3000;BG A;HM B;BG B"),
            Run(3000),
            Cmd("UI 3"),
            Run(10),
            STATE,
        ),
        ports=("TCP main", "UDP interrupts"),
    ),
    "DR through a switch stop": Scenario(
        (
            place("A", forward=1500),
            Cmd("DR 3,0", 1),
            Cmd("PR 3000,1000;BG AB"),
            Run(1000),
            STATE,
        ),
        ports=("TCP records",),
    ),
    "RA RD RC": Scenario(
        (
            Cmd("DM a[300],b[300],c[300];RA a[],b[],c[];RD _RPA,_TPB,TIME"),
            Cmd("PR 3000,1000;BG AB;RC 1"),
            Run(700),
            Cmd("MG _RC,_RD"),
            Cmd("QU a[],0,299,1"),
            Cmd("QU b[],0,299,1"),
            Cmd("QU c[],0,299,1"),
        )
    ),
    "RC round and round during an arc": Scenario(
        (
            Cmd("DM a[100],b[100];RA a[],b[];RD _TPA,_TPB;" + CIRCLE + ";RC 2,-50"),
            Run(1000),
            Cmd("MG _RC,_RD"),
            Cmd("QU a[],0,99,1"),
            Cmd("QU b[],0,99,1"),
        )
    ),
    "contour buffer runs dry": Scenario(
        (
            Cmd("DR 4,0", 1),
            Cmd("CM AB;DT 3;CD 100,50;CD 200,-50;CD 100,0"),
            Run(500),
            Cmd("MG _CM"),
            STATE,
        ),
        ports=("TCP records",),
    ),
    "contour ends": Scenario(
        (Cmd("CM AB;DT 3;CD 100,50;CD 200,-50;CD 100,0;CD 0=0"), Run(500), Cmd("MG _CM"), STATE)
    ),
    "vector sequence ends": Scenario(
        (
            Cmd("DR 64,0", 1),
            Cmd("VM AB;VP 3000,1000;CR 1000,0,90;VE;BG S"),
            Run(2000),
            Cmd("MG _CSS,_AVS,_BGS"),
            STATE,
        ),
        ports=("TCP records",),
    ),
    "LM sequence ends": Scenario(
        (Cmd("LM AB;LI 3000,1000;LI 1000,-500;LE;BG S"), Run(2000), Cmd("MG _CSS,_AVS"), STATE)
    ),
    # ---- decision 0037: AT pacing a loop, IF/ELSE on TS bit 6 while the error grows --------
    "AT -n paces IF/ELSE on TS bit 6": Scenario(
        (
            program(
                "#P",
                "AT 0",
                "n=0",
                "#L",
                "AT -37",
                "IF ((_TSA&64)=64)",
                ' MG "E",TIME,_TEA',
                "ELSE",
                ' IF (n=0);MG "first",TIME;ENDIF',
                "ENDIF",
                "n=n+1",
                "JP #L,(n<6)",
                "AT 20,1",
                'MG "end",TIME',
                "EN",
                "#J",
                "ER 40;JG 30000;BG A",
                "EN",
            ),
            Cmd("XQ #J,1"),
            Cmd("XQ #P"),
            Run(400),
            STATE,
        )
    ),
}

#: What a scenario must show (so both runs cannot agree on a wrong answer unnoticed).
EXPECT: dict[str, bytes] = {
    "forward switch, PR": b" 2.0000",
    "arc in and out of a switch": b" 2.0000",
    "follower of an arc in and out of a switch": b" 2.0000",
    "jog turned back just short of a switch": b" 2.0000",
    "contour buffer runs dry": b" 42.0000",
    "TM changed by a program": b" 500.0000",
    "#LIMSWI, RE 1 back to AM": b" 2.0000",
    "#POSERR and OE 1 at the error's first sample": b"E",
    "#POSERR with OE 0 while the lag catches up": b"E",
    "#ININT while an input is low, RI 1": b"I",
    "#MCTIME after TW": b" 99.0000",
    "AT -n paces IF/ELSE on TS bit 6": b"E",
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_one_advance_and_sample_by_sample_agree(name: str) -> None:
    sc = SCENARIOS[name]
    coarse = play(sc, one_go)
    assert b"?" not in coarse[1][0]
    assert play(sc, per_sample) == coarse
    if name in EXPECT:
        assert EXPECT[name] in coarse[1][0]


def _pieces(cuts: list[int]) -> Split:
    """Cut every stretch of ``n`` samples at the given fractions (in 1/1000ths)."""

    def split(n: int) -> list[int]:
        at = sorted({n * c // 1000 for c in cuts} - {0, n})
        return [b - a for a, b in zip([0, *at], [*at, n], strict=True)]

    return split


@settings(max_examples=6, deadline=None)
@given(st.lists(st.integers(1, 999), min_size=1, max_size=6))
@pytest.mark.parametrize(
    "name",
    [
        "HM",
        "AD AM MC WT AI",
        "arc in and out of a switch",
        "jog turned back just short of a switch",
        "DC in a jog, mid-ramp, in its stop and in a PR's stop",
        "DR through a switch stop",
        "RC round and round during an arc",
        "#POSERR with OE 0 while the lag catches up",
        "#ININT while an input is low, RI 1",
        "AT -n paces IF/ELSE on TS bit 6",
    ],
)
def test_uneven_pieces_agree_with_one_advance(name: str, cuts: list[int]) -> None:
    sc = SCENARIOS[name]
    assert play(sc, _pieces(cuts)) == play(sc, one_go)


def test_advance_until_output_lets_the_whole_time_pass_when_a_program_changes_tm() -> None:
    # (the samples were counted at the old period, and the clock then moved on by that many
    # samples of the new one: half the time asked for passed at TM 500)
    sim = SimController("DMC-4040")
    sim.feed(program("#T", "WT 100", "TM 500", "EN").text.encode() + b"\r")
    sim.feed(b"XQ #T\r")
    start = sim.clock.now()
    assert sim.advance_until_output(1.0) == b""
    assert sim.clock.now() - start == pytest.approx(1.0, abs=0.001)
    # ~0.1 s at TM 1000 (1024/s), the rest at TM 500 (2048/s)
    assert sim.sample == pytest.approx(0.1 * 1024 + 0.9 * 2048, abs=8)
