"""Data capture at servo rate on the controller (``controller.capture(...)``).

The controller records operands (``_RPA``, ``_TPA``, ``_TEA``, ``_TVA`` ...) into arrays by
itself, every ``2**n`` samples (``RA``, ``RD``, ``RC``), with nothing lost to the link; the
host uploads the arrays afterwards (``QU``) into numpy. The recording starts on a line of its
own, ``RC n,m;MG TIME``, so the controller sample of its first value is known exactly; start it
just before a move and every value lines up with the move's prediction
(``MoveHandle.begin``)::

    cap = dmc.capture(["_RPA", "_TPA"], every=2, seconds=1.0)
    move = dmc.A.move_to(10 * mm)
    recording = cap.wait()                  # a Recording: .samples, .t, ["_RPA"]
    compare_plot(move, recording)

Why not ``RC`` on the move's own line: a refused ``RC`` would raise for a line whose motion
did start; a line of its own costs a few samples of recording before the move (none on a
simulator whose clock waits for the host), never a wrong answer. See ``docs/decisions/0018``.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from galil.arrays import CAPTURE_ARRAYS, Arrays
from galil.errors import (
    FixedAttributes,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
    ReadOnly,
    decimal_hint,
)
from galil.link import CommandLink, check_count, check_wait_timeout
from galil.protocol import commands as cmds
from galil.protocol.numbers import read_one
from galil.units import plain_seconds

__all__ = ["Capture", "Recording"]


@dataclass(frozen=True)
class Recording:
    """Values the controller recorded, one every ``every`` samples from sample ``start``.

    Attributes:
        sources: the operands recorded (``"_RPA"`` ...), in order.
        every: samples between values.
        start: the controller sample (``TIME``) of the first value.
        sample_period: seconds per sample.
        values: the values per source, float64 (counts for positions).
    """

    sources: tuple[str, ...]
    every: int
    start: int
    sample_period: float
    values: Mapping[str, npt.NDArray[np.float64]] = field(repr=False)

    def __len__(self) -> int:
        return len(next(iter(self.values.values()))) if self.values else 0

    def __repr__(self) -> str:
        n = len(self)
        return (
            f"Recording(sources={self.sources!r}, {n} value{'s' if n != 1 else ''} each,"
            f" every={self.every}, start={self.start}, sample_period={self.sample_period:.6g},"
            f" {n * self.every * self.sample_period:.6g} s)"
        )

    def __getitem__(self, source: str) -> npt.NDArray[np.float64]:
        try:
            return self.values[source]
        except KeyError:
            raise KeyError(f"{source!r} was not recorded; recorded: {self.sources}") from None

    @property
    def samples(self) -> npt.NDArray[np.int64]:
        """The controller sample of each value (``start``, ``start + every`` ...)."""
        return self.start + self.every * np.arange(len(self), dtype=np.int64)

    @property
    def t(self) -> npt.NDArray[np.float64]:
        """Seconds since the first value."""
        return np.multiply(self.samples - self.start, self.sample_period, dtype=np.float64)

    def position(self, axis: str) -> npt.NDArray[np.float64]:
        """The recorded reference (``_RP``) of ``axis``, else its encoder position (``_TP``).

        Raises:
            KeyError: neither was recorded.
        """
        for op in ("RP", "TP"):
            if f"_{op}{axis}" in self.values:
                return self.values[f"_{op}{axis}"]
        raise KeyError(f"neither _RP{axis} nor _TP{axis} was recorded; recorded: {self.sources}")


def _count(count: object, seconds: object, every: int, sample_period: float) -> int:
    if (count is None) == (seconds is None):
        raise InvalidArgument("give how many values to record (count=) or for how long (seconds=)")
    if seconds is not None:
        value = plain_seconds(seconds, "seconds")  # (a time Quantity, in seconds)
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not (math.isfinite(value) and value > 0)
        ):
            raise InvalidArgument(
                f"seconds must be a positive number (or a time Quantity), not {seconds!r}"
                f"{decimal_hint(seconds)}"
            )
        return math.ceil(value / (every * sample_period) - 1e-9) + 1
    return check_count(count, "count")


class Capture(FixedAttributes):
    """A recording on the controller: started by :meth:`start`, read by :meth:`wait` or
    :meth:`stop`. Build it with ``controller.capture(...)``.

    Everything is checked when it is built, before a byte is sent: the sources (what ``RD``
    records), ``every`` (a power of two the model allows), and that ``count`` values of every
    source fit the model's array space.

    Args:
        link: the command link.
        sources: operands to record (``["_RPA", "_TPA"]``).
        every: samples between values (2, 4 ... 256).
        count: values to record per source.
        seconds: or how long to record (``count`` follows).

    Attributes:
        result: the :class:`Recording`, once uploaded.
        start_sample: the controller sample of the first value, once started.
    """

    link: ReadOnly[CommandLink] = ReadOnly()
    sources: ReadOnly[tuple[str, ...]] = ReadOnly()
    every: ReadOnly[int] = ReadOnly()
    count: ReadOnly[int] = ReadOnly()
    arrays: ReadOnly[tuple[str, ...]] = ReadOnly()
    start_sample: ReadOnly[int | None] = ReadOnly()
    result: ReadOnly[Recording | None] = ReadOnly()

    def __init__(
        self,
        link: CommandLink,
        sources: Sequence[str],
        *,
        every: int = 2,
        count: int | None = None,
        seconds: float | None = None,
    ) -> None:
        model = link.model
        if isinstance(sources, str) or not isinstance(sources, Sequence) or not sources:
            raise InvalidArgument(
                f"sources is a list of operands such as ['_RPA'], not {sources!r}"
            )
        names = tuple(sources)
        if len(set(names)) != len(names):
            raise InvalidArgument(f"a source is named twice in {list(names)}")
        self._rd = cmds.rd(*names, model=model)
        cmds.rc(every, None, model=model)  # a power of two in the model's range
        n = _count(count, seconds, every, link.sample_period)
        if n * len(names) > model.array_elements:
            raise InvalidArgument(
                f"{n} values of {len(names)} sources need {n * len(names)} array elements; "
                f"{model.name} has {model.array_elements}",
                model=model.name,
            )
        self._link = link
        self._sources = names
        self._every = every
        self._count = n
        self._arrays = CAPTURE_ARRAYS[: len(names)]
        self._start_sample: int | None = None
        self._result: Recording | None = None
        self._started_at = 0.0
        self._stop_pending = False  # an RC 0 owed to the controller (decision 0085)
        self._cut_at: int | None = None  # values recorded when the library stopped it
        self._reused = False  # a later capture took its arrays before it was read back

    @property
    def stop_pending(self) -> bool:
        """Whether the controller may still record for this capture although its start
        failed or its stop could not be sent (a dead link, Ctrl-C): :meth:`reopened`, run by
        the controller once the link works again, stops it (``RC 0``); no I/O."""
        return self._stop_pending

    @property
    def duration(self) -> float:
        """Seconds from the first value to the last."""
        return (self.count - 1) * self.every * self.link.sample_period

    def start(self) -> Capture:
        """Set the arrays up and start recording (``RC n,m`` with ``MG TIME`` behind it).

        Before anything is set up, ``_RC`` and the arrays (``LA``) are read: the capture's
        arrays must fit the array space the user's arrays leave. Arrays it set up are freed
        again (``DA``) if the start fails (decision 0097).

        Raises:
            InvalidArgument: a recording runs already (``_RC`` is 1), or the arrays the
                controller has leave too few elements or arrays free (nothing is set up).
            CommandError: the controller refused.
        """
        link = self.link
        if self.start_sample is not None:
            raise InvalidArgument("this capture was started already; make a new one")
        if round(link.query_operands(["_RC"])[0]):
            raise InvalidArgument(
                "the controller is recording already (_RC is 1); wait for it or stop it "
                "(RC 0) first",
                model=link.model.name,
            )
        old = self._check_room(Arrays(link).list())
        try:
            self._set_up(old)
            start = self._record()
        except BaseException:
            self._free_arrays()
            raise
        self._start_sample = start
        self._started_at = link.clock()
        return self

    def _check_room(self, existing: Mapping[str, int]) -> list[str]:
        """The capture's arrays left by an earlier one (freed first), once the room the
        other arrays leave is seen to hold this capture's.

        Raises:
            InvalidArgument: too few elements or arrays free.
        """
        model = self.link.model
        others = {a: n for a, n in existing.items() if a not in self.arrays}
        free = model.array_elements - sum(others.values())
        need = self.count * len(self.arrays)
        if need > free or len(others) + len(self.arrays) > model.arrays:
            raise InvalidArgument(
                f"{self.count} values of {len(self.arrays)} sources need {need} array elements"
                f" in {len(self.arrays)} arrays; the controller's {len(others)} other arrays"
                f" ({', '.join(others) or 'none'}) leave {free} of {model.array_elements}"
                f" elements and {model.arrays - len(others)} of {model.arrays} arrays: free"
                " some (arrays.delete) or record fewer values",
                model=model.name,
            )
        return [a for a in self.arrays if a in existing]

    def _set_up(self, old: Sequence[str]) -> None:
        """``DA`` the arrays an earlier capture left, ``DM`` each, ``RA`` and ``RD``."""
        link = self.link
        model = link.model
        setup = [cmds.da(*old)] if old else []
        setup += [cmds.dm(a, self.count, model=model) for a in self.arrays]
        setup += [cmds.ra(*self.arrays, model=model), self._rd]
        link.command_line(setup)

    def _record(self) -> int:
        """``RC n,m;MG TIME``: the sample of the first value.

        RC may have started when this fails (a lost or malformed reply): no recording
        outlives start(), and one whose RC 0 cannot go out (a dead link) is stopped once it
        works again (:attr:`stop_pending`).
        """
        link = self.link
        try:
            replies = link.command_line(
                [cmds.rc(self.every, self.count, model=link.model), cmds.time_stamp()]
            )
            try:
                return round(read_one(replies[-1]))
            except ProtocolError as exc:
                raise link.error(ProtocolError, f"MG TIME answered {replies[-1]!r}") from exc
        except BaseException:
            self._stop_pending = True
            with contextlib.suppress(GalilError):
                link.command_line([cmds.rc(0)])
                self._stop_pending = False
            raise

    def _free_arrays(self) -> None:
        """After a failed start, ``DA`` the capture's arrays it set up (those ``LA`` lists),
        unless a recording may still write them (an ``RC 0`` owed) or the link fails."""
        if self._stop_pending:
            return
        with contextlib.suppress(GalilError):
            present = [a for a in self.arrays if a in Arrays(self.link).list()]
            if present:
                self.link.command_line([cmds.da(*present)])

    @property
    def done(self) -> bool:
        """Whether the recording is over (``_RC`` is 0); one query."""
        if self.start_sample is None:
            return False
        return not round(self.link.query_operands(["_RC"])[0])

    def wait(self, timeout: float | None = None) -> Recording:
        """Wait until every value is recorded, then upload them (``QU``).

        Args:
            timeout: seconds at most (default: the recording's duration plus a margin).

        Raises:
            InvalidArgument: the capture was not started, or ``timeout`` is not ``None`` or a
                finite number >= 0 (:func:`~galil.link.check_wait_timeout`), or a later
                capture took its arrays before it was read back (:meth:`reused`), or the
                recording was stopped before its ``count`` values (a stop cut short, whose
                ``RC 0`` went out or goes out now: :meth:`stop` uploads what it holds).
            GalilTimeoutError: still recording after ``timeout`` (it goes on; :meth:`stop`).
        """
        timeout = check_wait_timeout(timeout)
        if self.result is not None:
            return self.result
        self._check_readable()
        if self._stop_pending:  # (a stop cut short on a link that works: it is owed now)
            self.reopened()
        if self._cut_at is not None:
            raise InvalidArgument(
                f"this capture was stopped (RC 0) after {self._cut_at} of {self.count} "
                "values (its stop was cut short, or its link reopened): stop() uploads those",
                model=self.link.model.name,
            )
        link = self.link
        limit = self.duration * 1.5 + 2.0 if timeout is None else timeout
        deadline = self._started_at + limit
        left = self._started_at + self.duration - link.clock()
        if left > 0:
            link.pause(min(left, limit))
        while not self.done:
            now = link.clock()
            if now >= deadline:
                raise link.error(
                    GalilTimeoutError, f"the capture still records after {limit:.3g} s"
                )
            link.pause(min(0.05, max(deadline - now, 0.001), self.every * link.sample_period * 4))
        return self._upload(self.count)

    def stop(self) -> Recording:
        """Stop recording now (``RC 0``) and upload what was recorded.

        A stop cut short before the recording is known stopped (a dead link, Ctrl-C) leaves
        :attr:`stop_pending`: the ``RC 0`` goes out when the link works again, and ``_RD``
        is read then even if the recording had stopped (that ``RC 0`` may have gone out
        before the link died), so only the values recorded are uploaded.

        Raises:
            InvalidArgument: the capture was not started, or a later capture took its arrays
                before it was read back (:meth:`reused`): it would stop that one.
        """
        if self.result is not None:
            return self.result
        self._check_readable()
        n = self._cut_at
        if n is None:
            owed, self._stop_pending = self._stop_pending, True
            _, recorded = self._stopped(self.link, owed=owed)
            self._stop_pending = False
            n = self.count if recorded is None else min(recorded, self.count)
        return self._upload(n)

    def reused(self) -> None:
        """A later capture of the same controller took this one's arrays (``gcap0``...)
        before it was read back: its values are gone, and :meth:`wait` and :meth:`stop`
        refuse rather than read (or stop) the later recording; no I/O."""
        if self.result is None and self.start_sample is not None:
            self._reused = True

    def _check_readable(self) -> None:
        if self.start_sample is None:
            raise InvalidArgument("start() the capture first")
        if self._reused:
            raise InvalidArgument(
                "a later capture reused this capture's arrays before it was read back: its "
                "values are gone (read a capture with wait() or stop() before starting the "
                "next)",
                model=self.link.model.name,
            )

    def _stopped(self, link: CommandLink, *, owed: bool = False) -> tuple[bool, int | None]:
        """``RC 0`` if the controller still records; whether it did, and how many values it
        had recorded then (``_RD``), or ``None`` when it had ended already, unless a stop was
        ``owed`` (one cut short: its ``RC 0`` may have gone out before the link died): then
        ``_RD``, read in the same query as ``_RC``, says how far the recording got.

        ``_RD`` is the index of the next element to record, so a recording that ended by
        itself reads ``count`` (the simulator's; unsourced for a controller's end of a
        recording).
        """
        names = ["_RC", "_RD"] if owed else ["_RC"]
        values = link.query_operands(names)
        if not round(values[0]):
            return False, round(values[1]) if owed else None
        link.command_line([cmds.rc(0)])
        return True, round(link.query_operands(["_RD"])[0])

    def reopened(self) -> bool:
        """The link works (again): a recording this capture left running (its start failed
        once ``RC`` had gone out, or its stop could not be sent) is stopped now (``RC 0``);
        :meth:`stop` then uploads the values recorded until then, and :meth:`wait` refuses
        (they are fewer than ``count``). A stop whose ``RC 0`` went out before its link died
        found the recording stopped: ``_RD`` says how many values it holds all the same. The
        controller runs this on every reopen and before the next capture (decision 0085).

        Returns:
            Whether the controller was still recording (and was stopped).
        """
        if not self._stop_pending:
            return False
        started = self.start_sample is not None
        recording, n = self._stopped(self.link, owed=started)
        if n is not None and started and n < self.count:
            self._cut_at = n  # (count values recorded: the recording ended by itself)
        self._stop_pending = False
        return recording

    def _upload(self, n: int) -> Recording:
        assert self.start_sample is not None
        link = self.link
        arrays = Arrays(link)
        values = {
            s: arrays.upload(a, 0, n - 1) if n > 0 else np.zeros(0)
            for s, a in zip(self.sources, self.arrays, strict=True)
        }
        link.command_line([cmds.da(*self.arrays)])
        result = Recording(self.sources, self.every, self.start_sample, link.sample_period, values)
        self._result = result
        return result

    def __enter__(self) -> Capture:
        if self.start_sample is None:
            self.start()
        return self

    def __exit__(self, kind: object, *exc: object) -> None:
        if self.result is None and self.start_sample is not None:
            try:
                self.stop()
            except GalilError:
                if kind is None:
                    raise  # the block's own exception, if any, matters more

    def __repr__(self) -> str:
        state = (
            "uploaded" if self.result else "recording" if self.start_sample is not None else "new"
        )
        return (
            f"<Capture {', '.join(self.sources)} every {self.every} samples, "
            f"{self.count} values, {state}>"
        )
