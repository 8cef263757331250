"""Raw MG lines whose output the reply framing cannot cut are refused unsent (decision 0090).

``{N}`` drops the CR LF (the ``:`` that ends the reply starts no line: the call timed out),
a line printed starting with ``:`` read as the reply's end (the link fell out of step), a
``?`` in a string read as a rejection; the link stays in step and the next command works.
"""

from __future__ import annotations

import pytest

import galil
from galil.protocol.commands import Command, Expect
from galil.testing import nothing_sent, simulated


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ('MG "hi"{N}', "CR LF"),
        ("MG {N} 5", "CR LF"),
        ('MG "a"{n};MG "b"', "CR LF"),
        ('MG "{N}"', "CR LF"),  # (a brace in a string may be read as a format)
        ('MG ":"', "starts with ':'"),
        ('MG "", ":x"', "starts with ':'"),
        ('MG ":";MG 5', "starts with ':'"),
        ('MG "?"', "TC 54"),
        ('MG "a?b"', "TC 54"),
        ("MG {^58}", "':'"),
        ("MG {^63}, 1", "'?'"),
        ('MG "a"{^13}{^10}":"', "CR"),
        ("MG {^200}", "bit 7"),
    ],
)
def test_an_mg_the_link_cannot_cut_is_refused_unsent_and_the_link_stays_in_step(
    line: str, why: str
) -> None:
    with simulated(timeout=0.5) as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=why):
            dmc.command(line, allow_compound=True)
        assert dmc.command("MG 42") == " 42.0000"


@pytest.mark.parametrize(
    ("line", "reply"),
    [
        ('MG "a:b"', "a:b"),
        ('MG "x", ":"', "x:"),
        ('MG "x", 1', "x 1.0000"),
        ('MG ""', ""),
        ("MG {^65}, 5", "A 5.0000"),
    ],
)
def test_an_mg_whose_output_the_link_can_cut_still_passes(line: str, reply: str) -> None:
    with simulated(timeout=0.5) as dmc:
        assert dmc.command(line) == reply


def test_a_variable_named_like_mg_is_no_mg() -> None:
    with simulated(timeout=0.5) as dmc:
        dmc.command("MGN=5")
        assert dmc.query_number("MG MGN") == 5.0


def test_a_prepared_mg_with_a_question_mark_in_a_string_is_refused_by_the_controller() -> None:
    # A Command built by hand is sent as it is; the controller refuses it with TC 54 "Question
    # mark part of string", and so does the simulator (it printed the text).
    with simulated() as dmc:
        with pytest.raises(galil.CommandError) as caught:
            dmc.send(Command('MG "a?b"', Expect.ANY))
        assert caught.value.code == 54
        assert dmc.command("MG 42") == " 42.0000"
