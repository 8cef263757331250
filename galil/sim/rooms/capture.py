"""Automatic data capture: ``RA`` ``RD`` ``RC``, and the ``_RC`` / ``_RD`` operands.

``RA a[],b[]`` names the arrays and ``RD _RPA,_TPA`` the operands, one per array; ``RC n,m``
records them every ``2**n`` samples, ``m`` values (default: as many as the smallest array
holds; negative: round and round in the first ``|m|`` elements), ``RC 0`` stops. The values
are read in the servo loop at their exact samples, the first one in the sample ``RC`` ran in
(after the rest of its command line), so a recording of ``_RPA`` holds exactly what the motion
engine commanded. ``_RC`` is 1 while recording, ``_RD`` the index of the next element.

``RD`` takes the sources the library's ``record_source`` takes (decision 0097; a source it
refuses is TC 1, unsourced). Refusals: ``RC`` while recording (TC 80), without arrays or
sources or with fewer arrays than sources (TC 81), an array ``RA`` names that does not exist
(TC 82), ``m`` larger than the smallest array (TC 84), ``n`` outside the model's
``record_exponents`` (TC 6).
"""

from __future__ import annotations

from galil.errors import InvalidArgument
from galil.protocol.commands import record_source
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import handler, operand
from galil.sim.rooms.arrays import Arrays, fixed

__all__ = ["Capture"]


class Capture(Room):
    """RA, RD, RC and the recording itself."""

    requires = (Arrays,)

    def __init__(self, machine: Machine) -> None:
        super().__init__(machine)
        self.reset()

    def reset(self) -> None:
        self.arrays: list[str] = []
        self.sources: list[str] = []
        self.every = 0  # samples between values; 0: not recording
        self.count = 0  # values to record (0 with circular)
        self.circular = 0  # |m| of a circular recording
        self.index = 0  # _RD
        self._next = 0  # sample of the next value

    @property
    def recording(self) -> bool:
        return self.every > 0

    @handler("RA")
    def ra(self, args: str) -> str:
        arrays = self.machine.room(Arrays)
        names = []
        for field in split_fields(args):
            f = field.strip()
            if not f.endswith("[]"):
                raise Refused(55, "RA takes name[]")
            name = f[:-2].strip()
            if name not in arrays.arrays:
                raise Refused(82, f"undefined array {name!r}")
            names.append(name)
        if not names or len(names) > self.machine.spec.record_arrays:
            raise Refused(6, "RA takes 1 to 8 arrays")
        self.arrays = names
        return ""

    @handler("RD")
    def rd(self, args: str) -> str:
        sources = [f.strip() for f in split_fields(args) if f.strip()]
        if not sources or len(sources) > self.machine.spec.record_arrays:
            raise Refused(6, "RD takes 1 to 8 sources")
        for s in sources:
            try:  # the library's own table of RD sources (decision 0097)
                record_source(s, model=self.machine.spec)
            except InvalidArgument as exc:  # (TC 1 for a source RD refuses: unsourced)
                raise Refused(1, str(exc)) from None
            self.machine.interp.lookup(s)  # an operand the simulator lacks is refused now
        self.sources = sources
        return ""

    @handler("RC")
    def rc(self, args: str) -> str:
        i = self.machine.interp
        text = args.strip()
        if text == "?":
            return i.num(1 if self.recording else 0, "1.0") + "\r\n"
        fields = split_fields(text)
        n = i.evaluate(fields[0]) if fields[0].strip() else 0.0
        if n == 0:
            self.every = 0
            return ""
        lo, hi = self.machine.spec.record_exponents
        if n != int(n) or not lo <= n <= hi:
            raise Refused(6, f"RC n is {lo} to {hi}")
        if self.recording:
            raise Refused(80, "record mode already running")
        if not self.arrays or not self.sources or len(self.arrays) < len(self.sources):
            raise Refused(81, "no array or source specified")
        store = self.machine.room(Arrays).arrays
        if any(a not in store for a in self.arrays):
            raise Refused(82, "undefined array")
        room = min(len(store[a]) for a in self.arrays[: len(self.sources)])
        m = int(i.evaluate(fields[1])) if len(fields) > 1 and fields[1].strip() else room
        if m == 0 or abs(m) > room:
            raise Refused(84, "too many elements")
        self.every = 1 << int(n)
        self.count, self.circular = (0, -m) if m < 0 else (m, 0)
        self.index = 0
        self._next = self.machine.servo.sample
        return ""

    @operand("RC")
    def is_recording(self) -> float:
        return 1.0 if self.recording else 0.0

    @operand("RD")
    def pointer(self) -> float:
        return float(self.index)

    # ---- the servo loop ----------------------------------------------------------------
    def horizon(self, k: int) -> int:
        if self.recording:
            return min(k, max(1, self._next - self.machine.servo.sample))
        return k

    def service(self) -> None:
        if not self.recording or self.machine.servo.sample < self._next:
            return
        interp = self.machine.interp
        store = self.machine.room(Arrays).arrays
        try:
            values = [fixed(interp.lookup(s)) for s in self.sources]
            for name, value in zip(self.arrays, values, strict=False):
                store[name][self.index] = value
        except (Refused, KeyError, IndexError):
            self.every = 0  # an array was deallocated or a source vanished: stop
            return
        self.index += 1
        self._next += self.every
        if self.circular:
            self.index %= self.circular
        elif self.index >= self.count:
            self.every = 0
