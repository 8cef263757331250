"""WT's range, REM, LS and DA's ``[0]`` forms, against the DMC-4103 command reference (decision
0051; the stored copy, ``read_file`` id 61423517454)."""

from __future__ import annotations

import pytest

import galil
from galil.sim.controller import SimController
from galil.terminal import Terminal


def ask(sim: SimController, text: str) -> str:
    return sim.feed(text.encode("latin-1") + b"\r").decode("latin-1")


def error_code(sim: SimController) -> int:
    return round(float(ask(sim, "MG _TC")[:-3]))


def download(sim: SimController, *lines: str) -> None:
    assert ask(sim, "DL\r" + "\r".join(lines) + "\r\\") == "::"


def run(sim: SimController, *lines: str, seconds: float = 0.05) -> tuple[int, int]:
    """Run ``lines`` as thread 0 for a while: the error code it left and ``_ED``."""
    download(sim, "#P", *lines, "EN")
    assert ask(sim, "XQ #P") == ":"
    sim.advance(seconds)
    return error_code(sim), round(float(ask(sim, "MG _ED")[:-3]))


# ---- WT: "n0  2  2,147,483,646 ... n1  0  1" -----------------------------------------------
@pytest.mark.parametrize("form", ["WT 0", "WT 1", "WT 2147483647", "WT -4", "WT 10,2", "WT 4,1,1"])
def test_wt_outside_its_range_stops_the_program_with_tc_6(form: str) -> None:
    sim = SimController("DMC-4040")
    assert run(sim, "a=1", form, "a=2") == (6, 2)
    assert ask(sim, "MG a") == " 1.0000\r\n:"


@pytest.mark.parametrize("form", ["WT 2", "WT 3", "WT 2,1", "WT 2,0", "WT 2147483646"])
def test_wt_in_its_range_is_taken(form: str) -> None:
    sim = SimController("DMC-4040")
    assert run(sim, form, seconds=0.01) == (0, 0)


def test_wt_waits_its_milliseconds_or_its_samples() -> None:
    sim = SimController("DMC-4040")
    download(sim, "#P", "t=TIME", "WT 100", "a=TIME-t", "t=TIME", "WT 100,1", "b=TIME-t", "EN")
    assert ask(sim, "XQ #P") == ":"
    sim.advance(0.5)
    # 100 ms is 103 samples at TM 1000 (a sample is 1/1024 s: decision 0042)
    assert ask(sim, "MG a,b") == " 103.0000 100.0000\r\n:"


# ---- REM: "REM is NOT a controller command" --------------------------------------------------
def test_a_rem_line_that_reaches_a_program_stops_it_with_tc_3() -> None:
    # "Not Valid in program": Galil's PC software strips REM lines before downloading; a
    # program that kept one stops there, as on the controller, which has no REM command.
    sim = SimController("DMC-4040")
    assert run(sim, "a=1", "REM a remark", "a=2") == (3, 2)
    assert ask(sim, "MG a") == " 1.0000\r\n:"


def test_rem_from_a_host_is_refused_and_comments_that_are_commands_run() -> None:
    sim = SimController("DMC-4040")
    assert ask(sim, "REM a remark") == "?"
    assert error_code(sim) == 2  # "Not Valid in terminal"
    assert ask(sim, "'a comment;NO another;MG 1;' and after") == ":: 1.0000\r\n::"
    sim = SimController("DMC-4040")
    assert run(sim, "NO a comment", "' another", "a=1;' after a command", "REMOTE=3") == (0, 0)
    assert ask(sim, "MG a,REMOTE") == " 1.0000 3.0000\r\n:"  # (REMOTE is a variable)


# ---- LS: "LS n0,n1 ... returns a listing of the programs in memory" --------------------------
def test_ls_lists_the_program_with_line_numbers_to_the_empty_line_after_it() -> None:
    sim = SimController("DMC-4040")
    download(sim, "MGTIME", "WT1000", "JP0")  # the program of the TR entry's example
    assert ask(sim, "LS") == "0 MGTIME\r\n1 WT1000\r\n2 JP0\r\n3 \r\n:"


def test_ls_lists_from_a_label_or_a_line_to_a_line() -> None:
    sim = SimController("DMC-4040")
    download(sim, "#m", "NO", "#a", "PR 500", "BG A", "AM", "WT 200", "EN")
    # LS's own example: "LS #a,6" lists lines 2 .. 6
    assert ask(sim, "LS #a,6") == "2 #a\r\n3 PR 500\r\n4 BG A\r\n5 AM\r\n6 WT 200\r\n:"
    assert ask(sim, "LS 6") == "6 WT 200\r\n7 EN\r\n8 \r\n:"
    assert ask(sim, "LS ,1") == "0 #m\r\n1 NO\r\n:"


@pytest.mark.parametrize(("form", "code"), [("LS 3,3", 6), ("LS 5,2", 6), ("LS 0,2000", 6)])
def test_ls_refuses_n0_not_below_n1_and_lines_past_the_memory(form: str, code: int) -> None:
    sim = SimController("DMC-4040")
    download(sim, "#a", "EN")
    assert ask(sim, form) == "?"
    assert error_code(sim) == code
    assert ask(sim, "LS #b") == "?"
    assert error_code(sim) == 10  # (no such label)


def test_ls_in_a_program_stops_it_with_tc_3() -> None:
    assert run(SimController("DMC-4040"), "a=1", "LS", "a=2") == (3, 2)


def test_ls_typed_in_the_terminal_prints_one_line_per_program_line() -> None:
    with galil.connect("sim://DMC-4040") as dmc:
        out: list[str] = []
        t = Terminal(dmc, write=out.append, timeout=1.0)
        t.download(["#A", 'MG "hi"', "EN"])
        t.feed("LS")
        assert out[-4:] == ["0 #A", '1 MG "hi"', "2 EN", "3 "]


# ---- DA: "DA*[0]; Deallocate all arrays", "DA Cars[0],Salesmen[0],Total" ---------------------
def test_da_takes_arrays_written_with_index_zero_as_its_examples_do() -> None:
    sim = SimController("DMC-4040")
    assert ask(sim, "DM Cars[40],Salesmen[50],pets[5];Total=70;x=1") == ":" * 3
    assert ask(sim, "DA Cars[0],Salesmen[0],Total") == ":"
    assert ask(sim, "LA;LV") == "pets[5]\r\n:x= 1.0000\r\n:"
    assert ask(sim, "DA *,*[0]") == ":"
    assert ask(sim, "LA;LV") == "::"


@pytest.mark.parametrize(("model", "longest"), [("DMC-4040", 72), ("DMC-1500", 31)])
def test_mg_text_longer_than_the_model_allows_is_refused_with_tc_52(
    model: str, longest: int
) -> None:
    # "MG text max 72 chars ..., 31 chars on DMC-1000/1500" (galil-protocol.md §1.1)
    sim = SimController(model)
    fits = "x" * longest
    assert sim.feed(f'MG "{fits}"\r'.encode()) == fits.encode() + b"\r\n:"
    assert sim.feed(f'MG "{fits}x"\r'.encode()) == b"?"
    assert sim.feed(b"TC\r") == b" 52\r\n:"


@pytest.mark.parametrize("line", ['MG "a?b"', 'MG "?"', 'MG 1,"why?"', 'MG "ok", "a?"{N}'])
def test_a_question_mark_in_an_mg_string_is_refused_with_tc_54(line: str) -> None:
    # TC 54 "Question mark part of string" (galil-protocol.md §1.2); the simulator printed it.
    sim = SimController("DMC-4040")
    assert sim.feed(f"{line}\r".encode()) == b"?"  # (nothing printed before the '?')
    assert sim.feed(b"TC 1\r") == b" 54 Question mark part of string\r\n:"
    assert sim.feed(b"MG {^63}\r") == b"?\r\n:"  # a '?' outside a string is a character


def test_a_program_line_with_a_question_mark_in_an_mg_string_stops_its_thread_with_tc_54() -> None:
    sim = SimController("DMC-4040")
    assert sim.feed(b'DL\r#A\rMG "one"\rMG "two?"\rMG "three"\rEN\r\\') == b"::"
    assert sim.feed(b"XQ #A\r") == b":one\r\n"  # (the '?' line prints nothing, the next never runs)
    assert sim.feed(b"MG _XQ0,_ED,_TC\r") == b"-1.0000 2.0000 54.0000\r\n:"


def test_xq_starts_a_thread_at_a_line_number() -> None:
    # "EPICS starts with XQ 0,0" (galil-wave2-facts.md, XQ)
    sim = SimController("DMC-4040")
    assert sim.feed(b'DL\r#A\rMG "one"\rMG "two"\rEN\r\\') == b"::"
    assert sim.feed(b"XQ 0,0\r") == b":one\r\ntwo\r\n"
    assert sim.feed(b"XQ 2,1\r") == b":two\r\n"
    assert sim.feed(b"XQ 4\r") == b"?"
    assert sim.feed(b"TC\r") == b" 11\r\n:"
