"""The simulator's arithmetic is the controller's 32.16 fixed point, not Python's floats.

Every number in an expression is held at the nearest 1/65536 and every result is one too
(galil-protocol.md section 1.4), so a program's ``IF`` on fractions branches as on a
controller. The manuals' own examples: the DMC-40x0 user manual (p.142, "Mathematical
Operation Precision and Range") and Galil's Application Note 3311a.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from program_helpers import run_program

import galil
from galil.errors import CommandError
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        yield controller


def test_the_manuals_examples_give_the_manuals_results(dmc: galil.Controller) -> None:
    # 1.4 is held as 91750/65536: "var= 1.4*80000 ... MG var ... 111999.5117" (40x0 p.142).
    dmc.command("var=1.4*80000")
    assert dmc.command("MG var").strip() == "111999.5117"
    # .001 is held as 66/65536 (AN3311a examples 1 and 2).
    assert dmc.command("MG .001*819200").strip() == "825.0000"
    assert dmc.command("MG (286*.001*6350)-25250").strip() == "-23421.0419"
    dmc.command("x=((286*635)-2525000)/100")
    assert dmc.command("MG x").strip() == "-23433.9000"


def test_sums_of_fractions_compare_as_the_controller_holds_them(dmc: galil.Controller) -> None:
    # 0.1 + 0.2 is 6554 + 13107 = 19661 sixty-five-thousandths: exactly 0.3's 19661 (a float
    # sum is 0.30000000000000004, not 0.3). 0.1*3 is 19662: not 0.3, nor 0.1+0.2.
    assert dmc.query_numbers("MG 0.1+0.2=0.3, (0.1*3)=0.3, (0.1*3)=(0.1+0.1+0.1)") == [1, 0, 1]
    dmc.command("a=0.1")
    dmc.command("b=a+0.2")
    assert dmc.query_number("MG b=0.3") == 1
    assert dmc.query_number("MG (b-0.3)*65536") == 0
    assert dmc.query_number("MG ((0.1*3)-0.3)*65536") == 1


def test_an_if_on_fractions_takes_the_controllers_branch(dmc: galil.Controller) -> None:
    program = """#M
a=0.1
b=0.2
IF ((a+b)=0.3)
 MG "equal"
ELSE
 MG "differ",((a+b)-0.3)*65536
ENDIF
t=0
#L
t=t+0.1
JP #L,t<1
MG "ten tenths",(t-1)*65536
EN
"""
    # 6554 + 13107 is 0.3's 19661 (in floats 0.1 + 0.2 is not 0.3); ten times 6554/65536 is
    # 65540/65536, four steps past 1.
    assert run_program(dmc, program) == ["equal", "ten tenths 4.0000"]


def test_products_and_quotients_round_to_the_nearest_step_and_overflow_is_refused(
    dmc: galil.Controller,
) -> None:
    dmc.command("q=1/3")
    dmc.command("h=0.5/65536")  # half a step: rounds away from zero [U] to one step
    assert dmc.query_numbers("MG q*196608, h*65536, -h*65536, 7/-2") == [65535, 1, -1, -3.5]
    with pytest.raises(CommandError) as info:
        dmc.command("MG 65536*32768")
    assert info.value.code == 6
    assert dmc.command("MG 65536*32767").strip() == "2147418112.0000"
