"""Sans-I/O protocol core: typed commands to bytes, bytes to events, replies to commands.

Nothing here touches a socket, a port or a clock; see ``docs/decisions/0001``.
"""

from __future__ import annotations

from galil.codes import STOP_CODES, TC_CODES, parse_tc1, stop_text, tc_text
from galil.protocol import commands
from galil.protocol.commands import Command, Expect, ReplyKind, pack, parse_line
from galil.protocol.framing import (
    Ack,
    Event,
    FrameParser,
    Record,
    Rejected,
    Reply,
    Synced,
    Unsolicited,
)
from galil.protocol.numbers import (
    format_number,
    format_reply,
    from_fixed,
    parse_number,
    parse_numbers,
    to_fixed,
)
from galil.protocol.operands import decode_operand, parse_axes_reply
from galil.protocol.records import decode_record, parse_qz, record_dtype, record_to_dict
from galil.protocol.session import Completed, Session

__all__ = [
    "STOP_CODES",
    "TC_CODES",
    "Ack",
    "Command",
    "Completed",
    "Event",
    "Expect",
    "FrameParser",
    "Record",
    "Rejected",
    "Reply",
    "ReplyKind",
    "Session",
    "Synced",
    "Unsolicited",
    "commands",
    "decode_operand",
    "decode_record",
    "format_number",
    "format_reply",
    "from_fixed",
    "pack",
    "parse_axes_reply",
    "parse_line",
    "parse_number",
    "parse_numbers",
    "parse_qz",
    "parse_tc1",
    "record_dtype",
    "record_to_dict",
    "stop_text",
    "tc_text",
    "to_fixed",
]
