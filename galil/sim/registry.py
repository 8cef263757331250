"""The handler contract: how a room of the simulator declares its commands and operands.

A room (see :mod:`galil.sim.machine`) marks its methods with :func:`handler`, :func:`operand`
and :func:`function`; the machine collects the marks of every room into the interpreter's
tables when a controller is built. Nothing here knows which commands exist.

A handler returns its reply text (``""`` for a bare ``:``; data ends with CR LF), a
:class:`Wait` (a trippoint: the ``:`` is held until it is released), or :data:`DOWNLOAD` (the
port collects program lines). It raises :class:`~galil.sim.parse.Refused` to answer ``?``, and
must change nothing before it raises.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

__all__ = [
    "DOWNLOAD",
    "Args",
    "Collect",
    "Download",
    "FunctionSpec",
    "HandlerSpec",
    "OperandKind",
    "OperandSpec",
    "Result",
    "Wait",
    "function",
    "handler",
    "marks",
    "operand",
]


class Args(enum.Enum):
    """How the interpreter hands a command's arguments to its handler."""

    #: The raw text after the two command letters (``"1000,,-200"``, ``"#A,1"``).
    TEXT = "text"
    #: A list of axes (``BG AB``, ``TP``): ``list[Axis]``, every axis when none is named.
    AXES = "axes"
    #: Per-axis fields (``PR 1,,3``, ``PRB=5``, ``SP ?``): ``list[tuple[Axis, str]]``.
    VALUES = "values"
    #: Coordinate systems, or coordinate systems and axes together (``BG S``, ``BG SA``):
    #: ``list[str]`` of the letters named (axis letters as written). Such a handler answers a
    #: command another room answers for axes alone (``BG A``); the interpreter calls it when
    #: a plane is named and every other letter is an axis. (A planes-only kind went with
    #: decision 0051: every plane command of the reference's masks also takes axes.)
    PLANES_AND_AXES = "planes and axes"


class OperandKind(enum.Enum):
    """Where an operand's name ends: ``_TC`` (plain), ``_TPA`` (axis), ``_XQ0`` (index),
    ``_BGS`` (a coordinate system, S or T: the method takes the plane letter)."""

    PLAIN = "plain"
    AXIS = "axis"
    INDEX = "index"
    PLANE = "plane"


@dataclass(frozen=True)
class HandlerSpec:
    """One command a room answers.

    Attributes:
        name: the two letters (``"PR"``), or a whole control command (``"\\x12\\x16"``).
        args: how the arguments are parsed before the handler sees them.
        equals: an ``=`` in the arguments belongs to the command (``CD 48=4``), so ``CDX=1``
            is never read as a variable assignment.
        every: ``*`` names every axis of the model (``KP*=0``, ``LD*=?``), for the per-axis
            commands (:attr:`Args.VALUES`) whose entry in the command reference shows it
            (decision 0048); elsewhere ``*`` is no axis (TC 4).
    """

    name: str
    args: Args = Args.TEXT
    equals: bool = False
    every: bool = False


@dataclass(frozen=True)
class OperandSpec:
    """One operand a room answers (``_TPA`` is ``OperandSpec("TP", OperandKind.AXIS)``)."""

    name: str
    kind: OperandKind = OperandKind.PLAIN


@dataclass(frozen=True)
class FunctionSpec:
    """One expression function a room answers (``@IN[n]`` is ``FunctionSpec("IN")``)."""

    name: str


Mark = HandlerSpec | OperandSpec | FunctionSpec


@dataclass
class Wait:
    """A held reply or a stalled thread: released when time and condition are met.

    Attributes:
        predicate: released once this is true (checked at every step of the servo loop;
            the loop bisects a step to find the sample where it turns true).
        wake: absolute sample number before which it is not released.
        then: run on release; its text is the reply (a ``CD`` that waited for room).
        exact: when true, the predicate can only change where a step ends anyway (a known
            profile end), so the loop needs no snapshot and bisection for it.
        cut: ``cut(k)``, the longest step (of at most ``k`` samples) in which the predicate
            turns true at most once, for one the bisection could not trust over a longer one
            (``AD`` while an axis turns back).
    """

    predicate: Callable[[], bool] | None = None
    wake: int | None = None
    then: Callable[[], str] | None = None
    exact: Callable[[], bool] | None = None
    cut: Callable[[int], int] | None = None

    def ready(self, sample: int) -> bool:
        """Whether the wait is over at ``sample``."""
        if self.wake is not None and sample < self.wake:
            return False
        return self.predicate is None or self.predicate()


class Download:
    """Returned by ``DL``: the port switches to collecting program lines."""


DOWNLOAD = Download()


@dataclass
class Collect:
    """Returned by a command whose data follows it (``QD``): the port collects the text up
    to ``\\`` and hands it to ``done``, whose text is the reply (before its ``:``); ``done``
    raises :class:`~galil.sim.parse.Refused` to answer ``?``."""

    done: Callable[[str], str]


#: What a handler returns.
Result = str | Wait | Download | Collect

_F = TypeVar("_F", bound=Callable[..., object])
_MARK = "_galil_sim_marks"


def handler(
    name: str, args: Args = Args.TEXT, *, equals: bool = False, every: bool = False
) -> Callable[[_F], _F]:
    """Mark a room method as the handler of command ``name``.

    The method is called with the parsed arguments (see :class:`Args`) and returns a
    :data:`Result`. A method may carry several marks (one per command it answers).

    Raises:
        ValueError: ``name`` is neither two letters nor a control command.
    """
    if not (len(name) == 2 and name.isalpha() and name.isupper()) and not name.startswith("\x12"):
        raise ValueError(f"a command is two upper-case letters or a control command: {name!r}")
    return _mark(HandlerSpec(name, args, equals, every))


def operand(*names: str, kind: OperandKind = OperandKind.PLAIN) -> Callable[[_F], _F]:
    """Mark a room method as the value of operands ``_NAME`` (one or more names).

    The method takes no argument (``PLAIN``), the :class:`~galil.sim.servo.Axis` (``AXIS``), or
    the text after the two letters (``INDEX``), and returns a number.

    Raises:
        ValueError: a name is not two upper-case letters.
    """
    for name in names:
        if not (len(name) == 2 and name.isalpha() and name.isupper()):
            raise ValueError(f"an operand name is two upper-case letters: {name!r}")
    return _mark(*(OperandSpec(n, kind) for n in names))


def function(name: str) -> Callable[[_F], _F]:
    """Mark a room method as the expression function ``@NAME[x]``: it takes the argument's
    value and returns a number.

    Raises:
        ValueError: ``name`` is not upper-case letters.
    """
    if not (name.isalpha() and name.isupper()):
        raise ValueError(f"a function name is upper-case letters: {name!r}")
    return _mark(FunctionSpec(name))


def _mark(*specs: Mark) -> Callable[[_F], _F]:
    def mark(fn: _F) -> _F:
        setattr(fn, _MARK, (*marks(fn), *specs))
        return fn

    return mark


def marks(fn: object) -> tuple[Mark, ...]:
    """The marks :func:`handler`, :func:`operand` and :func:`function` put on ``fn``."""
    found: tuple[Mark, ...] = getattr(fn, _MARK, ())
    return found
