"""Serial transport through pyserial's ``serial_for_url``.

Device paths (``/dev/ttyUSB0``, ``COM3``), ``serial:///dev/ttyS0?baudrate=19200`` and every
pyserial URL (``socket://``, ``loop://``, ``spy://``, ``rfc2217://`` ...) open here. Defaults
follow Galil's own host library: 8 data bits, no parity, 1 stop bit, RTS/CTS handshake.
"""

from __future__ import annotations

import contextlib
import errno
import sys
from collections.abc import Callable
from typing import Any, ClassVar, Protocol
from urllib.parse import SplitResult, parse_qsl

import serial

from galil.errors import GalilConnectionError, GalilError, InvalidArgument
from galil.transport import PYSERIAL_SCHEMES, parse_options
from galil.transport.base import TransportBase, locked_out
from galil.transport.options import choice, flag, seconds, whole_number

__all__ = ["DEFAULT_BAUDRATE", "SerialPort", "SerialTransport", "open_serial"]

DEFAULT_BAUDRATE = 115200

# What the OS's line settings call raises when the port refuses them (a data size, a parity
# or a speed it cannot do): termios.error on POSIX, which is no OSError.
if sys.platform != "win32":
    import termios

    _LINE_ERRORS: tuple[type[Exception], ...] = (termios.error,)
else:  # pragma: no cover - pyserial raises SerialException (an OSError) there
    _LINE_ERRORS = ()


_LOG_LEVELS = ("debug", "info", "warning", "error")
# The query parameters of pyserial's URL handlers (pyserial 3.5); a scheme not listed here
# (cp2110) is left to pyserial. The value checked, where pyserial looks it up in a table.
_PYSERIAL_QUERY: dict[str, dict[str, tuple[str, ...] | None]] = {
    "loop": {"logging": _LOG_LEVELS},
    "socket": {"logging": _LOG_LEVELS},
    "rfc2217": {
        "logging": _LOG_LEVELS,
        "ign_set_control": None,
        "poll_modem": None,
        "timeout": None,
    },
    "spy": {"file": None, "color": None, "raw": None, "all": None},
    "hwgrep": {"n": None, "skip_busy": None},
    "alt": {"class": None},
}


def _maybe_seconds(value: object, what: str) -> float | None:
    return None if value is None else seconds(value, what)


# Each option pyserial takes, with the check it gets before the port is opened.
_CHECKS: dict[str, Callable[[object, str], object]] = {
    "baudrate": lambda v, w: whole_number(v, w, 1, 100_000_000),
    "bytesize": lambda v, w: choice(v, w, (5, 6, 7, 8)),
    "parity": lambda v, w: choice(v.upper() if isinstance(v, str) else v, w, "NEOMS"),
    "stopbits": lambda v, w: choice(v, w, (1, 1.5, 2)),
    "xonxoff": flag,
    "rtscts": flag,
    "dsrdtr": flag,
    "exclusive": lambda v, w: None if v is None else flag(v, w),
    "write_timeout": _maybe_seconds,
    "inter_byte_timeout": _maybe_seconds,
}


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
    # (a port that refuses a line setting as its timeout is set raises termios.error)
    _io_errors: ClassVar[tuple[type[Exception], ...]] = (OSError, *_LINE_ERRORS)

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


def _check_url_query(url: SplitResult, target: str) -> None:
    """Refuse what pyserial's URL handler would not take in the query of ``target``."""
    known = _PYSERIAL_QUERY.get(url.scheme.lower())
    if known is None:
        return
    for key, value in parse_qsl(url.query, keep_blank_values=True):
        if key not in known:
            names = ", ".join(known) or "none"
            raise InvalidArgument(f"unknown option {key!r} in {target!r}; known: {names}")
        allowed = known[key]
        if allowed is not None:
            choice(value, f"{key} in {target!r}", allowed)


def _checked(opts: dict[str, Any]) -> dict[str, Any]:
    """The pyserial options, each checked, with this library's defaults filled in."""
    unknown = set(opts) - set(_CHECKS)
    if unknown:
        raise InvalidArgument(
            f"unknown serial option(s): {', '.join(sorted(unknown))}; "
            f"known: {', '.join(sorted(_CHECKS))}"
        )
    opts.setdefault("baudrate", DEFAULT_BAUDRATE)
    opts.setdefault("rtscts", True)
    return {key: _CHECKS[key](value, key) for key, value in opts.items()}


def open_serial(url: SplitResult, **options: object) -> SerialTransport:
    """Open a serial port or pyserial URL.

    Options (URL query or keywords): ``baudrate`` (115200), ``bytesize``, ``parity``,
    ``stopbits``, ``rtscts`` (True), ``xonxoff``, ``dsrdtr``, ``write_timeout``, ``exclusive``
    (True for a device on POSIX: a port another process holds is refused, as Windows does;
    ``exclusive=0`` shares it), ``inter_byte_timeout``.

    Raises:
        InvalidArgument: unknown option, a bad value, no port named, or line settings the
            port refuses (``bytesize=7`` on a port that only does 8).
        GalilConnectionError: the port cannot be opened, or another process holds it
            (:func:`~galil.transport.base.port_in_use` tells that case).
    """
    scheme = url.scheme.lower()
    if scheme in PYSERIAL_SCHEMES:
        # pyserial parses its own query parameters for these handlers.
        # Not url.geturl(): it drops the "//" of an empty host (spy:///dev/x -> spy:/dev/x).
        target = f"{url.scheme}://{url.netloc}{url.path}"
        if url.query:
            target += "?" + url.query
        _check_url_query(url, target)
        opts: dict[str, Any] = dict(options)  # (each checked by _checked, then pyserial)
    else:
        target = url.netloc + url.path
        opts = parse_options(url, options)
        if not target:
            raise InvalidArgument(f"no serial port in {url.geturl()!r}; e.g. serial:///dev/ttyS0")
        if sys.platform != "win32":
            # pyserial's flock(LOCK_EX | LOCK_NB) on the device: a second opener (another
            # script, `galil list`, a terminal) would read the replies meant for this one.
            # Windows opens a COM port exclusively anyway.
            opts.setdefault("exclusive", True)
    opts = _checked(opts)
    port = None
    try:
        port = serial.serial_for_url(target, timeout=0, **opts)
        # The settings once more: a port may ignore one it cannot do when it opens (a pty
        # keeps 8 data bits) and refuse it at the next change (the first read's timeout).
        port.timeout = 0
    except BaseException as exc:
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        if isinstance(exc, _LINE_ERRORS):  # the OS refused the line settings
            raise _refused(target, opts, exc) from exc
        if locked_out(exc):
            raise GalilConnectionError(
                f"cannot open serial port {target!r}: the port is in use by another process, "
                "or by another connection of this one not closed yet (an earlier connect() in "
                "a notebook, say): close that one; exclusive=0 shares the port, and then the "
                f"two read each other's replies: {exc}"
            ) from exc
        if isinstance(exc, (serial.SerialException, OSError)):
            raise GalilConnectionError(f"cannot open serial port {target!r}: {exc}") from exc
        if isinstance(exc, ValueError):  # pyserial refused a value (a query we do not check)
            raise InvalidArgument(f"cannot open serial port {target!r}: {exc}") from exc
        raise
    return SerialTransport(port, target)


def _refused(target: str, opts: dict[str, Any], exc: Exception) -> GalilError:
    """The error for line settings the OS refused: :class:`InvalidArgument` when the port
    cannot do them (``EINVAL``), else :class:`GalilConnectionError` (the port failed)."""
    code = exc.args[0] if exc.args and isinstance(exc.args[0], int) else None
    text = exc.args[1] if len(exc.args) > 1 else str(exc)
    if code == errno.EINVAL:
        settings = ", ".join(f"{k}={v}" for k, v in opts.items())
        return InvalidArgument(
            f"serial port {target!r} refused its line settings ({settings}): {text}"
        )
    return GalilConnectionError(f"cannot open serial port {target!r}: {text}")
