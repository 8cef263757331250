"""The Controller: the facade users hold, composing the rooms below it.

``connect(address)`` opens a transport (``galil.transport``), identifies the controller
(``^R^V``), routes its unsolicited output away from replies, and returns a :class:`Controller`::

    with galil.connect("tcp://192.168.0.2") as c:
        c.command("SHA")
        c.query_number("MG _TPA")        # -> 0.0
        c.messages.get(timeout=5)        # a line a program printed with MG

The facade owns no logic of its own: the link (:mod:`galil.link`) exchanges commands, the
message room (:mod:`galil.messages`) routes unsolicited output, the record room
(:mod:`galil.records`) reads data records, and the axis, motion and contour rooms move things.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
import warnings
import weakref
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from galil import predict
from galil.arrays import Arrays, Variables
from galil.axis import (
    Axis,
    MoveOverrides,
    MoveTargets,
    check_overrides,
    limits_by_axis,
    resolve_moves,
    user_units,
)
from galil.capture import Capture
from galil.contour import ContourResult, ContourStream
from galil.errors import (
    CONNECT_OPTIONS,
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
    ReadOnly,
    UnknownAxisError,
)
from galil.facade import LinkFacade
from galil.gearing import read_found
from galil.handshake import identify
from galil.homing import SwitchPolarity, read_polarity, set_polarity
from galil.interrupts import Interrupts
from galil.io import IO
from galil.link import (
    Link,
    check_count,
    check_flag,
    check_items,
    check_timeout,
)
from galil.messages import Messages
from galil.models import Identity, ModelSpec, get_model
from galil.motion import (
    MotionTracker,
    MoveHandle,
    abort_all,
    motion_guard,
    motors_off,
    moving_axes,
    servo_here,
    stop_axes,
)
from galil.moves import execute_move
from galil.programs import Programs
from galil.protocol import commands as cmds
from galil.protocol.commands import Command, Expect
from galil.protocol.numbers import read_one
from galil.records import Records
from galil.routines import Routines
from galil.segments import PathAxis, Segment, VectorPlan, show
from galil.transport import Transport, open_transport
from galil.tuning import burn, burn_parameters
from galil.units import Amount, Amounts, path_to_counts
from galil.vector import StreamOptions, VectorHandle, VectorOptions, VectorStream
from galil.watchdog import Watchdog, check_watchdog_args, replace_running

if sys.version_info >= (3, 11):
    from typing import Unpack
else:  # (typing_extensions: a dependency on Python 3.10)
    from typing_extensions import Unpack

__all__ = [
    "CLIENT_OPTIONS",
    "RESET_WAIT",
    "Controller",
    "CoordinatedMotion",
    "ReconnectPolicy",
    "Resetting",
    "connect",
    "no_axis_attribute",
]

_LOG = logging.getLogger("galil.controller")


@dataclass(frozen=True)
class ReconnectPolicy:
    """How a :class:`Controller` reopens a dead link by itself (``connect(..., reconnect=...)``).

    When the link dies, the controller reopens it (identify, route messages, ``DR`` streams
    again), waiting ``delay`` seconds between attempts (growing by ``backoff`` up to
    ``max_delay``). The query that found the link dead is asked again; a command that may have
    changed something is never sent twice: it raises :class:`GalilConnectionError` saying so.
    Every reconnect is logged at WARNING on ``galil.controller``.
    """

    attempts: int = 5
    delay: float = 0.2
    backoff: float = 2.0
    max_delay: float = 5.0

    def __post_init__(self) -> None:
        check_count(self.attempts, "attempts")
        for name, default in (("delay", 0.2), ("max_delay", 5.0)):  # (a Quantity: in seconds)
            object.__setattr__(self, name, check_timeout(getattr(self, name), default, name))
        if (
            isinstance(self.backoff, bool)
            or not isinstance(self.backoff, (int, float))
            or not (1 <= self.backoff <= 10)
        ):
            raise InvalidArgument(f"backoff must be a number in [1, 10], not {self.backoff!r}")


CLIENT_OPTIONS = frozenset(CONNECT_OPTIONS)
"""Keyword options :func:`connect` keeps for the :class:`Controller`; the rest go to the
transport opener (``baudrate=``, ``port=``, ``backend=`` ...)."""


class CoordinatedMotion:
    """Coordinated motion on a :class:`Controller` (a class of its own only to keep each
    class short): :meth:`vector_move` and :meth:`plan_vector` (see :mod:`galil.vector`)."""

    link: Link
    tracker: MotionTracker

    def axis(self, name: str) -> Axis:
        """The axis called ``name`` (the Controller's)."""
        raise NotImplementedError

    def _prepared(
        self, axes: str, segments: Sequence[Segment], **options: Unpack[StreamOptions]
    ) -> VectorStream:
        chosen = [self.axis(a) for a in _axis_names(axes, self.link)]
        path_axes = [PathAxis(a.letter, a.scale, a.display) for a in chosen]
        options.setdefault("byte_rate", self.link.byte_rate)
        with user_units({a.letter: a for a in chosen}):
            return VectorStream.prepared(self.link, path_axes, segments, self.tracker, **options)

    def vector_move(
        self,
        axes: str,
        segments: Sequence[Segment],
        *,
        speed: Amount,
        accel: Amount | None = None,
        decel: Amount | None = None,
        smoothing: float | None = None,
        mode: str | None = None,
        stream: bool = True,
        axis_speed: Mapping[str, Amount] | None = None,
        axis_accel: Mapping[str, Amount] | None = None,
    ) -> VectorHandle:
        """Run a path of :class:`~galil.Line` and :class:`~galil.Arc` segments on ``axes``
        (in the order of the segments' components), in the axes' user units.

        The whole path is predicted and checked first (:mod:`galil.vector`): a refusal names
        the segment and the sample, and nothing is sent. ``speed``, ``accel``, ``decel`` are
        along the path (Quantities when the axes share a scale, else counts; VA/VD default to
        the controller's); ``smoothing`` is VT where the model has it; ``mode`` is
        ``"vector"`` (VM, two axes, the default there) or ``"linear"`` (LM); ``stream=False``
        refuses a path longer than the buffer; ``axis_speed``/``axis_accel`` cap an axis's
        share (``{"B": 20 * mm / s}``). Returns once everything is sent (streamed if needed).

        Returns:
            A :class:`~galil.vector.VectorHandle` (``wait()``, ``stop()``, ``profiles``,
            ``vector``: the prediction in user units, ``begin``).
        """
        run = self._prepared(
            axes, segments, speed=speed, accel=accel, decel=decel, smoothing=smoothing,
            mode=mode, stream=stream, axis_speed=axis_speed, axis_accel=axis_accel,
        )  # fmt: skip
        return run.start(self.tracker)

    def plan_vector(
        self, axes: str, segments: Sequence[Segment], **options: Unpack[VectorOptions]
    ) -> VectorPlan:
        """Predict and check :meth:`vector_move` (same arguments) without sending anything.

        Returns:
            A :class:`~galil.segments.VectorPlan`: ``duration``, ``position(axis)`` and
            ``profiles`` per axis, ``path`` and ``speed`` along the path (in the axes' common
            unit), ``plot()``.
        """
        run = self._prepared(axes, segments, **options)
        assert run.profile is not None
        return show(run.profile, run.axes, run.path)


#: ``RS``: its reply may be ``:`` or nothing (a controller may reset before it answers).
_RS = Command("RS", Expect.ANY)
#: Seconds :meth:`Controller.reset` waits by default for the controller to answer again.
RESET_WAIT = 10.0


class Resetting:
    """:meth:`reset` of a :class:`Controller` (a class of its own only to keep each class
    short; see docs/decisions/0031)."""

    link: Link
    tracker: MotionTracker
    routines: Routines
    messages_room: Messages
    records_room: Records
    interrupts: Interrupts
    identity: Identity | None
    echo: bool
    _identity: Identity | None
    _echo: bool
    _watchdogs: list[Watchdog]
    _life: threading.RLock
    _factory: Callable[[], Transport] | None
    _handshake: bool
    _unsolicited: bool
    _given_model: ModelSpec | None
    _keep_echo: bool
    _axes: dict[str, Axis] | None

    def reconnect(self) -> None:
        """Close the link and open it again (the Controller's)."""
        raise NotImplementedError

    def reset(self, timeout: float | None = None) -> None:
        """Reset the controller (``RS``) and set the link up again, as at connect.

        In order: every axis is stopped (``ST``) and waited for, and the moves in progress
        end with their results (as a stop would); the watchdogs halt; ``RS`` goes out (the
        controller returns to its power-on state: the burned parameters, variables and
        program, which runs from ``#AUTO``; what was not burned is gone: decision 0052);
        once it answers ``^R^V`` again the link is set up as at connect (the echo, ``CW 1``
        or ``CF I`` for unsolicited output, ``DR`` streams, interrupts), and the library
        forgets what ``RS`` made false: gearing links (the ratios are read again: an axis a
        burned ``GA``/``GR`` geared again is found, as at connect, and its own motion refused
        until ``gear_off()``: decision 0055), homed flags, its routines in program memory,
        the sample period (``TM`` read again). The watchdogs then start again. If the
        controller dropped the link, it is reopened (from the address) within ``timeout``.

        ``RS`` sent as a raw command is refused: this is the way to reset.

        Args:
            timeout: seconds to wait for the axes to stop and for the controller to answer
                again (default 10).

        Raises:
            InvalidArgument: a bad timeout (nothing sent).
            GalilConnectionError: the link is closed, or the controller did not answer
                again within ``timeout``.
        """
        wait = check_timeout(timeout, RESET_WAIT)
        link = self.link
        _refuse_closed(link)
        # The tracker's lock from the stop to the end: no other thread's start can come
        # between the stop and RS (RS would end it unseen) or meet a link half set up.
        with self._life, self.tracker.lock:
            _stop_and_settle(link, self.tracker, wait)
            dogs = [d for d in self._watchdogs if d.beating]
            for dog in dogs:
                dog.stop()
            self.records_room.suspend()
            self.interrupts.close(keep_mask=True)
            try:
                try:
                    self._set_up_again(self._send_reset(), wait)
                except GalilConnectionError:
                    if self._factory is None or not link.dead:
                        raise
                    self._reconnect_within(wait)
            except BaseException:
                self._after_failed_reset(dogs, wait)
                raise
            self._forget_reset()
            for dog in dogs:
                dog.start()

    def _after_failed_reset(self, dogs: list[Watchdog], wait: float) -> None:
        """A reset that failed (Ctrl-C, no answer, a refusal) on a link that still works:
        the link is set up again as at connect, the streams, interrupts and watchdogs go on.
        If even that fails, the streams end with an error saying so and interrupts are
        closed (``reconnect()`` brings both back). On a dead link ``reconnect()`` does it
        all (the error says to call it)."""
        link = self.link
        if not link.is_open or link.dead:
            return
        try:
            self.records_room.suspend()  # (those the failed reset resumed already)
            self.interrupts.close(keep_mask=True)
            self._set_up_again(None, wait)
            for dog in dogs:
                dog.start()
        except BaseException as exc:  # the reset's own error is raised
            self.records_room.abandon(
                link.error(
                    GalilConnectionError,
                    f"a reset failed and the link could not be set up again ({exc!r}): the "
                    "record stream ended; call reconnect()",
                )
            )
            self.interrupts.close(keep_mask=True)

    def _send_reset(self) -> int | None:
        """``RS``, with ``MG _CW`` and ``CW 1`` right behind it where output is marked (what
        ``#AUTO`` prints at once is then marked already); returns ``_CW`` after ``RS``."""
        link = self.link
        marking = self._handshake and self._unsolicited and self.messages_room.marking
        batch = [_RS, cmds.mg_operand("_CW"), cmds.cw(1)] if marking else [_RS]
        with link.locked():
            try:
                done = link.roundtrip_locked(batch, link.timeout)
            except (GalilTimeoutError, ProtocolError):
                return None  # reset before it answered: the link starts afresh anyway
        if len(done) == 3 and done[1].ok:
            with contextlib.suppress(InvalidArgument, ProtocolError):
                value = round(read_one(done[1].text))
                return value if value in (1, 2) else None
        return None

    def _set_up_again(self, previous_cw: int | None, wait: float) -> None:
        """The handshake again on the same transport (``previous_cw``: ``_CW`` after RS)."""
        link = self.link
        assert link.transport is not None
        link.attach(link.transport)  # a fresh session, nothing to restore, stale bytes gone
        self.records_room.reset()
        if self._handshake:
            deadline = link.clock() + wait  # (the controller's clock: a simulator's too)
            with link.rebooting():  # (silent while it boots: not a dead link; decision 0089)
                while True:
                    try:
                        self._identity, self._echo = identify(
                            link, self._given_model, keep_echo=self._keep_echo
                        )
                        break
                    except GalilConnectionError:
                        if link.dead or link.clock() >= deadline:
                            raise
            if self._unsolicited:
                self.messages_room.after_reset(previous_cw)
        self.records_room.resume()
        self.interrupts.reopen()

    def _reconnect_within(self, wait: float) -> None:
        deadline = time.monotonic() + wait
        while True:
            try:
                self.reconnect()
                return
            except GalilConnectionError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.2)

    def _forget_reset(self) -> None:
        """What ``RS`` made false: gearing, homed flags, the library's threads, TM; the
        ratios a burned ``GR`` restored are read with ``_TM`` (decision 0055)."""
        tracker = self.tracker
        with tracker.lock:
            for gear in list(tracker.gears.values()):
                tracker.release(gear)
            tracker.found_geared({})
        self.routines.forget()
        for axis in (self._axes or {}).values():
            axis._homing.forget()
        link = self.link
        model = link.model
        axes = model.axes if self._handshake else ""
        try:
            tm, *ratios = link.query_operands(["_TM", *(f"_GR{a}" for a in axes)])
            link.sample_period = model.sample_period_for(tm)
            tracker.found_geared(dict(zip(axes, ratios, strict=True)), readable=bool(axes))
        except GalilError:  # (one refused operand: TM, and the ratios, read apart)
            try:
                link.sample_period = model.sample_period_for(link.query_operands(["_TM"])[0])
            except GalilError:
                link.sample_period = model.sample_period
            if axes:
                read_found(link, tracker)


def _refuse_closed(link: Link) -> None:
    if not link.is_open or link.dead:
        raise link.error(
            GalilConnectionError, "the controller link is closed or dead: nothing to reset"
        )


def _stop_and_settle(link: Link, tracker: MotionTracker, wait: float) -> None:
    """``ST`` to every axis, wait (up to ``wait`` s) until none moves, and let the moves in
    progress read their ends (after ``RS`` their positions would be the power-on ones)."""
    letters = link.model.axes
    if not letters:
        return
    stop_axes(link, tracker, "")
    deadline = link.clock() + wait
    while moving_axes(link, letters) and link.clock() < deadline:
        link.pause(0.005)
    handles = {id(h): h for a in letters if (h := tracker.active(a)) is not None}
    for handle in handles.values():
        with contextlib.suppress(GalilError):
            _ = handle.done


class _PublicParts(FixedAttributes):
    """The controller's public parts, bound by its own methods (each through its private twin,
    ``self._link``) and read-only to a user, whose assignment would change what the object
    says without changing the link or the controller behind it (decision 0091)."""

    link: ReadOnly[Link] = ReadOnly()
    messages_room: ReadOnly[Messages] = ReadOnly()
    records_room: ReadOnly[Records] = ReadOnly()
    tracker: ReadOnly[MotionTracker] = ReadOnly()
    routines: ReadOnly[Routines] = ReadOnly()
    io: ReadOnly[IO] = ReadOnly()
    programs: ReadOnly[Programs] = ReadOnly()
    arrays: ReadOnly[Arrays] = ReadOnly()
    variables: ReadOnly[Variables] = ReadOnly()
    interrupts: ReadOnly[Interrupts] = ReadOnly()
    identity: ReadOnly[Identity | None] = ReadOnly()
    echo: ReadOnly[bool] = ReadOnly()


class Controller(_PublicParts, CoordinatedMotion, Resetting, LinkFacade):
    """A connected controller. Build it with :func:`connect`.

    Args:
        transport: an open transport, or a callable that opens one (used again by
            :meth:`reconnect`).
        timeout: default seconds to wait for each reply.
        model: the model name (or spec) when it is known; checked against ``^R^V``.
        handshake: identify the controller and route unsolicited output at connect; with
            ``False`` nothing is sent at connect and ``model`` is required.
        unsolicited: route unsolicited output (second Ethernet handle, else ``CW1``).
        history: exchanges kept in the ring buffer attached to errors.
        poll_interval: seconds between polls for unsolicited lines while the link is idle.
        max_messages: unsolicited lines kept in :attr:`messages` before the oldest drop.
        echo: what to do when the handshake finds the controller echoing (``EO 1``, a serial
            setting): ``False`` (default) switches the echo off with ``EO 0``, as Galil's own
            library does, and :meth:`close` switches it back on; ``True`` leaves it on and
            strips the echo from every reply.
        reconnect: reopen a dead link by itself: ``True`` (the default
            :class:`ReconnectPolicy`) or a policy; needs an address, not a transport object.

    Attributes:
        link: the command link (:class:`~galil.link.Link`).
        io: digital and analog I/O (:class:`~galil.io.IO`).
        identity: the parsed ``^R^V`` reply (``None`` without a handshake).
        echo: whether the controller echoes (found at the handshake and kept).
        programs: the user's program and threads (:class:`~galil.programs.Programs`).
        arrays: the controller's arrays (:class:`~galil.arrays.Arrays`).
        variables: the controller's variables (:class:`~galil.arrays.Variables`).
        interrupts: ``UI``/``EI`` interrupts (:class:`~galil.interrupts.Interrupts`).
    """

    def __init__(
        self,
        transport: Transport | Callable[[], Transport],
        *,
        timeout: float = 1.0,
        model: str | ModelSpec | None = None,
        handshake: bool = True,
        unsolicited: bool = True,
        history: int = 64,
        poll_interval: float = 0.02,
        max_messages: int = 1000,
        echo: bool = False,
        reconnect: bool | ReconnectPolicy = False,
    ) -> None:
        _check_options(echo, handshake, unsolicited, model)
        self._link = Link(timeout=timeout, history=history)
        self._keep_echo = echo
        self._given_model = get_model(model) if isinstance(model, str) else model
        self._handshake = handshake
        self._unsolicited = unsolicited
        self._messages_room = Messages(
            self.link,
            max_messages=max_messages,
            poll_interval=check_timeout(poll_interval, 0.02, "poll_interval"),
        )
        self._records_room = Records(self.link)
        self._tracker = MotionTracker()
        self._routines = Routines(self.link)
        self._io = IO(self.link, self.messages_room, self.routines)
        self._programs = Programs(self.link, self.routines, self.tracker)
        self._arrays = Arrays(self.link)
        self._variables = Variables(self.link)
        self._interrupts = Interrupts(self.link)
        self._watchdogs: list[Watchdog] = []
        self._captures: list[Capture] = []  # started here and not yet read back
        self._identity: Identity | None = None
        self._echo = False
        self._axes: dict[str, Axis] | None = None
        self._life = threading.RLock()  # open, close and reconnect, one at a time
        self._generation = 0
        if callable(transport) and not isinstance(transport, Transport):
            self._factory: Callable[[], Transport] | None = transport
            first: Transport | None = None
        else:
            self._factory = None
            first = transport
        self._policy = _policy(reconnect, self._factory is not None)
        self.tracker.reconnect = _reopener(self) if self._factory is not None else None
        if self._policy is not None:  # weakly: a controller dropped unclosed is still garbage
            self.link.on_dead = _weakly(self._reopen_dead_link)
        self._parts = _Parts(self.link, self.messages_room, self.records_room, self.interrupts,
                             self._watchdogs, self._life, self.io)  # fmt: skip
        self._finalizer: weakref.finalize[Any, Any] | None = None
        self._open(first)

    # -- life cycle -------------------------------------------------------------------------

    def _open(self, transport: Transport | None) -> None:
        if transport is None:
            if self._factory is None:
                raise GalilConnectionError("no transport and no address to open one")
            transport = self._factory()
        link = self.link
        link.attach(transport)
        self.tracker.closed = False
        self.records_room.reset()
        try:
            if self._handshake:
                self._identity, self._echo = identify(
                    link, self._given_model, keep_echo=self._keep_echo, expect=self.identity
                )
                if self._unsolicited:
                    self.messages_room.restart()
                read_found(link, self.tracker)  # gearing set up elsewhere (decision 0055)
            else:
                assert self._given_model is not None
                link.model = self._given_model
        except BaseException:
            link.detach()
            self.messages_room.stop()
            raise
        self._generation += 1
        self.messages_room.queue.reopen()
        self.interrupts.queue.reopen()
        if self._finalizer is None or not self._finalizer.alive:
            self._finalizer = _close_when_collected(self, self._parts)

    def close(self) -> None:
        """Stop the motion the library started, restore what connect changed (``CW``,
        ``EO``), stop the readers, close the link.

        Every move, jog, homing, vector sequence or contour started through this controller
        that it has not seen end gets its ``ST`` first (the stop is sent, not waited for):
        no motion the library started outlives the link that could stop it (a call waiting
        on it in another thread raises :class:`~galil.errors.GalilConnectionError`, and the
        move's ``add_callback`` callbacks are never called: a move not seen done when close()
        begins is never seen done, even by a poll that finds it stopped meanwhile). What
        raw commands or a program on the controller started is left as it is, and so is
        gearing (``GA``): an axis geared to one that a program or a handwheel moves goes on
        following it. The watchdog's routine is halted (leaving on purpose is not dying), and so
        is a ``wait_for_input``'s in flight (the wait raises). A capture started here and not
        read back, or cut short by a dead link, is stopped (``RC 0``: it holds the recorder).
        A waiting ``messages.get()``, ``interrupts.get()`` or record stream
        ``get()`` raises :class:`~galil.errors.GalilConnectionError` too.

        Idempotent and thread-safe; never raises for a link that is already dead (it is
        reopened once for the stops; a stop that could not be sent even so is logged at
        WARNING on ``galil.controller``). Interrupted (Ctrl-C), it still sends every stop and
        closes the link, then the exception goes on (decision 0073). No background thread
        and no controller handle outlives it.
        """
        close_after(self, None)

    def reconnect(self) -> None:
        """Close the link and open it again (same address and options), handshake included;
        then end what a dead link left running (a watchdog's halt, a capture's ``RC 0``).

        Thread-safe: several threads asking at once get one reconnect.

        Raises:
            GalilConnectionError: the controller was built on a transport object, not an
                address, or the new link fails.
        """
        if self._factory is None:
            raise GalilConnectionError(
                "this Controller was given a transport object; reconnect needs an address "
                "(use galil.connect(address))"
            )
        self._reconnect(None)

    def _reconnect(self, life_timeout: float | None) -> None:
        """:meth:`reconnect`, waiting for the life lock at most ``life_timeout`` s (``None``:
        for ever). A reopen from inside a start holds the tracker's lock, which ``close()`` and
        ``reset()`` take inside the life lock: it must not wait for ever (a deadlock with them
        in another thread), so it gives up as a failed reopen does."""
        seen = self._generation
        if not self._life.acquire(timeout=-1 if life_timeout is None else life_timeout):
            raise GalilConnectionError("another thread is closing, resetting or reopening the link")
        try:
            if self._generation != seen and self.link.is_open and not self.link.dead:
                return  # another thread reconnected while this one waited
            with self.link.reopening():  # commands meanwhile wait for the new link
                self.records_room.suspend()
                _close_parts(self._parts, keep_watchdogs=True, keep_streams=True)
                with _dead_if_failing(self.link):
                    self._open(None)
                self.records_room.resume()
                self.interrupts.reopen()
                for dog in self._watchdogs:  # (one stopped while the link was dead)
                    dog.reopened()
                self._routines.reopened()  # (halted for a DL or a burn, XQ unsent: decision 0094)
                for dog in self._watchdogs:  # (a beating one says whether it guards)
                    dog.recheck()
                _end_captures_left_quietly(self.link, self._captures)
        finally:
            self._life.release()

    def _reopen_dead_link(self, error: GalilConnectionError) -> None:
        """The automatic reconnect (:class:`ReconnectPolicy`), called by the link."""
        _reopen_with_policy(self, error)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called (or connecting failed)."""
        return not self.link.is_open

    def __enter__(self) -> Controller:
        return self

    def __exit__(self, kind: object, error: BaseException | None, tb: object) -> None:
        close_after(self, error)

    def __repr__(self) -> str:
        link = self.link
        state = "closed" if self.closed else ("dead: call reconnect()" if link.dead else "open")
        return f"<Controller {link.model_name or '?'} on {link.transport!r} {state}>"

    # -- axes -------------------------------------------------------------------------------

    @property
    def axes(self) -> dict[str, Axis]:
        """The model's axes by letter (``controller.axes["A"]``; also ``controller.A``)."""
        if self._axes is None:
            self._axes = AxisMap(
                {a: Axis(self.link, a, self.tracker, self.routines) for a in self.model.axes},
                self.model,
            )
        return self._axes

    def axis(self, name: str) -> Axis:
        """The axis called ``name`` (``"A"``, or ``"X"`` where the model aliases it).

        Raises:
            InvalidArgument: the model has no such axis, or ``name`` is an Axis, not a letter.
        """
        return self.axes[self.model.axis_letter(_letter_given(self.link, name))]

    def _letters(self, axes: str) -> str:
        if not self.model.axes:
            raise InvalidArgument(
                f"{self.model.name} is an I/O controller with no axes: it cannot move",
                model=self.model.name,
            )
        if not isinstance(axes, str):
            raise InvalidArgument(
                f"axes must be a string of axis letters, got {axes!r}{_letters_hint(axes)}",
                model=self.model.name,
            )
        out = ""
        for name in axes.replace(" ", "").replace(",", ""):
            letter = self.model.axis_letter(name)
            if letter not in out:
                out += letter
        return out

    # -- motion on several axes -------------------------------------------------------------

    def _execute(
        self, targets: MoveTargets, relative: bool, dry_run: bool, overrides: MoveOverrides
    ) -> MoveHandle:
        if not isinstance(targets, Mapping) or not targets:
            raise InvalidArgument(
                f"targets must be a non-empty mapping of axis to value, got {targets!r}"
            )
        check_flag(relative, "relative")
        axes = {name: self.axis(name) for name in targets}
        moves = resolve_moves(axes, targets, relative, overrides)
        by_letter = {a.letter: a for a in axes.values()}
        with user_units(by_letter):
            return execute_move(
                self.link,
                self.tracker,
                moves,
                relative=relative,
                dry_run=dry_run,
                display={a: ax.display for a, ax in by_letter.items()},
            )

    def move(
        self, targets: MoveTargets, *, relative: bool = False, **overrides: Unpack[MoveOverrides]
    ) -> MoveHandle:
        """Move several axes at once, sent in one line and begun together (``BG AB``).

        Args:
            targets: position (or distance with ``relative=True``) per axis, in each axis's
                units.
            relative: move by the given distances instead of to the positions.
            **overrides: ``speed``, ``accel``, ``decel`` for every axis of this move.
        """
        check_overrides("move", overrides)
        return self._execute(targets, relative, False, overrides)

    def plan(
        self, targets: MoveTargets, *, relative: bool = False, **overrides: Unpack[MoveOverrides]
    ) -> predict.MultiProfile:
        """Predict and check :meth:`move` without sending anything."""
        check_overrides("plan", overrides)
        return predict.together(self._execute(targets, relative, True, overrides).profiles)

    def stop(self, axes: str = "") -> None:
        """Decelerate axes (default: all) to a stop at their DC (``ST``).

        The predictions of the moves in progress follow the stop (it is stamped with the
        controller's ``TIME``), so their handles still compare the end with a prediction.
        """
        stop_axes(self.link, self.tracker, self._letters(axes))

    def abort(self) -> None:
        """Stop all motion at once, without deceleration (``AB 1``: programs keep running)."""
        abort_all(self.link, self.tracker)

    def servo_here(self, axes: str = "") -> None:
        """Enable the servo on axes (default: all) at their present position (``SH``);
        refused while one moves."""
        servo_here(self.link, self.tracker, self._letters(axes))  # (ends unwaited moves)

    def motor_off(self, axes: str = "") -> None:
        """Turn the motors of axes (default: all) off (``MO``); refused while one moves."""
        motors_off(self.link, self._letters(axes), self.tracker)  # (refusal: galil.motion)

    def motion(self, axes: str | None = None) -> contextlib.AbstractContextManager[None]:
        """A context in which an exception or Ctrl-C stops the guarded axes and waits for them.

        ``with controller.motion(): ...``: on any exception, ``ST`` goes to every axis still
        moving (of ``axes``, default or ``""``: all; all of them when that cannot be read), a
        dead link is reopened once to send it, and the block's exception is re-raised once they
        have stopped. If they could not be stopped, :class:`~galil.errors.MotionError` says
        which axes may still be moving.
        """
        letters = self.model.axes if axes is None else self._letters(axes) or self.model.axes
        reopen = self.reconnect if self._factory is not None else None
        return motion_guard(self.link, self.tracker, letters, reconnect=reopen)

    def watchdog(
        self, timeout: float, *, thread: int | None = None, interval: float | None = None
    ) -> Watchdog:
        """Start a dead-man switch: the controller stops every axis (``ST``) when the host has
        been silent for ``timeout`` seconds (see :mod:`galil.watchdog`).

        Args:
            timeout: seconds of controller time without a heartbeat before motion stops.
            thread: the program thread for the routine (default: the last one that runs
                neither a program nor another routine of this session's library, decision
                0086); a thread named that runs a program is refused. One watchdog guards a
                controller (decision 0082): the running one is replaced, on any thread (it
                stops beating, and its ``stop()`` halts nothing; if this one fails to start,
                it guards on).
            interval: seconds between heartbeats (default: a quarter of ``timeout``).

        Returns:
            The running :class:`~galil.watchdog.Watchdog` (``stop()``, ``fired``, a context
            manager). :meth:`close` stops it: leaving on purpose is not dying.

        Raises:
            InvalidArgument: a bad timeout, interval or thread, a busy thread, a user program
                running while the routine must be installed.
        """
        t, n, every = check_watchdog_args(self.link, timeout, thread, interval)
        dog = Watchdog(self.link, self.routines, t, thread=n, interval=every)
        return replace_running(self._watchdogs, dog)

    def contour(
        self,
        axes: str,
        path: Amounts,
        *,
        dt: int,
        progress: bool = False,
        timeout: float | None = None,
        speed_limit: Amount | Mapping[str, Amount] | None = None,
        accel_limit: Amount | Mapping[str, Amount] | None = None,
    ) -> ContourResult:
        """Run a contour path on ``axes`` and return when it is done.

        ``path`` holds ideal positions relative to where each axis is now, one per
        ``2**dt``-sample segment (shape (segments,) or (segments, axes)): plain numbers are
        counts, a pint Quantity array goes through each axis's scale. The stream is checked
        first (CD range, DT, the speed and acceleration the path implies on each axis, soft
        limits, link speed against the model's buffer), then CM/DT/CD lines keep the
        controller's buffer fed, and ``CD 0=0`` ends it.

        Args:
            axes: the contour axes, e.g. ``"AB"``.
            path: the ideal positions (see above).
            dt: the DT exponent (segments of ``2**dt`` samples).
            progress: show a progress bar over the segments.
            timeout: seconds to wait for the end after the last segment.
            speed_limit: your own limit on each axis's speed along the path (the axis's
                units; one value or a mapping per axis); default the model's SP maximum.
            accel_limit: the same for acceleration; default the model's AC maximum.

        An exception while streaming or waiting for the end (the timeout, an error, a
        ``KeyboardInterrupt``) stops the contour axes (``ST``) and leaves contour mode
        before it propagates.

        Raises:
            InvalidArgument: bad axes, path, DT, timeout (nothing sent); axis moving, motor off.
            LimitError: the path beyond the model's or the given limits (nothing sent).
            GalilTimeoutError: the contour not finished within ``timeout`` (axes stopped).
        """
        check_flag(progress, "progress")
        chosen = [self.axis(a) for a in _axis_names(axes, self.link)]
        limits = _contour_limits(self.link.model, chosen, speed_limit, accel_limit)
        stream = contour_stream(self, chosen, path, dt, limits)
        with user_units({a.letter: a for a in chosen}):
            return stream.run(progress=progress, timeout=timeout)

    # -- switches and flash (galil.homing, galil.tuning) -------------------------------------

    @property
    def switch_polarity(self) -> SwitchPolarity:
        """``CN``: limit polarity, home direction and latch edge (``MG _CN0,_CN1,_CN2``)."""
        return read_polarity(self.link)

    @switch_polarity.setter
    def switch_polarity(self, polarity: SwitchPolarity) -> None:
        set_polarity(self.link, polarity)

    def save(self, timeout: float | None = None) -> None:
        """Burn the parameters to flash (``BN``), waiting as long as a flash write takes.

        The controller's own ``CW`` and ``EO`` are burned, not the link's (decision 0057).
        ``BN`` is refused while a thread runs (TC 17): the library's own (the watchdog) are
        halted for it and started again (decision 0087).

        Raises:
            InvalidArgument: a bad ``timeout``; a program of the user's runs (nothing sent).
            CommandError: the controller refused ``BN``.
        """
        burn_parameters(self.link, timeout, self.routines)

    def save_program(self, timeout: float | None = None) -> None:
        """Burn the program to flash (``BP``), as :meth:`Programs.burn
        <galil.programs.Programs.burn>` (the watchdog halted for it and started again)."""
        burn(self.link, "BP", timeout, self.tracker, self.routines)

    def save_variables(self, timeout: float | None = None) -> None:
        """Burn the variables and arrays to flash (``BV``)."""
        burn(self.link, "BV", timeout)

    def capture(
        self,
        sources: list[str],
        *,
        every: int = 2,
        count: int | None = None,
        seconds: float | None = None,
    ) -> Capture:
        """Start recording ``sources`` on the controller, every ``every`` samples, at servo
        rate (``RA``/``RD``/``RC``); see :mod:`galil.capture`.

        Start it right before a move: its values line up sample by sample with the move's
        prediction. ``wait()`` (or leaving a ``with`` block, or ``stop()``) uploads them.

        Args:
            sources: operands (``["_RPA", "_TPA", "_TEA", "_TVA"]``).
            every: samples between values: 2, 4, ... 256 (``RC n`` records every ``2**n``).
            count: values per source; or ``seconds``: how long to record.

        Raises:
            InvalidArgument: a source ``RD`` cannot record, ``every`` not allowed, too many
                values for the array space (nothing is sent), or a recording running
                already (``_RC`` read, nothing set up).
        """
        capture = Capture(self.link, sources, every=every, count=count, seconds=seconds)
        return _start_capture(self.link, self._captures, capture)

    if not TYPE_CHECKING:  # mypy knows the letters below, and nothing else

        def __getattr__(self, name: str) -> Axis:
            return self._axis_attribute(name)

    def _axis_attribute(self, name: str) -> Axis:
        # Only single axis letters reach here (and X/Y/Z/W aliases where the model has them).
        link = self.__dict__.get("_link")
        model = None if link is None else link._model
        if len(name) == 1 and name.isupper() and model is not None:
            try:
                return self.axes[model.axis_letter(name)]
            except InvalidArgument:
                pass
        raise no_axis_attribute(type(self).__name__, name, model)

    # Typed axis attributes: mypy sees ``connect(...).A`` as an Axis.
    A: Axis
    B: Axis
    C: Axis
    D: Axis
    E: Axis
    F: Axis
    G: Axis
    H: Axis
    X: Axis
    Y: Axis
    Z: Axis
    W: Axis


@dataclass(frozen=True)
class _Parts:
    """What closing a controller needs, without the controller (a finalizer holds it)."""

    link: Link
    messages: Messages
    records: Records
    interrupts: Interrupts
    watchdogs: list[Watchdog]
    life: threading.RLock
    io: IO


def _close_parts(parts: _Parts, *, keep_watchdogs: bool, keep_streams: bool = False) -> None:
    """Halt the watchdogs, close the streams, then the link and its reader: those last
    whatever interrupts the exchanges before them (a Ctrl-C goes on once they are closed)."""
    try:
        if not keep_watchdogs:
            for dog in parts.watchdogs:
                dog.stop()  # leaving on purpose is not dying: the routine is halted
            parts.watchdogs.clear()
            parts.io.end_wait()  # a wait_for_input's routine too (its waiter raises)
        if not keep_streams:
            parts.records.close_all()
            parts.interrupts.disable()
        else:
            parts.interrupts.close(keep_mask=True)
    finally:
        parts.link.detach()
        parts.messages.stop()
        if not keep_streams:  # closed for good: whoever waits for a line hears so
            parts.messages.queue.close()
            parts.interrupts.queue.close()


def close_after(c: Controller, error: BaseException | None) -> None:
    """``c.close()``, at the end of a ``with`` block (``error``: the exception that ended it,
    or ``None``): the warning for the motion it stops says why it was stopped."""
    if c._finalizer is not None:
        c._finalizer.detach()
    with c._life:
        try:
            _stop_started(c.link, c.tracker, error)
        finally:  # (Ctrl-C while stopping: the close still ends, then it goes on)
            if c.link.is_open:
                _stop_captures(c.link, c.tracker, c._captures)
            _close_parts(c._parts, keep_watchdogs=False)
            c.tracker.end_watches()


def _stop_started(link: Link, tracker: MotionTracker, error: BaseException | None) -> None:
    """Closing: stop what the library started (on a link still open); a call that finds the
    link closed from now on has nothing left to stop (``tracker.closed``). ``error``: the
    exception that ended the ``with`` block closing it (the warning says so)."""
    tracker.closed = True
    if not link.is_open:
        return
    interrupted: BaseException | None = None
    try:
        running = _moving(link, tracker.still_running(link.clock()))
    except BaseException as exc:  # (Ctrl-C: the stops go out all the same, then it goes on)
        running, interrupted = "", exc
    tracker.closing = True  # (a link that dies under the stops is reopened for them)
    try:
        failed, stop_interrupted = tracker.stop_started(link)
    finally:
        tracker.closing = False
        tracker.closed = True  # (a reopen for the stops set the link up as for use)
    interrupted = interrupted or stop_interrupted
    if running:
        _warn_stopped(link, running, error, tracker.wait_hint)
    if failed:
        _LOG.warning(
            "galil: closing the link to %s: the stop of axes %s could not be sent; they may "
            "still be moving",
            link.model_name,
            ", ".join(dict.fromkeys(failed)),
        )
    if interrupted is not None:
        raise interrupted


def _warn_stopped(link: Link, running: str, error: BaseException | None, hint: str) -> None:
    """Closing stopped motion the library started: say why, and what to do about it
    (``hint``: how to wait for a move, :attr:`MotionTracker.wait_hint`)."""
    if error is not None:  # (motion never outlives an exception: stopping was the point)
        _LOG.warning(
            "galil: closing the link to %s stopped axes %s mid-motion: the with block ended "
            "with an exception (%s)",
            link.model_name,
            ", ".join(running),
            type(error).__name__,
        )
        return
    _LOG.warning(  # (a script that left its with block without wait(): "nothing happened")
        "galil: closing the link to %s stopped axes %s mid-motion (started here, not "
        "waited for: %s before closing or leaving the with block)",
        link.model_name,
        ", ".join(running),
        hint,
    )


def _moving(link: Link, letters: str) -> str:
    """:func:`~galil.motion.moving_axes`, ``""`` when the query fails: closing goes on."""
    try:
        return moving_axes(link, letters)
    except GalilError:
        return ""


def _axis_names(axes: object, link: Link) -> list[str]:
    """The axes of a path or contour: a string of letters (``"AB"``) or a list of names."""
    if isinstance(axes, str):
        return list(axes)
    return [str(_letter_given(link, a)) for a in check_items(axes, "axes")]


def _letter_given(link: Link, name: Any) -> Any:
    """``name``, where an axis is named by its letter; an :class:`Axis` object is refused
    saying so (and whose it is: this controller's, or another's).

    Raises:
        InvalidArgument: ``name`` is an Axis.
    """
    if not isinstance(name, Axis):
        return name
    model = link.model
    if name._link is not link:
        raise InvalidArgument(
            f"{name!r} is an axis of another controller: name this controller's axes by "
            f"their letters ({', '.join(model.axes)})",
            model=model.name,
        )
    raise InvalidArgument(
        f"axes are named by their letters here: give {name.letter!r}, not {name!r}",
        model=model.name,
    )


def _letters_hint(axes: object) -> str:
    """What a refusal of ``axes`` that are not a string of letters adds when they are an
    axis (sync or async) or axes: the string to give instead (``: give 'A'``)."""
    given = list(axes) if isinstance(axes, (list, tuple, set, frozenset)) else [axes]
    letters = [getattr(a, "letter", None) for a in given]
    if not given or not all(isinstance(x, str) for x in letters):
        return ""
    return f": axes are named by their letters here, give {''.join(map(str, letters))!r}"


def _check_options(echo: object, handshake: object, unsolicited: object, model: object) -> None:
    """The connect options checked before anything is opened.

    Raises:
        InvalidArgument: a flag that is not a bool, a model that is neither a name nor a
            ModelSpec, or ``handshake=False`` without a model.
    """
    for flag, value in (("echo", echo), ("handshake", handshake), ("unsolicited", unsolicited)):
        if not isinstance(value, bool):
            raise InvalidArgument(f"{flag} must be True or False, not {value!r}")
    if model is not None and not isinstance(model, (str, ModelSpec)):
        raise InvalidArgument(f"model is a name such as 'DMC-4040' or a ModelSpec: {model!r}")
    if not handshake and model is None:
        raise InvalidArgument("handshake=False needs model= (nothing identifies it then)")


def _holds_recorder(capture: Capture) -> bool:
    """Whether ``capture`` may still record: started and not read back, or owed an ``RC 0``
    (its start or stop cut short)."""
    return capture.stop_pending or (capture.result is None and capture.start_sample is not None)


def _start_capture(link: Link, captures: list[Capture], capture: Capture) -> Capture:
    """Start ``capture`` once the captures a dead link left recording are stopped, and keep
    it among ``captures`` while it may record (a start whose ``RC 0`` could not go out too:
    it is stopped once the link works). Earlier captures not read back lose their arrays to
    it: their ``wait()`` and ``stop()`` refuse from then on."""
    _end_captures_left(link, captures)
    captures[:] = [c for c in captures if _holds_recorder(c)]
    earlier = list(captures)
    try:
        capture.start()
    except InvalidArgument:
        raise  # (refused before its arrays were touched: the earlier ones stay readable)
    except BaseException:
        _reused(captures, earlier)  # (their arrays may have been freed or redefined already)
        raise
    finally:
        if _holds_recorder(capture):
            captures.append(capture)
    _reused(captures, earlier)
    return capture


def _reused(captures: list[Capture], earlier: list[Capture]) -> None:
    """A new capture took the arrays (the same ``gcap`` names) of the ``earlier`` ones, not
    read back: they refuse to be read, and no longer hold the recorder."""
    for capture in earlier:
        capture.reused()
    captures[:] = [c for c in captures if c not in earlier]


def _end_captures_left(link: Link, captures: list[Capture]) -> None:
    """``RC 0`` for the captures a dead link (or a Ctrl-C) left recording (decision 0085),
    said at WARNING on ``galil.controller`` when one was still recording.

    Raises:
        GalilError: the link failed (they stay owed).
    """
    for capture in [c for c in captures if c.stop_pending]:
        if capture.reopened():
            _LOG.warning(
                "galil: the capture of %s on %s was still recording after its %s was cut "
                "short; it is stopped now (RC 0)",
                ", ".join(capture.sources),
                link.model_name,
                "start" if capture.start_sample is None else "stop",
            )


def _end_captures_left_quietly(link: Link, captures: list[Capture]) -> None:
    """:func:`_end_captures_left` on a reopen: a failure is logged (they stay owed: the next
    capture, reopen or ``close()`` tries again)."""
    try:
        _end_captures_left(link, captures)
    except GalilError as exc:
        _LOG.warning(
            "galil: RC 0 for a capture left recording on %s not sent (%s)", link.model_name, exc
        )


def _stop_captures(link: Link, tracker: MotionTracker, captures: list[Capture]) -> None:
    """Closing: ``RC 0`` if a capture started here has not been read back, or is owed one (it
    may still record: the next one would be refused until its count was reached); nothing
    sent otherwise. A dead link is reopened once for it, as for the stops (decision 0085)."""
    if not any(_holds_recorder(c) for c in captures):
        return
    if link.dead and tracker.reconnect is not None:
        with contextlib.suppress(GalilError):
            tracker.reconnect()  # (its own reopen sends the RC 0 owed)
        tracker.closed = True  # (the reopen set the link up as for use)
    try:
        link.command_line([cmds.rc(0)])
    except GalilError as exc:
        _LOG.warning("galil: closing the link to %s: RC 0 not sent (%s)", link.model_name, exc)


def _close_when_collected(controller: Controller, parts: _Parts) -> weakref.finalize[Any, Any]:
    """Close ``parts`` if ``controller`` is garbage-collected unclosed, with a ResourceWarning
    (as an unclosed socket). Not at interpreter exit: the process's end closes its sockets."""
    finalizer = weakref.finalize(controller, _collected, parts, repr(controller))
    finalizer.atexit = False
    return finalizer


def _collected(parts: _Parts, name: str) -> None:
    warnings.warn(
        f"{name} was never closed: call close() or use `with galil.connect(...)`; its link "
        "is closed now (motion it started is not stopped)",
        ResourceWarning,
        stacklevel=1,
    )
    _close_in_background(parts)


def _close_in_background(parts: _Parts) -> None:
    # On a thread of its own: a collection may run on a thread that holds the link's lock.
    with contextlib.suppress(RuntimeError):  # at shutdown, the process closes the rest
        threading.Thread(
            target=_close_quietly, args=(parts,), name="galil-finalize", daemon=True
        ).start()


def close_collected(controller: Controller) -> None:
    """Close ``controller`` as its garbage collection would (its link, readers and streams,
    on a thread of its own; motion is not stopped), without its warning: for a wrapper
    collected unclosed that warned in its own words (the async controller)."""
    if controller._finalizer is not None:
        controller._finalizer.detach()
    _close_in_background(controller._parts)


@contextlib.contextmanager
def _dead_if_failing(link: Link) -> Iterator[None]:
    """A reopen that fails leaves the link dead, not closed (decision 0075): the motion the
    library started may still run, and a later reopen (another reconnect(), a guard's,
    close()'s) can stop it."""
    try:
        yield
    except BaseException as exc:
        text = str(exc).splitlines()
        link.failed(f"reopening it failed: {text[0] if text and text[0] else type(exc).__name__}")
        raise


def _close_quietly(parts: _Parts) -> None:
    with parts.life, contextlib.suppress(GalilError, OSError):
        _close_parts(parts, keep_watchdogs=False)


def _reopen_with_policy(controller: Controller, error: GalilConnectionError) -> None:
    """Reconnect ``controller`` by its :class:`ReconnectPolicy`: its attempts, delays and backoff;
    each failure logged, the last one raised from ``error``."""
    policy = controller._policy
    assert policy is not None
    delay = policy.delay
    name = controller.link.model_name  # (the one that died, whatever answers on reopening)
    for attempt in range(1, policy.attempts + 1):
        try:
            controller._reconnect(controller.link.timeout)  # (maybe inside a start: see _reconnect)
        except GalilConnectionError as exc:
            _LOG.warning(
                "galil: reconnect %d/%d to %s failed: %s",
                attempt,
                policy.attempts,
                name,
                str(exc).splitlines()[0],
            )
            if attempt == policy.attempts:
                raise exc from error
            time.sleep(delay)
            delay = min(delay * policy.backoff, policy.max_delay)
        else:
            _LOG.warning(
                "galil: link to %s died (%s); reconnected (attempt %d)",
                name,
                str(error).splitlines()[0],
                attempt,
            )
            return


def _weakly(
    method: Callable[[GalilConnectionError], None],
) -> Callable[[GalilConnectionError], None]:
    """``method`` called through a weak reference to its object (gone: the error is raised)."""
    ref = weakref.WeakMethod(method)

    def call(error: GalilConnectionError) -> None:
        bound = ref()
        if bound is None:
            raise error
        bound(error)

    return call


def _reopener(controller: Controller) -> Callable[[], None]:
    """What reopens ``controller``'s link so that a stop can be sent after a failed start
    (:func:`~galil.motion.stop_on_error`): a link that died, never one closed on purpose.
    It holds the controller weakly (a controller dropped unclosed is closed when collected).

    Its caller holds the tracker's lock, which ``reset()`` and ``close()`` take inside the
    life lock: it waits for the life lock no longer than the link's timeout (for ever would
    be a deadlock with a reset in another thread), then gives up as a failed reopen would."""
    ref = weakref.ref(controller)

    def reopen() -> None:
        c = ref()
        if c is None or not c.link.dead:
            raise GalilConnectionError("the link is closed, not dead: it is not reopened")
        c._reconnect(c.link.timeout)

    return reopen


def _policy(reconnect: object, has_address: bool) -> ReconnectPolicy | None:
    if reconnect is False or reconnect is None:
        return None
    if not has_address:
        raise InvalidArgument("reconnect= needs an address (it opens the link again)")
    if reconnect is True:
        return ReconnectPolicy()
    if isinstance(reconnect, ReconnectPolicy):
        return reconnect
    raise InvalidArgument(f"reconnect is True, False or a ReconnectPolicy, not {reconnect!r}")


def contour_stream(
    controller: Controller,
    chosen: Sequence[Axis],
    path: Amounts,
    dt: int,
    limits: dict[str, tuple[float | None, float | None]] | None = None,
) -> ContourStream:
    """The stream of a contour of the axes ``chosen`` along ``path`` (in their units), on
    the controller's link and motion tracker, before any byte: what :meth:`Controller.contour`
    runs and a bluesky flight checks, prepares and runs. ``limits``: each axis's speed and
    acceleration limits in counts (``None``: the model's). A refusal in counts says the
    user's units too (decision 0063)."""
    letters = "".join(a.letter for a in chosen)
    counts = path_to_counts(path, [a.scale for a in chosen], letters)
    with user_units({a.letter: a for a in chosen}):
        return ContourStream(
            controller.link,
            letters,
            counts,
            dt=dt,
            display={a.letter: a.display for a in chosen},
            byte_rate=controller.link.byte_rate,
            limits=limits,
            followers=controller.tracker.followers(letters),
            tracker=controller.tracker,
        )


def _contour_limits(
    model: ModelSpec, chosen: Sequence[Axis], speed_limit: object, accel_limit: object
) -> dict[str, tuple[float | None, float | None]]:
    """Each contour axis's own speed and acceleration limits in counts (``None``: the
    model's); a mapping naming an axis the contour does not drive is refused."""
    letters = "".join(a.letter for a in chosen)
    for what, given in (("speed_limit", speed_limit), ("accel_limit", accel_limit)):
        if isinstance(given, Mapping):  # a limit for an axis not driven would be ignored
            limits_by_axis(model, given, what, letters)
    return {
        a.letter: (
            a.limit_counts(speed_limit, 1, "speed_limit"),
            a.limit_counts(accel_limit, 2, "accel_limit"),
        )
        for a in chosen
    }


_A = TypeVar("_A")


class AxisMap(dict[str, _A]):
    """A controller's axes by letter (``controller.axes``): a ``dict`` whose miss, a letter
    the model lacks, is an :class:`~galil.errors.UnknownAxisError` (a ``KeyError`` too) that
    names the model's axes, as ``controller.B`` does."""

    __slots__ = ("_model",)

    def __init__(self, axes: Mapping[str, _A], model: ModelSpec) -> None:
        super().__init__(axes)
        self._model = model

    def __missing__(self, key: str) -> _A:
        model = self._model
        if not model.axes:
            text = f"{model.name} is an I/O controller with no axes (controller.io)"
        else:
            text = (
                f"{model.name} has no axis {key!r:.40}: it has axes {', '.join(model.axes)} "
                "(controller.A, or controller.axes['A'])"
            )
        raise UnknownAxisError(text, name=key, model=model.name)


def no_axis_attribute(owner: str, name: str, model: ModelSpec | None) -> AttributeError:
    """The error for ``controller.<name>`` that is no attribute; a single letter is most
    likely an axis letter (a typo, lower case, one the model lacks): it names the axes."""
    if len(name) == 1 and name.isalpha() and model is not None and not model.axes:
        return AttributeError(
            f"{owner} has no attribute {name!r}: {model.name} is an I/O controller with no "
            "axes (controller.io)"
        )
    if len(name) == 1 and name.isalpha() and model is not None:
        return AttributeError(
            f"{owner} has no attribute {name!r}: {model.name} has axes "
            f"{', '.join(model.axes)} (controller.A, or controller.axes['A'])"
        )
    return AttributeError(f"{owner} has no attribute {name!r}")


def connect(address: str | Transport, **options: object) -> Controller:
    """Connect to a controller with one line.

    Args:
        address: ``tcp://host[:port]`` or a bare IPv4 address, ``/dev/ttyUSB0``, ``COM3``,
            ``serial:///dev/ttyS0?baudrate=19200`` or any pyserial URL,
            ``usb://[vid:pid][?serial=...]``, ``/dev/galilpci0``, ``sim://DMC-4040``; or an
            open :class:`~galil.transport.Transport`.
        **options: client options (``timeout``, ``model``, ``handshake``, ``unsolicited``,
            ``history``, ``poll_interval``, ``max_messages``, ``echo``, ``reconnect``); the
            rest go to the transport (``baudrate=``, ``connect_timeout=``, ``backend=`` ...).

    Raises:
        InvalidArgument: the address or an option is not understood.
        GalilConnectionError: the link cannot be opened or the controller does not answer.
    """
    # (each client option is checked by Controller, each transport option by its transport)
    client_opts: dict[str, Any] = {k: options.pop(k) for k in list(options) if k in CLIENT_OPTIONS}
    if "timeout" in client_opts:
        client_opts["timeout"] = check_timeout(client_opts["timeout"], 1.0)
    if isinstance(address, str):
        transport_opts = options
        opened: list[Transport] = []

        def factory() -> Transport:
            # A transport that can reopen itself (the in-process simulator: the same
            # controller, not a new one) does; any other is opened from the address again.
            again = getattr(opened[0], "reopen", None) if opened else None
            transport = again() if callable(again) else open_transport(address, **transport_opts)
            opened[:] = [transport]
            return transport

        return Controller(factory, **client_opts)
    if options:
        raise InvalidArgument(
            f"transport options {sorted(options)} need an address, not an open transport"
        )
    if not isinstance(address, Transport):
        raise InvalidArgument(f"connect() takes an address or a Transport, not {address!r}")
    return Controller(address, **client_opts)
