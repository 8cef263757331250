"""A refused command is explained: lower case gets a hint, upper case does not."""

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
    [("tp", "'TP'"), ("MG _tpa", "'MG _TPA'"), ('MG "keep", _tpa', "'MG \"keep\", _TPA'")],
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
