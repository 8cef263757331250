"""galil: a pure-Python driver for Galil DMC motion controllers."""

from __future__ import annotations

from galil.axis import Axis, MoveOverrides
from galil.capture import Capture, Recording
from galil.codes import stop_text, tc_text
from galil.contour import ContourResult
from galil.controller import Controller, ReconnectPolicy, connect
from galil.discovery import Found, find
from galil.errors import (
    CommandError,
    ContourUnderrunError,
    GalilAttributeError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    MotionError,
    ProgramError,
    ProtocolError,
    QueueTimeoutError,
    ScheduleError,
    UnknownAxisError,
    UnknownVariableError,
)
from galil.homing import Homed, Switches, SwitchPolarity
from galil.io import IO
from galil.messages import MessageQueue
from galil.models import ModelSpec, get_model
from galil.motion import MoveHandle, MoveResult
from galil.predict import MultiProfile, Profile
from galil.predict.homing import HomeSwitch
from galil.protocol.interrupts import Interrupt
from galil.protocol.records import RecordFields, decode_fields
from galil.records import RecordStream
from galil.segments import Arc, Line, VectorPlan
from galil.tuning import EncoderConfig, EncoderType, LimitDisable, MotorType
from galil.units import Amount, Amounts, QuantityLike, Reading, Readings
from galil.vector import VectorHandle, VectorOptions

__version__ = "0.1.0.dev0"

__all__ = [
    "IO",
    "Amount",
    "Amounts",
    "Arc",
    "Axis",
    "Capture",
    "CommandError",
    "ContourResult",
    "ContourUnderrunError",
    "Controller",
    "EncoderConfig",
    "EncoderType",
    "Found",
    "GalilAttributeError",
    "GalilConnectionError",
    "GalilError",
    "GalilTimeoutError",
    "HomeSwitch",
    "Homed",
    "Interrupt",
    "InvalidArgument",
    "LimitDisable",
    "LimitError",
    "Line",
    "MessageQueue",
    "ModelSpec",
    "MotionError",
    "MotorType",
    "MoveHandle",
    "MoveOverrides",
    "MoveResult",
    "MultiProfile",
    "Profile",
    "ProgramError",
    "ProtocolError",
    "QuantityLike",
    "QueueTimeoutError",
    "Reading",
    "Readings",
    "ReconnectPolicy",
    "RecordFields",
    "RecordStream",
    "Recording",
    "ScheduleError",
    "SwitchPolarity",
    "Switches",
    "UnknownAxisError",
    "UnknownVariableError",
    "VectorHandle",
    "VectorOptions",
    "VectorPlan",
    "__version__",
    "connect",
    "decode_fields",
    "find",
    "get_model",
    "stop_text",
    "tc_text",
]
