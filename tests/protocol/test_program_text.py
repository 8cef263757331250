"""Program text before a download: lines, comments, packing, and every rule of the model."""

from __future__ import annotations

import dataclasses
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from galil.errors import InvalidArgument
from galil.models import get_model
from galil.protocol.programs import (
    ProgramLine,
    check_program,
    labels_of,
    pack_lines,
    program_lines,
)

MODEL = get_model("DMC-4040")


def texts(lines: list[ProgramLine]) -> list[str]:
    return [p.text for p in lines]


def test_lines_lose_their_blanks_and_the_text_its_blank_ends() -> None:
    lines = program_lines("\n\n  #A\n   PR 1000  \nBG A\n\n")
    assert texts(lines) == ["#A", "PR 1000", "BG A"]
    assert [p.source for p in lines] == [3, 4, 5]  # lines of the text as given


def test_comments_are_stripped_outside_strings_only() -> None:
    text = """#A
' a whole comment line
REM another one
PR 1000;' after a command
MG "it's here";BG A;' trailing
MG "a;b"
#B ' after a label
"""
    lines = program_lines(text, strip_comments=True)
    assert texts(lines) == ["#A", "PR 1000", 'MG "it\'s here";BG A', 'MG "a;b"', "#B"]
    assert [p.source for p in lines] == [1, 4, 5, 6, 7]


def test_packing_joins_lines_but_starts_each_label_on_a_line_of_its_own() -> None:
    lines = program_lines("#A\nPR 10\nBG A\nAM A\n#B\nMG 1\nEN", pack=80)
    assert texts(lines) == ["#A;PR 10;BG A;AM A", "#B;MG 1;EN"]


def test_packing_never_appends_to_a_comment() -> None:
    lines = program_lines("#A\n' note\nPR 10\nBG A", pack=80)
    assert texts(lines) == ["#A;' note", "PR 10;BG A"]


commands = st.text(alphabet="ABCDEFGHPRSTZ0123456789 =_", min_size=1, max_size=30).map(str.strip)
program = st.lists(
    st.one_of(commands.filter(bool), st.sampled_from(["#A", "#LOOP", "#B2"])),
    min_size=1,
    max_size=60,
)


@given(program, st.integers(min_value=10, max_value=120))
def test_packing_keeps_every_command_in_order_within_the_limit(
    lines: list[str], limit: int
) -> None:
    given_lines = [ProgramLine(t, i) for i, t in enumerate(lines, 1)]
    packed = pack_lines(given_lines, limit)
    assert [c for p in packed for c in p.text.split(";")] == lines
    for p in packed:
        assert len(p.text) <= limit or ";" not in p.text  # only a single long line stays long
        assert ";#" not in p.text  # a label always begins its line
    assert labels_of(texts(packed)) == labels_of(lines)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("#A\n\nEN", "program line 2 is empty"),
        ("#A\nMG \\\nEN", "backslash"),
        ('#A\nMG "tab\there"', "not printable"),
        ('#A\nMG "é"', "not printable"),
        ("#A\n" + "x=1;" * 20 + "EN", "takes 80"),
        ('#A\nMG "open', "not closed"),
        ("#A\nEN\n#A\nEN", "label #A is already on line 1"),
        ("#TOOLONGLABEL\nEN", "allows 7"),
        ("#1A\nEN", "a letter"),
        ("#A_B\nEN", "a letter"),
        ("#A:\nEN", "must end"),
        ("", "empty"),
    ],
)
def test_each_rule_is_refused_naming_the_line(text: str, words: str) -> None:
    with pytest.raises(InvalidArgument, match=words):
        check_program(program_lines(text), MODEL)


def test_a_quote_inside_a_comment_is_not_an_open_string() -> None:
    check_program(program_lines("#A\nEN;' say \"hi"), MODEL)


def test_the_model_bounds_lines_and_labels_and_what_the_library_takes() -> None:
    small = dataclasses.replace(MODEL, program_lines=5, labels=2)
    check_program(program_lines("#A\n#B\nEN\nEN\nEN"), small)
    with pytest.raises(InvalidArgument, match="holds 5"):
        check_program(program_lines("#A\nEN\nEN\nEN\nEN\nEN"), small)
    with pytest.raises(InvalidArgument, match=r"holds 5 \(3 are the library's"):
        check_program(program_lines("#A\nEN\nEN"), small, reserve=3)
    with pytest.raises(InvalidArgument, match="3 labels"):
        check_program(program_lines("#A\n#B\n#C"), small)


def test_a_forty_character_controller_takes_forty_character_lines() -> None:
    narrow = dataclasses.replace(MODEL, line_length=40)
    with pytest.raises(InvalidArgument, match="41 characters"):
        check_program(program_lines("#A\n" + "x" * 41), narrow)
    assert all(len(p.text) <= 40 for p in program_lines("#A\n" + "x=1\n" * 30, pack=40))


def test_not_a_program_is_refused() -> None:
    with pytest.raises(InvalidArgument):
        program_lines(42)  # type: ignore[arg-type]


def test_rem_lines_are_never_downloaded_and_the_others_keep_their_source_lines() -> None:
    # "REM is NOT a controller command": Galil's PC software strips REM lines (DMC-4103).
    lines = program_lines("#A\nREM a remark\nPR 1000\n  REM\n' a comment\nEN")
    assert texts(lines) == ["#A", "PR 1000", "' a comment", "EN"]
    assert [p.source for p in lines] == [1, 3, 5, 6]


def test_a_word_beginning_with_rem_is_code_not_a_remark() -> None:
    lines = program_lines("#A\nREMAIN=5\nPR REMAIN;' the rest\nEN", strip_comments=True)
    assert texts(lines) == ["#A", "REMAIN=5", "PR REMAIN", "EN"]
    check_program(lines, MODEL)


@pytest.mark.parametrize("line", ["PR 1000;REM the rest", "#B REM after a label"])
def test_rem_after_a_command_or_a_label_is_refused_unless_comments_are_stripped(
    line: str,
) -> None:
    with pytest.raises(InvalidArgument, match="line 2: REM after a label or a command"):
        check_program(program_lines(f"#A\n{line}\nEN"), MODEL)
    check_program(program_lines(f"#A\n{line}\nEN", strip_comments=True), MODEL)


@pytest.mark.parametrize(
    ("text", "api", "terminal"),
    [
        ("", "or pass strip_comments=True)", "(write ' for a blank comment line)"),
        ("MG " + "1+" * 60 + "1", "pass pack=False and split it", "split it at a ';'"),
        ("PR 1;REM go", "or pass strip_comments=True", "or drop the comment"),
    ],
)
def test_a_refused_line_advises_a_keyword_in_python_and_an_edit_at_the_terminal(
    text: str, api: str, terminal: str
) -> None:
    lines = [ProgramLine("#A", 1), ProgramLine(text, 2), ProgramLine("EN", 3)]
    with pytest.raises(InvalidArgument, match=re.escape(api)):
        check_program(lines, MODEL)
    with pytest.raises(InvalidArgument) as info:
        check_program(lines, MODEL, at_terminal=True)
    assert terminal in str(info.value)
    assert "strip_comments" not in str(info.value)
    assert "pack=" not in str(info.value)
