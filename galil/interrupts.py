"""Interrupts: ``UI`` from a program and ``EI`` events, as callbacks and a queue.

Like gclib's ``GInterrupt``: the controller sends interrupt packets (one status byte per
event, :mod:`galil.protocol.interrupts`) to the Ethernet handle ``EI`` names. :meth:`enable`
opens a handle of its own for them, asks its letter (``MG _WH`` on it) and sends ``EI m,n,h``;
a reader thread turns the packets into :class:`~galil.protocol.interrupts.Interrupt` events,
which land in :attr:`queue` and go to every subscriber, in order, on that thread::

    dmc.interrupts.enable(axes="A")              # a user interrupt (UI) needs no mask
    dmc.interrupts.subscribe(lambda i: print(i)) # "UI 3", "axis A done" ...
    dmc.interrupts.get(timeout=5)

Interrupts need a second Ethernet handle: over serial or USB there is none (``enable``
refuses). A controller sends them to a UDP handle: this room opens one where the transport
can (``DatagramSource``: the TCP transport opens a UDP handle to the same port), else a TCP
handle; see ``docs/decisions/0017``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable

from galil.errors import (
    FixedAttributes,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
    ReadOnly,
)
from galil.link import Link, read_handle, read_reply
from galil.protocol import commands as cmds
from galil.protocol.handles import parse_th
from galil.protocol.interrupts import Interrupt, InterruptParser
from galil.protocol.numbers import read_one
from galil.queues import BoundedQueue, Subscribers, source_ended
from galil.transport import DatagramSource, HandleSource, LocalAddress, Transport

__all__ = ["Interrupt", "InterruptCallback", "InterruptQueue", "Interrupts"]

_LOG = logging.getLogger("galil.interrupts")

InterruptCallback = Callable[[Interrupt], None]


class InterruptQueue(BoundedQueue[Interrupt]):
    """Interrupts, oldest first; bounded (the oldest drop, counted in ``dropped``)."""

    def __init__(self, maxlen: int = 1000) -> None:
        super().__init__(maxlen, "interrupt")


class Interrupts(FixedAttributes):
    """The interrupts of one controller.

    Args:
        link: the command link.
        maxlen: interrupts kept in :attr:`queue` before the oldest drop.

    Attributes:
        queue: the interrupts received, oldest first.
        mask: the ``EI`` mask sent last (``None`` while not enabled).
    """

    link: ReadOnly[Link] = ReadOnly()
    queue: ReadOnly[InterruptQueue] = ReadOnly()
    mask: ReadOnly[int | None] = ReadOnly()

    def __init__(self, link: Link, *, maxlen: int = 1000) -> None:
        self._link = link
        self._queue = InterruptQueue(maxlen)
        self.queue.gone, self.queue.revive = link.gone, link.revive  # (a dead link's get())
        self._mask: int | None = None
        self._handle: Transport | None = None
        self._index = 0
        self._datagram = False  # the handle is UDP: the controller cannot see it close
        self._local: tuple[str, int] | None = None  # the UDP handle's host end (TH names it)
        # A UDP handle a dead link left on the controller: (its letter, its host end), freed
        # by reopen() once the new link is up, if TH still shows it ours.
        self._stale: tuple[str, tuple[str, int]] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._subscribers: Subscribers[Interrupt] = Subscribers("interrupt", _LOG)

    def _mask_of(self, axes: str, all_done: bool) -> int:
        model = self.link.model
        mask = 0
        if not isinstance(axes, str):
            raise InvalidArgument(f"axes must be a string of axis letters, not {axes!r}")
        for name in axes.replace(",", "").replace(" ", ""):
            mask |= 1 << "ABCDEFGH".index(model.axis_letter(name))
        if not isinstance(all_done, bool):
            raise InvalidArgument(f"all_done must be True or False, not {all_done!r}")
        return mask | (0x100 if all_done else 0)

    def enable(self, axes: str = "", *, all_done: bool = False) -> None:
        """Receive interrupts: user interrupts (``UI``), and motion complete on ``axes``
        (status ``0xD0`` + axis) and on every axis (``all_done``, ``0xD8``).

        Calling it again changes the mask and keeps the handle.

        Raises:
            InvalidArgument: a bad axis, or no second Ethernet handle on this link.
            GalilConnectionError: the handle could not be opened.
        """
        mask = self._mask_of(axes, all_done)
        link = self.link
        transport: object = link.transport
        if not isinstance(transport, HandleSource) or not link.model.has_ethernet:
            raise InvalidArgument(
                f"interrupts come on an Ethernet handle of their own; {transport!r} has none "
                "(poll _BG, or watch program output with controller.messages)",
                model=link.model.name,
            )
        if self._handle is None:
            self._open(transport)
        link.command_line([cmds.ei(mask, None, self._index)])
        self._mask = mask

    def _open(self, transport: HandleSource) -> None:
        link = self.link
        try:
            # A controller sends interrupt packets to a UDP handle: one where the link can
            # open it, else a TCP handle (which the simulator also accepts).
            source: object = transport
            datagram = isinstance(source, DatagramSource)
            if isinstance(source, DatagramSource):
                handle = source.open_datagram_handle()
            else:
                handle = transport.open_handle()
        except GalilConnectionError as exc:
            raise link.error(GalilConnectionError, f"no handle for interrupts: {exc}") from exc
        try:
            text = read_reply(handle, f"MG _WH{cmds.READ_FORMAT}\r".encode(), link.timeout)
            index = round(read_one(text))
            if not 0 <= index <= 7:
                raise ProtocolError(f"MG _WH answered {text!r}: not a handle 0..7")
        except (GalilError, ValueError) as exc:
            local = handle.local_address if isinstance(handle, LocalAddress) else None
            with contextlib.suppress(GalilError, OSError):
                handle.close()
            if datagram and local is not None:
                # the controller cannot see a UDP handle close: free it (its eight run out)
                self._free_udp(None, local)
            if isinstance(exc, GalilTimeoutError):
                # (a controller with no handle AVAILABLE ignores a UDP handle's packets)
                raise link.error(
                    GalilTimeoutError,
                    f"the new handle for interrupts had no answer to MG _WH in {link.timeout:g} s:"
                    " the controller may have no free Ethernet handle (TH lists them; close"
                    " another connection to it, or free a stale handle with IHm=>-1)",
                ) from exc
            if isinstance(exc, GalilError):
                raise
            raise link.error(ProtocolError, f"MG _WH answered {exc}") from exc
        self._handle, self._index, self._datagram = handle, index, datagram
        self._local = handle.local_address if isinstance(handle, LocalAddress) else None
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._read, args=(handle, self._stop), name="galil-interrupts", daemon=True
        )
        self._thread.start()

    def _read(self, handle: Transport, stop: threading.Event) -> None:
        # Over UDP each read is one datagram, parsed on its own (a datagram cut short is not
        # completed by the next one's bytes).
        parser = InterruptParser(datagram=self._datagram)
        while not stop.is_set():
            try:
                chunk = read_handle(handle, 0.25)
            except GalilConnectionError as exc:
                if not stop.is_set():  # (closed by close(): nothing to tell)
                    source_ended(self.link, self.queue, stop, "the interrupt handle", exc)
                return
            if not chunk:
                stop.wait(0.005)  # some handles return at once when idle
                continue
            events = parser.feed(chunk)  # (the good packets of a read, around a bad one)
            for why in parser.take_dropped():
                _LOG.warning("galil: interrupt packet dropped: %s", why)
            for event in events:
                # Callbacks first: once an interrupt is in the queue, every callback has had it.
                self._subscribers.notify(event)
                self.queue.put(event)

    def subscribe(self, callback: InterruptCallback) -> Callable[[], None]:
        """Call ``callback(interrupt)`` for each interrupt, on the reader thread; returns an
        unsubscriber. Interrupts arrive only once :meth:`enable` was called."""
        return self._subscribers.add(callback)

    def get(self, timeout: float | None = None) -> Interrupt:
        """The oldest interrupt (see :class:`InterruptQueue`).

        Raises:
            QueueTimeoutError: none within ``timeout`` (a ``GalilTimeoutError`` that is also
                a ``queue.Empty``).
            GalilConnectionError: none is waiting and the controller was closed.
        """
        return self.queue.get(timeout)

    @property
    def enabled(self) -> bool:
        """Whether interrupts come (``enable`` was called and not undone)."""
        return self._handle is not None

    def __repr__(self) -> str:
        mask = self.mask
        on = self.enabled and mask is not None
        state = f"enabled, EI mask {mask:#x}" if on else "not enabled"
        q = self.queue
        name = self.link.model.name
        return f"<Interrupts of {name}: {state}, {len(q)} waiting, {q.dropped} dropped>"

    def disable(self) -> None:
        """``EI 0`` (the controller forgets the mask and its queue) and close the handle.

        A UDP handle is closed on the controller too (``IHm=>-1``): no packet tells it that
        the host's socket is gone, and its eight handles would run out. (The handle of a link
        that died is freed by :meth:`reopen`.)
        """
        if self._handle is None:
            return
        if self.link.is_open:
            lines = [cmds.ei(0)]
            if self._datagram:
                lines.append(cmds.ih_close(self._index))
            with contextlib.suppress(GalilError):
                self.link.command_line(lines)
        self.close()

    def close(self, *, keep_mask: bool = False) -> None:
        """Stop the reader and close the handle (the link is closing); idempotent.

        With ``keep_mask`` (a reconnect), :meth:`reopen` enables the same mask again, and
        frees the UDP handle on the controller (the link that could send ``IHm=>-1`` is gone).
        """
        self._stop.set()
        if keep_mask and self._handle is not None and self._datagram and self._local:
            self._stale = ("ABCDEFGH"[self._index], self._local)
        handle, self._handle = self._handle, None
        if handle is not None:
            with contextlib.suppress(GalilError, OSError):
                handle.close()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        if not keep_mask:
            self._mask = None

    def reopen(self) -> None:
        """After a reconnect: the old UDP handle freed on the controller (if it is still this
        host's: :meth:`_free_stale`), then a new handle and the same mask again (if enabled
        before)."""
        mask = self.mask
        self.close()
        self._free_stale()
        if mask is not None:
            axes = "".join(c for i, c in enumerate("ABCDEFGH") if mask >> i & 1)
            self.enable(axes, all_done=bool(mask & 0x100))

    def _free_stale(self) -> None:
        """Free the UDP handle the dead link left on the controller: ``TH`` says which
        handles are open and to whom; ``IHm=>-1`` only if its letter is still a UDP handle to
        this host's old address and port (after a reconnect, or a controller reset, the
        letter may be another client's). Best effort: a failure is logged (the reconnect
        itself went well)."""
        stale, self._stale = self._stale, None
        if stale is not None:
            self._free_udp(*stale)

    def _free_udp(self, letter: str | None, local: tuple[str, int]) -> None:
        """``IHm=>-1`` for the UDP handle(s) to ``local`` that ``TH`` lists (only ``letter``
        if given). Best effort: a failure is logged."""
        if not self.link.is_open:
            return
        try:
            for held in parse_th(self.link.command_line([cmds.th()])[0]).values():
                if held.kind == "UDP" and held.peer == local and letter in (None, held.letter):
                    self.link.command_line([cmds.ih_close(held.letter)])
        except GalilError as exc:
            _LOG.warning("galil: the interrupt handle IH%s was not freed: %s", letter or "?", exc)
