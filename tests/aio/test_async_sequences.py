"""Random sequences of async operations against the simulator, checked after every step.

The async twin of ``tests/test_operation_sequences.py``: a hypothesis state machine drives
``await galil.aio.connect("sim://DMC-4040")`` through moves (awaited or not, alone or
``asyncio.gather``-ed over several axes, or in a ``TaskGroup``), jogs and their speed
changes, increments, speed schedules, homing, gearing, vector moves, contours, programs and
their waits, I/O and ``wait_for_input``, captures, stops, aborts, motors off and on, soft
limits, limit switches, ``LD``, the ``motion()`` guard and the passing of time (``await
c.sleep``: the simulator's clock only moves when the client lets time pass, and a wait lets
the predicted time pass at once). Each awaitable runs to its end, or is cancelled at a
random point: at its ``n``-th call to the controller's worker while the call is queued or
running, inside the ``n``-th write to the link (mid-exchange), by ``task.cancel()``, an
expiring ``asyncio.timeout``, an outer ``asyncio.wait_for`` or ``asyncio.wait_for(..., 0)``
(the traps of ``test_cancellation_everywhere.py``). After each step:

- a call raised nothing but the library's documented errors, and a refusal sent nothing but
  queries and changed no setting (the sync fuzz's checks, borrowed);
- a cancelled or timed-out await left no motion running that it started or awaited: each
  such axis is at rest or stopping (``_SC`` not a running code) at once, and at rest once its
  ramp down is over (unless newer motion, a master or the test's program moves it);
- a cancelled contour left no axis in contour mode and no segment held;
- a waited move ended where its handle predicted, with the stop code its kind ends with,
  when nothing interfered with it;
- the library's view agrees with the simulator's (moving axes, gearing);
- the link is in step (``MG 1``, ``MG 2``); no task is left on the loop, no call left on the
  worker (every worker thread takes a call at once), no thread but the worker's.

At the end ``aclose()`` leaves nothing moving (but what the test's program moves) and no
thread running.

Deterministic in CI (``derandomize``, no database); run it long with e.g.
``GALIL_ASEQ_EXAMPLES=1000 pytest --timeout=0 tests/aio/test_async_sequences.py`` (and
``GALIL_ASEQ_STEPS`` for longer sequences, ``GALIL_ASEQ_RANDOM=1`` for other sequences than
CI's).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import sys
import threading
import warnings
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import numpy as np
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule
from test_cancellation_everywhere import Trap, WireTrap
from test_operation_sequences import (
    _VALUES,
    AXES,
    PROGRAM,
    OperationSequences,
    Running,
    _dropped,
    _limit_stopped,
)

import galil
import galil.aio as aio
from galil import Line
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilTimeoutError,
    InvalidArgument,
    MotionError,
    ProgramError,
)
from galil.motion import MoveHandle, MoveResult
from galil.sim.rooms.contour import Contour as SimContour
from galil.testing import sim_of, transcript

T = TypeVar("T")

EXAMPLES = int(os.environ.get("GALIL_ASEQ_EXAMPLES", "12"))
STEPS = int(os.environ.get("GALIL_ASEQ_STEPS", "25"))
RANDOM = os.environ.get("GALIL_ASEQ_RANDOM", "") not in ("", "0")

axis_st = st.sampled_from(AXES)
HAS_TIMEOUT = sys.version_info >= (3, 11)  # asyncio.timeout, TaskGroup
# How an awaitable runs: to its end, or cancelled at its n-th worker call (the call queued
# behind busy threads, or held on its thread), or inside the n-th write to the link; by
# task.cancel(), an outer asyncio.wait_for's task cancelled, or an expiring asyncio.timeout.
# "wait_for 0": asyncio.wait_for(..., 0), cancelled before it starts. "drop": the link dies
# at the worker threads' n-th write or read (before it, or once it is done).
HOWS = [
    "plain",
    "plain",
    "plain",
    "task queued",
    "task running",
    "task wire",
    "wait_for running",
    "wait_for wire",
    "wait_for 0",
    *(["timeout queued", "timeout running", "timeout wire"] if HAS_TIMEOUT else []),
    "drop before",
    "drop after",
]
how_st = st.sampled_from(HOWS)
call_st = st.integers(1, 16)
# Which of the handles (or axes) running a rule takes: an index drawn whatever the state, so
# that a replay draws the same data when the worker threads' pacing changed what runs.
pick_st = st.integers(0, 63)
# Codes of an axis whose motion runs on (not stopping): independent, contour, vector.
_RUNNING_CODES = (0, 50, 100)
# Controller seconds within which every stop is over: the slowest ramp down here is SP
# 60 000 at DC 20 480 (2.9 s), plus IT smoothing.
STOP_TIME = 3.5


def _undo_the_groups_own_cancel(tg: Any) -> None:
    """CPython before 3.13 leaves a ``TaskGroup``'s own cancellation of its parent pending when
    a child fails after the group's body has ended (its ``__aexit__`` looks at the flag before
    the children end; 3.13 looks after): undone here as 3.13 does, or a timeout around the
    step lets ``CancelledError`` through instead of ``TimeoutError`` (seen once in 800
    examples on 3.11.7 and on 3.12.1). Not the library's: its waits only fail, as they must."""
    task = asyncio.current_task()
    if sys.version_info < (3, 13) and task is not None and tg._parent_cancel_requested:
        task.uncancel()


def _died(error: BaseException | None) -> bool:
    """Whether ``error`` is a dead link's, or a stop that could not be confirmed after one."""
    if isinstance(error, MotionError):
        error = error.__cause__
    return isinstance(error, GalilConnectionError)


def _worker(thread: threading.Thread) -> bool:
    """Whether ``thread`` is one of the async controller's worker threads."""
    return thread.name.startswith("galil-aio-")


def _picked(items: list[T], pick: int) -> T:
    return items[pick % len(items)]


class _CancelledError(Exception):
    """The step's awaitable was cancelled (or timed out) as the step asked."""


class BoomError(Exception):
    """A user's error inside ``async with c.motion()``."""


class AsyncSequences(RuleBasedStateMachine):
    # The sync fuzz's bookkeeping and checks: they read the sync controller behind the async
    # one (``self.dmc``) from the test's thread, between steps.
    _settings = OperationSequences._settings
    refusable = OperationSequences.refusable
    interfere = OperationSequences.interfere
    limits_changed = OperationSequences.limits_changed
    idle = OperationSequences.idle
    check_result = OperationSequences.check_result
    judge_wait = OperationSequences.judge_wait
    limit_stop_explained = OperationSequences.limit_stop_explained
    supersede = OperationSequences.supersede
    started = OperationSequences.started
    set_setting = OperationSequences.set_setting
    _followed = OperationSequences._followed
    _free = OperationSequences._free
    contour_stopped_at_a_switch = OperationSequences.contour_stopped_at_a_switch
    follower_limit_explained = OperationSequences.follower_limit_explained
    # A rule and an invariant, as they are (the simulator only; the library's view).
    place_limit_switch = OperationSequences.place_limit_switch
    judge_define = OperationSequences.judge_define
    judge_tc13 = OperationSequences.judge_tc13
    library_agrees_with_simulator = OperationSequences.library_agrees_with_simulator

    def __init__(self) -> None:
        super().__init__()
        self.threads_before = set(threading.enumerate())
        self.loop = asyncio.new_event_loop()
        self.c: aio.AsyncController = self.run(aio.connect("sim://DMC-4040"))
        self.dmc = self.c.sync
        self.sim = sim_of(self.dmc)
        self.threads_connected = set(threading.enumerate())  # (the link's poll thread too)
        self.running: list[Running] = []
        self.handles: dict[int, aio.AsyncMoveHandle] = {}
        self.gearings: dict[str, aio.AsyncGearing] = {}
        self.program_axis_free = True
        self.placed: dict[str, set[int]] = {a: set() for a in AXES}
        self.program_gears: list[Any] = []
        self.capture: aio.AsyncCapture | None = None
        # What the step's awaitable awaited (handles), and the waits it saw to an end.
        self.owned: list[MoveHandle] = []
        self.unawaited: list[MoveHandle] = []  # started in the step, never awaited by it
        self.outcomes: list[tuple[Running, MoveResult | None, MotionError | None]] = []
        self.cancel_asked = False  # the step's trap cancelled (or timed out) its task
        # The errors a dead link may raise in the step: none, unless the step's link dies.
        self.dead: tuple[type[GalilConnectionError], ...] = ()
        # Motion a cancellation stopped: (axes, the handle, controller time it must be over).
        self.stopping: list[tuple[str, MoveHandle, float]] = []

    # -- running awaitables -----------------------------------------------------------------
    def run(self, awaitable: Awaitable[T]) -> T:
        return self.loop.run_until_complete(awaitable)

    def act(self, body: Callable[[], Awaitable[T]], how: str, n: int) -> T:
        """Run ``body()`` on the loop as ``how`` says; when it was cancelled (or timed out),
        check what the cancellation left and raise :class:`_CancelledError`. The waits it saw to
        an end are judged either way (after the loop: the judging queries block)."""
        before = {a: self.dmc.tracker.active(a) for a in AXES}
        self.owned, self.outcomes, self.unawaited = [], [], []
        try:
            with transcript(self.dmc) as sent:
                try:
                    return self.run(self._act(body, how, n))
                finally:
                    if how.startswith("drop"):
                        self.reopen_if_dead()
        except _CancelledError:
            if how.startswith("drop"):
                # (a guard that met the dead link stops the axes it names, whatever runs on
                # them: the ends of the motion already there are not the prediction's)
                self.interfere()
            self.after_cancel(before, f"{how} at {n}, sent {sent.lines}")
            raise
        finally:
            outcomes, self.outcomes = self.outcomes, []
            for run, result, limited in outcomes:
                self.judge_wait(run, result, limited)

    async def _act(self, body: Callable[[], Awaitable[T]], how: str, n: int) -> T:
        self.cancel_asked = False
        if how == "plain":
            return await body()
        if how.startswith("drop"):
            return await self._dropped(body, n - 1, after=how == "drop after")
        if how == "wait_for 0":
            try:
                return await asyncio.wait_for(body(), 0)
            except asyncio.TimeoutError:
                raise _CancelledError from None
        wrapper, mode = how.split()
        c, loop = self.c, asyncio.get_running_loop()
        trap = WireTrap(c, n) if mode == "wire" else Trap(c.worker, c.sync.link, n, mode)
        task: asyncio.Future[T]

        def asking(cancel: Callable[[], object]) -> Callable[[], object]:
            def ask() -> object:
                self.cancel_asked = True
                return cancel()

            return ask

        if wrapper == "timeout":
            holder: list[Any] = []

            async def timed() -> T:
                async with asyncio.timeout(None) as cm:  # type: ignore[attr-defined]
                    holder.append(cm)
                    return await body()

            task = asyncio.ensure_future(timed())
            trap.watch(task, asking(lambda: holder[0].reschedule(loop.time())))
        elif wrapper == "wait_for":
            task = asyncio.ensure_future(asyncio.wait_for(body(), 3600))
            trap.watch(task, asking(task.cancel))
        else:
            task = asyncio.ensure_future(body())
            trap.watch(task, asking(task.cancel))
        try:
            await asyncio.wait({task})
        finally:
            await trap.settle()
        if not trap.fired:
            return task.result()  # it ended before the point: its own outcome
        if wrapper == "timeout":
            assert isinstance(task.exception(), asyncio.TimeoutError), (how, n, task)
        else:
            assert task.cancelled(), (how, n, task.exception() or task.result())
        raise _CancelledError

    def reopen_if_dead(self) -> None:
        """A link the step's drop left dead is reopened, as a user would (``reconnect()``).
        A reopened link's poll thread (the user's reconnect, or a guard's) is the link's,
        not one left behind."""
        if self.dmc.link.dead:
            self.run(self.c.reconnect())
        self.threads_connected |= {
            t for t in threading.enumerate() if t.name.startswith(("galil-poll", "galil-messages"))
        }

    async def _dropped(self, body: Callable[[], Awaitable[T]], at: int, *, after: bool) -> T:
        """Run ``body()`` while the link dies at the worker threads' ``at``-th write or read:
        what raises the dead link's error (or a ``MotionError`` from it: a stop not
        confirmed) was cut short, as a cancelled call is (:class:`_CancelledError`); the
        motion it started or awaited is then checked the same way."""
        tripped: list[bool] = []
        self.dead = (GalilConnectionError,)
        try:
            with _dropped(self.dmc.link, at, after=after, threads=_worker, tripped=tripped):
                return await body()
        except GalilConnectionError:
            if not tripped:
                raise
        except MotionError as exc:
            if not tripped or not isinstance(exc.__cause__, GalilConnectionError):
                raise
        finally:
            self.dead = ()
        raise _CancelledError

    def after_cancel(self, before: dict[str, MoveHandle | None], step: str) -> None:
        """A cancelled awaitable stopped every motion it started or awaited: each of its
        axes is at rest or stopping now, and is to be at rest by ``STOP_TIME``."""
        owned = {id(h): h for h in self.owned}
        for a in AXES:
            h = self.dmc.tracker.active(a)
            if h is not None and h is not before[a]:
                owned[id(h)] = h
        for h in self.unawaited:
            owned.pop(id(h), None)
        now = self.dmc.link.clock()
        for h in owned.values():
            self.interfere(h.axes)
            # (not the axes newer motion drives: a superseded handle's wait stops nothing,
            # also where a gearing made the axis a follower since)
            tracker = self.dmc.tracker
            axes = "".join(
                a
                for a in h.axes
                if (a != "D" or self.program_axis_free)
                and tracker.active(a) in (None, h)
                and a not in tracker.gears
            )
            if not axes:
                continue
            values = self.dmc.query_operands([f"_{op}{a}" for a in axes for op in ("BG", "SC")])
            for a, bg, sc in zip(axes, values[0::2], values[1::2], strict=True):
                assert not bg or round(sc) not in _RUNNING_CODES, (
                    f"{h} runs on: {a} SC {sc:g}; {step}"
                )
            self.stopping.append((axes, h, now + STOP_TIME))

    def record(self, handle: aio.AsyncMoveHandle) -> Running:
        """Keep a handle the step started (the sync fuzz's bookkeeping)."""
        self.handles[id(handle.sync)] = handle
        self.started(handle.sync, False)
        return self.running[-1]

    async def wait_for_run(self, run: Running, *, watch: bool = False) -> None:
        """Await ``run`` (a jog with a timeout: it never ends); its outcome is judged after
        the step."""
        h = run.handle
        handle = self.handles[id(h)]
        self.owned.append(h)
        timeout = 5.0 if math.isinf(h.duration) else None
        result: MoveResult | None = None
        limited: MotionError | None = None
        try:
            with warnings.catch_warnings():
                if run.unpredictable:  # (not the library's doing)
                    warnings.simplefilter("ignore", RuntimeWarning)
                if watch:
                    async for _ in handle.watch(timeout):
                        pass
                result = await handle.wait(timeout)
        except MotionError as exc:  # a limit stopped it (or a follower of it)
            limited = exc
        except GalilTimeoutError:
            pass
        self.outcomes.append((run, result, limited))

    # -- setup ------------------------------------------------------------------------------
    @initialize(reconnect=st.booleans())
    def setup(self, reconnect: bool) -> None:
        if reconnect:  # (a dead link reopened by itself: a query that met it asked again)
            self.run(self.c.aclose())
            self.c = self.run(aio.connect("sim://DMC-4040", reconnect=True))
            self.dmc = self.c.sync
            self.sim = sim_of(self.dmc)
            self.threads_connected = set(threading.enumerate())
        for a in AXES:
            self.sim.set_home_switch(a, edge=-3000, index_period=2000)
            self.run(self.c.axes[a].set_home_speed(2000))

    # -- settings ---------------------------------------------------------------------------
    def write_setting(self, a: str, what: str, value: float) -> None:
        self.run(getattr(self.c.axes[a], f"set_{what}")(value))

    @rule(
        a=axis_st,
        what=st.sampled_from(["speed", "accel", "decel", "smoothing"]),
        i=st.integers(0, 3),
    )
    def set_parameter(self, a: str, what: str, i: int) -> None:
        self.set_setting(a, what, _VALUES[what][i])

    @rule(
        pick=pick_st,
        what=st.sampled_from(["motor_type", "brush", "encoder_config"]),
        i=st.integers(0, 1),
    )
    def motor_setting(self, pick: int, what: str, i: int) -> None:
        moving = [a for r in self.running for a in r.handle.axes + r.handle.followers]
        a = _picked(sorted(set(moving)) or list(AXES), pick)
        values = {"motor_type": [1, -1], "brush": [0, 1], "encoder_config": [10, 0]}
        self.set_setting(a, what, values[what][i])

    @rule(
        a=axis_st,
        low=st.sampled_from([None, -20000, -5000]),
        high=st.sampled_from([None, 5000, 20000]),
    )
    def soft_limits(self, a: str, low: int | None, high: int | None) -> None:
        self.run(self.c.axes[a].set_soft_limits((low, high)))
        self.limits_changed(a)

    @rule(a=axis_st, ld=st.sampled_from(list(galil.LimitDisable)))
    def limit_disable(self, a: str, ld: galil.LimitDisable) -> None:
        axis = self.c.axes[a]
        before = self.run(axis.limit_disable())
        self.run(axis.set_limit_disable(ld))
        assert self.run(axis.limit_disable()) == ld
        self.limits_changed(a)
        if (before.forward and not ld.forward) or (before.reverse and not ld.reverse):
            self.interfere(a)

    # -- moves ------------------------------------------------------------------------------
    def start(
        self, make: Callable[[], Awaitable[aio.AsyncMoveHandle]], wait: bool, how: str, n: int
    ) -> None:
        """Start motion (and await it), as ``how`` says; a refusal is checked."""

        async def body() -> None:
            run = self.record(await make())
            if wait:
                await self.wait_for_run(run)

        with self.refusable(InvalidArgument, MotionError), contextlib.suppress(_CancelledError):
            self.act(body, how, n)

    @rule(
        a=axis_st,
        relative=st.booleans(),
        amount=st.integers(-30000, 30000),
        wait=st.booleans(),
        how=how_st,
        n=call_st,
    )
    def move(self, a: str, relative: bool, amount: int, wait: bool, how: str, n: int) -> None:
        ax = self.c.axes[a]
        self.start(lambda: ax.move_by(amount) if relative else ax.move_to(amount), wait, how, n)

    @rule(
        axes=st.sampled_from(["AB", "BC", "CD", "AD", "ABC"]),
        amount=st.integers(-9000, 9000),
        wait=st.booleans(),
        how=how_st,
        n=call_st,
    )
    def move_together(self, axes: str, amount: int, wait: bool, how: str, n: int) -> None:
        self.start(lambda: self.c.move({a: amount for a in axes}, relative=True), wait, how, n)

    @rule(
        moves=st.lists(
            st.tuples(axis_st, st.integers(-20000, 20000)),
            min_size=2,
            max_size=4,
            unique_by=lambda m: m[0],
        ),
        group=st.booleans() if HAS_TIMEOUT else st.just(False),
        how=how_st,
        n=call_st,
    )
    def gathered(self, moves: list[tuple[str, int]], group: bool, how: str, n: int) -> None:
        """Moves of several axes started with ``asyncio.gather`` (each may be refused on its
        own: documented errors only), then their ``wait()`` coroutines awaited together:
        ``gather``-ed (each wait to its own end), or in a ``TaskGroup`` (a limit's
        ``MotionError`` cancels the other waits, which stops their moves). Cancelled, even
        before a wait has begun, every move stops (decision 0061)."""

        async def body() -> None:
            starts = [asyncio.ensure_future(self.c.axes[a].move_by(d)) for a, d in moves]
            try:
                out = await asyncio.gather(*starts, return_exceptions=True)
            except asyncio.CancelledError:
                # A start that had returned is not cancelled (gather drops its handle): its
                # move goes on, nothing of the library awaits it.
                for t in starts:
                    if t.done() and not t.cancelled() and t.exception() is None:
                        self.unawaited.append(self.record(t.result()).handle)
                raise
            runs = []
            for got in out:
                if isinstance(got, BaseException):
                    assert isinstance(got, (InvalidArgument, MotionError, *self.dead)), repr(got)
                else:
                    runs.append(self.record(got))
            if dead := [e for e in out if _died(e)]:
                # (the link died under one start: the others' moves are the caller's, who
                # has their handles and never awaits them)
                self.unawaited.extend(r.handle for r in runs)
                raise dead[0]
            self.owned.extend(r.handle for r in runs)
            with warnings.catch_warnings():
                if any(r.unpredictable for r in runs):  # (not the library's doing)
                    warnings.simplefilter("ignore", RuntimeWarning)
                await self.waits_together(runs, group)

        with contextlib.suppress(_CancelledError):
            self.act(body, how, n)

    async def waits_together(self, runs: list[Running], group: bool) -> None:
        """The library's own wait coroutines of ``runs``, gathered or in a ``TaskGroup``;
        the outcomes of those that ended are judged after the step."""
        waits = [self.handles[id(r.handle)].wait() for r in runs]
        tasks: list[asyncio.Future[MoveResult]] = []
        errors: tuple[BaseException, ...] = ()
        cancelled = False
        try:
            if not group:
                tasks = [asyncio.ensure_future(w) for w in waits]
                await asyncio.gather(*tasks, return_exceptions=True)
            else:
                async with asyncio.TaskGroup() as tg:  # type: ignore[attr-defined]
                    tasks = [tg.create_task(w) for w in waits]
        except BaseExceptionGroup as eg:  # noqa: F821 - 3.11+
            errors = eg.exceptions
            if group:
                _undo_the_groups_own_cancel(tg)
            # A TaskGroup whose wait failed while the step's task was being cancelled raises
            # the group, not CancelledError, and the cancel stays pending on the task: caught
            # here, it would be lost (Python 3.11's cancelling() also counts the TaskGroup's
            # own cancel of its parent, so the trap says whether it cancelled).
            cancelled = self.cancel_asked
        finally:
            for run, task in zip(runs, tasks, strict=True):
                if task.done() and not task.cancelled():
                    error = task.exception()
                    if error is None:
                        self.outcomes.append((run, task.result(), None))
                    elif isinstance(error, MotionError) and not _died(error):
                        self.outcomes.append((run, None, error))  # a limit stopped it
        assert all(isinstance(e, (MotionError, *self.dead)) for e in errors), errors
        ended = [t.exception() for t in tasks if t.done() and not t.cancelled()]
        for error in ended:
            assert isinstance(error, (type(None), MotionError, GalilTimeoutError, *self.dead))
        if errors:
            self.stopped_siblings(runs)
        if cancelled:
            raise asyncio.CancelledError
        if dead := [e for e in (*errors, *ended) if _died(e)]:
            raise dead[0]  # (the step was cut short by the dead link)

    def stopped_siblings(self, runs: list[Running]) -> None:
        """A TaskGroup's MotionError cancelled the other waits: their moves were stopped."""
        done = {id(r) for r, _, _ in self.outcomes}
        for run in runs:
            if id(run) not in done:
                self.interfere(run.handle.axes)
                self.stopping.append((run.handle.axes, run.handle, self.dmc.link.clock() + 3.5))

    @rule(a=axis_st, speed=st.sampled_from([-30000, -4000, 3000, 20000]), how=how_st, n=call_st)
    def jog(self, a: str, speed: int, how: str, n: int) -> None:
        try:
            self.start(lambda: self.c.axes[a].jog(speed), False, how, n)
        except CommandError as exc:  # (a program's move in place of the library's jog)
            self.judge_tc13(a, exc)

    @rule(a=axis_st, speed=st.sampled_from([-8000, 1000, 12000]))
    def set_jog_speed(self, a: str, speed: int) -> None:
        refused: CommandError | None = None
        try:
            with self.refusable(InvalidArgument, MotionError):
                self.run(self.c.axes[a].set_jog_speed(speed))
        except CommandError as exc:  # documented: a move the library did not start (TC 13)
            refused = exc
        if refused is not None:
            assert not self._free(a), refused
            assert refused.code == 13, refused

    @rule(a=axis_st, n=st.sampled_from([-2000, -3, 5, 1500]))
    def increment(self, a: str, n: int) -> None:
        refused: CommandError | None = None
        try:
            self.start(lambda: self.c.axes[a].increment(n), False, "plain", 0)
        except CommandError as exc:  # documented: a reversal of the program's move (TC 16)
            refused = exc
        if refused is not None:
            assert not self._free(a), refused
            assert refused.code == 16, refused

    @rule(a=axis_st, sign=st.sampled_from([-1, 1]), wait=st.booleans(), how=how_st, n=call_st)
    def speed_schedule(self, a: str, sign: int, wait: bool, how: str, n: int) -> None:
        self.start(
            lambda: self.c.axes[a].speed_schedule(
                sign * 12000, [(4000, 8000), (8000, 3000)], speed=15000
            ),
            wait,
            how,
            n,
        )

    @rule(
        a=axis_st,
        kind=st.sampled_from(["home", "find_edge", "find_index"]),
        wait=st.booleans(),
        how=how_st,
        n=call_st,
    )
    def home(self, a: str, kind: str, wait: bool, how: str, n: int) -> None:
        switch = self.sim.home_switch(a)
        self.start(lambda: getattr(self.c.axes[a], kind)(switch=switch), wait, how, n)

    @rule(
        axes=st.sampled_from(["AB", "CD", "BD"]),
        dx=st.integers(-8000, 8000),
        dy=st.integers(-8000, 8000),
        wait=st.booleans(),
        how=how_st,
        n=call_st,
    )
    def vector_move(self, axes: str, dx: int, dy: int, wait: bool, how: str, n: int) -> None:
        path = [Line(dx, dy), Line(-dy, dx)]
        self.start(lambda: self.c.vector_move(axes, path, speed=20000), wait, how, n)

    @rule(pick=pick_st, how=how_st, n=call_st, watch=st.booleans())
    def wait_one(self, pick: int, how: str, n: int, watch: bool) -> None:
        """Await a handle started before (through ``watch()`` first, or not)."""
        if self.running:
            run = _picked(self.running, pick)
            with contextlib.suppress(_CancelledError):
                self.act(lambda: self.wait_for_run(run, watch=watch), how, n)

    @rule(a=axis_st, position=st.sampled_from([0, -7000, 12000]), shift=st.booleans())
    def define_position(self, a: str, position: int, shift: bool) -> None:
        axis = self.c.axes[a]
        self.judge_define(
            a, position, lambda: self.run(axis.define_position(position, shift_limits=shift))
        )

    # -- gearing ----------------------------------------------------------------------------
    @rule(
        follower=axis_st,
        master=st.sampled_from([*AXES, "S"]),
        ratio=st.sampled_from([-1.5, 0.5, 2.0]),
    )
    def gear(self, follower: str, master: str, ratio: float) -> None:
        with self.refusable(InvalidArgument, MotionError):
            self.gearings[follower] = self.run(self.c.axes[follower].gear_to(master, ratio))
            self.supersede(follower)

    @rule(follower=axis_st)
    def gear_off(self, follower: str) -> None:
        gearing = self.gearings.pop(follower, None)
        if gearing is not None:
            self.run(gearing.off())

    @rule(follower=axis_st, ratio=st.sampled_from([-0.5, 1.0, 3.0]))
    def gear_ratio(self, follower: str, ratio: float) -> None:
        gearing = self.gearings.get(follower)
        if gearing is not None:
            with self.refusable(InvalidArgument, MotionError):
                self.run(gearing.set_ratio(ratio))

    # -- contours ---------------------------------------------------------------------------
    @rule(
        axes=st.sampled_from(["A", "BC", "AD"]),
        reach=st.integers(-3000, 3000),
        how=how_st,
        n=call_st,
    )
    def contour(self, axes: str, reach: int, how: str, n: int) -> None:
        """A contour, run to its end or cancelled anywhere (decisions 0027, 0038): cancelled,
        it leaves no axis in contour mode, no segment held, and its axes stop."""
        path = np.outer(np.linspace(0, 1, 12), np.arange(1, len(axes) + 1) * reach).round()
        before = self.dmc.query_operands([f"_RP{a}" for a in axes])
        self.supersede(axes)  # (even if refused: harmless)
        stopped: list[MotionError] = []
        cancelled = False
        with (
            self.refusable(InvalidArgument, MotionError) as refused,
            _limit_stopped(axes, stopped),
        ):
            try:
                self.act(lambda: self.c.contour(axes, path, dt=3), how, n)
            except _CancelledError:
                cancelled = True
        if refused:
            return
        if cancelled:
            self.interfere(axes + "".join(self.dmc.tracker.followers(axes)))
            contour = self.sim.room(SimContour)
            assert not contour.axes(), f"left in contour mode: {contour.axes()}"
            assert not contour.held, f"segments held: {contour.held}"
            self.stopping.append((axes, None, self.dmc.link.clock() + 0.5))  # type: ignore[arg-type]
            return
        if not stopped or stopped[0].args[0].startswith("a follower stopped early"):
            after = self.dmc.query_operands([f"_RP{a}" for a in axes])
            assert after == list(np.add(before, path[-1])), (before, after, stopped)
        if stopped:
            self.contour_stopped_at_a_switch(axes, stopped[0])

    # -- stops, motors, time ----------------------------------------------------------------
    @rule(axes=st.sampled_from(["", "A", "B", "C", "D", "AC"]))
    def stop(self, axes: str) -> None:
        self.run(self.c.stop(axes))
        self.interfere(axes or AXES)

    @rule(pick=pick_st)
    def stop_handle(self, pick: int) -> None:
        if self.running:
            run = _picked(self.running, pick)
            self.run(self.handles[id(run.handle)].stop())
            axes = run.handle.axes
            if run.handle.kind == "vector":  # ST S: the sequence running now (decision 0034)
                axes += "".join(r.handle.axes for r in self.running if r.handle.kind == "vector")
            self.interfere(axes)

    @rule()
    def abort(self) -> None:
        codes = self.dmc.query_operands([f"_SC{a}" for a in AXES])
        limited = "".join(a for a, c in zip(AXES, codes, strict=True) if c in (2, 3))
        self.run(self.c.abort())
        self.interfere()
        self.interfere(limited, unpredictable=True)

    @rule(a=axis_st, on=st.booleans())
    def motor(self, a: str, on: bool) -> None:
        if on:
            if not self.dmc.query_operands([f"_MO{a}"])[0]:
                with self.refusable(InvalidArgument) as refused:
                    self.run(self.c.servo_here(a))
                if refused:
                    assert self.dmc.query_operands([f"_BG{a}"]) == [1], refused
                return
            self.run(self.c.servo_here(a))
            self.supersede(a)
        else:
            with self.refusable(InvalidArgument):
                self.run(self.c.motor_off(a))

    @rule(seconds=st.sampled_from([0.01, 0.1, 0.5, 2.0]), how=how_st, n=call_st)
    def sleep(self, seconds: float, how: str, n: int) -> None:
        with contextlib.suppress(_CancelledError):
            self.act(lambda: self.c.sleep(seconds), how, n)

    @rule(a=axis_st, amount=st.integers(-5000, 5000), how=how_st, n=call_st)
    def guarded_failure(self, a: str, amount: int, how: str, n: int) -> None:
        """``async with c.motion()``: a user's error (or a cancellation) in the block stops
        and waits for every axis the library moves."""

        entered: list[bool] = []

        async def body() -> None:
            async with self.c.motion():
                entered.append(True)
                self.record(await self.c.axes[a].move_by(amount))
                await self.c.sleep(0.05)
                raise BoomError

        with contextlib.suppress(BoomError, InvalidArgument, MotionError, _CancelledError):
            self.act(body, how, n)
        if not entered:
            return  # (cancelled before the block began)
        self.interfere()
        if how.startswith("drop"):
            # (the guard's ST went out and the link died while it watched the ramp down: it
            # raised the block's error once the stop was sent)
            self.run(self.c.sleep(STOP_TIME))
        assert not any(self.dmc.query_operands([f"_BG{x}" for x in AXES if self._free(x)]))

    # -- programs, I/O, capture -------------------------------------------------------------
    @rule(label=st.sampled_from(["#SEQMOVE", "#SEQIF", "#SEQTRIP"]))
    def run_program(self, label: str) -> None:
        with self.refusable(InvalidArgument):
            self.run(self.c.programs.download(PROGRAM))
            self.run(self.c.programs.run(label, thread=1))
            self.program_axis_free = False
            if (gear := self.dmc.tracker.gears.get("D")) is not None:
                self.program_gears.append(gear)
            self.interfere("D", unpredictable=True)

    @rule(timeout=st.sampled_from([0.2, 3.0]), how=how_st, n=call_st)
    def program_wait(self, timeout: float, how: str, n: int) -> None:
        """Await the test's thread (in slices of controller time): it ends, or still runs
        after ``timeout`` (documented: it is not halted), or a line of its moves of D failed
        because the test moves D behind it (a gearing, a move: documented, decision 0059)."""
        failed: ProgramError | None = None
        try:
            with contextlib.suppress(_CancelledError, GalilTimeoutError):
                self.act(lambda: self.c.programs.wait(1, timeout=timeout), how, n)
        except ProgramError as exc:
            failed = exc
        if failed is not None:
            assert failed.thread == 1, failed
            line = failed.command.replace(" ", "")
            assert line.startswith(("PRD", "BGD", "MFD", "MRD")), failed  # its moves of D

    @rule(
        kind=st.sampled_from(["output", "inputs", "analog", "wait same", "wait other"]),
        ch=st.integers(1, 8),
        how=how_st,
        n=call_st,
    )
    def io(self, kind: str, ch: int, how: str, n: int) -> None:
        """Outputs, inputs, analog inputs, and ``wait_for_input`` (its routine on a thread
        of the controller, in slices): cancelled or timed out, it leaves no thread running
        but the test's program."""
        io = self.c.io
        level = bool(self.dmc.io.inputs[ch])
        threads = [f"_XQ{t}" for t in range(8) if t != 1]
        idle = [x < 0 for x in self.dmc.query_operands(threads)]

        async def body() -> None:
            if kind == "output":
                await io.outputs.set(ch, ch % 2 == 0)
                assert await io.outputs[ch] == (ch % 2 == 0)
            elif kind == "inputs":
                assert len(await io.inputs.all()) == len(io.inputs)
            elif kind == "analog":
                await io.analog_in.all()
            else:
                high = level if kind == "wait same" else not level
                await io.wait_for_input(ch, high=high, timeout=0.6)

        with (
            self.refusable(InvalidArgument),
            contextlib.suppress(_CancelledError, GalilTimeoutError),
        ):
            self.act(body, how, n)
        xq = self.dmc.query_operands(threads)
        if how.startswith("drop"):
            # (a wait whose link died cannot halt its routine, on the last thread: it watches
            # on until its input changes, and the next wait takes the thread over)
            xq[-1] = -1
        assert all(x < 0 for x, was in zip(xq, idle, strict=True) if was), f"a routine runs: {xq}"

    @rule(seconds=st.sampled_from([0.1, 0.5]), how=how_st, n=call_st)
    def capture(self, seconds: float, how: str, n: int) -> None:
        """Start a recording and await it: a cancelled start records nothing; a cancelled
        wait leaves the recording going (documented), for the next step to stop or await."""

        async def body() -> None:
            if self.capture is None:
                self.capture = await self.c.capture(["_TPA", "_RPB"], every=8, seconds=seconds)
            recording = await self.capture.wait()
            assert len(recording) == self.capture.count, (len(recording), self.capture)
            self.capture = None

        with contextlib.suppress(_CancelledError):
            self.act(body, how, n)
        if self.capture is None and how.startswith("drop"):
            # (a start whose link died once its RC went out: nothing could stop the
            # recording, which ends by itself)
            self.run(self.c.sleep(seconds + 0.05))
        if self.capture is None:  # (what the step started is over, or never began)
            assert not self.dmc.query_operands(["_RC"])[0]

    @rule()
    def capture_stop(self) -> None:
        if self.capture is not None:
            self.run(self.capture.stop())
            self.capture = None
            assert not self.dmc.query_operands(["_RC"])[0]

    # -- invariants -------------------------------------------------------------------------
    @invariant()
    def link_in_step(self) -> None:
        assert self.run(self.c.query_number("MG 1")) == 1
        assert float(self.run(self.c.command("MG 2"))) == 2

    @invariant()
    def nothing_left_behind(self) -> None:
        """No task on the loop, no call on the worker (each thread takes one at once), no
        thread but the worker's."""
        assert not asyncio.all_tasks(self.loop), asyncio.all_tasks(self.loop)
        self.run(self.c.worker.drained())
        extra = set(threading.enumerate()) - self.threads_connected
        assert not extra, extra

    @invariant()
    def stops_over_in_time(self) -> None:
        """Motion a cancellation stopped is over by its time, unless newer motion, a master
        or the test's program moves the axis."""
        now = self.dmc.link.clock()
        due = [s for s in self.stopping if s[2] <= now]
        self.stopping = [s for s in self.stopping if s[2] > now]
        for axes, handle, _ in due:
            bg = self.dmc.query_operands([f"_BG{a}" for a in axes])
            for a, moving in zip(axes, bg, strict=True):
                if not moving or not self._free(a):
                    continue
                newer = self.dmc.tracker.active(a)
                assert newer is not None, f"{a} moves on ({handle})"
                assert newer is not handle, f"{a} moves on ({handle})"

    def teardown(self) -> None:
        dmc, sim = self.dmc, self.sim
        carried = {"D"}
        gears = {f: g.master for f, g in dmc.tracker.gears.items()}
        while grown := {f for f, m in gears.items() if m in carried} - carried:
            carried |= grown
        try:
            self.run(self.c.aclose())
            for t in self.c.worker.threads:
                t.join(5)
            sim.advance(30.0)
            before = [sim.motion(a).reference for a in AXES]
            sim.advance(1.0)
            after = [sim.motion(a).reference for a in AXES]
            moved = [a for a, x, y in zip(AXES, before, after, strict=True) if x != y]
            assert not asyncio.all_tasks(self.loop), asyncio.all_tasks(self.loop)
            left = [t for t in threading.enumerate() if t not in self.threads_before]
            assert not [t for t in left if t.is_alive()], left
            assert not moved or (set(moved) <= carried and not self.program_axis_free), moved
        finally:
            self.loop.close()


AsyncSequences.TestCase.settings = settings(
    max_examples=EXAMPLES,
    stateful_step_count=STEPS,
    derandomize=not RANDOM,
    database=None,
    deadline=None,
    # (the explain phase traces every line: with the worker threads, a failure then takes
    # minutes to report)
    phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],
    suppress_health_check=[HealthCheck.too_slow],
)
test_async_sequences = AsyncSequences.TestCase
