"""TC error codes and SC stop codes, with their texts: the one table (a leaf module).

``protocol/``, ``predict/`` and ``sim/`` all import it; nothing else holds a copy.

The tables follow the secondary copies collected in ``galil-protocol.md`` section 1.2 (BLISS,
gclib-based tools, a Tango device); they agree with each other. The controller's own ``TC1``
text wins over the table when it is available.
"""

from __future__ import annotations

import re

from galil.errors import ProtocolError

__all__ = [
    "FAULT_STOPS",
    "HALT_STOPS",
    "LIMIT_STOPS",
    "STOP_CODES",
    "TC_CODES",
    "parse_tc1",
    "stop_text",
    "tc_text",
]

TC_CODES: dict[int, str] = {
    1: "Unrecognized command",
    2: "Command only valid from program",
    3: "Command not valid in program",
    4: "Operand error",
    5: "Input buffer full",
    6: "Number out of range",
    7: "Command not valid while running",
    8: "Command not valid when not running",
    9: "Variable error",
    10: "Empty program line or undefined label",
    11: "Invalid label or line number",
    12: "Subroutine more than 16 deep",
    13: "JG only valid when running in jog mode",
    14: "EEPROM check sum error",
    15: "EEPROM write error",
    16: "IP incorrect sign during position move or IP given during forced deceleration",
    17: "ED, BN and DL not valid while program running",
    18: "Command not valid when contouring",
    19: "Application strand already executing",
    20: "Begin not valid with motor off",
    21: "Begin not valid while running",
    22: "Begin not possible due to limit switch",
    24: "Begin not valid because no sequence defined",
    25: "Variable not given in IN command",
    28: "S operand not valid",
    29: "Not valid during coordinated move",
    30: "Sequence segment too short",
    31: "Total move distance in a sequence > 2 billion",
    32: "Segment buffer full",
    33: "VP or CR cannot be mixed with LI",
    39: "No time specified",
    41: "Contouring record range error",
    42: "Contour data being sent too slowly",
    46: "Gear axis both master and follower",
    50: "Not enough fields",
    51: "Question mark not valid",
    52: "Missing quote or string too long",
    53: "Error in {}",
    54: "Question mark part of string",
    55: "Missing [ or []",
    56: "Array index invalid or out of range",
    57: "Bad function or array",
    58: "Bad command response (i.e. _GNX)",
    59: "Mismatched parentheses",
    60: "Download error - line too long or too many lines",
    61: "Duplicate or bad label",
    62: "Too many labels",
    63: "IF without ENDIF",
    65: "IN command must have a comma",
    66: "Array space full",
    67: "Too many arrays or variables",
    68: "Not valid from USB port",
    71: "IN only valid in task #0",
    80: "Record mode already running",
    81: "No array or source specified",
    82: "Undefined array",
    83: "Not a valid number",
    84: "Too many elements",
    90: "Only A B C D valid operand",
    96: "SM jumper needed for stepper motor operation",
    97: "Bad binary command format",
    98: "Binary commands not valid in application program",
    99: "Bad binary command number",
    100: "Not valid when running ECAM",
    101: "Improper index into ET (0-256)",
    102: "No master axis defined for ECAM",
    103: "Master axis modulus greater than 256*EP value",
    104: "Not valid when axis performing ECAM",
    105: "EB1 command must be given first",
    106: "Privilege violation",
    110: "No hall effect sensors detected",
    111: "Must be made brushless by BA command",
    112: "BZ command timeout",
    113: "No movement in BZ command",
    114: "BZ command runaway",
    118: "Controller has GL1600 not GL1800",
    119: "Not valid for axis configured as stepper",
    120: "Bad Ethernet transmit",
    121: "Bad Ethernet packet received",
    122: "Ethernet input buffer overrun",
    123: "TCP lost sync",
    124: "Ethernet handle already in use",
    125: "No ARP response from IP address",
    126: "Closed Ethernet handle",
    127: "Illegal Modbus function code",
    128: "IP address not valid",
    130: "Remote IO command error",
    131: "Serial port timeout",
    132: "Analog inputs not present",
    133: "Command not valid when locked / handle must be UDP",
    134: "All motors must be in MO for this command",
    135: "Motor must be in MO",
    136: "Invalid password",
    137: "Invalid lock setting",
    138: "Passwords not identical",
    140: "Serial encoder error",
    141: "Feature not supported",
    143: "TM timed out",
    144: "Incompatible with encoder type",
    160: "BX failure",
    161: "Sine amp axis not initialized",
    163: "IA command not valid when DHCP mode enabled",
    164: "Exceeded maximum sequence length, BGS or BGT is required",
    165: "SINE and SSI both enabled",
    166: "Unable to set analog output",
}

STOP_CODES: dict[int, str] = {
    0: "Motors are running, independent mode",
    1: "Motors decelerating or stopped at commanded independent position",
    2: "Decelerating or stopped by FWD limit switch or soft limit FL",
    3: "Decelerating or stopped by REV limit switch or soft limit BL",
    4: "Decelerating or stopped by Stop Command (ST)",
    6: "Stopped by Abort input",
    7: "Stopped by Abort command (AB)",
    8: "Decelerating or stopped by Off on Error (OE1)",
    9: "Stopped after finding edge (FE)",
    10: "Stopped after homing (HM) or find index (FI)",
    11: "Stopped by selective abort input",
    12: "Decelerating or stopped by encoder failure (OA1)",
    15: "Amplifier fault",
    16: "Stepper position maintenance error",
    30: "Running in PVT mode",
    31: "PVT mode completed normally",
    32: "PVT mode exited because buffer is empty",
    50: "Contour running",
    51: "Contour stopped",
    60: "ECAM running",
    61: "ECAM stopped",
    70: "EtherCAT communication failure",
    71: "EtherCAT drive fault",
    99: "MC timeout",
    100: "Motors are running, vector sequence",
    101: "Motors stopped at commanded vector",
}

#: Stop codes of a forward and a reverse limit (switch or soft limit).
LIMIT_STOPS = frozenset({2, 3})
#: Stop codes of a fault that ended a motion early, the motor often off: the abort input (6),
#: off-on-error (8), a selective abort input (11), an encoder failure (12), an amplifier fault
#: (15), a stepper's position maintenance error (16), EtherCAT (70, 71).
FAULT_STOPS = frozenset({6, 8, 11, 12, 15, 16, 70, 71})
#: Stop codes of a motion stopped before its end by anything but its own course: a limit, a
#: fault, ``ST`` (4) or ``AB`` (7). Never a normal end (1, 51, 101) nor a running code.
HALT_STOPS = LIMIT_STOPS | FAULT_STOPS | {4, 7}

_TC1 = re.compile(r"\s*(\d{1,3})(?:\s+(\S.*?))?\s*")


def tc_text(code: int) -> str:
    """Return the text for a TC error code (``tc_text(20)`` -> ``"Begin not valid ..."``)."""
    return TC_CODES.get(code, f"unknown error code {code}")


def stop_text(code: int) -> str:
    """Return the text for an SC stop code (``stop_text(4)`` -> ``"... Stop Command (ST)"``)."""
    return STOP_CODES.get(code, f"unknown stop code {code}")


def parse_tc1(reply: str) -> tuple[int, str]:
    """Parse a ``TC1`` reply such as ``" 1 Unrecognized command"`` into ``(1, "Unrecognized ...")``.

    A bare code (a ``TC`` or ``TC0`` reply) is explained from the table.

    Raises:
        ProtocolError: the reply does not start with a code.
    """
    m = _TC1.fullmatch(reply)
    if m is None:
        raise ProtocolError(f"not a TC reply: {reply!r}")
    code = int(m.group(1))
    return code, m.group(2) or tc_text(code)
