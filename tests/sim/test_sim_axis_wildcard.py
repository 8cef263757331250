"""``*`` as every axis in ``XX*=n`` / ``XX*=?`` (decision 0048), for the commands whose entry
in the DMC-4103 command reference shows it: KD and KI ("m=* will set the KD value for all
axes/channels"), KP (``KP*= 0``), LD (``LD*= ?``), OE (``OE*= 1``, AB's example) and JG
(``JG*=1000``, OE's example)."""

from __future__ import annotations

import pytest

from galil.link import parse_numbers_reply
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController


def ask(sim: SimController, line: str) -> bytes:
    return sim.feed(line.encode() + b"\r")


def values(sim: SimController, line: str) -> list[float]:
    return parse_numbers_reply(ask(sim, line).decode().split("\r\n")[0].lstrip(":"))


def test_ld_star_query_answers_every_axis_as_the_reference_example() -> None:
    sim = SimController("DMC-4040", ManualClock())
    assert ask(sim, "LD 3,1,2;LDC= 3") == b"::"
    assert ask(sim, "LD*= ?") == b" 3, 1, 3, 0\r\n:"


@pytest.mark.parametrize(
    ("command", "value"), [("KP", 0), ("KI", 2), ("KD", 12), ("OE", 1), ("JG", 1000)]
)
def test_star_sets_every_axis_of_the_model(command: str, value: int) -> None:
    sim = SimController("DMC-4080", ManualClock())
    assert ask(sim, f"{command}*={value}") == b":"
    assert values(sim, f"{command}*=?") == [value] * 8
    assert values(sim, f"{command} ?,?,?,?,?,?,?,?") == [value] * 8


def test_star_out_of_range_changes_no_axis() -> None:
    sim = SimController("DMC-4040", ManualClock())
    assert ask(sim, "KP*=2000") == b"?"
    assert values(sim, "TC") == [6]
    assert values(sim, "KP*=?") == [6] * 4


@pytest.mark.parametrize("line", ["PR*=5", "SP*=5", "CE*=1"])
def test_star_is_no_axis_for_a_command_whose_entry_does_not_show_it(line: str) -> None:
    sim = SimController("DMC-4040", ManualClock())
    assert ask(sim, line) == b"?"
    assert values(sim, "TC") == [4]
