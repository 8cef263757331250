"""Byte transports to a controller, picked by address.

Every transport satisfies the small :class:`Transport` protocol: bytes out, bytes in with a
timeout, close. Nothing here knows about commands or replies; framing lives in
``galil.protocol`` and the pairing of the two in ``galil.link``. Optional capabilities
(:mod:`galil.transport.capabilities`) are Protocols too. The built-in transports share
:class:`galil.transport.base.TransportBase`; a plug-in need not inherit it.

Addresses are URLs whose scheme picks an opener from a registry::

    tcp://192.168.0.2[:23]          Ethernet (a bare IPv4 address means the same)
    serial:///dev/ttyUSB0?baudrate=19200, /dev/ttyS0, COM3
    socket://host:port, loop://, spy://..., rfc2217://...   any pyserial URL
    usb://[vid:pid][?serial=...]    pyusb bulk endpoints
    /dev/galilpci0, pci:///dev/galilpci0                  Galil's PCI driver node
    sim://DMC-4040                  the simulator (registered by entry point)

Other packages add schemes with :func:`register_scheme` or through the entry-point group
``galil.transports`` (name = scheme, value = ``opener(url: SplitResult, **options)``).
"""

from __future__ import annotations

import ipaddress
import re
import threading
from collections.abc import Callable, Mapping
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any, Protocol, runtime_checkable
from urllib.parse import SplitResult, parse_qsl, urlsplit

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport.base import timeout_grid

__all__ = [
    "ENTRY_POINT_GROUP",
    "ByteRate",
    "ControllerClock",
    "DatagramSource",
    "HandleSource",
    "LocalAddress",
    "MessagesOnly",
    "Opener",
    "Transport",
    "open_transport",
    "parse_options",
    "register_scheme",
    "registered_schemes",
    "split_address",
    "timeout_grid",
]

ENTRY_POINT_GROUP = "galil.transports"


@runtime_checkable
class Transport(Protocol):
    """What the client needs from a link: bytes out, bytes in, close.

    Attributes:
        secondary: a second handle carrying unsolicited messages and records, if the link has
            one (Ethernet), else ``None``.
    """

    secondary: Transport | None

    def write(self, data: bytes) -> None:
        """Send all of ``data``; raise :class:`GalilConnectionError` when the link is dead.

        (The link takes any other ``OSError`` but a timeout for a dead link too.)
        """
        ...

    def read(self, timeout: float) -> bytes:
        """Return the bytes available within ``timeout`` seconds, ``b""`` when none came.

        A ``timeout`` of 0 polls without blocking. Raises :class:`GalilConnectionError` when the
        link is closed or dead.
        """
        ...

    def close(self) -> None:
        """Release the link; further reads and writes raise :class:`GalilConnectionError`."""
        ...

    @property
    def kind(self) -> str:
        """The bus: ``"serial"``, ``"usb"``, ``"ethernet"``, ``"pci"`` or ``"sim"``."""
        ...


from galil.transport.capabilities import (  # noqa: E402 (they refer to Transport)
    ByteRate,
    ControllerClock,
    DatagramSource,
    HandleSource,
    LocalAddress,
    MessagesOnly,
)

Opener = Callable[..., Transport]
"""``opener(url: SplitResult, **options) -> Transport``."""

# Built-in schemes are resolved lazily (module path, function name) so that importing
# galil.transport never imports pyusb or pyserial before a link of that kind is opened.
_BUILTIN: dict[str, tuple[str, str]] = {
    "tcp": ("galil.transport.tcp", "open_tcp"),
    "serial": ("galil.transport.serial", "open_serial"),
    "usb": ("galil.transport.usb", "open_usb"),
    "pci": ("galil.transport.pci", "open_pci"),
}
# pyserial's own URL handlers: the whole URL goes to serial_for_url unchanged.
PYSERIAL_SCHEMES = ("socket", "loop", "spy", "rfc2217", "hwgrep", "alt", "cp2110")
for _scheme in PYSERIAL_SCHEMES:
    _BUILTIN[_scheme] = ("galil.transport.serial", "open_serial")

_registry: dict[str, Opener] = {}
_registry_lock = threading.Lock()
_entry_points_loaded = False

_SCHEME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*$")
_IPV4 = re.compile(r"^\d{1,3}(?:\.\d{1,3}){3}(?::\d{1,5})?$")
_COM = re.compile(r"^(?:\\\\\.\\)?COM\d+$", re.IGNORECASE)
_PCI_NODE = re.compile(r"^/dev/galilpci\d+$")


def register_scheme(scheme: str, opener: Opener, *, replace: bool = False) -> None:
    """Make ``scheme://...`` addresses open through ``opener``.

    Args:
        scheme: URL scheme, e.g. ``"mybus"``; case-insensitive.
        opener: ``opener(url: SplitResult, **options) -> Transport``.
        replace: allow replacing an existing registration.

    Raises:
        InvalidArgument: the scheme is malformed or already taken (and ``replace`` is false).
    """
    if not isinstance(scheme, str) or not _SCHEME_RE.match(scheme):
        raise InvalidArgument(f"not a URL scheme: {scheme!r}")
    if not callable(opener):
        raise InvalidArgument(f"opener for {scheme!r} is not callable: {opener!r}")
    key = scheme.lower()
    with _registry_lock:
        if key in _registry and not replace and _registry[key] is not opener:
            raise InvalidArgument(f"scheme {key!r} is already registered (pass replace=True)")
        _registry[key] = opener


def registered_schemes() -> list[str]:
    """Return every scheme that :func:`open_transport` understands, sorted."""
    _load_entry_points()
    with _registry_lock:
        return sorted(set(_registry) | set(_BUILTIN))


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    found = entry_points(group=ENTRY_POINT_GROUP)
    with _registry_lock:
        for ep in found:
            key = ep.name.lower()
            if key in _registry:
                continue  # an explicit register_scheme wins over an installed plugin
            # Loaded on first use: a broken plugin must not break unrelated schemes.
            _registry[key] = _LazyEntryPoint(ep.name, ep.value, ep.load)
        _entry_points_loaded = True


class _LazyEntryPoint:
    """Opener that imports its entry point on first call."""

    def __init__(self, name: str, value: str, load: Callable[[], Any]) -> None:
        self.name = name
        self.value = value
        self._load = load
        self._target: Opener | None = None

    def __call__(self, url: SplitResult, **options: Any) -> Transport:
        if self._target is None:
            try:
                self._target = self._load()
            except Exception as exc:
                raise GalilConnectionError(
                    f"transport plugin {self.name!r} ({self.value}) failed to load: {exc}"
                ) from exc
        assert self._target is not None
        return self._target(url, **options)

    def __repr__(self) -> str:
        return f"<entry point {self.name} = {self.value}>"


def _opener_for(scheme: str) -> Opener:
    with _registry_lock:
        opener = _registry.get(scheme)
    if opener is not None:
        return opener
    _load_entry_points()
    with _registry_lock:
        opener = _registry.get(scheme)
    if opener is not None:
        return opener
    if scheme in _BUILTIN:
        module, name = _BUILTIN[scheme]
        func: Opener = getattr(import_module(module), name)
        return func
    raise InvalidArgument(
        f"no transport for scheme {scheme!r}; known: {', '.join(registered_schemes())}"
    )


def split_address(address: str) -> SplitResult:
    """Turn a user address into a URL, resolving the shorthand forms.

    ``/dev/ttyUSB0`` and ``COM3`` become ``serial:``, ``/dev/galilpci0`` becomes ``pci:``,
    ``192.168.0.2[:port]`` becomes ``tcp:``.

    Raises:
        InvalidArgument: the address is empty or not understood.
    """
    if not isinstance(address, str) or not address.strip():
        raise InvalidArgument(f"empty or non-text address: {address!r}")
    text = address.strip()
    if "://" in text:
        try:
            url = urlsplit(text)
        except ValueError as exc:  # an unclosed "[" of an IPv6 host
            raise InvalidArgument(f"malformed address {address!r}: {exc}") from exc
        if not _SCHEME_RE.match(url.scheme):
            raise InvalidArgument(f"malformed address {address!r}")
        return url
    if _PCI_NODE.match(text):
        return SplitResult("pci", "", text, "", "")
    if text.startswith("/") or _COM.match(text):
        # A device path keeps its text whole in .path (Windows COM names too).
        return SplitResult("serial", "", text, "", "")
    if _IPV4.match(text):
        try:
            ipaddress.IPv4Address(text.partition(":")[0])
        except ValueError as exc:  # 999.1.1.1 is no address, and no name to look up either
            raise InvalidArgument(f"{address!r}: not an IPv4 address ({exc})") from exc
        return urlsplit("tcp://" + text)
    raise InvalidArgument(
        f"cannot tell which bus {address!r} is on; write it as a URL, e.g. tcp://{text}, "
        f"serial://{text}, usb://vid:pid or sim://DMC-4040"
    )


def parse_options(url: SplitResult, options: Mapping[str, object]) -> dict[str, object]:
    """Merge a URL's query (``?baudrate=19200&rtscts=0``) with keyword options.

    Query values are converted to ``int``, ``float`` or ``bool`` where they look like one;
    keyword options win over the query.
    """
    merged: dict[str, object] = {}
    for key, raw in parse_qsl(url.query, keep_blank_values=True):
        merged[key] = _convert(raw)
    merged.update(options)
    return merged


def _convert(raw: str) -> Any:
    low = raw.lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    for kind in (int, float):
        try:
            return kind(raw)
        except ValueError:
            pass
    return raw


def open_transport(address: str, **options: object) -> Transport:
    """Open the transport an address names.

    Args:
        address: a URL or shorthand (see the module docstring).
        **options: passed to the scheme's opener (e.g. ``baudrate=``, ``port=``,
            ``connect_timeout=``, ``backend=``).

    Raises:
        InvalidArgument: the address is not understood or names an unknown scheme.
        GalilConnectionError: the link could not be opened.
    """
    url = split_address(address)
    opener = _opener_for(url.scheme.lower())
    transport = opener(url, **options)
    if not isinstance(transport, Transport):
        raise GalilConnectionError(
            f"opener for {url.scheme!r} returned {type(transport).__name__}, not a Transport"
        )
    return transport
