"""The simulated DMC controller: an interpreter fed bytes, answering bytes.

:class:`SimController` behaves like a controller of the chosen model on its command port: it
answers ``:`` or ``?`` for every command, prints queries in the PF/VF/LZ formats, keeps the TC
error code, holds the ``:`` of a command that takes time (``WC``, a burn) until it is done,
refuses program-only commands from a host (``AM``, ``MC``, ``WT``, ``JP`` ...: TC 2), runs
downloaded programs (``MG``, ``WT``, ``JP`` and any command) in threads, and
sends their output as unsolicited messages. Motion runs in a servo loop, sample by sample, on
the one motion engine shared with the predictor (:class:`galil.predict.engine.AxisProfiler`),
in vectorised chunks between events.

Time comes from a clock: with :class:`~galil.sim.clock.ManualClock` (the default) nothing moves
until a test calls :meth:`SimController.advance`; servers use a real-time clock. Every public
method is thread-safe.

This class is the front door only. The core (:mod:`galil.sim.machine`: ports, servo loop,
interpreter, programs) knows no command; the commands live in rooms (:mod:`galil.sim.rooms`),
each registering its handlers, operands and servo-loop hooks. Choices where the sources are
silent are written in the room that makes them (see ``shared/reference/galil-protocol.md``):

- replies put a blank in the sign position of positive numbers (``" 1000"``, ``" 4, 52, 26,
  36"``), LZ 1 is the default, ``TC`` clears the code while ``_TC`` does not;
- soft limits act on the reference position (``RP``) and stop at DC, like a limit switch;
- ``_LFx``/``_LRx`` are 1 while the switch is inactive, as the TS bits are;
- ``TD`` reads an auxiliary encoder rigidly coupled to the motor (equal to ``TP``);
- ``WC`` holds until at most one contour segment (the one running) is left, i.e. the previous
  interval is complete; a ``CD`` into a full buffer holds its ``:`` until there is room; an
  emptied buffer while contouring sets the error code to 42;
- a program command that fails halts its thread and sets the error code; nothing is printed
  (a program with ``#CMDERR`` runs it; automatic subroutines and OE: decision 0029).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument
from galil.models import ModelSpec, for_firmware, get_model
from galil.predict.homing import HomeSwitch
from galil.sim.clock import Clock, ManualClock
from galil.sim.machine import Machine, Room
from galil.sim.motion import AxisMotion
from galil.sim.parse import LOG, Refused
from galil.sim.rooms import IO, ROOMS, Limits, Records
from galil.sim.rooms.limits import DEFAULT_HOME_EDGE, DEFAULT_INDEX_PERIOD, HomeGeometry

__all__ = ["SimController"]

_R = TypeVar("_R", bound=Room)


class SimController:
    """A simulated Galil DMC controller.

    Args:
        model: model name (``"DMC-4040"``, ``"DMC-1806"``, ...); see :mod:`galil.models`.
        clock: where time comes from; a new :class:`ManualClock` by default.
        firmware: the revision reported by ``^R^V``; the model's facts that depend on it
            follow it (:func:`galil.models.for_firmware`: a DMC-30010 before 1.2a has 4
            threads).
        servo_lag: time constant (s) of the motor following the reference, for every axis.
        rooms: the rooms that make up the controller (default :data:`galil.sim.rooms.ROOMS`);
            add one to give the simulator new commands, operands or servo-loop behaviour.
        identity: the ``^R^V`` text, when it should not follow ``model`` (a controller the
            library's tables do not know, behind ``model``'s behaviour).

    Raises:
        InvalidArgument: unknown model.
        ValueError: two rooms answer the same command or operand, or a room's requirement
            is missing.
    """

    def __init__(
        self,
        model: str = "DMC-4040",
        clock: Clock | None = None,
        *,
        firmware: str = "1.2f-sim",
        servo_lag: float = 0.003,
        rooms: Sequence[type[Room]] = ROOMS,
        identity: str | None = None,
    ) -> None:
        # As parse_identity reads it: a DMC-30010 before 1.2a has 4 threads (models.py).
        self.spec: ModelSpec = for_firmware(get_model(model), firmware)
        compact = model.strip().upper().replace("-", "")
        self.identity = f"{compact} Rev {firmware}" if identity is None else identity
        self.clock: Clock = clock if clock is not None else ManualClock()
        self._lock = threading.RLock()
        self._m = Machine(self.spec, self.identity, self.clock, servo_lag, rooms)

    # ---- state -------------------------------------------------------------------------
    @property
    def sample(self) -> int:
        """Servo samples run since the controller was created (what ``TIME`` reports)."""
        return self._m.servo.sample

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample at the present TM."""
        return self._m.servo.ts

    @property
    def time(self) -> float:
        """Simulated time of the last servo sample, in clock seconds."""
        return self._m.servo.now()

    @property
    def command_log(self) -> deque[tuple[int, str]]:
        """``(sample, command text)`` of the latest host commands, oldest first."""
        return self._m.command_log

    @property
    def separate_messages(self) -> bool:
        """When True, unsolicited output goes to :meth:`read_messages` (a TCP message
        handle); otherwise it is interleaved with the replies of the main port (serial)."""
        return self._m.ports.separate

    @separate_messages.setter
    def separate_messages(self, value: bool) -> None:
        self._m.ports.separate = bool(value)

    @property
    def _cw(self) -> int:
        # Kept for tests/transport/test_scenarios.py, which checks the CW setting directly.
        return self._m.ports.cw

    def room(self, cls: type[_R]) -> _R:
        """The room of class ``cls`` (its state, for tests and for other rooms).

        Raises:
            KeyError: the controller was built without it.
        """
        return self._m.room(cls)

    def motion(self, axis: str) -> AxisMotion:
        """The servo-loop state of ``axis`` (read it; drive it through commands).

        Raises:
            InvalidArgument: no such axis.
        """
        return self._m.servo.axes[self.spec.axis_letter(axis)].m

    # ---- bytes in, bytes out -----------------------------------------------------------
    def feed(self, data: bytes, port: int = 0) -> bytes:
        """Give the controller bytes from the host; return what it answers right away.

        Replies held by a trippoint come later from :meth:`poll`. Never raises for what the
        host sends: a command that breaks the simulator itself is answered ``?`` (and logged
        at ERROR on the ``galil.sim`` logger), as a refused command is.
        """
        with self._lock:
            m = self._m
            m.servo.sync()
            p = m.ports.get(port)
            if m.ports.echo:
                p.out += data
            p.inbuf += data.decode("latin-1")
            try:
                m.pump(p)
                m.service()
            except Exception:
                # A simulator bug outside any one command (each command's own is answered
                # with ? by the machine): logged; the replies made so far are returned.
                LOG.error("simulator error while serving port %d", port, exc_info=True)
            return p.take()

    def poll(self, port: int = 0) -> bytes:
        """Run the servo loop up to the clock's time; return replies and messages released."""
        with self._lock:
            self._m.servo.sync()
            return self._m.ports.get(port).take()

    def read_messages(self) -> bytes:
        """Unsolicited output waiting for the message handle (``separate_messages``)."""
        with self._lock:
            self._m.servo.sync()
            return self._m.ports.take_messages()

    def open_port(self, name: str) -> int:
        """Open another command handle (an Ethernet handle); return its number.

        The handle takes the first free letter A-H (what ``TH``, ``WH`` and ``CF`` name).

        Raises:
            GalilConnectionError: all eight handles are in use.
        """
        with self._lock:
            return self._m.ports.open(name).number

    def has_port(self, port: int) -> bool:
        """Whether handle ``port`` is open (``IH...=>-1`` closes handles from the inside)."""
        with self._lock:
            return port in self._m.ports.ports

    def close_port(self, port: int) -> None:
        """Close a handle opened with :meth:`open_port` (its pending input is dropped)."""
        with self._lock:
            self._m.close_port(port)

    def describe_handles(self) -> str:
        """The ``TH`` text for the open handles."""
        with self._lock:
            return self._m.ports.describe()

    # ---- time --------------------------------------------------------------------------
    def advance(self, seconds: float) -> None:
        """Move a manual clock on by ``seconds`` and run the servo loop to it.

        Raises:
            InvalidArgument: the clock is not a :class:`ManualClock`, or ``seconds`` < 0.
        """
        with self._lock:
            clock = self.clock
            if not isinstance(clock, ManualClock):
                raise InvalidArgument("advance() needs a ManualClock; this one runs by itself")
            clock.advance(seconds)
            self._m.servo.sync()

    def advance_until_output(self, seconds: float, port: int = 0) -> bytes:
        """Advance a manual clock by up to ``seconds``, stopping at the first output.

        This is how the in-process link lets simulated time pass while a host waits.

        Raises:
            InvalidArgument: the clock is not a :class:`ManualClock`, or ``seconds`` < 0.
        """
        with self._lock:
            clock = self.clock
            if not isinstance(clock, ManualClock):
                raise InvalidArgument("advance_until_output() needs a ManualClock")
            if not seconds >= 0:
                raise InvalidArgument(f"cannot advance by {seconds!r} s")
            servo = self._m.servo
            p = self._m.ports.get(port)
            servo.sync()
            start = servo.now()
            while not p.out:
                # (a program may change TM on the way: the time left is counted again in
                # samples of the new period)
                ts = servo.ts
                n = math.floor((seconds - (servo.now() - start)) / ts + 1e-9)
                if n <= 0:
                    break
                servo.run(n, stop=lambda ts=ts: bool(p.out) or servo.ts != ts)  # type: ignore[misc]
            clock.advance(servo.now() - start)
            servo.sync()
            return p.take()

    # ---- test hooks --------------------------------------------------------------------
    def set_limit_switch(self, axis: str, which: str, active: bool) -> None:
        """Test hook: set a limit switch; an active one stops motion towards it (SC 2/3).

        Args:
            axis: axis letter.
            which: ``"forward"`` or ``"reverse"``.
            active: True when the switch is tripped.

        Raises:
            InvalidArgument: bad axis or ``which``.
        """
        if which not in ("forward", "reverse"):
            raise InvalidArgument(f"which must be 'forward' or 'reverse', not {which!r}")
        with self._lock:
            self._m.servo.sync()
            letter = self.spec.axis_letter(axis)
            self._m.room(Limits).set_switch(letter, which, active)
            self._m.service()

    def set_servo_lag(self, seconds: float, axis: str | None = None) -> None:
        """Test hook: the time constant of the motor following the reference.

        Raises:
            InvalidArgument: negative lag or bad axis.
        """
        with self._lock:
            servo = self._m.servo
            letters = self.spec.axes if axis is None else self.spec.axis_letter(axis)
            for letter in letters:
                servo.axes[letter].m.set_lag(seconds)
            if axis is None:
                servo.lag = seconds

    def emit_message(self, text: str) -> None:
        """Test hook: send ``text`` as a running program's ``MG`` would (CR LF added)."""
        with self._lock:
            self._m.ports.emit(text + "\r\n")

    def start_trace(self, axes: str | None = None) -> int:
        """Record every sample's reference position on ``axes`` (default: all) from now on.

        Returns:
            The sample number of the trace's first value (compare with :attr:`command_log`).
        """
        with self._lock:
            self._m.servo.sync()
            for letter in axes or self.spec.axes:
                self.motion(letter).start_trace()
            return self._m.servo.sample

    def stop_trace(self, axes: str | None = None) -> dict[str, npt.NDArray[np.int64]]:
        """Stop recording; return the reference positions per axis since :meth:`start_trace`.

        Each array starts with the position at the start of the trace, then one value per
        servo sample (``sample_period`` apart).
        """
        with self._lock:
            self._m.servo.sync()
            return {
                self.spec.axis_letter(a): self.motion(a).stop_trace()
                for a in (axes or self.spec.axes)
            }

    def record(self, axes: str = "") -> bytes:
        """The QR data record of this model's layout (4000, 21x3 or 30010 style), without
        the ``:``. ``axes`` (letters) limits the axis blocks; default all.

        Raises:
            InvalidArgument: the model has no data record layout here.
        """
        with self._lock:
            return self._m.room(Records).record(axes)

    # ---- switches, home, I/O (issue 11) --------------------------------------------------
    def place_limit_switches(
        self, axis: str, *, forward: int | None = None, reverse: int | None = None
    ) -> None:
        """Test hook: put the limit switches of ``axis`` at fixed positions (``None``: none).

        Positions are in the machine's fixed frame: encoder counts from power-on, before any
        position was defined (DP, HM). A switch is tripped at and beyond its position and
        stops motion towards it (SC 2/3), as :meth:`set_limit_switch` does by hand.

        Raises:
            InvalidArgument: bad axis, or forward below reverse.
        """
        if forward is not None and reverse is not None and forward <= reverse:
            raise InvalidArgument(f"forward ({forward}) must be above reverse ({reverse})")
        with self._lock:
            self._m.servo.sync()
            self._m.room(Limits).place(self.spec.axis_letter(axis), forward, reverse)
            self._m.service()

    def set_home_switch(
        self,
        axis: str,
        *,
        edge: int = DEFAULT_HOME_EDGE,
        side: int = -1,
        index_period: int = DEFAULT_INDEX_PERIOD,
        index_offset: int = 0,
        pressed: bool | None = None,
    ) -> None:
        """Test hook: where the home switch's edge and the index pulses of ``axis`` are.

        Args:
            axis: axis letter.
            edge: the edge, fixed frame (default -10,000).
            side: -1 when the switch is tripped below the edge, +1 at and above.
            index_period: counts between index pulses (default 4,000).
            index_offset: one index pulse's position (default 0).
            pressed: hold the home switch tripped (True) or released (False) whatever the
                position; ``None`` follows the edge. The home input (TS, ``_HMx``, the data
                record) reads the held level, and HM/FE search from it: they start the way it
                reads, and a phase that waits for the input to change sees it change when the
                hold ends (the input differs from the held level there), and never while the
                hold lasts (decision 0088). Changed while a homing runs, it takes effect at once.

        Raises:
            InvalidArgument: bad axis, side or period.
        """
        if side not in (-1, 1) or index_period <= 0:
            raise InvalidArgument("side is -1 or 1 and index_period > 0")
        with self._lock:
            self._m.servo.sync()
            geometry = HomeGeometry(int(edge), side, int(index_period), int(index_offset))
            self._m.room(Limits).set_home(self.spec.axis_letter(axis), geometry, pressed)
            self._m.service()

    def home_switch(self, axis: str) -> HomeSwitch:
        """The home switch and index of ``axis`` in its present encoder frame: what a
        prediction of HM, FE or FI needs (``axis.home(switch=...)``). The geometry only: a
        switch held by :meth:`set_home_switch` is not in it (the host's homing then finds the
        input disagreeing with it, or sees the held switch's search deviate)."""
        with self._lock:
            letter = self.spec.axis_letter(axis)
            g = self._m.room(Limits).axes[letter].home
            origin = self._m.servo.axes[letter].origin
            return HomeSwitch(g.edge, g.side, g.index_period, g.index_offset).shifted(-origin)

    def machine_position(self, axis: str) -> int:
        """Test hook: the motor's position in the machine's fixed frame, counts (the frame
        :meth:`set_home_switch` places switches in; DP and homing do not move it)."""
        with self._lock:
            self._m.servo.sync()
            return self._m.servo.axes[self.spec.axis_letter(axis)].physical

    def set_input(self, n: int, high: bool) -> None:
        """Test hook: drive digital input ``n`` (the model's numbering) high or low.

        Raises:
            InvalidArgument: no such input.
        """
        with self._lock:
            self._m.servo.sync()
            io = self._m.room(IO)
            try:
                io.set_input(n, high)
            except Refused:
                raise InvalidArgument(f"{self.spec.name} has no input {n}") from None
            self._m.service()

    def set_analog_input(self, n: int, volts: float) -> None:
        """Test hook: put ``volts`` on analog input ``n``'s pin; ``@AN[n]`` and the data
        record read them clipped to the range the input's ``AQ`` code sets (at power-on the
        model's, :meth:`~galil.models.ModelSpec.analog_input_range`).

        Raises:
            InvalidArgument: no such analog input.
        """
        with self._lock:
            try:
                self._m.room(IO).set_analog_input(n, volts)
            except Refused:
                raise InvalidArgument(f"{self.spec.name} has no analog input {n}") from None

    def output(self, n: int) -> bool:
        """Whether digital output ``n`` is set."""
        with self._lock:
            io = self._m.room(IO)
            return io.outputs[io.channel(n, len(io.outputs))]

    def analog_output(self, n: int) -> float:
        """The volts on analog output ``n``."""
        with self._lock:
            io = self._m.room(IO)
            return io.analog_out[io.channel(n, len(io.analog_out))]
