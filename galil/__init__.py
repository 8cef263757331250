"""galil: a pure-Python driver for Galil DMC motion controllers."""

from __future__ import annotations

from galil.axis import Axis, MoveHandle, MoveResult
from galil.client import Controller, MessageQueue, RecordStream, connect
from galil.codes import stop_text, tc_text
from galil.contour import ContourResult, ContourUnderrunError
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    ProtocolError,
)
from galil.models import ModelSpec, get_model
from galil.predict import Profile

__version__ = "0.1.0.dev0"

__all__ = [
    "Axis",
    "CommandError",
    "ContourResult",
    "ContourUnderrunError",
    "Controller",
    "GalilConnectionError",
    "GalilError",
    "GalilTimeoutError",
    "InvalidArgument",
    "LimitError",
    "MessageQueue",
    "ModelSpec",
    "MoveHandle",
    "MoveResult",
    "Profile",
    "ProtocolError",
    "RecordStream",
    "__version__",
    "connect",
    "get_model",
    "stop_text",
    "tc_text",
]
