"""The interpreter: expressions left to right, variables, operands and the caller's handle."""

from __future__ import annotations

import logging
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.machine import Room
from galil.sim.parse import Refused, evaluate, next_command, split_program_line
from galil.sim.registry import handler
from galil.sim.rooms import rooms_with


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(-1000, 1000), min_size=1, max_size=6), st.sampled_from("+-*"))
def test_expressions_run_left_to_right(values: list[int], op: str) -> None:
    text = op.join(f"({v})" for v in values)
    expected = float(values[0])
    overflow = False
    for v in values[1:]:
        expected = {"+": expected + v, "-": expected - v, "*": expected * v}[op]
        overflow = overflow or not -(2**31) <= expected < 2**31
    if overflow:  # every step is a 32.16 number: a step out of range is TC 6
        with pytest.raises(Refused) as e:
            evaluate(text, lambda name: 0.0)
        assert e.value.code == 6
    else:
        assert evaluate(text, lambda name: 0.0) == expected


def test_expression_errors() -> None:
    with pytest.raises(Refused) as e:
        evaluate("(1+2", lambda n: 0.0)
    assert e.value.code == 59
    assert evaluate("@ABS[-3]+$10", lambda n: 0.0) == 19
    assert evaluate("1+2*3", lambda n: 0.0) == 9


def test_a_variable_name_is_as_long_as_the_model_allows() -> None:
    sim = SimController("DMC-4040", ManualClock())
    longest = "v" * sim.spec.variable_length
    assert sim.feed(f"{longest}=2;MG {longest}\r".encode()) == b": 2.0000\r\n:"
    assert sim.feed(f"{longest}x=2\r".encode()) == b"?"


def test_an_assignment_to_a_command_name_with_axes_is_the_command() -> None:
    sim = SimController("DMC-4040", ManualClock())
    assert sim.feed(b"PRB=500;PR ?,?;MG _PRB\r") == b": 0, 500\r\n: 500.0000\r\n:"
    assert sim.feed(b"PRQ=7;MG PRQ\r") == b": 7.0000\r\n:"  # not an axis: a variable
    assert sim.feed(b"CD 0=2\r") == b"?"  # CD's '=' is its own (no contour mode: TC 8)
    assert sim.feed(b"TC\r") == b" 8\r\n:"


def test_wh_names_the_asking_handle() -> None:
    sim = SimController("DMC-4040", ManualClock())
    handle = sim.open_port("host")
    assert sim.feed(b"WH;MG _WH\r") == b"RS232\r\n:-1.0000\r\n:"
    assert sim.feed(b"WH;MG _WH\r", port=handle) == b"IHA\r\n: 0.0000\r\n:"


def test_ih_closes_a_handle_by_letter_by_itself_and_by_kind() -> None:
    sim = SimController("DMC-4040", ManualClock())
    tcp = sim.open_port("TCP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 5000")  # A
    udp1 = sim.open_port("UDP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 5001")  # B
    udp2 = sim.open_port("UDP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 5002")  # C
    other = sim.open_port("TCP PORT 23 TO IP ADDRESS 127,0,0,1 PORT 5003")  # D
    assert sim.feed(b"IHB=>-1\r", port=tcp) == b":"
    assert not sim.has_port(udp1)
    assert sim.feed(b"IHT=>-1\r", port=tcp) == b":"  # every other UDP handle
    assert not sim.has_port(udp2)
    assert sim.has_port(other)
    assert sim.feed(b"IHT=>-2\r", port=tcp) == b":"  # every other TCP handle
    assert (sim.has_port(tcp), sim.has_port(other)) == (True, False)
    assert sim.feed(b"IHS=>-1\r", port=tcp) == b":"  # its own
    assert not sim.has_port(tcp)
    assert sim.describe_handles().count("AVAILABLE") == 8
    for bad in (b"IHB=>-1", b"IHS=>-1", b"IHA=1,2,3,4<23>1", b"IHZ=>-1", b"IH"):
        assert sim.feed(bad + b"\r") == b"?"  # not open; not a handle; opening not simulated


@settings(max_examples=200, deadline=None)
@given(
    name=st.from_regex(r"_?[A-Za-z][A-Za-z0-9_]{0,8}", fullmatch=True),
    left=st.sampled_from(["", " ", "  ", "\t"]),
    right=st.sampled_from(["", " ", "\t "]),
    value=st.one_of(st.floats(-1e9, 1e9), st.just(math.inf)),
)
def test_a_name_alone_evaluates_as_its_tokens_do(
    name: str, left: str, right: str, value: float
) -> None:
    def lookup(n: str) -> float:
        if n.startswith("_Q"):
            raise Refused(1, f"unknown operand {n}")
        return value

    def outcome(text: str) -> object:
        try:
            return evaluate(text, lookup)
        except Refused as exc:
            return ("refused", exc.code)

    # In parentheses the same name goes through the tokenizer and the parser.
    assert outcome(f"{left}{name}{right}") == outcome(f"({left}{name}{right})")


def _next_command_by_characters(buffer: str) -> tuple[str, int] | None:
    """The rule, one character at a time: a CR ends a command, a ';' outside quotes too."""
    quoted = False
    for i, ch in enumerate(buffer):
        if ch == '"':
            quoted = not quoted
        elif ch == "\r" or (ch == ";" and not quoted):
            return buffer[:i].replace("\n", ""), i + 1
    return None


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet='AB1 ;"\r\n,{}', max_size=40))
def test_commands_are_cut_where_the_character_rule_cuts_them(buffer: str) -> None:
    assert next_command(buffer) == _next_command_by_characters(buffer)


# ---- nothing the host sends breaks the simulator ------------------------------------------
@pytest.mark.parametrize(
    "expression", ["2147483647+1", "65536*65536", "-2147483648-1", "$FFFFFFFF", "99999999999*0"]
)
def test_arithmetic_out_of_the_32_16_range_is_refused_with_tc_6(
    sim: SimController, expression: str
) -> None:
    # galil-protocol.md §1.4: -2,147,483,648 .. 2,147,483,647; §1.2: TC 6 "Number out of range"
    assert sim.feed(f"MG {expression}\r".encode()) == b"?"
    assert sim.feed(b"TC1\r") == b" 6 Number out of range\r\n:"
    assert sim.feed(b"MG -2147483648\r") == b"-2147483648.0000\r\n:"


def test_an_overflow_in_a_program_halts_it_and_the_replies_stay_in_step(
    sim: SimController,
) -> None:
    assert sim.feed(b"DL\r#A;x=65536;MG x*x;EN\r\\") == b"::"
    assert sim.feed(b"XQ #A\r") == b":"
    sim.advance(0.01)
    assert sim.feed(b"TP\r") == b" 0, 0, 0, 0\r\n:"
    assert sim.feed(b"MG _XQ0,_TC\r") == b"-1.0000 6.0000\r\n:"


def test_com_is_the_32_bit_complement(sim: SimController) -> None:
    assert sim.feed(b"MG @COM[0],@COM[-1],@COM[5]\r") == b"-1.0000 0.0000-6.0000\r\n:"


class _Broken(Room):
    """A room with a bug: ``ZZ`` raises what no command should."""

    @handler("ZZ")
    def zz(self, args: str) -> str:
        raise RuntimeError("a simulator bug")


def test_a_command_that_breaks_the_simulator_is_answered_with_a_question_mark(
    caplog: pytest.LogCaptureFixture,
) -> None:
    sim = SimController("DMC-4040", ManualClock(), rooms=rooms_with(_Broken))
    with caplog.at_level(logging.ERROR, logger="galil.sim"):
        assert sim.feed(b"ZZ;TPA\r") == b"? 0\r\n:"
        assert sim.feed(b"DL\r#A;ZZ;MG 1;EN\r\\\rXQ #A\r") == b":::"
        sim.advance(0.01)
        assert sim.feed(b"MG _XQ0;TPA\r") == b"-1.0000\r\n: 0\r\n:"
    assert [r.levelname for r in caplog.records] == ["ERROR", "ERROR"]
    assert "ZZ" in caplog.records[0].getMessage()


#: Commands whose replies are not ``data CR LF :`` text: binary records (QR, DR), ^Z-ended
#: listings (UL, QU), a switch to collecting input (DL, QD), echo (EO).
_NOT_FUZZED = {"DL", "QD", "QR", "DR", "UL", "QU", "EO"}
_MNEMONICS = sorted(
    c for c in SimController("DMC-4040")._m.interp.commands if c.isalpha() and c not in _NOT_FUZZED
)
#: Operands of an argument: numbers in and out of the controller's range, names, functions,
#: planes and axes, a string, and tokens it does not read.
_OPERANDS = [
    *("0", "1", "-1", ".5", "2147483647", "2147483648", "-2147483648", "65536", "4294967296"),
    *("99999999999", "$FFFFFFFF", "$7FFF.FFFF", "_TPA", "_LMS", "_XQ0", "@COM[0]", "@SQR[-1]"),
    *("@ABS[-2147483648]", "(1", "2)", "a[1]", "?", "S", "T", "ST", "A", "AB", "X", '"ab"'),
    *("1e300", "nan", "inf", "-0", "#A", ""),
]
_OPERATORS = ["+", "-", "*", "/", "&", "|", "<", ">", "<>", "="]


def _random_command(rnd: random.Random) -> str:
    """A mnemonic of the simulator's table with random fields (``PR 65536*65536,?``)."""
    fields = []
    for _ in range(rnd.randrange(4)):
        field = rnd.choice(_OPERANDS)
        for _ in range(rnd.randrange(3)):
            field += rnd.choice(_OPERATORS) + rnd.choice(_OPERANDS)
        fields.append(field)
    head = rnd.choice(["", " ", " A=", " AB=", "*=", "S=", " ?"])
    return rnd.choice(_MNEMONICS) + head + ",".join(fields)


def _terminators(reply: bytes) -> int:
    """How many ``:``/``?`` answers ``reply`` holds, past the data lines (ended CR LF)."""
    count = 0
    while reply:
        if reply[:1] in (b":", b"?"):
            count, reply = count + 1, reply[1:]
            continue
        end = reply.find(b"\r\n")
        assert end >= 0, reply
        reply = reply[end + 2 :]
    return count


@settings(max_examples=60, deadline=None)
@given(st.randoms(use_true_random=False))
def test_any_command_line_gets_exactly_its_replies(rnd: random.Random) -> None:
    # Random lines of random commands on one controller (its state carries from line to
    # line): feed never raises, and each command gets one ':' or '?', in order.
    sim = SimController("DMC-4040", ManualClock())
    replies, sent = b"", 0
    for _ in range(30):
        line = ";".join(_random_command(rnd) for _ in range(rnd.randint(1, 3)))
        replies += sim.feed(line.encode() + b"\r")
        sent += len(split_program_line(line))
        sim.advance(0.001)
    sim.advance(1.0)  # a burn (0.25 s) or another held command has answered by now
    replies += sim.poll()
    assert _terminators(replies) == sent, replies
    assert sim.feed(b"\x12\x16\r") == sim.identity.encode() + b"\r\n:"
