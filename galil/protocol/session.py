"""The session: matches every reply to the command it answers (sans-I/O).

Modelled on h11: :meth:`Session.send` turns a command into the bytes to write and queues it;
:meth:`Session.receive_data` takes whatever bytes arrived and returns what they complete. The
caller owns the transport, the lock and the clock.

A reply is handed to a command only when its shape fits (``:`` for a plain command, data for a
query, a record for ``QR``, ...). Anything else means the link is out of step: the session
raises :class:`~galil.errors.ProtocolError`, forgets its pending commands, and refuses to send
until :meth:`Session.resync` has been written and its marker has come back.

Resynchronisation: ``resync()`` returns ``\\`` CR (ends a download the controller may still be
in) then ``MG "<token>"`` CR, with a fresh token; the parser discards every byte until
``<token>`` CR LF ``:`` and then the session is in step again.
"""

from __future__ import annotations

import secrets
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

from galil.errors import ProtocolError
from galil.protocol.commands import Command, ReplyKind, parse_line
from galil.protocol.framing import (
    Ack,
    FrameParser,
    Record,
    Rejected,
    Reply,
    Synced,
    Unsolicited,
)

__all__ = ["Completed", "Session"]


class Completed(NamedTuple):
    """The complete reply to one command.

    Immutable and compared by value; a named tuple, built in one step, because one is made
    for every reply (see docs/decisions/0001).

    Attributes:
        command: the command answered (one part of a compound line).
        ok: ``False`` when the controller answered ``?`` (the client then asks ``TC1``).
        text: the data (without its final CR LF), or what was printed before a ``?``.
        record: the binary record of a ``QR``, else ``None``.
    """

    command: Command
    ok: bool
    text: str = ""
    record: bytes | None = None


_new = tuple.__new__
_UNANSWERED_KEPT = 64  # (only whether a burn is among them matters: a few are enough)
_ACK_KIND, _ANY_KIND, _DATA_KIND = ReplyKind.ACK, ReplyKind.ANY, ReplyKind.DATA


class Session:
    """Pending-command queue and reply matcher for one command link.

    Args:
        echo: the controller echoes what it receives (``EO1`` on serial); the echo is removed.
        unanswered: commands an earlier session gave up (see :attr:`unanswered`).
    """

    def __init__(self, echo: bool = False, unanswered: Sequence[Command] = ()) -> None:
        self.echo = echo
        self._parser = FrameParser()
        self._pending: deque[Command] = deque()
        self._dl_first: bool | None = None  # first terminator of the DL at the head
        self.out_of_step = False
        self._unanswered = list(unanswered)  # given up since the link was last in step
        self._token = ""
        self._resyncs = 0
        # Fast path for the usual one-command exchange: while the parser is idle, a lone
        # plain command is not registered with it (``_lazy``); a reply of the obvious shape
        # completes it without parsing, anything else registers it first and parses.
        self._idle = True  # the parser is idle (nothing expected, nothing half-parsed)
        self._lazy = False  # the one pending command is not registered with the parser

    @property
    def pending(self) -> int:
        """Commands sent whose replies are not complete yet."""
        return len(self._pending)

    @property
    def receiving(self) -> int:
        """Bytes of the reply that has begun to arrive and has not ended yet (0: none)."""
        return self._parser.receiving if self._pending else 0

    @property
    def resyncing(self) -> bool:
        """Whether a resync marker was sent and has not come back yet."""
        return self._parser.hunting

    def quick_wire(self, cmd: Command) -> bytes | None:
        """The bytes for ``cmd`` when it may be exchanged without queuing, else ``None``.

        For the usual exchange (one plain command on a quiet link in step): write the bytes,
        then give what came back to :meth:`quick_reply`. If that returns ``None``, call
        :meth:`send` (its bytes are already on the wire: do not write them again) and
        :meth:`receive_data` with the same data, as for any command.
        """
        if self._idle and not self._pending and not self.echo and type(cmd) is Command:
            text, expect, payload, parts = cmd
            kind = expect.kind
            if (
                not parts
                and not payload
                and (kind is _ACK_KIND or kind is _ANY_KIND or kind is _DATA_KIND)
            ):
                return text.encode("latin-1") + b"\r"
        return None

    @staticmethod
    def quick_reply(cmd: Command, data: bytes) -> str | None:
        """The reply text when ``data`` is exactly ``cmd``'s whole reply, else ``None``.

        Only the two shapes :meth:`receive_data` also completes without parsing: a lone ``:``
        for a command that may answer so, or one ASCII data line then ``:`` for a query.
        """
        kind = cmd.expect.kind
        if data == b":":
            return "" if kind is _ACK_KIND or kind is _ANY_KIND else None
        if (
            data[-3:] == b"\r\n:"
            and kind is not _ACK_KIND
            and data.count(b"\n") == 1
            and data[0] not in b":?"
            and data.isascii()
            and (cmd.expect.size is None or cmd.expect.size >= 1)
        ):
            return data[:-3].decode("ascii")
        return None

    def send(self, cmd: Command | str) -> bytes:
        """Queue ``cmd`` and return the bytes to write (CR terminated, payload appended).

        Raises:
            ProtocolError: the session is out of step (call :meth:`resync` first).
            InvalidArgument: a raw string that cannot be sent (see ``parse_line``).
        """
        # The usual exchange: one plain command on a quiet link (_idle implies in step).
        if type(cmd) is Command:
            quick = self.quick_wire(cmd)
            if quick is not None:
                self._pending.append(cmd)
                self._lazy = True
                return quick
        if self.out_of_step:
            raise ProtocolError("the link is out of step; write session.resync() first")
        if type(cmd) is str:
            cmd = parse_line(cmd)
        elif type(cmd) is not Command and not isinstance(cmd, Command):
            raise TypeError(f"send() takes a Command or a str, not {type(cmd).__name__}")
        text, expect, payload, parts = cmd
        wire = text.encode("latin-1") + b"\r"
        if payload:
            wire += payload
        if not parts and not self.echo:
            pending = self._pending
            if self._idle and not pending:
                kind = expect.kind
                if kind is _ACK_KIND or kind is _ANY_KIND or kind is _DATA_KIND:
                    pending.append(cmd)
                    self._lazy = True
                    return wire
            if self._lazy:
                self._register()
            self._idle = False
            pending.append(cmd)
            self._parser.expect(expect)
            return wire
        if self._lazy:
            self._register()
        self._idle = False
        parser = self._parser
        parts = parts or (cmd,)
        if self.echo:
            end = parser.echo_total
            parser.add_echo(wire)
            for i, part in enumerate(parts):
                end += len(part.text) + 1
                if i == len(parts) - 1:
                    end += len(payload)
                self._pending.append(part)
                parser.expect(part.expect, end)
        else:
            for part in parts:
                self._pending.append(part)
                parser.expect(part.expect)
        return wire

    def _register(self) -> None:
        # The lazy command meets a reply the fast path does not take: give it to the parser.
        self._lazy = False
        self._idle = False
        self._parser.expect(self._pending[0].expect)

    def receive_data(self, data: bytes) -> list[Completed | Unsolicited]:
        """Feed bytes from the link; return completed replies and unsolicited lines, in order.

        Raises:
            ProtocolError: a reply that fits no pending command; the session is now out of step.
        """
        pending = self._pending
        if self._lazy:
            cmd = pending[0]
            text = self.quick_reply(cmd, data)
            if text is not None:
                pending.popleft()
                self._lazy = False
                return [_new(Completed, (cmd, True, text, None))]
            self._register()
        parser = self._parser
        if (
            data == b":"
            and pending
            and not self.echo
            and parser._line_start
            and not parser._buf
            and parser._mode == 0
            and not parser._special
            and not parser.unsolicited_only
        ):
            # Hot path of a pipelined batch: a lone ':' for a plain command.
            cmd = pending[0]
            kind = cmd.expect.kind
            if kind is _ACK_KIND or kind is _ANY_KIND:
                pending.popleft()
                parser._pop()
                if not pending:
                    self._idle = parser.idle
                return [_new(Completed, (cmd, True, "", None))]
        self._idle = False
        try:
            events = parser.feed(data)
        except ProtocolError as exc:
            self._lose_step()
            raise ProtocolError(f"{exc} (pending: {self._describe()})") from exc
        out: list[Completed | Unsolicited] = []
        for event in events:
            if type(event) is Unsolicited:
                out.append(event)
            elif type(event) is Synced:
                self.out_of_step = False
                self._unanswered.clear()
            else:
                done = self._match(event)  # type: ignore[arg-type]
                if done is not None:
                    out.append(done)
        if not pending:
            self._idle = parser.idle
        return out

    def _match(self, event: Ack | Rejected | Reply | Record) -> Completed | None:
        if not self._pending:
            self._lose_step()
            raise ProtocolError(f"reply {event!r} arrived but no command is pending")
        cmd = self._pending[0]
        kind = cmd.expect.kind
        if kind is ReplyKind.DOUBLE_ACK:
            ok = type(event) is Ack
            if type(event) not in (Ack, Rejected):
                self._doubt(cmd, event)
            if self._dl_first is None:
                self._dl_first = ok
                return None
            ok = self._dl_first and ok
            self._dl_first = None
            self._pending.popleft()
            return _new(Completed, (cmd, ok, "", None))
        if type(event) is Rejected:
            self._pending.popleft()
            return _new(Completed, (cmd, False, event.text, None))
        if type(event) is Ack:
            if kind is ReplyKind.ACK or kind is ReplyKind.ANY:
                self._pending.popleft()
                return _new(Completed, (cmd, True, "", None))
        elif type(event) is Reply:
            if kind is ReplyKind.DATA:
                limit = cmd.expect.size
                if limit is not None and event.text.count("\n") >= limit:
                    self._doubt(cmd, event)
                self._pending.popleft()
                return _new(Completed, (cmd, True, event.text, None))
            if kind is ReplyKind.ANY or kind is ReplyKind.CTRL_Z:
                self._pending.popleft()
                return _new(Completed, (cmd, True, event.text, None))
        elif type(event) is Record and kind is ReplyKind.RECORD:
            self._pending.popleft()
            return _new(Completed, (cmd, True, "", event.data))
        self._doubt(cmd, event)
        return None  # pragma: no cover - _doubt raises

    def _doubt(self, cmd: Command, event: object) -> None:
        self._lose_step()
        raise ProtocolError(
            f"reply {event!r} does not fit command {cmd.text!r} "
            f"(expected {cmd.expect.kind.value}); the link is out of step"
        )

    def _describe(self) -> str:
        return ", ".join(repr(c.text) for c in list(self._pending)[:4]) or "none"

    @property
    def unanswered(self) -> tuple[Command, ...]:
        """The commands whose replies were given up (a timeout, a reply that did not fit)
        since the link was last in step, oldest first: what the controller may still be
        busy with while the link resynchronises (a burn holds its answer for seconds)."""
        return tuple(self._unanswered)

    def _lose_step(self) -> None:
        if self._pending:
            self._unanswered.extend(self._pending)
            del self._unanswered[:-_UNANSWERED_KEPT]
        self.out_of_step = True
        self._lazy = False
        self._idle = False
        self._pending.clear()
        self._dl_first = None
        self._parser.reset()

    def abandon(self) -> list[Command]:
        """Give up on every pending command (after a timeout); the session is out of step.

        Returns:
            The abandoned commands, oldest first.
        """
        lost = list(self._pending)
        self._lose_step()
        return lost

    def resync(self, token: str | None = None) -> bytes:
        """Return the bytes that bring the link back in step; write them, then keep feeding.

        Pending commands are abandoned. ``out_of_step`` stays ``True`` until the controller's
        answer to the marker has been read by :meth:`receive_data`.
        """
        self._resyncs += 1
        if token is None:
            token = f"SYNC{self._resyncs}X{secrets.token_hex(4).upper()}"
        elif not token.isalnum() or not token.isascii() or len(token) > 30:
            raise ProtocolError(f"resync token must be short and alphanumeric: {token!r}")
        self._token = token
        self._lose_step()
        self._parser.hunt(token.encode("ascii") + b"\r\n:")
        return b'\\\rMG "' + token.encode("ascii") + b'"\r'

    @staticmethod
    def marker_reply(token: str) -> bytes:
        """The controller's answer to the resync marker (what a simulator must print)."""
        return token.encode("ascii") + b"\r\n:"
