"""Finding controllers: serial ports by USB ids, TCP probes, the multicast query, BOOTP requests.

All network traffic stays on 127.0.0.1: the simulator answers where a controller would.
"""

from __future__ import annotations

import ipaddress
import math
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

import galil
from galil import cli
from galil.discovery import ask_group, listen_bootp, pci_nodes, probe_hosts, serial_ports
from galil.errors import GalilConnectionError, InvalidArgument
from galil.protocol.discovery import (
    GALIL_MAC_PREFIX,
    build_bootp_request,
    parse_bootp_request,
    parse_identify_reply,
)
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.discovery import SimDiscoveryResponder, send_bootp_request
from galil.sim.server import SimPtyServer, SimTcpServer


def _port(device: str, vid: int | None, pid: int = 0, manufacturer: str = "") -> ListPortInfo:
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid = vid, pid
    info.manufacturer = manufacturer or None
    info.description = "USB serial" if vid is not None else "ttyS0"
    return info


@pytest.fixture
def pty_sim() -> object:
    with SimPtyServer() as server:
        yield server


def test_a_galil_usb_serial_port_is_listed_and_identified(
    monkeypatch: pytest.MonkeyPatch, pty_sim: SimPtyServer
) -> None:
    ports = [
        _port(pty_sim.path, 0x1079, 0x0001),
        _port("/dev/ttyS0", None),  # a motherboard port: not a controller
        _port("/dev/ttyUSB7", 0x0403, 0x6001),  # an FTDI bridge: listed, not opened
    ]
    monkeypatch.setattr(list_ports, "comports", lambda: ports)
    found = serial_ports(timeout=2.0)
    assert [f.address for f in found] == [pty_sim.path, "/dev/ttyUSB7"]
    galil_port, bridge = found
    assert galil_port.identity == pty_sim.controller.identity
    assert galil_port.likely
    assert "FTDI" in bridge.description
    assert not bridge.likely
    assert bridge.identity == ""


def test_a_port_whose_manufacturer_names_galil_is_asked(
    monkeypatch: pytest.MonkeyPatch, pty_sim: SimPtyServer
) -> None:
    monkeypatch.setattr(
        list_ports, "comports", lambda: [_port(pty_sim.path, 0x9999, 1, "Galil Motion Control")]
    )
    (found,) = serial_ports(timeout=2.0)
    assert found.identity.startswith("DMC4040")


def test_galil_list_finds_a_pty_posing_as_galil_usb_and_a_controller_over_loopback(
    monkeypatch: pytest.MonkeyPatch, pty_sim: SimPtyServer, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(list_ports, "comports", lambda: [_port(pty_sim.path, 0x1079, 2)])
    with SimTcpServer(model="DMC-30010") as tcp:
        host, port = tcp.address
        code = cli.main(["list", "--no-usb", "--no-pci", "--probe", f"{host}:{port}"])
    out = capsys.readouterr().out
    assert code == 0
    lines = out.splitlines()
    assert any(pty_sim.path in line and "DMC4040" in line for line in lines), out
    assert any(f"tcp://{host}:{port}" in line and "DMC30010" in line for line in lines), out


@pytest.mark.parametrize("command", ["list", "find"])  # find: as galil.find() is named
def test_galil_list_says_when_nothing_is_found(
    command: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    assert cli.main([command, "--no-usb", "--no-pci"]) == 1
    err = capsys.readouterr().err
    assert "no controller found" in err
    assert "Ethernet not searched" in err


def test_probing_skips_addresses_that_do_not_answer() -> None:
    with socket.socket() as closed:  # a port that nobody listens on any more
        closed.bind(("127.0.0.1", 0))
        dead_port = closed.getsockname()[1]
    with SimTcpServer() as tcp:
        host, port = tcp.address
        found = probe_hosts([f"{host}:{port}", f"{host}:{dead_port}"], timeout=1.0)
    assert [f.address for f in found] == [f"tcp://{host}:{port}"]
    assert found[0].identity == tcp.controller.identity


def test_the_multicast_query_collects_every_answer_with_the_port_it_came_from() -> None:
    first = SimController("DMC-4040", ManualClock()).identity
    with SimDiscoveryResponder(first) as responder:
        found = ask_group(*responder.address, timeout=0.3)
        port = responder.address[1]
    # (the responder answers from a port of its own, not 23: connect must be told it)
    assert [(f.address, f.identity) for f in found] == [(f"tcp://127.0.0.1:{port}", first)]
    assert responder.answered == 1


def test_find_sends_nothing_to_the_network_unless_asked(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_network(*args: object, **kwargs: object) -> None:
        raise AssertionError("find() touched the network")

    monkeypatch.setattr(list_ports, "comports", lambda: [])
    monkeypatch.setattr(socket, "create_connection", no_network)
    monkeypatch.setattr(socket.socket, "sendto", no_network)
    assert galil.find(usb=False, pci=False) == []


def test_find_asks_the_group_it_is_given() -> None:
    with SimDiscoveryResponder("DMC4020 Rev 1.2e") as responder:
        found = galil.find(
            serial=False, usb=False, pci=False, network=True, group=responder.address, timeout=0.3
        )
    assert [f.identity for f in found] == ["DMC4020 Rev 1.2e"]


def test_find_validates_before_sending_anything() -> None:
    with pytest.raises(InvalidArgument, match="not an IP address"):
        galil.find(serial=False, usb=False, pci=False, probe=["controller.lab"])
    with pytest.raises(InvalidArgument, match="more than 1024"):
        galil.find(serial=False, usb=False, pci=False, probe=["10.0.0.0/16"])
    with pytest.raises(InvalidArgument, match="timeout"):
        galil.find(serial=False, usb=False, pci=False, timeout=0)


SEARCHES: dict[str, Callable[[Any, Path], object]] = {
    "serial_ports": lambda t, _: serial_ports(timeout=t),
    "pci_nodes": lambda t, tmp: pci_nodes(pattern=str(tmp / "none*"), timeout=t),
    "probe_hosts": lambda t, _: probe_hosts(["127.0.0.1:1"], timeout=t),
    "listen_bootp": lambda t, _: listen_bootp(address=("127.0.0.1", 0), timeout=t),
    "ask_group": lambda t, _: ask_group("127.0.0.1", 1, timeout=t),
    "find": lambda t, _: galil.find(usb=False, pci=False, timeout=t),
}


@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("timeout", [math.inf, math.nan, -1, "5", True, 0, None, 3600], ids=repr)
def test_every_search_checks_its_timeout_before_it_opens_or_sends_anything(
    search: str, timeout: object, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # The rule of every timeout (galil.link.check_seconds), more than 0 and less than an hour.
    touched: list[str] = []
    monkeypatch.setattr(list_ports, "comports", lambda: touched.append("comports") or [])
    with pytest.raises(InvalidArgument, match="timeout"):
        SEARCHES[search](timeout, tmp_path)
    assert touched == []


def test_pci_nodes_are_listed_by_their_driver_names(tmp_path: Path) -> None:
    assert pci_nodes(pattern=str(tmp_path / "galilpci*")) == []
    (tmp_path / "galilpci0").write_bytes(b"")
    (found,) = pci_nodes(pattern=str(tmp_path / "galilpci*"), identify=False)
    assert found.address.endswith("galilpci0")
    assert found.kind == "pci"


def test_a_controller_asking_for_an_ip_address_is_heard() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        address = probe.getsockname()
    got = threading.Event()
    result: list[object] = []

    def listen() -> None:
        result.extend(
            listen_bootp(timeout=5.0, address=address, count=1, on_request=lambda r: got.set())
        )

    listener = threading.Thread(target=listen)
    listener.start()
    try:
        # A controller repeats its request until answered; so does the test until heard.
        for _ in range(50):
            send_bootp_request(address, serial_number=34023, family=0x00)
            if got.wait(0.1):
                break
    finally:
        listener.join(10)
    (request,) = result
    assert request.mac_text == "00:50:4C:00:84:E7"  # gclib's own example: DMC2000 serial 34023
    assert request.serial_number == 34023
    assert request.family == "DMC-2000/2100"
    assert request.dhcp


def test_listening_on_a_port_that_cannot_be_bound_says_why() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        with pytest.raises(GalilConnectionError, match="port 67"):
            listen_bootp(timeout=0.1, address=taken.getsockname())


@given(serial=st.integers(0, 0xFFFF), family=st.integers(0, 255), xid=st.integers(0, 2**32 - 1))
def test_bootp_requests_round_trip(serial: int, family: int, xid: int) -> None:
    mac = GALIL_MAC_PREFIX + bytes([family, serial >> 8, serial & 0xFF])
    request = parse_bootp_request(build_bootp_request(mac, xid))
    assert request is not None
    assert (request.mac, request.serial_number, request.xid) == (mac, serial, xid)


def test_other_packets_are_not_taken_for_a_controller() -> None:
    other_vendor = build_bootp_request(b"\x00\x11\x22\x33\x44\x55")
    assert parse_bootp_request(other_vendor) is None
    galil_request = build_bootp_request(GALIL_MAC_PREFIX + b"\x58\x00\x07")
    assert parse_bootp_request(galil_request[:100]) is None  # truncated
    reply = b"\x02" + galil_request[1:]
    assert parse_bootp_request(reply) is None  # a server's reply, not a request
    request = parse_bootp_request(build_bootp_request(GALIL_MAC_PREFIX + b"\x58\x00\x07"))
    assert request is not None
    assert (request.family, request.serial_number) == ("DMC-2105", 7)


def test_identify_replies_are_read_or_refused() -> None:
    assert parse_identify_reply(b"DMC4040 Rev 1.2f\r\n:") == "DMC4040 Rev 1.2f"
    for bad in (b"?", b"DMC4040 Rev", b"\r\n:"):
        with pytest.raises(galil.ProtocolError):
            parse_identify_reply(bad)


def test_the_simulator_answers_discovery_on_loopback_only() -> None:
    with pytest.raises(InvalidArgument):
        SimDiscoveryResponder("DMC4040 Rev 1.0", host="0.0.0.0")
    with pytest.raises(InvalidArgument):
        send_bootp_request(("192.168.1.255", 67))


def test_a_huge_network_is_refused_at_once_without_listing_its_hosts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def listed(self: object) -> object:
        raise AssertionError("the hosts of the network were listed")

    monkeypatch.setattr(ipaddress.IPv4Network, "hosts", listed)
    for spec in ("127.0.0.0/8", "127.0.0.0/12", "10.0.0.0/21"):
        with pytest.raises(InvalidArgument, match="more than 1024"):
            probe_hosts([spec])


def test_a_single_address_network_probes_that_address() -> None:
    with SimTcpServer() as tcp:
        host, port = tcp.address
        found = probe_hosts([f"{host}/32:{port}"], timeout=1.0)
    assert [f.address for f in found] == [f"tcp://{host}:{port}"]


@pytest.mark.parametrize(
    ("group", "message"),
    [
        (("127.0.0.1", 70000), "port"),
        (("127.0.0.1", "23"), "port"),
        (("127.0.0.1", True), "port"),
        (("galil.invalid", 23), "group"),
        (("127.0.0.1",), "group"),
        ("127.0.0.1:23", "group"),
    ],
)
def test_find_checks_the_group_before_opening_anything(
    monkeypatch: pytest.MonkeyPatch, group: object, message: str
) -> None:
    def touched(*args: object, **kwargs: object) -> None:
        raise AssertionError("find() opened something before checking its arguments")

    monkeypatch.setattr(list_ports, "comports", touched)
    monkeypatch.setattr("glob.glob", touched)
    monkeypatch.setattr(socket, "getaddrinfo", touched)
    monkeypatch.setattr(socket.socket, "sendto", touched)
    with pytest.raises(InvalidArgument, match=message):
        galil.find(network=True, group=group)  # type: ignore[arg-type]


def test_find_checks_the_bootp_address_before_opening_anything(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def touched(*args: object, **kwargs: object) -> None:
        raise AssertionError("find() opened something before checking its arguments")

    monkeypatch.setattr(list_ports, "comports", touched)
    monkeypatch.setattr(socket.socket, "bind", touched)
    with pytest.raises(InvalidArgument, match="port"):
        galil.find(usb=False, pci=False, bootp=True, bootp_address=("127.0.0.1", 70000))


def test_ask_group_refuses_a_port_out_of_range() -> None:
    with pytest.raises(InvalidArgument, match="port"):
        ask_group("127.0.0.1", 70000, timeout=0.1)


def test_listen_bootp_refuses_a_port_out_of_range() -> None:
    with pytest.raises(InvalidArgument, match="port"):
        listen_bootp(timeout=0.1, address=("127.0.0.1", 70000))


class _Peer:
    """A TCP peer on ``family``'s loopback that answers every connection with ``answer``
    (once, or for ever with ``flood``), counting the connections."""

    def __init__(self, answer: bytes, *, flood: bool = False, family: int = socket.AF_INET):
        self.server = socket.socket(family)
        self.server.bind(("::1" if family == socket.AF_INET6 else "127.0.0.1", 0))
        self.server.listen()
        self.port = self.server.getsockname()[1]
        self._answer, self._flood = answer, flood
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        try:
            conn, _ = self.server.accept()
        except OSError:
            return
        with conn:
            try:
                conn.recv(16)
                conn.sendall(self._answer)
                while self._flood:
                    conn.sendall(self._answer)
            except OSError:
                return  # (the client closed)

    def close(self) -> None:
        self.server.close()
        self._thread.join(5)


def test_a_peer_that_floods_the_identify_read_is_left_soon() -> None:
    peer = _Peer(b"x" * 65536, flood=True)
    try:
        began = time.monotonic()
        assert probe_hosts([f"127.0.0.1:{peer.port}"], timeout=10.0) == []
        assert time.monotonic() - began < 5.0  # (not the whole 10 s, keeping all it sent)
    finally:
        peer.close()


def test_an_ipv6_address_is_listed_as_connect_takes_it() -> None:
    peer = _Peer(b"DMC4040 Rev 1.2f\r\n:", family=socket.AF_INET6)
    try:
        found = probe_hosts([f"[::1]:{peer.port}"], timeout=2.0)
    finally:
        peer.close()
    assert [f.address for f in found] == [f"tcp://[::1]:{peer.port}"]
    assert found[0].identity == "DMC4040 Rev 1.2f"
    with pytest.raises(GalilConnectionError, match="cannot connect"):
        galil.connect(found[0].address, timeout=0.5)  # (read as an address: no "bad port")


def test_a_serial_port_another_process_holds_is_listed_as_in_use_and_not_asked(
    monkeypatch: pytest.MonkeyPatch, pty_sim: SimPtyServer
) -> None:
    monkeypatch.setattr(list_ports, "comports", lambda: [_port(pty_sim.path, 0x1079, 1)])
    with galil.connect(pty_sim.path, timeout=2.0) as dmc:
        (found,) = serial_ports(timeout=0.5)
        assert found.identity == ""
        assert "in use by another process" in found.description
        assert dmc.query_number("MG 11") == 11.0  # (its replies were not read by the asker)
    (found,) = serial_ports(timeout=2.0)  # free again
    assert found.identity == pty_sim.controller.identity


def test_a_pci_node_another_process_holds_is_listed_as_in_use(pty_sim: SimPtyServer) -> None:
    with galil.connect(f"pci://{pty_sim.path}", timeout=2.0):
        (found,) = pci_nodes(pattern=pty_sim.path, timeout=0.5)
    assert (found.identity, found.kind) == ("", "pci")
    assert "in use by another process" in found.description


@pytest.mark.parametrize(
    "answer",
    [
        b"\xff\xfd\x18\xff\xfd\x20Ubuntu 22.04 LTS\r\nfactory-gw login: ",
        b"Password:",
        b"220 ftp ready\r\nName:",
    ],
)
def test_a_device_that_is_no_controller_is_not_listed_by_a_probe(answer: bytes) -> None:
    peer = _Peer(answer)
    try:
        assert probe_hosts([f"127.0.0.1:{peer.port}"], timeout=2.0) == []
    finally:
        peer.close()
    with pytest.raises(galil.ProtocolError, match="no Galil identity"):
        parse_identify_reply(answer)


def test_galil_list_probe_lists_no_telnet_login_as_a_controller(
    capsys: pytest.CaptureFixture[str],
) -> None:
    peer = _Peer(b"\xff\xfd\x18\xff\xfd\x20Ubuntu 22.04 LTS\r\nfactory-gw login: ")
    try:
        code = cli.main(
            ["list", "--no-serial", "--no-usb", "--no-pci", "--probe", f"127.0.0.1:{peer.port}"]
        )
    finally:
        peer.close()
    assert code == 1
    assert "factory-gw" not in capsys.readouterr().out


def test_a_multicast_answer_that_is_no_identity_is_not_listed() -> None:
    with SimDiscoveryResponder("factory-gw login") as responder:
        assert ask_group(*responder.address, timeout=0.3) == []
