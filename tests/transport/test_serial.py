"""What only the serial transport does: pyserial URLs and options, the line's byte rate.

The behaviour every transport shares (round trips, timeouts, close, a vanished peer) is in
test_contract.py, over a pty and loop://.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from transport_peers import PtyPair, PtyResponder, TcpPeer, read_until

import galil
from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim.server import SimPtyServer
from galil.transport import open_transport
from galil.transport.base import port_in_use
from galil.transport.serial import SerialTransport


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


@pytest.mark.parametrize(("baudrate", "byte_rate"), [(9600, 960.0), (115200, 11520.0)])
def test_byte_rate_follows_the_baud_rate(
    pty_pair: PtyPair, baudrate: int, byte_rate: float
) -> None:
    t = open_transport(pty_pair.path, baudrate=baudrate)
    try:
        assert isinstance(t, SerialTransport)
        assert t.byte_rate == byte_rate  # 10 bits a byte: start, 8 data, stop
    finally:
        t.close()


def test_reply_split_in_time_is_read_in_parts(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    try:
        pty_pair.send(b" 12")
        first = read_until(t.read, b"12")
        pty_pair.send(b"\r\n:")
        assert first + read_until(t.read, b":") == b" 12\r\n:"
    finally:
        t.close()


def test_closed_port_is_not_offered(pty_pair: PtyPair) -> None:
    t = open_transport(pty_pair.path)
    assert isinstance(t, SerialTransport)
    t.close()
    with pytest.raises(GalilConnectionError, match=r"serial port .* is closed"):
        _ = t.port


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


@pytest.mark.skipif(sys.platform == "win32", reason="a pty and termios")
@pytest.mark.parametrize("bytesize", [6, 7])
def test_line_settings_the_port_cannot_do_are_refused_with_a_galil_error(
    pty_pair: PtyPair, bytesize: int
) -> None:
    # (a pty keeps 8 data bits: the OS refuses the others, with termios.error, no OSError)
    with pytest.raises(InvalidArgument, match="refused its line settings") as info:
        open_transport(f"serial://{pty_pair.path}?bytesize={bytesize}")
    assert f"bytesize={bytesize}" in str(info.value)


class _Refusing:
    """A port whose line settings the OS refuses as its read timeout changes."""

    in_waiting = 0
    name = "/dev/ttyFAKE"

    def __init__(self) -> None:
        self._timeout: float | None = 0.0

    @property
    def timeout(self) -> float | None:
        return self._timeout

    @timeout.setter
    def timeout(self, value: float | None) -> None:
        import termios

        raise termios.error(22, "Invalid argument")

    def read(self, size: int = 1) -> bytes:
        return b""

    def write(self, data: bytes, /) -> int | None:
        return len(data)

    def close(self) -> None:
        pass


@pytest.mark.skipif(sys.platform == "win32", reason="termios")
def test_a_port_refusing_its_settings_as_it_reads_fails_as_a_dead_link() -> None:
    t = SerialTransport(_Refusing())
    with pytest.raises(GalilConnectionError, match="failed while reading"):
        t.read(0.5)


def test_a_port_another_opener_holds_is_refused_as_in_use_and_the_holder_keeps_it(
    pty_pair: PtyPair,
) -> None:
    held = open_transport(pty_pair.path)
    try:
        with pytest.raises(GalilConnectionError, match="in use by another process") as info:
            open_transport(pty_pair.path)
        assert port_in_use(info.value)
        assert "another connection of this one" in str(info.value)  # (as here: same process)
        with pytest.raises(GalilConnectionError, match="in use by another process"):
            open_transport(f"serial://{pty_pair.path}?baudrate=9600")
        # the holder's replies still reach the holder
        held.write(b"MG 5\r")
        assert pty_pair.recv(5) == b"MG 5\r"
        pty_pair.send(b" 5\r\n:")
        assert read_until(held.read, b":") == b" 5\r\n:"
    finally:
        held.close()
    open_transport(pty_pair.path).close()  # free again once the holder closed it


def test_exclusive_0_shares_a_port_as_before(pty_pair: PtyPair) -> None:
    first = open_transport(pty_pair.path, exclusive=False)
    try:
        second = open_transport(f"serial://{pty_pair.path}?exclusive=0")
        assert isinstance(second, SerialTransport)
        assert second.port.exclusive is False  # type: ignore[attr-defined]
        second.close()
    finally:
        first.close()


def test_a_missing_port_is_not_reported_as_in_use() -> None:
    with pytest.raises(GalilConnectionError, match="cannot open serial port") as info:
        open_transport("/dev/ttyGALILNOSUCH9")
    assert not port_in_use(info.value)
    assert "in use" not in str(info.value)


def test_a_second_connect_to_a_controllers_port_is_refused_and_the_first_keeps_working() -> None:
    with SimPtyServer() as server, galil.connect(server.path, timeout=2.0) as dmc:
        with pytest.raises(GalilConnectionError, match="in use by another process") as info:
            galil.connect(server.path, timeout=2.0)
        assert port_in_use(info.value)
        assert dmc.query_number("MG 7") == 7.0
