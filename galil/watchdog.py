"""A dead-man switch on the controller: motion stops when the host falls silent.

``controller.watchdog(timeout)`` installs a small routine (``#GWDOG``, beside the user's
program: see :mod:`galil.routines`) and runs it on a program thread. The host stamps a
heartbeat variable with the controller's ``TIME`` every ``interval`` seconds; when the
routine sees no heartbeat for ``timeout`` seconds of controller time (the host process died,
the cable was pulled, the host froze), it stops every axis with ``ST`` (a deceleration at
each axis's DC), sets ``gwfire=1`` and prints a message. A clean :meth:`Controller.close`
halts the routine first: leaving on purpose is not dying.

The routine takes one program thread (by default the last one that runs neither a program nor
another of this session's library routines: an input wait's, say; decision 0086); it refuses
a named thread that runs a program, so it never takes one the user's programs need without
saying so.

One watchdog guards a controller: its variables (``gwbeat``, ``gwlimit``, ``gwfire``) and its
routine are the controller's, so a new watchdog replaces the running one, on any thread
(decision 0082).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import weakref
from collections.abc import Sequence
from types import TracebackType

from galil.errors import (
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    InvalidArgument,
    ReadOnly,
)
from galil.link import CommandLink, Link, check_seconds
from galil.models import INT32_MAX
from galil.protocol import commands as cmds
from galil.protocol.numbers import read_one, whole
from galil.routines import RESERVED, WATCHDOG_FIRED, Routine, Routines
from galil.units import plain_seconds

__all__ = ["LABEL", "Watchdog", "watchdog_routine"]

_LOG = logging.getLogger("galil.watchdog")

LABEL = "#GWDOG"
_LOOP = "#GWDOGL"
BEAT = "gwbeat"
LIMIT = "gwlimit"
FIRED = WATCHDOG_FIRED


def watchdog_routine(axes: str) -> Routine:
    """The routine: wait while the heartbeat is fresh, then stop ``axes`` and say so."""
    lines = (
        LABEL,
        f"{FIRED}=0",
        _LOOP,
        "WT 2",
        f"JP {_LOOP},(TIME-{BEAT})<{LIMIT}",
        cmds.st(axes).text,
        f"{FIRED}=1",
        'MG "galil watchdog: motion stopped"',  # within every model's MG text and line
        "EN",
    )
    return Routine(LABEL, lines, kind=RESERVED[LABEL])


class Watchdog(FixedAttributes):
    """The controller-side dead-man switch and the host's heartbeat. Build it with
    :meth:`galil.Controller.watchdog`.

    Attributes:
        timeout: seconds of silence after which the controller stops the axes.
        interval: seconds between heartbeats.
        thread: the program thread the routine runs on (``None`` given: the last one that
            runs neither a program nor another routine of this session's library, 0086).
    """

    timeout: ReadOnly[float] = ReadOnly()
    thread: ReadOnly[int] = ReadOnly()
    interval: ReadOnly[float] = ReadOnly()

    def __init__(
        self,
        link: Link,
        routines: Routines,
        timeout: float,
        *,
        thread: int | None,
        interval: float,
    ) -> None:
        self._link = link
        self._routines = routines
        self._timeout = timeout
        self._samples()  # (a timeout refused before the query below)
        # (None: the last thread running no program nor another routine; one query)
        self._thread = routines.default_thread(LABEL) if thread is None else thread
        self._interval = interval
        self._stop = threading.Event()
        self._beater: threading.Thread | None = None
        self._beat = cmds.stamp(BEAT)
        self._ask = cmds.mg_operand(f"_XQ{self.thread}")  # (on the beat's line: the routine runs?)
        self._lost = False  # a heartbeat found the routine not running (said once)
        self._ended = False  # a query of running found the routine not running
        self._fired = False  # the routine seen fired (by a query of fired)
        self._live = False  # started, and not stopped since
        self._halt_pending = False  # stopped on a dead link: halted once it is reopened
        self._replaced = False  # a newer watchdog guards the controller (its flag is the new's)

    def start(self) -> Watchdog:
        """Install the routine, stamp the first heartbeat, run it, and keep beating.

        Raises:
            InvalidArgument: the thread is busy, or the routine cannot be installed.
            GalilError: the routine is not running after ``XQ`` (it is halted; no heartbeat
                is started, so the watchdog never claims to guard what it does not).
        """
        return self._start(())

    def _start(self, replacing: Sequence[Watchdog]) -> Watchdog:
        """:meth:`start` in place of the watchdogs ``replacing`` (:func:`replace_running`):
        stopped once this one runs; if this one fails to start, those on other threads guard
        on with their own timeout."""
        link = self._link
        samples = self._samples()
        self._routines.check_free(self.thread, LABEL)  # before anything is sent
        # (a fresh beat on the line of every XQ that starts it again after a download or a
        # burn halted it: the last beat is as old as the halt, which outlasts a short timeout)
        self._routines.restart_with(LABEL, self._beat)
        self._routines.install(watchdog_routine(link.model.axes))
        link.command_line([cmds.assign(LIMIT, samples), self._beat])
        fired = bool(round(link.query_operands([FIRED])[0])) if replacing else False
        try:
            self._launch()
        except BaseException:
            for other in replacing:
                if other.beating:  # (its own timeout again: the limit is the controller's one)
                    with contextlib.suppress(GalilError):
                        link.command_line([cmds.assign(LIMIT, other._samples())])
            raise
        self._live = True
        _keepalives.add(link, self)
        self._stop.clear()
        self._beater = threading.Thread(target=self._run, name="galil-watchdog", daemon=True)
        self._beater.start()
        for other in replacing:
            other._replaced, other._fired = True, other._fired or fired
            other.stop()  # (on another thread, its routine halted: this one guards)
        return self

    def _launch(self) -> None:
        """Run the routine on the thread; halt it and raise if it does not run after ``XQ``."""
        self._routines.start(LABEL, self.thread)
        if not self.running:
            with contextlib.suppress(GalilError):
                self._routines.halt(self.thread)
            raise self._link.error(
                GalilError,
                f"the watchdog routine {LABEL} is not running on thread {self.thread} after "
                "XQ; the watchdog is not started",
            )

    def _samples(self) -> int:
        """The timeout in samples (``gwlimit``).

        Raises:
            InvalidArgument: not 2 to ``INT32_MAX`` samples.
        """
        ticks = self.timeout / self._link.sample_period
        samples = round(ticks) if ticks <= INT32_MAX else INT32_MAX + 1
        if not 2 <= samples <= INT32_MAX:
            raise InvalidArgument(
                f"watchdog timeout {self.timeout!r} s is not 2 to {INT32_MAX} samples"
            )
        return samples

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                replies = self._link.command_line([self._beat, self._ask])
            except GalilConnectionError:
                if not self._link.is_open:
                    return  # closed for good
            except GalilError as exc:  # a timeout or a refusal: the next beat tries again
                _LOG.debug("watchdog heartbeat failed: %s", exc)
            else:
                self._check_running(replies[-1])

    def _check_running(self, xq: str) -> None:
        """Say once, at WARNING, that the routine no longer runs while the host still beats:
        a program error without ``#CMDERR`` stops every thread, and so do an ``HX`` or ``AB``
        sent raw or by another host; nothing guards the motion then."""
        try:
            running = round(read_one(xq)) >= 0
        except GalilError:
            return
        self._say_lost(running)

    def _say_lost(self, running: bool) -> None:
        """:meth:`_check_running`'s WARNING, said once while the routine does not run."""
        if not running and not self._lost and not self._stop.is_set():
            _LOG.warning(
                "galil watchdog: the routine %s no longer runs on thread %d (a program error "
                "stops every thread; an HX or AB too): motion is not guarded; start a new "
                "watchdog (controller.watchdog(...)) to guard it again",
                LABEL,
                self.thread,
            )
        self._lost = not running

    def stop(self) -> None:
        """Stop beating and halt the routine (the axes are left as they are); idempotent."""
        self._stop.set()
        _keepalives.remove(self._link, self)  # (another watchdog's beat stays: decision 0076)
        if self._beater is not None and self._beater is not threading.current_thread():
            self._beater.join(timeout=2.0)
        self._beater = None
        if self._live:  # (a second stop halts nothing: the thread may run another routine)
            self._live, self._halt_pending = False, True
        self.reopened()

    def hand_over(self) -> None:
        """Stop beating and leave the routine to a new watchdog on the same thread: this
        one's :meth:`stop` then halts nothing."""
        self._live = self._halt_pending = False
        self.stop()

    @property
    def halt_pending(self) -> bool:
        """Whether the routine still waits for a halt: stopped while the link was dead."""
        return self._halt_pending

    def reopened(self) -> None:
        """The link works (again): a stop that could not halt the routine (its link was
        dead) halts it now, before it fires for want of the heartbeats it stopped."""
        if not self._halt_pending or self.beating:
            return
        if self._routines.holder(self.thread) != LABEL:  # (a reset halted it: nothing left)
            self._halt_pending = False
            return
        if self._link.is_open and not self._link.dead:
            with contextlib.suppress(GalilError):
                self._routines.halt(self.thread)
                self._halt_pending = False

    def recheck(self) -> None:
        """After a reopening (and the restart of the routines a dead link left halted:
        :meth:`Routines.reopened`), a watchdog that beats reads whether its routine runs (one
        query), so that its repr says whether it guards, and says at WARNING once that it
        does not (decision 0094's amendment)."""
        if not self.beating:
            return
        try:
            running = self.running
        except GalilError:
            return
        self._say_lost(running)

    @property
    def beating(self) -> bool:
        """Whether the host's heartbeat runs (started and not stopped); no query."""
        beater = self._beater
        return beater is not None and beater.is_alive()

    @property
    def running(self) -> bool:
        """Whether the routine runs on the controller (``_XQn`` is not -1); one query."""
        running = round(self._link.query_operands([f"_XQ{self.thread}"])[0]) >= 0
        self._ended = not running
        return running

    @property
    def fired(self) -> bool:
        """Whether the routine stopped the axes for want of a heartbeat; one query. Once a
        newer watchdog replaced this one (the controller's ``gwfire`` is the new one's), what
        it was when this one was replaced, with no query."""
        if self._replaced:
            return self._fired
        self._fired = bool(round(self._link.query_operands([FIRED])[0]))
        return self._fired

    def __enter__(self) -> Watchdog:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def __repr__(self) -> str:
        """The state as last seen, without a query: ``stopped`` (no heartbeat), ``fired``
        (:attr:`fired` read true), ``beating, routine not running`` (a heartbeat or
        :attr:`running` found the routine ended: nothing guards the motion), or ``beating``."""
        if not self.beating:
            state = "stopped"
        elif self._fired:
            state = "fired"
        elif self._lost or self._ended:
            state = "beating, routine not running"
        else:
            state = "beating"
        return f"<Watchdog {self.timeout:g} s on thread {self.thread}, {state}>"


def replace_running(dogs: list[Watchdog], new: Watchdog) -> Watchdog:
    """Start ``new`` as the controller's one watchdog (decision 0082) in place of ``dogs``
    that beat: one on its thread is handed over first (it stops beating, and its stop()
    halts nothing: decision 0076); those on other threads are stopped once ``new`` runs, and
    guard on if it fails to start. ``dogs`` keeps those that beat or wait for a halt, and
    ``new``.

    Raises:
        What :meth:`Watchdog.start` raises.
    """
    old = [dog for dog in dogs if dog.beating]
    for dog in old:
        if dog.thread == new.thread:
            dog.hand_over()
    try:
        new._start(old)
    finally:
        dogs[:] = [dog for dog in dogs if dog.beating or dog.halt_pending]
    dogs.append(new)
    return new


class _Keepalives:
    """The link's keepalive (which slices a simulator's pauses with heartbeats) for the
    watchdogs that beat on it: set while one beats, at the shortest interval, and cleared
    only when the last stops. A replaced watchdog stopping leaves its successor's beat in
    place (one watchdog guards a controller; several of one link beat only while one replaces
    another)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # (weak both ways: a watchdog holds its link, and neither is kept alive from here)
        self._dogs: weakref.WeakKeyDictionary[Link, weakref.WeakSet[Watchdog]] = (
            weakref.WeakKeyDictionary()
        )

    def add(self, link: Link, dog: Watchdog) -> None:
        with self._lock:
            dogs = self._dogs.setdefault(link, weakref.WeakSet())
            dogs.add(dog)
            self._set(link, dogs)

    def remove(self, link: Link, dog: Watchdog) -> None:
        with self._lock:
            dogs = self._dogs.get(link)
            if dogs is not None and dog in dogs:  # (else the others' beat is left alone)
                dogs.discard(dog)
                self._set(link, dogs)

    @staticmethod
    def _set(link: Link, dogs: weakref.WeakSet[Watchdog]) -> None:
        beating = list(dogs)
        if beating:
            link.set_keepalive(beating[0]._beat, min(d.interval for d in beating))
        else:
            link.set_keepalive(None)


_keepalives = _Keepalives()


def check_watchdog_args(
    link: CommandLink, timeout: object, thread: object, interval: object
) -> tuple[float, int | None, float]:
    """Validate ``watchdog()`` arguments before anything is sent; the thread is ``None`` when
    none is named (:meth:`galil.routines.Routines.default_thread` chooses it).

    Raises:
        InvalidArgument: a timeout that is not a positive finite number, a thread that does
            not exist, an interval not shorter than the timeout, a model with no axes.
    """
    seconds = check_seconds(timeout, "watchdog timeout", positive=True)  # a period, not a wait
    model = link.model
    if not model.has_axes:
        raise InvalidArgument(
            f"{model.name} is an I/O controller with no axes: the watchdog stops motion, and "
            "there is none to stop",
            model=model.name,
        )
    chosen = None if thread is None else whole(thread)  # (an int or a numpy integer)
    if thread is not None and (chosen is None or not 0 <= chosen < model.threads):
        raise InvalidArgument(
            f"thread must be 0..{model.threads - 1} on {model.name}, not {thread!r}",
            model=model.name,
        )
    every = seconds / 4 if interval is None else plain_seconds(interval, "heartbeat interval")
    if isinstance(every, bool) or not isinstance(every, (int, float)) or not 0 < every < seconds:
        raise InvalidArgument(
            f"heartbeat interval must be positive and shorter than the timeout, not {interval!r}"
        )
    return seconds, chosen, float(every)
