"""Serial transport through pyserial's ``serial_for_url``.

Device paths (``/dev/ttyUSB0``, ``COM3``), ``serial:///dev/ttyS0?baudrate=19200`` and every
pyserial URL (``socket://``, ``loop://``, ``spy://``, ``rfc2217://`` ...) open here. Defaults
follow Galil's own host library: 8 data bits, no parity, 1 stop bit, RTS/CTS handshake.
"""

from __future__ import annotations

import contextlib
from typing import Any, Protocol
from urllib.parse import SplitResult

import serial

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import PYSERIAL_SCHEMES, parse_options, timeout_grid

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


class SerialTransport:
    """A pyserial port (or anything with pyserial's ``read``/``write``/``in_waiting``).

    Args:
        port: an open ``SerialPort`` instance to adopt.
        name: how to name the port in messages.
    """

    secondary: None = None

    def __init__(self, port: SerialPort, name: str = "") -> None:
        self._port: SerialPort | None = port
        self.name = name or str(getattr(port, "name", None) or getattr(port, "port", "serial"))
        self._timeout: float | None = port.timeout

    @property
    def kind(self) -> str:
        """Always ``"serial"``."""
        return "serial"

    @property
    def byte_rate(self) -> float:
        """Bytes per second the line carries: baud / 10 (start, 8 data, stop bits).

        A port that does not say its baud rate is taken at 9600, the slowest common one.
        """
        baud = getattr(self._port, "baudrate", None)
        return float(baud) / 10.0 if isinstance(baud, (int, float)) and baud > 0 else 960.0

    @property
    def port(self) -> SerialPort:
        """The underlying pyserial object (for line settings such as ``baudrate``)."""
        return self._live()

    def __repr__(self) -> str:
        state = "open" if self._port is not None else "closed"
        return f"<SerialTransport {self.name} {state}>"

    def _live(self) -> SerialPort:
        if self._port is None:
            raise GalilConnectionError(f"serial port {self.name} is closed")
        return self._port

    def write(self, data: bytes) -> None:
        """Send all of ``data``."""
        port = self._live()
        try:
            port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise GalilConnectionError(
                f"serial port {self.name} failed while sending: {exc}"
            ) from exc

    def read(self, timeout: float) -> bytes:
        """Return what arrives within ``timeout`` seconds (``b""`` if nothing)."""
        port = self._live()
        try:
            t = timeout_grid(timeout)
            if t != self._timeout:
                # Changing pyserial's timeout may reconfigure the port: only do it on change.
                port.timeout = t
                self._timeout = t
            waiting = port.in_waiting
            # read(n) blocks until n bytes or the timeout: ask for what is there, or one byte.
            data = bytes(port.read(waiting or 1))
            if data and not waiting:
                more = port.in_waiting
                if more:
                    data += bytes(port.read(more))
        except (serial.SerialException, OSError, TypeError) as exc:
            # pyserial raises TypeError from some handlers when the port vanished under it.
            raise GalilConnectionError(
                f"serial port {self.name} failed while reading: {exc}"
            ) from exc
        return data

    def close(self) -> None:
        """Close the port; idempotent."""
        port, self._port = self._port, None
        if port is not None:
            # The device may be gone already; closing is best effort.
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()


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
