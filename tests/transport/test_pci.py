"""PciTransport against a pty standing in for Galil's driver node."""

from __future__ import annotations

import os
import time

import pytest
from transport_peers import PtyPair, PtyResponder, read_until

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import Transport, open_transport
from galil.transport.pci import PciTransport


def test_round_trip(pty_responder: PtyResponder) -> None:
    t = open_transport(f"pci://{pty_responder.pair.path}")
    try:
        assert isinstance(t, PciTransport)
        assert isinstance(t, Transport)
        assert t.kind == "pci"
        assert t.secondary is None
        t.write(b"MG 11\rSHA\r")
        assert read_until(t.read, b"\r\n::") == b" 11\r\n::"
    finally:
        t.close()


def test_galilpci_node_names_pick_pci() -> None:
    # The shorthand resolves to the PCI opener; the node does not exist here.
    with pytest.raises(GalilConnectionError, match="cannot open PCI node /dev/galilpci7"):
        open_transport("/dev/galilpci7")


def test_large_write_goes_through(pty_pair: PtyPair) -> None:
    t = open_transport(f"pci://{pty_pair.path}")
    try:
        payload = b"".join(b"MG %d\r" % i for i in range(300))
        t.write(payload)
        assert pty_pair.recv(len(payload)) == payload
    finally:
        t.close()


def test_read_timeout_poll_and_data(pty_pair: PtyPair) -> None:
    t = open_transport(f"pci://{pty_pair.path}")
    try:
        start = time.monotonic()
        assert t.read(0.05) == b""
        assert time.monotonic() - start >= 0.04
        assert t.read(0) == b""
        pty_pair.send(b" 1.0000\r\n:")
        assert read_until(t.read, b":") == b" 1.0000\r\n:"
    finally:
        t.close()


def test_peer_gone_is_a_connection_error(pty_pair: PtyPair) -> None:
    t = open_transport(f"pci://{pty_pair.path}")
    try:
        os.close(pty_pair.master)
        with pytest.raises(GalilConnectionError, match="gone"):
            read_until(t.read, b":", timeout=1.0)
    finally:
        t.close()


def test_closed_node_refuses(pty_pair: PtyPair) -> None:
    t = open_transport(f"pci://{pty_pair.path}")
    t.close()
    t.close()
    with pytest.raises(GalilConnectionError, match="closed"):
        t.write(b"x")
    with pytest.raises(GalilConnectionError, match="closed"):
        t.read(0)


def test_bad_options() -> None:
    with pytest.raises(InvalidArgument, match="unknown PCI option"):
        open_transport("/dev/galilpci0", baudrate=9600)
    with pytest.raises(InvalidArgument, match="no device node"):
        open_transport("pci://")
