"""Interrupts (``EI`` / ``UI``), sans-I/O: the packets they travel in and their status bytes.

A controller sends interrupts to the Ethernet handle ``EI m,n,h`` names, in packets of one to
sixteen status bytes: a header byte (1), the status bytes, then the packet's length in bytes
(header and length included), e.g. ``01 D0 F1 DB E1 06`` (DMC-40x0 command reference, EI).
Status bytes (same page; ``UI`` page for user interrupts):

====================  =================================================
``0xD0`` - ``0xD7``   axis A-H: profiled motion complete (``_BG`` is 0)
``0xD8``              all axes: motion complete
``0xC8``              excess position error
``0xC0``              limit switch
``0xDB``              application program stopped
``0xE1`` - ``0xE8``   digital input 1-8 is low
``0xF0`` - ``0xFF``   user interrupt ``UI 0`` - ``UI 15``
====================  =================================================

:class:`InterruptParser` cuts a byte stream (or UDP datagrams, each on its own) into
:class:`Interrupt` events (one per status byte, in order), dropping a malformed packet alone;
:func:`packet` builds a packet (the simulator sends them).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from galil.errors import InvalidArgument

__all__ = ["HEADER", "Interrupt", "InterruptParser", "decode_status", "packet"]

#: First byte of every interrupt packet.
HEADER = 0x01
_MAX_STATUS = 16
_AXES = "ABCDEFGH"


@dataclass(frozen=True)
class Interrupt:
    """One interrupt.

    Attributes:
        status: the status byte (``0xF3`` for ``UI 3``).
        kind: ``"user"``, ``"axis_done"``, ``"all_done"``, ``"position_error"``,
            ``"limit"``, ``"program_stopped"``, ``"input_low"`` or ``"unknown"``.
        number: the ``UI`` number, the input number, else ``None``.
        axis: the axis letter of ``"axis_done"``, else ``None``.
    """

    status: int
    kind: str
    number: int | None = None
    axis: str | None = None

    def __str__(self) -> str:
        if self.kind == "user":
            return f"UI {self.number}"
        if self.kind == "axis_done":
            return f"axis {self.axis} done"
        if self.kind == "input_low":
            return f"input {self.number} low"
        return f"{self.kind.replace('_', ' ')} (${self.status:02X})"


def decode_status(status: int) -> Interrupt:
    """The :class:`Interrupt` a status byte stands for.

    Raises:
        InvalidArgument: not a byte.
    """
    if isinstance(status, bool) or not isinstance(status, int) or not 0 <= status <= 0xFF:
        raise InvalidArgument(f"an interrupt status is a byte, not {status!r}")
    if status >= 0xF0:
        return Interrupt(status, "user", number=status - 0xF0)
    if 0xD0 <= status <= 0xD7:
        return Interrupt(status, "axis_done", axis=_AXES[status - 0xD0])
    if 0xE1 <= status <= 0xE8:
        return Interrupt(status, "input_low", number=status - 0xE0)
    kind = {0xD8: "all_done", 0xC8: "position_error", 0xC0: "limit", 0xDB: "program_stopped"}
    return Interrupt(status, kind.get(status, "unknown"))


def packet(statuses: Sequence[int]) -> bytes:
    """One interrupt packet holding ``statuses`` (1 to 16 status bytes).

    Raises:
        InvalidArgument: no status, too many, or one that is not a status byte (< 0x80).
    """
    if not 1 <= len(statuses) <= _MAX_STATUS:
        raise InvalidArgument(f"an interrupt packet holds 1 to 16 statuses, not {len(statuses)}")
    for s in statuses:
        if isinstance(s, bool) or not isinstance(s, int) or not 0x80 <= s <= 0xFF:
            raise InvalidArgument(f"not an interrupt status byte: {s!r}")
    return bytes([HEADER, *statuses, len(statuses) + 2])


class InterruptParser:
    """Cut a stream of interrupt packets into :class:`Interrupt` events; sans-I/O.

    Packets may arrive split anywhere or several at once (a TCP handle). A malformed packet
    (a byte that cannot start or continue one, a wrong length) is dropped alone: the parser
    goes on at the next header byte, so the good packets around it are kept, and says what
    it dropped in :meth:`take_dropped`. A header byte (``01``) never is a status or a length
    (those are ``80``-``FF`` and 3-18), so it always starts a packet.

    Args:
        datagram: each :meth:`feed` is one whole UDP datagram: a packet it leaves unfinished
            is dropped (a datagram cut short), not completed by the next datagram's bytes.
    """

    def __init__(self, *, datagram: bool = False) -> None:
        self.datagram = datagram
        self._buf = bytearray()
        self._dropped: list[str] = []

    def reset(self) -> None:
        """Forget a partial packet."""
        self._buf.clear()

    def take_dropped(self) -> list[str]:
        """What was dropped since the last call, one line per malformed packet (and forget
        it)."""
        dropped, self._dropped = self._dropped, []
        return dropped

    def feed(self, data: bytes) -> list[Interrupt]:
        """Add bytes; return the interrupts of every good packet now complete, oldest first.

        A malformed packet is dropped (see :meth:`take_dropped`); those around it are kept.
        """
        buf = self._buf
        buf += data
        out: list[Interrupt] = []
        while buf:
            statuses = self._next_packet(buf)
            if statuses is None:
                break  # the rest of a packet has not arrived
            out += [decode_status(s) for s in statuses]
        if self.datagram and buf:
            self._drop(len(buf), f"interrupt datagram cut short: {bytes(buf).hex(' ')}")
        return out

    def _next_packet(self, buf: bytearray) -> bytes | None:
        """The statuses of the packet at the start of ``buf`` (taken from it), ``b""`` for a
        malformed one (dropped), ``None`` when it has not all arrived."""
        if buf[0] != HEADER:
            return self._drop(_to_header(buf), f"not an interrupt packet: {buf[0]:#04x}")
        end = 1
        while end < len(buf) and buf[end] >= 0x80:
            end += 1
        if end == len(buf):
            if end - 1 > _MAX_STATUS:
                return self._drop(end, "interrupt packet longer than 16 statuses")
            return None
        statuses = bytes(buf[1:end])
        length = buf[end]
        if length == HEADER:  # a packet cut short, and the next one begins
            return self._drop(end, f"interrupt packet cut short: {bytes(buf[:end]).hex(' ')}")
        if not statuses or len(statuses) > _MAX_STATUS or length != len(statuses) + 2:
            why = f"interrupt packet of {len(statuses)} statuses says length {length}"
            return self._drop(end + 1, why)
        del buf[: end + 1]
        return statuses

    def _drop(self, count: int, why: str) -> bytes:
        del self._buf[:count]
        self._dropped.append(why)
        return b""


def _to_header(buf: bytearray) -> int:
    """How many bytes of ``buf`` come before its next header byte (after the first byte)."""
    at = buf.find(HEADER, 1)
    return len(buf) if at < 0 else at
