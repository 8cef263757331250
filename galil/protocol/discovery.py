"""What controllers say when they are looked for (sans-I/O): BOOTP requests and ``^R^V`` replies.

Known (see ``docs/decisions/0010-finding-controllers.md`` for the sources):

- A Galil Ethernet controller without an IP address broadcasts BOOTP/DHCP requests to UDP port
  67 (the server port); the reply goes to UDP port 68. Its hardware address starts with Galil's
  prefix ``00:50:4C``; in every example of Galil's own software the fourth byte names the
  product family and the last two bytes are the serial number (big endian).
- Every controller answers ``^R^V`` (bytes 0x12 0x16) with its model and firmware
  (``DMC4040 Rev 1.2f``), on every bus.
- Galil controllers belong to the multicast group 239.255.19.56 by default (changed with
  ``IA>``). Which port and what exactly Galil's own tools send there to find controllers is
  not documented; :mod:`galil.discovery` sends ``^R^V`` to the command port (23) of that group.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from galil.errors import InvalidArgument, ProtocolError
from galil.models import parse_identity

__all__ = [
    "BOOTP_CLIENT_PORT",
    "BOOTP_SERVER_PORT",
    "COMMAND_PORT",
    "GALIL_MAC_PREFIX",
    "IDENTIFY",
    "MULTICAST_GROUP",
    "BootpRequest",
    "build_bootp_request",
    "format_mac",
    "parse_bootp_request",
    "parse_identify_reply",
]

GALIL_MAC_PREFIX = b"\x00\x50\x4c"
MULTICAST_GROUP = "239.255.19.56"
COMMAND_PORT = 23
BOOTP_SERVER_PORT = 67
BOOTP_CLIENT_PORT = 68
IDENTIFY = b"\x12\x16\r"

_BOOTREQUEST = 1
_MAGIC_COOKIE = 0x63825363
_MIN_LENGTH = 240  # fixed BOOTP fields and the magic cookie (RFC 951, RFC 2131)
_CHADDR = 28
# The family byte (fourth byte of the MAC) as seen in Galil's software and documentation.
_FAMILIES = {0x00: "DMC-2000/2100", 0x08: "DMC-1415", 0x58: "DMC-2105"}


def format_mac(mac: bytes) -> str:
    """``00:50:4C:58:00:07``."""
    return ":".join(f"{b:02X}" for b in mac)


@dataclass(frozen=True)
class BootpRequest:
    """A Galil controller asking for an IP address.

    Attributes:
        mac: its hardware address (6 bytes).
        serial_number: from the last two bytes of the MAC.
        family: the product family the fourth MAC byte names, or ``""`` if not known.
        dhcp: whether the request carries DHCP options (else plain BOOTP).
        xid: the transaction id (a reply must carry it).
    """

    mac: bytes
    serial_number: int
    family: str
    dhcp: bool
    xid: int

    @property
    def mac_text(self) -> str:
        """The MAC as ``00:50:4C:58:00:07``."""
        return format_mac(self.mac)


def parse_bootp_request(packet: bytes) -> BootpRequest | None:
    """The request of a Galil controller in a UDP payload sent to port 67, else ``None``.

    ``None`` for anything else: a reply, another vendor's MAC, a short or malformed packet.
    """
    if len(packet) < _MIN_LENGTH or packet[0] != _BOOTREQUEST:
        return None
    htype, hlen = packet[1], packet[2]
    if htype != 1 or hlen != 6:
        return None
    mac = bytes(packet[_CHADDR : _CHADDR + 6])
    if mac[:3] != GALIL_MAC_PREFIX:
        return None
    (xid,) = struct.unpack_from(">I", packet, 4)
    (cookie,) = struct.unpack_from(">I", packet, 236)
    return BootpRequest(
        mac=mac,
        serial_number=(mac[4] << 8) | mac[5],
        family=_FAMILIES.get(mac[3], ""),
        dhcp=cookie == _MAGIC_COOKIE and len(packet) > _MIN_LENGTH,
        xid=xid,
    )


def build_bootp_request(mac: bytes, xid: int = 0, *, dhcp: bool = True) -> bytes:
    """A BOOTP request (a DHCPDISCOVER when ``dhcp``) as a controller without an address sends.

    Raises:
        InvalidArgument: ``mac`` is not 6 bytes or ``xid`` not a 32-bit number.
    """
    if len(mac) != 6:
        raise InvalidArgument(f"a MAC address has 6 bytes, not {len(mac)}")
    if not 0 <= xid <= 0xFFFFFFFF:
        raise InvalidArgument(f"xid must fit 32 bits, not {xid!r}")
    packet = bytearray(300)  # the classic minimum size of a BOOTP message
    packet[0:4] = bytes([_BOOTREQUEST, 1, 6, 0])
    struct.pack_into(">I", packet, 4, xid)
    struct.pack_into(">H", packet, 10, 0x8000)  # broadcast flag: no address to answer to yet
    packet[_CHADDR : _CHADDR + 6] = mac
    struct.pack_into(">I", packet, 236, _MAGIC_COOKIE)
    if dhcp:
        packet[240:243] = bytes([53, 1, 1])  # option 53, DHCP message type: DISCOVER
        packet[243] = 255
    else:
        packet[240] = 255
    return bytes(packet)


def parse_identify_reply(data: bytes) -> str:
    """The identity in a reply to ``^R^V`` (``b"DMC4040 Rev 1.2f\\r\\n:"`` -> the text).

    Only a Galil identification string (:func:`galil.models.parse_identity`: a model, ``Rev``
    and a firmware) is one: any other device on the port (a telnet login ending in ``login:``)
    is no controller.

    Raises:
        ProtocolError: no complete reply, a ``?``, no text, or text that is no Galil identity.
    """
    text = data.replace(b"\r\n", b"\n").strip()
    if not text.endswith(b":"):
        raise ProtocolError(f"no identity in {data!r}")
    body = text[:-1].strip().decode("latin-1")
    line = body.splitlines()[-1].strip() if body else ""
    if not line:
        raise ProtocolError(f"no identity in {data!r}")
    try:
        parse_identity(line)
    except InvalidArgument as exc:
        raise ProtocolError(f"no Galil identity in {data[:80]!r}") from exc
    return line
