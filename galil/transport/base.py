"""What the built-in transports share: lifecycle, ``repr``, timeout caching, error wrapping.

:class:`TransportBase` is a template in the manner of python-can's ``BusABC``: it owns the
public ``write``/``read``/``close`` and the bookkeeping around them, and a subclass supplies
the few operations that touch its OS handle (a socket, a pyserial port, a USB device, a file
descriptor). It is a convenience for the transports in this package, not a contract: the
:class:`~galil.transport.Transport` Protocol is what the rest of ``galil`` relies on, and a
plug-in transport satisfies it without inheriting anything.

What the base gives every subclass:

- lifecycle: a closed transport raises :class:`GalilConnectionError` saying so on ``write``
  and ``read``; ``close`` is idempotent, closes the ``secondary`` handle too, and never raises
  for a link that is already dead;
- ``repr``: ``<TcpTransport 192.168.0.2:23 open>``;
- read timeouts on the 10 ms grid (:func:`timeout_grid`), set on the handle only when the
  value changes (:meth:`TransportBase._set_timeout`);
- error wrapping: an ``OSError`` (pyserial's and pyusb's errors are ``OSError`` too) becomes a
  :class:`GalilConnectionError` naming the link and what it was doing, chained with ``from``;
- a write loop for handles that take data in pieces (:meth:`TransportBase._send_some`).
"""

from __future__ import annotations

import contextlib
import errno
import math
import sys
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar, Generic, TypeVar

from galil.errors import GalilConnectionError
from galil.transport.options import LONGEST_WAIT

if TYPE_CHECKING:
    from galil.transport import Transport

__all__ = ["TransportBase", "locked_out", "port_in_use", "timeout_grid"]


def locked_out(exc: BaseException) -> bool:
    """Whether ``exc`` is the refusal of an exclusive lock on a device (``flock`` with
    ``LOCK_NB`` found it locked: ``EWOULDBLOCK``; pyserial's ``exclusive=True`` raises it as a
    ``SerialException``, an ``OSError``), or Windows' refusal of a COM port another program
    holds (pyserial: ``could not open port 'COM3': PermissionError(13, 'Access is denied.'``)."""
    if not isinstance(exc, OSError):
        return False
    if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
        return True
    return sys.platform == "win32" and "PermissionError" in str(exc)  # pragma: no cover


def port_in_use(exc: BaseException) -> bool:
    """Whether ``exc`` (a :class:`GalilConnectionError` from opening a serial port or a PCI
    node, or from :func:`galil.connect`) says another process holds the device, rather than
    that it is missing or broken."""
    if not isinstance(exc, GalilConnectionError):
        return False
    cause: BaseException | None = exc
    for _ in range(8):  # (the chain of a connect that wrapped the transport's error)
        if cause is None:
            return False
        if locked_out(cause):
            return True
        cause = cause.__cause__
    return False


H = TypeVar("H")
"""The OS-level handle a transport holds (socket, pyserial port, USB device, fd)."""


def timeout_grid(timeout: float) -> float:
    """Round a read timeout up to the next 10 ms (0 stays 0, negatives become 0).

    Setting a timeout costs system calls on sockets and serial ports; a caller counting down
    to a deadline would pass a new value every read. On the grid the common case (the same
    default timeout, command after command) reuses the value already set. A read still returns
    as soon as data arrives, so rounding up only delays an empty read by under 10 ms.
    """
    if timeout <= 0:
        return 0.0
    return math.ceil(timeout * 100.0 - 1e-9) / 100.0


class TransportBase(ABC, Generic[H]):
    """Base of the built-in transports; see the module docstring for what it provides.

    A subclass implements :meth:`_recv` and :meth:`_release`, and either :meth:`_send` (a
    handle that sends everything at once) or :meth:`_send_some` (one that takes data in
    pieces, with :meth:`_wait_writable` for when it takes none). A handle with a settable read
    timeout implements :meth:`_set_timeout`. Errors listed in :attr:`_io_errors` raised by
    any of these become :class:`GalilConnectionError`; a :class:`GalilConnectionError` raised
    by a subclass (with a more precise text) passes through unchanged.

    Args:
        handle: the open OS-level handle; the transport owns it from now on.
        name: how ``repr`` names the link (``"192.168.0.2:23"``, ``"/dev/ttyUSB0"``).
        label: how error messages name it (``"TCP link to 192.168.0.2:23"``).
        timeout: the read timeout already set on ``handle`` (``None``: unknown, set it at the
            first read).

    Attributes:
        kind: the bus (``"ethernet"``, ``"serial"``, ``"usb"``, ``"pci"``).
        secondary: a second handle closed together with this one, if any.
        name: see Args.
        label: see Args.
    """

    kind: str
    secondary: Transport | None = None
    _io_errors: ClassVar[tuple[type[Exception], ...]] = (OSError,)

    def __init__(self, handle: H, *, name: str, label: str, timeout: float | None = None) -> None:
        self._handle: H | None = handle
        self.name = name
        self.label = label
        self._timeout_in: float | None = None  # last timeout asked for, as given
        self._timeout_set: float | None = timeout  # last timeout set on the handle (grid)

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        return self._handle is None

    def __repr__(self) -> str:
        state = "closed" if self._handle is None else "open"
        return f"<{type(self).__name__} {self.name} {state}>"

    def _closed_error(self) -> GalilConnectionError:
        return GalilConnectionError(f"{self.label} is closed (close() was called on it)")

    def _failure(self, action: str, exc: BaseException) -> GalilConnectionError:
        """The error for an OS failure while ``action`` (``"sending"``, ``"reading"``)."""
        return GalilConnectionError(f"{self.label} failed while {action}: {exc}")

    def _live(self) -> H:
        """The handle; raises :class:`GalilConnectionError` if the transport is closed."""
        handle = self._handle
        if handle is None:
            raise self._closed_error()
        return handle

    def close(self) -> None:
        """Close the handle (and the secondary one); idempotent, never fails on a dead link."""
        secondary = self.secondary
        if secondary is not None:
            secondary.close()
        handle, self._handle = self._handle, None
        if handle is not None:
            with contextlib.suppress(*self._io_errors):  # the peer or device is gone already
                self._release(handle)

    # -- bytes out and in --------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Send all of ``data``.

        Raises:
            GalilConnectionError: the transport is closed or the link failed.
        """
        handle = self._handle
        if handle is None:
            raise self._closed_error()
        try:
            self._send(handle, data)
        except GalilConnectionError:
            raise
        except self._io_errors as exc:
            raise self._failure("sending", exc) from exc

    def read(self, timeout: float) -> bytes:
        """Return what arrives within ``timeout`` seconds (``b""`` if nothing; 0 polls; at
        most :data:`~galil.transport.options.LONGEST_WAIT`, what every OS call takes).

        Raises:
            GalilConnectionError: the transport is closed or the link failed.
        """
        handle = self._handle
        if handle is None:
            raise self._closed_error()
        if timeout > LONGEST_WAIT:  # (a wait longer than the OS takes: the caller reads again)
            timeout = LONGEST_WAIT
        try:
            if timeout != self._timeout_in:
                self._regrid(handle, timeout)
            return self._recv(handle, timeout)
        except GalilConnectionError:
            raise
        except self._io_errors as exc:
            raise self._failure("reading", exc) from exc

    def _regrid(self, handle: H, timeout: float) -> None:
        # A caller repeating its timeout skips even the rounding; a new value on the same
        # grid step costs no system call.
        grid = timeout_grid(timeout)
        if grid != self._timeout_set:
            self._set_timeout(handle, grid)
            self._timeout_set = grid
        self._timeout_in = timeout

    def _send(self, handle: H, data: bytes) -> None:
        """Send all of ``data``: by default piece by piece through :meth:`_send_some`."""
        view = memoryview(data)
        while view:
            n = self._send_some(handle, view)
            if n > 0:
                view = view[n:]
            else:
                self._wait_writable(handle)

    # -- what a subclass supplies ------------------------------------------------------------

    def _send_some(self, handle: H, data: memoryview) -> int:
        """Send a first part of ``data``; return how many bytes went (0: none just now)."""
        raise NotImplementedError(f"{type(self).__name__} overrides neither _send nor _send_some")

    def _wait_writable(self, handle: H) -> None:
        """Wait until the handle takes data again; raise if it will not."""
        raise GalilConnectionError(f"{self.label} accepted no bytes")

    def _set_timeout(self, handle: H, seconds: float) -> None:
        """Make the next reads wait up to ``seconds`` (a 10 ms grid value; 0 polls).

        The default does nothing: for handles that take the timeout with each read.
        """

    @abstractmethod
    def _recv(self, handle: H, timeout: float) -> bytes:
        """Return what arrives within ``timeout`` (``b""`` if nothing)."""

    @abstractmethod
    def _release(self, handle: H) -> None:
        """Close the OS handle (errors in :attr:`_io_errors` are ignored by :meth:`close`)."""
