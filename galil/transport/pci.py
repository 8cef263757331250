"""PCI transport: the character device node of Galil's Linux driver (``/dev/galilpci0``).

The driver exposes the controller's command FIFO as a byte stream: ``write`` sends commands,
``read`` returns replies. The node is opened non-blocking and read through ``poll`` so that a
read honours its timeout, and locked (``flock``, advisory) so that a second opener of this
library (a script, ``galil list``) is refused instead of reading the first one's replies.
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import time
from urllib.parse import SplitResult

from galil.errors import GalilConnectionError, InvalidArgument, unknown_options
from galil.transport import parse_options
from galil.transport.base import TransportBase
from galil.transport.options import flag, seconds

__all__ = ["PciTransport", "open_pci"]

_CHUNK = 4096
_DEAD = select.POLLERR | select.POLLHUP | select.POLLNVAL
_EOF_STEP = 0.01  # how often a node at end of file is read again while a read waits


class PciTransport(TransportBase[int]):
    """A Galil PCI device node opened read/write.

    Capabilities: none (the driver's FIFO rate is not documented).

    Args:
        path: the node, e.g. ``/dev/galilpci0``.
        write_timeout: seconds to wait for the driver to take a write.
        exclusive: lock the node (``flock``): a node another process holds this way is
            refused. The lock is advisory: it keeps out other users of this library (and of
            pyserial's ``exclusive``), not a program that does not ask for it.
    """

    kind = "pci"

    def __init__(self, path: str, *, write_timeout: float = 1.0, exclusive: bool = True) -> None:
        self.path = path
        self.write_timeout = seconds(write_timeout, "write_timeout")
        exclusive = flag(exclusive, "exclusive")
        try:
            flags = os.O_RDWR | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
            fd = os.open(path, flags)
        except OSError as exc:
            raise GalilConnectionError(f"cannot open PCI node {path}: {exc}") from exc
        if exclusive:
            _lock(fd, path)
        super().__init__(fd, name=path, label=f"PCI node {path}")
        self._poll_in = select.poll()
        self._poll_in.register(fd, select.POLLIN | select.POLLPRI)
        self._poll_out = select.poll()
        self._poll_out.register(fd, select.POLLOUT)

    def _send_some(self, handle: int, data: memoryview) -> int:
        try:
            return os.write(handle, data)
        except BlockingIOError:
            return 0

    def _wait_writable(self, handle: int) -> None:
        events = self._poll_out.poll(self.write_timeout * 1000)
        if not events:
            raise GalilConnectionError(
                f"{self.label} did not accept data within {self.write_timeout} s"
            )
        if events[0][1] & _DEAD:
            raise GalilConnectionError(f"{self.label} is gone")

    def _recv(self, handle: int, timeout: float) -> bytes:
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            data = self._recv_once(handle, deadline - time.monotonic())
            if data is not None:
                return data
            # End of file without a hang-up (/dev/null does this): poll says readable at
            # once, every time. Read again now and then until the timeout, not in a spin.
            left = deadline - time.monotonic()
            if left <= 0:
                return b""
            time.sleep(min(_EOF_STEP, left))

    def _recv_once(self, handle: int, timeout: float) -> bytes | None:
        """What one read gets within ``timeout``; ``None`` for end of file."""
        events = self._poll_in.poll(max(0.0, timeout) * 1000)
        if not events:
            return b""
        mask = events[0][1]
        try:
            data = os.read(handle, _CHUNK)
        except BlockingIOError:
            return b""
        except OSError as exc:
            # A pty master reports its closed peer as EIO; a driver node as ENODEV.
            if exc.errno in (errno.EIO, errno.ENODEV, errno.ENXIO):
                raise GalilConnectionError(f"{self.label} is gone: {exc}") from exc
            raise
        if not data and mask & _DEAD:
            raise GalilConnectionError(f"{self.label} is gone (peer hung up)")
        return data or None

    def _release(self, handle: int) -> None:
        os.close(handle)


def _lock(fd: int, path: str) -> None:
    """Lock the node ``fd`` for this process, or close it and say who holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise GalilConnectionError(
                f"cannot open PCI node {path}: the node is in use by another process, or by "
                "another connection of this one not closed yet: close that one, or pass "
                f"exclusive=0 to share it: {exc}"
            ) from exc
        raise GalilConnectionError(f"cannot lock PCI node {path}: {exc}") from exc


def open_pci(url: SplitResult, **options: object) -> PciTransport:
    """Open ``/dev/galilpciN`` or ``pci:///path/to/node``; options ``write_timeout`` and
    ``exclusive`` (True: a node another process holds is refused).

    Raises:
        InvalidArgument: no path, a bad ``write_timeout`` or ``exclusive``, or an unknown
            option.
        GalilConnectionError: the node cannot be opened, or another process holds it.
    """
    opts = parse_options(url, options)
    path = url.netloc + url.path
    if not path:
        raise InvalidArgument(f"no device node in {url.geturl()!r}; e.g. /dev/galilpci0")
    write_timeout = seconds(opts.pop("write_timeout", 1.0), "write_timeout")
    exclusive = flag(opts.pop("exclusive", True), "exclusive")
    if opts:
        raise unknown_options("PCI", opts, ("write_timeout", "exclusive"))
    return PciTransport(path, write_timeout=write_timeout, exclusive=exclusive)
