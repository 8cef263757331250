"""Incremental reply parser: bytes in, events out (sans-I/O).

What the controller sends back, and how we cut it:

* ``:`` at the start of a line ends a reply: :class:`Ack` when no data came first, else
  :class:`Reply` with the data (its final CR LF removed). ``?`` at the start of a line is a
  rejection (:class:`Rejected`); Galil forbids ``?`` inside MG strings (TC 54) and our builders
  refuse it, so a ``?`` there cannot be data.
* Bytes with bit 7 set are unsolicited output (``CW1``); they are split out of the stream
  wherever they fall, even inside a reply, and become :class:`Unsolicited` lines at each LF.
* A binary data record (``QR``) is raw bytes: the parser is told to expect it, takes the size
  from the 4-byte header (first byte 0x80-0x87) and then wants one ``:``.
* ``UL``/``QU`` answer text, ``^Z`` (0x1A), then ``:``; the text may hold anything but ^Z.
* With echo on (``EO1``) the caller declares the bytes it sent (:meth:`FrameParser.add_echo`)
  and the parser removes their echo (an echoed CR may be followed by LF).

The parser keeps a queue of what each pending reply looks like (:meth:`FrameParser.expect`);
the :class:`~galil.protocol.session.Session` drives it. Any byte sequence gives events or a
:class:`~galil.errors.ProtocolError`, never another exception.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from galil.errors import ProtocolError
from galil.protocol.commands import Expect, ReplyKind

__all__ = [
    "ACK",
    "Ack",
    "Event",
    "FrameParser",
    "Record",
    "Rejected",
    "Reply",
    "Synced",
    "Unsolicited",
]


@dataclass(frozen=True, slots=True)
class Ack:
    """``:`` alone: the command was accepted."""


@dataclass(frozen=True, slots=True)
class Rejected:
    """``?``: the command was rejected; ``text`` holds any data printed before it."""

    text: str = ""


@dataclass(frozen=True, slots=True)
class Reply:
    """Data lines then ``:``; ``text`` is the data without its final CR LF."""

    text: str


@dataclass(frozen=True, slots=True)
class Unsolicited:
    """One line the controller sent on its own (program ``MG``, errors), without CR LF."""

    line: str


@dataclass(frozen=True, slots=True)
class Record:
    """A binary data record (``QR``), header included; its ``:`` has arrived."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Synced:
    """The resynchronisation marker was found; what follows is in step again."""

    marker: bytes


Event = Ack | Rejected | Reply | Unsolicited | Record | Synced

ACK = Ack()
_COLON, _QMARK, _CR, _LF, _CTRL_Z = 0x3A, 0x3F, 0x0D, 0x0A, 0x1A

# parser modes
_NORMAL, _RECORD, _AFTER_RECORD, _UPLOAD, _AFTER_UPLOAD, _HUNT = range(6)


class FrameParser:
    """Turns the controller's bytes into events.

    Args:
        unsolicited_only: for a secondary handle that only carries unsolicited output: every
            line (high bit set or not) becomes :class:`Unsolicited`.
        max_reply: largest reply (bytes) before the parser gives up (a runaway peer).
    """

    def __init__(self, *, unsolicited_only: bool = False, max_reply: int = 4 << 20) -> None:
        self.unsolicited_only = unsolicited_only
        self.max_reply = max_reply
        self._expects: deque[Expect] = deque()
        self.reset()

    # ------------------------------------------------------------------ control

    def reset(self) -> None:
        """Forget everything: partial replies, expectations, echo, hunting."""
        self._expects.clear()
        self._mode = _NORMAL
        self._buf = bytearray()
        self._line_start = True
        self._unsol = bytearray()
        self._acks_seen = 0  # terminators already seen for a DOUBLE_ACK head
        self._special = False  # head expects a record or an upload
        self._rec_size = 0
        self._echo = bytearray()
        self._echo_pos = 0  # bytes of _echo consumed
        self._echo_base = 0  # absolute count of echo bytes dropped from _echo
        self._echo_ends: deque[int] = deque()
        self._echo_lf = False
        self._marker = b""

    def expect(self, expect: Expect, echo_end: int | None = None) -> None:
        """Queue the shape of the next reply (in send order).

        ``echo_end`` is the absolute echo offset that must be consumed before this reply may
        end (echo mode only).
        """
        expects = self._expects
        expects.append(expect)
        if echo_end is not None:
            self._echo_ends.append(echo_end)
        if len(expects) == 1:
            kind = expect.kind
            self._special = kind is ReplyKind.RECORD or kind is ReplyKind.CTRL_Z

    @property
    def pending(self) -> int:
        """Replies still expected."""
        return len(self._expects)

    @property
    def echo_total(self) -> int:
        """Echo bytes declared so far (absolute offset of the next one)."""
        return self._echo_base + len(self._echo)

    def add_echo(self, sent: bytes) -> None:
        """Declare bytes that were written and will come back as echo."""
        if self._echo_pos and self._echo_pos == len(self._echo):
            self._echo_base += self._echo_pos
            self._echo.clear()
            self._echo_pos = 0
        self._echo += sent

    def hunt(self, marker: bytes) -> None:
        """Discard everything until ``marker`` (then emit :class:`Synced`)."""
        if not marker:
            raise ValueError("empty marker")
        self.reset()
        self._mode = _HUNT
        self._marker = marker

    @property
    def idle(self) -> bool:
        """Nothing expected and nothing half-parsed: the next byte starts a fresh reply."""
        return (
            not self._expects
            and self._mode == _NORMAL
            and self._line_start
            and not self._buf
            and self._echo_pos == len(self._echo)
            and not self._echo_lf
            and not self.unsolicited_only
        )

    @property
    def receiving(self) -> int:
        """Bytes of a reply that has begun to arrive and has not ended yet (0: none)."""
        return 0 if self._mode == _HUNT else len(self._buf)

    @property
    def hunting(self) -> bool:
        """Whether the parser is still looking for the resync marker."""
        return self._mode == _HUNT

    # ------------------------------------------------------------------ feeding

    def feed(self, data: bytes) -> list[Event]:
        """Parse the next bytes; return the events they complete.

        Raises:
            ProtocolError: bytes that fit no reply; the parser must be reset or hunt.
        """
        # Fast path: a lone ':' for a plain command, the commonest reply there is.
        if (
            data == b":"
            and self._line_start
            and not self._buf
            and self._mode == _NORMAL
            and not self._special
            and self._echo_pos == len(self._echo)
            and not self._echo_lf
            and not self.unsolicited_only
            and self._expects
            and self._expects[0].kind is not ReplyKind.DOUBLE_ACK
        ):
            self._check_echo()
            self._pop()
            return [ACK]
        events: list[Event] = []
        if self.unsolicited_only:
            self._feed_unsolicited(data, events)
        elif data.isascii() and self._echo_pos == len(self._echo) and not self._echo_lf:
            self._feed_ascii(data, events)
        else:
            self._feed_bytes(data, events)
        return events

    def _feed_unsolicited(self, data: bytes, events: list[Event]) -> None:
        for b in data:
            self._unsolicited_byte(b & 0x7F, events)

    def _unsolicited_byte(self, c: int, events: list[Event]) -> None:
        if c == _LF:
            line = self._unsol.decode("ascii").rstrip("\r")
            self._unsol.clear()
            if line or not self.unsolicited_only:
                events.append(Unsolicited(line))
        else:
            if len(self._unsol) >= self.max_reply:
                self._unsol.clear()
                raise ProtocolError("unsolicited line longer than the parser's limit")
            self._unsol.append(c)

    def _feed_ascii(self, data: bytes, events: list[Event]) -> None:
        """No high-bit bytes and no echo outstanding: work on whole runs, not bytes."""
        i, n = 0, len(data)
        while i < n:
            if self._mode != _NORMAL or self._special:
                self._feed_bytes(data[i:], events)
                return
            if self._line_start:
                c = data[i]
                if c == _COLON:
                    self._terminate(events)
                    i += 1
                    continue
                if c == _QMARK:
                    self._reject(events)
                    i += 1
                    continue
            j = data.find(b"\n", i)
            if j < 0:
                self._append(data[i:])
                self._line_start = False
                return
            self._append(data[i : j + 1])
            self._line_start = True
            i = j + 1

    def _append(self, chunk: bytes) -> None:
        self._buf += chunk
        if len(self._buf) > self.max_reply:
            raise ProtocolError(f"reply longer than {self.max_reply} bytes without a terminator")

    def _feed_bytes(self, data: bytes, events: list[Event]) -> None:
        i, n = 0, len(data)
        while i < n:
            mode = self._mode
            if mode == _RECORD:
                i = self._record_bytes(data, i, events)
                continue
            if mode == _HUNT:
                i = self._hunt_bytes(data, i, events)
                continue
            b = data[i]
            i += 1
            if self._echo_pos < len(self._echo) or self._echo_lf:
                if self._echo_pos < len(self._echo) and b == self._echo[self._echo_pos]:
                    self._echo_pos += 1
                    self._echo_lf = b == _CR
                    continue
                if self._echo_lf and b == _LF:
                    self._echo_lf = False
                    continue
                self._echo_lf = False
            if mode == _NORMAL:
                self._normal_byte(b, events)
            elif mode == _UPLOAD:
                if b >= 0x80:
                    self._unsolicited_byte(b & 0x7F, events)
                elif b == _CTRL_Z:
                    self._mode = _AFTER_UPLOAD
                else:
                    self._buf.append(b)
                    if len(self._buf) > self.max_reply:
                        raise ProtocolError(f"upload longer than {self.max_reply} bytes")
            elif mode == _AFTER_UPLOAD:
                if b >= 0x80:
                    self._unsolicited_byte(b & 0x7F, events)
                elif b == _COLON:
                    text = self._buf.decode("ascii").rstrip("\r\n")
                    self._buf.clear()
                    self._mode = _NORMAL
                    self._line_start = True
                    self._check_echo()
                    self._pop()
                    events.append(Reply(text))
                elif b not in (_CR, _LF):
                    raise ProtocolError(f"expected ':' after ^Z, got {bytes([b])!r}")
            else:  # _AFTER_RECORD
                if b >= 0x88:
                    self._unsolicited_byte(b & 0x7F, events)
                elif b == _COLON:
                    record = bytes(self._buf)
                    self._buf.clear()
                    self._mode = _NORMAL
                    self._line_start = True
                    self._check_echo()
                    self._pop()
                    events.append(Record(record))
                else:
                    raise ProtocolError(f"expected ':' after the data record, got {bytes([b])!r}")

    def _normal_byte(self, b: int, events: list[Event]) -> None:
        at_start = self._line_start and not self._buf
        if self._special and at_start:
            kind = self._expects[0].kind
            if b == _QMARK:
                self._reject(events)
                return
            if kind is ReplyKind.RECORD:
                if 0x80 <= b <= 0x87:
                    self._mode = _RECORD
                    self._rec_size = 0
                    self._buf.append(b)
                    return
                if b >= 0x80:
                    self._unsolicited_byte(b & 0x7F, events)
                    return
                raise ProtocolError(f"expected a data record, got {bytes([b])!r}")
            if b >= 0x80:  # CTRL_Z head
                self._unsolicited_byte(b & 0x7F, events)
                return
            self._mode = _UPLOAD
            if b == _CTRL_Z:
                self._mode = _AFTER_UPLOAD
            else:
                self._buf.append(b)
            return
        if b >= 0x80:
            self._unsolicited_byte(b & 0x7F, events)
            return
        if self._line_start:
            if b == _COLON:
                self._terminate(events)
                return
            if b == _QMARK:
                self._reject(events)
                return
        self._buf.append(b)
        if len(self._buf) > self.max_reply:
            raise ProtocolError(f"reply longer than {self.max_reply} bytes without a terminator")
        self._line_start = b == _LF

    def _record_bytes(self, data: bytes, i: int, events: list[Event]) -> int:
        buf = self._buf
        if self._rec_size == 0:
            take = min(4 - len(buf), len(data) - i)
            buf += data[i : i + take]
            i += take
            if len(buf) < 4:
                return i
            size = buf[2] | (buf[3] << 8)
            wanted = self._expects[0].size if self._expects else None
            if size < 4 or (wanted is not None and size != wanted):
                raise ProtocolError(
                    f"data record header says {size} bytes, expected {wanted or 'at least 4'}"
                )
            self._rec_size = size
        take = min(self._rec_size - len(buf), len(data) - i)
        buf += data[i : i + take]
        i += take
        if len(buf) == self._rec_size:
            self._mode = _AFTER_RECORD
        return i

    def _hunt_bytes(self, data: bytes, i: int, events: list[Event]) -> int:
        # High-bit bytes are unsolicited or record data: neither can be part of the marker.
        # The marker is searched in the low bytes, but what follows it is taken from ``data``
        # itself, so unsolicited (high-bit) output after the marker survives.
        marker = self._marker
        buf = self._buf
        n = len(data)
        while i < n:
            b = data[i]
            i += 1
            if b >= 0x80:
                continue
            buf.append(b)
            if b == marker[-1] and buf.endswith(marker):
                self.reset()
                events.append(Synced(marker))
                # What followed the marker is ordinary traffic again (nothing is pending).
                self._feed_bytes(data[i:], events)
                return n
        keep = len(marker) - 1
        if len(buf) > keep:
            del buf[: len(buf) - keep]
        return n

    # ------------------------------------------------------------------ completion

    def _pop(self) -> None:
        expects = self._expects
        if expects:
            expects.popleft()
            if self._echo_ends:
                self._echo_ends.popleft()
            self._acks_seen = 0
            if expects:
                kind = expects[0].kind
                self._special = kind is ReplyKind.RECORD or kind is ReplyKind.CTRL_Z
            else:
                self._special = False

    def _check_echo(self) -> None:
        if self._echo_ends and self._echo_base + self._echo_pos < self._echo_ends[0]:
            raise ProtocolError(
                "a reply ended before the echo of its command: echo is not on, "
                "or the link is out of step"
            )

    def _terminate(self, events: list[Event]) -> None:
        self._check_echo()
        if self._buf:
            text = self._buf.decode("ascii")
            if text.endswith("\r\n"):
                text = text[:-2]
            elif text.endswith("\n"):
                text = text[:-1]
            self._buf.clear()
            events.append(Reply(text))
        else:
            events.append(ACK)
        self._line_start = True
        self._finish_terminator()

    def _reject(self, events: list[Event]) -> None:
        self._check_echo()
        text = self._buf.decode("ascii").rstrip("\r\n")
        self._buf.clear()
        self._line_start = True
        events.append(Rejected(text))
        self._finish_terminator()

    def _finish_terminator(self) -> None:
        if self._expects and self._expects[0].kind is ReplyKind.DOUBLE_ACK:
            self._acks_seen += 1
            if self._acks_seen < 2:
                return
        self._pop()
