"""What only the PCI transport does: node names, options, a driver that stops taking data.

A pty stands in for Galil's driver node. The behaviour every transport shares (round trips,
timeouts, large writes, close, a vanished peer) is in test_contract.py.
"""

from __future__ import annotations

import os
import time

import pytest
from transport_peers import PtyPair

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import open_transport
from galil.transport.base import port_in_use
from galil.transport.pci import PciTransport


def test_galilpci_node_names_pick_pci() -> None:
    # The shorthand resolves to the PCI opener; the node does not exist here.
    with pytest.raises(GalilConnectionError, match="cannot open PCI node /dev/galilpci7"):
        open_transport("/dev/galilpci7")


def test_node_that_stops_taking_data_times_out_the_write(pty_pair: PtyPair) -> None:
    # Nobody reads the master: once the pty's buffer is full the write has to wait, and gives
    # up after write_timeout.
    t = open_transport(f"pci://{pty_pair.path}", write_timeout=0.05)
    try:
        assert isinstance(t, PciTransport)
        with pytest.raises(GalilConnectionError, match=r"did not accept data within 0\.05 s"):
            t.write(b"x" * 1_000_000)
    finally:
        t.close()


def test_peer_hanging_up_says_the_node_is_gone(pty_pair: PtyPair) -> None:
    t = open_transport(f"pci://{pty_pair.path}")
    try:
        pty_pair.hang_up()
        with pytest.raises(GalilConnectionError, match=r"PCI node .* is gone"):
            t.read(1.0)
    finally:
        t.close()


def test_bad_options() -> None:
    with pytest.raises(InvalidArgument, match="unknown PCI option"):
        open_transport("/dev/galilpci0", baudrate=9600)
    with pytest.raises(InvalidArgument, match="no device node"):
        open_transport("pci://")


def test_a_node_at_end_of_file_waits_out_the_read_timeout_instead_of_spinning(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # /dev/null polls readable and reads as end of file, with no hang-up: each read used to
    # return at once, so a caller waiting for a reply spun on the CPU until its deadline.
    reads = 0
    real_read = os.read

    def counting_read(fd: int, n: int) -> bytes:
        nonlocal reads
        reads += 1
        return real_read(fd, n)

    t = open_transport("pci:///dev/null")
    monkeypatch.setattr(os, "read", counting_read)
    try:
        deadline = time.monotonic() + 0.3
        while (left := deadline - time.monotonic()) > 0:
            assert t.read(left) == b""
        assert reads < 100
    finally:
        t.close()


def test_a_node_another_opener_holds_is_refused_as_in_use(pty_pair: PtyPair) -> None:
    held = open_transport(f"pci://{pty_pair.path}")
    try:
        with pytest.raises(GalilConnectionError, match="in use by another process") as info:
            open_transport(f"pci://{pty_pair.path}")
        assert port_in_use(info.value)
        shared = open_transport(f"pci://{pty_pair.path}", exclusive=False)
        shared.close()  # exclusive=0 opens it without asking for the lock
        held.write(b"TPA\r")
        assert pty_pair.recv(4) == b"TPA\r"
    finally:
        held.close()
    open_transport(f"pci://{pty_pair.path}").close()


def test_a_bad_exclusive_option_is_refused_before_the_node_is_opened() -> None:
    with pytest.raises(InvalidArgument, match="exclusive"):
        open_transport("pci:///dev/galilpci-nosuch", exclusive="maybe")
