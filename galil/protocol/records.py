"""Binary data records (``QR`` / ``DR``) as numpy structured dtypes.

The layout is chosen from the ``QZ`` sizes (axes, general, coordinated, per-axis bytes), as
EPICS does, not from fixed offsets: a 52-byte general block is the DMC-40x0/41x3/500x0 (and
18x6) layout, a 24-byte one the DMC-21x3/2x00/1700/18x2 layout (28- or 26-byte axis blocks).
Other general blocks (DMC-30010: 18 bytes) are kept as raw bytes, with the 36-byte axis block
of the 40x0 when the axis size matches. All fields are little-endian. Offsets follow
``galil-protocol.md`` section 4 (gclib ``gclib_record.h``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from galil.errors import InvalidArgument, ProtocolError
from galil.models import ModelSpec

__all__ = [
    "AXIS_LETTERS",
    "RecordSplitter",
    "decode_record",
    "parse_qz",
    "record_dtype",
    "record_size",
    "record_to_dict",
]

AXIS_LETTERS = "ABCDEFGH"

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
) -> np.dtype[Any]:
    """Return the structured dtype of a full data record for ``model`` (or a QZ tuple).

    ``axes`` overrides the axis count (a record holding fewer axis blocks) and ``letters``
    names the axis blocks (default ``"A"``, ``"B"``, ...). The general and coordinated blocks
    are flattened into top-level fields (``sample``, ``error_code``, ``contour_buffer``, ...).

    Raises:
        InvalidArgument: the model has no data record we know of.
    """
    qz = model.qz if isinstance(model, ModelSpec) else model
    if qz is None:
        name = model.name if isinstance(model, ModelSpec) else str(model)
        raise InvalidArgument(f"{name} has no binary data record layout")
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
    elif general == _size(_GENERAL_RIO) and qz[0] == 0:
        g, a = _GENERAL_RIO, _AXIS_4000
        c = _IO_RIO_47300 if coord == _size(_IO_RIO_47300) else _IO_RIO_47100
    else:
        g, c, a = _GENERAL_2103, _COORD_2103, _AXIS_2103[: 9 if per_axis == 26 else 10]
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


def decode_record(data: bytes, model: ModelSpec | tuple[int, int, int, int]) -> np.void:
    """Decode one record into a structured scalar (``rec["A"]["position"]``).

    The axis blocks present are read from the header (byte 1, bit n = axis n), so a ``QR``
    limited to some axes decodes too, with its blocks named by their letters.

    Raises:
        ProtocolError: the size disagrees with the header or the layout.
    """
    if len(data) < 4 or not data[0] & 0x80:
        raise ProtocolError("not a data record: missing header")
    size = data[2] | data[3] << 8
    if size != len(data):
        raise ProtocolError(f"record of {len(data)} bytes but its header says {size}")
    letters = "".join(AXIS_LETTERS[i] for i in range(8) if data[1] >> i & 1)
    dtype = record_dtype(model, axes=len(letters), letters=letters)
    if dtype.itemsize != len(data):
        raise ProtocolError(f"record of {len(data)} bytes, the layout wants {dtype.itemsize}")
    record: np.void = np.frombuffer(data, dtype=dtype)[0]
    return record


def record_to_dict(record: np.void) -> dict[str, Any]:
    """Turn a decoded record into plain Python values (nested dicts per axis)."""
    out: dict[str, Any] = {}
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

    def reset(self) -> None:
        """Forget a partial record (after an error, or to resynchronise)."""
        self._buf.clear()

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes; return every record now complete, oldest first.

        Raises:
            ProtocolError: a header is not a record header, or its size is impossible. The
                partial record is dropped; call :meth:`reset` before feeding on.
        """
        buf = self._buf
        buf += data
        out: list[bytes] = []
        while len(buf) >= 4:
            if not buf[0] & 0x80:
                self.reset()
                raise ProtocolError(f"not a data record header: {bytes(buf[:4])!r}")
            size = buf[2] | buf[3] << 8
            if size < 4 or size > self.max_size:
                self.reset()
                raise ProtocolError(f"data record header announces {size} bytes")
            if self.qz is not None and size != record_size(self.qz, buf[1]):
                want = record_size(self.qz, buf[1])
                self.reset()
                raise ProtocolError(
                    f"data record header announces {size} bytes; its axes need {want}"
                )
            if len(buf) < size:
                break
            out.append(bytes(buf[:size]))
            del buf[:size]
        return out
