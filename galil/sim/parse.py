"""Text handling for the simulated interpreter: splitting, fields and expressions.

The controller reads ASCII commands ended by ``;`` or carriage return (never inside a quoted
string), two upper-case letters and their arguments. Expressions are evaluated strictly left to
right with parentheses only, as Galil's interpreter does (``1+2*3`` is 9), in the controller's
32.16 fixed point (:func:`quantised`): every number in an expression and every intermediate
result is a multiple of 1/65536, so ``0.1+0.2=0.3`` holds and ``1.4*80000`` is 111999.5117
(DMC-40x0 user manual p.142).
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable, Mapping

from galil.protocol.commands import split_commands

__all__ = [
    "FUNCTIONS",
    "INTERNAL_ERROR",
    "LOG",
    "Refused",
    "evaluate",
    "in_range",
    "internal_error",
    "next_command",
    "quantised",
    "split_fields",
    "split_program_line",
]


#: What ends a command, or opens a quote (outside quotes) / closes it (inside).
_STOPS = re.compile(r'[\r;"]')
_STOPS_QUOTED = re.compile(r'[\r"]')


class Refused(Exception):  # noqa: N818 (a reply, not a failure)
    """The interpreter answers ``?``; ``code`` is the TC code it records."""

    def __init__(self, code: int, why: str = "") -> None:
        super().__init__(why or f"TC {code}")
        self.code = code


#: The simulator's logger: an internal error (a bug of the simulator) is logged here at ERROR.
LOG = logging.getLogger("galil.sim")

#: The TC recorded for a command that broke the simulator itself. The facts have no "unknown
#: error" code (galil-protocol.md §1.2); 1 "Unrecognized command" is the controller's generic
#: refusal. What matters is the reply: "just ``?`` for a rejected command" (§1.1).
INTERNAL_ERROR = 1


def internal_error(text: str) -> Refused:
    """Log the exception being handled (a simulator bug met while running ``text``) and
    return the refusal that answers it: ``?``, TC :data:`INTERNAL_ERROR`."""
    LOG.error("simulator error while running %r; answered ?", text, exc_info=True)
    return Refused(INTERNAL_ERROR, "internal simulator error")


def next_command(buffer: str) -> tuple[str, int] | None:
    """Find the first complete command in ``buffer``.

    Returns:
        ``(command text without its terminator, index just past the terminator)``, or ``None``
        when no terminator has arrived yet. Line feeds are dropped (terminals send CR LF).
    """
    # A CR always ends a command; a ';' only outside quotes (found a stop at a time).
    pos = 0
    stops = _STOPS
    while True:
        m = stops.search(buffer, pos)
        if m is None:
            return None
        i = m.start()
        ch = buffer[i]
        if ch == '"':
            stops = _STOPS_QUOTED if stops is _STOPS else _STOPS
            pos = i + 1
            continue
        return buffer[:i].replace("\n", ""), i + 1


def split_program_line(line: str) -> list[str]:
    """Split one program line into its ``;``-separated commands (quotes respected)."""
    return split_commands(line)


def split_fields(text: str) -> list[str]:
    """Split on commas that are outside quotes, brackets and parentheses."""
    fields: list[str] = []
    depth = 0
    quoted = False
    start = 0
    for i, ch in enumerate(text):
        if ch == '"':
            quoted = not quoted
        elif quoted:
            continue
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            fields.append(text[start:i])
            start = i + 1
    fields.append(text[start:])
    return fields


_TOKEN = re.compile(
    r"\s*(?:"
    r"(?P<num>(?:\d+(?:\.\d*)?|\.\d+))"
    r"|(?P<hex>\$[0-9A-Fa-f]+(?:\.[0-9A-Fa-f]+)?)"
    r"|(?P<func>@[A-Z]+\[)"
    r"|(?P<element>[A-Za-z][A-Za-z0-9]*\[)"
    r"|(?P<name>_?[A-Za-z][A-Za-z0-9_]*)"
    r"|(?P<op><=|>=|<>|[-+*/&|<>=()\]])"
    r")"
)
#: An expression that is a name alone (leading and trailing blanks allowed): one name token.
_NAME_ONLY = re.compile(r"\s*(_?[A-Za-z][A-Za-z0-9_]*)\s*")
#: An expression that is a decimal number alone, signed or not (blanks allowed).
_NUMBER_ONLY = re.compile(r"\s*[-+]?(?:\d+(?:\.\d*)?|\.\d+)\s*")
#: The interpreter's own functions (``@ABS[x]``); rooms may add more (``@IN[n]``).
FUNCTIONS: dict[str, Callable[[float], float]] = {
    "ABS": abs,
    "INT": lambda x: float(math.floor(x)),
    "FRAC": lambda x: x - math.trunc(x),
    "RND": lambda x: float(math.floor(x + 0.5)),
    "SQR": lambda x: math.sqrt(x) if x >= 0 else math.nan,
    # Bitwise complement of the 32-bit whole part. The facts do not describe @COM [U]; numbers
    # are 32-bit two's complement (galil-protocol.md §1.4: range -2,147,483,648 ..
    # 2,147,483,647; hex "2's complement"), so the complement of a value in range is in range
    # (@COM[0] is -1), never the unsigned 4294967295 the controller could not hold.
    "COM": lambda x: float(~int(x)),
}

#: The raw 32.16 limits: "Numeric range -2,147,483,648 ... 2,147,483,647 with fractional
#: resolution 1/65,536" (galil-protocol.md §1.4, C40x0 operator pages).
_RAW_MIN = -(1 << 47)
_RAW_MAX = (1 << 47) - 1


#: The fraction of a 32.16 number: values are floats that are whole multiples of 1/65536,
#: which a double holds exactly (48 significant bits of 53), so ``+``, ``-`` and comparisons
#: on them are exact; ``*`` and ``/`` go through the raw integers (:func:`_arith`).
_ONE = 65536


def in_range(value: float) -> bool:
    """Whether ``value`` is a number the controller can hold (32.16 fixed point)."""
    return math.isfinite(value) and _RAW_MIN <= round(value * _ONE) <= _RAW_MAX


def _rounded(num: int, den: int) -> int:
    """``num / den`` to the nearest integer, halves away from zero (``den`` > 0)."""
    q, r = divmod(abs(num), den)
    if 2 * r >= den:
        q += 1
    return q if num >= 0 else -q


def quantised(value: float) -> float:
    """``value`` as the controller holds it: the nearest multiple of 1/65536, or TC 6.

    "1.4 must be stored to the nearest multiple of 1/65536, which is 91750/65536" (DMC-40x0
    user manual p.142, "Mathematical Operation Precision and Range"); Application Note 3311a
    stores .001 as 66/65536. Halves go away from zero [U: no source shows a tie].

    Raises:
        Refused: TC 6 "Number out of range" (galil-protocol.md §1.2) for a value the 32.16
            format cannot hold (§1.4): ``MG 2147483647+1``, ``65536*65536``.
    """
    if not in_range(value):
        raise Refused(6, "number out of range")
    scaled = value * _ONE
    raw = math.floor(abs(scaled) + 0.5)
    return math.copysign(raw, scaled) / _ONE if raw else 0.0


#: An array element's value: ``element(name, index)``.
Element = Callable[[str, float], float]

_Env = tuple[Callable[[str], float], Mapping[str, Callable[[float], float]], Element | None]


def _tokens(text: str) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    pos = 0
    text = text.rstrip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise Refused(1, f"cannot read {text[pos:]!r}")
        kind = m.lastgroup
        assert kind is not None
        out.append((kind, m.group(kind)))
        pos = m.end()
    return out


def evaluate(
    text: str,
    lookup: Callable[[str], float],
    functions: Mapping[str, Callable[[float], float]] = FUNCTIONS,
    element: Element | None = None,
) -> float:
    """Evaluate a Galil expression, left to right.

    Args:
        text: the expression (``"_TPA+100"``, ``"(a<5)&(b>2)"``, ``"-$10"``, ``"arr[i]*2"``).
        lookup: returns the value of a variable or operand name, or raises :class:`Refused`.
        functions: the ``@NAME[x]`` functions known.
        element: returns an array element (``arr[3]``); ``None``: no arrays (TC 57).

    Raises:
        Refused: a syntax error (TC 1), unbalanced parentheses (TC 59), a bad value (TC 6).
    """
    literal = _NUMBER_ONLY.fullmatch(text)
    if literal is not None:
        # A decimal number alone (``IT 0.004``, ``ILA=9.998``, ``x=0.1``) is handed on as
        # typed: the command applies its own resolution and range to it, and a variable or an
        # array element stores it at 1/65536. [U] The manuals accept IT 0.004 and IL 9.998
        # (their documented bounds), which their nearest 1/65536 (0.0039978, 9.9980011) would
        # fail against those bounds: the controller checks the number as typed, or against
        # bounds in its own format; either way the same settings are taken.
        value = float(literal.group(0))
        if not in_range(value):
            raise Refused(6, "number out of range")
        return value
    plain = _NAME_ONLY.fullmatch(text)
    if plain is not None:
        # A name alone (MG _TPA, a variable): what the tokens below would give, directly.
        value = lookup(plain.group(1))
    else:
        tokens = _tokens(text)
        if not tokens:
            raise Refused(1, "missing value")
        value, pos = _sequence(tokens, 0, (lookup, functions, element))
        if pos != len(tokens):
            raise Refused(59 if tokens[pos][1] in ")]" else 1, f"unexpected {tokens[pos][1]!r}")
    return quantised(value)


def _apply(op: str, a: float, b: float) -> float:
    # Every step is a 32.16 number: an intermediate result out of range is refused too.
    return quantised(_arith(op, a, b))


def _arith(op: str, a: float, b: float) -> float:
    # a and b are 32.16 numbers (multiples of 1/65536, exact as doubles). A sum or a
    # difference is exact; a product or a quotient is taken from the raw integers and rounded
    # to the nearest 1/65536: the DMC-40x0 user manual's (91750/65536)*80000 = 111999.5117
    # (p.142) and AN3311a's (66/65536)*819200 = 825 are exact either way [U: how the
    # firmware rounds a product or quotient that is not a multiple of 1/65536].
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return _rounded(round(a * _ONE) * round(b * _ONE), _ONE) / _ONE
    if op == "/":
        if b == 0:
            raise Refused(6, "division by zero")
        rb = round(b * _ONE)
        num = round(a * _ONE) * _ONE
        return _rounded(num if rb > 0 else -num, abs(rb)) / _ONE
    if op == "&":
        return float(int(a) & int(b))
    if op == "|":
        return float(int(a) | int(b))
    comparisons = {
        "<": a < b,
        ">": a > b,
        "=": a == b,
        "<=": a <= b,
        ">=": a >= b,
        "<>": a != b,
    }
    return 1.0 if comparisons[op] else 0.0


def _sequence(tokens: list[tuple[str, str]], pos: int, env: _Env) -> tuple[float, int]:
    value, pos = _operand(tokens, pos, env)
    while pos < len(tokens) and tokens[pos][0] == "op" and tokens[pos][1] not in ")]":
        op = tokens[pos][1]
        if op == "(":
            raise Refused(1, "missing operator")
        rhs, pos = _operand(tokens, pos + 1, env)
        value = _apply(op, value, rhs)
    return value, pos


def _operand(tokens: list[tuple[str, str]], pos: int, env: _Env) -> tuple[float, int]:
    if pos >= len(tokens):
        raise Refused(1, "missing value")
    kind, text = tokens[pos]
    if kind == "num":
        return quantised(float(text)), pos + 1
    if kind == "hex":
        whole, _, frac = text[1:].partition(".")
        value = float(int(whole, 16))
        if frac:
            value += int(frac, 16) / 16 ** len(frac)
        return quantised(value), pos + 1
    if kind == "name":
        return quantised(env[0](text)), pos + 1
    if kind == "func":
        name = text[1:-1]
        fn = env[1].get(name)
        if fn is None:
            raise Refused(57, f"unknown function @{name}")
        arg, pos = _sequence(tokens, pos + 1, env)
        if pos >= len(tokens) or tokens[pos][1] != "]":
            raise Refused(55, "missing ]")
        return quantised(fn(arg)), pos + 1
    if kind == "element":
        get = env[2]
        if get is None:
            raise Refused(57, f"no array {text[:-1]!r}")
        index, pos = _sequence(tokens, pos + 1, env)
        if pos >= len(tokens) or tokens[pos][1] != "]":
            raise Refused(55, "missing ]")
        return quantised(get(text[:-1], index)), pos + 1
    if text == "-":
        if pos + 1 < len(tokens) and tokens[pos + 1][0] == "num":  # -2147483648 is in range
            return quantised(-float(tokens[pos + 1][1])), pos + 2
        value, pos = _operand(tokens, pos + 1, env)
        return -value, pos
    if text == "+":
        return _operand(tokens, pos + 1, env)
    if text == "(":
        value, pos = _sequence(tokens, pos + 1, env)
        if pos >= len(tokens) or tokens[pos][1] != ")":
            raise Refused(59, "mismatched parentheses")
        return value, pos + 1
    raise Refused(1, f"unexpected {text!r}")
