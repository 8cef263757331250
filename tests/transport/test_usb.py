"""What only the USB transport does: finding the device, claiming it, bulk transfers.

pyusb's real code runs on a fake backend (fake_usb.py). The behaviour every transport shares
(round trips, timeouts, close, an unplugged device) is in test_contract.py.
"""

from __future__ import annotations

import pytest
import usb.core
from fake_usb import FakeBackend, FakeUsbDevice
from transport_peers import LineAnswerer, read_exactly, read_until

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import open_transport
from galil.transport.usb import UsbTransport


def make_device(**kwargs: object) -> tuple[FakeUsbDevice, LineAnswerer]:
    answerer = LineAnswerer()
    return FakeUsbDevice(answerer.feed, **kwargs), answerer  # type: ignore[arg-type]


def test_configures_claims_and_releases_the_interface() -> None:
    dev, answerer = make_device()
    backend = FakeBackend(dev)
    t = open_transport("usb://1079:4040", backend=backend)
    try:
        assert isinstance(t, UsbTransport)
        assert repr(t) == "<UsbTransport 1079:4040 open>"
        assert dev.configuration == 1
        assert dev.claimed == {0}
        t.write(b"MG 77\r")
        assert read_until(t.read, b":") == b" 77\r\n:"
        assert answerer.received == b"MG 77\r"
    finally:
        t.close()
    assert dev.claimed == set()
    assert "release 0" in backend.calls
    assert dev.closed >= 1


def test_kernel_driver_is_detached_before_claiming() -> None:
    dev, _ = make_device(kernel_driver=True)
    backend = FakeBackend(dev)
    t = open_transport("usb://1079:4040", backend=backend)
    try:
        assert backend.calls.index("detach 0") < backend.calls.index("claim 0")
        t.write(b"MG 1\r")  # the fake refuses transfers while the kernel holds the interface
        assert read_until(t.read, b":") == b" 1\r\n:"
    finally:
        t.close()


def test_found_by_manufacturer_without_ids() -> None:
    other = FakeUsbDevice(lambda b: b"", vid=0x046D, pid=0xC077, manufacturer="Logitech")
    dev, _ = make_device()
    t = open_transport("usb://", backend=FakeBackend(other, dev))
    try:
        t.write(b"MG 1\r")
        assert read_until(t.read, b":") == b" 1\r\n:"
    finally:
        t.close()


def test_serial_number_picks_one_of_two() -> None:
    a, _ = make_device(serial="AAA")
    b, answerer_b = make_device(serial="BBB")
    backend = FakeBackend(a, b)
    with pytest.raises(GalilConnectionError, match=r"2 USB devices match.*AAA, BBB"):
        open_transport("usb://1079:4040", backend=backend)
    t = open_transport("usb://1079:4040?serial=BBB", backend=backend)
    try:
        t.write(b"SHA\r")
        assert read_until(t.read, b":") == b":"
        assert answerer_b.received == b"SHA\r"
    finally:
        t.close()


def test_no_matching_device() -> None:
    dev, _ = make_device()
    with pytest.raises(GalilConnectionError, match=r"no USB device found.*1079:4041"):
        open_transport("usb://1079:4041", backend=FakeBackend(dev))
    with pytest.raises(GalilConnectionError, match="serial 'ZZZ'"):
        open_transport("usb://1079:4040?serial=ZZZ", backend=FakeBackend(dev))


def test_injected_device_skips_search() -> None:
    dev, _ = make_device()
    found = usb.core.find(idVendor=0x1079, backend=FakeBackend(dev))
    t = open_transport("usb://", device=found)
    try:
        t.write(b"MG 2\r")
        assert read_until(t.read, b":") == b" 2\r\n:"
    finally:
        t.close()


def test_long_write_goes_out_in_the_pieces_the_device_takes() -> None:
    dev, answerer = make_device(max_transfer=64)
    t = open_transport("usb://1079:4040", backend=FakeBackend(dev))
    try:
        payload = b"".join(b"MG %d\r" % i for i in range(40))
        t.write(payload)
        assert answerer.received == payload
        assert dev.transfers[:-1] == [64] * (len(payload) // 64)
    finally:
        t.close()


def test_device_taking_no_bytes_is_a_connection_error() -> None:
    dev, _ = make_device(max_transfer=0)
    t = open_transport("usb://1079:4040", backend=FakeBackend(dev))
    try:
        with pytest.raises(GalilConnectionError, match="USB device 1079:4040 accepted no bytes"):
            t.write(b"MG 1\r")
    finally:
        t.close()


def test_long_reply_arrives_over_several_packets() -> None:
    long = b"x" * 1000
    dev = FakeUsbDevice(lambda data: long + b"\r\n:")
    t = open_transport("usb://1079:4040", backend=FakeBackend(dev))
    try:
        t.write(b"LS\r")
        assert read_exactly(t.read, len(long) + 3) == long + b"\r\n:"
    finally:
        t.close()


def test_unplugged_device_names_what_failed() -> None:
    dev, _ = make_device()
    t = open_transport("usb://1079:4040", backend=FakeBackend(dev))
    try:
        dev.unplugged = True
        with pytest.raises(GalilConnectionError, match="failed while sending") as sending:
            t.write(b"TP\r")
        assert isinstance(sending.value.__cause__, usb.core.USBError)
        with pytest.raises(GalilConnectionError, match="failed while reading"):
            t.read(0.01)
    finally:
        t.close()  # releasing an unplugged device does not raise


@pytest.mark.parametrize(
    ("address", "options", "message"),
    [
        ("usb://1079", {}, "usb://vid:pid"),
        ("usb://xyz:4040", {}, "hex"),
        ("usb://10000:1", {}, "out of range"),
        ("usb://1079:4040", {"baudrate": 1}, "unknown USB option"),
    ],
)
def test_bad_usb_addresses(address: str, options: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidArgument, match=message):
        open_transport(address, backend=FakeBackend(), **options)
