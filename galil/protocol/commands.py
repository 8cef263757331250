"""Typed command builders: every byte we send is built and validated here.

Each builder returns a :class:`Command` (text without terminator, and how its reply ends) or
raises :class:`~galil.errors.InvalidArgument` / :class:`~galil.errors.LimitError` before any
bytes exist. Builders take an optional ``model`` (:class:`~galil.models.ModelSpec`) to check axes
and ranges for that controller; without one they apply a permissive 8-axis check (axes A-H, and
X Y Z W as aliases of A-D) with only the limits every model shares.

Axis forms::

    pr(1000, None, -200)      -> "PR 1000,,-200"
    pr(B=500)                 -> "PRB=500"
    pr(A=1, C=-2)             -> "PR 1,,-2"
    bg("AC")                  -> "BG AC"

Strings and names never carry ``;``, CR, LF, quotes, backslashes or non-ASCII characters, so a
caller cannot smuggle a second command into a line.
"""

from __future__ import annotations

import enum
import functools
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from numbers import Real
from typing import ClassVar, NamedTuple

import numpy as np

from galil.errors import InvalidArgument, LimitError, decimal_hint
from galil.models import INT32_MAX, INT32_MIN, IT_RANGE, ModelSpec
from galil.protocol.numbers import format_number, whole

__all__ = [
    "COMMAND_NAMES",
    "READ_FORMAT",
    "Command",
    "Expect",
    "ReplyKind",
    "ab",
    "ac",
    "am",
    "ao",
    "array_name",
    "assign",
    "bg",
    "bl",
    "br",
    "burn",
    "ca",
    "cb",
    "cd",
    "cd_end",
    "cd_rows",
    "ce",
    "cm",
    "cn",
    "contour_end",
    "cr",
    "cs",
    "cw",
    "da",
    "da_variables",
    "dc",
    "de",
    "dl",
    "dm",
    "dp",
    "dt",
    "ei",
    "eo",
    "er",
    "fe",
    "fi",
    "fl",
    "ga",
    "gr",
    "hm",
    "hv",
    "hx",
    "identify",
    "il",
    "ip",
    "it",
    "jg",
    "kd",
    "ki",
    "kp",
    "ks",
    "la",
    "ld",
    "le",
    "li",
    "link_setting",
    "lm",
    "lv",
    "lz",
    "mc",
    "mg",
    "mg_operand",
    "mo",
    "mt",
    "oe",
    "op",
    "pa",
    "pack",
    "parse_line",
    "pr",
    "qd",
    "qr",
    "qu",
    "qz",
    "ra",
    "rc",
    "rd",
    "record_source",
    "require_hv",
    "require_limit_disable",
    "rp",
    "sb",
    "sc",
    "sh",
    "sp",
    "st",
    "tc",
    "td",
    "te",
    "th",
    "tl",
    "tm",
    "tp",
    "ts",
    "tv",
    "ui",
    "ul",
    "unrecognized_hint",
    "va",
    "variable_name",
    "vd",
    "ve",
    "vf",
    "vm",
    "vp",
    "vs",
    "vt",
    "wc",
    "xq",
]


class ReplyKind(enum.Enum):
    """How the controller ends its answer to one command."""

    ACK = "ack"  # ':' alone
    DATA = "data"  # data lines (CR LF) then ':'
    ANY = "any"  # either of the above (a raw line we cannot classify)
    RECORD = "record"  # binary record then ':'
    DOUBLE_ACK = "double_ack"  # '::' after a DL download
    CTRL_Z = "ctrl_z"  # text, ^Z, then ':' (UL, QU)


@dataclass(frozen=True, slots=True)
class Expect:
    """What ends the reply to a command.

    Attributes:
        kind: the reply shape.
        size: for ``RECORD`` the record size in bytes (``None``: read it from the header);
            for ``DATA`` the most data lines allowed (``None``: any number).
    """

    kind: ReplyKind
    size: int | None = None

    ACK: ClassVar[Expect]
    DATA: ClassVar[Expect]
    ANY: ClassVar[Expect]
    DOUBLE_ACK: ClassVar[Expect]
    CTRL_Z: ClassVar[Expect]
    LINE: ClassVar[Expect]

    @staticmethod
    def record(size: int | None = None) -> Expect:
        """A binary record of ``size`` bytes (``None``: from its header), then ``:``."""
        if size is not None and size < 4:
            raise InvalidArgument(f"a data record has at least a 4-byte header, not {size}")
        return Expect(ReplyKind.RECORD, size)

    @staticmethod
    def data(lines: int | None = None) -> Expect:
        """Data lines (at most ``lines``), then ``:``."""
        return Expect(ReplyKind.DATA, lines)


Expect.ACK = Expect(ReplyKind.ACK)
Expect.DATA = Expect(ReplyKind.DATA)
Expect.ANY = Expect(ReplyKind.ANY)
Expect.DOUBLE_ACK = Expect(ReplyKind.DOUBLE_ACK)
Expect.CTRL_Z = Expect(ReplyKind.CTRL_Z)
Expect.LINE = Expect(ReplyKind.DATA, 1)

_ACK = Expect.ACK
_LINE = Expect.LINE


class Command(NamedTuple):
    """One command (or a compound line of several) ready to send.

    Immutable, hashable and compared by value. A named tuple rather than a frozen dataclass:
    a command is built for almost every exchange and a tuple is built several times faster
    (see docs/decisions/0001).

    Attributes:
        text: the command text, without terminator (``"PRA=1000"``).
        expect: how the reply ends.
        payload: bytes sent after ``text`` and CR (the program of ``DL``, the values of ``QD``).
        parts: for a compound line built by :func:`pack`, the commands in it, in order.
    """

    text: str
    expect: Expect = _ACK
    payload: bytes = b""
    parts: tuple[Command, ...] = ()

    @property
    def returns_data(self) -> bool:
        """Whether the reply carries data (text, record or upload) before its ``:``."""
        return self.expect.kind not in (ReplyKind.ACK, ReplyKind.DOUBLE_ACK)

    @property
    def wire(self) -> bytes:
        """The bytes to write: text, CR, then any payload."""
        return self.text.encode("latin-1") + b"\r" + self.payload

    def __str__(self) -> str:
        return self.text


_new = tuple.__new__


def _plain(text: str) -> Command:
    """``Command(text)`` without the named tuple's keyword handling (the builders' hot path)."""
    return _new(Command, (text, _ACK, b"", ()))


#: The format the library gives every number it reads with ``MG`` (decision 0032): ten digits
#: and four decimals, leading zeros suppressed: what the default ``VF 10.4`` prints, but fixed
#: whatever ``VF`` (or ``LZ``) a user or a program has set. Placed after each item, as the
#: command reference shows (``MG "The answer is...",total{F4.2}``).
READ_FORMAT = "{Z10.4}"

_TIME = Command("MG TIME" + READ_FORMAT, _LINE)


# Two-letter mnemonics of the firmware (40x0/18x2/2x00 command references). A variable whose
# name starts with one of these, in upper case, followed only by digits or axis letters
# (``CD0``, ``SPA``) would be parsed as that command, so such names are refused. Commands are
# upper case and names case-sensitive, so ``data`` or ``ta0`` is no command (decision 0060).
_MNEMONICS = """
    AB AC AD AE AF AG AI AL AM AO AP AQ AR AS AT AU AV AW AZ BA BB BC BD BG BI BK BL BM BN BO
    BP BQ BR BS BV BW BX BZ CA CB CC CD CE CF CI CM CN CO CR CS CW DA DC DE DF DH DL DM DP DR DS
    DT DV EA EB EC ED EG EI EM EN EO EP EQ ER ES ET EW EY FA FC FE FI FL FV GA GD GM GN GR GS HM
    HS HV HX IA ID IF IH IK IL IN IP IT JG JP JS KD KI KP KS LA LB LC LD LE LI LL LM LS LU LV LZ
    MB MC MF MG MO MR MT MW NB NF NO NZ OA OB OC OE OF OP OT OV PA PF PL PR PT PV PW QD QH QP QR
    QS QU QZ RA RC RD RE RI RL RO RP RS SA SB SC SD SH SI SL SM SP ST SY TA TB TC TD TE TH TI TK
    TL TM TN TP TR TS TT TV TW TZ UI UL VA VD VE VF VM VP VR VS VV WC WH WT XQ YA YB YC
    YR ZA ZS"""
COMMAND_NAMES: frozenset[str] = frozenset(_MNEMONICS.split())
_KEYWORDS = frozenset({"ELSE", "ENDIF", "TIME", "AND", "OR"})

_DEFAULT_NAMES = ModelSpec("", "", "A")  # label/variable lengths when no model is given
_VAR = re.compile(rf"[A-Za-z][A-Za-z0-9]{{0,{_DEFAULT_NAMES.variable_length - 1}}}")
_LABEL = re.compile(rf"#[A-Za-z][A-Za-z0-9]{{0,{_DEFAULT_NAMES.label_length - 1}}}")
_OPERAND = re.compile(
    r"_[A-Z]{2}[A-Z0-9]{0,2}"  # _TPA, _TC, _XQ0, _LFA
    r"|@[A-Z]{2,4}\[\d{1,4}\]"  # @IN[1], @AN[2]
    r"|[A-Za-z][A-Za-z0-9]{0,7}(?:\[\d{1,5}\])?"  # variable or array element
)
_AXIS_SUFFIX = re.compile(r"[A-HSTXYZWN]{1,8}|\d+")
_UNSAFE = re.compile(r'[^\x20-\x7e]|[;"\\]')


# --------------------------------------------------------------------------------- axes


class _Axes:
    """Axis letters a model accepts, with their positional index."""

    __slots__ = ("index", "model_name", "nax", "ordered")

    def __init__(self, model: ModelSpec | None) -> None:
        if model is None:
            letters = "ABCDEFGH"
            aliases = {"X": "A", "Y": "B", "Z": "C", "W": "D"}
            self.model_name = None
        else:
            letters, aliases, self.model_name = model.axes, model.aliases, model.name
        self.index = {c: "ABCDEFGH".index(c) for c in letters}
        for alias, real in aliases.items():
            if real in self.index:
                self.index[alias] = self.index[real]
        self.nax = len(letters)
        self.ordered = letters

    def position(self, letter: object) -> int:
        idx = self.index.get(letter) if isinstance(letter, str) else None
        if idx is None:
            where = f" on {self.model_name}" if self.model_name else ""
            raise InvalidArgument(
                f"unknown axis {letter!r}{where}; valid: {', '.join(sorted(self.index))}",
                model=self.model_name,
            )
        return idx


_DEFAULT_AXES = _Axes(None)
_AXES_CACHE: dict[tuple[str, str, tuple[tuple[str, str], ...]], _Axes] = {}


def _axes(model: ModelSpec | None) -> _Axes:
    if model is None:
        return _DEFAULT_AXES
    key = (model.name, model.axes, tuple(sorted(model.aliases.items())))
    found = _AXES_CACHE.get(key)
    if found is None:
        found = _AXES_CACHE[key] = _Axes(model)
    return found


def _axis_list(axes: str | Iterable[str], model: ModelSpec | None, extra: str = "") -> str:
    """Validate an axis list like ``"AC"`` (letters as given, no repeats)."""
    if not isinstance(axes, str):
        if isinstance(axes, Mapping) or not isinstance(axes, Iterable):
            raise InvalidArgument(f"axes must be letters such as 'AB', not {axes!r:.60}")
        axes = list(axes)
        if not all(isinstance(a, str) for a in axes):
            raise InvalidArgument(f"axes must be letters such as 'AB', not {axes!r:.60}")
        axes = "".join(axes)
    table = _axes(model)
    seen: set[int | str] = set()
    for letter in axes:
        key: int | str = letter if letter in extra else table.position(letter)
        if key in seen:
            raise InvalidArgument(f"axis {letter!r} given twice in {axes!r}")
        seen.add(key)
    return axes


# --------------------------------------------------------------------------------- values


def _number(value: object, what: str) -> float:
    # bool is an int, but True as a count is almost always a bug.
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise InvalidArgument(f"{what}: {value!r} is not a number{decimal_hint(value)}")
    try:
        v = float(value)
    except OverflowError:  # an int too large for any float
        raise InvalidArgument(f"{what}: {value!r:.40} is far out of range") from None
    if not math.isfinite(v):
        raise InvalidArgument(f"{what}: {value!r} cannot be sent (NaN or infinity)")
    return v


def _count(value: object, what: str, axis: str | None = None) -> str:
    """A signed 32-bit integer count."""
    if type(value) is int and INT32_MIN <= value <= INT32_MAX:
        return str(value)
    v = _number(value, what)
    if not v.is_integer():
        raise InvalidArgument(f"{what}: {value!r} is not a whole number of counts")
    if not INT32_MIN <= v <= INT32_MAX:
        limit = INT32_MAX if v > 0 else INT32_MIN
        raise LimitError(
            f"{what}: {value!r} is outside the 32-bit range",
            name=what,
            value=v,
            limit=limit,
            axis=axis,
        )
    return str(int(v))


def _ranged(
    value: object,
    lo: float,
    hi: float,
    what: str,
    axis: str | None = None,
    model: str | None = None,
    *,
    integer: bool = False,
) -> str:
    if type(value) is int and lo <= value <= hi:
        return str(value)
    v = _number(value, what)
    if integer and not v.is_integer():
        raise InvalidArgument(f"{what}: {value!r} must be a whole number", model=model)
    if not lo <= v <= hi:
        where = f" on {model}" if model else ""
        raise LimitError(
            f"{what}: {value!r} is outside {format_number(lo)} .. {format_number(hi)}{where}",
            name=what,
            value=v,
            limit=hi if v > hi else lo,
            axis=axis,
            model=model,
        )
    return format_number(v)


def _counted(value: object, lo: int, hi: int, what: str, model: str | None = None) -> str:
    """A count (an array's size, an element index, a thread, how many values) within
    ``lo`` .. ``hi``: an ``int`` or a numpy integer, as Python's sequences take (``[0] *
    10.0`` is a TypeError); a float, even a whole one, and a bool are refused."""
    n = whole(value)
    if n is None:
        shown = f"{value!r:.60}"
        raise InvalidArgument(
            f"{what} must be an int (a count: a whole number; numpy's too), not {shown}",
            model=model,
        )
    return _ranged(n, lo, hi, what, model=model, integer=True)


def _away(text: str, value: object) -> str:
    """``text`` (``value`` at four decimals), one last digit further from zero if rounding
    took a float nearer: a stepped value (SP at TM 1500 is a multiple of 4/3 counts/s) then
    reaches the controller at or just beyond its step, never just short of it, where
    rounding down to the step would store the step below."""
    if not isinstance(value, float) or abs(float(text)) >= abs(value):
        return text
    return format_number(math.copysign(abs(float(text)) + 1e-4, value))


class _Checker:
    """Range check for one per-axis command, bound to a model (``stepped``: a value the
    controller rounds down to its step, sent at or beyond it: :func:`_away`)."""

    __slots__ = ("hi", "integer", "lo", "model_name", "name", "stepped")

    def __init__(
        self,
        name: str,
        lo: float,
        hi: float,
        model: ModelSpec | None,
        *,
        integer: bool,
        stepped: bool = False,
    ) -> None:
        self.name, self.lo, self.hi, self.integer = name, lo, hi, integer
        self.model_name = model.name if model is not None else None
        self.stepped = stepped

    def __call__(self, value: object, axis: str) -> str:
        if type(value) is int and self.lo <= value <= self.hi:
            return str(value)
        if self.integer and self.lo == INT32_MIN and self.hi == INT32_MAX:
            return _count(value, self.name, axis)
        text = _ranged(
            value, self.lo, self.hi, self.name, axis, self.model_name, integer=self.integer
        )
        return _away(text, value) if self.stepped else text


# Integer ranges every model accepts, for the hot path of _axis_command.
_DEFAULT_INT_RANGES: dict[str, tuple[int, int]] = {
    "PR": (INT32_MIN, INT32_MAX),
    "PA": (INT32_MIN, INT32_MAX),
    "DP": (INT32_MIN, INT32_MAX),
    "DE": (INT32_MIN, INT32_MAX),
    "FL": (INT32_MIN, INT32_MAX),
    "BL": (INT32_MIN, INT32_MAX),
    "IP": (INT32_MIN, INT32_MAX),
    "SP": (0, INT32_MAX),
    "JG": (-INT32_MAX, INT32_MAX),
    "AC": (1024, INT32_MAX),
    "DC": (1024, INT32_MAX),
}


_DEFAULT_LETTERS = frozenset(_DEFAULT_AXES.index)
_NO_RANGE = (1, 0)
# Commands whose range (32-bit counts) is the same on every model (:func:`_checker`).
_POSITION_MNEMONICS = frozenset({"PR", "PA", "DP", "DE", "FL", "BL", "IP"})


def _axis_command(
    mnemonic: str,
    values: Sequence[object],
    by_axis: dict[str, object],
    model: ModelSpec | None,
    suffix: str = "",
) -> str:
    if not values and model is None and len(by_axis) == 1:
        # hot path: one axis, an int, the permissive model (popitem is the cheapest way to
        # the one item; the item goes back, callers may read the dict again)
        letter, value = by_axis.popitem()
        by_axis[letter] = value
        if type(value) is int and letter in _DEFAULT_LETTERS:
            lo, hi = _DEFAULT_INT_RANGES.get(mnemonic, _NO_RANGE)
            if lo <= value <= hi:
                return f"{mnemonic}{letter}={value}{suffix}"
    elif not values and model is not None and len(by_axis) == 1 and mnemonic in _POSITION_MNEMONICS:
        # hot path with a model: one axis of its own letters, a count in the 32-bit range
        # every model takes for these (a move's PA, its IP)
        letter, value = by_axis.popitem()
        by_axis[letter] = value
        if (
            type(value) is int
            and INT32_MIN <= value <= INT32_MAX
            and len(letter) == 1
            and letter in model.axes
        ):
            return f"{mnemonic}{letter}={value}{suffix}"
    table = _axes(model)
    check = _checker(mnemonic, model)
    if not values and len(by_axis) == 1:
        ((letter, value),) = by_axis.items()
        table.position(letter)
        return f"{mnemonic}{letter}={check(value, letter)}{suffix}"
    if len(values) > table.nax:
        raise InvalidArgument(
            f"{mnemonic}: {len(values)} values for {table.nax} axes", model=table.model_name
        )
    fields: list[str] = [
        "" if v is None else check(v, table.ordered[i]) for i, v in enumerate(values)
    ]
    for letter, value in by_axis.items():
        idx = table.position(letter)
        if idx >= len(fields):
            fields.extend([""] * (idx + 1 - len(fields)))
        elif fields[idx]:
            raise InvalidArgument(f"{mnemonic}: axis {letter!r} given twice")
        if value is not None:
            fields[idx] = check(value, letter)
    while fields and not fields[-1]:
        fields.pop()
    if not fields:
        raise InvalidArgument(f"{mnemonic}: no value given")
    return f"{mnemonic} {','.join(fields)}{suffix}"


# Checkers are cached per command and per model values (ModelSpec holds a dict, so it is not
# hashable; specs built on the fly by get_model() share their values).
_CHECKERS: dict[tuple[object, ...], _Checker] = {}


def _accel_floor(model: ModelSpec) -> float:
    """The smallest AC/DC ``model`` takes at any TM it allows (its longest TM)."""
    return model.accel_min(model.tm_range[1])


def _checker(kind: str, model: ModelSpec | None) -> _Checker:
    key: tuple[object, ...] = (kind,)
    if model is not None:
        key = (kind, model.name, model.ac_min, model.ac_max, model.sp_max, *model.cd_range)
        key += (*model.it_range, model.li_max, model.gr_max)
    found = _CHECKERS.get(key)
    if found is not None:
        return found
    if kind in ("PR", "PA", "DP", "DE", "FL", "BL", "IP"):
        found = _Checker(kind, INT32_MIN, INT32_MAX, model, integer=True)
    elif kind in ("AC", "DC"):
        # The smallest AC/DC falls with a longer TM (1024 * (1000/TM)**2): the range is the
        # model's over every TM it allows; the predictor quantises for the TM in force.
        lo, hi = (1024, INT32_MAX) if model is None else (_accel_floor(model), model.ac_max)
        found = _Checker(kind, lo, hi, model, integer=False, stepped=True)
    elif kind == "SP":
        hi = INT32_MAX if model is None else model.sp_max
        found = _Checker(kind, 0, hi, model, integer=False, stepped=True)
    elif kind == "JG":
        hi = INT32_MAX if model is None else model.sp_max
        found = _Checker(kind, -hi, hi, model, integer=False, stepped=True)
    elif kind == "AD":
        found = _Checker(kind, 0, INT32_MAX, model, integer=True)
    elif kind == "IT":
        it_lo, it_hi = IT_RANGE if model is None else model.it_range
        found = _Checker(kind, it_lo, it_hi, model, integer=False)
    elif kind == "CD":
        lo, hi = (-INT32_MAX, INT32_MAX) if model is None else model.cd_range
        found = _Checker(kind, lo, hi, model, integer=True)
    elif kind == "LI":
        hi = _DEFAULT_NAMES.li_max if model is None else model.li_max
        found = _Checker(kind, -hi, hi, model, integer=True)
    elif kind == "GR":
        g = _DEFAULT_NAMES.gr_max if model is None else model.gr_max
        found = _Checker(kind, -g, g, model, integer=False)
    else:  # pragma: no cover - programming error
        raise KeyError(kind)
    _CHECKERS[key] = found
    return found


def pr(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """PR: relative move distance per axis in counts (``pr(1000, None, -200)``, ``pr(B=500)``)."""
    return _plain(_axis_command("PR", values, by_axis, model))


def ad(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """AD: trippoint, held until the axis has moved this distance (counts) from its start."""
    return _plain(_axis_command("AD", values, by_axis, model))


def pa(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """PA: absolute target position per axis in counts."""
    return _plain(_axis_command("PA", values, by_axis, model))


def sp(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """SP: slew speed per axis, counts/s, 0 .. the model's maximum."""
    return _plain(_axis_command("SP", values, by_axis, model))


def ac(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """AC: acceleration per axis, counts/s², inside the model's AC range."""
    return _plain(_axis_command("AC", values, by_axis, model))


def dc(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """DC: deceleration per axis, counts/s², inside the model's DC range."""
    return _plain(_axis_command("DC", values, by_axis, model))


def jg(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """JG: signed jog speed per axis, counts/s."""
    return _plain(_axis_command("JG", values, by_axis, model))


def ip(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """IP: increment the target position, counts."""
    return _plain(_axis_command("IP", values, by_axis, model))


def _least_it(value: object, model: ModelSpec | None) -> object:
    """IT's smallest step, 1/256 (``MG _ITA`` prints 0.0039), goes out as the 0.004 that sets
    it: the command takes 0.004 .. 1 and the controller holds IT in 1/256ths."""
    low = IT_RANGE[0] if model is None else model.it_range[0]
    if type(value) is float and 1 / 256 - 1e-4 < value < low:
        return low
    return value


def it(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """IT: independent time constant (smoothing), 0.004 .. 1 (1/256, what IT 0.004 sets, as
    0.004)."""
    fields = tuple(_least_it(v, model) for v in values)
    named = {k: _least_it(v, model) for k, v in by_axis.items()}
    return _plain(_axis_command("IT", fields, named, model))


def dp(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """DP: define the current position, counts."""
    return _plain(_axis_command("DP", values, by_axis, model))


def de(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """DE: define the auxiliary encoder's position (a stepper's main encoder), counts."""
    return _plain(_axis_command("DE", values, by_axis, model))


def fl(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """FL: forward software limit, counts (2147483647 disables it)."""
    return _plain(_axis_command("FL", values, by_axis, model))


def bl(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """BL: reverse software limit, counts (-2147483648 disables it)."""
    return _plain(_axis_command("BL", values, by_axis, model))


# --------------------------------------------------------------------------------- axis lists


# Validated axis-list texts for the permissive model (bounded: a cache, not a leak).
_LIST_CACHE: dict[tuple[str, str, str], str] = {}


def _list_command(
    mnemonic: str, axes: str | Iterable[str], model: ModelSpec | None, extra: str = ""
) -> str:
    if model is None and type(axes) is str:
        key = (mnemonic, axes, extra)
        text = _LIST_CACHE.get(key)
        if text is None:
            text = _list_command(mnemonic, list(axes), None, extra)
            if len(_LIST_CACHE) < 4096:
                _LIST_CACHE[key] = text
        return text
    if type(axes) is str and len(axes) == 1 and model is not None and axes in model.axes:
        return f"{mnemonic} {axes}"  # (hot path: one of the model's own letters)
    letters = _axis_list(axes, model, extra)
    return f"{mnemonic} {letters}" if letters else mnemonic


def bg(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """BG: begin motion on ``axes`` (``""``: all; ``S``/``T`` coordinated planes allowed)."""
    return _plain(_list_command("BG", axes, model, "ST"))


def st(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """ST: decelerate to a stop (``""``: every axis, and stop programs)."""
    return _plain(_list_command("ST", axes, model, "ST"))


def am(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """AM: trippoint for program text; it holds the thread until the profiler of ``axes`` has
    finished.

    A controller refuses it from a host with TC 2, "Command only valid from program" (the
    DMC-4103 command reference marks AM "Not Valid in terminal"; decision 0044): put its
    ``text`` in a program line. A host waits for a move by polling ``_BGm``, as
    ``MoveHandle.wait`` does.
    """
    return _plain(_list_command("AM", axes, model, "ST"))


def mc(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """MC: trippoint for program text; it holds the thread until ``axes`` are in position.

    A controller refuses it from a host with TC 2, as :func:`am` (MC is "Not Valid in
    terminal" too; decision 0044): put its ``text`` in a program line.
    """
    return _plain(_list_command("MC", axes, model))


def sh(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """SH: servo here (motor on)."""
    return _plain(_list_command("SH", axes, model))


def mo(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """MO: motor off."""
    return _plain(_list_command("MO", axes, model))


def cm(axes: str | Iterable[str], *, model: ModelSpec | None = None) -> Command:
    """CM: select contour mode on ``axes``."""
    letters = _axis_list(axes, model)
    if not letters:
        raise InvalidArgument("CM needs at least one axis")
    return Command(f"CM {letters}")


def ab(motion_only: bool = False) -> Command:
    """AB: abort motion (and programs, unless ``motion_only``: ``AB 1``)."""
    return Command("AB 1" if motion_only else "AB")


_QUERY_CACHE: dict[tuple[str, str], Command] = {}


def _query(mnemonic: str, axes: str | Iterable[str], model: ModelSpec | None) -> Command:
    if model is None and type(axes) is str:
        # Commands are immutable, so the permissive model's queries can be shared.
        found = _QUERY_CACHE.get((mnemonic, axes))
        if found is None:
            found = Command(_list_command(mnemonic, axes, None), _LINE)
            if len(_QUERY_CACHE) < 4096:
                _QUERY_CACHE[mnemonic, axes] = found
        return found
    return Command(_list_command(mnemonic, axes, model), _LINE)


def tp(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """TP: tell position (one line: one value per axis, comma separated)."""
    return _query("TP", axes, model)


def tv(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """TV: tell velocity (filtered), counts/s."""
    return _query("TV", axes, model)


def te(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """TE: tell position error."""
    return _query("TE", axes, model)


def rp(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """RP: reference position (profiler output after IT)."""
    return _query("RP", axes, model)


def td(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """TD: tell dual (auxiliary) encoder, or step count on steppers."""
    return _query("TD", axes, model)


def ts(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """TS: tell switches (status byte per axis)."""
    return _query("TS", axes, model)


def sc(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """SC: stop code per axis."""
    return _query("SC", axes, model)


# --------------------------------------------------------------------------------- contour


def cd(
    *values: object, dt: int | None = None, model: ModelSpec | None = None, **by_axis: object
) -> Command:
    """CD: one contour segment of increments per axis, optionally with its own DT (``=n``).

    Raises:
        InvalidArgument: ``dt`` on a model whose ``CD`` takes no ``=n`` (set ``DT`` instead).
    """
    suffix = ""
    if dt is not None:
        if model is not None and not model.contour_dt_suffix:
            raise InvalidArgument(
                f"{model.name}: CD takes no '=n'; send DT {dt} before the segments instead"
            )
        suffix = "=" + _ranged(dt, 0, 8, "CD =n (DT)", integer=True)
    text = _axis_command("CD", values, by_axis, model, suffix)
    if "=" in text and not text.startswith("CD "):
        # "CDA=5" would not parse as a segment; always use the positional form.
        table = _axes(model)
        ((letter, value),) = by_axis.items()
        fields = [""] * (table.position(letter) + 1)
        fields[-1] = _checker("CD", model)(value, letter)
        text = f"CD {','.join(fields)}{suffix}"
    return Command(text)


def cd_rows(
    increments: object, axes: str = "A", *, model: ModelSpec | None = None
) -> list[Command]:
    """CD for many segments at once: one command per row of ``increments``.

    ``increments`` has one row per segment and one column per axis of ``axes`` (or one
    value per segment for one axis). Each command is the one :func:`cd` builds from that row
    (``cd(A=row[0], B=row[1], ...)``), the values checked together: a contour of a million
    segments is built in a fraction of a second rather than one builder call at a time.

    Raises:
        InvalidArgument: bad axes, a shape that does not match them, values that are not
            whole numbers.
        LimitError: a value outside the model's CD range (the first one, as :func:`cd`
            refuses it).
    """
    letters = _axis_list(axes, model)
    if not letters:
        raise InvalidArgument("cd_rows needs at least one axis")
    table = _axes(model)
    positions = [table.position(c) for c in letters]
    if len(set(positions)) != len(positions):
        raise InvalidArgument(f"CD: an axis of {axes!r} is given twice")
    c = np.asarray(increments)
    if c.ndim == 1 and len(letters) == 1:
        c = c[:, None]
    if c.ndim != 2 or c.shape[1] != len(letters):
        raise InvalidArgument(f"CD rows must have shape (segments, {len(letters)}), not {c.shape}")
    whole = c.dtype.kind in "iu" or (
        c.dtype.kind == "f" and bool(np.all(np.isfinite(c))) and bool(np.all(c == np.round(c)))
    )
    if not whole:
        raise InvalidArgument("CD increments must be whole numbers")
    c = c.astype(np.int64)
    lo, hi = (-INT32_MAX, INT32_MAX) if model is None else model.cd_range
    bad = np.flatnonzero(((c > hi) | (c < lo)).any(axis=1))
    if bad.size:
        row = c[int(bad[0])].tolist()
        cd(model=model, **dict(zip(letters, row, strict=True)))  # raises as cd() does
    order = sorted(range(len(letters)), key=lambda i: positions[i])
    slots = [""] * (max(positions) + 1)
    for i in order:
        slots[positions[i]] = "%d"
    form = "CD " + ",".join(slots)
    rows = c[:, order].tolist()
    if len(letters) == 1:
        return [_plain(form % r[0]) for r in rows]
    return [_plain(form % tuple(r)) for r in rows]


def cd_end(axes: str = "A", *, model: ModelSpec | None = None) -> Command:
    """End contour mode: ``CD 0=0`` (the space matters: ``CD0=0`` assigns a variable CD0).

    On a model whose ``CD`` takes no ``=n`` (``contour_dt_suffix`` false: the DMC-1500,
    1700/1800 and 18x2) it is ``CD 0`` with a zero per axis, which ends contour mode after
    ``DT 0`` (send :func:`dt` ``(0)`` first; :func:`contour_end` gives both).
    """
    letters = _axis_list(axes, model)
    if not letters:
        raise InvalidArgument("cd_end needs at least one axis")
    table = _axes(model)
    n = max(table.position(c) for c in letters) + 1
    zeros = "CD " + ",".join(["0"] * n)
    if model is not None and not model.contour_dt_suffix:
        return Command(zeros)
    return Command(zeros + "=0")


def contour_end(axes: str = "A", *, model: ModelSpec | None = None) -> list[Command]:
    """The commands that end contour mode on ``model``: ``[CD 0=0]``, or ``[DT 0, CD 0]``
    where ``CD`` takes no ``=n`` ("zero parameters for DT followed by zero parameters for
    CD exit the contour mode", DMC-18x2 manual)."""
    end = cd_end(axes, model=model)
    if model is not None and not model.contour_dt_suffix:
        return [dt(0, model=model), end]
    return [end]


def dt(n: int, *, model: ModelSpec | None = None) -> Command:
    """DT: contour segment time, 2**n samples (0 ends, -1 pauses on buffered models)."""
    lo, hi = (-1, 8) if model is None else model.dt_range
    if model is not None and model.contour_preload:
        lo = -1
    allowed = _ranged(
        n, min(lo, 0), hi, "DT", model=None if model is None else model.name, integer=True
    )
    return Command(f"DT {allowed}")


def wc() -> Command:
    """WC: trippoint, the ``:`` comes when the current contour segment is complete."""
    return Command("WC")


# ------------------------------------------------------------------------- coordinated motion

_MASTER = re.compile(r"[CD]?([A-HXYZW])|[ST]|N")


def _plane(plane: str) -> str:
    if plane not in ("S", "T"):
        raise InvalidArgument(f"a coordinate system (plane) is S or T, not {plane!r}")
    return plane


def ca(plane: str = "S") -> Command:
    """CA: select the coordinate system (``S`` or ``T``) the sequence commands apply to."""
    return Command(f"CA {_plane(plane)}")


def cs(plane: str = "S") -> Command:
    """CS: clear the sequence (the queued segments) of coordinate system ``plane``."""
    return Command(f"CS {_plane(plane)}")


def vm(axes: str | Iterable[str], *, model: ModelSpec | None = None) -> Command:
    """VM: vector mode on two axes, the plane of ``VP`` and ``CR`` (``VM AB``)."""
    letters = _axis_list(axes, model)
    if len(letters) != 2:
        raise InvalidArgument(f"VM takes two axes (the plane), got {letters!r}")
    return Command(f"VM {letters}")


def lm(axes: str | Iterable[str], *, model: ModelSpec | None = None) -> Command:
    """LM: linear interpolation on 1 to 8 axes (``LM ABC``)."""
    letters = _axis_list(axes, model)
    if not letters:
        raise InvalidArgument("LM needs at least one axis")
    return Command(f"LM {letters}")


def vp(x: object, y: object) -> Command:
    """VP: a straight segment to ``(x, y)``, counts from where the sequence began (32-bit)."""
    return Command(f"VP {_count(x, 'VP')},{_count(y, 'VP')}")


def cr(radius: object, start: object, sweep: object, *, model: ModelSpec | None = None) -> Command:
    """CR: a circular segment of ``radius`` counts from angle ``start`` through ``sweep`` degrees.

    0 degrees is the first plane axis's positive direction; a positive sweep turns
    counter-clockwise. Ranges (radius, angles, radius × sweep) come from the model.
    """
    spec = _DEFAULT_NAMES if model is None else model
    name = None if model is None else model.name
    lo, hi = spec.cr_radius
    r = _ranged(radius, lo, hi, "CR radius", model=name)
    amax = spec.cr_angle_max
    theta = _ranged(start, -amax, amax, "CR start angle", model=name)
    delta = _ranged(sweep, -amax, amax, "CR sweep", model=name)
    if float(delta) == 0:
        raise InvalidArgument("CR sweep must not be 0 degrees")
    arc = _number(radius, "CR radius") * _number(sweep, "CR sweep")
    _ranged(arc, -spec.cr_arc_max, spec.cr_arc_max, "CR radius × sweep", model=name)
    return Command(f"CR {r},{theta},{delta}")


def ve() -> Command:
    """VE: the vector sequence ends with the segments given (decelerate to the last one)."""
    return Command("VE")


def le() -> Command:
    """LE: the linear-interpolation sequence ends with the segments given."""
    return Command("LE")


def li(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """LI: one linear segment, an increment per axis in counts (fields by axis, as PR)."""
    text = _axis_command("LI", values, by_axis, model)
    if "=" in text:  # "LIA=5" is a valid form, but one form is easier to read in a log
        table = _axes(model)
        ((letter, value),) = by_axis.items()
        fields = [""] * (table.position(letter) + 1)
        fields[-1] = _checker("LI", model)(value, letter)
        text = "LI " + ",".join(fields)
    return Command(text)


def _plane_value(
    mnemonic: str,
    value: object,
    lo: float,
    hi: float,
    plane: str,
    model: str | None,
    *,
    integer: bool = False,
    stepped: bool = False,
) -> Command:
    text = _ranged(value, lo, hi, mnemonic, model=model, integer=integer)
    if stepped:
        text = _away(text, value)
    return Command(f"{mnemonic}{_plane(plane)}={text}")


# VS, VA and VD are taken from their smallest step at the model's longest TM (their steps
# follow TM as SP's and AC's do, assumed: docs/decisions/0025); the predictor quantises for
# the TM in force. They go out at or just beyond their step (:func:`_away`).
def vs(speed: object, plane: str = "S", *, model: ModelSpec | None = None) -> Command:
    """VS: vector speed of ``plane`` along the path, counts/s (``VSS=20000``)."""
    spec = _DEFAULT_NAMES if model is None else model
    hi = spec.vs_max if spec.vs_max is not None else spec.sp_max
    lo = spec.speed_resolution(spec.tm_range[1])
    name = None if model is None else model.name
    return _plane_value("VS", speed, lo, hi, plane, name, stepped=True)


def va(accel: object, plane: str = "S", *, model: ModelSpec | None = None) -> Command:
    """VA: vector acceleration of ``plane``, counts/s² (``VAS=256000``)."""
    spec = _DEFAULT_NAMES if model is None else model
    hi = spec.va_max if spec.va_max is not None else spec.ac_max
    name = None if model is None else model.name
    return _plane_value("VA", accel, _accel_floor(spec), hi, plane, name, stepped=True)


def vd(decel: object, plane: str = "S", *, model: ModelSpec | None = None) -> Command:
    """VD: vector deceleration of ``plane``, counts/s² (``VDS=256000``)."""
    spec = _DEFAULT_NAMES if model is None else model
    hi = spec.va_max if spec.va_max is not None else spec.ac_max
    name = None if model is None else model.name
    return _plane_value("VD", decel, _accel_floor(spec), hi, plane, name, stepped=True)


def vt(smoothing: object, plane: str = "S", *, model: ModelSpec | None = None) -> Command:
    """VT: vector time constant (smoothing) of ``plane``, as IT (refused where the model has
    none: those smooth a sequence with the axes' IT)."""
    if model is not None and not model.vt:
        raise InvalidArgument(
            f"{model.name} has no VT; its sequences are smoothed by the axes' IT", model=model.name
        )
    lo, hi = IT_RANGE if model is None else model.it_range
    value = _least_it(smoothing, model)
    return _plane_value("VT", value, lo, hi, plane, None if model is None else model.name)


def ga(*masters: str | None, model: ModelSpec | None = None, **by_axis: str) -> Command:
    """GA: the gearing master of each follower, by follower position (``GA ,CA``).

    A master is an axis letter (its main encoder), ``C`` + letter (its commanded position),
    ``D`` + letter (its auxiliary encoder), ``S``/``T`` (the vector distance of a plane) or
    ``N`` (the virtual axis).
    """
    table = _axes(model)
    fields: list[str] = ["" if m is None else m for m in masters]
    if len(fields) > table.nax:
        raise InvalidArgument(f"GA: {len(fields)} masters for {table.nax} axes")
    for letter, master in by_axis.items():
        idx = table.position(letter)
        if idx >= len(fields):
            fields.extend([""] * (idx + 1 - len(fields)))
        elif fields[idx]:
            raise InvalidArgument(f"GA: axis {letter!r} given twice")
        fields[idx] = master
    for i, master in enumerate(fields):
        if not master:
            continue
        m = _MASTER.fullmatch(master) if isinstance(master, str) else None
        if m is None or (m.group(1) is not None and m.group(1) not in table.index):
            raise InvalidArgument(
                f"GA: {master!r} is not a master (an axis, C or D + axis, S, T or N)",
                model=table.model_name,
            )
        if m.group(1) is not None and table.index[m.group(1)] == i:
            raise InvalidArgument(f"GA: axis {table.ordered[i]} cannot follow itself (TC 46)")
    while fields and not fields[-1]:
        fields.pop()
    if not fields:
        raise InvalidArgument("GA: no master given")
    return Command("GA " + ",".join(fields))


def gr(*values: object, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """GR: gear ratio per follower (``GR ,0.5``); 0 turns that axis's gearing off."""
    text = _axis_command("GR", values, by_axis, model)
    if "=" in text:
        table = _axes(model)
        ((letter, value),) = by_axis.items()
        fields = [""] * (table.position(letter) + 1)
        fields[-1] = _checker("GR", model)(value, letter)
        text = "GR " + ",".join(fields)
    return Command(text)


# --------------------------------------------------------------------------------- queries, setup


def tc(mode: int = 1) -> Command:
    """TC: tell the last error code (``TC1``: code and text)."""
    if mode not in (0, 1) or isinstance(mode, bool):
        raise InvalidArgument(f"TC takes 0 or 1, not {mode!r}")
    return Command(f"TC{mode}", _LINE)


def _safe_text(text: str, what: str, limit: int) -> str:
    if not isinstance(text, str):
        raise InvalidArgument(f"{what}: {text!r} is not a string")
    bad = _UNSAFE.search(text)
    if bad is not None:
        raise InvalidArgument(
            f"{what}: character {bad.group()!r} cannot be sent "
            "(no ';', quotes, backslash, control or non-ASCII characters)"
        )
    if len(text) > limit:
        raise InvalidArgument(f"{what}: {len(text)} characters, the limit is {limit}")
    return text


def mg(text: str, *, model: ModelSpec | None = None) -> Command:
    """MG "text": print a message (the controller answers with that line).

    Refused: ``?`` (TC 54), braces, a leading ``:`` (it would read as an acknowledgement),
    and anything :func:`_safe_text` refuses; longer than the model's MG limit.
    """
    limit = 72 if model is None else model.mg_max
    _safe_text(text, "MG text", limit)
    if "?" in text or "{" in text or "}" in text:
        raise InvalidArgument(f"MG text {text!r}: '?' and braces are not allowed in a message")
    if text.startswith(":"):
        raise InvalidArgument(f"MG text {text!r} would start a line with ':'")
    return Command(f'MG "{text}"', _LINE)


def mg_operand(*names: str, formatted: bool = True) -> Command:
    """MG of operands or variables, each in :data:`READ_FORMAT` so no ``VF`` can change what
    is read: ``mg_operand("_TPA")`` -> ``MG _TPA{Z10.4}`` (one line reply). With
    ``formatted=False``, the items alone (``MG _TPA``): what the default ``VF 10.4`` prints,
    for a reader that checks the reply and asks again formatted when it may not be that
    (:func:`~galil.protocol.numbers.parse_plain_read`)."""
    if not names:
        raise InvalidArgument("mg_operand needs at least one operand")
    for name in names:
        if not isinstance(name, str) or _OPERAND.fullmatch(name) is None:
            raise InvalidArgument(f"not an operand or variable name: {name!r}")
    fmt = READ_FORMAT if formatted else ""
    return Command("MG " + ",".join(n + fmt for n in names), _LINE)


def mg_operand_lines(
    names: Sequence[str], line_length: int = 80, *, formatted: bool = True
) -> list[Command]:
    """As few ``MG`` lines as hold ``names`` within ``line_length`` (one reply line each),
    each item in :data:`READ_FORMAT` unless not ``formatted`` (see :func:`mg_operand`).

    Each line's reply has one number per name, in order; several lines go out pipelined.
    """
    key = tuple(names)
    try:
        hash(key)
    except TypeError:  # something that is not a name: refused with the reason
        return list(_build_mg_lines(key, line_length, formatted))
    return list(_cached_mg_lines(key, line_length, formatted))


def _build_mg_lines(
    names: tuple[str, ...], line_length: int, formatted: bool
) -> tuple[Command, ...]:
    limit = line_length - 4  # "MG " and the CR
    extra = (len(READ_FORMAT) if formatted else 0) + 1  # each item's format and its comma
    batches: list[list[str]] = [[]]
    length = 0
    for n in names:
        if batches[-1] and length + len(n) + extra > limit:
            batches.append([])
            length = 0
        batches[-1].append(n)
        length += len(n) + extra
    return tuple(mg_operand(*b, formatted=formatted) for b in batches if b)


# The same few sets of operands are read again and again (a move's state, a handle's poll):
# each is built and checked once. A refused name raises every time (nothing is cached then).
_cached_mg_lines = functools.lru_cache(maxsize=1024)(_build_mg_lines)


def tm(period_us: float, *, model: ModelSpec | None = None) -> Command:
    """TM: servo sample period in µs (the model's range and step; refused where it is fixed).

    Without a model the widest range any firmware takes (31.25 .. 20000, "fast firmware").
    """
    if model is not None and not model.tm_adjustable:
        raise InvalidArgument(
            f"{model.name} has a fixed sample period; TM cannot be set", model=model.name
        )
    low, high = (31.25, 20000.0) if model is None else model.tm_range
    text = _ranged(period_us, low, high, "TM")
    if model is not None:
        model.tm_setting(float(text))  # (off the model's step: refused)
    return Command("TM " + text)


def cw(mode: int | None = None, drop: int | None = None) -> Command:
    """CW: unsolicited characters with high bit set (1) or clear (2); ``drop`` 0 pause, 1 drop."""
    if mode is None and drop is None:
        raise InvalidArgument("CW needs a mode or a drop setting")
    if mode is not None and (isinstance(mode, bool) or mode not in (1, 2)):
        raise InvalidArgument(f"CW mode is 1 or 2, not {mode!r}")
    if drop is not None and (isinstance(drop, bool) or drop not in (0, 1)):
        raise InvalidArgument(f"CW drop setting is 0 or 1, not {drop!r}")
    first = "" if mode is None else str(mode)
    return Command(f"CW {first}" + ("" if drop is None else f",{drop}"))


def eo(enable: int) -> Command:
    """EO: echo off (0) or on (1)."""
    if isinstance(enable, bool) or enable not in (0, 1):
        raise InvalidArgument(f"EO takes 0 or 1, not {enable!r}")
    return Command(f"EO {enable}")


def lz(enable: int) -> Command:
    """LZ: leading zeros in replies off (1, zeros removed) or on (0)."""
    if isinstance(enable, bool) or enable not in (0, 1):
        raise InvalidArgument(f"LZ takes 0 or 1, not {enable!r}")
    return Command(f"LZ {enable}")


def vf(digits: int, decimals: int) -> Command:
    """VF: the format of variables, array elements and ``MG`` (``vf(10, 4)`` -> ``VF 10.4``,
    the default; negative ``digits`` print hex).

    Raises:
        InvalidArgument: ``digits`` outside -8..10 or ``decimals`` outside 0..4 (the DMC-4103
            reference's ranges).
    """
    for value, low, high, what in ((digits, -8, 10, "digits"), (decimals, 0, 4, "decimals")):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise InvalidArgument(f"VF {what} must be a whole number {low}..{high}, not {value!r}")
    return Command(f"VF {digits}.{decimals}")


def qz() -> Command:
    """QZ: data-record sizes (axes, general, coordinated, per-axis bytes)."""
    return Command("QZ", _LINE)


def qr(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """QR: one binary data record then ``:``; the size comes from the model or the header."""
    letters = _axis_list(axes, model, "ISTN")
    size = model.record_size if model is not None and not letters else None
    return Command(f"QR {letters}" if letters else "QR", Expect.record(size))


def dr(period: int, handle: int | None = None, *, model: ModelSpec | None = None) -> Command:
    """DR: push a data record every ``period`` samples to Ethernet handle ``handle`` (0-7).

    ``dr(0)`` stops the stream. The period must be 0 or within the model's ``dr_range``.

    Raises:
        InvalidArgument: ``model`` takes ``DR n`` as an exponent (``2**n`` samples: the PCI
            DMC-18xx, ``ModelSpec.dr_exponent``): no period form is built for it (its record
            comes over the bus, not a second Ethernet handle: send ``DR n`` raw if needed).
    """
    if model is not None and model.dr_exponent:
        raise InvalidArgument(
            f"{model.name} takes DR n as an exponent (a record every 2**n samples, the PCI"
            " DMC-18xx form), which this builder does not make: send it raw"
            " (controller.command('DR 3'))",
            model=model.name,
        )
    low, high = (1, 65535) if model is None else model.dr_range
    n = whole(period)
    if n is None:
        raise InvalidArgument(f"DR period is a whole number of samples, not {period!r}")
    period = n
    if period != 0:
        _ranged(period, low, high, "DR period", integer=True)
    if handle is None:
        return Command(f"DR {period}")
    return Command(f"DR {period},{_ranged(handle, 0, 7, 'DR handle', integer=True)}")


def time_stamp() -> Command:
    """``MG TIME{Z10.4}``: the controller's sample counter, sent on the line of a motion
    command (in :data:`READ_FORMAT`, so no ``VF`` can change it)."""
    return _TIME


def ih_close(handle: int | str) -> Command:
    """IH: close an Ethernet handle: ``"A"``-``"H"`` (or 0-7) that handle, ``"S"`` the one the
    command is sent on (``IHm=>-1``). The form is from driver code (gclib's HwIO and the
    EPICS driver close handles with ``IHS=>-1`` and ``IHT=>-1``), not from a manual page."""
    if isinstance(handle, int) and not isinstance(handle, bool):
        letter = "ABCDEFGH"[int(_ranged(handle, 0, 7, "handle", integer=True))]
    elif isinstance(handle, str) and len(handle) == 1 and handle.upper() in "ABCDEFGHS":
        letter = handle.upper()
    else:
        raise InvalidArgument(f"an Ethernet handle is a letter A-H or S, or 0-7, not {handle!r}")
    return Command(f"IH{letter}=>-1")


def th() -> Command:
    """TH: Ethernet handles (several lines)."""
    return Command("TH", Expect.DATA)


def identify() -> Command:
    """``^R^V`` (bytes 0x12 0x16): model and firmware, e.g. ``DMC4040 Rev 1.2f``."""
    return Command("\x12\x16", _LINE)


# --------------------------------------------------------------------------------- programs, arrays


def _variable_name(name: str, what: str = "variable") -> str:
    if not isinstance(name, str) or _VAR.fullmatch(name) is None:
        raise InvalidArgument(
            f"{what} name {name!r}: a letter then up to "
            f"{_DEFAULT_NAMES.variable_length - 1} letters or digits"
        )
    # "SPA" or "CD0" would parse as a command; "SPEEDZ" repeats letters, so it cannot be an
    # axis list and the firmware reads it as a name. A command is two upper-case letters
    # ("data", "Data" are names), what follows it is compared in any case ("SPa" is refused:
    # whether the firmware takes a lower-case axis letter is not documented).
    head, rest = name[:2], name[2:].upper()
    looks_like_args = (
        not rest
        or rest.isdigit()
        or (_AXIS_SUFFIX.fullmatch(rest) is not None and len(set(rest)) == len(rest))
    )
    if name in _KEYWORDS:
        raise InvalidArgument(f"{what} name {name!r} is the controller's keyword {name}")
    if head in COMMAND_NAMES and looks_like_args:
        raise InvalidArgument(
            f"{what} name {name!r} clashes with the command {head} "
            f"(the controller would read {name}= as that command; "
            f"a lower-case name such as {name.lower()!r} is not one)"
        )
    return name


def assign(name: str, value: float) -> Command:
    """Variable assignment ``name=value`` (Galil name rules; no command clash like ``CD0``)."""
    return Command(f"{_variable_name(name)}={format_number(_number(value, name))}")


def stamp(name: str) -> Command:
    """``name=TIME``: store the controller's sample counter in a variable (a heartbeat)."""
    return Command(f"{_variable_name(name)}=TIME")


def _label(label: str) -> str:
    if not isinstance(label, str) or _LABEL.fullmatch(label) is None:
        hint = ""
        if isinstance(label, str) and _LABEL.fullmatch(f"#{label}") is not None:
            hint = f" (did you mean '#{label}'?)"  # the program's own text has the '#'
        raise InvalidArgument(
            f"label {label!r}: '#', a letter, then up to "
            f"{_DEFAULT_NAMES.label_length - 1} letters or digits{hint}"
        )
    return label


def xq(label: str = "", thread: int | None = None) -> Command:
    """XQ: execute the program from ``label`` (``"#A"``) in ``thread`` (0-7)."""
    text = "XQ"
    if label:
        text += " " + _label(label)
    if thread is not None:
        t = _counted(thread, 0, 7, "XQ thread")
        text += f",{t}" if label else f" ,{t}"
    return Command(text)


def hx(thread: int | None = None) -> Command:
    """HX: halt program thread ``thread`` (``None``: all)."""
    if thread is None:
        return Command("HX")
    return Command("HX" + _counted(thread, 0, 7, "HX thread"))


def dl(program: str | Sequence[str], *, model: ModelSpec | None = None) -> Command:
    """DL: download a program (replaces the controller's program); the reply is ``::``.

    Lines may hold any printable ASCII but no backslash (it ends the download); empty lines are
    refused because the firmware rejects them (write ``'`` for a blank comment line).
    """
    lines = program.splitlines() if isinstance(program, str) else list(program)
    if not lines:
        raise InvalidArgument("DL: the program is empty")
    limit = 80 if model is None else model.line_length
    for i, line in enumerate(lines, 1):
        if not isinstance(line, str):
            raise InvalidArgument(f"DL line {i}: {line!r} is not a string")
        bad = re.search(r"[^\x20-\x7e]|\\", line)
        if bad is not None:
            raise InvalidArgument(f"DL line {i}: character {bad.group()!r} cannot be downloaded")
        if not line.strip():
            raise InvalidArgument(f"DL line {i} is empty; the controller rejects empty lines")
        if len(line) > limit:
            raise InvalidArgument(f"DL line {i}: {len(line)} characters, the limit is {limit}")
    payload = ("\r".join(lines) + "\r\\").encode("ascii")
    return Command("DL", Expect.DOUBLE_ACK, payload)


def ul() -> Command:
    """UL: upload the program; text, ^Z, then ``:``."""
    return Command("UL", Expect.CTRL_Z)


def _array_range(first: int | None, last: int | None) -> str:
    if first is None and last is None:
        return ""
    lo = _counted(0 if first is None else first, 0, 999_999, "first index")
    if last is None:
        return f",{lo}"
    hi = _counted(last, int(lo), 999_999, "last index")
    return f",{lo},{hi}"


def qu(name: str, first: int | None = None, last: int | None = None, delim: int = 1) -> Command:
    """QU: upload array ``name`` (elements ``first``..``last``); ends with ^Z then ``:``."""
    _variable_name(name, "array")
    if isinstance(delim, bool) or delim not in (0, 1):
        raise InvalidArgument(f"QU delimiter is 0 (CR) or 1 (comma), not {delim!r}")
    rng = _array_range(first, last)
    if not rng:
        rng = ",,"
    elif rng.count(",") == 1:
        rng += ","
    return Command(f"QU {name}[]{rng},{delim}", Expect.CTRL_Z)


def qd(name: str, values: Sequence[float], first: int | None = None) -> Command:
    """QD: download ``values`` into array ``name`` from index ``first``; one ``:`` at the end."""
    _variable_name(name, "array")
    if len(values) == 0:
        raise InvalidArgument("QD: no values")
    start = 0 if first is None else int(_counted(first, 0, 999_999, "first index"))
    data = ",".join(format_number(_number(v, f"{name}[{start + i}]")) for i, v in enumerate(values))
    text = f"QD {name}[],{start},{start + len(values) - 1}"
    return Command(text, _ACK, (data + "\\").encode("ascii"))


def variable_name(name: str) -> str:
    """``name`` if it is a valid variable name (letter, up to 7 more letters or digits, no
    clash with an upper-case command such as ``CD0``: ``data`` is a name, ``DA`` is not),
    else :class:`InvalidArgument`."""
    return _variable_name(name)


def array_name(name: str) -> str:
    """``name`` if it is a valid array name (the variable rules), else :class:`InvalidArgument`."""
    return _variable_name(name, "array")


def dm(name: str, size: int, *, model: ModelSpec | None = None) -> Command:
    """DM: dimension array ``name`` with ``size`` elements (the model's array space)."""
    _variable_name(name, "array")
    most = 24_000 if model is None else model.array_elements
    n = _counted(size, 1, most, f"DM {name}[] size", None if model is None else model.name)
    return Command(f"DM {name}[{n}]")


def da(*names: str) -> Command:
    """DA: deallocate arrays (``da("pos")`` -> ``DA pos[]``)."""
    if not names:
        raise InvalidArgument("DA needs at least one array name")
    return Command("DA " + ",".join(f"{_variable_name(n, 'array')}[]" for n in names))


def da_variables(*names: str) -> Command:
    """DA: deallocate variables (``da_variables("gain")`` -> ``DA gain``; the DMC-4103
    reference: "str - Defined variable name")."""
    if not names:
        raise InvalidArgument("DA needs at least one variable name")
    return Command("DA " + ",".join(_variable_name(n) for n in names))


def la() -> Command:
    """LA: list the arrays (one ``name[size]`` line each; a bare ``:`` when there is none)."""
    return Command("LA", Expect.ANY)


def lv() -> Command:
    """LV: list the variables (one ``name= value`` line each; a bare ``:`` when none)."""
    return Command("LV", Expect.ANY)


# The operands RD records, one table for the library and its simulator (whose RD checks with
# record_source too). Per axis: _TP _TE _DE _TS _SC _TT, from the RD sources the DMC-1600/1700/
# 1800 manuals list; _RP and _TV as listed on the 40x0 (decision 0018: unconfirmed on the other
# families). _TI and _OP are the input and output banks, taken with their bank as every other
# use of the operands takes them (_TI0; the bank in an RD argument is unsourced). The manuals
# list _SH, _RL, _NO and _AF too; they are refused (decision 0097): _SH has no operand on
# today's controllers, _NO is the threads' mask there, not an axis's, _AF reads the AF setting,
# and a latched position (_RL) needs the latch the simulator does not model. TIME, the
# controller's sample, is taken as the simulator records it (unsourced, decision 0018).
_RECORD_AXIS = frozenset({"DE", "TP", "TE", "TS", "SC", "TT", "RP", "TV"})
_RECORD_REFUSED = frozenset({"SH", "RL", "NO", "AF"})
_RECORD_SOURCE = re.compile(r"_([A-Z]{2})([A-H])|_(TI|OP)(\d)")


def record_source(source: str, *, model: ModelSpec | None = None) -> str:
    """``source`` if ``RD`` can record it (``"_RPA"``, ``"_TEB"``, ``"_TI0"``, ``"TIME"``), else
    :class:`InvalidArgument` (decision 0097)."""
    if source == "TIME":
        return source
    m = _RECORD_SOURCE.fullmatch(source) if isinstance(source, str) else None
    if m is None or (m.group(1) is not None and m.group(1) not in _RECORD_AXIS):
        known = ", ".join(f"_{op}A" for op in sorted(_RECORD_AXIS))
        why = ""
        if m is not None and m.group(1) in _RECORD_REFUSED:
            why = " (listed by the old manuals, unsettled on today's controllers: decision 0097)"
        elif isinstance(source, str) and source in ("_TI", "_OP"):
            why = f" (give the bank: {source}0)"
        raise InvalidArgument(
            f"cannot record {source!r:.40}{why}: RD records {known} (any axis), the input"
            " and output banks _TI0, _OP0 ..., and TIME"
        )
    if m.group(2) is not None:
        _axes(model).position(m.group(2))
    return source


def ra(*names: str, model: ModelSpec | None = None) -> Command:
    """RA: the arrays ``RD``'s sources are recorded into, in order."""
    most = 8 if model is None else model.record_arrays
    if not 1 <= len(names) <= most:
        raise InvalidArgument(f"RA takes 1 to {most} arrays, not {len(names)}")
    return Command("RA " + ",".join(f"{_variable_name(n, 'array')}[]" for n in names))


def rd(*sources: str, model: ModelSpec | None = None) -> Command:
    """RD: the operands to record (``rd("_RPA", "_TPA")``), one per ``RA`` array."""
    most = 8 if model is None else model.record_arrays
    if not 1 <= len(sources) <= most:
        raise InvalidArgument(f"RD takes 1 to {most} sources, not {len(sources)}")
    return Command("RD " + ",".join(record_source(s, model=model) for s in sources))


def rc(every: int, count: int | None = None, *, model: ModelSpec | None = None) -> Command:
    """RC: record every ``every`` samples (a power of two in the model's range), ``count``
    values (default: as many as the smallest array holds); ``rc(0)`` stops recording."""
    n = whole(every)
    if n is None:
        raise InvalidArgument(f"RC interval is a whole number of samples, not {every!r}")
    every = n
    if every == 0:
        return Command("RC 0")
    lo, hi = (1, 8) if model is None else model.record_exponents
    if every < 1 or every & (every - 1) or not lo <= every.bit_length() - 1 <= hi:
        allowed = ", ".join(str(1 << n) for n in range(lo, hi + 1))
        raise InvalidArgument(
            f"the controller records every 2**n samples: every={every!r} is not one of {allowed}",
            model=None if model is None else model.name,
        )
    text = f"RC {every.bit_length() - 1}"
    if count is not None:
        most = 24_000 if model is None else model.array_elements
        text += "," + _counted(count, 1, most, "RC count")
    return Command(text)


def ui(n: int, *, model: ModelSpec | None = None) -> Command:
    """UI: raise user interrupt ``n`` (status byte ``0xF0 + n``)."""
    top = 16 if model is None else model.user_interrupts
    return Command("UI " + _ranged(n, 0, top - 1, "UI", integer=True))


def ei(mask: int, inputs: int | None = None, handle: int | None = None) -> Command:
    """EI: enable interrupts: ``mask`` of events (bits 0-7 an axis done, 8 all done, 9
    position error, 10 limit switch, 11 reserved), ``inputs`` (bit n: input n+1 going low)
    and the Ethernet ``handle`` (0-7 for A-H) they are sent to. ``ei(0)`` turns them off."""
    text = "EI " + _ranged(mask, 0, 0xFFFF, "EI mask", integer=True)
    if inputs is not None or handle is not None:
        text += "," + (
            "" if inputs is None else _ranged(inputs, 0, 0xFF, "EI inputs", integer=True)
        )
    if handle is not None:
        text += "," + _ranged(handle, 0, 7, "EI handle", integer=True)
    return Command(text)


# --------------------------------------------------------------------------------- lines


_SPECIAL = (ReplyKind.RECORD, ReplyKind.DOUBLE_ACK, ReplyKind.CTRL_Z)


def pack(commands: Iterable[Command], limit: int | ModelSpec = 80) -> list[Command]:
    """Join commands into compound lines (``PRA=1;BGA``) no longer than the line limit.

    The limit counts the terminating CR. Commands with a payload or a special reply (QR, DL,
    UL, QU, QD, ^R^V) go on a line of their own.

    Raises:
        InvalidArgument: a single command is already longer than the limit.
    """
    if isinstance(commands, Command):  # a named tuple is iterable: catch the slip here
        raise InvalidArgument("pack() takes a sequence of commands, not one Command")
    maximum = limit if isinstance(limit, int) else limit.line_length
    lines: list[Command] = []
    group: list[Command] = []
    length = 0

    def flush() -> None:
        if len(group) == 1:
            lines.append(group[0])
        elif group:
            lines.append(Command(";".join(c.text for c in group), Expect.ANY, b"", tuple(group)))
        group.clear()

    for cmd in commands:
        if cmd.parts:
            raise InvalidArgument("pack() takes single commands, not compound lines")
        size = len(cmd.text) + 1
        if size > maximum:
            raise InvalidArgument(f"{cmd.text!r} is longer than the {maximum}-character line limit")
        alone = bool(cmd.payload) or cmd.expect.kind in _SPECIAL or cmd.text.startswith("\x12")
        if alone:
            flush()
            lines.append(cmd)
            length = 0
            continue
        if group and length + size > maximum:
            flush()
            length = 0
        group.append(cmd)
        length += size
    flush()
    return lines


_QUERIES = frozenset(
    {
        "TP",
        "TV",
        "TE",
        "RP",
        "TD",
        "TS",
        "SC",
        "TC",
        "MG",
        "QZ",
        "TH",
        "ID",
        "LS",
        "TB",
        "TI",
        "TT",
        "WH",
    }
)


def split_commands(text: str) -> list[str]:
    """Split a command line at the ``;`` outside double quotes (``MG "a;b";TP`` is two)."""
    return _split_outside_quotes(text, ";")


def _split_outside_quotes(text: str, separator: str) -> list[str]:
    """Split ``text`` at each ``separator`` outside double quotes."""
    parts: list[str] = []
    start = 0
    quoted = False
    for i, ch in enumerate(text):
        if ch == '"':
            quoted = not quoted
        elif ch == separator and not quoted:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return parts


def parse_line(text: str) -> Command:
    """Turn a raw command line (``"PRA=1;MG _TPA"``) into a :class:`Command`.

    Each sub-command's reply shape is inferred: ``QR`` is a record, ``UL``/``QU`` end with
    ^Z, known queries and ``?`` interrogations return data, anything else may return either.

    Raises:
        InvalidArgument: CR, LF or non-ASCII in the line, or ``DL``/``QD`` (use their builders).
    """
    if not isinstance(text, str) or not text.isascii():
        raise InvalidArgument(f"command line {text!r} must be ASCII text")
    if "\r" in text or "\n" in text:
        raise InvalidArgument(f"command line {text!r} must not contain CR or LF")
    pieces = split_commands(text)
    parts = tuple(_raw_command(p) for p in pieces)
    if len(parts) == 1:
        return parts[0]
    return Command(text, Expect.ANY, b"", parts)


# Raw commands that change the link's own settings or reset the controller (decision 0031):
# the first two letters are looked at only on a line's first parse (the link caches parses).
_LINK_SETTINGS = frozenset({"RS", "CW", "EO", "CF", "IH", "BN"})
_COMMAND_NAME = re.compile(r"[A-Z]{2}[A-Za-z0-9]*")
_CLOSES_OWN_HANDLE = re.compile(r"[ST]\s*=\s*>")
_WHY_REFUSED = {
    "RS": "RS resets the controller, and with it what the link set up at connect (CW 1 or "
    "the message handle, EO 0, DR streams, interrupts, the library's routines): use "
    "controller.reset(), which sets them up again and tells the library what RS undid",
    "^R^S": "^R^S (master reset) returns the controller to its factory settings and resets "
    "it; the library does not send it: use Galil's own tools, then controller.reconnect()",
    "CW": "{cmd!r} changes how unsolicited output is marked, which the link chose at "
    "connect (and restores at close); read it with MG _CW; for unmarked output, "
    "connect(..., unsolicited=False)",
    "EO": "{cmd!r} switches the echo the link handles (set at connect, restored at close); "
    "read it with MG _EO; to keep the echo, connect(..., echo=True)",
    "CF": "{cmd!r} sends unsolicited output away from where the link reads it (its "
    "message handle, or the command link marked with CW 1); read it with MG _CF; the "
    "library routes it at connect: read the lines from controller.messages",
    "IH": "{cmd!r} closes the handle this link talks on (S), or every handle with it (T): "
    "use controller.close(); to free another handle, name it (IHC=>-1)",
    "BN": "{cmd!r} would burn the link's own CW 1 and EO 0 with the parameters: use "
    "controller.save(), which burns the controller's own (decision 0057)",
}


def link_setting(text: str) -> str | None:
    """Why a raw command must not be sent by hand, or ``None`` (decision 0031).

    Refused: ``RS`` and ``^R^S`` (they reset the controller under the link), ``CW``, ``EO``
    and ``CF`` with a setting (the link's own: queries such as ``CW ?`` or ``EO ?`` pass), and
    ``IHS=>``/``IHT=>`` (they close the link's own handle), ``BN`` (it would burn the link's
    settings: decision 0057). A variable whose name only starts
    like one of them (``RSVAL=1``) is not that command.
    """
    s = text.lstrip()
    if s.startswith("\x12\x13"):
        return _WHY_REFUSED["^R^S"]
    head = s[:2]
    if head not in _LINK_SETTINGS:
        return None
    found = _COMMAND_NAME.match(s)
    name = found.group() if found is not None else head
    suffix = name[2:]
    if suffix and _AXIS_SUFFIX.fullmatch(suffix) is None and not (head == "CF" and suffix == "I"):
        return None  # a variable named like the command (CF's handle may also be I)
    args = s[2:].strip()
    refused = (
        head in ("RS", "BN")
        or (head == "CW" and args not in ("", "?", "0"))
        or (head in ("EO", "CF") and args != "?")
        or (head == "IH" and _CLOSES_OWN_HANDLE.match(args) is not None)
    )
    return _WHY_REFUSED[head].format(cmd=s.rstrip()) if refused else None


# A raw line refused as unrecognised (TC 1): words and quoted strings, and the ';' between
# commands. A word at a command's head is a command; after it, an operand (_TPA), a function
# (@ABS), a keyword, an axis list (BG a) or a variable, whose name is case sensitive (0060).
_TOKEN = re.compile(r'"[^"]*"?|(?<![\w.$])[_@#]?[A-Za-z][A-Za-z0-9]*|;')  # (not 1e3, $ff)
_AXES_ONLY = re.compile(r"[A-HSTXYZW]{1,8}")


def unrecognized_hint(text: str) -> str | None:
    """What to say of lower case in a raw line the controller refused as unrecognised: the
    line with its commands, operands and keywords in upper case, when one of them was not;
    else the lower-case names that can only be variables, which none of is defined (variable
    names are case sensitive: upper-casing them would name another variable). ``None`` when
    lower case is not to blame."""
    out: list[str] = []
    unknown: list[str] = []
    last, head, command = 0, True, ""
    for m in _TOKEN.finditer(text):
        word = m.group()
        out.append(text[last : m.start()])
        last = m.end()
        known = _known_word(word.upper(), head, command)
        if head and word != ";":
            command = word.upper() if known else ""
        at_head, head = head, word == ";"
        if word.startswith(('"', "#")) or word == word.upper():
            out.append(word)
        elif known:
            out.append(word.upper())
        else:
            out.append(word)
            assigned = text[last:].lstrip().startswith(("=", "["))
            if not (at_head and assigned):  # (x=1 makes x: no name is missing there)
                unknown.append(word)
    out.append(text[last:])
    suggestion = "".join(out)
    if suggestion != text:
        return f"Galil commands and operands are upper case: did you mean {suggestion!r}?"
    names = list(dict.fromkeys(unknown))
    if not names:
        return None
    which = (  # (which of several is missing, the refusal does not say)
        f"no command, operand or variable {names[0]!r}"
        if len(names) == 1
        else f"one of {', '.join(repr(n) for n in names)} is no command, operand or variable"
    )
    return (
        f"{which} on the controller: variable names are case sensitive, and variables.list() "
        "names those there"
    )


def _known_word(upper: str, head: bool, command: str) -> bool:
    """Whether ``upper`` (a word in upper case) is the controller's: a command at a head, an
    operand, a function or keyword anywhere, an axis list after a command but MG."""
    if upper.startswith("_"):
        return upper[1:3] in COMMAND_NAMES
    if upper.startswith("@") or upper in _KEYWORDS:
        return True
    if head:
        rest = upper[2:]
        return upper[:2] in COMMAND_NAMES and (not rest or _AXIS_SUFFIX.fullmatch(rest) is not None)
    return command not in ("", "MG") and _AXES_ONLY.fullmatch(upper) is not None


def _raw_command(text: str) -> Command:
    head = text.lstrip().upper()[:2]
    if _variable_named_like(text.lstrip(), head):
        return Command(text, Expect.ANY)
    if head in ("DL", "QD"):
        raise InvalidArgument(f"{head} needs a payload; use commands.{head.lower()}()")
    if head == "QR":
        return Command(text, Expect.record(None))
    if head in ("UL", "QU"):
        return Command(text, Expect.CTRL_Z)
    if head == "MG":
        why = _mg_unframed(text)
        if why is not None:
            raise InvalidArgument(f"{text.strip()!r}: {why}")
    if head in _QUERIES or text.startswith("\x12\x16"):
        return Command(text, Expect.DATA)
    return Command(text, Expect.ANY)


# What an MG prints that the reply framing cannot cut (decision 0090; the formats from the
# MG entry of the command reference, /work/shared/reference/galil-protocol.md): {N} drops the
# CR LF, so the ':' that ends the reply starts no line; {^n} prints the byte n.
_MG_NO_CRLF = re.compile(r"\{\s*N\s*\}", re.IGNORECASE)
_MG_BYTE = re.compile(r"\{\s*\^\s*(\d+)\s*\}")
_QUOTED_TEXT = re.compile(r'"([^"]*)"?')
#: Bytes the framing reads as a reply's end or a rejection at a line's start, as a line's
#: end, or (bit 7 set) as unsolicited output.
_FRAMING_BYTES = {10: "LF", 13: "CR", 58: "':'", 63: "'?'"}


def _mg_unframed(text: str) -> str | None:
    """Why the raw ``MG`` line ``text`` prints what the link cannot cut into its reply, or
    ``None``: ``{N}`` (no CR LF: the reply never ends), a ``?`` in a string (the controller
    refuses it, TC 54; one that starts a line reads as a rejection), a line that starts with
    ``:`` (read as the reply's end), ``{^n}`` of ``:``, ``?``, CR, LF or a byte of 128 and
    more (read as unsolicited output)."""
    # Formats are looked for inside strings too: whether the controller prints a brace in a
    # string as it is is not in the sources [A] (the simulator reads it as a format; mg()
    # refuses braces in a message for that).
    if _MG_NO_CRLF.search(text):
        return (
            "{N} leaves out the CR LF, so the ':' that ends the reply starts no line and the "
            "link cannot tell where the reply ends; send it without {N} (a program may use it)"
        )
    strings = _QUOTED_TEXT.findall(text)
    if any("?" in x for x in strings):
        return "a '?' inside an MG string is refused by the controller (TC 54)"
    for match in _MG_BYTE.finditer(text):
        code = int(match.group(1))
        if code in _FRAMING_BYTES or code >= 128:
            what = _FRAMING_BYTES.get(code, "a byte with bit 7 set (unsolicited output)")
            return f"{match.group()} prints {what}, which the link reads as part of the framing"
    if _first_printed(text).startswith(":"):
        return "the line it prints starts with ':', which the link reads as the reply's end"
    return None


def _first_printed(text: str) -> str:
    """The text the MG line prints first: its leading string arguments, joined (the
    controller prints strings back to back)."""
    body = text.lstrip()[2:]
    printed = ""
    for argument in _split_arguments(body):
        item = argument.strip()
        if not (item.startswith('"') and _QUOTED_TEXT.fullmatch(item)):
            break
        printed += item.strip('"')
        if printed:
            break
    return printed


def _split_arguments(text: str) -> list[str]:
    """Split at the ``,`` outside double quotes (``"a,b", 1`` is two)."""
    return _split_outside_quotes(text, ",")


#: Commands that take no axis letters after their name: any name that only begins like them
#: is a variable's (``ULIM=5``, ``DLY=2``).
_BARE = frozenset({"DL", "QD", "UL", "QU"})


def _variable_named_like(text: str, head: str) -> bool:
    """Whether ``text`` begins with a variable (or array) whose name only begins like the
    command ``head``, or assigns to one: ``ULIM=5``, ``QRX=2``, ``TPOS=1``, ``TP2[3]=0`` are no
    ``UL``, ``QR`` or ``TP`` (their replies are a ``:`` or a value, never a transfer or a
    record)."""
    if head not in _BARE and head != "QR" and head not in _QUERIES:
        return False
    found = _COMMAND_NAME.match(text)
    if found is None:
        return False
    suffix = found.group()[2:]
    rest = text[found.end() :].lstrip()
    if rest.startswith("[") or (rest.startswith("=") and not rest.startswith("=?")):
        return True  # an array element, or an assignment: no transfer, record or query
    if not suffix:
        return False
    return head in _BARE or _AXIS_SUFFIX.fullmatch(suffix) is None


# ------------------------------------------------------- homing, switches, I/O, loop settings
# Builders for issue 11 (decision 0015). Ranges come from the model (galil.models); without
# one, the DMC-40x0 defaults of ModelSpec apply.

_DEFAULT_SPEC = ModelSpec("DMC", "DMC", "ABCDEFGH")


def hm(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """HM: arm the homing sequence on ``axes`` (``BG`` starts it; stop code 10 at its end)."""
    return _plain(_list_command("HM", axes, model))


def fe(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """FE: arm find-edge on ``axes`` (``BG`` starts it; stop code 9 at the home input's edge)."""
    return _plain(_list_command("FE", axes, model))


def fi(axes: str | Iterable[str] = "", *, model: ModelSpec | None = None) -> Command:
    """FI: arm find-index on ``axes`` (``BG`` starts it at ``JG``; stop code 10 at the index)."""
    return _plain(_list_command("FI", axes, model))


def _setting(
    mnemonic: str,
    by_axis: dict[str, object],
    model: ModelSpec | None,
    check: _Checker | Callable[[object, str], str],
) -> Command:
    """A per-axis setting in the ``KPA=10`` form (one axis) or ``KP 10,,5`` (several)."""
    if not by_axis:
        raise InvalidArgument(f"{mnemonic}: no value given (e.g. {mnemonic.lower()}(A=1))")
    table = _axes(model)
    fields: list[str] = [""] * table.nax
    for letter, value in by_axis.items():
        idx = table.position(letter)
        if fields[idx]:
            raise InvalidArgument(f"{mnemonic}: axis {letter!r} given twice")
        fields[idx] = check(value, table.ordered[idx])
    if len(by_axis) == 1:
        ((letter, _),) = by_axis.items()
        return _plain(f"{mnemonic}{table.ordered[table.position(letter)]}={''.join(fields)}")
    while fields and not fields[-1]:
        fields.pop()
    return _plain(f"{mnemonic} {','.join(fields)}")


def _range_check(
    name: str, lo: float, hi: float, model: ModelSpec | None, *, integer: bool = False
) -> _Checker:
    return _Checker(name, lo, hi, model, integer=integer)


def hv(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """HV: homing speed in counts/s (stages 2 and 3 of HM, the return of FI): 0 .. SP max.
    Stepped as SP (sent at or just beyond its step, :func:`_away`).

    Raises:
        InvalidArgument: the model has no HV (``ModelSpec.has_hv``: the Optima-era cards, whose
            HM runs its slow stages at ``home_slow_speed``).
    """
    require_hv(model)
    spec = model or _DEFAULT_SPEC
    check = _Checker("HV", 0, spec.sp_max, model, integer=False, stepped=True)
    return _setting("HV", by_axis, model, check)


def kp(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """KP: proportional gain, 0 .. ``model.kp_max`` (1023.875 on the 40x0)."""
    spec = model or _DEFAULT_SPEC
    return _setting("KP", by_axis, model, _range_check("KP", 0, spec.kp_max, model))


def ki(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """KI: integral gain, 0 .. ``model.ki_max`` (255.999 on the 40x0, 2047.992 on the 21x3,
    2047.875 on the Optima DMC-1700/1800 and 18x2)."""
    spec = model or _DEFAULT_SPEC
    return _setting("KI", by_axis, model, _range_check("KI", 0, spec.ki_max, model))


def kd(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """KD: derivative gain, 0 .. ``model.kd_max`` (4095.875)."""
    spec = model or _DEFAULT_SPEC
    return _setting("KD", by_axis, model, _range_check("KD", 0, spec.kd_max, model))


def ks(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """KS: stepper smoothing, ``model.ks_range`` (0.25 .. 64 on the 40x0, 0.5 .. 64 on the
    41x3)."""
    lo, hi = (model or _DEFAULT_SPEC).ks_range
    return _setting("KS", by_axis, model, _range_check("KS", lo, hi, model))


def il(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """IL: integrator limit in volts, ``model.il_min`` .. ``model.il_max`` (0 .. 9.998 on the
    40x0; ±9.9982 on the 41x3, where a negative IL freezes the integrator during a move)."""
    spec = model or _DEFAULT_SPEC
    return _setting("IL", by_axis, model, _range_check("IL", spec.il_min, spec.il_max, model))


def tl(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """TL: torque limit in volts, 0 .. ``model.tl_max``."""
    spec = model or _DEFAULT_SPEC
    return _setting("TL", by_axis, model, _range_check("TL", 0, spec.tl_max, model))


def er(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """ER: position-error limit in counts, ``model.er_min`` .. ``model.er_max`` (whole counts;
    from 1 on the 40x0, from -1 on the 41x3: ER 0 turns the error output on, ER -1 off)."""
    spec = model or _DEFAULT_SPEC
    check = _range_check("ER", spec.er_min, spec.er_max, model, integer=True)
    return _setting("ER", by_axis, model, check)


def _one_of(name: str, allowed: Iterable[float], model: ModelSpec | None) -> Callable[..., str]:
    choices = sorted(set(allowed))

    def check(value: object, axis: str) -> str:
        v = _number(value, name)
        if v not in choices:
            where = f" on {model.name}" if model is not None else ""
            shown = ", ".join(format_number(c) for c in choices) or "none"
            raise InvalidArgument(
                f"{name}: {value!r} on {axis} is not one of {shown}{where}",
                model=None if model is None else model.name,
            )
        return format_number(v)

    return check


def mt(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """MT: motor type per axis, one of ``model.motor_types`` (see ``galil.models.MOTOR_TYPES``)."""
    allowed = (model or _DEFAULT_SPEC).motor_types
    return _setting("MT", by_axis, model, _one_of("MT", allowed, model))


def oe(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """OE: off-on-error, 0 off, 1 position/amplifier error or abort input, 2 limits, 3 all."""
    return _setting("OE", by_axis, model, _one_of("OE", (0, 1, 2, 3), model))


def require_hv(model: ModelSpec | None) -> None:
    """Refuse ``HV`` on a model without it (:attr:`ModelSpec.has_hv`; ``None`` passes).

    Raises:
        InvalidArgument: naming the model and the speed its HM's slow stages run at.
    """
    if model is not None and not model.has_hv:
        raise InvalidArgument(
            f"{model.name} has no HV: its HM runs the slow stages at the firmware's own speed"
            f" (about {model.home_slow_speed:g} counts/s), which cannot be set",
            model=model.name,
        )


def require_limit_disable(model: ModelSpec | None) -> None:
    """Refuse ``LD`` (and ``_LDa``) on a model without it (:attr:`ModelSpec.has_limit_disable`;
    ``None``, no model known, passes).

    Raises:
        InvalidArgument: naming the model.
    """
    if model is not None and not model.has_limit_disable:
        raise InvalidArgument(
            f"{model.name} has no LD (limit disable): the command reference lists it for the "
            "DMC-40x0, 41x3, 42x0, 18x6, 30010 and 500x0 only; its limit switches always stop "
            "motion towards them",
            model=model.name,
        )


def ld(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """LD: limit disable, 0 both switches stop motion, 1 the forward switch disabled, 2 the
    reverse one, 3 both (``FL``/``BL`` soft limits stay). Refused on a model without LD."""
    require_limit_disable(model)
    return _setting("LD", by_axis, model, _one_of("LD", (0, 1, 2, 3), model))


def ce(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """CE: encoder configuration, 0 .. 15, the main encoder's type plus four times the
    auxiliary encoder's (0 normal quadrature, 1 normal pulse and direction, 2 reversed
    quadrature, 3 reversed pulse and direction; :class:`galil.EncoderConfig`)."""
    return _setting("CE", by_axis, model, _one_of("CE", range(16), model))


def br(*, model: ModelSpec | None = None, **by_axis: object) -> Command:
    """BR: brush setting, -1 external drive, 0 brushless, 1 brush."""
    return _setting("BR", by_axis, model, _one_of("BR", (-1, 0, 1), model))


def cn(
    limit: int | None = None,
    home: int | None = None,
    latch: int | None = None,
) -> Command:
    """CN: switch configuration: limit polarity (1 active high, -1 active low), home
    direction (1 drive forward when the home input is high, -1 reverse), latch edge.

    ``None`` leaves a field as it is (``cn(limit=1)`` -> ``CN 1``).
    """
    fields = []
    for name, value in (("limit", limit), ("home", home), ("latch", latch)):
        if value is None:
            fields.append("")
            continue
        if isinstance(value, bool) or value not in (-1, 1):
            raise InvalidArgument(f"CN {name} is 1 or -1, not {value!r}")
        fields.append(str(int(value)))
    while fields and not fields[-1]:
        fields.pop()
    if not fields:
        raise InvalidArgument("CN: no field given")
    return Command("CN " + ",".join(fields))


def _channel(n: object, first: int, count: int, what: str, model: ModelSpec | None) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise InvalidArgument(f"{what} number must be an integer, not {n!r}")
    last = first + count - 1
    if not first <= int(n) <= last:
        name = model.name if model is not None else "this model"
        span = f"{first} .. {last}" if count else "none"
        raise InvalidArgument(f"{what} {n} does not exist on {name} ({span})", model=name)
    return int(n)


def _io_counts(model: ModelSpec | None) -> ModelSpec:
    return model or _DEFAULT_SPEC


def sb(n: int, *, model: ModelSpec | None = None) -> Command:
    """SB: set digital output ``n`` (numbered from ``model.io_first``)."""
    m = _io_counts(model)
    return _plain(f"SB {_channel(n, m.io_first, m.digital_outputs, 'output', model)}")


def cb(n: int, *, model: ModelSpec | None = None) -> Command:
    """CB: clear digital output ``n``."""
    m = _io_counts(model)
    return _plain(f"CB {_channel(n, m.io_first, m.digital_outputs, 'output', model)}")


def op(*banks: int, model: ModelSpec | None = None) -> Command:
    """OP: write the outputs as banks of ``model.op_bits`` (bank 0 = the first outputs).

    8-bit banks are sourced for the RIO and for outputs 1-8; the banks past them are an
    assumption (a model's ``assumptions`` say so; the DMC-3425 manual gives extended I/O
    16-bit fields). The DMC-41x3 takes one field for all its outputs (``op_bits`` 16; the 4103
    reference: "General Outputs 1-16", at most 255 on a 1-4 axis controller).
    """
    m = _io_counts(model)
    width = min(m.op_bits, max(8, m.digital_outputs))
    nbanks = max(1, -(-m.digital_outputs // width))
    if not banks or len(banks) > nbanks:
        raise InvalidArgument(f"OP takes 1 .. {nbanks} bank values, got {len(banks)}")
    fields = [_ranged(b, 0, 2**width - 1, "OP bank", integer=True) for b in banks]
    return _plain("OP " + ",".join(fields))


def ao(n: int, volts: float, *, model: ModelSpec | None = None) -> Command:
    """AO: set analog output ``n`` to ``volts`` (the model's range; refused where none)."""
    m = _io_counts(model)
    ch = _channel(n, m.io_first, m.analog_outputs, "analog output", model)
    lo, hi = m.analog_out_range
    name = None if model is None else model.name
    return _plain(f"AO {ch},{_ranged(volts, lo, hi, 'AO', model=name)}")


def burn(what: str) -> Command:
    """BN (parameters), BP (program) or BV (variables and arrays): write flash memory."""
    if what not in ("BN", "BP", "BV"):
        raise InvalidArgument(f"burn takes 'BN', 'BP' or 'BV', not {what!r}")
    return Command(what)
