"""Bad addresses and options are refused with InvalidArgument before any device is touched.

Every way of touching a device or the network is replaced by one that fails the test, so a
check that comes too late (or not at all) shows as an AssertionError, not as a passing test.
"""

from __future__ import annotations

import math
import os
import socket
from typing import Any

import pytest
import serial
import usb.core

from galil.errors import InvalidArgument
from galil.transport import open_transport


@pytest.fixture(autouse=True)
def no_io(monkeypatch: pytest.MonkeyPatch) -> None:
    def touched(*args: object, **kwargs: object) -> Any:
        raise AssertionError(f"I/O before validation: {args!r}")

    monkeypatch.setattr(socket, "create_connection", touched)
    monkeypatch.setattr(socket, "getaddrinfo", touched)
    monkeypatch.setattr(os, "open", touched)
    monkeypatch.setattr(serial, "serial_for_url", touched)
    monkeypatch.setattr(usb.core, "find", touched)


@pytest.mark.parametrize(
    ("address", "options", "message"),
    [
        ("tcp://[::1", {}, "malformed address"),
        ("tcp://127.0.0.1:1?connect_timeout=abc", {}, "connect_timeout"),
        ("tcp://127.0.0.1:1", {"connect_timeout": -1}, "connect_timeout"),
        ("tcp://127.0.0.1:1", {"connect_timeout": math.nan}, "connect_timeout"),
        ("tcp://127.0.0.1:1", {"connect_timeout": math.inf}, "connect_timeout"),
        ("tcp://127.0.0.1:1?connect_timeout=1e10", {}, "connect_timeout.*at most 1e\\+06"),
        ("tcp://127.0.0.1:1", {"write_timeout": 1e7}, "write_timeout.*at most"),
        ("tcp://127.0.0.1:1", {"write_timeout": 0}, "write_timeout"),
        ("tcp://127.0.0.1:1", {"port": "23"}, "TCP port"),
        ("tcp://127.0.0.1:1", {"message_port": "x"}, "message port"),
        ("tcp://127.0.0.1:p/path", {}, "port"),
        ("tcp://127.0.0.1:23/path", {}, "no path"),
        ("tcp://999.1.1.1", {}, "not an IPv4 address"),
        ("999.1.1.1", {}, "not an IPv4 address"),
        ("300.300.300.300:23", {}, "not an IPv4 address"),
        ("usb://1079:4040?interface=abc", {}, "interface"),
        ("usb://1079:4040?interface=-1", {}, "interface"),
        ("usb://1079:4040?write_timeout=nan", {}, "write_timeout"),
        ("usb://1079:4040", {"device": object()}, "device"),
        ("pci:///dev/null?write_timeout=abc", {}, "write_timeout"),
        ("pci:///dev/null", {"write_timeout": -1}, "write_timeout"),
        ("pci:///dev/null", {"write_timeout": math.nan}, "write_timeout"),
        ("loop://?bogus=1", {}, "loop://"),
        ("loop://", {"baudrate": "abc"}, "baudrate"),
        ("serial:///dev/ttyS0?baudrate=0", {}, "baudrate"),
        ("loop://", {"write_timeout": -1}, "write_timeout"),
        ("loop://", {"bytesize": 9}, "bytesize"),
        ("loop://", {"parity": "Q"}, "parity"),
        ("loop://", {"stopbits": 3}, "stopbits"),
        ("loop://", {"rtscts": "maybe"}, "rtscts"),
    ],
)
def test_a_bad_address_or_option_is_refused_before_any_io(
    address: str, options: dict[str, object], message: str
) -> None:
    with pytest.raises(InvalidArgument, match=message):
        open_transport(address, **options)
