"""Arrays and variables: ``DM`` ``DA`` ``LA`` ``LV`` ``QU`` ``QD``, and ``arr[i]`` in programs.

Arrays hold numbers with the controller's 1/65536 resolution, zero when dimensioned. The model
bounds how many arrays and elements there are (``arrays``, ``array_elements``; TC 67 and 66
beyond) and how many variables (``variables``; TC 67). Choices where the sources are silent:

- ``DM`` of an array that exists is refused (TC 82 is kept for undefined arrays; TC 4 here):
  deallocate it first (``DA name[]``), so a program never loses data by a typo;
- ``LA`` prints ``name[size]`` and ``LV`` ``name= value`` (VF format), one per line, sorted;
- ``QU name[],first,last,delim`` prints the values separated by commas (delim 1) or CR LF
  (delim 0), then CR LF and ^Z; ``QD name[],first,last`` takes values separated by commas,
  CR or CR LF up to ``\\``, and refuses too many (TC 84), too few or a bad number (TC 83);
- ``_DM`` is the number of array elements still free;
- ``name[-1]`` in an expression (``MG name[-1]``) is the array's size, as Galil's command
  reference documents it (DMC-4103 reference, DM: "Typing in array name with [-1] element
  marked reports the number of elements for that array", with ``MG "MyArray contains",
  MyArray[-1]," elements"`` answering ``1000.0000``; ``[,]``: "n = -1 returns the array
  length"; docs/decisions/0025). Its example names the DMC-4000 and 30010; that the older
  cards and the RIO (whose index table starts at 0) answer it too is assumed. Assigning to
  it is refused (TC 56).
"""

from __future__ import annotations

import math
import re

from galil.models import INT32_MAX, INT32_MIN
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused, quantised, split_fields
from galil.sim.registry import Collect, handler, operand

__all__ = ["Arrays", "fixed"]

_ARRAY = re.compile(r"\s*([A-Za-z][A-Za-z0-9]*)\[(.*)\]\s*")
_VALUE = re.compile(r"-?(?:\d+(?:\.\d*)?|\.\d+)")


def fixed(value: float) -> float:
    """A value as the controller stores it (32.16 fixed point).

    Raises:
        Refused: TC 6, out of range.
    """
    if not math.isfinite(value) or not INT32_MIN <= value < INT32_MAX + 1:
        raise Refused(6, "value out of range")
    return quantised(value)


class Arrays(Room):
    """The array table and the variable listing."""

    def __init__(self, machine: Machine) -> None:
        super().__init__(machine)
        self.arrays: dict[str, list[float]] = {}
        interp = machine.interp
        interp.element = self.element
        interp.store_element = self.store

    def reset(self) -> None:
        self.arrays = {}

    def burn(self, name: str) -> object | None:
        # BV: "saves the controller variables and arrays" (DMC-4103 reference).
        return (self.machine.interp.variables, self.arrays) if name == "BV" else None

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, tuple)
        self.machine.interp.variables, self.arrays = saved

    # ---- elements in expressions -------------------------------------------------------
    def _array(self, name: str) -> list[float]:
        found = self.arrays.get(name)
        if found is None:
            raise Refused(82, f"undefined array {name!r}")
        return found

    def _index(self, values: list[float], index: float) -> int:
        if index != int(index) or not 0 <= index < len(values):
            raise Refused(56, "array index out of range")
        return int(index)

    def element(self, name: str, index: float) -> float:
        values = self._array(name)
        if index == -1:  # element -1 reads the array's size
            return float(len(values))
        return values[self._index(values, index)]

    def store(self, name: str, index: float, value: float) -> None:
        values = self._array(name)
        values[self._index(values, index)] = fixed(value)

    # ---- DM DA LA LV -------------------------------------------------------------------
    def _name(self, text: str) -> str:
        name = text.strip()
        if not self.machine.interp.is_name(name):
            raise Refused(57, f"bad array name {name!r}")
        return name

    @handler("DM")
    def dm(self, args: str) -> str:
        if args.strip() == "?":
            return self.machine.interp.num(self.free(), "10.0") + "\r\n"
        spec = self.machine.spec
        wanted: dict[str, int] = {}
        for field in split_fields(args):
            m = _ARRAY.fullmatch(field)
            if m is None:
                raise Refused(55, "DM takes name[size]")
            name = self._name(m.group(1))
            size = self.machine.interp.evaluate(m.group(2))
            if size != int(size) or size < 1:
                raise Refused(6, "array size must be a positive whole number")
            if name in self.arrays or name in wanted:
                raise Refused(4, f"array {name} exists; DA {name}[] first")
            wanted[name] = int(size)
        if len(self.arrays) + len(wanted) > spec.arrays:
            raise Refused(67, "too many arrays")
        if sum(wanted.values()) > self.free():
            raise Refused(66, "array space full")
        for name, size in wanted.items():
            self.arrays[name] = [0.0] * size
        return ""

    def free(self) -> int:
        """Array elements still free."""
        used = sum(len(v) for v in self.arrays.values())
        return self.machine.spec.array_elements - used

    @operand("DM")
    def free_elements(self) -> float:
        return float(self.free())

    @handler("DA")
    def da(self, args: str) -> str:
        variables = self.machine.interp.variables
        arrays: list[str] = []
        plain: list[str] = []
        for field in split_fields(args):
            # An array is written ``name[]`` or, as in DA's own examples (``DA*[0]``,
            # ``DA Cars[0],Total``), ``name[0]``; ``*`` is every variable, ``*[]`` every array.
            f = field.strip()
            is_array = f.endswith(("[]", "[0]"))
            base = f[: f.rindex("[")].strip() if is_array else f
            if base == "*" and is_array:
                arrays += list(self.arrays)
            elif base == "*":
                plain += list(variables)
            elif is_array:
                name = self._name(base)
                if name not in self.arrays:
                    raise Refused(82, f"undefined array {name!r}")
                arrays.append(name)
            else:
                plain.append(self._name(f))
        for name in arrays:
            self.arrays.pop(name, None)
        for name in plain:
            variables.pop(name, None)
        return ""

    @handler("LA")
    def la(self, args: str) -> str:
        return "".join(f"{n}[{len(v)}]\r\n" for n, v in sorted(self.arrays.items()))

    @handler("LV")
    def lv(self, args: str) -> str:
        i = self.machine.interp
        return "".join(f"{n}={i.vnum(v)}\r\n" for n, v in sorted(i.variables.items()))

    # ---- QU QD -------------------------------------------------------------------------
    def _range(self, fields: list[str], values: list[float]) -> tuple[int, int]:
        i = self.machine.interp
        first = int(i.evaluate(fields[0])) if fields and fields[0].strip() else 0
        last = int(i.evaluate(fields[1])) if len(fields) > 1 and fields[1].strip() else None
        if last is None:
            last = len(values) - 1
        if not 0 <= first <= last < len(values):
            raise Refused(56, "array index out of range")
        return first, last

    def _target(self, args: str) -> tuple[str, list[str]]:
        fields = split_fields(args)
        head = fields[0].strip()
        if not head.endswith("[]"):
            raise Refused(55, "name[] expected")
        return self._name(head[:-2]), fields[1:]

    @handler("QU")
    def qu(self, args: str) -> str:
        name, rest = self._target(args)
        values = self._array(name)
        first, last = self._range(rest, values)
        delim = int(self.machine.interp.evaluate(rest[2])) if len(rest) > 2 else 0
        i = self.machine.interp
        sep = "," if delim == 1 else "\r\n"
        text = sep.join(i.vnum(v) for v in values[first : last + 1])
        return text + "\r\n\x1a"

    @handler("QD")
    def qd(self, args: str) -> Collect:
        name, rest = self._target(args)
        values = self._array(name)
        first, last = self._range(rest, values)

        def done(data: str) -> str:
            items = [x for x in re.split(r"[,\r\n]+", data.strip()) if x]
            if len(items) > last - first + 1:
                raise Refused(84, "too many elements")
            if len(items) < last - first + 1 or not all(_VALUE.fullmatch(x) for x in items):
                raise Refused(83, "not a valid number")
            new = [fixed(float(x)) for x in items]
            values[first : last + 1] = new
            return ""

        return Collect(done)
