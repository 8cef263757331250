"""The binary data record: ``QZ``, ``QR`` and the ``DR`` stream.

The record is built from the dtype :func:`galil.protocol.records.record_dtype` gives for the
model's ``QZ`` sizes: a zeroed numpy record whose fields are filled by name, then taken as
bytes. Inputs read high (nothing is connected). ``QR AB`` limits the axis blocks (the header
says which); ``DR n,h`` streams a record every ``n`` samples to handle ``h``, without ``:``,
at the exact sample it is due.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from galil.errors import InvalidArgument
from galil.models import INT32_MAX, INT32_MIN
from galil.protocol.records import record_dtype
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused, split_fields
from galil.sim.ports import HANDLES, Port
from galil.sim.registry import handler, operand
from galil.sim.rooms.contour import Contour
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.motion import Motion
from galil.sim.servo import Axis

__all__ = ["Records"]

#: What every known general block starts with; an unsourced block (the DMC-30010's 18 bytes,
#: kept raw by galil.protocol.records) gets these and nothing else.
_GENERAL_START = np.dtype([("sample", "<u2"), ("inputs", "u1", (10,))])


@dataclass(frozen=True)
class _Layout:
    """A record layout with some axis blocks: its dtype, header and where the blocks are."""

    dtype: np.dtype[Any]
    mask: int
    general_at: int | None  # byte offset of a general block of unknown layout (kept raw)
    axes_at: int  # byte offset of the first axis block
    axis: np.dtype[Any] | None


def _field(dtype: np.dtype[Any], name: str) -> tuple[np.dtype[Any], int] | None:
    """The dtype and byte offset of field ``name``, or None."""
    fields = dtype.fields
    if fields is None or name not in fields:
        return None
    sub, offset = fields[name][:2]
    return sub, int(offset)


class Records(Room):
    """QZ, QR, DR and the record itself."""

    requires = (Motion, Limits, Contour)

    def __init__(self, machine: Machine) -> None:
        super().__init__(machine)
        self._layouts: dict[str, _Layout] = {}
        #: ``DR`` stream: (samples between records, port number), and the next record's sample.
        self.stream: tuple[int, int] | None = None
        self._next = 0

    # ---- the record --------------------------------------------------------------------
    def record(self, axes: str = "") -> bytes:
        """The data record; ``axes`` (letters) limits the axis blocks; default all.

        Raises:
            InvalidArgument: the model has no data record layout here.
        """
        spec = self.machine.spec
        qz = spec.qz
        if qz is None:
            raise InvalidArgument(f"{spec.name}: no data record layout in the simulator")
        present = [
            ax
            for ax in list(self.machine.servo.axes.values())[: qz[0]]
            if not axes or ax.letter in axes
        ]
        layout = self._layout(present)
        buf = np.zeros((), layout.dtype)
        buf["header"] = 0x87
        buf["axes_present"] = layout.mask
        buf["size"] = layout.dtype.itemsize
        self._general(buf, layout)
        if present:
            assert layout.axis is not None
            blocks = np.ndarray(len(present), layout.axis, buffer=buf.data, offset=layout.axes_at)
            self._fill_axes(blocks, present)
        return buf.tobytes()

    def _layout(self, present: list[Axis]) -> _Layout:
        letters = "".join(ax.letter for ax in present)
        layout = self._layouts.get(letters)
        if layout is None:
            spec = self.machine.spec
            dtype = record_dtype(spec, axes=len(present), letters=letters)
            general = _field(dtype, "general")
            first = _field(dtype, letters[0]) if letters else None
            layout = _Layout(
                dtype,
                sum(1 << spec.axes.index(c) for c in letters),
                general[1] if general else None,
                first[1] if first else dtype.itemsize,
                first[0] if first else None,
            )
            self._layouts[letters] = layout
        return layout

    def _general(self, buf: np.ndarray[Any, Any], layout: _Layout) -> None:
        m = self.machine
        if layout.general_at is not None:  # a general block of unknown layout
            start = np.ndarray((), _GENERAL_START, buffer=buf.data, offset=layout.general_at)
            start["sample"] = m.servo.sample & 0xFFFF
            start["inputs"] = 0xFF
            return
        names = layout.dtype.names or ()
        threads = sum(1 << t for t in m.programs.threads)
        buf["sample"] = m.servo.sample & 0xFFFF
        buf["inputs"] = 0xFF
        buf["error_code"] = m.interp.tc & 0xFF
        if "thread_status" in names:
            buf["thread_status"] = threads & 0xFF
        if "contour_buffer" in names:
            buf["contour_buffer"] = m.room(Contour).free()
        if "general_status" in names:
            buf["general_status"] = (0x80 if threads else 0) | (1 if m.ports.echo else 0)

    def _fill_axes(self, blocks: np.ndarray[Any, Any], present: list[Axis]) -> None:
        limits = self.machine.room(Limits)
        ms = [ax.m for ax in present]
        blocks["status"] = [self._status_word(ax) for ax in present]
        blocks["switches"] = [limits.switch_bits(ax) for ax in present]
        blocks["stop_code"] = [int(m.profiler.stop_code) & 0xFF for m in ms]
        blocks["reference"] = [_clamp32(m.reference) for m in ms]
        encoders = [_clamp32(m.encoder) for m in ms]
        blocks["position"] = encoders
        blocks["error"] = [_clamp32(m.error) for m in ms]
        blocks["aux_position"] = encoders
        blocks["velocity"] = [_clamp32(round(64 * m.velocity)) for m in ms]

    def _status_word(self, ax: Axis) -> int:
        m = ax.m
        prof = m.profiler
        word = 0
        if m.moving:
            word |= 0x8000
            if prof.mode == "position":
                absolute = self.machine.room(Motion).params(ax).absolute
                word |= 0x4000 | (0x2000 if absolute else 0)
            if prof.velocity < 0:
                word |= 0x0080
            if ax.limit_stop or prof.stop_code in (2, 3, 4):
                word |= 0x0010
        if prof.mode == "contour":
            word |= 0x0040
        if not m.motor_on:
            word |= 0x0001
        return word

    # ---- commands ----------------------------------------------------------------------
    def _check_model(self) -> None:
        if self.machine.spec.qz is None:
            raise Refused(1, "no data record on this model")

    @handler("QZ")
    def qz(self, args: str) -> str:
        qz = self.machine.spec.qz
        if qz is None:
            raise Refused(1, "no data record on this model")
        return ",".join(self.machine.interp.num(v, "10.0") for v in qz) + "\r\n"

    @handler("QR")
    def qr(self, args: str) -> str:
        self._check_model()
        # QR AB asks for those axis blocks only (the header says which); the general and
        # coordinated blocks always come (I, S, T, N letters are accepted and change nothing).
        axes = ""
        for c in args.replace(" ", "").replace(",", "").upper():
            if c in "ISTN":
                continue
            letter = self.machine.interp.axis(c).letter
            if letter not in axes:
                axes += letter
        return self.record(axes).decode("latin-1")

    @handler("DR")
    def dr(self, args: str) -> str:
        i = self.machine.interp
        fields = split_fields(args)
        if len(fields) > 2 or not fields[0].strip():
            raise Refused(6, "DR takes samples and an optional handle")
        period = i.evaluate(fields[0])
        if period == 0:
            self.stream = None
            return ""
        self._check_model()
        low, high = self.machine.spec.dr_range
        if period != int(period) or not low <= period <= high:
            raise Refused(6, f"DR period must be 0 or {low}..{high} samples")
        number = self._target(fields[1] if len(fields) == 2 else "")
        self.stream = (int(period), number)
        self._next = self.machine.servo.sample + int(period)
        return ""

    def _target(self, field: str) -> int:
        """The port a ``DR`` streams to: handle ``field`` (0-7), or the asking handle."""
        caller = self.machine.interp.caller
        if field.strip():
            index = self.machine.interp.evaluate(field)
            if index != int(index) or not 0 <= index < len(HANDLES):
                raise Refused(6, "DR handle is 0..7 (A..H)")
            return self.machine.ports.handle(HANDLES[int(index)]).number
        if isinstance(caller, Port) and caller.letter:
            return caller.number
        raise Refused(6, "DR streams to an Ethernet handle; name one (DR n,h)")

    @operand("DR")
    def period(self) -> float:
        return float(self.stream[0]) if self.stream is not None else 0.0

    # ---- the stream --------------------------------------------------------------------
    def horizon(self, k: int) -> int:
        if self.stream is not None:
            return min(k, self._next - self.machine.servo.sample)  # a record is due there
        return k

    def service(self) -> None:
        if self.stream is None or self.machine.servo.sample < self._next:
            return
        period, number = self.stream
        port = self.machine.ports.ports.get(number)
        if port is None:
            self.stream = None
            return
        # Streamed records carry no ':' (only a solicited QR has one).
        port.out += self.record()
        while self._next <= self.machine.servo.sample:
            self._next += period

    def port_closed(self, number: int) -> None:
        if self.stream is not None and self.stream[1] == number:
            self.stream = None


def _clamp32(v: int) -> int:
    return max(INT32_MIN, min(INT32_MAX, int(v)))
