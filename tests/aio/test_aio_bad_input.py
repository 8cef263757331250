"""The bad-input fuzz of the sync API (``tests/test_public_api_bad_input.py``, decision 0026),
run on the ``galil.aio`` twins: every public async entry point, every parameter, the same bad
values.

The rows come from the sync fuzz where the signatures match (:func:`_derived`: a method of the
same name, a property's ``set_`` method, ``[]`` awaited, ``[]=`` as ``set``/``write``), so a
parameter refused in sync is refused in async, before anything is sent, and with the same
error type (each refusal is compared with the sync method's on the same controller). The
async-only entry points have rows of their own (:data:`ASYNC_ONLY`). A test fails when a new
public async method is neither fuzzed nor skipped with a reason (:data:`ASYNC_SKIPPED`).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import inspect
import queue
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import pytest
import test_public_api_bad_input as sync_fuzz
from test_public_api_bad_input import BAD, ENTRIES, SKIPPED, Entry, Lazy

import galil
import galil.aio as aio
from galil.aio._axis import read_setting, write_setting
from galil.aio._motion import motion_twin
from galil.aio._worker import same, twin
from galil.segments import Line
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent


@dataclass(frozen=True)
class AGroup:
    """An async object whose entry points are fuzzed: its class (for the coverage guard),
    how to make it, what to undo afterwards, and its sync twin (for the error types)."""

    kind: type
    make: Callable[[aio.AsyncController], Awaitable[Any]]
    after: Callable[[aio.AsyncController, Any], Awaitable[None]] | None = None
    sync: Callable[[Any], Any] = lambda obj: obj.sync


async def _now(obj: Any) -> Any:
    return obj


async def _programs(c: aio.AsyncController) -> Any:
    await c.programs.download("#A\nWT 2\nEN\n")
    return c.programs


async def _arrays(c: aio.AsyncController) -> Any:
    await c.arrays.define("arr", 10, replace=True)
    return c.arrays


async def _variables(c: aio.AsyncController) -> Any:
    await c.variables.write("v", 1.0)
    return c.variables


async def _stop(c: aio.AsyncController, obj: Any) -> None:
    await obj.stop()


async def _capture_after(c: aio.AsyncController, cap: Any) -> None:
    if cap.result is None:
        await cap.stop()


async def _off(c: aio.AsyncController, gearing: Any) -> None:
    await gearing.off()


async def _close(c: aio.AsyncController, stream: Any) -> None:
    await stream.close()


async def _disable(c: aio.AsyncController, interrupts: Any) -> None:
    await interrupts.disable()


def _vector(c: aio.AsyncController) -> Awaitable[Any]:
    return c.vector_move("AB", [Line(2000, 2000)], speed=10_000)


AGROUPS: dict[str, AGroup] = {
    "controller": AGroup(aio.AsyncController, _now),
    "axis": AGroup(aio.AsyncAxis, lambda c: _now(c.A)),
    "io": AGroup(aio.AsyncIO, lambda c: _now(c.io)),
    "io.inputs": AGroup(aio.AsyncDigitalInputs, lambda c: _now(c.io.inputs)),
    "io.outputs": AGroup(aio.AsyncDigitalOutputs, lambda c: _now(c.io.outputs)),
    "io.analog_in": AGroup(aio.AsyncAnalogInputs, lambda c: _now(c.io.analog_in)),
    "io.analog_out": AGroup(aio.AsyncAnalogOutputs, lambda c: _now(c.io.analog_out)),
    "programs": AGroup(aio.AsyncPrograms, _programs),
    "arrays": AGroup(aio.AsyncArrays, _arrays),
    "variables": AGroup(aio.AsyncVariables, _variables),
    "interrupts": AGroup(aio.AsyncInterrupts, lambda c: _now(c.interrupts), _disable),
    "messages": AGroup(aio.AsyncMessages, lambda c: _now(c.messages), sync=lambda m: None),
    "move handle": AGroup(aio.AsyncMoveHandle, lambda c: c.A.move_by(2000), _stop),
    "vector handle": AGroup(aio.AsyncVectorHandle, _vector, _stop),
    "gearing": AGroup(aio.AsyncGearing, lambda c: c.B.gear_to("A", 0.5), _off),
    "capture": AGroup(aio.AsyncCapture, lambda c: c.capture(["_TPA"], count=4), _capture_after),
    "record stream": AGroup(aio.AsyncRecordStream, lambda c: c.records(8), _close),
    "watchdog": AGroup(aio.AsyncWatchdog, lambda c: c.watchdog(1.0), _stop),
}

#: Sync groups without an async twin of their own: the async API hands out the sync object.
SYNC_OBJECTS = {
    "model": "c.model is the sync ModelSpec (no I/O)",
    "wire_log": "c.wire_log is the sync WireLog",
    "recording": "await capture.wait() returns the sync Recording",
    "profile": "plans return the sync Profile",
    "multi profile": "await c.plan() returns the sync MultiProfile",
    "vector plan": "await c.plan_vector() returns the sync VectorPlan",
    "homed": "await axis.homed() returns the sync Homed",
    "switches": "await axis.switches() returns the sync Switches",
    "switch polarity": "await c.switch_polarity() returns the sync SwitchPolarity",
    "download": "await programs.download() returns the sync result",
    "contour result": "await c.contour() returns the sync ContourResult",
}


@dataclass(frozen=True)
class AEntry:
    """One async entry point: ``kind`` is ``"call"`` (awaited, or iterated for an async
    generator, or entered for an async context manager), ``"set"`` (a property) or
    ``"getitem"`` (awaited). ``names`` maps its parameters to the sync row's (for ACCEPTS and
    the sync call the error types are compared with)."""

    group: str
    name: str
    valid: Mapping[str, object]
    kind: str = "call"
    sync: Entry | None = None
    names: Mapping[str, str] = field(default_factory=dict)
    moves: bool = False
    raw: tuple[str, ...] = ()
    model: str = "DMC-4040"
    tcp: bool = False
    accepts: Mapping[str, set[str]] = field(default_factory=dict)


def _signature(kind: type, name: str) -> inspect.Signature | None:
    """The parameters of an async entry point (a twin's are its sync method's, less ``self``);
    ``None`` for a property."""
    attr = inspect.getattr_static(kind, name)
    if isinstance(attr, property):
        return None
    if isinstance(attr, (twin, same, motion_twin)):
        sig = inspect.signature(attr._method)
        return sig.replace(parameters=list(sig.parameters.values())[1:])
    if isinstance(attr, write_setting):
        return inspect.Signature([inspect.Parameter("value", inspect.Parameter.POSITIONAL_ONLY)])
    if isinstance(attr, read_setting):
        return inspect.Signature([])
    sig = inspect.signature(attr)
    return sig.replace(parameters=[p for n, p in sig.parameters.items() if n != "self"])


def _named(sig: inspect.Signature) -> list[str]:
    return [
        p.name for p in sig.parameters.values() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)
    ]


def _derived(e: Entry) -> AEntry | None:
    """The async twin of a sync row, or ``None`` (its group has no async twin)."""
    if e.group not in AGROUPS:
        return None
    kind = AGROUPS[e.group].kind
    common = {"sync": e, "moves": e.moves, "raw": e.raw, "model": e.model, "tcp": e.tcp}
    if e.kind == "set":
        if isinstance(inspect.getattr_static(kind, e.name, None), property):
            return AEntry(e.group, e.name, e.valid, "set", names={"value": "value"}, **common)
        name = f"set_{e.name}"
        sig = _signature(kind, name)
        assert sig is not None, name
        (param,) = _named(sig)
        return AEntry(e.group, name, {param: e.valid["value"]}, names={param: "value"}, **common)
    if e.kind == "getitem":
        return AEntry(e.group, "__getitem__", e.valid, "getitem", names={"key": "key"}, **common)
    name = e.name if e.kind == "call" else ("write" if e.group == "variables" else "set")
    if not hasattr(kind, name):
        assert (e.group, e.name) in NO_TWIN, f"{e.group}.{e.name}: no async twin; say why"
        return None
    sig = _signature(kind, name)
    assert sig is not None, (e.group, name)
    params = _named(sig)
    if e.kind == "setitem":  # [k] = v: set(k, v) / write(name, value)
        names = dict(zip(params, ("key", "value"), strict=True))
    else:  # the sync row's values for the parameters both have, and its **overrides
        names = {p: p for p in e.valid if p in params or p not in _named_sync(e)}
    valid = {p: e.valid[s] for p, s in names.items()}
    return AEntry(e.group, name, valid, names=names, **common)


def _named_sync(e: Entry) -> list[str]:
    sync_kind = {"controller": galil.Controller, "axis": galil.Axis}.get(e.group)
    if sync_kind is None:
        return list(e.valid)
    sig = inspect.signature(getattr(sync_kind, e.name))
    return _named(sig)


#: Sync rows whose async group has no method of that name, and why.
NO_TWIN: dict[tuple[str, str], str] = {
    ("record stream", "subscribe"): "the async stream is read with async for / get / batch",
}


def _quiet(*args: object) -> None:
    pass


ALL = {label for label, _ in BAD}

#: Async entry points without a sync row of the same shape.
ASYNC_ONLY: list[AEntry] = [
    AEntry("move handle", "watch", {"timeout": None, "stop_on_cancel": True}, moves=True),
    AEntry("vector handle", "watch", {"timeout": None, "stop_on_cancel": True}, moves=True),
    AEntry(
        "record stream",
        "batch",
        {"limit": 2, "timeout": None},
        accepts={"limit": {"10**400"}},  # a bound never reached (as records(maxlen=))
    ),
    *(
        AEntry(group, "run", {"fn": _quiet})
        for group, spec in AGROUPS.items()
        if issubclass(spec.kind, aio.Room)
    ),
]

#: Public async entry points with parameters left out, and why.
ASYNC_SKIPPED: dict[tuple[str, str], str] = {
    ("messages", "deliver"): "the producer side of the queue (the sync core's subscription)",
    ("arrays", "contains"): "a membership test: anything not an array's name is not there"
    " (False), as `in` answers",
    ("variables", "contains"): "a membership test, as `in` answers",
}


def _entries() -> list[AEntry]:
    out = []
    for e in ENTRIES:
        twin_entry = _derived(e)
        if twin_entry is not None:
            out.append(twin_entry)
    return out + ASYNC_ONLY


AENTRIES = _entries()


def _async_skipped_of_sync() -> set[tuple[str, str]]:
    """The sync skips, where the async group has the same method."""
    return {(g, n) for g, n in SKIPPED if g in AGROUPS}


def _apublic(kind: type) -> Iterator[tuple[str, str]]:
    """(name, kind) of every public entry point of an async class that takes a value."""
    for name in dir(kind):
        if name.startswith("_") and name != "__getitem__":
            continue
        attr = inspect.getattr_static(kind, name)
        if isinstance(attr, property):
            if attr.fset is not None:
                yield name, "set"
            continue
        if name == "__getitem__":
            yield name, "getitem"
            continue
        if not (callable(attr) or isinstance(attr, (twin, same, motion_twin, write_setting))):
            continue
        sig = _signature(kind, name)
        if sig is not None and sig.parameters:
            yield name, "call"


def test_every_async_entry_point_is_fuzzed_or_skipped() -> None:
    surface = {(g, n): k for g, spec in AGROUPS.items() for n, k in _apublic(spec.kind)}
    listed = {(e.group, e.name) for e in AENTRIES}
    skipped = set(ASYNC_SKIPPED) | _async_skipped_of_sync()
    missing = sorted(set(surface) - listed - skipped)
    assert not missing, f"public async entry points neither fuzzed nor skipped: {missing}"
    stale = sorted((listed | set(ASYNC_SKIPPED)) - set(surface))
    assert not stale, f"listed but not found (renamed?): {stale}"
    for e in AENTRIES:
        assert e.kind == surface[(e.group, e.name)], e
    # every sync group is twinned here or hands out the sync object
    assert set(sync_fuzz.GROUPS) == set(AGROUPS) | set(SYNC_OBJECTS)


# -- one case -----------------------------------------------------------------------------------


def _hint(e: AEntry, param: str) -> object:
    if e.kind != "call":
        return None
    sig = _signature(AGROUPS[e.group].kind, e.name)
    found = None if sig is None else sig.parameters.get(param)
    return None if found is None else found.annotation


def _accepted(e: AEntry, param: str) -> set[str]:
    out = set(e.accepts.get(param, ()))
    if e.sync is not None:
        out |= sync_fuzz.ACCEPTS.get((e.group, e.sync.name, e.names[param]), set())
    if _hint(e, param) == "bool":
        out.add("True")
    return out


def _none_allowed(e: AEntry, param: str) -> bool:
    hint = _hint(e, param)
    if e.kind != "call":
        return False
    if hint is None:  # a **overrides key: None keeps the axis's setting
        return True
    return isinstance(hint, str) and ("None" in hint or hint in ("Any", "object"))


async def _ainvoke(e: AEntry, target: Any, args: dict[str, object]) -> object:
    if e.kind == "set":
        setattr(target, e.name, args["value"])
        return None
    if e.kind == "getitem":
        return await target[args["key"]]
    sig = _signature(AGROUPS[e.group].kind, e.name)
    assert sig is not None
    first = [p.name for p in sig.parameters.values() if p.kind == p.POSITIONAL_ONLY]
    result = getattr(target, e.name)(
        *(args[p] for p in first), **{k: v for k, v in args.items() if k not in first}
    )
    if inspect.isawaitable(result):
        return await result
    if isinstance(result, AsyncIterator):  # a watch: its first step, then closed
        with contextlib.suppress(StopAsyncIteration):
            await result.__anext__()
        await result.aclose()  # type: ignore[attr-defined]
        return None
    if hasattr(result, "__aenter__"):  # motion(): the guard of a block
        async with result:
            pass
        return None
    return result


async def _adispose(result: object) -> None:
    if isinstance(result, (aio.AsyncRecordStream, aio.AsyncWatchdog, aio.AsyncMoveHandle)):
        await (result.close() if isinstance(result, aio.AsyncRecordStream) else result.stop())
    elif isinstance(result, aio.AsyncCapture):
        if result.result is None:
            await result.stop()
    elif isinstance(result, aio.AsyncGearing):
        await result.off()
    elif callable(result) and not isinstance(result, type):
        result()  # an unsubscribe


def _sync_outcome(c: aio.AsyncController, e: AEntry, target: Any, args: dict[str, object]) -> str:
    """What the sync twin does with the same values: the name of its error, or "taken"."""
    assert e.sync is not None
    sync_target = AGROUPS[e.group].sync(target)
    if sync_target is None:
        sync_target = sync_fuzz.GROUPS[e.group].make(c.sync)
    sync_args = {e.names[p]: v for p, v in args.items()}
    try:
        with nothing_sent(c.sync, allow_queries=True):
            result = sync_fuzz._invoke(e.sync, sync_target, sync_args)
    except queue.Empty:  # (a galil.QueueTimeoutError, so caught before GalilError)
        return "taken"
    except (galil.GalilError, KeyError, TypeError) as exc:
        return type(exc).__name__
    sync_fuzz._dispose(result)
    return "taken"


async def _acase(
    c: aio.AsyncController, e: AEntry, param: str, label: str, bad: object, *, valid: bool = False
) -> list[str]:
    where = f"{e.group}.{e.name}({param}={label})"
    group = AGROUPS[e.group]
    target = await group.make(c)
    args = {k: v.make(c.sync) if isinstance(v, Lazy) else v for k, v in e.valid.items()}
    args[param] = bad
    before = getattr(target, e.name) if e.kind == "set" else None
    moving_before = sync_fuzz._moving(c.sync)
    problems: list[str] = []
    raised: BaseException | None = None
    sent: AssertionError | None = None
    result: object = None
    may_send = param in e.raw and isinstance(bad, str)
    try:
        with nothing_sent(c.sync, allow_queries=True):
            try:
                result = await _ainvoke(e, target, args)
            except queue.Empty:  # (a galil.QueueTimeoutError, so caught before GalilError)
                pass
            except galil.GalilError as exc:
                raised = exc
            except Exception as exc:
                raised = exc
                problems.append(f"{where}: bare {type(exc).__name__}: {str(exc)[:120]}")
    except AssertionError as exc:
        sent = exc
    accepted = functools.partial(_accepted, e, param)
    problems += sync_fuzz.verdict(where, raised, sent, may_send, valid, lambda: label in accepted())
    if raised is None:
        await _adispose(result)
        if e.kind == "set":
            setattr(target, e.name, before)
    elif e.sync is not None and not may_send and not problems:
        sync = await c.run(_sync_outcome, c, e, target, args)
        if sync != type(raised).__name__:
            problems.append(f"{where}: async raised {type(raised).__name__}, sync {sync}")
    no_motion = raised is not None or not e.moves
    after, broken = sync_fuzz._afterwards(c.sync, where, moving_before, no_motion)
    problems += after
    if broken:
        return problems
    if group.after is not None:
        with contextlib.suppress(galil.GalilError):
            await group.after(c, target)
    sync_fuzz._settle(c.sync)
    return problems


@contextlib.asynccontextmanager
async def _connected(e: AEntry) -> AsyncIterator[aio.AsyncController]:
    if not e.tcp:
        async with await aio.connect(f"sim://{e.model}") as c:
            yield c
        return
    with SimTcpServer(model=e.model) as server:
        async with await aio.connect(server.url) as c:
            yield c


async def _fuzz(e: AEntry) -> list[str]:
    async with _connected(e) as c:
        group = AGROUPS[e.group]
        probe = await group.make(c)
        if group.after is not None:
            await group.after(c, probe)
        sync_fuzz._settle(c.sync)
        params = list(e.valid)
        if e.kind == "call":
            sig = _signature(group.kind, e.name)
            assert sig is not None
            missing = [p for p in _named(sig) if p not in e.valid]
            assert not missing, f"{e.group}.{e.name}: no valid value for {missing}"
        first = e.valid[params[0]]
        first = first.make(c.sync) if isinstance(first, Lazy) else first
        problems = await _acase(c, e, params[0], "valid", first, valid=True)
        assert not problems, problems
        for param in params:
            for label, bad in BAD:
                if bad is None and _none_allowed(e, param):
                    continue
                problems += await _acase(c, e, param, label, bad)
        return problems


@pytest.mark.timeout(60)
@pytest.mark.filterwarnings("ignore:move on .* away from the prediction:RuntimeWarning")  # stopped
@pytest.mark.parametrize("entry", AENTRIES, ids=lambda e: f"{e.group}.{e.name}")
def test_bad_values_are_refused_by_the_async_twins(entry: AEntry) -> None:
    problems = asyncio.run(asyncio.wait_for(_fuzz(entry), 50))
    assert not problems, "\n".join(problems)


# -- connect ------------------------------------------------------------------------------------

CONNECT: dict[str, object] = {"threads": 2, "max_messages": 100, "history": 64, "timeout": 1.0}


@pytest.mark.parametrize("param", list(CONNECT))
def test_connect_refuses_bad_options_before_opening(param: str) -> None:
    async def body() -> list[str]:
        problems = []
        for label, bad in BAD:
            if bad is None and param == "timeout":
                continue  # the default
            try:
                c = await aio.connect("sim://DMC-4040", **{**CONNECT, param: bad})
            except galil.InvalidArgument:
                continue
            except Exception as exc:
                problems.append(f"connect({param}={label}): bare {type(exc).__name__}: {exc}")
                continue
            await c.aclose()
            if not (param == "max_messages" and label == "10**400"):  # a bound never reached
                problems.append(f"connect({param}={label}): taken")
        return problems

    assert not asyncio.run(body())
