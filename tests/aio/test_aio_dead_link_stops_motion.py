"""Every async operation that starts, waits for or stops motion, with the link dying at each
of the write or read calls its worker threads make: motion never outlives the error
(decisions 0028, 0074), as ``tests/test_exceptions_stop_motion.py`` checks for the sync API.

Each operation runs once on a fresh simulator to count the transport calls of the async
controller's worker threads; then, for each of those calls, again on a fresh simulator with
that call failing as a dead link does (``GalilConnectionError``), before it does its work or
once it did (the bytes written, or read and lost). Afterwards, from the outside (a handle of
the test's own on the simulator):

- the awaiting task got a ``GalilError``, except from a stop whose link the guard reopened to
  send it again (it has done its job and returns);
- a link left dead is reopened by ``reconnect()`` (``sim://`` reopens onto the same
  simulator);
- within a quarter of a second of controller time (a stop's ramp) no axis moves and no axis
  is left in contour mode;
- the link answers ``MG 1`` then ``MG 2``.
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from aio_helpers import run
from test_async_sequences import _worker
from test_operation_sequences import _dropped

import galil.aio as aio
from galil import Line
from galil.errors import GalilError
from galil.sim.controller import SimController
from galil.testing import sim_of

HAS_TASKGROUP = sys.version_info >= (3, 11)
#: Controller time whatever the failed operation left stopping takes to come to rest.
SETTLE = 0.25
LONG = 200_000  # counts: 10 s at SP 20 000


def _ask(sim: SimController, names: list[str]) -> list[int]:
    """Operands read on a handle of the test's own (not through the library)."""
    port = sim.open_port("audit")
    try:
        reply = sim.feed(f"MG {','.join(names)}\r".encode(), port)
    finally:
        sim.close_port(port)
    text = reply.decode("latin-1").strip().rstrip(":")
    return [round(float(v)) for v in text.replace("-", " -").split()]


# -- the operations ---------------------------------------------------------------------------


async def _slow(c: aio.AsyncController) -> None:
    for command in ("SP 20000,20000,20000,20000", "AC 1000000,1000000,1000000,1000000"):
        await c.command(command)
    await c.command("DC 1000000,1000000,1000000,1000000")


async def _moving(c: aio.AsyncController) -> aio.AsyncMoveHandle:
    await _slow(c)
    return await c.A.move_by(LONG)


async def _jogging(c: aio.AsyncController) -> aio.AsyncMoveHandle:
    await _slow(c)
    return await c.A.jog(20_000)


async def _homing(c: aio.AsyncController) -> None:
    """Speeds for homing, the home switch and the index pulses far away (10 s of travel)."""
    await _slow(c)
    await c.command("HV 5000,5000,5000,5000")
    await c.command("JG 5000,5000,5000,5000")
    sim_of(c.sync).set_home_switch("A", edge=-LONG // 4, index_period=LONG // 4)


async def _awaited(start: Awaitable[aio.AsyncMoveHandle]) -> object:
    return await (await start)


async def _watched(c: aio.AsyncController, handle: aio.AsyncMoveHandle) -> None:
    async for _ in handle.watch(timeout=0.5):
        pass


async def _two_moves(c: aio.AsyncController) -> tuple[aio.AsyncMoveHandle, aio.AsyncMoveHandle]:
    await _slow(c)
    return await c.A.move_by(LONG), await c.B.move_by(-LONG)


async def _grouped(c: aio.AsyncController, moves: tuple[aio.AsyncMoveHandle, ...]) -> None:
    """Two moves' waits in a ``TaskGroup``: one failing cancels the other, and a wait
    cancelled stops its move."""
    async with asyncio.TaskGroup() as tg:  # type: ignore[attr-defined]
        for move in moves:
            tg.create_task(move.wait())


async def _guarded(c: aio.AsyncController, _: object) -> None:
    async with c.motion("AB"):
        a = await c.A.move_by(LONG)
        await c.B.move_by(LONG)
        await a


async def _nothing(c: aio.AsyncController) -> None:
    return None


@dataclass(frozen=True)
class Op:
    """``await body(c, await setup(c))``, the operation whose calls fail.

    Attributes:
        every: check each ``every``-th call only (and the first 8 and last 3): the polls of
            a wait in between are all alike.
        stops: the operation is a stop: when its link dies and the guard gets the stop
            through on the reopened link, it has done its job and returns.
    """

    name: str
    body: Callable[[aio.AsyncController, Any], Awaitable[object]]
    setup: Callable[[aio.AsyncController], Awaitable[Any]] = _nothing
    every: int = 1
    stops: bool = False


OPS = [
    Op("move_by + await", lambda c, _: _awaited(c.A.move_by(LONG)), _slow, every=31),
    Op(
        "controller.move + await",
        lambda c, _: _awaited(c.move({"A": LONG, "B": -LONG})),
        _slow,
        every=31,
    ),
    # (a jog's polls find it moving: the wait polls until its timeout)
    Op("handle.wait of a jog", lambda c, h: h.wait(timeout=0.5), _jogging),
    Op("handle.watch of a jog", _watched, _jogging),
    Op("jog", lambda c, _: c.A.jog(20_000), _slow),
    *([Op("waits in a task group", _grouped, _two_moves, every=31)] if HAS_TASKGROUP else []),
    Op(
        "speed_schedule + await",
        lambda c, _: _awaited(c.B.speed_schedule(LONG, [(LONG // 2, 10_000)])),
        _slow,
        every=37,
    ),
    Op("home + await", lambda c, _: _awaited(c.A.home()), _homing, every=41),
    Op(
        "vector_move + await",
        lambda c, _: _awaited(c.vector_move("AB", [Line(LONG, LONG // 2)], speed=20_000)),
        every=31,
    ),
    Op("contour", lambda c, _: c.contour("A", np.arange(1, 521) * 100.0, dt=2), every=53),
    Op("motion guard", _guarded, _slow, every=31),
    Op("handle.stop", lambda c, h: h.stop(), _moving, stops=True),
    Op("axis.stop", lambda c, _: c.A.stop(), _jogging, stops=True),
    Op("controller.abort", lambda c, _: c.abort(), _moving, stops=True),
]


async def _attempt(op: Op, at: int | None, after: bool) -> tuple[int, str]:
    """Run ``op`` on a fresh simulator with the ``at``-th call dying (``None``: none);
    return the calls counted and what went wrong ("" when all is well)."""
    c = await aio.connect("sim://DMC-4040")
    try:
        sim = sim_of(c.sync)
        ctx = await op.setup(c)
        calls: list[bool] = []
        tripped: list[bool] = []
        counting = _dropped(
            c.sync.link,
            -1 if at is None else at,
            after=after,
            threads=_counted(calls),
            tripped=tripped,
        )
        caught: BaseException | None = None
        with counting:
            try:
                await op.body(c, ctx)
            except BaseException as exc:  # (judged here)
                if not _galil(exc):
                    raise
                caught = exc
        if not tripped:  # (a run with fewer calls than the count: the threads' timing)
            return len(calls), ""
        if caught is None and not op.stops:
            return len(calls), "returned normally"
        if c.sync.link.dead:
            await c.reconnect()
        await c.sleep(SETTLE)
        letters = c.sync.model.axes
        moving = _ask(sim, [f"_BG{a}" for a in letters] + ["_BGS"])
        still = "".join(a for a, m in zip(letters + "S", moving, strict=True) if m)
        if still:
            return len(calls), f"{still} still moving ({caught!r})"
        contour = [a for a in letters if sim._m.servo.axes[a].contour]
        if contour:
            return len(calls), f"{contour} left in contour mode"
        if await c.query_number("MG 1") != 1 or await c.query_number("MG 2") != 2:
            return len(calls), "the link is out of step"
        return len(calls), ""
    finally:
        await c.aclose()


def _galil(exc: BaseException) -> bool:
    """Whether ``exc`` is a ``GalilError``, or a task group's of those only."""
    inner = getattr(exc, "exceptions", None)  # (a BaseExceptionGroup, Python 3.11+)
    if inner is not None:
        return all(map(_galil, inner))
    return isinstance(exc, GalilError)


def _counted(calls: list[bool]) -> Callable[[Any], bool]:
    """The worker threads' calls count (and are noted in ``calls``)."""

    def counts(thread: Any) -> bool:
        mine = _worker(thread)
        if mine:
            calls.append(True)
        return mine

    return counts


def _points(op: Op, total: int) -> list[int]:
    return sorted(
        {*range(min(total, 8)), *range(0, total, op.every), *range(max(0, total - 3), total)}
    )


@pytest.mark.parametrize("op", OPS, ids=[op.name for op in OPS])
def test_a_dead_link_at_any_call_leaves_no_motion_running(op: Op) -> None:
    total, problem = run(lambda: _attempt(op, None, False))
    assert total > 0
    assert not problem
    failures = []
    for k in _points(op, total):
        for after in (False, True):
            _, problem = run(lambda: _attempt(op, k, after))  # noqa: B023 - run at once
            if problem:
                where = f"call {k} dying {'after' if after else 'before'}"
                failures.append(f"{op.name}, {where}: {problem}")
    assert not failures, f"{len(failures)} of {2 * len(_points(op, total))}:\n" + "\n".join(
        failures[:30]
    )
