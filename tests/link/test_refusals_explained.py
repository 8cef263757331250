"""A refused command is explained: lower case gets a hint, upper case does not; a lower-case
name that can only be a variable is said to be missing, never upper-cased (variable names are
case sensitive, decision 0060: ``spd`` and ``SPD`` are two variables)."""

from __future__ import annotations

import pytest

import galil
from galil.testing import simulated


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        yield controller


@pytest.mark.parametrize(
    ("text", "suggestion"),
    [
        ("tp", "'TP'"),
        ("MG _tpa", "'MG _TPA'"),
        ('MG "keep", _tpa', "'MG \"keep\", _TPA'"),
        ("bg a", "'BG A'"),
        ("MG _tpa, Speed", "'MG _TPA, Speed'"),  # (the variable keeps its case)
        ("MG @abs[-2]", "'MG @ABS[-2]'"),
    ],
)
def test_a_lower_case_command_is_explained(
    dmc: galil.Controller, text: str, suggestion: str
) -> None:
    with pytest.raises(galil.CommandError) as info:
        dmc.command(text)
    assert info.value.code == 1
    assert f"upper case: did you mean {suggestion}?" in str(info.value)


def test_an_upper_case_refusal_gets_no_case_hint(dmc: galil.Controller) -> None:
    with pytest.raises(galil.CommandError) as info:
        dmc.command("XQ #NOSUCH")
    assert "upper case" not in str(info.value)


@pytest.mark.parametrize(
    ("text", "missing"),
    [
        ("MG speed", "no command, operand or variable 'speed'"),
        ("x=spd+1", "no command, operand or variable 'spd'"),
        ("MG Speed+nosuch", "one of 'Speed', 'nosuch' is no command, operand or variable"),
    ],
)
def test_a_lower_case_name_no_variable_has_is_said_missing_not_upper_cased(
    dmc: galil.Controller, text: str, missing: str
) -> None:
    dmc.variables["Speed"] = 5
    with pytest.raises(galil.CommandError) as info:
        dmc.command(text)
    message = str(info.value).splitlines()[0]
    assert "upper case" not in message
    assert f"{missing} on the controller" in message
    assert "case sensitive" in message
    assert dmc.command("MG Speed") == " 5.0000"


def test_one_missing_name_among_operands_is_the_one_named(dmc: galil.Controller) -> None:
    with pytest.raises(galil.CommandError) as info:
        dmc.query_operands(["_TPA"] * 3 + ["nosuch"] + ["_TPB"] * 3)
    message = str(info.value).splitlines()[0]
    assert "upper case" not in message
    assert "variable 'nosuch' on the controller" in message
    assert "NOSUCH" not in message


@pytest.mark.parametrize(
    ("line", "refused", "code", "earlier"),
    [
        ("PRA=1000;BGA", "BGA", 21, "'PRA=1000'"),
        ("MG 1;BGA;MG 2;XYZ;MG 3", "XYZ", 1, "'BGA'"),
    ],
)
def test_a_line_with_two_refused_parts_gives_the_code_to_the_last_which_tc1_explains(
    dmc: galil.Controller, line: str, refused: str, code: int, earlier: str
) -> None:
    # The controller keeps only its last error's code. Before, the first refused part was
    # blamed for it ('PRA=1000' "Begin not valid while running", 'BGA' "Unrecognized").
    dmc.A.jog(5000)
    with pytest.raises(galil.CommandError) as info:
        dmc.command(line, allow_compound=True)
    assert (info.value.command, info.value.code) == (refused, code)
    assert f"also refused: {earlier}, why not known" in str(info.value)
    dmc.stop()
