"""The async API takes the parameters of the sync one: every public method of a sync class
(the controller, an axis, a handle, a room) and its twin in ``galil.aio`` have the same
parameters, pair by pair (names, kinds, defaults and annotations; not the return types, which
are awaited or the async twins), the protocol methods too (``[]``, ``in``, ``with``, ``for``,
and their awaited names). A method whose parameters differ, or a protocol method the async side
lacks, fails here unless :data:`DIFFERENT` or :data:`SYNC_ONLY` says why. (A named method the
async side lacks fails ``test_every_public_name_of_the_sync_room_has_its_async_twin``.)

The twins made by ``twin``, ``same`` and ``motion_twin`` take the sync method's signature by
construction; the hand-written ones (``wait``, ``add_callback``, ``subscribe``, ``capture``,
``motion``, ``gear_to`` ...) drift unless something compares them: this.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import galil
import galil.aio as aio
from galil.aio._motion import motion_twin
from galil.aio._worker import same, twin
from galil.arrays import Arrays, Variables
from galil.gearing import Gearing
from galil.interrupts import Interrupts
from galil.io import AnalogInputs, AnalogOutputs, DigitalInputs, DigitalOutputs
from galil.programs import Programs
from galil.watchdog import Watchdog

#: Each sync class and its async twin.
PAIRS: dict[type, type] = {
    galil.Controller: aio.AsyncController,
    galil.Axis: aio.AsyncAxis,
    Gearing: aio.AsyncGearing,
    galil.MoveHandle: aio.AsyncMoveHandle,
    galil.VectorHandle: aio.AsyncVectorHandle,
    galil.Capture: aio.AsyncCapture,
    Watchdog: aio.AsyncWatchdog,
    galil.IO: aio.AsyncIO,
    DigitalInputs: aio.AsyncDigitalInputs,
    DigitalOutputs: aio.AsyncDigitalOutputs,
    AnalogInputs: aio.AsyncAnalogInputs,
    AnalogOutputs: aio.AsyncAnalogOutputs,
    Programs: aio.AsyncPrograms,
    Arrays: aio.AsyncArrays,
    Variables: aio.AsyncVariables,
    Interrupts: aio.AsyncInterrupts,
    galil.MessageQueue: aio.AsyncMessages,
    galil.RecordStream: aio.AsyncRecordStream,
}

#: Module functions and their async twins.
FUNCTIONS: dict[str, tuple[Callable[..., Any], Callable[..., Any]]] = {
    "connect": (galil.connect, aio.connect),
}

#: The protocol methods compared (the ones a user reaches by syntax: ``[]``, ``in``, ``with``).
DUNDERS = ("__getitem__", "__setitem__", "__delitem__", "__contains__", "__iter__", "__len__")
DUNDERS += ("__enter__", "__exit__")

#: Where the async twin of a sync method has another name: the syntax that cannot be awaited
#: becomes a method (``await dmc.io.outputs.set(2, True)`` for ``dmc.io.outputs[2] = True``),
#: ``with`` becomes ``async with``, ``for`` becomes ``async for``.
RENAMED: dict[str, str] = {
    "__enter__": "__aenter__",
    "__exit__": "__aexit__",
    "__iter__": "__aiter__",
    "__setitem__": "set",
    "__contains__": "contains",
    "__delitem__": "delete",
}
RENAMED_IN: dict[tuple[type, str], str] = {
    (galil.Controller, "close"): "aclose",  # (async with ... / await c.aclose())
    (Variables, "__setitem__"): "write",  # await variables.write("x", 2)
    **{(kind, "__iter__"): "all" for kind in (DigitalInputs, DigitalOutputs)},
    **{(kind, "__iter__"): "all" for kind in (AnalogInputs, AnalogOutputs)},
}

#: Protocol methods of a sync class without an async twin on purpose, and why. (A missing twin
#: of a named method fails ``test_every_public_name_of_the_sync_room_has_its_async_twin`` in
#: test_aio_rooms.py, with its reasons; the protocol methods, which it does not look at, here.)
SYNC_ONLY: dict[tuple[type, str], str] = {
    (Variables, "__iter__"): "the async variables are no mapping: await variables.list()",
    (Variables, "__len__"): "the async variables are no mapping: len(await variables.list())",
}

#: Methods of both sides whose parameters differ on purpose: the parameters that differ (a
#: further difference in the same method fails), and why.
DIFFERENT: dict[tuple[Any, str], tuple[set[str], str]] = {
    ("function", "connect"): ({"threads"}, "the async controller's worker threads"),
    (galil.MessageQueue, "close"): (
        {"why"},
        "sync: the controller closes the queue saying why (the getters raise it); async: "
        "aclose() ends the readers' iteration, with nothing to say",
    ),
    # The callbacks are handed the async handle, an async axis is a master too: the
    # annotations name the async types.
    (galil.MoveHandle, "add_callback"): ({"callback"}, "called with the AsyncMoveHandle"),
    (galil.VectorHandle, "add_callback"): ({"callback"}, "called with the AsyncMoveHandle"),
    (galil.Axis, "gear_to"): ({"master"}, "an AsyncAxis is a master too"),
}


def _public(kind: type) -> list[str]:
    names = [n for n in dir(kind) if not n.startswith("_")]
    return names + [n for n in DUNDERS if hasattr(kind, n)]


def _parameters(kind: type, name: str) -> list[inspect.Parameter] | None:
    """The parameters of a method, less ``self`` (a twin's: its sync method's), annotations
    evaluated; ``None`` for a property or an attribute."""
    attr = inspect.getattr_static(kind, name)
    if isinstance(attr, (twin, same, motion_twin)):
        attr = attr._method
    if isinstance(attr, staticmethod):
        return list(inspect.signature(attr.__func__, eval_str=True).parameters.values())
    if isinstance(attr, classmethod):
        attr = attr.__func__
    if isinstance(attr, (property, type)) or not callable(attr):
        return None
    return list(inspect.signature(attr, eval_str=True).parameters.values())[1:]


def _differing(sync: list[inspect.Parameter], other: list[inspect.Parameter]) -> set[str]:
    """The names of the parameters that one side lacks or that differ in kind, default or
    annotation."""
    mine = {p.name: p for p in sync}
    theirs = {p.name: p for p in other}
    out = set(mine) ^ set(theirs)
    for name in set(mine) & set(theirs):
        a, b = mine[name], theirs[name]
        if (a.kind, a.default, a.annotation) != (b.kind, b.default, b.annotation):
            out.add(name)
    if [p.name for p in sync] != [p.name for p in other] and not out:
        out = set(mine)  # the same parameters in another order
    return out


def _differences() -> tuple[dict[tuple[Any, str], set[str]], set[tuple[type, str]]]:
    """(the methods of both sides whose parameters differ: which; the sync protocol methods
    without a twin)."""
    different: dict[tuple[Any, str], set[str]] = {}
    missing: set[tuple[type, str]] = set()
    for sync_kind, async_kind in PAIRS.items():
        for name in _public(sync_kind):
            sync = _parameters(sync_kind, name)
            if sync is None:
                continue
            twin_name = RENAMED_IN.get((sync_kind, name), RENAMED.get(name, name))
            if not hasattr(async_kind, twin_name):
                if name in DUNDERS:
                    missing.add((sync_kind, name))
                continue  # (a named method: test_aio_rooms.py says whether it may lack one)
            other = _parameters(async_kind, twin_name)
            assert other is not None, f"{async_kind.__name__}.{twin_name} is not a method"
            if found := _differing(sync, other):
                different[(sync_kind, name)] = found
    for name, (sync_fn, async_fn) in FUNCTIONS.items():
        sync, other = (
            list(inspect.signature(f, eval_str=True).parameters.values())
            for f in (sync_fn, async_fn)
        )
        if found := _differing(sync, other):
            different[("function", name)] = found
    return different, missing


def _label(key: tuple[Any, str]) -> str:
    kind, name = key
    return f"{getattr(kind, '__name__', kind)}.{name}"


def test_the_async_methods_take_the_parameters_of_their_sync_twins() -> None:
    # every async twin class of galil.aio is compared with its sync class
    twins = {getattr(aio, n) for n in aio.__all__ if n.startswith("Async")}
    assert twins == set(PAIRS.values()), sorted(t.__name__ for t in twins ^ set(PAIRS.values()))
    different, missing = _differences()
    unexplained = sorted(
        f"{_label(k)}: {sorted(found)}"
        for k, found in different.items()
        if k not in DIFFERENT or DIFFERENT[k][0] != found
    )
    assert not unexplained, f"parameters differ between sync and async: {unexplained}"
    no_twin = sorted(_label(k) for k in missing - set(SYNC_ONLY))
    assert not no_twin, f"sync protocol methods without an async twin (add one, say why): {no_twin}"
    gone = (set(DIFFERENT) - set(different)) | (set(SYNC_ONLY) - missing)
    stale = sorted(_label(k) for k in gone)
    assert not stale, f"allowed differences that are no more (remove them): {stale}"
