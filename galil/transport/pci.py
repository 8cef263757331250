"""PCI transport: the character device node of Galil's Linux driver (``/dev/galilpci0``).

The driver exposes the controller's command FIFO as a byte stream: ``write`` sends commands,
``read`` returns replies. The node is opened non-blocking and read through ``poll`` so that a
read honours its timeout.
"""

from __future__ import annotations

import errno
import os
import select
import time
from typing import Any
from urllib.parse import SplitResult

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import parse_options
from galil.transport.base import TransportBase
from galil.transport.options import seconds

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
    """

    kind = "pci"

    def __init__(self, path: str, *, write_timeout: float = 1.0) -> None:
        self.path = path
        self.write_timeout = seconds(write_timeout, "write_timeout")
        try:
            flags = os.O_RDWR | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
            fd = os.open(path, flags)
        except OSError as exc:
            raise GalilConnectionError(f"cannot open PCI node {path}: {exc}") from exc
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


def open_pci(url: SplitResult, **options: Any) -> PciTransport:
    """Open ``/dev/galilpciN`` or ``pci:///path/to/node``; option ``write_timeout``.

    Raises:
        InvalidArgument: no path, a bad ``write_timeout``, or an unknown option.
        GalilConnectionError: the node cannot be opened.
    """
    opts = parse_options(url, options)
    path = url.netloc + url.path
    if not path:
        raise InvalidArgument(f"no device node in {url.geturl()!r}; e.g. /dev/galilpci0")
    write_timeout = seconds(opts.pop("write_timeout", 1.0), "write_timeout")
    if opts:
        raise InvalidArgument(f"unknown PCI option(s): {', '.join(sorted(opts))}")
    return PciTransport(path, write_timeout=write_timeout)
