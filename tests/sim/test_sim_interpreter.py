"""The interpreter: expressions left to right, variables, operands and the caller's handle."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.parse import Refused, evaluate, next_command


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(-1000, 1000), min_size=1, max_size=6), st.sampled_from("+-*"))
def test_expressions_run_left_to_right(values: list[int], op: str) -> None:
    text = op.join(f"({v})" for v in values)
    expected = float(values[0])
    for v in values[1:]:
        expected = {"+": expected + v, "-": expected - v, "*": expected * v}[op]
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
