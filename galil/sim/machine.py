"""The machine: the simulator's core, and the :class:`Room` base every part of it extends.

The core is four parts, none of which knows a single command:

- :class:`~galil.sim.ports.Ports`: the handles, their input and output, CF routing;
- :class:`~galil.sim.servo.Servo`: simulated time and the axes on the shared motion engine;
- :class:`~galil.sim.interpreter.Interpreter`: command text to handlers, variables, operands;
- :class:`~galil.sim.programs.Programs`: the downloaded program and its threads.

Everything a controller *does* lives in rooms (:mod:`galil.sim.rooms`). A room is a class with
its own state; it marks its methods with :func:`~galil.sim.registry.handler`,
:func:`~galil.sim.registry.operand` and :func:`~galil.sim.registry.function`, and overrides the
hooks it needs (:meth:`Room.reset`, :meth:`Room.abort`, :meth:`Room.port_closed` and the
servo-loop hooks :meth:`Room.horizon`, :meth:`Room.watches`, :meth:`Room.after_step`,
:meth:`Room.service`). The machine builds the command, operand and function tables from the
marks and wires only the hooks a room overrides. Adding a room is adding a module; the core
stays as it is.
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Callable, Sequence
from typing import ClassVar, TypeVar

from galil.models import ModelSpec
from galil.sim.clock import Clock
from galil.sim.interpreter import Command, Interpreter
from galil.sim.parse import Refused, internal_error, next_command
from galil.sim.ports import Port, Ports
from galil.sim.programs import NO_ERROR, Programs
from galil.sim.registry import (
    Args,
    Collect,
    Download,
    FunctionSpec,
    HandlerSpec,
    Mark,
    OperandKind,
    Wait,
    marks,
)
from galil.sim.servo import Servo, Watch

__all__ = ["Machine", "Room"]

_R = TypeVar("_R", bound="Room")
_V = TypeVar("_V")


class Room:
    """One part of the controller: its state, its commands and operands, its hooks.

    Subclasses set ``requires`` to the rooms they use and reach them with
    ``self.machine.room(Other)``. The order of the rooms is the order their hooks run in.
    """

    requires: ClassVar[tuple[type[Room], ...]] = ()

    def __init__(self, machine: Machine) -> None:
        self.machine = machine

    def reset(self) -> None:
        """Factory power-on state (at start, ``RS`` and ``^R^S``); the axes are new already.
        What was burned is put back afterwards with :meth:`restore`."""

    def burn(self, name: str) -> object | None:
        """``BN``, ``BP`` or ``BV`` (``name``): what of this room's state that burn saves (the
        machine copies it), or None for nothing."""
        return None

    def restore(self, name: str, saved: object) -> None:
        """``RS``: put back what :meth:`burn` returned for ``name`` (a copy), after
        :meth:`reset`."""

    def abort(self) -> None:
        """``AB``: every axis was stopped at once; drop motion state."""

    def port_closed(self, number: int) -> None:
        """A handle closed; forget output aimed at it."""

    def horizon(self, k: int) -> int:
        """The longest step (``1 <= step <= k``) that ends at or before this room's next event
        (a room that previews the profile should come late in the list: ``k`` is smallest)."""
        return k

    def watches(self, out: list[Watch]) -> None:
        """Append conditions that end a servo step at the sample where they turn true."""

    def after_step(self) -> None:
        """Called after every step of the servo loop."""

    def service(self) -> None:
        """Called at every step boundary, before held replies and threads run."""


class Machine:
    """The core of one simulated controller, with its rooms.

    Args:
        spec: the model.
        identity: the ``^R^V`` text.
        clock: where time comes from.
        servo_lag: servo lag (s) of the axes.
        rooms: room classes; their hooks run in this order.

    Raises:
        ValueError: two rooms claim a command or operand, or a room's requirement is missing.
    """

    def __init__(
        self,
        spec: ModelSpec,
        identity: str,
        clock: Clock,
        servo_lag: float,
        rooms: Sequence[type[Room]],
    ) -> None:
        self.spec = spec
        self.identity = identity
        self.ports = Ports()
        self.servo = Servo(spec, clock, servo_lag)
        self.interp = Interpreter(spec, self.servo)
        self.programs = Programs(
            self.interp, self.ports.emit, lambda: self.servo.sample, memory=spec
        )
        #: ``(sample, command text)`` of the latest host commands, oldest first.
        self.command_log: deque[tuple[int, str]] = deque(maxlen=10_000)
        self._list = [cls(self) for cls in rooms]
        #: Each room under its class and the room classes it extends (a subclass stands in).
        self._rooms: dict[type[Room], Room] = {}
        for room in self._list:
            for klass in type(room).__mro__:
                if issubclass(klass, Room) and klass is not Room:
                    if klass in self._rooms:
                        raise ValueError(f"two rooms are a {klass.__name__}")
                    self._rooms[klass] = room
        for cls in rooms:
            missing = [r.__name__ for r in cls.requires if r not in self._rooms]
            if missing:
                raise ValueError(f"room {cls.__name__} needs {', '.join(missing)}")
        #: The non-volatile memory: for each burn (``BN``, ``BP``, ``BV``) that ran, what each
        #: room saved (by its place in the list). ``^R^S`` erases it; a new machine has none.
        self.flash: dict[str, dict[int, object]] = {}
        self._wire()
        self.reset()

    def room(self, cls: type[_R]) -> _R:
        """The room of class ``cls``.

        Raises:
            KeyError: the controller was built without it.
        """
        found = self._rooms[cls]
        assert isinstance(found, cls)
        return found

    # ---- building ----------------------------------------------------------------------
    def _wire(self) -> None:
        servo = self.servo
        servo.service = self.service
        servo.horizon_hooks.append(self._wait_horizon)
        servo.watch_hooks.append(self._wait_watches)
        self._service_hooks: list[Callable[[], None]] = []
        self._abort_hooks: list[Callable[[], None]] = []
        self._reset_hooks: list[Callable[[], None]] = []
        self._closed_hooks: list[Callable[[int], None]] = []
        for room in self._list:
            self._register(room)
            for name, hooks in (
                ("horizon", servo.horizon_hooks),
                ("watches", servo.watch_hooks),
                ("after_step", servo.after_step_hooks),
                ("service", self._service_hooks),
                ("abort", self._abort_hooks),
                ("reset", self._reset_hooks),
                ("port_closed", self._closed_hooks),
            ):
                if getattr(type(room), name) is not getattr(Room, name):
                    hooks.append(getattr(room, name))

    def _register(self, room: Room) -> None:
        interp = self.interp
        for attr in dir(type(room)):
            for spec in _marks(type(room), attr):
                fn = getattr(room, attr)
                if isinstance(spec, HandlerSpec) and spec.args is Args.PLANES_AND_AXES:
                    _claim(interp.plane_commands, spec.name, Command(spec, fn), "plane command")
                elif isinstance(spec, HandlerSpec):
                    _claim(interp.commands, spec.name, Command(spec, fn), "command")
                elif isinstance(spec, FunctionSpec):
                    _claim(interp.functions, spec.name, fn, "function")
                elif spec.kind is OperandKind.AXIS:
                    _claim(interp.axis_operands, spec.name, fn, "operand")
                elif spec.kind is OperandKind.INDEX:
                    _claim(interp.index_operands, spec.name, fn, "operand")
                elif spec.kind is OperandKind.PLANE:
                    _claim(interp.plane_operands, spec.name, fn, "plane operand")
                else:
                    _claim(interp.operands, spec.name, fn, "operand")

    # ---- state -------------------------------------------------------------------------
    def reset(self) -> None:
        """Factory power-on defaults (also ``^R^S``; ``RS`` then restores what was burned,
        :meth:`power_on`): no program, no variables; time keeps running."""
        self.servo.reset()
        self.interp.reset()
        self.ports.reset()
        self.programs.reset()
        self.programs.install([])
        self.programs.error_at = NO_ERROR
        for hook in self._reset_hooks:
            hook()

    def burn(self, name: str) -> None:
        """``BN``, ``BP`` or ``BV`` has finished: what each room saves replaces what that burn
        saved before."""
        saved = {i: room.burn(name) for i, room in enumerate(self._list)}
        self.flash[name] = {i: copy.deepcopy(s) for i, s in saved.items() if s is not None}

    def power_on(self, *, parameters: bool = True) -> None:
        """``RS``: factory defaults, then what was burned; ``parameters=False`` (``RS -1``,
        the soft master reset) leaves the parameters at their factory defaults."""
        self.reset()
        for name, saved in self.flash.items():
            if name == "BN" and not parameters:
                continue
            for i, state in saved.items():
                self._list[i].restore(name, copy.deepcopy(state))

    def abort(self) -> None:
        """Tell every room that ``AB`` stopped the axes."""
        for hook in self._abort_hooks:
            hook()

    def close_port(self, number: int) -> None:
        """Close a handle and tell the rooms."""
        self.ports.close(number)
        for hook in self._closed_hooks:
            hook(number)

    # ---- host input --------------------------------------------------------------------
    def pump(self, p: Port) -> None:
        """Run the complete commands waiting in ``p``'s input, until one is held."""
        while p.wait is None:
            if p.download is not None:
                if not self.programs.collect(p):
                    return
                continue
            if p.collect is not None:
                if not self._collect(p):
                    return
                continue
            if p.swallow_cr and p.inbuf:
                p.swallow_cr = False
                if p.inbuf[0] == "\r":
                    p.inbuf = p.inbuf[1:]
            found = next_command(p.inbuf)
            if found is None:
                return
            text, end = found
            p.inbuf = p.inbuf[end:]
            self._host_command(p, text)

    def _host_command(self, p: Port, text: str) -> None:
        # Which sample each host command ran in: lets a test or the demo rebuild the exact
        # schedule of changes in motion and predict it.
        self.command_log.append((self.servo.sample, text))
        try:
            result = self.interp.execute(text, p)
        except Refused as e:
            self._refuse(p, e.code)
            return
        except Exception:  # a simulator bug: answer ? and keep the replies in step
            self._refuse(p, internal_error(text).code)
            return
        if isinstance(result, Wait):
            if result.ready(self.servo.sample):
                self._release(p, result)
            else:
                p.wait = result
        elif isinstance(result, Download):
            p.download = []
            p.download_refused = False
        elif isinstance(result, Collect):
            p.collect = result
        else:
            p.out += result.encode("latin-1") + b":"

    def _collect(self, p: Port) -> bool:
        """Collect a command's data up to ``\\`` (``QD``); False while more is needed."""
        assert p.collect is not None
        end = p.inbuf.find("\\")
        if end < 0:
            return False
        data, p.inbuf = p.inbuf[:end], p.inbuf[end + 1 :]
        done, p.collect = p.collect.done, None
        p.swallow_cr = True
        try:
            reply = done(data)
        except Refused as e:
            self._refuse(p, e.code)
            return True
        except Exception:
            self._refuse(p, internal_error(data[:40]).code)
            return True
        p.out += reply.encode("latin-1") + b":"
        return True

    def _refuse(self, p: Port, code: int) -> None:
        """Answer ``?`` on ``p`` and record ``code`` (TC)."""
        self.interp.tc = code
        p.out += b"?"

    def _release(self, port: Port, w: Wait) -> None:
        data = ""
        if w.then is not None:
            try:
                data = w.then()
            except Refused as e:
                self._refuse(port, e.code)
                return
            except Exception:
                self._refuse(port, internal_error("a held command").code)
                return
        port.out += data.encode("latin-1") + b":"

    # ---- the servo loop's view of waits ------------------------------------------------
    def service(self) -> None:
        """Release what is due at this sample and run program threads until they block."""
        hooks = self._service_hooks
        ports = self.ports.ports
        programs = self.programs
        progress = True
        while progress:
            progress = False
            for hook in hooks:
                hook()
            for port in list(ports.values()):
                w = port.wait
                if w is not None and w.ready(self.servo.sample):
                    port.wait = None
                    self._release(port, w)
                    self.pump(port)
                    progress = True
            if programs.threads and programs.run():
                progress = True

    def _wait_horizon(self, k: int) -> int:
        now = self.servo.sample
        for th in self.programs.threads.values():
            if th.wait is None:
                return 1  # a running thread runs its commands sample by sample
            if th.wait.wake is not None:
                k = min(k, th.wait.wake - now)
            if th.wait.cut is not None:
                k = th.wait.cut(k)
        for p in self.ports.ports.values():
            w = p.wait
            if w is not None:
                if w.wake is not None:
                    k = min(k, w.wake - now)
                if w.cut is not None:
                    k = w.cut(k)
        return k

    def _wait_watches(self, out: list[Watch]) -> None:
        # The ports' waits, then the threads' (at every step: no lists built on the way).
        for p in self.ports.ports.values():
            w = p.wait
            if w is not None and w.predicate is not None and not (w.exact and w.exact()):
                out.append(w.predicate)
        if self.programs.threads:
            for t in self.programs.threads.values():
                w = t.wait
                if w is not None and w.predicate is not None and not (w.exact and w.exact()):
                    out.append(w.predicate)


def _marks(cls: type[Room], attr: str) -> tuple[Mark, ...]:
    """The marks of ``cls.attr``; an override without marks keeps those of what it overrides."""
    for klass in cls.__mro__:
        if attr in klass.__dict__:
            found = marks(klass.__dict__[attr])
            if found:
                return found
    return ()


def _claim(table: dict[str, _V], name: str, value: _V, what: str) -> None:
    if name in table:
        raise ValueError(f"two rooms answer the {what} {name!r}")
    table[name] = value
