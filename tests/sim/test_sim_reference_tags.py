"""Every command the simulator runs, against the tags of its DMC-4103 command reference entry.

Source: the DMC-4103 command reference (the stored copy, ``read_file`` id 61423517454). Each
entry's header line carries "Valid in terminal" or "Not Valid in terminal", and "Valid while in
motion" or "Not Valid while in motion" (e.g. ``SH``: "Burnable Valid in terminal Not Valid
while in motion Valid in program Variable axis supported"). :data:`TAGS` has one row per
command the simulator answers (its rooms' handlers, and the interpreter's own IF, ELSE, ENDIF
and ``=``), read off those lines, with a harmless form of it; where the simulator keeps another
behaviour on purpose, the row says why (decision 0045). The tests check a DMC-4040:

- in motion: from a host, while the motion the row names runs, a command "Valid while in
  motion" is taken and one "Not Valid while in motion" is refused (``?``, TC 7 unless the row
  gives another code); a program-only command is checked in a program thread instead;
- in the terminal: at rest, from a host, a command "Valid in terminal" is taken, one "Not
  Valid in terminal" is refused with TC 2 ("Command only valid from program");
- in a program: at rest, in a program thread, a command "Valid in program" runs, and one "Not
  Valid in program" stops the thread with TC 3 ("Command not valid in program"), the download
  of its program having been taken (decision 0047).
"""

from __future__ import annotations

import inspect
import pkgutil
from dataclasses import dataclass

import pytest

import galil.sim.rooms
from galil.axis import Axis
from galil.errors import CommandError, InvalidArgument
from galil.sim.controller import SimController
from galil.sim.machine import Room
from galil.sim.programs import NOT_IN_PROGRAM, PROGRAM_ONLY
from galil.sim.registry import HandlerSpec, marks
from galil.sim.rooms.tuning import Tuning
from galil.testing import nothing_sent, sim_of, simulated
from galil.tuning import Setting

#: The motion a form meets (each is accepted on a fresh DMC-4040).
JOG = "JGA=5000;BGA"  # A jogs
MOVE = "PRA=1000000;BGA"  # A runs a position move
SEQ = "VMBC;VS 5000;VP 100000,0;BGS"  # a vector sequence runs on S (B and C), its buffer open
LSEQ = "LMBC;VS 5000;LI ,100000,0;BGS"  # a linear sequence runs on S
CONTOUR = "CMA;DT 4;CD 100;CD 100"  # A contours


@dataclass(frozen=True)
class Tag:
    """One command's reference tags and how the test meets them.

    Attributes:
        motion: "Valid while in motion" (``False``: "Not Valid while in motion").
        terminal: "Valid in terminal" (``False``: "Not Valid in terminal").
        form: a harmless form of the command (lines of a program for a program-only one).
        scenario: the motion the form meets.
        code: the TC of the refusal in motion.
        rest: the form sent at rest from a host, where it must differ.
        kept: why the simulator keeps another behaviour than the tag (decision 0045).
        sim_motion: what the simulator does in motion where ``kept`` says so.
        always: the TC every form gets on the DMC-4040 (nothing there to take): the test
            then checks that neither motion nor the host port changes the answer.
        program: "Valid in program" (``False``: "Not Valid in program").
        in_program: the form a program runs, where the host's cannot be one (a ``\\``
            would end the download; ``CF I`` names the sender, which a thread is not).
        sim_program: the TC the simulator stops a thread with where ``kept`` says why it
            departs from "Valid in program".
    """

    motion: bool
    terminal: bool
    form: str
    scenario: str = JOG
    code: int = 7
    rest: str | None = None
    kept: str = ""
    sim_motion: bool | None = None
    always: int | None = None
    program: bool = True
    in_program: str | None = None
    sim_program: int | None = None


def _valid(form: str, scenario: str = JOG, **kw: object) -> Tag:
    return Tag(True, True, form, scenario, **kw)  # type: ignore[arg-type]


def _still(form: str, scenario: str = JOG, **kw: object) -> Tag:
    return Tag(False, True, form, scenario, **kw)  # type: ignore[arg-type]


def _program(form: str, motion: bool = True, **kw: object) -> Tag:
    return Tag(motion, False, form, **kw)  # type: ignore[arg-type]


_DC_KEPT = "decision 0039: its remark allows DC in a jog and in a stop's ramp (checked in a move)"
_DT_KEPT = (
    "its remarks: 'DT-1 during contour mode will pause', 'A positive DT will resume'; the "
    "library's contour streams send DT in contour mode (decision 0038)"
)
_WT_KEPT = (
    "the reference's own examples wait in motion (AB: 'BG A; WT 5000'); a program's WT runs in "
    "motion as it always has"
)
_PLANE_KEPT = "TC 29 'Not valid during coordinated move' (the TC list) while its plane runs"
_BURN_KEPT = (
    "TC 17 'ED, BN and DL not valid while program running' (the TC list), and so in a "
    "thread; the simulator has refused BP with BN from the start (decision 0047)"
)
_LM_KEPT = (
    "taken while other axes move; refused (TC 29) while its own plane runs, as VM: a running "
    "sequence's mode is not changed"
)

#: DMC-4103 command reference tags (file 61423517454) of every command the simulator runs.
TAGS: dict[str, Tag] = {
    "\x12\x13": _valid("\x12\x13", program=False),  # ^R^S
    "\x12\x16": _valid("\x12\x16", program=False),  # ^R^V
    "AB": _valid("AB 1"),
    "AC": _valid("ACA=256000"),
    "AD": _program("AD 0"),
    "AI": _program("AI 1"),
    "AM": _program("AMB"),
    "AO": _valid("AO 1,0", always=6),  # (analog outputs: Modbus only on the DMC-4000)
    "AP": _program("AP 0"),
    "AQ": _valid("AQ 1,2"),
    "AR": _program("AR 0"),
    "AS": _program("ASB"),
    "AT": _program("AT 0"),
    "AV": _program("AV 0", scenario=SEQ),
    "BG": _still("BGA", code=21),  # (TC 21 "Begin not valid while running")
    "BL": _valid("BLA=-2147483648"),
    "BN": _valid("BN", kept=_BURN_KEPT, sim_program=17),
    "BP": _still("BP", kept=_BURN_KEPT, sim_program=17),
    "BR": _still("BRA=0"),
    "BV": _valid("BV"),
    "CA": _valid("CAS"),
    "CB": _valid("CB 1"),
    "CD": _valid("CD 100", CONTOUR, rest="CMD;CD 0=0"),
    "CE": _still("CEA=0"),
    "CF": _valid("CF I", in_program="CF S"),
    "CM": _valid("CMD"),
    "CN": _valid("CN -1"),
    "CR": _valid("CR 1000,0,90", SEQ, rest="VMBC;CR 1000,0,90;CSS"),
    "CS": _still("CSS", SEQ, code=29, kept=_PLANE_KEPT),
    "CW": _valid("CW 2"),
    "DA": _valid("DM xx[2];DA xx[]"),
    "DC": _still("DCA=256000", MOVE, kept=_DC_KEPT),
    "DE": _valid("DEA=0"),
    "DL": _valid("DL\r#T\rEN\r\\", program=False, in_program="DL"),
    "DM": _valid("DM xx[2]"),
    "DP": _still("DPA=0"),
    "DQ": _valid("DQ 0,4", always=1),  # (analog output ranges: a RIO-47120's, no DMC's)
    "DR": _valid("DR 0"),
    "DT": _still("DT 4", CONTOUR, kept=_DT_KEPT, sim_motion=True),
    "EI": _valid("EI 0"),
    "ELSE": _program("IF (0)\rELSE\rENDIF"),
    "EN": _program("EN"),
    "ENDIF": _program("IF (1)\rENDIF"),
    "EO": _valid("EO 0"),
    "ER": _valid("ERA=16384"),
    "FE": _still("FEA"),
    "FI": _still("FIA"),
    "FL": _valid("FLA=2147483647"),
    "GA": _valid("GAB=A"),
    "GR": _valid("GRD=0"),
    "HM": _still("HMA"),
    "HV": _valid("HVA=256"),
    "HX": _valid("HX"),
    "IF": _program("IF (1)\rENDIF"),
    "IH": _valid("IHT=>-1"),
    "II": _valid("II 0"),
    "IL": _valid("ILA=9.998"),
    "IP": _valid("IPA=0"),
    "IT": _valid("ITA=1"),
    "JG": _valid("JGA=5000"),
    "JP": _program("JP #S"),
    "JS": _program("JS #S"),
    "KD": _valid("KDA=64"),
    "KI": _valid("KIA=0"),
    "KP": _valid("KPA=6"),
    "KS": _valid("KSA=2"),
    "LA": _valid("LA"),
    "LD": _valid("LDA=0"),
    "LE": _valid("LE", LSEQ, rest="LMBC;LI ,100,0;LE;CSS"),
    "LI": _valid("LI ,100000,0", LSEQ, rest="LMBC;LI ,100,0;CSS"),
    "LM": _valid("LMBC", SEQ, code=29, kept=_LM_KEPT, sim_motion=False),
    "LS": _valid("LS", program=False),
    "LV": _valid("LV"),
    "LZ": _valid("LZ 1"),
    "MC": _program("MCB"),
    "MF": _program("MF 0"),
    "MG": _valid("MG 1"),
    "MO": _still("MOA"),
    "MR": _program("MR 0"),
    "MT": _still("MTA=1", rest="MOA;MTA=1"),  # (TC 135 with the motor on: decision 0043)
    "NO": _valid("NO"),
    "OB": _valid("OB 1,1"),
    "OE": _valid("OEA=0"),
    "OP": _valid("OP 0"),
    "PA": _still("PAA=0"),
    "PF": _valid("PF 10.0"),
    "PR": _still("PRA=0"),
    "QD": _valid("DM qq[2];QD qq[]\r1,2\\", program=False, in_program="DM qq[2];QD qq[]"),
    "QR": _valid("QR"),
    "QU": _valid("DM qq[2];QU qq[],0,1,1"),
    "QZ": _valid("QZ"),
    "RA": _valid("DM qq[2];RA qq[]"),
    "RC": _valid("RC 0"),
    "RD": _valid("RD _TPA"),
    "RE": _program("RE"),
    "RI": _program("RI"),
    "RP": _valid("RP"),
    "RS": _valid("RS", program=False),
    "SB": _valid("SB 1"),
    "SC": _valid("SC"),
    "SH": _still("SHA"),
    "SP": _valid("SPA=5000"),
    "ST": _valid("STB"),
    "TB": _valid("TB"),
    "TC": _valid("TC"),
    "TD": _valid("TD"),
    "TE": _valid("TE"),
    "TH": _valid("TH"),
    "TL": _valid("TLA=9.998"),
    "TM": _still("TM 1000"),
    "TP": _valid("TP"),
    "TS": _valid("TS"),
    "TV": _valid("TV"),
    "TW": _valid("TWA=32766"),
    "UI": _valid("UI 1"),
    "UL": _valid("UL", program=False),
    "VA": _valid("VA 256000", SEQ),
    "VD": _still("VD 256000", SEQ),
    "VE": _valid("VE", SEQ, rest="VMBC;VP 100,0;VE;CSS"),
    "VF": _valid("VF 10.4"),
    "VM": _still("VMBC", SEQ, code=29, kept=_PLANE_KEPT),
    "VP": _valid("VP 200000,0", SEQ, rest="VMBC;VP 100,0;CSS"),
    "VS": _valid("VS 5000", SEQ),
    # VT and WC have no entry in this reference; the DMC-4040 has no VT (TC 1).
    "VT": _valid("VT 1", SEQ, always=1),
    "WC": _valid("WC", CONTOUR),
    "WH": _valid("WH", program=False),
    "WT": _program("WT 2", motion=False, kept=_WT_KEPT, sim_motion=True),
    "XQ": _valid("DL\r#T\rEN\r\\\rXQ #T,1", in_program="XQ #S,2"),
    "ZS": _program("ZS"),
    "=": _valid("x=1"),  # (the assignment operator)
}

#: "Not Valid in terminal", answered from a host with the ``:`` held until they clear since
#: decision 0001 (decision 0037); a parallel change puts them in ``PROGRAM_ONLY``.
_HELD_FROM_HOST = frozenset({"AM", "MC", "WT"})


def ask(sim: SimController, text: str) -> str:
    """Send one line; a held ``:`` (a burn, a trippoint) is waited for."""
    reply = sim.feed(text.encode("latin-1") + b"\r").decode("latin-1")
    if not reply:
        reply = sim.advance_until_output(5.0).decode("latin-1")
    return reply


def error_code(sim: SimController) -> int:
    reply = sim.feed(b"MG _TC\r").decode()
    return round(float(reply[:-3]))


def moving(scenario: str) -> SimController:
    sim = SimController("DMC-4040")
    assert ask(sim, scenario) == ":" * (scenario.count(";") + 1), scenario
    return sim


def in_program(sim: SimController, form: str) -> int:
    """Run ``form`` in thread 1 for a few samples; the error code it left."""
    assert ask(sim, f"DL\r#P\r{form}\rEN\r#S\rEN\r\\") == "::"
    assert ask(sim, "XQ #P,1") == ":"
    sim.advance(0.02)
    return error_code(sim)


def check(sim: SimController, form: str, valid: bool, code: int, always: int | None) -> None:
    reply = ask(sim, form)
    if always is not None:
        assert reply.endswith("?"), reply
        assert error_code(sim) == always
    elif valid:
        assert reply.endswith(":"), reply
        assert error_code(sim) == 0
    else:
        assert reply.endswith("?"), reply
        assert error_code(sim) == code


def handler_names() -> set[str]:
    """Every command a room of the simulator answers (``galil.sim.rooms``, all modules)."""
    names: set[str] = set()
    package = galil.sim.rooms
    for info in pkgutil.iter_modules(package.__path__):
        module = __import__(f"{package.__name__}.{info.name}", fromlist=["_"])
        for _, room in inspect.getmembers(module, inspect.isclass):
            if issubclass(room, Room):
                for value in vars(room).values():
                    names.update(m.name for m in marks(value) if isinstance(m, HandlerSpec))
    return names


def test_the_table_has_a_row_for_every_command_the_simulator_runs() -> None:
    # (a room that gains a handler needs its row here, read off the reference's header)
    assert set(TAGS) == handler_names() | {"IF", "ELSE", "ENDIF", "="}


def test_every_row_where_the_simulator_departs_from_the_tag_says_why() -> None:
    for name, tag in TAGS.items():
        departs = tag.sim_motion is not None and tag.sim_motion != tag.motion
        assert not departs or tag.kept, name
        assert tag.sim_program is None or tag.kept, name


@pytest.mark.parametrize("name", sorted(n for n, t in TAGS.items() if t.terminal))
def test_commands_valid_while_in_motion_are_taken_and_the_others_refused(name: str) -> None:
    tag = TAGS[name]
    valid = tag.motion if tag.sim_motion is None else tag.sim_motion
    check(moving(tag.scenario), tag.form, valid, tag.code, tag.always)


@pytest.mark.parametrize("name", sorted(n for n, t in TAGS.items() if not t.terminal))
def test_program_only_commands_run_in_a_program_while_an_axis_moves(name: str) -> None:
    tag = TAGS[name]
    valid = tag.motion if tag.sim_motion is None else tag.sim_motion
    code = in_program(moving(tag.scenario), tag.form)
    assert code == (0 if valid else tag.code)


@pytest.mark.parametrize("name", sorted(TAGS))
def test_commands_valid_in_the_terminal_are_answered_from_a_host_and_the_others_refused(
    name: str,
) -> None:
    tag = TAGS[name]
    sim = SimController("DMC-4040")
    form = tag.rest or tag.form
    if tag.terminal or (name in _HELD_FROM_HOST and name not in PROGRAM_ONLY):
        check(sim, form, True, 0, tag.always)
    else:
        check(sim, form, False, 2, None)


def test_the_rows_not_valid_in_a_program_are_the_simulators_set() -> None:
    # (one set, NOT_IN_PROGRAM, is what a program thread refuses: its rows here say so)
    assert {n for n, t in TAGS.items() if not t.program} == NOT_IN_PROGRAM


def number(sim: SimController, expression: str) -> float:
    return float(sim.feed(f"MG {expression}\r".encode()).decode()[:-3])


def in_a_thread(form: str) -> SimController:
    """A DMC-4040 at rest that ran ``form`` (line 1 of its program) in thread 1 for a few
    samples, its output kept apart from the replies."""
    sim = SimController("DMC-4040")
    sim.separate_messages = True
    assert ask(sim, f"DL\r#P\r{form}\rEN\r#S\rEN\r\\") == "::"  # (any line is stored)
    assert ask(sim, "XQ #P,1") == ":"
    sim.advance(0.02)
    return sim


@pytest.mark.parametrize("name", sorted(TAGS))
def test_commands_valid_in_a_program_run_in_a_thread_and_the_others_stop_it_with_tc_3(
    name: str,
) -> None:
    tag = TAGS[name]
    sim = in_a_thread(tag.in_program or tag.rest or tag.form)
    code = error_code(sim)
    if tag.always is not None or tag.sim_program is not None:
        assert code == (tag.always or tag.sim_program)
    elif tag.program:
        assert code == 0
    else:
        assert code == 3
        assert (number(sim, "_ED"), number(sim, "_ED1"), number(sim, "_XQ1")) == (1, 1, -1)


def test_a_thread_runs_up_to_a_command_not_valid_in_a_program_and_stops_there() -> None:
    sim = in_a_thread("y=1\rx=1;WH;x=2\rx=3")
    assert (error_code(sim), number(sim, "_ED"), number(sim, "x")) == (3, 2, 1)
    assert ask(sim, "TC 1") == " 3 Command not valid in program\r\n:"
    assert ask(sim, "WH") == "RS232\r\n:"  # (from a host it answers)


_STILL_SETTINGS = sorted(
    name
    for name, value in vars(Axis).items()
    if isinstance(value, Setting) and not TAGS[value.mnemonic].motion
)


def test_typed_settings_of_commands_not_valid_in_motion_are_marked_still() -> None:
    for name, value in vars(Axis).items():
        if isinstance(value, Setting):
            assert value.still == (not TAGS[value.mnemonic].motion), name
    assert _STILL_SETTINGS == ["brush", "encoder_config", "motor_type"]


@pytest.mark.parametrize("name", _STILL_SETTINGS)
def test_a_still_setting_is_refused_unsent_while_the_librarys_own_jog_runs(name: str) -> None:
    with simulated() as dmc:
        jog = dmc.A.jog(5000)
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(InvalidArgument, match="while axis A moves"),
        ):
            setattr(dmc.A, name, 1)
        jog.stop()


def test_servo_here_is_refused_unsent_while_an_axis_moves_and_sent_at_rest() -> None:
    with simulated() as dmc:
        jog = dmc.A.jog(5000)
        with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="A mov"):
            dmc.servo_here("AB")
        dmc.servo_here("B")  # (B is at rest)
        jog.stop()
        jog.wait()
        dmc.servo_here()


def test_burning_the_program_is_refused_unsent_while_the_librarys_own_jog_runs() -> None:
    # BP: "Not Valid while in motion" (TC 7; decisions 0045, 0047)
    with simulated() as dmc:
        burns = sim_of(dmc).room(Tuning).burns
        jog = dmc.A.jog(5000)
        for burn in (dmc.programs.burn, dmc.save_program):
            with (
                nothing_sent(dmc, allow_queries=True),
                pytest.raises(InvalidArgument, match="BP is not valid while axis A moves"),
            ):
                burn()
        jog.stop()
        jog.wait()
        dmc.programs.burn()  # (at rest it goes out)
        assert burns["BP"] == 1


def test_burning_the_program_right_after_a_move_of_no_length_is_refused_unsent() -> None:
    # A move to where the axis is predicts 0 s; the controller's _BG reads 1 until its next
    # sample, so BP in the same instant would be its TC 7 (a random operation run found it).
    with simulated() as dmc:
        burns = sim_of(dmc).room(Tuning).burns
        move = dmc.A.move_to(0)
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(InvalidArgument, match="BP is not valid while axis A moves"),
        ):
            dmc.programs.burn()
        move.wait()
        dmc.programs.burn()
        assert burns["BP"] == 1


def test_burning_the_program_in_motion_the_library_did_not_start_is_the_controllers_tc_7() -> None:
    with simulated() as dmc:
        dmc.command("JGA=5000;BGA", allow_compound=True)  # (a raw BG: the library knows nothing)
        with pytest.raises(CommandError) as refused:
            dmc.programs.burn()
        assert refused.value.code == 7
        assert sim_of(dmc).room(Tuning).burns["BP"] == 0
        dmc.command("STA")


def test_ed_reads_no_error_until_a_program_fails_and_again_after_a_reset() -> None:
    # ED: "_ED0 returns 0 if no error has occurred. _ED1 returns -1 if no error has occurred."
    sim = SimController("DMC-4040")
    assert (number(sim, "_ED"), number(sim, "_ED1")) == (0, -1)
    sim = in_a_thread("KPA=-1")
    assert (number(sim, "_ED"), number(sim, "_ED1"), error_code(sim)) == (1, 1, 6)
    assert ask(sim, "RS") == ":"
    sim.advance(0.02)
    assert (number(sim, "_ED"), number(sim, "_ED1")) == (0, -1)


@pytest.mark.parametrize("cmderr", [False, True])
def test_an_error_without_cmderr_stops_every_thread_and_with_it_only_its_own(
    cmderr: bool,
) -> None:
    # #CMDERR: "Without #CMDERR defined, if an error (see TC command) occurs in an application
    # program ..., the program (and all threads) will stop"; "the thread that has an error will
    # be halted ... Thread 0 will be interrupted to run the #CMDERR routine but other threads
    # will continue to run".
    sim = SimController("DMC-4040")
    routine = "\r#CMDERR\rEN 1" if cmderr else ""  # (EN 1: thread 0 waits on)
    assert ask(sim, f"DL\r#W\rWT 1000\rEN\r#F\rKPA=-1\rEN{routine}\r\\") == "::"
    assert ask(sim, "XQ #W,0;XQ #W,1;XQ #F,2") == ":::"
    sim.advance(0.02)
    assert [number(sim, f"_XQ{t}") for t in range(3)] == ([1, 1, -1] if cmderr else [-1] * 3)
    assert (number(sim, "_ED"), number(sim, "_ED1")) == (4, 2)
