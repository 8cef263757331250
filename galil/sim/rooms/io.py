"""Digital and analog I/O: SB CB OB OP AO AQ DQ AI, ``@IN @OUT @AN @AO``, ``_TI _OP _AQ``.

Channels are numbered from the model's ``io_first`` (1 on DMC controllers, 0 on the RIO).
Inputs read high when nothing is connected; a test sets them with :meth:`IO.set_input` and
:meth:`IO.set_analog_input` (``galil.testing`` reaches these). ``_TIn`` is input bank ``n``
(8 inputs a byte), ``_OPn`` output word ``n`` (16 outputs). ``AI n`` holds until input ``n``
is high (``AI -n``: low), from the host or a program thread.

An analog input reads the volts on its pin (the test hook's) clipped to the range its ``AQ``
code sets, per input (``_AQn`` reads the code): :data:`AQ_RANGES` on the DMC controllers and
the RIO-47120/47300, :data:`AQ_RANGES_47100` on the RIO-47100. At power-on each input's code
is the one of its model's range (:meth:`~galil.models.ModelSpec.analog_input_range`: AQ 2,
±10 V; the DMC-30010's input 2, 0-5 V, AQ 3; the RIO-47100's AQ 0). ``@AN[n]`` and the data
record read the same range. Analog values in the data record are 16-bit counts of that range:
two's complement over ±R (32768/R counts/V), unsigned over 0-R (65536/R: the 30010's input 2
at 13107.2 counts/V, EPICS); the outputs at ±10 V full scale (an assumption for DQ 4; the
RIO-47100's 0-5 V outputs too).
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

import numpy as np
import numpy.typing as npt

from galil.models import ModelSpec
from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import OperandKind, Wait, function, handler, operand

__all__ = ["AQ_RANGES", "AQ_RANGES_47100", "IO", "aq_ranges"]

#: ``AQ n,code`` -> the volts input ``n`` reads, lowest and highest (wave-2 facts, I/O: EPICS's
#: decoding of ``_AQn`` and the RIO-47120 user manual p.44 agree: 1 ±5 V, 2 ±10 V (the
#: default), 3 0-5 V, 4 0-10 V, all in 16-bit counts). A negative code (differential, [U]) is
#: taken where its positive one is and reads the same range: the pairing of inputs it means
#: is not modelled. That the DMC-30010 (input 2 included) and the RIO-47300 take these codes
#: is [U]: the simulator took them before AQ set a range, and keeps taking them.
AQ_RANGES: dict[int, tuple[float, float]] = {
    1: (-5.0, 5.0),
    2: (-10.0, 10.0),
    3: (0.0, 5.0),
    4: (0.0, 10.0),
}
#: The RIO-47100's codes (RIO-47xxx user manual p.44: AQ 0 0-5 V, AQ 1 ±5 V, the only two it
#: lists); 2, 3 and 4 are refused there. Its record counts of them as EPICS decodes AQ 3 and
#: AQ 1 [U: the manual's Modbus table gives 0 ... 0x7FF0 for both ranges, not the record's].
AQ_RANGES_47100: dict[int, tuple[float, float]] = {0: (0.0, 5.0), 1: (-5.0, 5.0)}


def aq_ranges(spec: ModelSpec) -> dict[int, tuple[float, float]]:
    """The AQ codes ``spec`` takes and the range each sets: :data:`AQ_RANGES_47100` on a RIO
    whose inputs read 0-5 V at power-on (the RIO-47100, and the generic RIO, which has its
    I/O), :data:`AQ_RANGES` everywhere else."""
    rio = not spec.axes and spec.io_first == 0
    return AQ_RANGES_47100 if rio and spec.analog_in_range == (0.0, 5.0) else AQ_RANGES


class IO(Room):
    """The controller's general-purpose inputs, outputs and analog channels."""

    def reset(self) -> None:
        spec = self.machine.spec
        self.first = spec.io_first
        self.inputs = [True] * spec.digital_inputs
        self.outputs = [False] * spec.digital_outputs
        self.analog_in = [0.0] * spec.analog_inputs  # the volts on the pins
        self.analog_out = [0.0] * spec.analog_outputs
        # DQ: each output's range code, where the model has DQ (spec.dq_ranges: the
        # RIO-47120's, RIO-UM p44); at power-on the code of its analog_out_range.
        out_code = {span: code for code, span in spec.dq_ranges.items()}
        self.dq = [out_code.get(spec.analog_out_range, 0)] * spec.analog_outputs
        self.aq_ranges = aq_ranges(spec)
        code_of = {span: code for code, span in self.aq_ranges.items()}
        self.aq = [
            code_of[spec.analog_input_range(self.first + k)] for k in range(spec.analog_inputs)
        ]
        # (a pin's volts are kept within the widest range any code sets: that clips nothing
        # a reading would not)
        self.pin_range = (
            min(lo for lo, _ in self.aq_ranges.values()),
            max(hi for _, hi in self.aq_ranges.values()),
        )

    def burn(self, name: str) -> object | None:
        # The BN table: SB CB OP (the outputs), AQ and DQ [U: DQ burned as AQ is]; the
        # inputs are the outside world's.
        return (list(self.outputs), list(self.aq), list(self.dq)) if name == "BN" else None

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, tuple)
        self.outputs, self.aq, self.dq = saved

    # ---- channels ------------------------------------------------------------------------
    def channel(self, n: float, count: int) -> int:
        """The list index of channel ``n`` among ``count`` (TC 6 if there is none)."""
        k = int(n) - self.first
        if n != int(n) or not 0 <= k < count:
            raise Refused(6, "no such I/O point")
        return k

    def set_input(self, n: int, high: bool) -> None:
        """Test hook: drive digital input ``n`` high or low."""
        self.inputs[self.channel(n, len(self.inputs))] = bool(high)

    def set_analog_input(self, n: int, volts: float) -> None:
        """Test hook: put ``volts`` on analog input ``n``'s pin (a reading clips them to the
        range its AQ sets)."""
        k = self.channel(n, len(self.analog_in))
        lo, hi = self.pin_range
        self.analog_in[k] = min(max(float(volts), lo), hi)

    def _input_ranges(self) -> list[tuple[float, float]]:
        """Each input's range, as its AQ code sets it."""
        return [self.aq_ranges[abs(code)] for code in self.aq]

    def analog_volts(self, k: int) -> float:
        """The volts input ``first + k`` reads: its pin's, clipped to its AQ range."""
        lo, hi = self.aq_ranges[abs(self.aq[k])]
        return min(max(self.analog_in[k], lo), hi)

    def input_bits(self) -> int:
        """Every input as one integer (bit k = input ``first + k``)."""
        return sum(1 << k for k, high in enumerate(self.inputs) if high)

    def output_bits(self) -> int:
        """Every output as one integer (bit k = output ``first + k``)."""
        return sum(1 << k for k, on in enumerate(self.outputs) if on)

    # ---- functions and operands --------------------------------------------------------
    @function("IN")
    def read_input(self, n: float) -> float:
        return 1.0 if self.inputs[self.channel(n, len(self.inputs))] else 0.0

    @function("OUT")
    def read_output(self, n: float) -> float:
        return 1.0 if self.outputs[self.channel(n, len(self.outputs))] else 0.0

    @function("AN")
    def read_analog(self, n: float) -> float:
        return round(self.analog_volts(self.channel(n, len(self.analog_in))), 4)

    @function("AO")
    def read_analog_output(self, n: float) -> float:
        return round(self.analog_out[self.channel(n, len(self.analog_out))], 4)

    @operand("TI", kind=OperandKind.INDEX)
    def input_bank(self, index: str) -> float:
        if not index.isdigit():
            raise Refused(4, "bank number")
        return float(self.input_bits() >> (8 * int(index)) & 0xFF)

    @operand("OP", kind=OperandKind.INDEX)
    def output_word(self, index: str) -> float:
        if not index.isdigit():
            raise Refused(4, "word number")
        return float(self.output_bits() >> (16 * int(index)) & 0xFFFF)

    @operand("AQ", kind=OperandKind.INDEX)
    def analog_range(self, index: str) -> float:
        """``_AQn``: input n's AQ code (EPICS reads ``MG{Z10.0}_AQn``; IRTF ``MG _AQ0``)."""
        if not index.isdigit():
            raise Refused(4, "input number")
        return float(self.aq[self.channel(int(index), len(self.aq))])

    # ---- commands ------------------------------------------------------------------------
    def _output(self, args: str) -> int:
        fields = split_fields(args)
        if len(fields) != 1 or not fields[0].strip():
            raise Refused(4, "one output number")
        return self.channel(self.machine.interp.evaluate(fields[0]), len(self.outputs))

    @handler("SB")
    def sb(self, args: str) -> str:
        self.outputs[self._output(args)] = True
        return ""

    @handler("CB")
    def cb(self, args: str) -> str:
        self.outputs[self._output(args)] = False
        return ""

    @handler("OB")
    def ob(self, args: str) -> str:
        fields = split_fields(args)
        if len(fields) != 2:
            raise Refused(50, "OB n,state")
        i = self.machine.interp
        k = self.channel(i.evaluate(fields[0]), len(self.outputs))
        self.outputs[k] = i.evaluate(fields[1]) != 0
        return ""

    # OP n0,n1,...: banks of the model's op_bits. 8-bit banks are sourced for the RIO (IRTF
    # notes) and for outputs 1-8 (DMC-3425 manual); the banks past them are an assumption
    # (models.py _OP_ASSUMPTION). The DMC-41x3 takes one field for outputs 1-16, at most 255
    # on a 1-4 axis controller (DMC-4103 command reference, OP).
    @handler("OP")
    def op(self, args: str) -> str:
        fields = split_fields(args)
        values = [None if not f.strip() else int(self.machine.interp.evaluate(f)) for f in fields]
        width = min(self.machine.spec.op_bits, max(8, len(self.outputs)))
        if len(values) * width > max(width, len(self.outputs) + width - 1):
            raise Refused(50, "too many OP fields")
        if any(v is not None and not 0 <= v < 2**width for v in values):
            raise Refused(6, f"OP bank is 0..{2**width - 1}")
        for bank, v in enumerate(values):
            if v is None:
                continue
            for bit in range(width):
                k = bank * width + bit
                if k < len(self.outputs):
                    self.outputs[k] = bool(v >> bit & 1)
        return ""

    @handler("AO")
    def ao(self, args: str) -> str:
        fields = split_fields(args)
        if len(fields) != 2:
            raise Refused(50, "AO n,volts")
        i = self.machine.interp
        k = self.channel(i.evaluate(fields[0]), len(self.analog_out))
        volts = i.evaluate(fields[1])
        lo, hi = self.out_range(k)
        if not lo <= volts <= hi:
            raise Refused(6, "AO out of range")
        self.analog_out[k] = volts
        return ""

    def out_range(self, k: int) -> tuple[float, float]:
        """The volts output ``first + k`` takes: its DQ code's range, or the model's fixed
        ``analog_out_range`` where it has no DQ."""
        ranges = self.machine.spec.dq_ranges
        return ranges[self.dq[k]] if ranges else self.machine.spec.analog_out_range

    @handler("DQ")
    def dq_command(self, args: str) -> str:
        """``DQ n,code``: analog output n's range (RIO-47120: 1 0-5 V, 2 0-10 V, 3 ±5 V, 4
        ±10 V; RIO-UM p44). A model without DQ answers TC 1 [U: the code it gives]; an
        output already beyond the new range is clipped to it [U]."""
        ranges = self.machine.spec.dq_ranges
        if not ranges:
            raise Refused(1, "no DQ on this model")
        k, code = self._range_code("DQ", args, len(self.analog_out), ranges)
        self.dq[k] = code
        lo, hi = ranges[self.dq[k]]
        self.analog_out[k] = min(max(self.analog_out[k], lo), hi)
        return ""

    @handler("AQ")
    def aq_command(self, args: str) -> str:
        k, code = self._range_code("AQ", args, len(self.analog_in), self.aq_ranges, signed=True)
        self.aq[k] = code
        return ""

    def _range_code(
        self, name: str, args: str, channels: int, codes: Collection[int], *, signed: bool = False
    ) -> tuple[int, int]:
        """``AQ``/``DQ n,code``: the channel ``n`` (of ``channels``) and its range code, one of
        ``codes`` (``signed``: a negative code too, AQ's differential input [U])."""
        fields = split_fields(args)
        if len(fields) != 2:
            raise Refused(50, f"{name} n,range")
        i = self.machine.interp
        k = self.channel(i.evaluate(fields[0]), channels)
        code = i.evaluate(fields[1])
        if code != int(code) or (abs(int(code)) if signed else int(code)) not in codes:
            taken = ", ".join(str(c) for c in codes)
            raise Refused(
                6,
                f"{name} code is one of {taken}" + (" (negative: differential)" if signed else ""),
            )
        return k, int(code)

    @handler("AI")
    def ai(self, args: str) -> Wait:
        """AI n: hold until input n is high (``AI -n``: low)."""
        n = self.machine.interp.evaluate(args)
        want = n > 0
        k = self.channel(abs(n), len(self.inputs))
        return Wait(lambda: self.inputs[k] == want)

    # ---- the data record -----------------------------------------------------------------
    def fill_record(self, buf: npt.NDArray[np.void], letters: str) -> None:
        """Put the inputs, outputs and analog values into the record fields that exist."""
        names = buf.dtype.names or ()
        if "inputs" in names:
            unconnected = ~((1 << len(self.inputs)) - 1)  # banks the model lacks read high
            _put_bits(buf, "inputs", self.input_bits() | unconnected)
        if "outputs" in names:
            _put_bits(buf, "outputs", self.output_bits())
        ranges = self._input_ranges()
        volts = [self.analog_volts(k) for k in range(len(self.analog_in))]
        if "analog_in" in names:
            if buf.dtype["analog_in"].shape:  # the RIO's eight
                _put_counts(buf, "analog_in", volts, ranges)
            else:  # the DMC-30010's input 2 (input 1 is in its axis block)
                _put_counts(buf, "analog_in", volts[1:2], ranges[1:2])
        if "analog_out" in names:
            _put_counts(buf, "analog_out", self.analog_out, [_FULL_SCALE] * len(self.analog_out))
        for letter in letters:
            # An axis block's analog input is the input of the axis's number (gclib: "A axis
            # analog input"); blocks for axes past the model's inputs keep 0.
            block = buf[letter]
            if "analog_in" in (block.dtype.names or ()):
                number = self.machine.spec.axes.index(letter)
                if number < len(self.analog_in):
                    block["analog_in"] = _counts(volts[number], ranges[number])


def _put_bits(buf: np.ndarray[Any, Any], name: str, bits: int) -> None:
    field = buf[name]
    if field.shape[1:]:  # banks of bytes (DMC general block)
        field[0][:] = [bits >> (8 * k) & 0xFF for k in range(field.shape[1])]
        return
    else:  # one word (RIO)
        field[0] = bits & ((1 << (8 * field.dtype.itemsize)) - 1)


def _put_counts(
    buf: np.ndarray[Any, Any], name: str, volts: list[float], ranges: list[tuple[float, float]]
) -> None:
    """As many channels as the record's field holds (the DMC-30010's holds one input), each
    in the counts of its range."""
    field = buf[name]
    signed = field.dtype.base.kind == "i"
    counts = [_counts(v, r) for v, r in zip(volts, ranges, strict=True)]
    values = [c - (0x10000 if signed and c & 0x8000 else 0) for c in counts]
    if field.shape[1:]:
        n = min(len(values), field.shape[1])
        field[0][:n] = values[:n]
    elif values:
        field[0] = values[0]


#: The range the analog outputs' counts are taken over.
_FULL_SCALE = (-10.0, 10.0)


def _counts(volts: float, span: tuple[float, float]) -> int:
    """16-bit counts of ``volts`` in the range ``span``: two's complement over ±R, unsigned
    over 0-R (EPICS's AQ decoding; the top of an unsigned range is the largest count)."""
    lo, hi = span
    if lo < 0:  # (+R itself reads the largest count, as an ADC saturates, not -32768)
        return min(round(volts * 32768 / hi), 0x7FFF) & 0xFFFF
    return min(round(volts * 65536 / hi), 0xFFFF)
