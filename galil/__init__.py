"""galil: a pure-Python driver for Galil DMC motion controllers."""

from __future__ import annotations

from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    ProtocolError,
)

__version__ = "0.1.0.dev0"

__all__ = [
    "CommandError",
    "GalilConnectionError",
    "GalilError",
    "GalilTimeoutError",
    "InvalidArgument",
    "LimitError",
    "ProtocolError",
    "__version__",
]
