"""``TP`` with a format of its own (``TP {F2.2}``), as the manuals print it, on ``sim://``.

"Local format: ``TP {F2.2}`` -> ``-05.00, 05.00, 00.00, 07.00``; ``TP {$4.2}`` -> hex"
(galil-protocol.md section 1.4: DMC-2x00 user manual p.166-167, DMC-1700 p.172).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import galil
from galil.errors import CommandError
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        controller.command("MO")
        controller.command("DP -5,5,0,7")
        yield controller


def test_tp_in_a_format_of_its_own_prints_as_the_manual_shows(dmc: galil.Controller) -> None:
    assert dmc.command("TP {F2.2}") == "-05.00, 05.00, 00.00, 07.00"
    assert dmc.command("TP AB{Z4.1}") == "-5.0, 5.0"
    assert dmc.command("TPD {$4.2}").strip() == "$0007.00"
    assert dmc.command("TP").split(",")[0].strip() == "-5"  # PF again: the format was local


def test_a_format_that_is_not_one_is_refused_with_tc_53(dmc: galil.Controller) -> None:
    for text in ("TP {Q2}", "TPA {F2.2}{F1.1}"):
        with pytest.raises(CommandError) as info:
            dmc.command(text)
        assert info.value.code == 53
