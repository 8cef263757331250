"""The binary data record: ``QZ``, ``QR`` and the ``DR`` stream.

The record is built from the dtype :func:`galil.protocol.records.record_dtype` gives for the
model's ``QZ`` sizes: a zeroed numpy record (one per set of axis blocks, reused) whose fields
are filled by name, then taken as bytes. Inputs read high (nothing is connected). ``QR AB``
limits the axis blocks (the header says which); ``DR n,h`` streams a record every ``n`` samples
to handle ``h``, without ``:``, at the exact sample it is due.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import numpy as np

from galil.errors import InvalidArgument
from galil.models import INT32_MAX, INT32_MIN
from galil.predict.engine import final_decel, slewing
from galil.protocol.records import record_dtype
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused, split_fields
from galil.sim.ports import HANDLES, Port
from galil.sim.registry import handler, operand
from galil.sim.rooms.contour import Contour
from galil.sim.rooms.homing import Homing
from galil.sim.rooms.io import IO
from galil.sim.rooms.limits import Limits
from galil.sim.rooms.motion import Motion
from galil.sim.rooms.reports import Reports
from galil.sim.rooms.vector import Vector
from galil.sim.servo import Axis

__all__ = ["Records"]

#: What every known general block starts with; a block of unknown layout (kept raw by
#: galil.protocol.records) gets these and nothing else.
_GENERAL_START = np.dtype([("sample", "<u2"), ("inputs", "u1", (10,))])
#: The general fields that change (those a layout has), filled by name; the coordinated
#: planes' blocks (S, and T where the layout has it) with them.
_PLANE = ("segments", "status", "distance", "buffer")
_GENERAL: tuple[str, ...] = ("sample", "error_code", "thread_status", "contour_buffer")
_GENERAL += ("general_status", *(f"{p}_{name}" for p in "st" for name in _PLANE))
#: The axis fields that change, in the order :meth:`Records._axis` gives their values.
_AXIS = ["status", "switches", "stop_code", "reference", "position", "error"]
_AXIS += ["aux_position", "velocity"]


class _Layout:
    """One record with some axis blocks, reused: the fields that never change are set once;
    ``general`` and ``axes`` are views of the fields that change (by name, from the dtype)."""

    def __init__(self, dtype: np.dtype[Any], mask: int, letters: str) -> None:
        self.buf = np.zeros(1, dtype)
        self.buf["header"] = 0x87
        self.buf["axes_present"] = mask
        self.buf["size"] = dtype.itemsize
        names = dtype.names or ()
        if "general" in names:  # a general block of unknown layout
            start = self._view(_GENERAL_START, _field(dtype, "general")[1])
            start["inputs"] = 0xFF
            self.general_names: tuple[str, ...] = ("sample",)
            self.general = start[["sample"]]
        else:
            self.buf["inputs"] = 0xFF  # inputs read high when nothing is connected
            self.general_names = tuple(n for n in _GENERAL if n in names)
            self.general = self.buf[list(self.general_names)]
        self.axes: np.ndarray[Any, Any] | None = None
        if letters:
            block, at = _field(dtype, letters[0])
            blocks = self._view(block, at, len(letters))
            self.axes = blocks[_AXIS]

    def _view(self, dtype: np.dtype[Any], offset: int, n: int = 1) -> np.ndarray[Any, Any]:
        view: np.ndarray[Any, Any] = np.ndarray(n, dtype, buffer=self.buf.data, offset=offset)
        return view


def _field(dtype: np.dtype[Any], name: str) -> tuple[np.dtype[Any], int]:
    """The dtype and byte offset of field ``name``."""
    fields = dtype.fields
    assert fields is not None
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
        self._fill: list[Callable[[np.ndarray[Any, Any], str], None]] | None = None
        self._vector_room: Vector | None = None
        self._vector_known = False  # whether _vector_room was looked up

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
        letters = "".join(ax.letter for ax in present)
        layout = self._layouts.get(letters)
        if layout is None:
            dtype = record_dtype(spec, axes=len(present), letters=letters)
            mask = sum(1 << spec.axes.index(c) for c in letters)
            layout = self._layouts[letters] = _Layout(dtype, mask, letters)
        layout.general[0] = self._general(layout.general_names)
        if layout.axes is not None:
            m = self.machine
            motion, limits, reports = m.room(Motion), m.room(Limits), m.room(Reports)
            layout.axes[:] = [self._axis(ax, motion, limits, reports) for ax in present]
        for fill in self._fillers():
            fill(layout.buf, letters)
        return layout.buf.tobytes()

    def _fillers(self) -> list[Callable[[np.ndarray[Any, Any], str], None]]:
        """Rooms that put their own fields into the record (I/O, homing status bits)."""
        if self._fill is None:
            self._fill = []
            with contextlib.suppress(KeyError):
                self._fill.append(self.machine.room(IO).fill_record)
            with contextlib.suppress(KeyError):
                self._fill.append(self.machine.room(Homing).fill_record)
        return self._fill

    def _general(self, names: tuple[str, ...]) -> tuple[int, ...]:
        m = self.machine
        sample = m.servo.sample & 0xFFFF
        if len(names) == 1:
            return (sample,)
        threads = sum(1 << t for t in m.programs.threads)
        values = {
            "sample": sample,
            "error_code": m.interp.tc & 0xFF,
            "thread_status": threads & 0xFF,
            "general_status": (0x80 if threads else 0) | (1 if m.ports.echo else 0),
        }
        if "contour_buffer" in names:
            values["contour_buffer"] = m.room(Contour).free()
        vector = self._vector()
        if vector is not None:
            for p in "st":
                if f"{p}_status" in names:
                    block = vector.record_block(p.upper())
                    values.update(zip([f"{p}_{n}" for n in _PLANE], block, strict=True))
        return tuple(values.get(n, 0) for n in names)

    def _vector(self) -> Vector | None:
        """The coordinated-motion room, when the controller has one."""
        if not self._vector_known:
            with contextlib.suppress(KeyError):
                self._vector_room = self.machine.room(Vector)
            self._vector_known = True
        return self._vector_room

    @staticmethod
    def _axis(ax: Axis, motion: Motion, limits: Limits, reports: Reports) -> tuple[int, ...]:
        m = ax.m
        prof = m.profiler
        status = 0
        if prof.moving:
            status |= 0x8000
            if prof.mode == "position":
                status |= 0x6000 if motion.params(ax).absolute else 0x4000
            if prof.velocity < 0:
                status |= 0x0080
            if ax.limit_stop or prof.stop_code in (2, 3, 4):
                status |= 0x0010
            # b8 coordinated motion, b5 slewing, b3 final deceleration (galil-protocol.md
            # section 4, axis status word; DMC-2x00 user manual p.68).
            if prof.mode == "vector":  # a VM or LM sequence drives the axis
                status |= 0x0100
            elif slewing(prof):  # b5 (a sequence's phases are in its plane's block)
                status |= 0x0020
            elif final_decel(prof):  # b3
                status |= 0x0008
        if prof.mode == "contour":
            status |= 0x0040
        if not m.motor_on:
            status |= 0x0001
        return (
            status,
            limits.switch_bits(ax),
            int(prof.stop_code) & 0xFF,
            _clamp32(m.reference),
            _clamp32(round(reports.position(ax))),
            _clamp32(m.error),
            _clamp32(round(reports.auxiliary(ax))),
            _clamp32(round(64 * m.velocity)),
        )

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
