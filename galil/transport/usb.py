"""USB transport through pyusb bulk endpoints.

``usb://1079:4040`` picks a device by vendor and product id (hex), ``?serial=...`` narrows it
to one unit, and ``usb://`` alone takes the first device whose manufacturer string mentions
Galil. The device (``device=``) or the pyusb backend (``backend=``) can be injected, which is
how the tests drive the real pyusb code path without hardware. Controllers whose USB port is an
FTDI serial bridge appear as ``/dev/ttyUSB*`` / ``COMn``: open those as serial ports instead.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import SplitResult

import usb.core
import usb.util

from galil.errors import GalilConnectionError, InvalidArgument, unknown_options
from galil.transport import parse_options
from galil.transport.base import TransportBase
from galil.transport.options import seconds, whole_number

__all__ = ["UsbTransport", "open_usb"]

_WRITE_TIMEOUT_MS = 1000
_READ_PACKETS = 64  # packets asked for per read; a read returns early on a short packet


class UsbTransport(TransportBase[Any]):
    """Bulk IN/OUT endpoints of one interface of a pyusb device.

    Capabilities: none. The byte rate a Galil USB port sustains is not documented, so this
    transport does not claim one (:class:`~galil.transport.ByteRate`).

    Args:
        device: a ``usb.core.Device``.
        interface: interface number holding the bulk endpoints.
        write_timeout: seconds allowed for one bulk write.
    """

    kind = "usb"

    def __init__(self, device: Any, *, interface: int = 0, write_timeout: float = 1.0) -> None:
        _check_device(device)
        interface = whole_number(interface, "interface", 0, 255)
        write_ms = max(1, round(seconds(write_timeout, "write_timeout") * 1000))
        name = f"{device.idVendor:04x}:{device.idProduct:04x}"
        super().__init__(device, name=name, label=f"USB device {name}")
        self.interface = interface
        self.write_timeout_ms = write_ms
        try:
            self._detach_kernel_driver(device)
            try:
                cfg = device.get_active_configuration()
            except usb.core.USBError:
                cfg = None
            if cfg is None:
                device.set_configuration()
                cfg = device.get_active_configuration()
            intf = cfg[(interface, 0)]
            usb.util.claim_interface(device, interface)
            self._ep_out = _bulk_endpoint(intf, usb.util.ENDPOINT_OUT)
            self._ep_in = _bulk_endpoint(intf, usb.util.ENDPOINT_IN)
        except (usb.core.USBError, KeyError, IndexError, ValueError) as exc:
            self._abandon(device)
            raise GalilConnectionError(f"cannot open {self.label}: {exc}") from exc
        if self._ep_out is None or self._ep_in is None:
            self._abandon(device)
            raise GalilConnectionError(
                f"{self.label} interface {interface} has no bulk IN/OUT endpoint pair"
            )
        self._read_size = int(self._ep_in.wMaxPacketSize) * _READ_PACKETS

    def _abandon(self, device: Any) -> None:
        self._handle = None  # never opened: repr says closed, close() has nothing to do
        usb.util.dispose_resources(device)

    def _detach_kernel_driver(self, device: Any) -> None:
        try:
            if device.is_kernel_driver_active(self.interface):
                device.detach_kernel_driver(self.interface)
        except (NotImplementedError, usb.core.USBError):
            pass  # backends without kernel drivers (or not permitted): try to claim anyway

    def _send_some(self, handle: Any, data: memoryview) -> int:
        try:
            return int(self._ep_out.write(data, timeout=self.write_timeout_ms))
        except usb.core.USBTimeoutError as exc:
            raise GalilConnectionError(f"{self.label} did not accept data: {exc}") from exc

    def _recv(self, handle: Any, timeout: float) -> bytes:
        # pyusb treats 0 ms as "wait forever": a poll is 1 ms.
        ms = max(1, round(timeout * 1000))
        try:
            data = self._ep_in.read(self._read_size, timeout=ms)
        except usb.core.USBTimeoutError:
            return b""
        return bytes(data)

    def _release(self, handle: Any) -> None:
        try:
            usb.util.release_interface(handle, self.interface)
        finally:  # unplugged: nothing left to release, but pyusb's resources still go
            usb.util.dispose_resources(handle)


def _check_device(device: object) -> None:
    """Refuse a ``device=`` that is not a USB device (it has no 16-bit vendor and product ids)."""
    for attr in ("idVendor", "idProduct"):
        value = getattr(device, attr, None)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
            raise InvalidArgument(f"device must be a usb.core.Device, got {device!r}")


def _bulk_endpoint(intf: Any, direction: int) -> Any:
    def match(ep: Any) -> bool:
        return bool(
            usb.util.endpoint_direction(ep.bEndpointAddress) == direction
            and usb.util.endpoint_type(ep.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK
        )

    return usb.util.find_descriptor(intf, custom_match=match)


def _parse_ids(netloc: str) -> tuple[int | None, int | None]:
    if not netloc:
        return None, None
    parts = netloc.split(":")
    if len(parts) != 2:
        raise InvalidArgument(f"USB address must be usb://vid:pid (hex), got {netloc!r}")
    try:
        vid, pid = (int(p, 16) for p in parts)
    except ValueError as exc:
        raise InvalidArgument(f"USB vid:pid must be hex numbers, got {netloc!r}") from exc
    if not (0 <= vid <= 0xFFFF and 0 <= pid <= 0xFFFF):
        raise InvalidArgument(f"USB vid:pid out of range: {netloc!r}")
    return vid, pid


def _string(dev: Any, index: int) -> str:
    if not index:
        return ""
    try:
        return str(usb.util.get_string(dev, index) or "")
    except (usb.core.USBError, ValueError, NotImplementedError):
        return ""


def find_device(
    vid: int | None = None,
    pid: int | None = None,
    serial: str | None = None,
    *,
    backend: Any = None,
) -> Any:
    """Find one USB device by ids and serial number (a Galil one when no ids are given).

    Raises:
        GalilConnectionError: no device matches, or several do and nothing tells them apart.
    """
    kwargs: dict[str, Any] = {"find_all": True}
    if vid is not None:
        kwargs["idVendor"] = vid
        kwargs["idProduct"] = pid
    if backend is not None:
        kwargs["backend"] = backend
    try:
        candidates = list(usb.core.find(**kwargs))
    except usb.core.NoBackendError as exc:
        raise GalilConnectionError(
            "no USB backend: install libusb (e.g. the libusb-package wheel) or pass backend="
        ) from exc
    if vid is None:
        candidates = [d for d in candidates if "galil" in _string(d, d.iManufacturer).lower()]
    if serial is not None:
        candidates = [d for d in candidates if _string(d, d.iSerialNumber) == serial]
    want = f"{vid:04x}:{pid:04x}" if vid is not None and pid is not None else "a Galil device"
    if serial is not None:
        want += f" with serial {serial!r}"
    if not candidates:
        raise GalilConnectionError(f"no USB device found: looked for {want}")
    if len(candidates) > 1 and serial is None:
        serials = ", ".join(_string(d, d.iSerialNumber) or "?" for d in candidates)
        raise GalilConnectionError(
            f"{len(candidates)} USB devices match {want} (serials: {serials}); add ?serial=..."
        )
    return candidates[0]


def open_usb(url: SplitResult, **options: object) -> UsbTransport:
    """Open ``usb://[vid:pid][?serial=...&interface=0]``.

    Options: ``serial``, ``interface``, ``write_timeout``, ``backend`` (a pyusb backend),
    ``device`` (a ready ``usb.core.Device``; skips the search).

    Raises:
        InvalidArgument: malformed address, a bad value, or an unknown option.
        GalilConnectionError: no such device, or it cannot be claimed.
    """
    opts = parse_options(url, options)
    vid, pid = _parse_ids(url.netloc)
    serial = opts.pop("serial", None)
    interface = whole_number(opts.pop("interface", 0), "interface", 0, 255)
    write_timeout = seconds(opts.pop("write_timeout", 1.0), "write_timeout")
    backend = opts.pop("backend", None)
    device = opts.pop("device", None)
    if opts:
        raise unknown_options(
            "USB", opts, ("serial", "interface", "write_timeout", "backend", "device")
        )
    if device is not None:
        _check_device(device)
    if device is None:
        device = find_device(vid, pid, None if serial is None else str(serial), backend=backend)
    return UsbTransport(device, interface=interface, write_timeout=write_timeout)
