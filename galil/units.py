"""Units at the edge: pint Quantities in, counts and seconds inside.

The default registry is created on first use (building one costs ~0.2 s). Quantities from any other
registry are accepted: they are re-read through their magnitude and unit name, so a user's own
``pint.UnitRegistry()`` works as well as ``galil.units.ureg``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache, cached_property, lru_cache
from typing import Any, Protocol, TypeAlias, TypeGuard, cast, overload

import numpy as np
import numpy.typing as npt
import pint

from galil.errors import InvalidArgument, LimitError, decimal_hint

__all__ = [
    "UNIT_KINDS",
    "Amount",
    "Amounts",
    "PathSamples",
    "QuantityLike",
    "Reading",
    "Readings",
    "Real",
    "Scale",
    "angle_in_degrees",
    "counts_or_plain",
    "get_registry",
    "is_quantity",
    "path_to_counts",
    "plain_seconds",
    "sampled_values",
    "state_in_units",
    "unit_refused",
    "ureg",
]


# -- the public types (decision 0099) ------------------------------------------------------
# Defined here, where pint and numpy are imported anyway, as runtime objects: the annotations
# that name them resolve (typing.get_type_hints, inspect.signature(eval_str=True)).

#: pint's Quantity, generic in its magnitude: ``Quantity[float]`` (one value),
#: ``Quantity[npt.NDArray[np.float64]]`` (an array). Every registry's Quantity derives from it.
#: (Not in ``__all__``: it is pint's own class, documented by pint; ``isinstance(v,
#: pint.Quantity)`` narrows a :data:`Reading`.)
Quantity = pint.Quantity


class QuantityLike(Protocol):
    """What the library takes as a Quantity: anything with a magnitude, units and a
    dimensionality (:func:`is_quantity`'s test), of any registry and any magnitude type
    (pint's own ``Quantity[int]``, ``Quantity[float]``, a numpy magnitude ...). Whether it
    is one real value, and of which dimension, is checked at run time."""

    @property
    def magnitude(self) -> object:
        """The number (or array) without its unit."""
        ...

    @property
    def units(self) -> object:
        """The unit."""
        ...

    @property
    def dimensionality(self) -> object:
        """The dimension (length, angle, time ...)."""
        ...


#: A plain real number as the library takes it: an int or a float, or a numpy integer or
#: floating scalar (``np.int64``, ``np.float32``); a bool is refused at run time.
Real: TypeAlias = float | np.integer | np.floating
#: One value in, on an axis without a scale or with one: a plain number (counts, or counts
#: per second ...) or a Quantity (in the axis's units; counts on an axis without a scale).
Amount: TypeAlias = Real | QuantityLike
#: Values in, as an array: anything numpy makes an array of, or a Quantity array.
Amounts: TypeAlias = npt.ArrayLike | QuantityLike
#: One value out: a float on an axis without a scale (counts, counts/s ...), a Quantity of a
#: float on one with a scale. A typed caller narrows (``isinstance(v, pint.Quantity)``)
#: before ``v.to("mm")``: on an axis without a scale that call fails.
Reading: TypeAlias = float | pint.Quantity[float]
#: Values out, as an array: floats (counts ...) or a Quantity of them.
Readings: TypeAlias = npt.NDArray[np.float64] | pint.Quantity[npt.NDArray[np.float64]]


@cache
def get_registry() -> pint.UnitRegistry[float]:
    """Return the library's default registry (shared with ``pint`` application registry)."""
    reg: Any = pint.get_application_registry()  # type: ignore[no-untyped-call]
    registry: pint.UnitRegistry[float] = reg.get()
    return registry


class _LazyRegistry:
    """``galil.units.ureg``: the default registry, built on first attribute access."""

    # Any: the registry's attributes are its units (``ureg.mm``), found by name at run time,
    # and pint types its own registry's __getattr__ as Any.
    def __getattr__(self, name: str) -> Any:
        return getattr(get_registry(), name)

    def __call__(
        self, input_string: str, case_sensitive: bool | None = None, **values: object
    ) -> pint.Quantity[float]:
        """``ureg("2000 / mm")``: the expression parsed by the default registry (pint's
        ``UnitRegistry.__call__``; ``values`` are passed on as they are)."""
        return get_registry()(input_string, case_sensitive, **values)

    def __repr__(self) -> str:
        return "<galil default pint registry>"


# (Typed as the registry it stands for: ``ureg.Quantity(5, "mm")`` is typed as pint types it.)
ureg: pint.UnitRegistry[float] = _LazyRegistry()  # type: ignore[assignment]


def is_quantity(value: object) -> TypeGuard[QuantityLike]:
    """True for a pint Quantity of any registry."""
    if isinstance(value, pint.Quantity):  # every registry's Quantity class derives from it
        return True
    return (
        hasattr(value, "magnitude") and hasattr(value, "units") and hasattr(value, "dimensionality")
    )


def _shown(value: object) -> str:
    """A Quantity as a refusal shows it (``100 / °C``), whatever its registry can format."""
    try:
        return f"{value:~}"
    except Exception:  # (a Quantity-like object pint's short format cannot take)
        return f"{value!r:.60}"


def unit_refused(what: str, value: object, why: str) -> InvalidArgument:
    """The refusal of ``value`` (for ``what``) when pint itself failed on its unit (raise it
    from pint's error): it does not convert (``DimensionalityError``), it multiplies an
    offset unit such as °C (``OffsetUnitCalculusError``), or only the user's own registry
    defines it (``UndefinedUnitError``). ``why`` says what was expected."""
    return InvalidArgument(f"{what}: {_shown(value)} {why}")


def _ours(q: Any, what: str = "value", expected: str | Callable[[], str] = "") -> Any:
    """Re-express a Quantity of any registry in the default registry.

    Raises:
        InvalidArgument: a unit the default registry does not define (one a user's own
            registry added), naming ``what`` and, when given, what was ``expected`` (a
            callable is called only then: formatting a unit costs microseconds).
    """
    reg = get_registry()
    theirs = getattr(q, "_REGISTRY", None)
    if theirs is reg:
        return q
    if callable(expected):
        expected = expected()
    wanted = f"; expected {expected}, in a unit that registry defines" if expected else ""
    try:
        ours = reg.Quantity(q.magnitude, str(q.units))
    except pint.errors.PintError as exc:
        why = "is in a unit pint's default registry does not define"
        why += wanted or " (give it in one it does, such as mm, inch, degree, count)"
        raise unit_refused(what, q, why) from exc
    if theirs is not None and not _same_meaning(theirs, str(q.units)):
        # (a user's "qturn = 90 * degree" is a quecto-turn to the default registry)
        raise unit_refused(
            what, q, f"is {ours.units} to pint's default registry, not your unit{wanted}"
        )
    return ours


@lru_cache(maxsize=64)
def _same_meaning(registry: Any, units: str) -> bool:
    """Whether ``units`` means the same in ``registry`` (a user's own) as in the default one:
    the same root units and factor. A unit that fails to convert in either is left to the
    conversion that follows (which refuses it in the library's words)."""
    try:
        theirs = registry.Quantity(1.0, units).to_root_units()
        ours = get_registry().Quantity(1.0, units).to_root_units()
    except pint.errors.PintError:
        return True
    if str(theirs.units) != str(ours.units):
        return False
    return math.isclose(float(theirs.magnitude), float(ours.magnitude), rel_tol=1e-9)


def angle_in_degrees(value: object, what: str) -> float:
    """An angle in degrees: a plain number is degrees, a Quantity must be an angle (of any
    registry, in a unit the default registry defines).

    Raises:
        InvalidArgument: not a finite real number; a Quantity that is not an angle, or whose
            unit pint's default registry does not define; both naming ``what``.
    """
    if not is_quantity(value):
        return _plain_number(value, what)
    expected = "an angle such as 90 * ureg.degree (a plain number is degrees)"
    q = _ours(value, what, expected)
    try:
        angle = _angle_power(q.units) == 1 and q.to_root_units().dimensionless
        degrees = _magnitude(q.to("degree"), what) if angle else None
    except pint.errors.PintError as exc:  # (an offset unit such as °C: no root units)
        raise unit_refused(what, value, f"is not an angle; expected {expected}") from exc
    if degrees is None:
        raise InvalidArgument(f"{what}: {_shown(value)} is not an angle; expected {expected}")
    return degrees


#: What a time argument takes, as a refusal says it.
_A_TIME = "a time such as 0.5 * ureg.s or 100 * ureg.ms (a plain number is seconds)"


def plain_seconds(value: object, what: str) -> object:
    """A time Quantity (of any registry: s, ms, min ...) as a float of seconds, for the checks
    of every timeout, pause and duration; anything else is returned as it is, for the
    caller's own check of a plain number of seconds.

    Raises:
        InvalidArgument: a Quantity that is not a time (``5 * ureg.mm``, ``10 * ureg.Hz``), an
            array, a complex or non-finite magnitude, naming ``what``.
    """
    if not is_quantity(value):
        return value
    q = _ours(value, what, _A_TIME)
    try:
        if q.dimensionality != _second().dimensionality:
            raise InvalidArgument(f"{what} must be {_A_TIME}, not {_shown(value)}")
        seconds = q.to("second")
    except pint.errors.PintError as exc:  # (an offset unit such as degC)
        raise InvalidArgument(f"{what} must be {_A_TIME}, not {_shown(value)}") from exc
    return _magnitude(seconds, what)


@cache
def _second() -> Any:
    return get_registry().Quantity(1.0, "second")


@lru_cache(maxsize=256)
def _angle_power(units: Any) -> int:
    """The power of angle in ``units`` (pint treats angles as dimensionless: count radians)."""
    root: Any = get_registry().Quantity(1.0, units).to_root_units()
    return int(dict(root.unit_items()).get("radian", 0))


@lru_cache(maxsize=256)
def _offset(units: Any) -> bool:
    """Whether ``units`` has an offset (degC ...): those go through pint's own conversion."""
    return not get_registry().Quantity(1.0, units)._ok_for_muldiv()


@lru_cache(maxsize=256)
def _factor(source: Any, target: Any) -> float:
    """Multiply a magnitude in ``source`` units by this to get ``target`` units.

    Raises:
        pint.DimensionalityError: the units do not convert (offset units never reach here).
    """
    return float(get_registry().Quantity(1.0, source).to(target).magnitude)


def _without_counts(q: Any) -> Any:
    """``2000 count / mm`` -> ``2000 / mm``: counts are what the scale converts to."""
    power = dict(q.unit_items()).get("count", 0)
    return q / get_registry().count ** power if power else q


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise InvalidArgument(f"{what} must be a finite number, got {value!r}")
    return value


def _real(value: numbers.Real | float, what: str) -> float:
    """``float(value)``, a typed error for a number no float holds (an int of 400 digits)."""
    try:
        return _finite(float(value), what)
    except OverflowError:
        raise InvalidArgument(f"{what} is too large for any controller: {value!r:.40}") from None


def string_hint(value: object, *, number: bool = False) -> str:
    """What a refusal of a string adds: strings are not parsed, and how to make a Quantity
    (or, where a plain ``number`` is taken too, a number)."""
    if not isinstance(value, str):
        return ""
    text = value.strip()[:40] if any(c.isalpha() for c in value) else "10 mm"
    return (
        f" (a string is not parsed: give {'a number, or ' if number else ''}a Quantity such as"
        f" ureg({text!r}) or 10 * ureg.mm)"
    )


def _plain_number(value: object, what: str) -> float:
    if type(value) is int or type(value) is float:  # (the usual case: no ABC check)
        return _real(value, what)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidArgument(
            f"{what} must be a number or a pint Quantity, got {value!r:.60}"
            f"{decimal_hint(value) or string_hint(value, number=True)}"
        )
    return _real(value, what)


def _magnitude(q: Any, what: str) -> float:
    """The magnitude of a scalar, real Quantity (arrays and complex values are refused)."""
    m = q.magnitude
    if type(m) is float:  # (the usual case: a plain float, nothing to look at)
        return _finite(m, what)
    if getattr(m, "ndim", 0) == 0 and hasattr(m, "item"):
        m = m.item()
    if isinstance(m, bool) or not isinstance(m, numbers.Real):
        raise InvalidArgument(f"{what} must be one real value, got {q!r}{decimal_hint(m)}")
    return _real(m, what)


def _one_value(m: object, given: object) -> float:
    """The magnitude ``m`` of ``counts_per`` (``given``) as a float: one real value.

    Raises:
        InvalidArgument: an array (``np.array([2000, 1]) / ureg.mm``), a complex value.
    """
    if getattr(m, "ndim", 0) == 0 and hasattr(m, "item"):
        m = m.item()  # (a numpy scalar or a 0-d array)
    if isinstance(m, bool) or not isinstance(m, numbers.Real):
        raise InvalidArgument(
            f"counts_per must be one real value, such as 2000 / ureg.mm, got {given!r:.80}"
            f"{decimal_hint(m)}"
        )
    return float(m)


@dataclass(frozen=True, init=False)  # (__init__ takes any Quantity; the fields hold checked ones)
class Scale:
    """How one axis maps user units onto encoder counts.

    ``counts = sign * (x - offset) * counts_per`` for positions; speeds and accelerations
    use ``sign * counts_per`` alone.

    Attributes:
        counts_per: counts per unit, e.g. ``2000 / ureg.mm`` or ``4096 / ureg.degree``.
        offset: the user position at count 0 (a Quantity in the axis's length/angle unit).
        sign: +1, or -1 when the user's positive direction is the motor's negative one.
    """

    counts_per: pint.Quantity[float]
    # (None only as __init__'s default, as before: the checked offset replaces it)
    offset: pint.Quantity[float] = None  # type: ignore[assignment]
    sign: int = 1

    def __init__(
        self, counts_per: QuantityLike, offset: QuantityLike | None = None, sign: int = 1
    ) -> None:
        # What the generated __init__ did: set the fields, then check them (__post_init__).
        object.__setattr__(self, "counts_per", counts_per)
        object.__setattr__(self, "offset", offset)
        object.__setattr__(self, "sign", sign)
        self.__post_init__()

    def __post_init__(self) -> None:
        if not is_quantity(self.counts_per):
            raise InvalidArgument(
                f"counts_per must be a Quantity such as 2000 / ureg.mm, got {self.counts_per!r}"
            )
        expected = (
            "counts_per must be counts per a length or an angle, e.g. 2000 / ureg.mm or "
            f"4096 / ureg.degree, got {self.counts_per!r}"
        )
        try:
            cp = _without_counts(_ours(self.counts_per, "counts_per"))
            magnitude = _one_value(cp.magnitude, self.counts_per)
            linear = cp.dimensionality == get_registry().Quantity(1.0, "1/m").dimensionality
            rotary = cp.dimensionless and _angle_power(cp.units) == -1
        except OverflowError:
            raise InvalidArgument(f"counts_per is too large: {self.counts_per!r:.60}") from None
        except pint.errors.PintError as exc:  # 100 / ureg.degC: an offset unit divides nothing
            raise InvalidArgument(expected) from exc
        if not (linear or rotary):
            raise InvalidArgument(expected)
        if not math.isfinite(magnitude) or magnitude <= 0:
            raise InvalidArgument(
                f"counts_per must be positive and finite, got {self.counts_per!r}"
                + (
                    " (an axis whose positive direction is the motor's negative one: sign=-1)"
                    if magnitude < 0
                    else ""
                )
            )
        object.__setattr__(self, "counts_per", cp)
        if isinstance(self.sign, bool) or self.sign not in (1, -1):
            raise InvalidArgument(f"sign must be +1 or -1, got {self.sign!r}")
        unit = self.unit
        offset: object = self.offset  # (as given: None, or any Quantity, until checked here)
        if offset is None:
            object.__setattr__(self, "offset", get_registry().Quantity(0.0, unit))
        else:
            object.__setattr__(self, "offset", self._convert(offset, unit, "offset"))

    @cached_property
    def unit(self) -> pint.Unit:
        """The user's position unit (``mm`` for ``2000 / mm``)."""
        cp: Any = self.counts_per  # (a Quantity of the default registry once checked)
        unit: pint.Unit = (1 / cp).units
        return unit

    @cached_property
    def unit_text(self) -> str:
        """The unit as text (``"mm"``)."""
        return f"{self.unit:~}"

    @cached_property
    def _k(self) -> float:
        cp: Any = self.counts_per
        return float(cp.magnitude)

    @cached_property
    def _offset(self) -> float:
        offset: Any = self.offset  # (a Quantity in the axis's unit once checked)
        return float(offset.magnitude)

    @cached_property
    def display(self) -> tuple[float, float, str]:
        """``(counts per unit, offset, unit)`` as a profile shows itself in the axis's unit
        (:attr:`galil.predict.Profile.display`); counts per unit is negative with sign -1."""
        return (self.sign * self._k, self._offset, self.unit_text)

    @cached_property
    def _rate_units(self) -> tuple[pint.Unit, pint.Unit]:
        reg = get_registry()
        return self.unit / reg.second, self.unit / reg.second**2

    def _convert(self, value: Any, unit: Any, what: str) -> Any:
        if not is_quantity(value):
            raise InvalidArgument(
                f"{what} needs units compatible with {unit:~} (the axis has a scale), got "
                f"{value!r:.60}{string_hint(value)}"
            )
        q = _ours(value, what, lambda: f"{unit:~}-compatible units")
        if getattr(q, "_units", None) == getattr(unit, "_units", False):
            # The usual case, the axis's own unit (compared without building Unit objects):
            # nothing to convert, and the angle check below is trivially met.
            _magnitude(q, what)
            return q
        try:
            if q.units == unit:
                out = q  # the usual case: the axis's own unit, nothing to convert
            elif getattr(q, "_magnitude", None).__class__ in (int, float) and not _offset(q.units):
                out = q.__class__(q.magnitude * _factor(q.units, unit), unit)
            else:
                out = q.to(unit)
            angles = _angle_power(q.units), _angle_power(unit)
        except pint.errors.PintError as exc:  # (a wrong dimension; °C in a product ...)
            raise unit_refused(
                what, value, f"has the wrong dimension; expected {unit:~}-compatible units"
            ) from exc
        if angles[0] != angles[1]:
            # pint converts 5 (dimensionless) or 5 Hz to degrees silently: refuse it here.
            raise InvalidArgument(
                f"{what}: {value:~} is not an angle; expected {unit:~}-compatible units"
            )
        _magnitude(out, what)
        return out

    def position_to_counts(self, value: QuantityLike, what: str = "position") -> float:
        """A position Quantity to (unrounded) counts."""
        if is_quantity(value):
            q = _ours(value, what, lambda: f"{self.unit:~}-compatible units")
            if getattr(q, "_units", None) == getattr(self.unit, "_units", False):
                # The usual case (_convert's own): its magnitude looked at once, not twice.
                return self.sign * (_magnitude(q, what) - self._offset) * self._k
        q = self._convert(value, self.unit, what)
        # q and the offset are in the axis's unit (a length or an angle, never an offset unit
        # such as degC): subtracting magnitudes is what pint's subtraction does.
        return self.sign * (_magnitude(q, what) - self._offset) * self._k

    def distance_to_counts(self, value: QuantityLike, what: str = "distance") -> float:
        """A relative distance Quantity to counts (no offset)."""
        q = self._convert(value, self.unit, what)
        return self.sign * float(q.magnitude) * self._k

    def rate_to_counts(self, value: QuantityLike, power: int, what: str) -> float:
        """A speed (power 1) or acceleration (power 2) Quantity to counts/s**power."""
        unit = self._rate_units[power - 1]
        q = self._convert(value, unit, what)
        return self.sign * float(q.magnitude) * self._k

    @overload
    def counts_to_position(self, counts: float) -> pint.Quantity[float]: ...
    @overload
    def counts_to_position(
        self, counts: npt.NDArray[np.float64]
    ) -> pint.Quantity[npt.NDArray[np.float64]]: ...
    def counts_to_position(
        self, counts: float | npt.NDArray[np.float64]
    ) -> pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]]:
        """Counts to a position Quantity.

        ``(sign * counts + offset * k) / k`` (``k`` counts per unit): one rounding, so that a
        position that converted to whole counts reads back as given (``0.1 mm``, not the
        ``0.09999999999999964 mm`` of ``counts / k`` then ``+ offset``).
        """
        k = self._k
        out: Any = get_registry().Quantity((counts * self.sign + self._offset * k) / k, self.unit)
        return out  # type: ignore[no-any-return]

    @overload
    def counts_to_distance(self, counts: float) -> pint.Quantity[float]: ...
    @overload
    def counts_to_distance(
        self, counts: npt.NDArray[np.float64]
    ) -> pint.Quantity[npt.NDArray[np.float64]]: ...
    def counts_to_distance(
        self, counts: float | npt.NDArray[np.float64]
    ) -> pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]]:
        """Counts to a relative distance Quantity."""
        out: Any = get_registry().Quantity(counts * self.sign / self._k, self.unit)
        return out  # type: ignore[no-any-return]

    @overload
    def counts_to_rate(self, counts: float, power: int) -> pint.Quantity[float]: ...
    @overload
    def counts_to_rate(
        self, counts: npt.NDArray[np.float64], power: int
    ) -> pint.Quantity[npt.NDArray[np.float64]]: ...
    def counts_to_rate(
        self, counts: float | npt.NDArray[np.float64], power: int
    ) -> pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]]:
        """Counts/s**power to a speed or acceleration Quantity."""
        unit = self._rate_units[power - 1]
        out: Any = get_registry().Quantity(counts * self.sign / self._k, unit)
        return out  # type: ignore[no-any-return]


def _no_scale(what: str, value: object, letter: str) -> InvalidArgument:
    """The refusal of a value with units on an axis without a scale (one wording for all)."""
    axis = "the axis has"
    if len(letter) == 1:
        axis = f"axis {letter} has"
    elif letter:  # (the axes of a path)
        axis = f"axes {', '.join(letter)} have"
    return InvalidArgument(
        f"{what}: {value} has units but {axis} no scale; "
        "call axis.set_scale(counts_per=...) or pass counts"
    )


#: What an axis without a scale takes, by power of time: counts, counts/s, counts/s².
_COUNT_UNITS = ("count", "count / second", "count / second ** 2")


@lru_cache(maxsize=64)
def _of_time(name: str) -> bool:
    """Whether unit ``name`` measures time alone (second, ms, minute; hertz, its inverse)."""
    return set(get_registry().Quantity(1.0, name).dimensionality) == {"[time]"}


def counts_or_plain(value: object, what: str, letter: str = "", *, power: int = 0) -> float:
    """For an axis (``letter``, if known; several letters: the axes of a path) without a
    scale: a plain number, or a Quantity in counts (``power`` 0), counts per second (1) or
    per second squared (2); ``count`` may be left out (``5000 / ureg.s``).

    Raises:
        InvalidArgument: not a number; a Quantity with a length, an angle or any unit but
            counts and time (no scale to convert it); counts of the wrong power of time.
    """
    if not is_quantity(value):
        return _plain_number(value, what)
    q = _ours(value, what, _COUNT_UNITS[power])
    names = dict(q.unit_items())
    try:
        if all(name == "count" or _of_time(name) for name in names):
            return _magnitude(q.to(_COUNT_UNITS[power]), what)
    except pint.errors.PintError as exc:
        raise unit_refused(
            what, value, f"has the wrong dimension; expected {_COUNT_UNITS[power]}"
        ) from exc
    raise _no_scale(what, value, letter)


def signed_rate_counts(
    scale: Scale | None, value: object, power: int, what: str, letter: str
) -> float:
    """A signed speed (power 1) or acceleration (power 2) as counts/s^power, through the
    ``scale`` of axis ``letter`` (``None``: plain numbers, or Quantities in counts/s^power:
    :func:`counts_or_plain`)."""
    if type(power) is not int or power not in (1, 2):
        raise InvalidArgument(
            f"power must be 1 (a speed) or 2 (an acceleration), not {power!r:.60}"
        )
    if scale is not None:
        return scale.rate_to_counts(cast("QuantityLike", value), power, what)
    return counts_or_plain(value, what, letter, power=power)


def rate_magnitude_counts(
    scale: Scale | None, value: object, power: int, what: str, letter: str, hint: str = ""
) -> float:
    """A speed or acceleration magnitude as counts/s^power (see :func:`signed_rate_counts`).

    Raises:
        InvalidArgument: a negative value in the user's direction (the scale's sign reverses
            positions, not magnitudes), with ``hint`` after the message.
    """
    counts = signed_rate_counts(scale, value, power, what, letter)
    if counts * (1 if scale is None else scale.sign) < 0:
        raise InvalidArgument(f"{what} must not be negative, got {value!r}{hint}")
    return abs(counts)


def path_to_counts(
    path: object, scales: Sequence[Scale | None], letters: str
) -> npt.NDArray[np.float64]:
    """A relative contour path in counts: plain numbers as they are, a Quantity array through
    each axis's scale (shape (segments,) or (segments, axes); no offset, the path is relative).

    Raises:
        InvalidArgument: not numbers, complex or non-finite values, or units an axis cannot
            take.
    """
    if not is_quantity(path):
        return _real_array(path, "contour path")
    q: Any = path
    magnitude = _real_array(q.magnitude, "contour path")
    columns = magnitude[:, None] if magnitude.ndim == 1 else magnitude
    if columns.ndim != 2 or columns.shape[1] != len(letters):
        return magnitude  # the caller's shape check reports it
    out = np.empty_like(columns)
    unit_of = q.units
    for j, (a, scale) in enumerate(zip(letters, scales, strict=True)):
        what = f"contour path on {a}"
        if scale is None:
            out[:, j] = columns[:, j] * counts_or_plain(1.0 * unit_of, what, a)
        else:
            out[:, j] = columns[:, j] * scale.distance_to_counts(1.0 * unit_of, what)
    return out.ravel() if magnitude.ndim == 1 else out


#: What a :class:`~galil.errors.LimitError`'s value and limit measure, by its ``name``: a
#: position (the scale's offset and sign apply), a signed distance, a length (a magnitude:
#: along a path, a trigger distance), a speed or an acceleration (magnitudes).
UNIT_KINDS: dict[str, str] = {
    **dict.fromkeys(("FL", "BL", "PA", "DP", "position range"), "position"),
    **dict.fromkeys(("PR", "CD", "path point"), "distance"),
    **dict.fromkeys(("TC 30", "TC 31", "VP range", "CR radius", "speed schedule"), "length"),
    **dict.fromkeys(("SP", "JG", "HV", "VS", "speed", "axis speed"), "speed"),
    **dict.fromkeys(("AC", "DC", "VA", "VD", "acceleration", "axis acceleration"), "acceleration"),
}


def _in_unit(scale: Scale, counts: float, kind: str) -> pint.Quantity[float]:
    if kind == "position":
        return scale.counts_to_position(counts)
    q: Any  # (pint types abs() of a Quantity as a PlainQuantity)
    if kind in ("distance", "length"):
        q = scale.counts_to_distance(counts)
        return q if kind == "distance" else abs(q)
    q = scale.counts_to_rate(counts, 1 if kind == "speed" else 2)
    return abs(q)


def state_in_units(exc: LimitError, scale: Scale | None, kind: str | None = None) -> None:
    """Add to ``exc`` (raised in counts) its value and limit in ``scale``'s unit: the message
    gains `` (in user units: 25.1 mm / s, limit 25 mm / s)`` (a position ``reaches`` its limit,
    and says where the motion would ``end``; a :attr:`~galil.errors.LimitError.floor` says
    ``the smallest is 0.001 mm / s, you gave 0.0004 mm / s``), and
    ``value_in_units``/``limit_in_units`` are set. ``kind`` is ``"position"``, ``"distance"``,
    ``"length"``, ``"speed"`` or ``"acceleration"`` (default: :data:`UNIT_KINDS` by
    ``exc.name``). Nothing changes without a scale, without a value or a limit, for a name of
    no known kind, or when it was done."""
    kind = UNIT_KINDS.get(exc.name) if kind is None else kind
    value, limit = exc.value, exc.limit
    if scale is None or kind is None or value is None or limit is None:
        return
    if exc.value_in_units is not None:
        return  # (stated once already, by an inner handler)
    shown, top = _in_unit(scale, value, kind), _in_unit(scale, limit, kind)
    exc.value_in_units, exc.limit_in_units = shown, top
    text = f"{'reaches ' if kind == 'position' else ''}{shown:~.6g}, limit {top:~.6g}"
    if exc.floor:  # (the limit is the smallest value allowed: not read as the value given)
        text = f"the smallest is {top:~.6g}, you gave {shown:~.6g}"
    if kind == "position" and exc.end is not None:
        text += f", end {scale.counts_to_position(exc.end):~.6g}"
    exc.args = (f"{exc.args[0]} (in user units: {text})", *exc.args[1:])


PathSamples: TypeAlias = Readings
"""Positions sampled along a path: a float array in counts, or a pint Quantity array."""


def sampled_values(values: object, what: str) -> PathSamples:
    """Real numbers as floats: a Quantity stays a Quantity (of floats), never stripped.

    Raises:
        InvalidArgument: strings, complex numbers, NaN or infinity.
    """
    if is_quantity(values):
        q: Any = values
        out: PathSamples = q.__class__(_real_array(q.magnitude, what), q.units)
        return out
    return _real_array(values, what)


def _holds_quantities(values: object) -> bool:
    """Whether a list (or a list of rows) holds a pint Quantity."""
    if not isinstance(values, (list, tuple)):
        return False
    return any(
        is_quantity(v) or (isinstance(v, (list, tuple)) and any(map(is_quantity, v)))
        for v in values
    )


def _real_array(values: object, what: str) -> npt.NDArray[np.float64]:
    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as exc:
        if _holds_quantities(values):  # [1 * mm, 2 * mm]: numpy cannot make one array of it
            raise InvalidArgument(
                f"{what} is a list of Quantities; give one Quantity array instead, such as "
                "np.array([1, 2]) * ureg.mm or ureg.Quantity([1, 2], 'mm')"
            ) from exc
        raise InvalidArgument(f"{what} must be an array of numbers: {exc}") from exc
    if array.dtype.kind not in "iuf":
        hint = next((decimal_hint(v) for v in array.flat if decimal_hint(v)), "")
        raise InvalidArgument(
            f"{what} must hold real numbers, got {array.dtype} values ({values!r:.60}){hint}"
        )
    out = array.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise InvalidArgument(f"{what} holds NaN or infinity")
    return out
