"""Serial transport through pyserial's ``serial_for_url``.

Device paths (``/dev/ttyUSB0``, ``COM3``), ``serial:///dev/ttyS0?baudrate=19200`` and every
pyserial URL (``socket://``, ``loop://``, ``spy://``, ``rfc2217://`` ...) open here. Defaults
follow Galil's own host library: 8 data bits, no parity, 1 stop bit, RTS/CTS handshake.
"""

from __future__ import annotations

from typing import Any, Protocol
from urllib.parse import SplitResult

import serial

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import PYSERIAL_SCHEMES, parse_options
from galil.transport.base import TransportBase

__all__ = ["DEFAULT_BAUDRATE", "SerialPort", "SerialTransport", "open_serial"]

DEFAULT_BAUDRATE = 115200

# Options forwarded to pyserial; anything else is a typo we report.
_PYSERIAL_OPTIONS = frozenset(
    {
        "baudrate",
        "bytesize",
        "parity",
        "stopbits",
        "xonxoff",
        "rtscts",
        "dsrdtr",
        "write_timeout",
        "exclusive",
        "inter_byte_timeout",
    }
)


class SerialPort(Protocol):
    """The part of a pyserial port this transport uses."""

    timeout: float | None

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read."""
        ...

    def read(self, size: int = 1) -> bytes:
        """Read up to ``size`` bytes, blocking up to ``timeout``."""
        ...

    def write(self, data: bytes, /) -> int | None:
        """Write ``data``."""
        ...

    def close(self) -> None:
        """Close the port."""
        ...


class SerialTransport(TransportBase[SerialPort]):
    """A pyserial port (or anything with pyserial's ``read``/``write``/``in_waiting``).

    Capability: :class:`~galil.transport.ByteRate` (from the port's baud rate).

    Args:
        port: an open ``SerialPort`` instance to adopt.
        name: how to name the port in messages.
    """

    kind = "serial"

    def __init__(self, port: SerialPort, name: str = "") -> None:
        name = name or str(getattr(port, "name", None) or getattr(port, "port", "serial"))
        super().__init__(port, name=name, label=f"serial port {name}", timeout=port.timeout)

    @property
    def byte_rate(self) -> float:
        """Bytes per second the line carries: baud / 10 (start, 8 data, stop bits).

        A port that does not say its baud rate is taken at 9600, the slowest common one.
        """
        baud = getattr(self._handle, "baudrate", None)
        return float(baud) / 10.0 if isinstance(baud, (int, float)) and baud > 0 else 960.0

    @property
    def port(self) -> SerialPort:
        """The underlying pyserial object (for line settings such as ``baudrate``)."""
        return self._live()

    def _send(self, handle: SerialPort, data: bytes) -> None:
        handle.write(data)  # pyserial writes everything (or raises on its write_timeout)

    def _set_timeout(self, handle: SerialPort, seconds: float) -> None:
        handle.timeout = seconds  # may reconfigure the port: the base only sets a new value

    def _recv(self, handle: SerialPort, timeout: float) -> bytes:
        try:
            waiting = handle.in_waiting
            # read(n) blocks until n bytes or the timeout: ask for what is there, or one byte.
            data = bytes(handle.read(waiting or 1))
            if data and not waiting:
                more = handle.in_waiting
                if more:
                    data += bytes(handle.read(more))
        except TypeError as exc:
            # pyserial raises TypeError from some handlers when the port vanished under it.
            raise self._failure("reading", exc) from exc
        return data

    def _release(self, handle: SerialPort) -> None:
        handle.close()  # best effort: the base ignores the errors of a vanished device


def open_serial(url: SplitResult, **options: Any) -> SerialTransport:
    """Open a serial port or pyserial URL.

    Options (URL query or keywords): ``baudrate`` (115200), ``bytesize``, ``parity``,
    ``stopbits``, ``rtscts`` (True), ``xonxoff``, ``dsrdtr``, ``write_timeout``, ``exclusive``.

    Raises:
        InvalidArgument: unknown option or no port named.
        GalilConnectionError: the port cannot be opened.
    """
    scheme = url.scheme.lower()
    if scheme in PYSERIAL_SCHEMES:
        # pyserial parses its own query parameters for these handlers.
        # Not url.geturl(): it drops the "//" of an empty host (spy:///dev/x -> spy:/dev/x).
        target = f"{url.scheme}://{url.netloc}{url.path}"
        if url.query:
            target += "?" + url.query
        opts = dict(options)
    else:
        target = url.netloc + url.path
        opts = parse_options(url, options)
        if not target:
            raise InvalidArgument(f"no serial port in {url.geturl()!r}; e.g. serial:///dev/ttyS0")
    unknown = set(opts) - _PYSERIAL_OPTIONS
    if unknown:
        raise InvalidArgument(
            f"unknown serial option(s): {', '.join(sorted(unknown))}; "
            f"known: {', '.join(sorted(_PYSERIAL_OPTIONS))}"
        )
    opts.setdefault("baudrate", DEFAULT_BAUDRATE)
    opts.setdefault("rtscts", True)
    try:
        port = serial.serial_for_url(target, timeout=0, **opts)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise GalilConnectionError(f"cannot open serial port {target!r}: {exc}") from exc
    return SerialTransport(port, target)
