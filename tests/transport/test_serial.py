"""SerialTransport over a pty pair, loop://, socket:// and spy://."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from transport_peers import PtyPair, PtyResponder, TcpPeer, read_until

from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import Transport, open_transport
from galil.transport.serial import SerialTransport


def test_pty_round_trip(pty_responder: PtyResponder) -> None:
    t = open_transport(pty_responder.pair.path)
    try:
        assert isinstance(t, SerialTransport)
        assert isinstance(t, Transport)
        assert t.kind == "serial"
        assert t.secondary is None
        t.write(b"MG 3\r")
        assert read_until(t.read, b":") == b" 3\r\n:"
        t.write(b"tp\r")
        assert read_until(t.read, b"?") == b"?"
        assert pty_responder.answerer.received == b"MG 3\rtp\r"
    finally:
        t.close()


def test_serial_url_with_query(pty_pair: PtyPair) -> None:
    t = open_transport(f"serial://{pty_pair.path}?baudrate=19200&rtscts=0")
    try:
        assert isinstance(t, SerialTransport)
        assert t.port.baudrate == 19200  # type: ignore[attr-defined]
        assert not t.port.rtscts  # type: ignore[attr-defined]
        t.write(b"TPA\r")
        assert pty_pair.recv(4) == b"TPA\r"
    finally:
        t.close()


def test_keyword_options_reach_pyserial(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path, baudrate=9600)
    try:
        assert isinstance(t, SerialTransport)
        assert t.port.baudrate == 9600  # type: ignore[attr-defined]
        assert t.port.rtscts is True  # type: ignore[attr-defined]  # Galil's default handshake
    finally:
        t.close()


def test_partial_and_split_reads(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    try:
        pty_pair.send(b" 12")
        first = read_until(t.read, b"12")
        pty_pair.send(b"\r\n:")
        assert first + read_until(t.read, b":") == b" 12\r\n:"
    finally:
        t.close()


def test_read_timeout_and_poll(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    try:
        start = time.monotonic()
        assert t.read(0.05) == b""
        assert time.monotonic() - start >= 0.04
        assert t.read(0) == b""
        pty_pair.send(b":")
        assert read_until(t.read, b":") == b":"
    finally:
        t.close()


def test_master_hangup_is_a_connection_error(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    try:
        os.close(pty_pair.master)
        with pytest.raises(GalilConnectionError, match="failed while reading"):
            read_until(t.read, b":", timeout=1.0)
    finally:
        t.close()


def test_loop_url_echoes() -> None:
    t = open_transport("loop://")
    try:
        t.write(b"MG 1\r")
        assert read_until(t.read, b"\r") == b"MG 1\r"
    finally:
        t.close()


def test_socket_url_to_tcp_peer(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"socket://127.0.0.1:{tcp_peer.port}")
    try:
        assert t.kind == "serial"
        t.write(b"MG 5\r")
        assert read_until(t.read, b":") == b" 5\r\n:"
    finally:
        t.close()


def test_spy_url_logs_traffic(pty_responder: PtyResponder, tmp_path: Path) -> None:
    log = tmp_path / "spy.txt"
    t = open_transport(f"spy://{pty_responder.pair.path}?file={log}")
    try:
        t.write(b"MG 8\r")
        assert read_until(t.read, b":") == b" 8\r\n:"
    finally:
        t.close()
    text = log.read_text()
    assert "TX" in text
    assert "RX" in text


def test_closed_port_refuses(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    t.close()
    t.close()
    with pytest.raises(GalilConnectionError, match="closed"):
        t.write(b"x")
    with pytest.raises(GalilConnectionError, match="closed"):
        t.read(0)


def test_missing_device() -> None:
    with pytest.raises(GalilConnectionError, match="cannot open serial port"):
        open_transport("/dev/does-not-exist-galil")


@pytest.mark.parametrize(
    ("address", "options", "message"),
    [
        ("serial://", {}, "no serial port"),
        ("loop://", {"speed": 1}, "unknown serial option"),
        ("/dev/ttyS0", {"port": 2}, "unknown serial option"),
    ],
)
def test_bad_serial_options(address: str, options: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidArgument, match=message):
        open_transport(address, **options)
