"""Binary data records (``QR`` / ``DR``) as numpy structured dtypes.

The layout is chosen from the ``QZ`` sizes (axes, general, coordinated, per-axis bytes), as
EPICS does, not from fixed offsets: a 52-byte general block is the DMC-40x0/41x3/500x0 (and
18x6) layout, a 24-byte one the DMC-21x3/2x00/1700/18x2 layout (28-byte axis blocks; the 18x2's
end in two reserved bytes where the others carry the axis's analog input),
an 18-byte one the DMC-30010 layout (gclib ``GDataRecord30000``: two input and two output
banks, the analog input and outputs, the amplifier status; a 16-byte coordinated block with
the contour and S-plane fields). Other blocks are kept as raw bytes, with the 36-byte axis
block of the 40x0 when the axis size matches. All fields are little-endian. Offsets follow
``galil-protocol.md`` section 4 (gclib ``gclib_record.h``).

Beyond the bulk form (numpy structured records), :func:`decode_fields` gives one record as
named values: the axis status word, switch byte and stop code as booleans and text
(:class:`AxisStatus`, :class:`Switches`). The record's sample counter is 16 bits and wraps;
:func:`extend_sample` extends it against the controller's ``TIME``, and :func:`with_time`
adds the extended value to a record as its ``time`` field.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from galil.codes import stop_text
from galil.errors import InvalidArgument, ProtocolError
from galil.models import ModelSpec

__all__ = [
    "AXIS_LETTERS",
    "RECORD_VELOCITY_SCALE",
    "AxisFields",
    "AxisStatus",
    "PlaneFields",
    "PlaneStatus",
    "RecordFields",
    "RecordSplitter",
    "Switches",
    "decode_fields",
    "decode_record",
    "decode_records",
    "extend_sample",
    "follow_samples",
    "parse_qz",
    "record_dtype",
    "record_size",
    "record_to_dict",
    "with_time",
    "with_times",
]

AXIS_LETTERS = "ABCDEFGH"
#: A data record's ``velocity`` field is this many times ``TV`` (counts/s; M40-UM, decision
#: 0097): the record and its dict keep the controller's raw value, ``decode_fields`` divides.
RECORD_VELOCITY_SCALE = 64

_HEADER: list[tuple[str, str]] = [("header", "u1"), ("axes_present", "u1"), ("size", "<u2")]

_GENERAL_4000: list[tuple[Any, ...]] = [
    ("sample", "<u2"),
    ("inputs", "u1", (10,)),
    ("outputs", "u1", (10,)),
    ("reserved", "u1", (16,)),
    ("ethernet", "u1", (8,)),
    ("error_code", "u1"),
    ("thread_status", "u1"),
    ("amplifier_status", "<u4"),
]
_COORD_4000: list[tuple[Any, ...]] = [
    ("contour_segments", "<u4"),
    ("contour_buffer", "<u2"),
    ("s_segments", "<u2"),
    ("s_status", "<u2"),
    ("s_distance", "<i4"),
    ("s_buffer", "<u2"),
    ("t_segments", "<u2"),
    ("t_status", "<u2"),
    ("t_distance", "<i4"),
    ("t_buffer", "<u2"),
]
_AXIS_4000: list[tuple[Any, ...]] = [
    ("status", "<u2"),
    ("switches", "u1"),
    ("stop_code", "u1"),
    ("reference", "<i4"),
    ("position", "<i4"),
    ("error", "<i4"),
    ("aux_position", "<i4"),
    ("velocity", "<i4"),
    ("torque", "<i4"),
    ("analog_in", "<u2"),
    ("hall", "u1"),
    ("reserved", "u1"),
    ("user", "<i4"),
]
_GENERAL_2103: list[tuple[Any, ...]] = [
    ("sample", "<u2"),
    ("inputs", "u1", (10,)),
    ("outputs", "u1", (10,)),
    ("error_code", "u1"),
    ("general_status", "u1"),
]
_COORD_2103: list[tuple[Any, ...]] = [
    ("s_segments", "<u2"),
    ("s_status", "<u2"),
    ("s_distance", "<i4"),
    ("t_segments", "<u2"),
    ("t_status", "<u2"),
    ("t_distance", "<i4"),
]
_AXIS_2103: list[tuple[Any, ...]] = [
    ("status", "<u2"),
    ("switches", "u1"),
    ("stop_code", "u1"),
    ("reference", "<i4"),
    ("position", "<i4"),
    ("error", "<i4"),
    ("aux_position", "<i4"),
    ("velocity", "<i4"),
    ("torque", "<i2"),
    ("analog_in", "<u2"),
]
# DMC-18x2 (gclib GDataRecord1802): the 21x3 block, "no analog in axis data".
_AXIS_1802 = [*_AXIS_2103[:-1], ("reserved", "<u2")]


_GENERAL_30000: list[tuple[Any, ...]] = [
    ("sample", "<u2"),
    ("inputs", "u1", (2,)),
    ("outputs", "u1", (2,)),
    ("error_code", "u1"),
    ("thread_status", "u1"),
    ("analog_in", "<u2"),
    ("analog_out", "<i2", (2,)),
    ("amplifier_status", "<u4"),
]
_COORD_30000: list[tuple[Any, ...]] = [
    ("contour_segments", "<u4"),
    ("contour_buffer", "<u2"),
    ("s_segments", "<u2"),
    ("s_status", "<u2"),
    ("s_distance", "<i4"),
    ("s_buffer", "<u2"),
]
# RIO-47xxx (gclib GDataRecord47000_ENC / 47300): a 4-byte general block and the I/O in the
# "coordinated" block of QZ; no axis blocks. Analog values are 16-bit counts.
_GENERAL_RIO: list[tuple[Any, ...]] = [
    ("sample", "<u2"),
    ("error_code", "u1"),
    ("general_status", "u1"),
]
_IO_RIO_47100: list[tuple[Any, ...]] = [
    ("analog_out", "<u2", (8,)),
    ("analog_in", "<u2", (8,)),
    ("outputs", "<u2"),
    ("inputs", "<u2"),
    ("pulse_count", "<u4"),
    ("zc", "<i4"),
    ("zd", "<i4"),
]
_IO_RIO_47300: list[tuple[Any, ...]] = [
    ("analog_out", "<u2", (8,)),
    ("analog_in", "<u2", (8,)),
    ("outputs", "<u4"),
    ("inputs", "<u4"),
    ("pulse_count", "<u4"),
    ("zc", "<i4"),
    ("zd", "<i4"),
]


def parse_qz(reply: str) -> tuple[int, int, int, int]:
    """Parse a ``QZ`` reply (``" 4, 52, 26, 36"``) into (axes, general, coord, per-axis).

    Raises:
        ProtocolError: not four non-negative integers.
    """
    fields = [f.strip() for f in reply.split(",")]
    if len(fields) != 4 or not all(f.isdigit() for f in fields):
        raise ProtocolError(f"not a QZ reply: {reply!r}")
    n, general, coord, axis = (int(f) for f in fields)
    return n, general, coord, axis


def record_dtype(
    model: ModelSpec | tuple[int, int, int, int],
    axes: int | None = None,
    letters: str | None = None,
    *,
    analog: bool | None = None,
) -> np.dtype[np.void]:
    """Return the structured dtype of a full data record for ``model`` (or a QZ tuple).

    ``axes`` overrides the axis count (a record holding fewer axis blocks) and ``letters``
    names the axis blocks (default ``"A"``, ``"B"``, ...). The general and coordinated blocks
    are flattened into top-level fields (``sample``, ``error_code``, ``contour_buffer``, ...).
    The fields keep the controller's raw values: an axis's ``velocity`` is
    :data:`RECORD_VELOCITY_SCALE` (64) times ``TV`` in counts/s, its ``status`` and
    ``switches`` the raw bits (:func:`decode_fields` gives counts/s and named bits).
    ``analog``: whether a 28-byte axis block ends with the axis's analog input (the 21x3's)
    or reserved bytes (the 18x2's, whose QZ is the same); default the model's
    (:attr:`~galil.models.ModelSpec.record_axis_analog`), True for a QZ tuple alone.

    Raises:
        InvalidArgument: the model has no data record we know of.
    """
    qz = model.qz if isinstance(model, ModelSpec) else model
    if qz is None:
        name = model.name if isinstance(model, ModelSpec) else str(model)
        raise InvalidArgument(f"{name} has no binary data record layout")
    if analog is None:
        analog = model.record_axis_analog if isinstance(model, ModelSpec) else True
    return _record_dtype(tuple(qz), axes, letters, analog)


@functools.lru_cache(maxsize=256)
def _record_dtype(
    qz: tuple[int, ...], axes: int | None, letters: str | None, analog: bool = True
) -> np.dtype[np.void]:
    # Built once per layout and set of axis blocks: a stream decodes thousands a second.
    # ``analog``: the 2103 axis block ends with the analog input (the 18x2's: reserved).
    n, general, coord, per_axis = qz
    if axes is not None:
        n = axes
    if not 0 <= n <= 8:
        raise InvalidArgument(f"a data record has 0 to 8 axis blocks, not {n}")
    names = AXIS_LETTERS[:n] if letters is None else letters
    if len(names) != n:
        raise InvalidArgument(f"{len(names)} axis letters for {n} axis blocks")
    if general == 52:
        g, c, a = _GENERAL_4000, _COORD_4000, _AXIS_4000
    elif general == 18:
        g, c, a = _GENERAL_30000, _COORD_30000, _AXIS_4000
    elif general == _size(_GENERAL_RIO) and qz[0] == 0:
        g, a = _GENERAL_RIO, _AXIS_4000
        c = _IO_RIO_47300 if coord == _size(_IO_RIO_47300) else _IO_RIO_47100
    else:
        g, c, a = _GENERAL_2103, _COORD_2103, _AXIS_2103 if analog else _AXIS_1802
    gen = g if _size(g) == general else [("general", f"V{general}")]
    crd = c if _size(c) == coord else [("coordinated", f"V{coord}")]
    if _size(a) == per_axis:
        axis = np.dtype(a)
    elif _size(_AXIS_4000) == per_axis:
        axis = np.dtype(_AXIS_4000)
    else:
        axis = np.dtype([("raw", f"V{per_axis}")])
    fields: list[tuple[Any, ...]] = [*_HEADER, *gen, *crd]
    fields += [(letter, axis) for letter in names]
    dtype = np.dtype(fields)
    if dtype.itemsize != 4 + general + coord + n * per_axis:  # pragma: no cover - table bug
        raise AssertionError("record layout does not add up")
    return dtype


def _size(fields: list[tuple[Any, ...]]) -> int:
    return np.dtype(fields).itemsize


def decode_record(
    data: bytes, model: ModelSpec | tuple[int, int, int, int], *, analog: bool | None = None
) -> np.void:
    """Decode one record into a structured scalar (``rec["A"]["position"]``).

    The axis blocks present are read from the header (byte 1, bit n = axis n), so a ``QR``
    limited to some axes decodes too, with its blocks named by their letters. ``analog``: as
    :func:`record_dtype`.

    Raises:
        ProtocolError: the size disagrees with the header or the layout.
    """
    if len(data) < 4 or not data[0] & 0x80:
        raise ProtocolError("not a data record: missing header")
    size = data[2] | data[3] << 8
    if size != len(data):
        raise ProtocolError(f"record of {len(data)} bytes but its header says {size}")
    letters = "".join(AXIS_LETTERS[i] for i in range(8) if data[1] >> i & 1)
    dtype = record_dtype(model, axes=len(letters), letters=letters, analog=analog)
    if dtype.itemsize != len(data):
        raise ProtocolError(f"record of {len(data)} bytes, the layout wants {dtype.itemsize}")
    record: np.void = np.frombuffer(data, dtype=dtype)[0]
    return record


def decode_records(
    data: bytes | bytearray | memoryview,
    model: ModelSpec | tuple[int, int, int, int],
    *,
    analog: bool | None = None,
) -> npt.NDArray[np.void]:
    """Decode records laid end to end (a ``DR`` stream's bytes, whole records) in one pass;
    ``analog`` as :func:`record_dtype`.

    Every header is checked (at once, as an array) against the first one: a stream's records
    all have the same axis blocks. The result is a structured array viewing ``data``, nothing
    copied: read-only for ``bytes``; copy it before changing a ``bytearray`` it views.

    Raises:
        ProtocolError: a header that is not a record's or differs from the first, a size the
            layout disagrees with, or bytes left over after the last whole record.
    """
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size == 0:
        return np.frombuffer(b"", dtype=record_dtype(model, analog=analog))
    if raw.size < 4 or not raw[0] & 0x80:
        raise ProtocolError("not a data record: missing header")
    size = int(raw[2]) | int(raw[3]) << 8
    mask = int(raw[1])
    letters = "".join(AXIS_LETTERS[i] for i in range(8) if mask >> i & 1)
    dtype = record_dtype(model, axes=len(letters), letters=letters, analog=analog)
    if dtype.itemsize != size:
        raise ProtocolError(f"record header says {size} bytes, the layout wants {dtype.itemsize}")
    if raw.size % size:
        raise ProtocolError(f"{raw.size} bytes are not whole records of {size} bytes")
    heads = raw.reshape(-1, size)[:, :4]
    good = (heads[:, 0] & 0x80).astype(bool)
    good &= heads[:, 1] == raw[1]
    good &= heads[:, 2] == raw[2]
    good &= heads[:, 3] == raw[3]
    if not good.all():
        i = int(np.argmin(good))
        raise ProtocolError(f"record {i}: header {bytes(heads[i])!r} is not the stream's")
    records: npt.NDArray[np.void] = np.frombuffer(data, dtype=dtype)
    return records


def record_to_dict(record: np.void) -> dict[str, object]:
    """Turn a decoded record into plain Python values (nested dicts per axis), raw as the
    record holds them: ``velocity`` is 64 times ``TV`` (:data:`RECORD_VELOCITY_SCALE`;
    :func:`decode_fields` gives counts/s)."""
    out: dict[str, object] = {}
    for name in record.dtype.names or ():
        value = record[name]
        if value.dtype.names:
            out[name] = record_to_dict(value)
        elif value.shape:
            out[name] = value.tolist()
        else:
            out[name] = value.item()
    return out


def record_size(qz: tuple[int, int, int, int], axes_present: int) -> int:
    """Bytes of a record whose header says ``axes_present`` (byte 1: bit n = axis n)."""
    _, general, coord, per_axis = qz
    return 4 + general + coord + bin(axes_present & 0xFF).count("1") * per_axis


class RecordSplitter:
    """Cut a stream of ``DR`` records (no ``:`` between them) into whole records; sans-I/O.

    Each record announces its size in its header; with the ``QZ`` sizes given, that size is
    checked against the axis blocks the header says are present, so a stream that lost a
    byte is noticed at the next header rather than decoded as garbage.

    Args:
        qz: the controller's ``QZ`` sizes, or ``None`` to trust the headers' sizes.
        max_size: largest record accepted (bytes).
    """

    def __init__(self, qz: tuple[int, int, int, int] | None = None, max_size: int = 4096) -> None:
        self.qz = qz
        self.max_size = max_size
        self._buf = bytearray()
        self._sizes: dict[int, int] = {}  # record size by header axis byte

    def reset(self) -> None:
        """Forget a partial record (after an error, or to resynchronise)."""
        self._buf.clear()

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return every record now complete, oldest first.

        Raises:
            ProtocolError: a header is not a record header, or its size is impossible. The
                partial record is dropped; call :meth:`reset` before feeding on.
        """
        self._buf += data
        ends = self._cut()
        buf = self._buf
        out = [bytes(buf[a:b]) for a, b in zip([0, *ends], ends, strict=False)]
        if ends:
            del buf[: ends[-1]]
        return out

    def feed_block(self, data: bytes) -> bytes:
        """:meth:`feed`, the complete records returned end to end in one piece (for
        :func:`decode_records`): one copy, however many records.

        Raises:
            ProtocolError: as :meth:`feed`.
        """
        self._buf += data
        ends = self._cut()
        if not ends:
            return b""
        buf = self._buf
        out = bytes(buf[: ends[-1]])
        del buf[: ends[-1]]
        return out

    def _cut(self) -> list[int]:
        """Where each complete record in the buffer ends; every header checked."""
        buf = self._buf
        n = len(buf)
        ends: list[int] = []
        at = 0
        sizes = self._sizes
        while n - at >= 4:
            if not buf[at] & 0x80:
                self.reset()
                raise ProtocolError(f"not a data record header: {bytes(buf[at : at + 4])!r}")
            size = buf[at + 2] | buf[at + 3] << 8
            if size < 4 or size > self.max_size:
                self.reset()
                raise ProtocolError(f"data record header announces {size} bytes")
            if self.qz is not None:
                mask = buf[at + 1]
                want = sizes.get(mask)
                if want is None:
                    want = sizes[mask] = record_size(self.qz, mask)
                if size != want:
                    self.reset()
                    raise ProtocolError(
                        f"data record header announces {size} bytes; its axes need {want}"
                    )
            if n - at < size:
                break
            at += size
            ends.append(at)
        return ends


# --------------------------------------------------------------------------------- time

#: The record's sample counter wraps at this value (16 bits).
SAMPLE_WRAP = 1 << 16


def extend_sample(low: int, near: int) -> int:
    """The controller sample whose low 16 bits are ``low``, nearest to sample ``near``.

    The data record counts samples in 16 bits (it wraps every 64 s at TM 1000) while
    ``TIME`` does not; ``near`` is a ``TIME`` read close to the record (within half a wrap,
    32768 samples, either way).
    """
    low &= SAMPLE_WRAP - 1
    base = near - (near % SAMPLE_WRAP) + low
    if base - near > SAMPLE_WRAP // 2:
        base -= SAMPLE_WRAP
    elif near - base > SAMPLE_WRAP // 2:
        base += SAMPLE_WRAP
    return base


def follow_samples(samples: npt.ArrayLike, near: int, period: int) -> npt.NDArray[np.int64]:
    """Extend the 16-bit sample counters of consecutive records to full samples, at once.

    The first is extended against ``near`` (a ``TIME`` close to it), each next one against
    the one before plus ``period`` (the stream's samples between records): what
    :func:`extend_sample` gives one record at a time, so a record that came late or early
    (by less than half a wrap) still gets its own sample.
    """
    low = np.asarray(samples, dtype=np.int64) & (SAMPLE_WRAP - 1)
    out = np.empty(low.size, dtype=np.int64)
    if low.size == 0:
        return out
    first = extend_sample(int(low[0]), near)
    # extend_sample(low[i], t[i-1] + period), written as steps: t[i-1] + period has the low
    # bits (low[i-1] + period) mod the wrap, and the result is the nearest sample (ties as
    # extend_sample breaks them: at exactly half a wrap the raw difference decides).
    diff = low[1:] - (low[:-1] + period) % SAMPLE_WRAP
    half = SAMPLE_WRAP // 2
    diff[diff > half] -= SAMPLE_WRAP
    diff[diff < -half] += SAMPLE_WRAP
    out[0] = first
    np.cumsum(diff + period, out=out[1:])
    out[1:] += first
    return out


def with_times(records: npt.NDArray[np.void], times: npt.ArrayLike) -> npt.NDArray[np.void]:
    """:func:`with_time` for an array of records: a new array with a ``time`` field last.

    Raises:
        InvalidArgument: the records have a time already, or the lengths differ.
    """
    dtype = records.dtype
    if "time" in (dtype.names or ()):
        raise InvalidArgument("the records have a time already")
    t = np.asarray(times, dtype=np.int64)
    if t.shape != records.shape or records.ndim != 1:
        raise InvalidArgument(f"{t.size} times for {records.size} records")
    out = np.empty(records.size, dtype=_timed(dtype))
    size = dtype.itemsize
    view = out.view(np.uint8).reshape(records.size, size + 8)
    view[:, :size] = np.ascontiguousarray(records).view(np.uint8).reshape(records.size, size)
    out["time"] = t
    return out


@functools.lru_cache(maxsize=64)
def _timed(dtype: np.dtype[Any]) -> np.dtype[Any]:
    names = list(dtype.names or ())
    spec = dtype.fields
    assert spec is not None
    return np.dtype(
        {
            "names": [*names, "time"],
            "formats": [spec[n][0] for n in names] + ["<i8"],
            "offsets": [spec[n][1] for n in names] + [dtype.itemsize],
            "itemsize": dtype.itemsize + 8,
        }
    )


def with_time(record: np.void, time: int) -> np.void:
    """``record`` with one more field, ``time``: the controller sample it was taken at, in
    full (see :func:`extend_sample`); the other fields are unchanged."""
    names = record.dtype.names or ()
    if "time" in names:
        raise InvalidArgument("the record has a time already")
    data = bytes(record.tobytes()) + struct.pack("<q", int(time))
    out: np.void = np.frombuffer(data, dtype=_timed(record.dtype))[0]
    return out


# --------------------------------------------------------------------------------- named fields


def _bits(cls: type[Any], value: int, width: int) -> dict[str, bool]:
    order = [f.name for f in fields(cls) if f.name != "raw"]
    return {name: bool(value >> (width - 1 - i) & 1) for i, name in enumerate(order)}


@dataclass(frozen=True)
class AxisStatus:
    """An axis's status word (DMC-40x0 user manual; the 2x00 and 1700 share it), bit 15 first.

    Attributes:
        raw: the word itself.
        moving: b15, a move is in progress.
        position_mode: b14, the move is a PR or PA move.
        absolute: b13, the move is a PA move.
        finding_edge: b12, FE in progress.
        homing: b11, HM in progress.
        home_first_phase_done: b10.
        home_second_phase_done: b9 (or FI issued).
        coordinated: b8, coordinated motion mode.
        negative: b7, moving in the negative direction.
        contour: b6, contour mode.
        slewing: b5.
        stopping: b4, stopping because of ST or a limit.
        final_decel: b3, in the final deceleration.
        latch_armed: b2.
        home_third_phase: b1 (40x0; "off-on-error armed" on the 2x00 and 1700).
        motor_off: b0.
    """

    moving: bool
    position_mode: bool
    absolute: bool
    finding_edge: bool
    homing: bool
    home_first_phase_done: bool
    home_second_phase_done: bool
    coordinated: bool
    negative: bool
    contour: bool
    slewing: bool
    stopping: bool
    final_decel: bool
    latch_armed: bool
    home_third_phase: bool
    motor_off: bool
    raw: int = 0

    @classmethod
    def from_word(cls, word: int) -> AxisStatus:
        """Decode a status word."""
        return cls(**_bits(cls, int(word), 16), raw=int(word))


@dataclass(frozen=True)
class Switches:
    """An axis's switch byte, bit 7 first (DMC-40x0 user manual).

    The limit bits are 1 while the switch is *inactive*, as ``TS`` reports them;
    :attr:`forward_limit` and :attr:`reverse_limit` say whether a switch is active.

    Attributes:
        raw: the byte itself.
        latch_occurred: b7.
        latch_input: b6, the state of the latch input.
        forward_limit: b3 clear: the forward limit switch is active.
        reverse_limit: b2 clear: the reverse limit switch is active.
        home: b1, the state of the home input.
        stepper: b0, stepper mode.
    """

    latch_occurred: bool
    latch_input: bool
    forward_limit: bool
    reverse_limit: bool
    home: bool
    stepper: bool
    raw: int = 0

    @classmethod
    def from_byte(cls, byte: int) -> Switches:
        """Decode a switch byte."""
        b = int(byte)
        return cls(
            latch_occurred=bool(b & 0x80),
            latch_input=bool(b & 0x40),
            forward_limit=not b & 0x08,
            reverse_limit=not b & 0x04,
            home=bool(b & 0x02),
            stepper=bool(b & 0x01),
            raw=b,
        )


@dataclass(frozen=True)
class PlaneStatus:
    """A coordinate plane's move status word (``S`` or ``T``), bit 15 first (DMC-4123 user
    manual, "Coordinated Motion Status for S or T Plane"; the 2x00 and 1700 share it).

    Attributes:
        raw: the word itself.
        moving: b15, a sequence is in progress (``_BGS``).
        slewing: b5, the path runs at its vector speed.
        stopping: b4, stopping because of ST or a limit.
        final_decel: b3, in the deceleration that ends the sequence (or its stop).
    """

    moving: bool
    slewing: bool
    stopping: bool
    final_decel: bool
    raw: int = 0

    @classmethod
    def from_word(cls, word: int) -> PlaneStatus:
        """Decode a plane status word."""
        w = int(word)
        return cls(
            moving=bool(w & 0x8000),
            slewing=bool(w & 0x0020),
            stopping=bool(w & 0x0010),
            final_decel=bool(w & 0x0008),
            raw=w,
        )


@dataclass(frozen=True)
class PlaneFields:
    """A coordinate plane's block of a record (gclib ``s_plane_*``, ``t_plane_*``).

    Attributes:
        segments: the segment count of the sequence (``_CSS``).
        status: the move status word.
        distance: the distance travelled along the path (``_AVS``), counts.
        buffer: free places in the segment buffer (``_LMS``); ``None`` where the layout has
            none (the DMC-21x3/2x00/18x2 record).
    """

    segments: int
    status: PlaneStatus
    distance: int
    buffer: int | None


def _plane_fields(record: np.void, names: tuple[str, ...], p: str) -> PlaneFields | None:
    if f"{p}_status" not in names:
        return None
    buffer = f"{p}_buffer"
    return PlaneFields(
        segments=int(record[f"{p}_segments"]),
        status=PlaneStatus.from_word(int(record[f"{p}_status"])),
        distance=int(record[f"{p}_distance"]),
        buffer=int(record[buffer]) if buffer in names else None,
    )


@dataclass(frozen=True)
class AxisFields:
    """One axis block of a record, by name, in counts.

    Attributes:
        reference: reference position (``_RP``).
        position: encoder position (``_TP``).
        error: position error (``_TE``).
        velocity: velocity in counts/s (the record holds 64 times ``TV``).
        torque: torque (DAC counts).
        aux_position: auxiliary encoder (``_TD``).
        stop_code: ``_SC``; :attr:`stop_text` is its meaning.
        status: the status word.
        switches: the switch byte.
    """

    reference: int
    position: int
    error: int
    velocity: float
    torque: int
    aux_position: int
    stop_code: int
    status: AxisStatus
    switches: Switches

    @property
    def stop_text(self) -> str:
        """What the stop code means."""
        return stop_text(self.stop_code)


@dataclass(frozen=True)
class RecordFields:
    """One data record, by name.

    Attributes:
        sample: the record's 16-bit sample counter.
        time: the controller sample in full (``None`` when the record carries no ``time``).
        error_code: ``_TC``.
        threads: the program threads running.
        inputs: the input bytes (bank 0 first).
        axes: the axis blocks by letter.
        planes: the coordinate planes' blocks by letter (``"S"``, ``"T"``: those the layout
            has).
    """

    sample: int
    time: int | None
    error_code: int | None
    threads: frozenset[int]
    inputs: tuple[int, ...]
    axes: dict[str, AxisFields]
    planes: dict[str, PlaneFields] = field(default_factory=dict)


def _axis_fields(block: np.void) -> AxisFields:
    names = block.dtype.names or ()
    value = {n: int(block[n]) for n in names if n != "raw"}
    return AxisFields(
        reference=value.get("reference", 0),
        position=value.get("position", 0),
        error=value.get("error", 0),
        velocity=value.get("velocity", 0) / RECORD_VELOCITY_SCALE,
        torque=value.get("torque", 0),
        aux_position=value.get("aux_position", 0),
        stop_code=value.get("stop_code", 0),
        status=AxisStatus.from_word(value.get("status", 0)),
        switches=Switches.from_byte(value.get("switches", 0)),
    )


def decode_fields(record: np.void) -> RecordFields:
    """One decoded record (from :func:`decode_record`) as named values and booleans.

    Raises:
        InvalidArgument: not a data record (no ``sample`` field).
    """
    names = record.dtype.names or ()
    if "sample" not in names:
        if "general" in names:
            raise InvalidArgument("this record's general block has no known layout")
        raise InvalidArgument("not a decoded data record")
    threads = int(record["thread_status"]) if "thread_status" in names else 0
    inputs = tuple(int(v) for v in np.atleast_1d(record["inputs"])) if "inputs" in names else ()
    axes = {n: _axis_fields(record[n]) for n in names if n in AXIS_LETTERS and len(n) == 1}
    planes = {p.upper(): _plane_fields(record, names, p) for p in "st"}
    return RecordFields(
        sample=int(record["sample"]),
        time=int(record["time"]) if "time" in names else None,
        error_code=int(record["error_code"]) if "error_code" in names else None,
        threads=frozenset(t for t in range(8) if threads >> t & 1),
        inputs=inputs,
        axes=axes,
        planes={p: block for p, block in planes.items() if block is not None},
    )
