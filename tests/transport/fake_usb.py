"""A fake pyusb backend: a real ``usb.backend.IBackend`` wired to an in-process peer.

pyusb's own code (``usb.core.find``, descriptors, ``set_configuration``, interface claiming,
bulk transfers, string descriptors) runs unchanged on top of it; only the bottom layer, which
would talk to libusb, answers from a Python object instead.
"""

from __future__ import annotations

import errno
import threading
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import usb.backend
import usb.core

EP_OUT = 0x02
EP_IN = 0x81
PACKET = 64


class FakeUsbDevice:
    """One device: descriptors, strings and a byte peer behind its bulk endpoints.

    Args:
        respond: called with the bytes of each bulk OUT transfer; returns bytes to queue on IN.
        poll: called while a bulk IN read waits; returns bytes that appeared meanwhile.
        max_transfer: the most bytes one bulk OUT transfer takes (None: all), so that a host
            has to send a long write in pieces.
        kernel_driver: a kernel driver holds interface 0 until the host detaches it.
    """

    def __init__(
        self,
        respond: Callable[[bytes], bytes],
        *,
        vid: int = 0x1079,
        pid: int = 0x4040,
        manufacturer: str = "Galil Motion Control",
        serial: str = "SN0001",
        poll: Callable[[], bytes] | None = None,
        max_transfer: int | None = None,
        kernel_driver: bool = False,
    ) -> None:
        self.respond = respond
        self.poll = poll
        self.vid = vid
        self.pid = pid
        self.strings = {1: manufacturer, 2: "DMC fake", 3: serial}
        self.inbox = bytearray()
        self.cond = threading.Condition()
        self.configuration = 0
        self.claimed: set[int] = set()
        self.opened = 0
        self.closed = 0
        self.unplugged = False
        self.max_transfer = max_transfer
        self.transfers: list[int] = []  # sizes of the bulk OUT transfers taken
        self.kernel_driver = kernel_driver

    def push(self, data: bytes) -> None:
        with self.cond:
            self.inbox += data
            self.cond.notify_all()


class FakeBackend(usb.backend.IBackend):  # type: ignore[misc]
    """Serves :class:`FakeUsbDevice` objects to pyusb."""

    def __init__(self, *devices: FakeUsbDevice) -> None:
        super().__init__()
        self.devices = list(devices)
        self.calls: list[str] = []

    def enumerate_devices(self) -> Any:
        yield from self.devices

    def get_device_descriptor(self, dev: FakeUsbDevice) -> Any:
        return SimpleNamespace(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0200,
            bDeviceClass=0,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=dev.vid,
            idProduct=dev.pid,
            bcdDevice=0x0100,
            iManufacturer=1,
            iProduct=2,
            iSerialNumber=3,
            bNumConfigurations=1,
            address=self.devices.index(dev) + 1,
            bus=1,
            port_number=1,
            port_numbers=(1,),
            speed=3,
        )

    def get_configuration_descriptor(self, dev: FakeUsbDevice, config: int) -> Any:
        return SimpleNamespace(
            bLength=9,
            bDescriptorType=2,
            wTotalLength=32,
            bNumInterfaces=1,
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=50,
            extra_descriptors=[],
        )

    def get_interface_descriptor(self, dev: FakeUsbDevice, intf: int, alt: int, config: int) -> Any:
        if intf != 0 or alt != 0:
            raise IndexError("no such interface")
        return SimpleNamespace(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=0,
            bAlternateSetting=0,
            bNumEndpoints=2,
            bInterfaceClass=0xFF,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
            extra_descriptors=[],
        )

    def get_endpoint_descriptor(
        self, dev: FakeUsbDevice, ep: int, intf: int, alt: int, config: int
    ) -> Any:
        address = (EP_OUT, EP_IN)[ep]
        return SimpleNamespace(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=address,
            bmAttributes=0x02,  # bulk
            wMaxPacketSize=PACKET,
            bInterval=0,
            bRefresh=0,
            bSynchAddress=0,
            extra_descriptors=[],
        )

    def open_device(self, dev: FakeUsbDevice) -> FakeUsbDevice:
        self.calls.append("open")
        dev.opened += 1
        return dev

    def close_device(self, dev_handle: FakeUsbDevice) -> None:
        self.calls.append("close")
        dev_handle.closed += 1

    def set_configuration(self, dev_handle: FakeUsbDevice, config_value: int) -> None:
        self.calls.append(f"set_configuration {config_value}")
        dev_handle.configuration = config_value

    def get_configuration(self, dev_handle: FakeUsbDevice) -> int:
        return dev_handle.configuration

    def claim_interface(self, dev_handle: FakeUsbDevice, intf: int) -> None:
        self.calls.append(f"claim {intf}")
        dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: FakeUsbDevice, intf: int) -> None:
        self.calls.append(f"release {intf}")
        dev_handle.claimed.discard(intf)

    def _check_alive(self, dev: FakeUsbDevice) -> None:
        if dev.unplugged:
            raise usb.core.USBError("No such device", errno.ENODEV, -4)

    def bulk_write(
        self, dev_handle: FakeUsbDevice, ep: int, intf: int, data: Any, timeout: int
    ) -> int:
        self._check_alive(dev_handle)
        assert ep == EP_OUT, ep
        assert intf in dev_handle.claimed, "bulk write on an unclaimed interface"
        assert not dev_handle.kernel_driver, "bulk write while the kernel driver holds it"
        piece = bytes(data[: dev_handle.max_transfer])
        dev_handle.transfers.append(len(piece))
        reply = dev_handle.respond(piece)
        if reply:
            dev_handle.push(reply)
        return len(piece)

    def bulk_read(
        self, dev_handle: FakeUsbDevice, ep: int, intf: int, buff: Any, timeout: int
    ) -> int:
        assert ep == EP_IN, ep
        assert timeout > 0, "pyusb reads with timeout 0 block forever"
        with dev_handle.cond:
            deadline = timeout / 1000.0
            waited = 0.0
            step = 0.002
            while not dev_handle.inbox:
                self._check_alive(dev_handle)
                if dev_handle.poll is not None:
                    extra = dev_handle.poll()
                    if extra:
                        dev_handle.inbox += extra
                        break
                if waited >= deadline:
                    raise usb.core.USBTimeoutError("Operation timed out", errno.ETIMEDOUT, -7)
                dev_handle.cond.wait(step)
                waited += step
            n = min(len(buff), len(dev_handle.inbox))
            memoryview(buff)[:n] = dev_handle.inbox[:n]
            del dev_handle.inbox[:n]
            return n

    def ctrl_transfer(
        self,
        dev_handle: FakeUsbDevice,
        request_type: int,
        request: int,
        value: int,
        index: int,
        data: Any,
        timeout: int,
    ) -> int:
        # Only GET_DESCRIPTOR(STRING) is needed, for manufacturer and serial number look-ups.
        if request != 6 or (value >> 8) != 3:
            raise usb.core.USBError("Pipe error", errno.EPIPE, -9)
        index = value & 0xFF
        if index == 0:
            desc = bytes([4, 3, 0x09, 0x04])  # one language: en-US
        else:
            text = dev_handle.strings[index].encode("utf-16-le")
            desc = bytes([2 + len(text), 3]) + text
        n = min(len(data), len(desc))
        memoryview(data)[:n] = desc[:n]
        return n

    def is_kernel_driver_active(self, dev_handle: FakeUsbDevice, intf: int) -> bool:
        return dev_handle.kernel_driver and intf == 0

    def detach_kernel_driver(self, dev_handle: FakeUsbDevice, intf: int) -> None:
        self.calls.append(f"detach {intf}")
        dev_handle.kernel_driver = False
