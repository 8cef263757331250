"""The one error tree of ``galil``.

Every exception the library raises on purpose derives from :class:`GalilError`; each also
mixes in the stdlib type a caller would naturally catch::

    GalilError
    ├── CommandError          the controller answered '?'; carries code, text, command
    │   ├── ProgramError      a program thread stopped on an error (code, line, its text)
    │   └── UnknownVariableError  (also KeyError) no variable of that name on the controller
    ├── ProtocolError         the peer sent bytes we cannot make sense of
    ├── GalilTimeoutError     (also TimeoutError) no reply in time
    │   └── QueueTimeoutError (also queue.Empty) nothing arrived in a queue in time
    ├── GalilConnectionError  (also ConnectionError) the link is closed or dead
    ├── GalilAttributeError   (also AttributeError) an assignment to a name that is no setting
    │                         (a misspelt one, a method, a read-only property, any public name
    │                         of an async object); nothing is sent
    ├── InvalidArgument       (also ValueError) refused before anything was sent
    │   ├── UnknownAxisError  (also KeyError) no axis of that letter (``controller.axes["E"]``)
    │   └── LimitError        a move or value would cross a limit (range, soft limit, CD range,
    │       │                 contour feasibility); says which value, limit, and when
    │       └── ScheduleError a speed-schedule change point the profiler cannot honour
    └── MotionError           (also RuntimeError) motion that was sent and ended badly: a limit
        │                     switch, an abort, an axis left moving when stopping failed
        └── ContourUnderrunError  the contour buffer ran dry while streaming (TC 42)

``LimitError`` always means "refused before sending"; ``MotionError`` means "it moved, and it
did not end as planned".
"""

from __future__ import annotations

import decimal
import difflib
import inspect
import queue
from collections.abc import Iterable, Sequence
from typing import ClassVar, Generic, NoReturn, TypeVar, overload

__all__ = [
    "CommandError",
    "ContourUnderrunError",
    "GalilAttributeError",
    "GalilConnectionError",
    "GalilError",
    "GalilTimeoutError",
    "InvalidArgument",
    "LimitError",
    "MotionError",
    "ProgramError",
    "ProtocolError",
    "QueueTimeoutError",
    "ScheduleError",
    "UnknownAxisError",
    "UnknownVariableError",
]


def decimal_hint(value: object) -> str:
    """What the refusal of ``value`` as a number adds when it is a :class:`decimal.Decimal`
    (a number, but no :class:`numbers.Real`; never taken, so that no digits are rounded away
    unseen): how to give it. Empty for anything else."""
    if isinstance(value, decimal.Decimal):
        return " (a decimal.Decimal is not taken: pass float() of it)"
    return ""


#: The options ``galil.connect()`` takes for the client itself (``galil.CLIENT_OPTIONS``);
#: every other option goes to the transport. Here, below both, so that a transport's refusal
#: of an option it does not know can suggest one of these too (:func:`unknown_options`).
CONNECT_OPTIONS = (
    "reconnect",
    "timeout",
    "model",
    "handshake",
    "unsolicited",
    "history",
    "poll_interval",
    "max_messages",
    "echo",
)


def unknown_options(what: str, unknown: Iterable[str], known: Iterable[str]) -> InvalidArgument:
    """The refusal of options ``what`` (``"sim://"``, ``"TCP"``) does not know: each named,
    with the closest spelling among ``known`` (the transport's) and the client options of
    ``connect()`` (:data:`CONNECT_OPTIONS`) where one is close (``reconect``: "did you mean
    'reconnect'?")."""
    pool = sorted({*known, *CONNECT_OPTIONS})
    names = sorted(unknown)
    hints = []
    for name in names:
        close = difflib.get_close_matches(name, pool, n=1, cutoff=0.75)
        if close:
            hints.append(f"{name!r}: did you mean {close[0]!r}?")
    hint = f" ({'; '.join(hints)})" if hints else ""
    return InvalidArgument(f"unknown {what} option(s): {', '.join(names)}{hint}")


def missing_extra(exc: ImportError, what: str, extra: str = "jupyter") -> ModuleNotFoundError:
    """The error for ``what`` (``"Profile.plot()"``), which needs an optional package that
    ``exc`` says is not installed: a :class:`ModuleNotFoundError` (an ``ImportError``, as the
    bare one was) naming the package and the extra that installs it; raise it ``from exc``."""
    name = exc.name or "an optional package"
    return ModuleNotFoundError(
        f"{what} needs {name}, which is not installed: pip install 'galil[{extra}]'", name=name
    )


class GalilError(Exception):
    """Root of every error raised by ``galil``.

    Attributes:
        model: controller model name when known (e.g. ``"DMC-4040"``), else ``None``.
        recent: the last exchanges on the link (oldest first), attached by the client.
    """

    model: str | None
    recent: tuple[str, ...]

    def __init__(
        self, message: str = "", *, model: str | None = None, recent: Sequence[str] = ()
    ) -> None:
        super().__init__(message)
        self.model = model
        self.recent = tuple(recent)

    def __str__(self) -> str:
        text = super().__str__()
        if self.model:
            text = f"{text} [{self.model}]"
        if self.recent:
            tail = "\n  ".join(self.recent[-8:])
            text = f"{text}\n recent exchanges (oldest first):\n  {tail}"
        return text


class CommandError(GalilError):
    """The controller rejected a command with ``?``; ``TC1`` explained why.

    Attributes:
        code: the TC error code (``None`` when TC1 could not be read).
        text: the controller's (or our table's) explanation.
        command: the command line that was rejected.
        replies: when ``command`` was part of a compound line (``MG 1;XYZ;MG 2``), one entry
            per part of that line, in order: the reply text of a part the controller
            answered, ``None`` for one it rejected; empty otherwise.
    """

    def __init__(
        self,
        code: int | None,
        text: str,
        command: str,
        *,
        model: str | None = None,
        recent: Sequence[str] = (),
    ) -> None:
        where = f" by {model}" if model else ""
        code_txt = f"TC {code}" if code is not None else "TC unknown"
        super().__init__(f"{command!r} rejected{where}: {code_txt} {text}".rstrip(), recent=recent)
        self.model = model
        self.code = code
        self.text = text
        self.command = command
        self.replies: tuple[str | None, ...] = ()

    def __str__(self) -> str:
        # The model is already part of the sentence; do not repeat it.
        text = Exception.__str__(self)
        if self.recent:
            tail = "\n  ".join(self.recent[-8:])
            text = f"{text}\n recent exchanges (oldest first):\n  {tail}"
        return text


class ProgramError(CommandError):
    """A thread of the controller's program stopped on an error instead of at ``EN``
    (``programs.wait``; decision 0059): ``_ED`` and ``_ED1`` moved to a new line and thread
    since ``programs.run``. Without ``#CMDERR`` such an error stops every thread, so the
    thread waited for may be another than the one that failed.

    Attributes:
        code: the TC error code (``None`` when a later refusal overwrote it).
        text: the TC code's explanation.
        command: the text of the program line that failed (``""`` when unknown).
        line: the program line that failed (``_ED``; 0 is the first line).
        thread: the thread that failed (``_ED1``).
        waited: the thread that was waited for.
    """

    def __init__(
        self,
        code: int | None,
        text: str,
        command: str,
        *,
        line: int,
        thread: int,
        waited: int,
        model: str | None = None,
        recent: Sequence[str] = (),
    ) -> None:
        who = f"thread {thread}"
        if thread != waited:
            who = f"thread {waited} stopped because {who}"
        where = f" on {model}" if model else ""
        shown = f" ({command})" if command else ""
        told = f"TC {code} {text}" if code is not None else "TC unknown (a later '?' took it)"
        message = f"{who} failed{where} at program line {line}{shown}: {told}"
        super().__init__(code, text, command, model=model, recent=recent)
        self.args = (message.rstrip(),)
        self.line = line
        self.thread = thread
        self.waited = waited


class UnknownVariableError(CommandError, KeyError):
    """The controller has no variable of that name (reading it was TC 1, "Unrecognized
    command"); also a :class:`KeyError`, so ``controller.variables`` is a mapping
    (``variables.get("x")``, ``variables.pop("x", None)``).

    Attributes:
        name: the variable's name.
    """

    def __init__(
        self,
        message: str,
        *,
        name: str,
        code: int | None,
        text: str,
        command: str,
        model: str | None = None,
        recent: Sequence[str] = (),
    ) -> None:
        super().__init__(code, text, command, model=model, recent=recent)
        self.args = (message,)
        self.name = name


class ProtocolError(GalilError):
    """The peer sent something that cannot be parsed, or the link is out of step."""


class GalilTimeoutError(GalilError, TimeoutError):
    """No (complete) reply arrived within the timeout."""


class QueueTimeoutError(GalilTimeoutError, queue.Empty):
    """Nothing arrived within the timeout in a queue the controller fills: ``messages.get``,
    ``interrupts.get``, a record stream's ``get`` (sync and async), and their
    ``get_nowait`` with nothing waiting. A :class:`GalilTimeoutError` like every other wait's,
    and also a :class:`queue.Empty`, the stdlib queue's own, so ``except queue.Empty`` still
    catches it."""


class GalilConnectionError(GalilError, ConnectionError):
    """The link could not be opened, or is closed or dead."""


class GalilAttributeError(GalilError, AttributeError):
    """An assignment refused before anything was sent: ``axis.soft_limit = ...`` (no such
    setting; the nearest names are suggested), ``axis.velocity = ...`` (read-only), or any
    public name of an async object, whose settings are ``await x.set_...(...)`` calls
    (decision 0091). Also an :class:`AttributeError`, what a refused assignment raises in
    Python.

    Attributes:
        attribute: the name that was assigned.
        suggestions: the names meant, nearest first (``"set_soft_limits"`` for an async object).
    """

    def __init__(self, message: str, *, attribute: str, suggestions: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.attribute = attribute
        self.suggestions = tuple(suggestions)


_T = TypeVar("_T")


class ReadOnly(Generic[_T]):
    """A public attribute the library binds and a user only reads (``capture.count``,
    ``watchdog.thread``, ``controller.link``): it reads the private ``_<name>`` the class's
    own methods bind, and a user's assignment is refused as a read-only property's is
    (:class:`FixedAttributes`; decision 0091), since it would change what the object says
    without changing the controller (or the link) behind it.

    Declared on the class: ``count: ReadOnly[int] = ReadOnly()``; bound inside it:
    ``self._count = n``.
    """

    __slots__ = ("_name", "_private")

    def __init__(self) -> None:
        self._name = self._private = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self._name, self._private = name, "_" + name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> ReadOnly[_T]: ...
    @overload
    def __get__(self, obj: object, owner: type | None = None) -> _T: ...
    def __get__(self, obj: object, owner: type | None = None) -> ReadOnly[_T] | _T:
        if obj is None:
            return self
        value: _T = getattr(obj, self._private)
        return value

    def __set__(self, obj: FixedAttributes, value: NoReturn) -> None:
        # (a type checker refuses the assignment too; FixedAttributes refuses it first)
        raise assignment_refused(type(obj), self._name)


class FixedAttributes:
    """A mixin for the user-facing objects (axes, controllers, rooms, handles): assigning a
    public name that is not one of the class's settings raises :class:`GalilAttributeError`
    instead of binding a new attribute that nothing reads (decision 0091).

    What may be assigned: a name with a leading underscore; a property with a setter (or any
    data descriptor with ``__set__``, such as a tuning setting). A public attribute the
    class's own methods bind is a :class:`ReadOnly` (bound through its private twin): refused
    to a user like a read-only property. ``_awaited`` marks an async object: its settings are
    ``await x.set_<name>(...)``, which the refusal names.
    """

    __slots__ = ()
    _awaited: ClassVar[bool] = False
    _settable: ClassVar[frozenset[str]] = frozenset()
    #: What to call instead, by name: said when the name is assigned (a read-only property)
    #: or read when the class has no such attribute (:func:`missing_attribute`); ``{letter}``
    #: in it is the object's ``letter`` (an axis's).
    _elsewhere: ClassVar[dict[str, str]] = {}

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls._settable = frozenset(
            name
            for name in dir(cls)
            if not name.startswith("_") and _has_setter(inspect.getattr_static(cls, name))
        )

    def __setattr__(self, name: str, value: object) -> None:
        if name[:1] != "_" and name not in self._settable:
            raise assignment_refused(type(self), name, self)
        object.__setattr__(self, name, value)


def _has_setter(attribute: object) -> bool:
    if isinstance(attribute, ReadOnly):
        return False  # (its __set__ refuses: the library binds its private twin)
    if isinstance(attribute, property):
        return attribute.fset is not None
    return hasattr(type(attribute), "__set__")


def _elsewhere(cls: type[FixedAttributes], name: str, obj: object) -> str:
    """What ``cls`` says to call instead of ``name`` (``""``: nothing), with ``obj``'s letter."""
    said = cls._elsewhere.get(name, "")
    if not said:
        return ""
    try:
        letter = getattr(obj, "letter", "A")
    except Exception:  # (an object half made: the example's letter)
        letter = "A"
    return said.format(letter=letter if isinstance(letter, str) else "A")


def assignment_refused(
    cls: type[FixedAttributes], name: str, obj: object = None
) -> GalilAttributeError:
    """Why ``name`` cannot be assigned on a ``cls`` (a :class:`FixedAttributes`; ``obj``, the
    object, where known), with the name meant when there is one."""
    what, setter = f"{cls.__name__}.{name}", f"set_{name}"
    if cls._awaited and hasattr(cls, setter):
        return GalilAttributeError(
            f"{what} cannot be assigned, an async object's settings are awaited: use "
            f"`await x.{setter}(...)`; nothing was set",
            attribute=name,
            suggestions=(setter,),
        )
    if hasattr(cls, name):
        known = inspect.getattr_static(cls, name)
        kind = "read-only" if isinstance(known, (property, ReadOnly)) else "not a setting"
        how = f": use `{'await ' if cls._awaited else ''}x.{setter}(...)`"
        if not hasattr(cls, setter) and name in cls._elsewhere:
            how = f": {_elsewhere(cls, name, obj)}"
        elif not hasattr(cls, setter):
            how = ""
        return GalilAttributeError(
            f"{what} is {kind}{how}; nothing was set",
            attribute=name,
            suggestions=(setter,) if hasattr(cls, setter) else (),
        )
    meant = _nearest(cls, name)
    return GalilAttributeError(
        f"{cls.__name__} has no setting {name!r}{_did_you_mean(meant)}; nothing was set",
        attribute=name,
        suggestions=meant,
    )


def missing_attribute(cls: type[FixedAttributes], name: str, obj: object = None) -> AttributeError:
    """What reading ``name``, which ``cls`` does not have, raises: a
    :class:`GalilAttributeError` saying what to call instead (``Axis.motor_off`` is the
    controller's: ``controller.motor_off('A')``) or the closest public names; a plain
    ``AttributeError`` for a dunder or private name (what ``copy``, ``pickle`` and
    ``hasattr`` probe)."""
    if name[:1] == "_":
        return AttributeError(f"{cls.__name__!r} object has no attribute {name!r}", name=name)
    if name in cls._elsewhere:
        hint = f": {_elsewhere(cls, name, obj)}"
        meant: list[str] = []
    else:
        public = [n for n in dir(cls) if n[:1] != "_"]
        meant = difflib.get_close_matches(name, public, n=3, cutoff=0.7)
        hint = _did_you_mean(meant)
    return GalilAttributeError(
        f"{cls.__name__} has no attribute {name!r}{hint}", attribute=name, suggestions=meant
    )


def _did_you_mean(meant: Sequence[str]) -> str:
    """`` (did you mean 'a' or 'b'?)`` for the names a misspelt one may have meant; ``""``
    for none."""
    return f" (did you mean {' or '.join(repr(m) for m in meant)}?)" if meant else ""


def _nearest(cls: type[FixedAttributes], name: str) -> list[str]:
    """The settings ``name`` may have meant (``set_`` methods of an async object): the same
    name in another case, one it extends or shortens (``accel`` for ``acceleration``), then
    the closest spellings (:func:`difflib.get_close_matches`); three at most."""
    pool = {n: n for n in cls._settable}
    setters = (n for n in dir(cls) if n.startswith("set_"))
    pool.update({n[4:]: n for n in setters} if cls._awaited else {})
    low = name.lower()
    lowered = {n.lower(): n for n in sorted(pool)}
    near = [n for n in lowered if n == low]
    near += [n for n in lowered if n not in near and len(n) >= 3 and (
        low.startswith(n) or n.startswith(low))]  # fmt: skip
    close = difflib.get_close_matches(low, list(lowered), n=3, cutoff=0.6)
    near += [n for n in close if n not in near]
    return [pool[lowered[n]] for n in near[:3]]


class InvalidArgument(GalilError, ValueError):  # noqa: N818 (name fixed by the public API)
    """An argument we refuse to send; raised before any byte reaches the wire."""


class UnknownAxisError(InvalidArgument, KeyError):
    """The model has no axis of that letter: ``controller.axes["B"]`` on a one-axis
    controller (as ``controller.B`` says it); also a :class:`KeyError`, so ``axes`` is a
    mapping (``axes.get("B")``, ``"B" in axes``). Nothing is sent.

    Attributes:
        name: the key asked for.
    """

    def __init__(self, message: str, *, name: object, model: str | None = None) -> None:
        super().__init__(message, model=model)
        self.name = name

    def __str__(self) -> str:
        # (KeyError's own would print the message quoted)
        text = Exception.__str__(self)
        return f"{text} [{self.model}]" if self.model else text


class LimitError(InvalidArgument):
    """A value or a predicted path would cross a limit.

    Attributes:
        name: what was checked (``"SP"``, ``"soft limit FL"``, ``"CD"``, ...).
        value: the offending value.
        limit: the limit it crosses.
        time: seconds from the start of the move where it is crossed, if known.
        sample: sample index where it is crossed, if known.
        axis: axis letter, if known.
        end: where the refused motion would have ended (counts), if known.
        segment: index of the path segment (contour, vector) where it is crossed, if known.
        value_in_units: ``value`` in the user's units (a pint Quantity) when the axis has a
            scale; ``value`` stays in counts.
        limit_in_units: ``limit`` likewise.
        floor: whether ``limit`` is the smallest value allowed, which ``value`` is under (a
            speed above 0 but under one step): the user's units then say "the smallest is
            ..., you gave ...".
    """

    def __init__(
        self,
        message: str,
        *,
        name: str = "",
        value: float | None = None,
        limit: float | None = None,
        time: float | None = None,
        sample: int | None = None,
        axis: str | None = None,
        model: str | None = None,
        end: float | None = None,
        segment: int | None = None,
        floor: bool = False,
    ) -> None:
        super().__init__(message, model=model)
        self.name = name
        self.floor = floor
        self.value = value
        self.limit = limit
        self.time = time
        self.sample = sample
        self.axis = axis
        self.end = end
        self.segment = segment
        self.value_in_units: object | None = None
        self.limit_in_units: object | None = None


class ScheduleError(LimitError):
    """A speed-schedule change point that is not valid.

    Attributes:
        index: which change (0-based) is invalid; ``len(changes)`` for the final deceleration.
        earliest: the earliest valid trigger distance for that change (for the final
            deceleration: the shortest move distance that fits).
    """

    def __init__(self, message: str, *, index: int, earliest: float, value: float) -> None:
        super().__init__(
            message,
            name="speed schedule",
            value=value,
            limit=earliest,
            time=None,
            sample=None,
            floor=True,  # (the earliest valid trigger: the smallest distance allowed)
        )
        self.index = index
        self.earliest = earliest


class MotionError(GalilError, RuntimeError):
    """Motion that was sent and ended badly (a limit switch, an abort, a failed stop).

    Attributes:
        axis: the first axis concerned, if known.
        stop_codes: ``_SC`` per axis when the motion ended, if known.
        moving: axes that may still be moving (a stop that could not be confirmed).
        position: the final reference position of ``axis``, if known (counts).
    """

    def __init__(
        self,
        message: str,
        *,
        axis: str | None = None,
        stop_codes: dict[str, int] | None = None,
        moving: str = "",
        position: float | None = None,
        model: str | None = None,
        recent: Sequence[str] = (),
    ) -> None:
        super().__init__(message, model=model, recent=recent)
        self.axis = axis
        self.stop_codes = dict(stop_codes or {})
        self.moving = moving
        self.position = position


class ContourUnderrunError(MotionError):
    """The controller's contour buffer ran dry before the path was sent (TC 42's condition).

    Attributes:
        code: 42, the controller's "contour data being sent too slowly".
        segment: index of the first segment that arrived late.
    """

    code = 42

    def __init__(self, message: str, *, segment: int, model: str | None = None) -> None:
        super().__init__(message, model=model)
        self.segment = segment
