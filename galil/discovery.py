"""Finding controllers: ``galil.find()`` and ``galil list``.

Where it looks, and how sure each way is (sources in ``docs/decisions/0010``):

- **Serial ports** (pyserial's ``list_ports``): ports whose USB vendor id is Galil's (0x1079,
  as given to this project; not in the public USB id list) or whose manufacturer or
  description names Galil are listed and asked ``^R^V``; ports of common USB-serial bridges
  (FTDI, Prolific, Silicon Labs, WCH) are listed as *possible* and only opened when asked
  (``identify_bridges=True``), since opening a port can reset the device behind it. A port
  (or PCI node) another process holds is listed as in use and not asked: it is opened
  exclusively, and a second opener would read the replies meant for the first.
- **USB** (pyusb, needs libusb): devices with Galil's vendor id, listed, not opened.
- **PCI**: the nodes of Galil's driver, ``/dev/galilpci*``, opened and asked ``^R^V``.
- **Ethernet, by address**: ``probe=["192.168.0.0/24", "10.0.0.5:23"]`` connects to TCP port
  23 and asks ``^R^V`` (documented: the command port and the identity query).
- **Ethernet, the LAN** (``network=True``): ``^R^V`` in one UDP datagram to Galil's multicast
  group 239.255.19.56, port 23, and every answer within ``timeout``. The group is documented;
  that Galil's own tools find controllers this way is not (their wire format is unpublished).
- **Controllers without an IP address** (``bootp=True``): listens on UDP port 67 for the
  BOOTP/DHCP requests they broadcast (needs root or CAP_NET_BIND_SERVICE on Linux). This
  library does not assign addresses: use ``IA`` over serial or USB, or a DHCP reservation.
"""

from __future__ import annotations

import contextlib
import glob
import ipaddress
import socket
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from galil.errors import GalilConnectionError, GalilError, InvalidArgument, ProtocolError
from galil.link import check_callable, check_count, check_flag, check_items, check_seconds
from galil.portnumber import check_port
from galil.protocol.discovery import (
    BOOTP_SERVER_PORT,
    COMMAND_PORT,
    IDENTIFY,
    MULTICAST_GROUP,
    BootpRequest,
    parse_bootp_request,
    parse_identify_reply,
)
from galil.transport import Transport, open_transport
from galil.transport.base import port_in_use
from galil.transport.tcp import TcpTransport

__all__ = [
    "GALIL_USB_VENDOR_ID",
    "USB_SERIAL_BRIDGES",
    "Found",
    "ask_group",
    "find",
    "listen_bootp",
    "pci_nodes",
    "probe_hosts",
    "serial_ports",
    "usb_devices",
]

#: Galil's USB vendor id as given to this project (unconfirmed: not in the public USB id list).
GALIL_USB_VENDOR_ID = 0x1079
#: Vendor ids of the USB-serial bridges commonly found between a PC and a controller's RS-232.
USB_SERIAL_BRIDGES = {
    0x0403: "FTDI",
    0x067B: "Prolific",
    0x10C4: "Silicon Labs",
    0x1A86: "WCH",
}
_MAX_HOSTS = 1024
#: The most bytes an answer to ``^R^V`` is read for: an identity is a line of some 30
#: (``DMC4040 Rev 1.2f``), a controller that echoes sends it twice.
_IDENTIFY_MOST = 1024
_PCI_GLOB = "/dev/galilpci*"


@dataclass(frozen=True)
class Found:
    """One controller (or a place one may be).

    Attributes:
        address: what :func:`galil.connect` takes (``""`` for a controller with no IP yet).
        kind: ``"serial"``, ``"usb"``, ``"pci"``, ``"ethernet"`` or ``"bootp"``.
        description: what the operating system or the network says about it.
        identity: the controller's answer to ``^R^V`` (``DMC4040 Rev 1.2f``), ``""`` if not
            asked or no answer.
        likely: ``False`` for a place a controller may be but nothing says one is (a
            USB-serial bridge that was not asked).
    """

    address: str
    kind: str
    description: str
    identity: str = ""
    likely: bool = True

    def __str__(self) -> str:
        what = self.identity or self.description
        if self.identity and self.description:
            what = f"{self.identity} ({self.description})"
        return f"{self.address or '(no address)':<28} {self.kind:<8} {what}"


# ----------------------------------------------------------------------------------- asking


def _ask_transport(transport: Transport, timeout: float) -> str:
    """Write ``^R^V`` on an open transport and return the identity (``""`` if none: no
    answer in time, or more than :data:`_IDENTIFY_MOST` bytes, no Galil's)."""
    try:
        transport.write(IDENTIFY)
        got = bytearray()
        deadline = time.monotonic() + timeout
        while not got.rstrip().endswith((b":", b"?")):
            left = deadline - time.monotonic()
            if left <= 0 or len(got) > _IDENTIFY_MOST:
                return ""  # (a peer that floods is no controller: nothing more is kept)
            got += transport.read(left)
        return parse_identify_reply(bytes(got))
    except (GalilError, OSError):
        return ""
    finally:
        with contextlib.suppress(GalilError, OSError):
            transport.close()


#: What a port or node another process holds is listed with (it is not asked).
_BUSY = "in use by another process (or a connection of this one), not asked"


def _identify_address(address: str, timeout: float) -> tuple[str, bool]:
    """(identity, busy): what the device at ``address`` answers to ``^R^V``, and whether it
    was not asked because another process holds it (opened exclusively: a second opener
    would read, and steal, the replies meant for that process)."""
    try:
        transport = open_transport(address)
    except (GalilError, OSError) as exc:
        return "", port_in_use(exc)
    return _ask_transport(transport, timeout), False


def _described(description: str, busy: bool) -> str:
    return f"{description} ({_BUSY})" if busy else description


def _ask_tcp(host: str, port: int, timeout: float) -> str:
    try:
        transport = TcpTransport(host, port, connect_timeout=timeout)
    except (GalilError, OSError):
        return ""
    return _ask_transport(transport, timeout)


# ----------------------------------------------------------------------------------- buses


def _comports() -> list[Any]:
    from serial.tools import list_ports

    return list(list_ports.comports())


def serial_ports(
    *, identify: bool = True, identify_bridges: bool = False, timeout: float = 1.0
) -> list[Found]:
    """Serial ports that are (or may be) a controller, from pyserial's ``list_ports``.

    Raises:
        InvalidArgument: a bad timeout (before any port is opened).
    """
    timeout = _check_seconds(timeout, "timeout")
    check_flag(identify, "identify")
    check_flag(identify_bridges, "identify_bridges")
    out: list[Found] = []
    for port in _comports():
        vid = getattr(port, "vid", None)
        text = " ".join(
            str(getattr(port, k, "") or "") for k in ("manufacturer", "description", "product")
        )
        ids = f"USB {vid:04x}:{port.pid or 0:04x}" if vid is not None else ""
        if vid == GALIL_USB_VENDOR_ID or "galil" in text.lower():
            label = ", ".join(x for x in (ids, text.strip()) if x)
            ident, busy = _identify_address(port.device, timeout) if identify else ("", False)
            what = _described(f"Galil USB serial port {label}", busy)
            out.append(Found(port.device, "serial", what, ident))
        elif vid in USB_SERIAL_BRIDGES:
            bridge = f"{USB_SERIAL_BRIDGES[vid]} USB-serial bridge ({ids})"
            asked = _identify_address(port.device, timeout) if identify_bridges else ("", False)
            ident, busy = asked
            what = _described(bridge, busy)
            out.append(Found(port.device, "serial", what, ident, likely=bool(ident)))
    return out


def usb_devices(*, backend: object = None) -> list[Found]:
    """USB devices with Galil's vendor id (pyusb; empty when no libusb backend is found).

    Raises:
        InvalidArgument: ``backend`` is not a pyusb backend.
    """
    if backend is not None and not callable(getattr(backend, "enumerate_devices", None)):
        raise InvalidArgument(f"backend must be a pyusb backend, not {backend!r:.60}")
    try:
        import usb.core
    except ImportError:  # pragma: no cover - pyusb is a dependency
        return []
    kwargs: dict[str, Any] = {"find_all": True, "idVendor": GALIL_USB_VENDOR_ID}
    if backend is not None:
        kwargs["backend"] = backend
    try:
        devices = list(usb.core.find(**kwargs))
    except (usb.core.NoBackendError, usb.core.USBError, OSError):
        return []
    return [
        Found(
            f"usb://{d.idVendor:04x}:{d.idProduct:04x}",
            "usb",
            f"USB bus {getattr(d, 'bus', '?')} device {getattr(d, 'address', '?')}",
        )
        for d in devices
    ]


def pci_nodes(
    *, pattern: str = _PCI_GLOB, identify: bool = True, timeout: float = 1.0
) -> list[Found]:
    """The device nodes of Galil's PCI driver (``/dev/galilpci0`` ...).

    Raises:
        InvalidArgument: a bad timeout (before any node is opened).
    """
    timeout = _check_seconds(timeout, "timeout")
    check_flag(identify, "identify")
    if not isinstance(pattern, str):
        raise InvalidArgument(f"pattern must be a glob pattern, not {pattern!r:.60}")
    out = []
    for path in sorted(glob.glob(pattern)):
        ident, busy = _identify_address(path, timeout) if identify else ("", False)
        out.append(Found(path, "pci", _described("Galil PCI driver node", busy), ident))
    return out


# ----------------------------------------------------------------------------------- Ethernet


def _targets(specs: Iterable[str] | str) -> list[tuple[str, int]]:
    """``"10.0.0.5"``, ``"10.0.0.5:23"``, ``"10.0.0.0/24"``, ``"::1"``, ``"[::1]:23"`` (one,
    or a list) -> (host, port) pairs.

    Raises:
        InvalidArgument: a spec that is none of these, not a list of them, or more than 1024
            hosts in all.
    """
    out: list[tuple[str, int]] = []
    for spec in [specs] if isinstance(specs, str) else check_items(specs, "probe"):
        if not isinstance(spec, str) or not spec.strip():
            raise InvalidArgument(f"not an address to probe: {spec!r}")
        text = spec.strip()
        host, port = text, COMMAND_PORT
        port_text = None
        if text.startswith("[") and "]" in text:  # [::1] or [::1]:23, as in a URL
            host, _, rest = text[1:].partition("]")
            if rest:
                if not rest.startswith(":"):
                    raise InvalidArgument(f"bad port in {spec!r}")
                port_text = rest[1:]
        elif text.count(":") == 1:
            host, _, port_text = text.partition(":")
        if port_text is not None:
            if not port_text.isdigit():
                raise InvalidArgument(f"bad port in {spec!r}")
            port = check_port(int(port_text), f"the port in {spec!r}")
        out += [(h, port) for h in _hosts(host, spec, _MAX_HOSTS - len(out))]
    return out


def _hosts(text: str, spec: str, room: int) -> list[str]:
    """The addresses ``text`` (an address or a network) names; more than ``room`` is refused.

    The size of a network is checked before its hosts are listed: a /8 has 16 million.
    """
    try:
        net = ipaddress.ip_network(text, strict=False)
    except ValueError as exc:
        raise InvalidArgument(f"not an IP address or network: {spec!r}") from exc
    # hosts() leaves out at most two addresses (the network's own and its broadcast).
    if net.num_addresses - 2 > room:
        raise InvalidArgument(f"more than {_MAX_HOSTS} addresses to probe; narrow the range")
    # 10.0.0.5 or 10.0.0.5/32: that address, without the prefix.
    single = net.num_addresses == 1
    hosts = [str(net.network_address)] if single else [str(h) for h in net.hosts()]
    if len(hosts) > room:
        raise InvalidArgument(f"more than {_MAX_HOSTS} addresses to probe; narrow the range")
    return hosts


def probe_hosts(specs: Iterable[str], *, timeout: float = 1.0) -> list[Found]:
    """Ask each address (or every host of a network) ``^R^V`` over TCP; return who answered.

    Raises:
        InvalidArgument: an address that cannot be read, too many of them, or a bad timeout.
    """
    timeout = _check_seconds(timeout, "timeout")
    targets = _targets(specs)
    if not targets:
        return []
    with ThreadPoolExecutor(max_workers=min(64, len(targets))) as pool:
        answers = list(pool.map(lambda hp: _ask_tcp(hp[0], hp[1], timeout), targets))
    return [
        Found(_tcp_address(host, port), "ethernet", "answered on TCP", ident)
        for (host, port), ident in zip(targets, answers, strict=True)
        if ident
    ]


def _tcp_address(host: str, port: int) -> str:
    """The address :func:`galil.connect` takes: an IPv6 address in brackets
    (``tcp://[::1]:23``: without them its colons would read as a port)."""
    where = f"[{host}]" if ":" in host else host
    return f"tcp://{where}" if port == COMMAND_PORT else f"tcp://{where}:{port}"


def ask_group(
    group: str = MULTICAST_GROUP, port: int = COMMAND_PORT, *, timeout: float = 1.0
) -> list[Found]:
    """Send ``^R^V`` in one UDP datagram to ``group`` and collect the answers for ``timeout`` s.

    ``group`` is Galil's multicast group by default (TTL 1: the local network only); any
    address that answers the same way works (the tests use the simulator on 127.0.0.1).

    Raises:
        InvalidArgument: ``group`` is no IPv4 address, or ``port`` no port number.
        GalilConnectionError: the query could not be sent.
    """
    _check_endpoint((group, port), "group")
    timeout = _check_seconds(timeout, "timeout")
    found: dict[str, Found] = {}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        try:
            sock.sendto(IDENTIFY, (group, port))
        except OSError as exc:
            raise GalilConnectionError(f"cannot send to {group}:{port}: {exc}") from exc
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            sock.settimeout(left)
            try:
                data, (host, answered_from) = sock.recvfrom(2048)
            except TimeoutError:
                break
            with contextlib.suppress(ProtocolError):
                ident = parse_identify_reply(data)
                # Answered from its command port: the TCP port of the same number (23 on a
                # controller; the simulator's responder answers from the port it was given).
                address = _tcp_address(host, answered_from)
                found[address] = Found(address, "ethernet", f"answered {group}", ident)
    return list(found.values())


def listen_bootp(
    *,
    timeout: float = 5.0,
    address: tuple[str, int] = ("0.0.0.0", BOOTP_SERVER_PORT),
    on_request: Callable[[BootpRequest], None] | None = None,
    count: int | None = None,
) -> list[BootpRequest]:
    """Listen for Galil controllers asking for an IP address (BOOTP/DHCP) for ``timeout`` s.

    Args:
        timeout: seconds to listen.
        address: where to listen (the BOOTP server port, 67, on every interface).
        on_request: called with each controller the first time it asks.
        count: return as soon as this many different controllers asked.

    Raises:
        InvalidArgument: ``address`` is no (IPv4 address, port) pair, or a bad timeout.
        GalilConnectionError: the port cannot be bound (port 67 needs root on most systems).
    """
    _check_endpoint(address, "bootp_address")
    timeout = _check_seconds(timeout, "timeout")
    if on_request is not None:
        check_callable(on_request, "on_request")
    if count is not None:
        check_count(count, "count")
    seen: dict[bytes, BootpRequest] = {}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(address)
        except OSError as exc:
            raise GalilConnectionError(
                f"cannot listen on UDP {address[0]}:{address[1]} ({exc}); BOOTP/DHCP requests "
                "arrive on port 67, which needs root (or CAP_NET_BIND_SERVICE) to bind"
            ) from exc
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            sock.settimeout(left)
            try:
                data = sock.recv(2048)
            except TimeoutError:
                break
            request = parse_bootp_request(data)
            if request is not None and request.mac not in seen:
                seen[request.mac] = request
                if on_request is not None:
                    on_request(request)
                if count is not None and len(seen) >= count:
                    break
    return list(seen.values())


def _bootp_found(request: BootpRequest) -> Found:
    family = f"{request.family} " if request.family else ""
    what = "DHCP" if request.dhcp else "BOOTP"
    return Found(
        "",
        "bootp",
        f"{family}serial {request.serial_number}, MAC {request.mac_text}, asking for an IP "
        f"address ({what})",
    )


# ----------------------------------------------------------------------------------- find


def _check_seconds(value: object, what: str) -> float:
    """Seconds to wait for answers or requests: :func:`~galil.link.check_seconds` (more than
    0: nothing answers in no time) and less than an hour."""
    seconds = check_seconds(value, what, positive=True)
    if seconds >= 3600:
        raise InvalidArgument(f"{what} must be less than 3600 s, not {value!r}")
    return seconds


def _check_endpoint(value: object, what: str) -> None:
    """Refuse anything but an (IPv4 address, port) pair: no name to look up, no bad port."""
    if not isinstance(value, tuple) or len(value) != 2 or not isinstance(value[0], str):
        raise InvalidArgument(f"{what} must be an (IPv4 address, port) pair, not {value!r}")
    try:
        ipaddress.IPv4Address(value[0])
    except ValueError as exc:
        raise InvalidArgument(f"{what}: {value[0]!r} is not an IPv4 address") from exc
    check_port(value[1], f"{what} port", zero=what == "bootp_address")


def find(
    *,
    serial: bool = True,
    usb: bool = True,
    pci: bool = True,
    network: bool = False,
    probe: Sequence[str] = (),
    bootp: bool = False,
    identify: bool = True,
    identify_bridges: bool = False,
    timeout: float = 1.0,
    group: tuple[str, int] = (MULTICAST_GROUP, COMMAND_PORT),
    bootp_address: tuple[str, int] = ("0.0.0.0", BOOTP_SERVER_PORT),
    bootp_timeout: float = 5.0,
) -> list[Found]:
    """Find controllers on this computer's buses and, when asked, on the network.

    Nothing goes out on the network unless ``network``, ``probe`` or ``bootp`` asks for it.

    Args:
        serial: list serial ports whose USB ids are Galil's or a USB-serial bridge's.
        usb: list USB devices with Galil's vendor id.
        pci: list Galil PCI driver nodes.
        network: send ``^R^V`` to Galil's multicast group (``group``) and take the answers.
        probe: addresses or networks to ask over TCP (``"192.168.0.0/24"``, ``"10.0.0.5:23"``).
        bootp: listen ``bootp_timeout`` s for controllers asking for an IP address.
        identify: open what is found on serial and PCI and ask ``^R^V``.
        identify_bridges: ask USB-serial bridge ports too (opening a port may reset the
            device behind it).
        timeout: seconds to wait for each answer (and for the multicast answers).
        group: (address, port) the ``network`` query goes to.
        bootp_address: (address, port) to listen on for BOOTP/DHCP requests.
        bootp_timeout: seconds to listen for them.

    Raises:
        InvalidArgument: a bad address, network, group or timeout (checked before any port
            or device is opened and anything is sent).
        GalilConnectionError: the network query could not be sent, or port 67 not bound.
    """
    timeout = _check_seconds(timeout, "timeout")
    bootp_timeout = _check_seconds(bootp_timeout, "bootp_timeout")
    for name, value in (
        ("serial", serial),
        ("usb", usb),
        ("pci", pci),
        ("network", network),
        ("bootp", bootp),
        ("identify", identify),
        ("identify_bridges", identify_bridges),
    ):
        check_flag(value, name)
    probe = [probe] if isinstance(probe, str) else check_items(probe, "probe")
    _targets(probe)  # validate before anything goes out
    _check_endpoint(group, "group")
    _check_endpoint(bootp_address, "bootp_address")
    found: list[Found] = []
    if serial:
        found += serial_ports(identify=identify, identify_bridges=identify_bridges, timeout=timeout)
    if usb:
        found += usb_devices()
    if pci:
        found += pci_nodes(identify=identify, timeout=timeout)
    if probe:
        found += probe_hosts(probe, timeout=timeout)
    if network:
        found += ask_group(group[0], group[1], timeout=timeout)
    if bootp:
        requests = listen_bootp(timeout=bootp_timeout, address=bootp_address)
        found += [_bootp_found(r) for r in requests]
    return _unique(found)


def _unique(found: Sequence[Found]) -> list[Found]:
    """One entry per address (or description), the identified one where there are two."""
    unique: dict[str, Found] = {}
    for item in found:
        key = item.address or item.description
        if key not in unique or (item.identity and not unique[key].identity):
            unique[key] = item
    return list(unique.values())
