"""How long an event loop is blocked: the duration of every callback it runs.

An event loop is blocked exactly while one of its callbacks (a task step, a future's done
callback, a timer) runs; :func:`watch_loop` times each of them, on the loop's thread only, in
wall time and in CPU time of that thread::

    with watch_loop() as watch:            # inside a coroutine, on the loop to watch
        await scan()
    print(watch.max_cpu, watch.slowest)    # seconds; and which callback it was

Wall time includes waits that are not the loop's own doing (the OS running another process,
the GIL held by another thread); CPU time is the work done on the loop's thread itself, read
inside the wall interval. (On a virtual machine the thread's CPU clock also takes in what the
machine does meanwhile, interrupts or the hypervisor's work: on a shared 2-core VM about one
callback of 50 us in 60,000 read over 1 ms.) This is a diagnostic: while a watch is active,
``asyncio.Handle._run`` is wrapped (the technique of the ``aiodebug`` project), for every loop
of the process, and unwrapped when the last watch ends. It costs about a microsecond per
callback. Garbage collection that runs inside a callback is timed too (``gc``), so a pause of
the whole process can be told from the work of the callback it interrupted.
"""

from __future__ import annotations

import asyncio
import gc
import threading
import time
from array import array
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

__all__ = ["LoopWatch", "watch_loop"]

_active: dict[int, LoopWatch] = {}
_lock = threading.Lock()
_original: Callable[[asyncio.Handle], None] | None = None


@dataclass
class LoopWatch:
    """Callback durations of one loop while it was watched (seconds).

    Attributes:
        wall: wall-clock duration of each callback.
        cpu: CPU time of the loop's thread in each callback.
        gc: CPU time the garbage collector took inside each callback (a pause of the whole
            process that happened to start there, not the callback's own work).
        slowest: the repr of the callback with the longest wall time.
    """

    wall: array[float] = field(default_factory=lambda: array("d"))
    cpu: array[float] = field(default_factory=lambda: array("d"))
    gc: array[float] = field(default_factory=lambda: array("d"))
    slowest: str = ""
    _gc_started: float = 0.0
    _gc_in_step: float = 0.0
    _top_wall: float = 0.0  # the longest wall time so far (no rescan of the history)

    @property
    def steps(self) -> int:
        """Callbacks timed."""
        return len(self.wall)

    @property
    def max_wall(self) -> float:
        """Longest wall time of one callback."""
        return max(self.wall, default=0.0)

    @property
    def max_cpu(self) -> float:
        """Most CPU time of one callback."""
        return max(self.cpu, default=0.0)

    @property
    def max_own_cpu(self) -> float:
        """Most CPU time of one callback, garbage collection left out."""
        return max((c - g for c, g in zip(self.cpu, self.gc, strict=True)), default=0.0)

    def percentile(self, q: float, *, cpu: bool = False) -> float:
        """The ``q``-th percentile (0..100) of the wall (or CPU) times."""
        values = sorted(self.cpu if cpu else self.wall)
        if not values:
            return 0.0
        k = min(len(values) - 1, max(0, round(q / 100 * (len(values) - 1))))
        return values[k]

    def over(self, seconds: float, *, cpu: bool = False) -> int:
        """How many callbacks took longer than ``seconds``."""
        return sum(1 for v in (self.cpu if cpu else self.wall) if v > seconds)

    def _record(self, wall: float, cpu: float, handle: asyncio.Handle) -> None:
        if wall > self._top_wall:
            self._top_wall = wall
            self.slowest = _describe(handle)
        self.wall.append(wall)
        self.cpu.append(cpu)
        self.gc.append(self._gc_in_step)

    def summary(self) -> str:
        """One line: steps, p50/p99/max wall and max CPU in microseconds."""
        us = 1e6
        return (
            f"{self.steps} loop steps: wall p50 {self.percentile(50) * us:.0f} us, "
            f"p99 {self.percentile(99) * us:.0f} us, max {self.max_wall * us:.0f} us; "
            f"CPU max {self.max_cpu * us:.0f} us ({self.max_own_cpu * us:.0f} us without GC)"
        )


def _describe(handle: asyncio.Handle) -> str:
    """Which code a callback ran: the task's coroutine for a task step, else the handle."""
    task = getattr(getattr(handle, "_callback", None), "__self__", None)
    if isinstance(task, asyncio.Task):
        coro = task.get_coro()
        name = getattr(coro, "__qualname__", None) or repr(coro)
        return f"step of task {task.get_name()} running {name}"
    return repr(handle)


def _timed_run(handle: asyncio.Handle) -> None:
    watch = _active.get(threading.get_ident())
    run = _original
    assert run is not None
    if watch is None:
        run(handle)
        return
    watch._gc_in_step = 0.0
    # The CPU interval nests inside the wall one (the CPU clock read last at the start and
    # first at the end). Read the other way round, the CPU time also took in whatever happened
    # between the two end readings, and callbacks showed more CPU time than wall time.
    w0 = time.perf_counter()
    c0 = time.thread_time()
    try:
        run(handle)
    finally:
        c1 = time.thread_time()
        w1 = time.perf_counter()
        watch._record(w1 - w0, c1 - c0, handle)


def _gc_phase(phase: str, info: dict[str, int]) -> None:
    watch = _active.get(threading.get_ident())
    if watch is None:
        return
    if phase == "start":
        watch._gc_started = time.thread_time()
    else:
        watch._gc_in_step += time.thread_time() - watch._gc_started


@contextmanager
def watch_loop(thread: threading.Thread | None = None) -> Iterator[LoopWatch]:
    """Time every callback the event loop of ``thread`` runs inside the block.

    Args:
        thread: the loop's thread (default: the calling thread, e.g. inside a coroutine).
            Only one watch per thread at a time.

    Raises:
        RuntimeError: that thread is already watched.
    """
    global _original
    ident = (thread or threading.current_thread()).ident
    assert ident is not None
    watch = LoopWatch()
    with _lock:
        if ident in _active:
            raise RuntimeError("this thread's loop is already watched")
        if not _active:
            _original = asyncio.Handle._run
            setattr(asyncio.Handle, "_run", _timed_run)  # noqa: B010 - a method we wrap
            gc.callbacks.append(_gc_phase)
        _active[ident] = watch
    try:
        yield watch
    finally:
        with _lock:
            del _active[ident]
            if not _active:
                setattr(asyncio.Handle, "_run", _original)  # noqa: B010
                gc.callbacks.remove(_gc_phase)
                _original = None
