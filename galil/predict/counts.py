"""Counts as the predictor takes them: whole numbers inside the controller's 32-bit range.

One rule (decision 0092): a value *in counts* (the predictor's distances and start positions,
``galil plan`` without ``--scale``, an axis without a scale) must be a whole number, since the
controller moves whole counts; a value in *user units* (an axis with a scale) is rounded to
the nearest count by the axis before it gets here.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from galil.errors import InvalidArgument, LimitError, decimal_hint
from galil.models import INT32_MAX, INT32_MIN
from galil.predict.quantities import no_quantity

__all__ = ["ROUND_IT", "WHOLE_TOLERANCE", "check_position_range", "whole_counts"]

#: A count this close to a whole number is that number: half of the 1/65536 count the
#: controller keeps positions in (32.16 fixed point, so it would store the whole number), and
#: far above a float's rounding error after a unit conversion (2**-22 at 2**31 counts).
WHOLE_TOLERANCE = 2.0**-17


#: What a refused fraction of a count is told by default.
ROUND_IT = " (the controller moves whole counts: round it first)"


def whole_counts(value: object, what: str, hint: str = ROUND_IT) -> int:
    """``value`` as an ``int`` number of counts: an ``int``, a numpy integer, or a real number
    within :data:`WHOLE_TOLERANCE` of a whole one (``1000.0``, ``np.float64(1000)``). ``hint``
    follows the refusal of a fraction of a count.

    Raises:
        InvalidArgument: a bool, a string or anything not a real number, NaN or infinity, or a
            fraction of a count (``10.7``), naming ``what``.
    """
    if type(value) is int:
        return value
    if type(value) is float and math.isfinite(value):  # (the usual case after a conversion)
        v = value
    elif isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        return int(value)
    else:
        v = _real(value, what)
    n = round(v)
    if abs(v - n) > WHOLE_TOLERANCE:
        raise InvalidArgument(f"{what} {value!r:.60} is not a whole number of counts{hint}")
    return int(n)


def _real(value: object, what: str) -> float:
    """:func:`whole_counts` for what is neither an integer nor a finite float: ``value`` as a
    finite float.

    Raises:
        InvalidArgument: a bool, anything not a real number, NaN or infinity.
    """
    refused = f"{what} must be a whole number of counts, not {value!r:.60}"
    no_quantity(value, what, "counts")  # (a Quantity passes for a numbers.Real)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InvalidArgument(refused + decimal_hint(value))
    try:
        v = float(value)
    except OverflowError:  # (a Fraction no float holds)
        raise InvalidArgument(f"{what} is far out of range: {value!r:.60}") from None
    if not math.isfinite(v):
        raise InvalidArgument(refused)
    return v


def check_position_range(
    name: str, value: int, what: str, *, axis: str | None = None, model: str | None = None
) -> None:
    """Refuse ``value`` (a distance or a position, counts) outside the controller's 32-bit
    registers, which take -2147483648 .. 2147483647 (``PR``, ``PA``, ``DP``, ``FL``/``BL``).

    Raises:
        LimitError: outside that range, named ``name``.
    """
    if INT32_MIN <= value <= INT32_MAX:
        return
    raise LimitError(
        f"{what} {value} is outside the 32-bit position range {INT32_MIN} .. {INT32_MAX}"
        " (the controller's registers cannot hold it)",
        name=name,
        value=value,
        limit=INT32_MAX if value > 0 else INT32_MIN,
        axis=axis,
        model=model,
    )
