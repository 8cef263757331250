"""pint Quantities as the predictor takes them, without importing pint (the predictor is pure
numpy: an import-linter contract keeps ``galil.units`` and pint out of it).

Decision 0092 and 0103: an argument in seconds takes a time Quantity of any registry
(``250 * ureg.ms``), converted to seconds; any other Quantity there is refused. Counts,
counts/s, counts/s², IT and DT are plain numbers: the predictor has no scale, so a Quantity
there is refused naming the argument (an axis with a scale converts its units first).
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from galil.errors import InvalidArgument

__all__ = ["is_quantity", "no_quantity", "period_seconds", "seconds"]

#: What an argument in seconds takes, as a refusal says it.
A_TIME = "a time such as 0.5 * ureg.s or 100 * ureg.ms (a plain number is seconds)"


def is_quantity(value: object) -> bool:
    """True for a pint Quantity of any registry (told by what it has, as
    ``galil.units.is_quantity`` tells it)."""
    return (
        hasattr(value, "magnitude") and hasattr(value, "units") and hasattr(value, "dimensionality")
    )


def _shown(value: object) -> str:
    try:
        return f"{value:~}"
    except Exception:  # (a Quantity-like object pint's short format cannot take)
        return f"{value!r:.60}"


def seconds(value: object, name: str) -> object:
    """A time Quantity (s, ms, min ...; a scalar or an array) as seconds: a float, or a float
    array; anything else is returned as it is, for the caller's own check of a plain number.

    Raises:
        InvalidArgument: a Quantity that is not a time (``1 * ureg.mm``, ``5 * ureg.Hz``, a
            dimensionless one), naming ``name``.
    """
    if not is_quantity(value):
        return value
    q: Any = value  # (a Quantity of some registry: pint is not imported to type it)
    magnitude: Any = None
    try:
        is_time = dict(q.dimensionality) == {"[time]": 1}
        if is_time:
            magnitude = q.m_as("second")
    except Exception:  # (pint's own errors: pint may not be imported here)
        is_time = False
    if not is_time:
        raise InvalidArgument(f"{name} must be {A_TIME}, not {_shown(value)}")
    if np.ndim(magnitude) == 0:  # (the caller checks the number: finite, real, >= 0 ...)
        return magnitude.item() if hasattr(magnitude, "item") else magnitude
    return np.asarray(magnitude)


def period_seconds(sample_period: object) -> float:
    """``sample_period`` as seconds: a time Quantity converted (refused if not a time), a
    plain number as it is (each predictor checks it)."""
    return cast("float", seconds(sample_period, "sample_period"))


#: What a refused Quantity in counts (or counts/s, counts/s²) is pointed to.
_TO_AN_AXIS = (
    "; for units, plan on an axis with a scale (axis.set_scale(...), then axis.plan_to(...))"
)


def no_quantity(value: object, name: str, unit: str, *, counts: bool = True) -> None:
    """Refuse a Quantity for ``name``, a plain number of ``unit`` in the predictor.

    Raises:
        InvalidArgument: ``value`` is a Quantity; one in ``counts`` (or counts per second)
            is pointed at an axis with a scale.
    """
    if is_quantity(value):
        raise InvalidArgument(
            f"{name} is a plain number of {unit} in galil.predict (it has no scale), not "
            f"{_shown(value)}{_TO_AN_AXIS if counts else ''}"
        )
