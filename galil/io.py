"""Digital and analog I/O: ``controller.io``.

Channels use the controller's own numbering: from 1 on DMC controllers (``io.inputs[1]`` is
``@IN[1]``), from 0 on a RIO. Every index and value is checked against the model before a byte
is sent::

    dmc.io.inputs[3]                 # True while input 3 is high (@IN[3])
    dmc.io.inputs[1:9]               # inputs 1..8 in one round trip (MG _TI0)
    dmc.io.outputs[2] = True         # SB 2
    dmc.io.analog_in[1]              # <Quantity(2.5, 'volt')> (@AN[1])
    rio.io.analog_out[0] = 1.5 * ureg.volt   # AO 0,1.5 (range-checked per model)
    dmc.io.wait_for_input(4, high=True, timeout=5)

Slices read whole banks in one line (``_TIn`` holds 8 inputs, ``_OPn`` 16 outputs) and write
outputs with one line of ``SB``/``CB``. :meth:`IO.wait_for_input` lets a small routine on the
controller watch the input and report the edge as an unsolicited message, so the host waits on
its message queue (pushed on a second Ethernet handle) instead of polling the input; the
message is the library's, never in ``controller.messages``.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from numbers import Integral, Real
from typing import Any, Generic, Protocol, TypeVar, overload

import numpy as np
import pint

from galil.errors import (
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ReadOnly,
    decimal_hint,
)
from galil.link import CommandLink, check_wait_timeout
from galil.protocol import commands as cmds
from galil.routines import INPUT_MESSAGE, RESERVED, ProgramRunning, Routine, Routines
from galil.units import Amount, get_registry, is_quantity

__all__ = ["IO", "AnalogInputs", "AnalogOutputs", "DigitalInputs", "DigitalOutputs"]

_INPUT_ROUTINE = "#GINWAIT"
#: Seconds between the polls of a wait that cannot use the routine (another wait holds it, or
#: a program of the user's runs while it is not in memory).
_POLL = 0.05


class MessageSource(Protocol):
    """What the I/O room needs of the message room (:class:`galil.messages.Messages`)."""

    def subscribe_library(self, callback: Callable[[str], None]) -> Callable[[], None]:
        """Call ``callback(line)`` for each line the library's routines print for the
        library (never in the user's queue); return an unsubscribe."""
        ...

    def ensure_polling(self) -> None:
        """Make sure unsolicited lines are being read."""
        ...

    def ended(self) -> str:
        """Why no more lines will come (the link was closed or died); ``""`` while they may."""
        ...

    def poll(self) -> None:
        """Read the lines the link holds now (a wait on a simulator's clock, between pauses)."""
        ...


def volts(value: object, what: str) -> float:
    """A voltage as a float: a pint Quantity convertible to volts, or a plain number."""
    if is_quantity(value):
        try:
            v = float(value.to("volt").magnitude)  # type: ignore[attr-defined]
        except Exception as exc:  # pint's DimensionalityError and friends
            raise InvalidArgument(f"{what}: {value} is not a voltage") from exc
    elif isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise InvalidArgument(
            f"{what} takes volts (a number or a Quantity), not {value!r}{decimal_hint(value)}"
        )
    else:
        try:
            v = float(value)
        except OverflowError:  # an int no float holds (10**400)
            raise InvalidArgument(
                f"{what}: {value!r:.40} is not a voltage any output gives"
            ) from None
    if not math.isfinite(v):
        raise InvalidArgument(f"{what}: {value!r} is not a finite voltage")
    return v


def _index(n: object, what: str) -> int:
    """A channel number (or a slice's bound) as an ``int``: an integer, numpy's included,
    never a bool.

    Raises:
        InvalidArgument: anything else (a float, a string, a bool).
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, Integral):
        raise InvalidArgument(f"{what} must be an integer, not {n!r}")
    return int(n)


def _level(value: object) -> bool:
    """An output's state: ``True``/``False`` (numpy's too) or 1/0.

    Raises:
        InvalidArgument: anything else.
    """
    if isinstance(value, (bool, np.bool_, Integral)) and value in (0, 1):
        return bool(value)
    raise InvalidArgument(f"an output is True or False, not {value!r}")


#: What one channel reads: a bool (digital), a Quantity of volts (analog).
V = TypeVar("V")


class _Channels(FixedAttributes, Generic[V]):
    """Channels ``first .. first + count - 1`` of one kind, indexed as the controller does."""

    first: ReadOnly[int] = ReadOnly()
    count: ReadOnly[int] = ReadOnly()

    kind = "channel"

    def __init__(self, link: CommandLink, first: int, count: int) -> None:
        self._link = link
        self._first = first
        self._count = count

    def __len__(self) -> int:
        return self.count

    def numbers(self) -> range:
        """The channel numbers, in the controller's numbering."""
        return range(self.first, self.first + self.count)

    def __iter__(self) -> Iterator[V]:
        return iter(self._all())

    def _all(self) -> Sequence[V]:
        """Every channel's value (one round trip)."""
        raise NotImplementedError

    def _check(self, n: object) -> int:
        n = _index(n, f"{self.kind} number")
        if not self.first <= n < self.first + self.count:
            name = self._link.model.name
            span = f"{self.first} .. {self.first + self.count - 1}"
            raise InvalidArgument(
                f"{self.kind} {n} does not exist on {name} ({span})"
                if self.count
                else f"{self.kind} {n} does not exist: {name} has no {self.kind}s",
                model=self._link.model.name,
            )
        return n

    def _span(self, key: slice) -> list[int]:
        if key.step is not None and _index(key.step, f"{self.kind} slice step") != 1:
            raise InvalidArgument(f"{self.kind} slices take no step, got {key!r}")
        what = f"{self.kind} slice bound"
        start = self.first if key.start is None else _index(key.start, what)
        stop = self.first + self.count if key.stop is None else _index(key.stop, what)
        numbers = list(range(start, stop))
        for n in numbers:
            self._check(n)
        if not numbers:
            raise InvalidArgument(f"empty {self.kind} slice {key!r}")
        return numbers

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.first}..{self.first + self.count - 1}>"


class _Bits(_Channels[bool]):
    """Digital channels read as banks of bits (``_TIn`` / ``_OPn``)."""

    operand = "TI"
    bank_bits = 8
    function = "IN"

    @overload
    def __getitem__(self, key: int) -> bool: ...
    @overload
    def __getitem__(self, key: slice) -> tuple[bool, ...]: ...
    def __getitem__(self, key: int | slice) -> bool | tuple[bool, ...]:
        if isinstance(key, slice):
            return self._read(self._span(key))
        n = self._check(key)
        return bool(round(self._link.query_operands([f"@{self.function}[{n}]"])[0]))

    def _all(self) -> Sequence[bool]:
        return self._read(list(self.numbers())) if self.count else ()

    def _read(self, numbers: list[int]) -> tuple[bool, ...]:
        size = self.bank_bits
        banks = sorted({(n - self.first) // size for n in numbers})
        values = self._link.query_operands([f"_{self.operand}{b}" for b in banks])
        word = {b: round(v) for b, v in zip(banks, values, strict=True)}
        return tuple(
            bool(word[(n - self.first) // size] >> ((n - self.first) % size) & 1) for n in numbers
        )


class DigitalInputs(_Bits):
    """``io.inputs[n]`` (``@IN[n]``), ``io.inputs[a:b]`` (input banks ``_TIn``, one line)."""

    kind = "input"


class DigitalOutputs(_Bits):
    """``io.outputs[n]`` (``@OUT[n]``; set with ``SB``/``CB``), slices in one line."""

    kind = "output"
    operand = "OP"
    bank_bits = 16
    function = "OUT"

    @overload
    def __setitem__(self, key: int, value: bool) -> None: ...
    @overload
    def __setitem__(self, key: slice, value: Sequence[bool]) -> None: ...
    def __setitem__(self, key: int | slice, value: object) -> None:
        model = self._link.model
        if isinstance(key, slice):
            channels = self._span(key)
            if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
                raise InvalidArgument(
                    f"outputs[{key.start}:{key.stop}] takes one True or False per output (a "
                    f"list), not {value!r:.40}"
                )
            states = [_level(s) for s in value]
            if len(states) != len(channels):
                raise InvalidArgument(f"{len(states)} values for {len(channels)} outputs")
        else:
            channels, states = [self._check(key)], [_level(value)]
        parts = [
            (cmds.sb if s else cmds.cb)(n, model=model)
            for n, s in zip(channels, states, strict=True)
        ]
        self._link.command_line(parts)


class AnalogInputs(_Channels[pint.Quantity[float]]):
    """``io.analog_in[n]``: the volts on analog input ``n`` (``@AN[n]``) as a Quantity."""

    kind = "analog input"

    @overload
    def __getitem__(self, key: int) -> pint.Quantity[float]: ...
    @overload
    def __getitem__(self, key: slice) -> tuple[pint.Quantity[float], ...]: ...
    def __getitem__(
        self, key: int | slice
    ) -> pint.Quantity[float] | tuple[pint.Quantity[float], ...]:
        numbers = self._span(key) if isinstance(key, slice) else [self._check(key)]
        values = self._link.query_operands([f"@AN[{n}]" for n in numbers])
        out = tuple(get_registry().Quantity(v, "volt") for v in values)
        return out if isinstance(key, slice) else out[0]

    def _all(self) -> Sequence[pint.Quantity[float]]:
        return self[self.first : self.first + self.count] if self.count else ()


class AnalogOutputs(_Channels[pint.Quantity[float]]):
    """``io.analog_out[n]``: set (``AO n,v``, range-checked per model) and read (``@AO[n]``).

    The range checked is the model's power-on one (``analog_out_range``); a ``DQ`` sent raw
    (``ModelSpec.dq_ranges``) is not read back: the controller enforces the range it set."""

    kind = "analog output"

    def __getitem__(self, n: int) -> pint.Quantity[float]:
        value = self._link.query_operands([f"@AO[{self._check(n)}]"])[0]
        return get_registry().Quantity(value, "volt")

    def _all(self) -> Sequence[pint.Quantity[float]]:
        if not self.count:
            return ()
        values = self._link.query_operands([f"@AO[{n}]" for n in self.numbers()])
        return tuple(get_registry().Quantity(v, "volt") for v in values)

    def __setitem__(self, n: int, value: Amount) -> None:
        v = volts(value, f"analog output {n}")
        self._link.command_line([cmds.ao(self._check(n), v, model=self._link.model)])


class IO(FixedAttributes):
    """The controller's digital and analog I/O (``controller.io``)."""

    def __init__(self, link: CommandLink, messages: MessageSource, routines: Routines) -> None:
        self._link = link
        self._messages = messages
        self._routines = routines
        self._wait_lock = threading.Lock()
        self._watching: int | None = None  # the thread of the routine a wait is watching

    def _model_channels(self) -> tuple[int, Any]:
        m = self._link.model
        return m.io_first, m

    def __repr__(self) -> str:
        m = self._link.model
        return (
            f"<IO of {m.name}: {m.digital_inputs} inputs, {m.digital_outputs} outputs,"
            f" {m.analog_inputs} analog in, {m.analog_outputs} analog out>"
        )

    @property
    def inputs(self) -> DigitalInputs:
        """Digital inputs (``bool``), numbered as the controller numbers them."""
        first, m = self._model_channels()
        return DigitalInputs(self._link, first, m.digital_inputs)

    @property
    def outputs(self) -> DigitalOutputs:
        """Digital outputs (``bool``); assign to set or clear them."""
        first, m = self._model_channels()
        return DigitalOutputs(self._link, first, m.digital_outputs)

    @property
    def analog_in(self) -> AnalogInputs:
        """Analog inputs, in volts (pint Quantities)."""
        first, m = self._model_channels()
        return AnalogInputs(self._link, first, m.analog_inputs)

    @property
    def analog_out(self) -> AnalogOutputs:
        """Analog outputs, in volts; none on models without them (every index refused)."""
        first, m = self._model_channels()
        return AnalogOutputs(self._link, first, m.analog_outputs)

    def wait_for_input(
        self, n: int, *, high: bool = True, timeout: float | None = None, thread: int | None = None
    ) -> None:
        """Block until input ``n`` is high (``high=False``: low).

        The input is read first (``@IN[n]``, one query): the wait returns at once when it
        already is at that level. Otherwise a routine on the controller (installed beside
        your program, :mod:`galil.routines`) watches the input and prints one message when
        it changes; the host waits for that message, so the link carries no polling traffic
        (on Ethernet the message is pushed on the message handle). The message is the
        library's: it never reaches ``controller.messages`` nor your callbacks.

        One such wait runs on the controller at a time (the routine is one). A wait that
        comes while another runs (from another thread, or a task) does not wait for it to
        end: until its turn comes, it polls its input (``@IN[n]`` every 50 ms), returns when
        the input is at the level, and raises :class:`~galil.errors.GalilTimeoutError` when
        its own timeout passes first. Its turn come, the time left of its timeout is what
        the routine watches for.

        While a program of yours runs, the routine can be started beside it only if it is
        in memory already (an earlier wait put it there): adding it takes a download, which
        would disturb your program. The wait then polls its input the same way (``@IN[n]``
        every 50 ms), for the whole of its timeout.

        Args:
            n: the input (the controller's numbering).
            high: wait for high (True) or low (False).
            timeout: seconds to wait at most (``None``: for ever), a finite number >= 0
                (:func:`~galil.link.check_wait_timeout`).
            thread: program thread for the routine (default: the last one that runs neither
                a program of yours nor another of this session's library routines: never the
                watchdog's; with none free, the wait polls its input).

        Raises:
            InvalidArgument: no such input, a bad timeout (infinity too: ``None`` waits for
                ever), or a busy thread (one of this session's watchdog is named so).
            GalilTimeoutError: the input did not change in time (the routine is halted; one
                that another wait held all that time is not started).
            GalilConnectionError: the controller was closed, or its link died, during the
                wait.

        Anything else that cuts the wait short (Ctrl-C, a reply lost) halts the routine too
        before it propagates; a dead link cannot, and the routine watches on until its input
        changes (the next wait reuses its thread, in this session or a later one). Closing
        the controller halts the routine of a wait in flight; the wait (in another thread)
        raises :class:`~galil.errors.GalilConnectionError`, as it does when the link dies.
        """
        watch = InputWatch(self, n, high=high, timeout=timeout, thread=thread)
        watch.step()  # to the deadline: returns once the input is at the level, or raises

    def end_wait(self) -> None:
        """Closing: halt the routine of a wait in flight (another thread's, or an async
        wait's, between its slices too), which then raises
        :class:`~galil.errors.GalilConnectionError` as the link closes; nothing is sent when
        no wait runs. Never raises for a dead link."""
        thread = self._watching
        if thread is not None and self._routines.holder(thread) == _INPUT_ROUTINE:
            with contextlib.suppress(GalilError):
                self._routines.halt(thread)

    def _turn(self, n: int, high: bool, deadline: float | None) -> bool | None:
        """Take the input routine (one wait at a time: its variables are shared): ``True``
        once it is this wait's; while another wait holds it, poll input ``n`` (``@IN[n]``,
        every :data:`_POLL` s): ``None`` when it is at the level, ``False`` when ``deadline``
        has passed first. Never holds the routine when it returns anything but ``True``."""
        return _poll(self._link, n, high, deadline, lambda: self._wait_lock.acquire(False))


def _at_level(link: CommandLink, n: int, high: bool) -> bool:
    """Whether input ``n`` is at the level (``@IN[n]``, one query)."""
    return bool(round(link.query_operands([f"@IN[{n}]"])[0])) == high


def _poll(
    link: CommandLink,
    n: int,
    high: bool,
    until: float | None,
    turn: Callable[[], bool] | None = None,
) -> bool | None:
    """Poll input ``n`` every :data:`_POLL` s: ``None`` once it is at the level, ``False``
    once ``until`` has passed first; with ``turn`` (tried before each poll), ``True`` as soon
    as ``turn()`` is."""
    while turn is None or not turn():
        if _at_level(link, n, high):
            return None
        now = link.clock()
        if until is not None and now >= until:
            return False
        link.pause(_POLL if until is None else min(_POLL, max(until - now, 0.001)))
    return True


class InputWatch:
    """One :meth:`IO.wait_for_input`, taken in steps: the sync wait takes one step to its
    deadline; its async twin takes steps of at most half a second on a worker thread, so a
    cancelled task frees its thread soon, while the routine, installed and started at the
    first step that holds it, watches on between steps (it is not installed again per step).

    Every argument is checked here, before a byte is sent. One step at a time; :meth:`end`
    (idempotent) halts a routine still watching and lets the next wait take it.

    Raises:
        InvalidArgument: no such input, a bad ``high``, timeout or thread.
    """

    def __init__(
        self, io: IO, n: int, *, high: bool, timeout: float | None, thread: int | None
    ) -> None:
        self._n = n = io.inputs._check(n)
        if not isinstance(high, (bool, np.bool_)):
            raise InvalidArgument(f"high is True or False, not {high!r}")
        self._high = high = bool(high)
        timeout = check_wait_timeout(timeout)
        link = self._link = io._link
        # (None: the default thread, chosen when the routine starts: Routines.default_thread)
        self._thread = None if thread is None else io._routines.check_thread(thread)
        self._io = io
        self._deadline = None if timeout is None else link.clock() + timeout
        self._expired = f"input {n} did not go {'high' if high else 'low'} within {timeout} s"
        self._seen = threading.Event()
        self._held = False  # this wait holds the routine (IO._wait_lock)
        self._started = False  # its XQ may have gone out
        self._polling = False  # a program of the user's runs: no routine, the input polled
        self._why_polled = ""  # (the ProgramRunning that made it poll)
        self._over = False
        self._unsubscribe: Callable[[], None] | None = None
        self._lock = threading.Lock()  # one step (or end) at a time

    def step(self, seconds: float | None = None) -> bool:
        """Wait at most ``seconds`` (``None``: to the deadline) of the whole wait.

        Returns:
            ``True`` once the input is at the level (the wait is over); ``False`` when the
            seconds passed first and time is left (the routine, if it runs, watches on).

        Raises:
            GalilTimeoutError: the whole timeout passed (the routine is halted; one that
                another wait held all that time is not started).
            GalilConnectionError: the controller was closed, or its link died.
            GalilError: the wait was ended (:meth:`end`) before this step.
        """
        with self._lock:
            if self._over:
                if self._seen.is_set():
                    return True
                raise GalilError(f"the wait for input {self._n} was ended")
            link = self._link
            until = self._deadline
            if seconds is not None:
                end_of_step = link.clock() + seconds
                until = end_of_step if until is None else min(until, end_of_step)
            try:
                seen = self._watch(until)
            except BaseException:
                self._end(quiet=True)
                raise
            if seen is not False:
                self._end(quiet=True)  # (the routine said so and ended: nothing to halt)
                return True
            if self._deadline is None or until is None or until < self._deadline:
                return False
            why = self._expired_why()
            self._end(quiet=False)  # the whole timeout passed: the routine is halted
            raise link.error(GalilTimeoutError, f"{self._expired}{why}")

    def _expired_why(self) -> str:
        """What a timeout adds: why the wait polled its input, if it did."""
        if self._polling and self._why_polled.startswith("every thread"):
            return (
                ": every thread ran a program of yours (or another of the library's routines),"
                " so this wait polled its input"
            )
        if self._polling:
            return (
                ": a program of yours (or a speed schedule) ran while the input routine was not "
                "in memory (its download would have disturbed it), so this wait polled its input"
            )
        if not self._held:
            return (
                ": another wait_for_input held the controller's input routine all that time "
                "(one runs at a time; meanwhile this one polled its input)"
            )
        return ""

    def _watch(self, until: float | None) -> bool | None:
        """Take the routine (polling the input until it is this wait's turn), start it
        unless it runs, and wait for its message until ``until``: ``True`` (the message
        came), ``None`` (the input was at the level: read before the routine started, or
        polled while it could not be used), ``False`` (``until`` passed first)."""
        io, link, n, high = self._io, self._link, self._n, self._high
        if self._polling:
            return _poll(link, n, high, until)
        if not self._held:
            turn = io._turn(n, high, until)
            if not turn:
                return turn
            self._held = True
            if not self._started and _at_level(link, n, high):
                return None  # (at the level already: no routine)
        if not self._started and not self._start():
            self._polling, self._held = True, False
            io._wait_lock.release()  # (no routine used: the next wait may take it)
            return _poll(link, n, high, until)
        io._messages.ensure_polling()
        left = None if until is None else max(0.0, until - link.clock())
        return _wait(link, self._seen, left, io._messages)

    def _start(self) -> bool:
        """Install the routine (when it is not in memory), listen for its message, set its
        variables and start it on the thread: ``False`` (nothing started) when the install
        needs a download a running program of the user's refuses (:class:`ProgramRunning`)."""
        io, tag = self._io, [INPUT_MESSAGE, str(self._n)]
        routines = io._routines
        try:
            # (before the install sends a byte; the default: Routines.default_thread, and
            # with every thread running a program (ProgramRunning), the wait polls)
            thread = self._thread = routines.free_thread(self._thread, _INPUT_ROUTINE)
            routines.install(_input_routine())
        except ProgramRunning as exc:
            self._why_polled = str(exc)
            return False

        def on_message(line: str) -> None:
            if line.split()[:2] == tag:
                self._seen.set()

        self._unsubscribe = io._messages.subscribe_library(on_message)
        level = 1 if self._high else 0
        io._link.command_line([cmds.assign("ginput", self._n), cmds.assign("ginlevel", level)])
        routines.start(_INPUT_ROUTINE, thread)
        self._started = True
        io._watching = thread
        return True

    def end(self) -> None:
        """End the wait (a cancelled async wait): halt its routine if it still watches, and
        let the next wait take the routine. Idempotent; never raises for a dead link."""
        with self._lock:
            self._end(quiet=True)

    def _end(self, *, quiet: bool) -> None:
        """Halt a routine that said nothing (errors raised unless ``quiet``: on a dead link it
        cannot be halted), or give up the thread of one that said so and ended; stop
        listening and give the routine up."""
        if self._over:
            return
        self._over = True
        routines, thread = self._io._routines, self._thread
        try:
            if self._started and thread is not None and not self._seen.is_set():
                if quiet:
                    with contextlib.suppress(GalilError):
                        routines.halt(thread)
                else:
                    routines.halt(thread)
            elif self._started and thread is not None:
                routines.release(thread, _INPUT_ROUTINE)  # (it printed, then ended at EN)
        finally:
            if self._unsubscribe is not None:
                self._unsubscribe()
            if self._held:
                self._io._watching = None
                self._io._wait_lock.release()


def _wait(
    link: CommandLink, seen: threading.Event, timeout: float | None, messages: MessageSource
) -> bool:
    """Wait until ``seen`` is set (``True``) or ``timeout`` has passed (``False``).

    On a simulator's clock the link is read between pauses (:meth:`MessageSource.poll`):
    the routine's line is heard in the simulated time it was printed in.

    Raises:
        GalilConnectionError: no message will come (``messages.ended()`` says why: the link
            was closed, or died).
    """
    deadline = None if timeout is None else link.clock() + timeout
    simulated = link.simulated_time
    while not seen.is_set():
        why = messages.ended()
        if why:
            raise GalilConnectionError(f"the wait for an input ended: {why}")
        now = link.clock()
        if deadline is not None and now >= deadline:
            return False
        step = 0.05 if deadline is None else min(0.05, max(deadline - now, 0.001))
        link.pause(step)  # real time on hardware; simulated time on a manual clock
        if simulated:
            messages.poll()
    return True


def _input_routine() -> Routine:
    """Wait in the controller until @IN[ginput] = ginlevel, then say so once."""
    label = _INPUT_ROUTINE
    loop = "#GINLOOP"
    return Routine(
        label,
        (
            label,
            loop,
            f"JP {loop},@IN[ginput]<>ginlevel",
            f'MG "{INPUT_MESSAGE} ",ginput{{Z3.0}}',
            "EN",
        ),
        kind=RESERVED[label],
    )
