"""Digital and analog I/O, awaited: the twin of ``controller.io`` (:mod:`galil.io`).

Indexing reads, as on the sync side, but returns an awaitable; writes are ``set`` calls::

    await dmc.io.inputs[3]                   # @IN[3]
    await dmc.io.inputs[1:9]                 # inputs 1..8 in one round trip
    await dmc.io.outputs.set(2, True)        # SB 2  (sync: dmc.io.outputs[2] = True)
    await dmc.io.analog_out.set(0, 1.5 * ureg.volt)
    await dmc.io.wait_for_input(4, high=True, timeout=5)

Every channel number and value is checked by the sync room, on a worker thread, before a
byte is sent.
"""

from __future__ import annotations

import operator
from collections.abc import Awaitable, Iterable, Sequence
from typing import Any, Generic, TypeVar, overload

import pint

from galil.aio._waits import in_steps
from galil.aio._worker import Room, Worker
from galil.io import (
    IO,
    AnalogInputs,
    AnalogOutputs,
    DigitalInputs,
    DigitalOutputs,
    InputWatch,
)
from galil.link import Link
from galil.units import Amount

__all__ = [
    "AsyncAnalogInputs",
    "AsyncAnalogOutputs",
    "AsyncDigitalInputs",
    "AsyncDigitalOutputs",
    "AsyncIO",
]

C = TypeVar("C", DigitalInputs, DigitalOutputs, AnalogInputs, AnalogOutputs)


T = TypeVar("T")


def _all(channels: Iterable[T]) -> tuple[T, ...]:
    return tuple(channels)


def _set_outputs(outputs: DigitalOutputs, key: int | slice, value: object) -> None:
    outputs[key] = value  # type: ignore[call-overload]  # (DigitalOutputs checks the pair)


def _set_analog(outputs: AnalogOutputs, n: int, value: Amount) -> None:
    outputs[n] = value


class _Channels(Room[C], Generic[C]):
    """Channels of one kind, numbered as the controller numbers them."""

    def __len__(self) -> int:
        return len(self.sync)

    @property
    def kind(self) -> str:
        """What a channel is (``"input"``, ``"analog output"`` ...)."""
        return self.sync.kind

    @property
    def first(self) -> int:
        """The first channel's number."""
        return self.sync.first

    @property
    def count(self) -> int:
        """How many channels the model has."""
        return self.sync.count

    def numbers(self) -> range:
        """The channel numbers, in the controller's numbering."""
        return self.sync.numbers()

    def _read(self, key: int | slice) -> Awaitable[Any]:  # (private: typed by each caller)
        return self._worker.run(operator.getitem, self.sync, key)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} of {self.sync!r}>"


class AsyncDigitalInputs(_Channels[DigitalInputs]):
    """``await io.inputs[n]`` (``@IN[n]``), ``await io.inputs[a:b]`` (banks, one line)."""

    @overload
    def __getitem__(self, key: int) -> Awaitable[bool]: ...
    @overload
    def __getitem__(self, key: slice) -> Awaitable[tuple[bool, ...]]: ...
    def __getitem__(self, key: int | slice) -> Awaitable[bool | tuple[bool, ...]]:
        return self._read(key)

    async def all(self) -> tuple[bool, ...]:
        """Every input, in one round trip (sync: ``tuple(io.inputs)``)."""
        values: tuple[bool, ...] = await self._worker.run(_all, self.sync)
        return values


class AsyncDigitalOutputs(_Channels[DigitalOutputs]):
    """``await io.outputs[n]`` (``@OUT[n]``) and ``await io.outputs.set(n, True)`` (``SB``
    / ``CB``; a slice and a list of values set several in one line)."""

    @overload
    def __getitem__(self, key: int) -> Awaitable[bool]: ...
    @overload
    def __getitem__(self, key: slice) -> Awaitable[tuple[bool, ...]]: ...
    def __getitem__(self, key: int | slice) -> Awaitable[bool | tuple[bool, ...]]:
        return self._read(key)

    @overload
    async def set(self, key: int, value: bool) -> None: ...
    @overload
    async def set(self, key: slice, value: Sequence[bool]) -> None: ...
    async def set(self, key: int | slice, value: object) -> None:
        """Set (True) or clear (False) output ``key``, or the outputs of a slice (sync:
        ``io.outputs[key] = value``).

        Raises:
            InvalidArgument: no such output, a value not True/False, a count that differs.
        """
        await self._worker.run(_set_outputs, self.sync, key, value)

    async def all(self) -> tuple[bool, ...]:
        """Every output, in one round trip (sync: ``tuple(io.outputs)``)."""
        values: tuple[bool, ...] = await self._worker.run(_all, self.sync)
        return values


class AsyncAnalogInputs(_Channels[AnalogInputs]):
    """``await io.analog_in[n]``: the volts on analog input ``n`` (``@AN[n]``)."""

    @overload
    def __getitem__(self, key: int) -> Awaitable[pint.Quantity[float]]: ...
    @overload
    def __getitem__(self, key: slice) -> Awaitable[tuple[pint.Quantity[float], ...]]: ...
    def __getitem__(
        self, key: int | slice
    ) -> Awaitable[pint.Quantity[float] | tuple[pint.Quantity[float], ...]]:
        return self._read(key)

    async def all(self) -> tuple[pint.Quantity[float], ...]:
        """Every analog input, in volts (sync: ``tuple(io.analog_in)``)."""
        return await self._worker.run(_all, self.sync)


class AsyncAnalogOutputs(_Channels[AnalogOutputs]):
    """``await io.analog_out[n]`` (``@AO[n]``) and ``await io.analog_out.set(n, volts)``."""

    def __getitem__(self, n: int) -> Awaitable[pint.Quantity[float]]:
        return self._read(n)

    async def set(self, n: int, value: Amount) -> None:
        """Set analog output ``n`` (``AO n,v``; sync: ``io.analog_out[n] = value``).

        Raises:
            InvalidArgument: no such output, or not a voltage.
            LimitError: beyond the model's output range.
        """
        await self._worker.run(_set_analog, self.sync, n, value)

    async def all(self) -> tuple[pint.Quantity[float], ...]:
        """Every analog output, in volts (sync: ``tuple(io.analog_out)``)."""
        return await self._worker.run(_all, self.sync)


class AsyncIO(Room[IO]):
    """The controller's digital and analog I/O (``controller.io``), awaited."""

    def __init__(self, sync: IO, worker: Worker, link: Link) -> None:
        super().__init__(sync, worker)
        self._link = link

    @property
    def inputs(self) -> AsyncDigitalInputs:
        """Digital inputs (``bool``), numbered as the controller numbers them."""
        return AsyncDigitalInputs(self.sync.inputs, self._worker)

    @property
    def outputs(self) -> AsyncDigitalOutputs:
        """Digital outputs (``bool``); ``await outputs.set(n, True)`` to set them."""
        return AsyncDigitalOutputs(self.sync.outputs, self._worker)

    @property
    def analog_in(self) -> AsyncAnalogInputs:
        """Analog inputs, in volts (pint Quantities)."""
        return AsyncAnalogInputs(self.sync.analog_in, self._worker)

    @property
    def analog_out(self) -> AsyncAnalogOutputs:
        """Analog outputs, in volts; none on models without them (every index refused)."""
        return AsyncAnalogOutputs(self.sync.analog_out, self._worker)

    async def wait_for_input(
        self, n: int, *, high: bool = True, timeout: float | None = None, thread: int | None = None
    ) -> None:
        """Wait until input ``n`` is high (``high=False``: low); see
        :meth:`galil.io.IO.wait_for_input` (the input read first: at the level, the wait
        returns at once; else a routine on the controller watches it, on a thread the
        watchdog does not hold, and its line never reaches ``c.messages``; while a program
        of yours runs and the routine is not in memory, the input is polled instead).

        The sync wait runs in steps of at most ``WAIT_SLICE`` (0.5 s) on a worker, so a
        cancelled task frees its thread within one step; the routine is installed and
        started once, at the first step that holds it, and watches on between steps (a wait
        costs the link what the sync wait costs). Cancelled, the wait halts the routine once
        the step under way is over.

        Raises:
            InvalidArgument: no such input, a bad timeout (refused before anything is sent,
                as by the sync wait: infinity too, ``None`` waits for ever), or a busy thread
                (one of this session's watchdog is named so).
            GalilTimeoutError: the input did not change in time (the routine is halted).
            GalilConnectionError: the controller was closed, or its link died, during the
                wait.
        """
        watch = await self._worker.run(
            InputWatch, self.sync, n, high=high, timeout=timeout, thread=thread
        )
        await in_steps(self._worker, watch.step, watch.end)

    def __repr__(self) -> str:
        return f"<AsyncIO of {self.sync!r}>"
