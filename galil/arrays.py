"""Arrays and variables on the controller (``controller.arrays``, ``controller.variables``).

Arrays are dimensioned with ``DM``, filled from the host with ``QD``, read back with ``QU``
(as numpy arrays), listed with ``LA`` and freed with ``DA``; variables are read with ``MG``,
written with an assignment, listed with ``LV`` and freed with ``DA``. Names follow the
controller's rules (a letter, then up to seven letters or digits, case-sensitive; never an
upper-case command such as ``CD0``, while ``data`` is a name: decision 0060) and sizes the
model's array space; both are checked before a byte is sent. Values are the controller's
numbers: 32-bit with four decimals (1/65536 resolution)::

    dmc.arrays.define("speeds", 4)
    dmc.arrays.download("speeds", [1000, 2000, 4000, 8000])
    dmc.arrays.upload("speeds")          # array([1000., 2000., 4000., 8000.])
    dmc.variables["gain"] = 2.5
    dmc.variables.get("offset", 0.0)     # a MutableMapping: get, pop, in, del, dict(...)
"""

from __future__ import annotations

import contextlib
import numbers
import re
from collections.abc import ItemsView, Iterator, KeysView, MutableMapping, ValuesView

import numpy as np
import numpy.typing as npt

from galil.errors import (
    CommandError,
    FixedAttributes,
    GalilError,
    InvalidArgument,
    LimitError,
    ProtocolError,
    ReadOnly,
    UnknownVariableError,
    decimal_hint,
)
from galil.link import CommandLink, check_flag
from galil.models import INT32_MAX, INT32_MIN
from galil.protocol import commands as cmds
from galil.protocol.numbers import read_one

__all__ = ["CAPTURE_ARRAYS", "LIBRARY_VARIABLES", "Arrays", "Variables"]

_LA_LINE = re.compile(r"\s*([A-Za-z][A-Za-z0-9]*)\s*\[\s*(\d+)\s*\]")
_LV_LINE = re.compile(r"\s*([A-Za-z][A-Za-z0-9]*)\s*=\s*(\S+)")
#: The variables the library's own routines read while they run (the watchdog's, a speed
#: schedule's, ``io.wait_for_input``'s): freeing one would stop such a routine with an error
#: (a watchdog would stop guarding, silently), so ``del`` refuses them and ``clear`` keeps them.
LIBRARY_VARIABLES = frozenset({"gwbeat", "gwlimit", "gwfire", "gsbegin", "ginput", "ginlevel"})
#: The arrays a capture records into (one per source, ``RD`` takes 8 at most): a capture frees
#: them before it sets them up and once it is read, so ``define`` and ``download`` refuse them
#: (decision 0097), as ``del`` refuses the library's variables.
CAPTURE_ARRAYS = tuple(f"gcap{i}" for i in range(8))
_DA_NAMES = 6  # names per DA line: 6 of 8 letters and commas stay within 80 characters


def _values(values: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    """``values`` as float64, each a real number: a bool, a string or a complex number is
    refused (decision 0026: numpy would take ``True`` as 1 and ``"1"`` as 1.0).

    Raises:
        InvalidArgument: not a non-empty 1-D sequence of finite real numbers.
        LimitError: a value outside the controller's 32-bit range.
    """
    if isinstance(values, (str, bytes)):
        raise InvalidArgument(f"values for {name}[] are numbers, not {values!r:.40}")
    try:
        raw = values if isinstance(values, np.ndarray) else np.asarray(values, dtype=object)
    except (TypeError, ValueError) as exc:
        raise InvalidArgument(f"values for {name}[] must be numbers: {exc}") from exc
    if raw.ndim != 1 or raw.size == 0:
        raise InvalidArgument(f"values for {name}[] must be a non-empty 1-D sequence")
    if raw.dtype.kind not in "iuf":  # (bool, complex, strings, objects: look at each)
        for i, v in enumerate(raw.tolist()):
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise InvalidArgument(
                    f"{name}[{i}] is {v!r:.40}: values for {name}[] are real numbers, never"
                    f" a bool, a string or a complex number{decimal_hint(v)}"
                )
    try:
        data = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:  # OverflowError: 10**400
        raise InvalidArgument(f"values for {name}[] must be numbers: {exc}") from exc
    if not np.all(np.isfinite(data)):
        i = int(np.argmin(np.isfinite(data)))
        raise InvalidArgument(f"{name}[{i}] is {data[i]!r}: NaN and infinity cannot be sent")
    bad = np.flatnonzero((data < INT32_MIN) | (data >= INT32_MAX + 1))
    if bad.size:
        i = int(bad[0])
        raise LimitError(
            f"{name}[{i}] = {data[i]:.6g} is outside the controller's 32-bit range",
            name=f"{name}[{i}]",
            value=float(data[i]),
            limit=INT32_MAX if data[i] > 0 else INT32_MIN,
        )
    return data


def _index(value: object, what: str) -> int:
    """An element index as an ``int``: an integer, numpy's too (never a bool), >= 0.

    Raises:
        InvalidArgument: naming ``what``.
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 0:
        return int(value)
    raise InvalidArgument(f"{what} must be a whole number index >= 0, not {value!r:.60}")


_DIGITS, _DECIMALS = 10, 4
_READ_VF = cmds.vf(_DIGITS, _DECIMALS)  # what the read format {Z10.4} prints, for QU and LV
#: The most bytes a number takes in the read format (the widest VF prints no wider): its
#: sign or a space, ten digits, the point, four decimals.
_NUMBER_BYTES = 1 + _DIGITS + 1 + _DECIMALS
#: After the last value of a ``QU`` (CR LF, ^Z, ``:``) and around ``LV``'s reply.
_END_BYTES = 4


def _qu_reply_bytes(elements: int) -> int:
    """The most bytes ``QU``'s reply of ``elements`` values can hold (a comma after each)."""
    return (_NUMBER_BYTES + 1) * elements + _END_BYTES


def _lv_reply_bytes(link: CommandLink) -> int:
    """The most bytes ``LV``'s reply can hold: every variable the model has, a line each
    (its name, `` = ``, a number, CR LF)."""
    model = link.model
    return (model.variable_length + 3 + _NUMBER_BYTES + 2) * model.variables + _END_BYTES


def _la_reply_bytes(link: CommandLink) -> int:
    """The most bytes ``LA``'s reply can hold: every array the model has, a line each (a
    space, its name, its size in brackets, CR LF)."""
    model = link.model
    line = 1 + model.variable_length + len(str(model.array_elements)) + 2 + 2
    return line * model.arrays + _END_BYTES


def _in_read_format(link: CommandLink, command: cmds.Command, reply_bytes: int) -> str:
    """The reply to ``command`` (``QU``, ``LV``: printed in VF, with no format of their own;
    a transfer of at most ``reply_bytes``) with ``VF 10.4`` for it and the user's (or a
    program's) VF put back right after.

    A VF set in between by a running program can still change the reply; the strict parse
    of its numbers (four decimals each) refuses the forms that would misread (decision 0032).
    """
    try:
        vf = round(link.query_operands(["_VF"])[0], 1)
    except CommandError:  # a firmware without _VF: as it prints (the parse still checks)
        vf = 10.4
    if vf == 10.4:
        return link.transfer(command, reply_bytes).text
    digits = int(vf)
    restore = cmds.vf(digits, round(abs(vf - digits) * 10))
    try:
        # (inside: a VF 10.4 whose reply is lost may still have been taken)
        link.exchange(_READ_VF)
        text = link.transfer(command, reply_bytes).text
    except BaseException:
        with contextlib.suppress(GalilError):
            link.exchange(restore)
        raise
    link.exchange(restore)
    return text


def _not_a_capture_array(name: str, what: str) -> None:
    """Refuse one of :data:`CAPTURE_ARRAYS`: a capture frees and rebuilds them (decision 0097).

    Raises:
        InvalidArgument: ``name`` is a capture's array.
    """
    if name in CAPTURE_ARRAYS:
        raise InvalidArgument(
            f"{name!r} is a name captures record into (gcap0 .. gcap7): a capture frees it"
            f" before it records and once it is read, so it is not {what} here; give your"
            " array another name"
        )


class Arrays(FixedAttributes):
    """The controller's arrays.

    Args:
        link: the command link.
    """

    link: ReadOnly[CommandLink] = ReadOnly()

    def __init__(self, link: CommandLink) -> None:
        self._link = link

    def list(self) -> dict[str, int]:
        """Every array and its size (``LA``; its reply timeout covers every array the model
        can hold, decision 0064)."""
        text = self.link.transfer(cmds.la(), _la_reply_bytes(self.link)).text
        out: dict[str, int] = {}
        for line in text.splitlines():
            if not line.strip():
                continue
            m = _LA_LINE.match(line)
            if m is None:
                raise self.link.error(ProtocolError, f"LA answered a line {line!r}")
            out[m.group(1)] = int(m.group(2))
        return out

    def _size(self, name: str) -> int:
        """How many elements array ``name`` has, from the ``LA`` listing (gclib reads array
        sizes this way; ``MG name[-1]`` is in the DMC-4103 reference, decision 0025, but not
        in the older ones, so it is not relied on).

        Raises:
            InvalidArgument: there is no such array.
        """
        size = self.list().get(name)
        if size is None:
            raise InvalidArgument(
                f"there is no array {name!r} on the controller (define it first)",
                model=self.link.model.name,
            )
        return size

    def define(self, name: str, size: int, *, replace: bool = False) -> None:
        """Dimension array ``name`` with ``size`` elements, all zero (``DM``).

        Args:
            name: the array's name.
            size: its number of elements (within the model's array space): an ``int`` or a
                numpy integer; a float is refused, a whole one too (``10.0``), and a bool.
            replace: free an array of that name first (its values are lost); without it an
                existing array is refused by the controller.

        Raises:
            InvalidArgument: a bad name, a capture's name (:data:`CAPTURE_ARRAYS`), a size
                that is not an integer, or one outside the model's array space.
            CommandError: the controller refused (the name exists, no room left).
        """
        check_flag(replace, "replace")
        command = cmds.dm(name, size, model=self.link.model)
        _not_a_capture_array(name, "defined")
        parts = [command]
        if replace and name in self.list():
            parts.insert(0, cmds.da(name))
        self.link.command_line(parts)

    def delete(self, name: str) -> None:
        """Free array ``name`` (``DA name[]``).

        Raises:
            InvalidArgument: a bad name.
            CommandError: there is no such array.
        """
        self.link.command_line([cmds.da(name)])

    def download(self, name: str, values: npt.ArrayLike, *, first: int = 0) -> None:
        """Write ``values`` into array ``name`` from element ``first`` (``QD``; an ``int``,
        numpy's too).

        The array's size is read first (``LA``), so values that would not fit are
        refused before any of them is sent. The reply timeout covers the values' bytes at the
        link's byte rate (decision 0064): a large download over a slow serial line has time.

        Raises:
            InvalidArgument: a bad name or index, a capture's name (:data:`CAPTURE_ARRAYS`),
                values that are not finite real numbers (a bool, a string or a complex number
                is refused, decision 0026), no such array, more values than fit.
            LimitError: a value outside the controller's 32-bit range.
        """
        cmds.array_name(name)
        _not_a_capture_array(name, "written")
        data = _values(values, name)
        first = _index(first, "first")
        size = self._size(name)
        if first + data.size > size:
            raise InvalidArgument(
                f"{data.size} values from {name}[{first}] do not fit {name}[] of {size}",
                model=self.link.model.name,
            )
        command = cmds.qd(name, data.tolist(), first)
        self.link.transfer(command)

    def upload(
        self, name: str, first: int | None = None, last: int | None = None
    ) -> npt.NDArray[np.float64]:
        """Read array ``name`` (elements ``first`` to ``last``, default all; integers, numpy's
        too) with ``QU``.

        The array's size is read first (``LA``), so a range outside the array is
        refused before the upload is sent. The reply timeout covers the most bytes the range
        can take at the link's byte rate (decision 0064).

        Raises:
            InvalidArgument: a bad name or range, a range outside the array, or no such array.
            ProtocolError: the reply is not the numbers asked for.
        """
        first = None if first is None else _index(first, "first")
        last = None if last is None else _index(last, "last")
        cmds.qu(name, first, last)  # a bad name or index: refused before the size query
        size = self._size(name)
        lo = 0 if first is None else first
        hi = size - 1 if last is None else last
        if not lo <= hi < size:
            shown = f"{lo}..{hi}" if last is not None else f"{lo}.."
            raise InvalidArgument(
                f"{name}[{shown}] is outside {name}[] of {size} (indices 0..{size - 1})",
                model=self.link.model.name,
            )
        command = cmds.qu(name, lo, hi, delim=1)
        text = _in_read_format(self.link, command, _qu_reply_bytes(hi - lo + 1))
        try:
            out = np.array(
                [read_one(x) for x in re.split(r"[,\r\n]+", text) if x.strip()],
                dtype=np.float64,
            )
        except ProtocolError as exc:
            raise self.link.error(ProtocolError, f"{command.text!r} answered {text!r}") from exc
        if out.size != hi - lo + 1:
            raise self.link.error(
                ProtocolError, f"{command.text!r} answered {out.size} values, not {hi - lo + 1}"
            )
        return out

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.list()

    def __repr__(self) -> str:
        return f"<Arrays of {self.link.model.name}>"


class Variables(MutableMapping[str, float], FixedAttributes):
    """The controller's variables, a mapping of name to value: ``variables["x"]`` reads one
    (``MG x``), ``variables["x"] = 2`` sets it, ``del variables["x"]`` frees it (``DA x``);
    ``get``, ``pop``, ``in``, ``keys()``, ``items()`` and ``dict(variables)`` work as on a
    dict. A name the controller does not have raises :class:`~galil.errors.UnknownVariableError`
    (a ``CommandError`` and a ``KeyError``).

    Every access asks the controller: iteration, ``len``, ``in``, ``keys()``, ``items()`` and
    ``values()`` list them with one ``LV`` (``items()`` and ``values()`` are that listing, not
    live views); ``dict(variables)`` lists the names, then reads each with ``MG``:
    :meth:`list` reads them all in one round trip.

    Args:
        link: the command link.
    """

    link: ReadOnly[CommandLink] = ReadOnly()

    def __init__(self, link: CommandLink) -> None:
        self._link = link

    def read(self, name: str) -> float:
        """The value of variable ``name`` (``MG name``).

        Raises:
            InvalidArgument: a bad name.
            UnknownVariableError: there is no such variable (TC 1); also a ``KeyError``.
        """
        cmds.variable_name(name)
        try:
            return self.link.query_operands([name])[0]
        except CommandError as exc:
            if exc.code != 1:
                raise
            # The link's hint (commands are upper case) misleads here: a variable's name is
            # the user's, in any case.
            raise UnknownVariableError(
                f"there is no variable {name!r} on the controller (TC 1: {exc.text}); "
                f"variables.list() names those there, variables.write({name!r}, value) makes it",
                name=name,
                code=exc.code,
                text=exc.text,
                command=exc.command,
                model=exc.model,
                recent=exc.recent,
            ) from None

    def write(self, name: str, value: float) -> None:
        """Set variable ``name`` (it is created if needed).

        Raises:
            InvalidArgument: a bad name or value.
            LimitError: a value outside the controller's 32-bit range.
        """
        command = cmds.assign(name, value)
        _values([value], name)
        self.link.command_line([command])

    def delete(self, name: str) -> None:
        """Free variable ``name`` (``DA name``); it is read first (``MG``), so a name the
        controller does not have is said, not passed over.

        Raises:
            InvalidArgument: a bad name.
            UnknownVariableError: there is no such variable; also a ``KeyError``.
        """
        command = cmds.da_variables(name)
        if name in LIBRARY_VARIABLES:
            raise InvalidArgument(
                f"{name!r} is the library's own variable (its routines read it while they run: "
                "the watchdog, a speed schedule, io.wait_for_input); it is not freed"
            )
        self.read(name)
        self.link.command_line([command])

    def list(self) -> dict[str, float]:
        """Every variable and its value (``LV``)."""
        command = cmds.lv()
        text = _in_read_format(self.link, command, _lv_reply_bytes(self.link))
        out: dict[str, float] = {}
        for line in text.splitlines():
            if not line.strip():
                continue
            m = _LV_LINE.match(line)
            if m is None:
                raise self.link.error(ProtocolError, f"LV answered a line {line!r}")
            try:
                out[m.group(1)] = read_one(m.group(2))
            except ProtocolError as exc:
                raise self.link.error(ProtocolError, f"LV answered a line {line!r}") from exc
        return out

    def __getitem__(self, name: str) -> float:
        return self.read(name)

    def __setitem__(self, name: str, value: float) -> None:
        self.write(name, value)

    def __delitem__(self, name: str) -> None:
        self.delete(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self.list())

    def __len__(self) -> int:
        return len(self.list())

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.list()

    def keys(self) -> KeysView[str]:
        """The names, from one ``LV``."""
        return self.list().keys()

    def items(self) -> ItemsView[str, float]:
        """The names and values, from one ``LV`` (not a live view)."""
        return self.list().items()

    def values(self) -> ValuesView[float]:
        """The values, from one ``LV`` (not a live view)."""
        return self.list().values()

    def clear(self) -> None:
        """Free every variable but the library's own (:data:`LIBRARY_VARIABLES`), listed with
        ``LV``, with ``DA`` (a few names a line)."""
        names = [n for n in self.list() if n not in LIBRARY_VARIABLES]
        for i in range(0, len(names), _DA_NAMES):
            self.link.command_line([cmds.da_variables(*names[i : i + _DA_NAMES])])

    def __repr__(self) -> str:
        return f"<Variables of {self.link.model.name}>"
