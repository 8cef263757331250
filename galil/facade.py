"""What a user holds of the link: commands, queries, time, messages and data records.

:class:`LinkFacade` is the part of :class:`~galil.controller.Controller` that only passes
calls on to the link (:mod:`galil.link`), the message room and the record room; it holds no
logic. The controller adds the life cycle, the axes and motion on top.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Iterable, Sequence
from typing import Literal, overload

import numpy as np

from galil.arrays import _la_reply_bytes, _lv_reply_bytes, _qu_reply_bytes
from galil.errors import GalilConnectionError, InvalidArgument
from galil.link import Link, WireLog, check_flag, check_items, check_seconds, refuse_link_settings
from galil.messages import MessageCallback, MessageQueue, Messages
from galil.models import ModelSpec
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.protocol.session import Completed
from galil.records import Records, RecordStream
from galil.routines import Routines, ls_reply_bytes, ul_reply_bytes
from galil.transport import Transport
from galil.tuning import follow_tm, refuse_tm

__all__ = ["LONGEST_SLEEP", "LinkFacade", "check_sleep"]

#: The longest :meth:`LinkFacade.sleep` in seconds (a simulator steps every sample of it:
#: about a billion at 1024 Hz).
LONGEST_SLEEP = 1e6


def check_sleep(seconds: object) -> float:
    """``seconds`` as a float from 0 to :data:`LONGEST_SLEEP` (:func:`~galil.link.check_seconds`,
    as every wait's timeout, and not too long).

    Raises:
        InvalidArgument: not a number (a bool neither, nor ``None``), negative, NaN, infinity,
            or too long.
    """
    value = check_seconds(seconds, "seconds")
    if value > LONGEST_SLEEP:
        raise InvalidArgument(f"seconds must be at most {LONGEST_SLEEP:g}, not {seconds!r}")
    return value


#: The bulk transfers sent as raw text (``command("UL")``): timed by their size.
_UPLOADS = frozenset({"UL", "QU", "LV", "LA", "LS"})
#: A bulk transfer's command (decision 0064): ``DL``, ``UL``, ``LV``, ``LA``; ``LS`` alone or
#: with its label or line range (``LS #A,20``: bounded by the whole program all the same,
#: decision 0090); ``QU``/``QD`` and an array name, and for ``QU`` its range
#: (``QU a[],0,99,1``) when given.
_TRANSFER = re.compile(
    r"(DL|UL|LV|LA)$|(LS)(?:$|[\s#,\d])|(QD) ?[A-Za-z]|QU ?[A-Za-z]\w*\[\](?:,(\d+),(\d+))?"
)


def _transfer_bytes(link: Link, command: Command) -> int | None:
    """The most bytes the reply of ``command`` holds when it is a bulk transfer (``None``
    when it is not): a colon for ``DL`` and ``QD`` (their size is their payload); the whole
    program memory for ``UL`` (numbered, for ``LS``); every variable for ``LV``, every array
    for ``LA``; the elements for ``QU`` (all the model's array space when its range is not
    given)."""
    m = _TRANSFER.match(command.text) if isinstance(command, Command) else None
    if m is None or command.parts:
        return None
    head = m.group(1) or m.group(2) or m.group(3) or "QU"
    if head == "UL":
        return ul_reply_bytes(link.model)
    if head == "LS":
        return ls_reply_bytes(link.model)
    if head == "LV":
        return _lv_reply_bytes(link)
    if head == "LA":
        return _la_reply_bytes(link)
    if head == "QU":
        first, last = m.group(4), m.group(5)
        known = first is not None and last is not None and int(last) >= int(first)
        count = int(last) - int(first) + 1 if known else link.model.array_elements
        return _qu_reply_bytes(count)
    return 0


def _prepared(command: Command) -> Command:
    """``command`` unless it would change the link's own settings (decision 0031)."""
    if isinstance(command, Command):
        refuse_link_settings(command)
    return command  # (anything else: the link says what it takes)


class LinkFacade:
    """Commands, queries, time, messages and records of one controller (see ``Controller``).

    Attributes:
        link: the command link.
        messages_room: unsolicited output.
        records_room: data records.
        routines: the library's routines in program memory (a raw ``DL`` replaces them).
    """

    link: Link
    messages_room: Messages
    records_room: Records
    routines: Routines

    @property
    def model(self) -> ModelSpec:
        """The controller's :class:`~galil.models.ModelSpec`."""
        return self.link.model

    @property
    def transport(self) -> Transport:
        """The open :class:`~galil.transport.Transport`."""
        t = self.link.transport
        if t is None:  # pragma: no cover - a Controller always has one
            raise GalilConnectionError("no transport")
        return t

    @property
    def timeout(self) -> float:
        """Default seconds to wait for each reply."""
        return self.link.timeout

    @timeout.setter
    def timeout(self, seconds: float) -> None:
        # (None is no default here: it would silently keep the old value)
        self.link.timeout = check_seconds(seconds, "timeout", positive=True)

    @property
    def wire_log(self) -> WireLog:
        """Hooks on the raw bytes of the command link."""
        return self.link.wire_log

    @property
    def bytes_sent(self) -> int:
        """Bytes written to the command link."""
        return self.link.bytes_sent

    @property
    def bytes_received(self) -> int:
        """Bytes read from the command link."""
        return self.link.bytes_received

    @property
    def recent(self) -> tuple[str, ...]:
        """The last exchanges on the link, oldest first (what errors carry)."""
        return self.link.recent

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample."""
        return self.link.sample_period

    def command(
        self, text: str, *, timeout: float | None = None, allow_compound: bool = False
    ) -> str:
        """Send one raw command line and return its reply text (see :meth:`Link.command`).

        Commands that would change the link's own settings or reset the controller under it
        are refused, unsent: ``RS`` (use :meth:`reset`), ``^R^S``, ``CW``/``EO``/``CF`` with a
        setting (``CW ?``, ``MG _CW`` pass), ``IHS=>``/``IHT=>``, ``BN`` (use
        :meth:`~galil.Controller.save`; docs/raw.md).

        Raises:
            InvalidArgument: the text cannot be sent (CR/LF, non-ASCII, a stray ``;``), or it
                is one of the commands above (the message says what to use instead).
            CommandError: the controller answered ``?`` (code and text from ``TC1``).
            ProtocolError: the link went out of step during the exchange (it may have run).
            GalilTimeoutError: no complete reply within the timeout.
            GalilConnectionError: the link is closed or dead.
        """
        head = text.lstrip()[:2].upper() if type(text) is str else ""
        if type(text) is str:
            refuse_tm(self.link.model, [text])
        if timeout is None and head in _UPLOADS:
            command = cmds.parse_line(text)
            if not command.parts:  # (a compound line: the link says what it takes)
                return self.send(command)  # a bulk transfer: timed by its size
        reply = self.link.command(text, timeout=timeout, allow_compound=allow_compound)
        self._follow_tm([text])  # (a TM anywhere in the line, as refuse_tm checked it)
        return reply

    def _follow_tm(self, parts: Sequence[str | Command]) -> None:
        """A TM the controller accepted changes the sample period predictions use."""
        for part in parts:
            period = follow_tm(self.link.model, part if isinstance(part, str) else part.text)
            if period is not None:
                self.link.sample_period = period

    def command_line(
        self, parts: Sequence[str | Command], *, timeout: float | None = None
    ) -> list[str]:
        """Send several commands as compound line(s) (``PRA=1;BGA``); one reply per part."""
        if isinstance(parts, (list, tuple)):  # (anything else: the link says what it takes)
            refuse_tm(self.link.model, [p.text if isinstance(p, Command) else p for p in parts])
        replies = self.link.command_line(parts, timeout=timeout)
        self._follow_tm(parts)
        return replies

    def send(self, command: Command, *, timeout: float | None = None) -> str:
        """Send a prepared :class:`~galil.protocol.commands.Command`; return its reply text.

        Raises:
            InvalidArgument: not a Command, or one that would change the link's own
                settings (``RS``, ``CW 1`` ...: see :meth:`command`); nothing is sent.
        """
        return self.exchange(command, timeout=timeout).text

    def exchange(self, command: Command, *, timeout: float | None = None) -> Completed:
        """Send a prepared command and return the whole reply (``record`` for QR).

        A bulk transfer (``DL``, ``UL``, ``QD``, ``QU``, ``LV``) sent without a ``timeout``
        gets the timeout of its size, as the rooms' own transfers do
        (:meth:`~galil.link.Link.transfer`, decisions 0064 and 0067).
        """
        prepared = _prepared(command)
        if isinstance(prepared, Command):
            refuse_tm(self.link.model, [prepared.text])
        size = None if timeout is not None else _transfer_bytes(self.link, prepared)
        if size is None:
            send = functools.partial(self.link.exchange, prepared, timeout=timeout)
        else:
            send = functools.partial(self.link.transfer, prepared, size)
        # A DL replaces the library's routines too: refused while a thread runs, and they
        # are forgotten once it is sent.
        raw_dl = isinstance(prepared, Command) and prepared.text == "DL"
        done = self.routines.download_raw(send) if raw_dl else send()
        self._follow_tm([command])
        return done

    def send_many(self, commands: Iterable[Command], *, timeout: float | None = None) -> list[str]:
        """Send prepared commands back to back (pipelined) and return every reply text."""
        batch = check_items(commands, "commands")
        for c in batch:
            _prepared(c)
        refuse_tm(self.link.model, [c.text for c in batch if isinstance(c, Command)])
        replies = self.link.send_many(batch, timeout=timeout)
        self._follow_tm(batch)
        return replies

    def query_number(self, text: str, *, timeout: float | None = None) -> float:
        """Send a query (``"MG _TPA"``, ``"TPA"``) and return its one number (as the controller
        prints it: in your ``VF``/``PF``; :meth:`query_operands` does not depend on them)."""
        return self.link.query_number(text, timeout=timeout)

    def query_numbers(self, text: str, *, timeout: float | None = None) -> list[float]:
        """Send a query and return every number in its reply (``"TP"`` -> ``[0.0, 5.0, ...]``)."""
        return self.link.query_numbers(text, timeout=timeout)

    def query_operands(self, names: Sequence[str], *, timeout: float | None = None) -> list[float]:
        """Read operands or variables (``["_TPA", "_SCA", "speed"]``) in as few lines as fit:
        no ``VF`` or ``LZ`` changes what is read (plain ``MG``, asked again with each item in
        ``{Z10.4}`` when the reply may be another format: decision 0032)."""
        return self.link.query_operands(names, timeout=timeout)

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass for the controller (simulated time on a manual-clock simulator).

        Scripts that wait between commands should use this rather than ``time.sleep`` so the
        same script runs instantly against the simulator in tests. At most
        :data:`LONGEST_SLEEP` (about 11 days) at once: a simulator steps every sample of it.

        Raises:
            InvalidArgument: not a number, negative, not finite or longer than that.
        """
        self.link.pause(check_sleep(seconds))

    # -- unsolicited output and records -----------------------------------------------------

    @property
    def messages(self) -> MessageQueue:
        """Unsolicited lines (program ``MG`` output ...) as a queue: ``messages.get(timeout)``.

        Reading it starts the background poll of an idle link.
        """
        self.messages_room.ensure_polling()
        return self.messages_room.queue

    def subscribe(self, callback: MessageCallback) -> Callable[[], None]:
        """Call ``callback(line)`` for each unsolicited line, in order, outside the link lock
        (a callback may send commands itself). Returns a function that unsubscribes."""
        return self.messages_room.subscribe(callback)

    @overload
    def record(
        self, axes: str = "", *, as_dict: Literal[False] = False, timeout: float | None = None
    ) -> np.void: ...
    @overload
    def record(
        self, axes: str = "", *, as_dict: Literal[True], timeout: float | None = None
    ) -> dict[str, object]: ...
    @overload
    def record(
        self, axes: str = "", *, as_dict: bool, timeout: float | None = None
    ) -> np.void | dict[str, object]: ...
    def record(
        self, axes: str = "", *, as_dict: bool = False, timeout: float | None = None
    ) -> np.void | dict[str, object]:
        """Read one data record (``QR``) and decode it.

        Returns:
            A structured numpy record (``rec["A"]["position"]``, ``rec["sample"]``,
            ``rec["error_code"]``, ``rec["time"]``: the controller sample in full; field
            names in :mod:`galil.protocol.records`), or a dict, both raw as the controller
            sends them: an axis's ``velocity`` is 64 times ``TV``
            (:data:`~galil.protocol.records.RECORD_VELOCITY_SCALE`).
            ``galil.decode_fields(rec)`` gives it in counts/s and names its status bits,
            switches and stop codes.
        """
        if check_flag(as_dict, "as_dict"):
            return self.records_room.record_dict(axes, timeout=timeout)
        return self.records_room.record(axes, timeout=timeout)

    def records(
        self,
        period: int | None = None,
        *,
        seconds: object = None,
        method: str = "auto",
        maxlen: int = 10_000,
    ) -> RecordStream:
        """Stream data records every ``period`` servo samples (or every ``seconds``).

        ``"DR"`` (the default over Ethernet) has the controller push them (``DR period,h``) to
        a handle opened for them alone; ``"QR"`` (elsewhere) polls, one ``QR`` per record when
        it is due. Each record's ``time`` is the controller sample it was taken at; the
        stream counts records that went missing (``missed``, ``gaps``). Close the stream (or
        use it as a context manager) to stop it.

        Args:
            period: servo samples between records.
            seconds: or the period in seconds (a number or a time Quantity), a whole number
                of samples.
            method: ``"auto"``, ``"DR"`` or ``"QR"``.
            maxlen: records kept waiting before the oldest drop.

        Raises:
            InvalidArgument: bad period or method, DR where there is no handle for it, or the
                model has no data record.
            CommandError: the controller refused ``DR`` (a period below its minimum ...).
        """
        return self.records_room.stream(period, seconds=seconds, method=method, maxlen=maxlen)
