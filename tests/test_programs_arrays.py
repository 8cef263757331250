"""``controller.programs``, ``arrays`` and ``variables`` on the in-process simulator."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

import galil
from galil.protocol import commands as cmds
from galil.routines import MARKER
from galil.testing import nothing_sent, simulated, transcript

SQUARES = """
#SQUARES
i=0
#LOOP
sq[i]=i*i
i=i+1
JP #LOOP,i<10
EN
"""


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        yield controller


def test_a_program_fills_an_array_and_its_thread_finishes(dmc: galil.Controller) -> None:
    dmc.arrays.define("sq", 10)
    assert dmc.programs.download(SQUARES).sent
    dmc.programs.run("#SQUARES", thread=1)
    assert 1 in dmc.programs.threads
    dmc.programs.wait(1)
    assert dmc.programs.threads == {}
    assert dmc.arrays.upload("sq").tolist() == [i * i for i in range(10)]
    assert dmc.variables["i"] == 10


def test_the_same_program_again_sends_nothing_but_the_upload(dmc: galil.Controller) -> None:
    dmc.programs.download(SQUARES)
    assert dmc.programs.upload() == SQUARES.strip()
    with transcript(dmc) as sent:
        result = dmc.programs.download("  " + SQUARES.replace("\n", "  \n"))  # blanks differ
    assert not result.sent
    assert sent.lines == ["UL"]


def test_a_file_is_read_and_comments_stripped_and_lines_packed(
    dmc: galil.Controller, tmp_path: Path
) -> None:
    path = tmp_path / "move.dmc"
    path.write_text("#M ' a move\n' set up\nPR 1000\nBG A\nAM A\nEN\n", encoding="ascii")
    result = dmc.programs.download(path, strip_comments=True, pack=True)
    assert result.lines == 1
    assert dmc.programs.upload() == "#M;PR 1000;BG A;AM A;EN"
    assert not dmc.programs.download(str(path), strip_comments=True, pack=True).sent


def test_a_mistyped_file_name_is_refused_and_one_line_programs_are_still_text(
    dmc: galil.Controller, tmp_path: Path
) -> None:
    dmc.programs.download("#MAIN\nEN")
    typo = str(tmp_path / "mian.dmc")
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="no such file") as e:
        dmc.programs.download(typo)
    assert typo in str(e.value)
    assert dmc.programs.upload() == "#MAIN\nEN"
    for text in ["#A;MG 10/2;EN", "MG 1.5", "x=a/b", "#A;EN", "MG 10/2\n"]:
        assert dmc.programs.download(text).sent  # one-line programs: still program text
        assert dmc.programs.upload() == text.strip()


@pytest.mark.parametrize(
    ("call", "words"),
    [
        (lambda d: d.programs.download("#A\n\nEN"), "line 2 is empty"),
        (lambda d: d.programs.download("#A\nMG \\\nEN"), "backslash"),
        (lambda d: d.programs.download("#A\n" + "x=1;" * 25), "takes 80"),
        (lambda d: d.programs.download("#A\nEN\n#A"), "already on line 1"),
        (lambda d: d.programs.download("#LONGLABEL\nEN"), "allows 7"),
        (lambda d: d.programs.download('#A\nMG "x'), "not closed"),
        (lambda d: d.programs.download("#A\n" + "EN\n" * 2000), "holds 2000"),
        (lambda d: d.programs.download(f"#A\n{MARKER}\nEN"), "marks the library"),
        (lambda d: d.programs.download("#A\nJS #GINLOOP\nEN\n#GINLOOP\nEN"), "GINLOOP"),
        (lambda d: d.programs.download("/tmp/no/such/prog.dmc"), "no such file"),
        (lambda d: d.programs.download("programs\\main.txt"), "no such file"),
        (lambda d: d.programs.download("square.dmc"), "no such file"),
        (lambda d: d.programs.run("#A", thread=8), "threads 0..7"),
        (lambda d: d.programs.run("A", thread=0), "label"),
        (lambda d: d.programs.halt(-1), "threads 0..7"),
        (lambda d: d.arrays.define("CD0", 10), "clashes with the command CD"),
        (lambda d: d.arrays.define("2ab", 10), "array name"),
        (lambda d: d.arrays.define("toolongname", 10), "array name"),
        (lambda d: d.arrays.define("a", 0), "size"),
        (lambda d: d.arrays.define("a", 24_001), "size"),
        (lambda d: d.arrays.define("a", 2.5), "whole number"),
        (lambda d: d.arrays.download("a b", [1]), "array name"),
        (lambda d: d.arrays.download("a", [np.nan]), "NaN"),
        (lambda d: d.arrays.download("a", []), "non-empty"),
        (lambda d: d.arrays.download("a", [[1, 2]]), "1-D"),
        (lambda d: d.arrays.download("a", [3e9]), "32-bit"),
        (lambda d: d.arrays.upload("SPA"), "clashes"),
        (lambda d: d.arrays.delete("x y"), "array name"),
        (lambda d: d.variables.write("TIME", 1), "variable name"),
        (lambda d: d.variables.write("x", float("inf")), "NaN or infinity"),
        (lambda d: d.variables.read("1x"), "variable name"),
    ],
)
def test_every_bad_program_name_or_size_is_refused_before_a_byte(
    dmc: galil.Controller, call: object, words: str
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=words):
        call(dmc)  # type: ignore[operator]


def test_values_that_do_not_fit_are_refused_after_one_query(dmc: galil.Controller) -> None:
    dmc.arrays.define("a", 3)
    with (
        nothing_sent(dmc, allow_queries=True) as sent,
        pytest.raises(galil.InvalidArgument, match="do not fit"),
    ):
        dmc.arrays.download("a", [1, 2, 3], first=1)
    assert sent.lines == ["LA"]
    with pytest.raises(galil.InvalidArgument, match="no array 'b'"):
        dmc.arrays.download("b", [1])


@pytest.mark.parametrize(("first", "last"), [(0, 10), (0, 5), (4, 5), (5, None), (7, 9)])
def test_an_upload_outside_the_array_is_refused_after_the_size_query(
    dmc: galil.Controller, first: int, last: int | None
) -> None:
    dmc.arrays.define("a", 5)
    dmc.arrays.download("a", [1, 2, 3, 4, 5])
    with (
        transcript(dmc) as sent,
        pytest.raises(galil.InvalidArgument, match=r"outside a\[\] of 5 \(indices 0\.\.4\)"),
    ):
        dmc.arrays.upload("a", first, last)
    assert sent.lines == ["LA"]  # the size, and nothing else
    assert dmc.query_number("MG _TC") == 0  # the controller refused nothing
    assert dmc.arrays.upload("a", 3, 4).tolist() == [4, 5]
    assert dmc.arrays.upload("a", 4).tolist() == [5]


def test_an_upload_of_an_array_that_is_not_there_is_refused(dmc: galil.Controller) -> None:
    with pytest.raises(galil.InvalidArgument, match="no array 'b'"):
        dmc.arrays.upload("b", 0, 1)
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="last index"):
        dmc.arrays.upload("b", 3, 1)  # a range that is no range: refused before the size query


def test_array_indices_may_be_numpy_integers(dmc: galil.Controller) -> None:
    dmc.arrays.define("a", np.int64(5))
    dmc.arrays.download("a", [7, 8], first=np.int64(1))
    assert dmc.arrays.upload("a", np.int64(0), np.int32(2)).tolist() == [0, 7, 8]
    assert dmc.arrays.upload("a", np.uint8(2)).tolist() == [8, 0, 0]


def test_threads_periods_and_exponents_may_be_numpy_integers(dmc: galil.Controller) -> None:
    """Wherever a count, a thread, a record period or a DT exponent is taken, a numpy integer
    (what indexing an array hands back) is that integer, as array sizes are; a numpy bool
    and a whole float are refused as a bool and a float are."""
    dmc.programs.download("#A\nWT 10\nEN\n")
    dmc.programs.run("#A", thread=np.int64(1))
    dmc.programs.wait(thread=np.int32(1))
    assert isinstance(
        dmc.contour("A", np.linspace(0, 100, 20), dt=np.int64(3)), galil.ContourResult
    )
    with dmc.records(np.int64(8)) as stream:
        assert stream.get(timeout=1.0) is not None
    capture = dmc.capture(["_RPA"], every=np.int64(4), count=np.int64(10))
    assert len(capture.wait()["_RPA"]) == 10
    for bad in (1.0, np.bool_(True), np.float64(1)):
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.programs.run("#A", thread=bad)  # type: ignore[arg-type]
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.records(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("where", "bad"),
    [("first", True), ("first", np.True_), ("first", 1.0), ("last", 2.0)],
)
def test_an_array_index_that_is_no_whole_number_is_refused_naming_it(
    dmc: galil.Controller, where: str, bad: object
) -> None:
    dmc.arrays.define("a", 5)
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=f"^{where} must be"):
        dmc.arrays.upload("a", **{"first": 0, "last": 3, where: bad})  # type: ignore[arg-type]
    if where == "first":
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=r"^first must be"):
            dmc.arrays.download("a", [1.0], first=bad)  # type: ignore[arg-type]


def test_arrays_and_variables_round_trip(dmc: galil.Controller) -> None:
    dmc.arrays.define("speeds", 4)
    dmc.arrays.download("speeds", [1000, 2000.5, -4000, 0.0001])
    got = dmc.arrays.upload("speeds")
    assert got.dtype == np.float64
    assert got.tolist() == [1000, 2000.5, -4000, 0.0001]
    assert dmc.arrays.upload("speeds", 1, 2).tolist() == [2000.5, -4000]
    assert dmc.arrays.list() == {"speeds": 4}
    assert "speeds" in dmc.arrays
    with pytest.raises(galil.CommandError) as info:
        dmc.arrays.define("speeds", 8)  # exists
    assert info.value.code == 4
    dmc.arrays.define("speeds", 8, replace=True)
    assert dmc.arrays.upload("speeds").tolist() == [0] * 8
    dmc.arrays.delete("speeds")
    assert dmc.arrays.list() == {}
    dmc.variables["gain"] = 2.5
    dmc.variables.write("shift", -3)
    assert dmc.variables["gain"] == 2.5
    assert dmc.variables.list() == {"gain": 2.5, "shift": -3.0}
    assert sorted(dmc.variables) == ["gain", "shift"]
    assert "gain" in dmc.variables
    assert len(dmc.variables) == 2


def test_reading_a_missing_variable_says_it_is_missing_not_that_case_is_wrong(
    dmc: galil.Controller,
) -> None:
    # A variable's name is the user's own, lower case included: the link's hint that
    # commands are upper case ("did you mean 'MG NOTHERE'?") would send them the wrong way.
    with pytest.raises(galil.CommandError) as info:
        dmc.variables["nothere"]
    assert info.value.code == 1
    message = info.value.args[0]
    assert message.startswith("there is no variable 'nothere' on the controller"), message
    assert "variables.write('nothere', value)" in message
    assert "upper case" not in message
    with pytest.raises(galil.CommandError) as raw:  # nor for a raw command (decision 0060)
        dmc.command("MG nothere")
    assert "upper case" not in str(raw.value)
    assert "variable 'nothere' on the controller" in str(raw.value)


def test_a_users_running_program_is_never_replaced(dmc: galil.Controller) -> None:
    dmc.programs.download("#W\nWT 10000\nEN")
    dmc.programs.run("#W")
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(galil.InvalidArgument, match=r"runs on thread\(s\) \[0\]"),
    ):
        dmc.programs.download("#B\nEN")
    with pytest.raises(galil.InvalidArgument, match="runs a program already"):
        dmc.programs.run("#W", thread=0)
    dmc.programs.halt()
    assert dmc.programs.threads == {}
    assert dmc.programs.download("#B\nEN").sent


def test_the_watchdog_keeps_running_and_the_download_says_it_was_restarted(
    dmc: galil.Controller, caplog: pytest.LogCaptureFixture
) -> None:
    dog = dmc.watchdog(1.0)
    thread = next(iter(dmc.routines.threads))
    dmc.programs.download("#A\nMG 1\nEN")
    with caplog.at_level(logging.WARNING, logger="galil.programs"):
        result = dmc.programs.download("#B\nMG 2\nEN")
    assert result.restarted == (thread,)
    assert "halted for the program download and started again" in caplog.text
    assert thread in dmc.routines.running()
    assert dmc.programs.upload() == "#B\nMG 2\nEN"
    program = dmc.routines.upload()
    assert program[:3] == ["#B", "MG 2", "EN"]
    assert program[3] == MARKER
    # The library's thread is the library's: the user's halt leaves it, run() refuses it.
    dmc.programs.halt()
    assert thread in dmc.routines.running()
    with pytest.raises(galil.InvalidArgument, match="library"):
        dmc.programs.run("#B", thread=thread)
    with pytest.raises(galil.InvalidArgument, match="library"):
        dmc.programs.halt(thread)
    with pytest.raises(galil.InvalidArgument, match="label"):
        dmc.programs.download("#GWDOG\nEN")
    dog.stop()


def test_a_program_with_rem_lines_runs_to_its_end(dmc: galil.Controller) -> None:
    # The controller has no REM command (a thread reaching one stops: TC 3); the library
    # drops REM lines before the download, as Galil's software does.
    result = dmc.programs.download("#R\nREM set n\nn=1\nREM and again\nn=n+1\nEN")
    assert result.lines == 4
    dmc.programs.run("#R", thread=1)
    dmc.programs.wait(1)
    assert dmc.variables["n"] == 2
    assert dmc.programs.upload() == "#R\nn=1\nn=n+1\nEN"


def test_burn_reads_the_threads_once_and_sends_bp(dmc: galil.Controller) -> None:
    # (BP is refused while a thread runs, TC 17: the library's own are halted for it,
    # a program of the user's is refused unsent; decision 0087)
    with transcript(dmc) as sent:
        dmc.programs.burn()
    assert sent.lines == ["MG " + ",".join(f"_XQ{t}" for t in range(8)), "BP"]


def test_waiting_for_a_thread_times_out_in_controller_time(dmc: galil.Controller) -> None:
    dmc.programs.download("#W\nWT 5000\nEN")
    dmc.programs.run("#W", thread=2)
    with pytest.raises(galil.GalilTimeoutError, match="thread 2 still runs"):
        dmc.programs.wait(2, timeout=0.5)
    dmc.programs.wait(2, timeout=6)


@pytest.mark.parametrize("bad", [None, -1, float("nan"), float("inf"), True, "1"])
def test_waiting_for_a_thread_refuses_a_bad_timeout_before_asking(
    dmc: galil.Controller, bad: object
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="timeout"):
        dmc.programs.wait(0, timeout=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("model", "limit"),
    [("DMC-1500", 31), ("DMC-4040", 72)],
    # DMC-1500: a compound line, its label, a text with a ';', a format; DMC-4040: the text
    # alone (with more, the line would be over 80 characters).
)
def test_a_program_whose_mg_text_is_longer_than_the_model_prints_is_refused_naming_the_line(
    model: str, limit: int
) -> None:
    longest, over = "m" * limit, "o" * (limit + 1)
    third = f'#B;MG "a;b", x;MG{{N}} "{over}"' if limit < 40 else f'MG "{over}"'
    with simulated(model) as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="line 3: MG text"):
            dmc.programs.download(f'#A\nMG "a;b", x\n{third}\nEN')
        # The longest text, and a longer one in a comment, are no refusal.
        assert dmc.programs.download(f'#A\nMG "{longest}"\n\' MG "{over}"\nEN').sent


def test_a_program_with_a_question_mark_in_an_mg_string_is_refused_naming_the_line() -> None:
    # TC 54 "Question mark part of string": the line could never run (it was downloaded).
    with simulated("DMC-4040") as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="line 2: MG text"):
            dmc.programs.download('#A\nMG "ready?", x\nEN')
        # {^63} prints one; a '?' in a comment, or outside MG, is no refusal.
        assert dmc.programs.download('#A\nMG "ready", {^63}\n\' MG "why?"\nEN').sent
        dmc.programs.run("#A")
        dmc.programs.wait(1)
        assert dmc.messages.get(timeout=1) == "ready?"


@pytest.mark.parametrize("size", [10.0, np.float64(4), True, np.bool_(True), "4"])
def test_an_array_size_that_is_not_an_integer_is_refused_even_a_whole_float(
    dmc: galil.Controller, size: object
) -> None:
    with (
        nothing_sent(dmc),
        pytest.raises(galil.InvalidArgument, match=r"DM a\[\] size must be an int"),
    ):
        dmc.arrays.define("a", size)  # type: ignore[arg-type]
    assert "a" not in dmc.arrays.list()


def test_an_array_size_in_a_numpy_integer_defines_the_array(dmc: galil.Controller) -> None:
    dmc.arrays.define("a", np.int64(4))
    dmc.arrays.define("b", np.uint8(2))
    assert dmc.arrays.list() == {"a": 4, "b": 2}


@pytest.mark.parametrize(
    "build",
    [
        lambda: cmds.dm("a", 10.0),
        lambda: cmds.xq("#A", 1.0),
        lambda: cmds.hx(True),
        lambda: cmds.qu("a", 1.0),
        lambda: cmds.qu("a", 0, 2.0),
        lambda: cmds.qd("a", [1.0], 1.0),
        lambda: cmds.rc(2, 10.0),
    ],
)
def test_the_command_builders_refuse_a_float_where_they_take_a_count(build: object) -> None:
    with pytest.raises(galil.InvalidArgument, match="must be an int"):
        build()  # type: ignore[operator]
