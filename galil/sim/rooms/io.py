"""Digital and analog I/O: SB CB OB OP AO AQ AI, ``@IN @OUT @AN @AO``, ``_TI`` and ``_OP``.

Channels are numbered from the model's ``io_first`` (1 on DMC controllers, 0 on the RIO).
Inputs read high when nothing is connected; a test sets them with :meth:`IO.set_input` and
:meth:`IO.set_analog_input` (``galil.testing`` reaches these). ``_TIn`` is input bank ``n``
(8 inputs a byte), ``_OPn`` output word ``n`` (16 outputs). ``AI n`` holds until input ``n``
is high (``AI -n``: low), from the host or a program thread. An analog input takes the volts
of its model's range at the default AQ (:meth:`~galil.models.ModelSpec.analog_input_range`;
the DMC-30010's input 2 reads 0-5 V); the test hook clips to it. Analog values in the data
record are 16-bit counts of that range: two's complement over ±R (32768/R counts/V), unsigned
over 0-R (65536/R: the 30010's input 2 at 13107.2 counts/V, EPICS); the outputs at ±10 V full
scale (an assumption for DQ 4; the RIO-47100's 0-5 V outputs too).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from galil.sim.machine import Room
from galil.sim.parse import Refused, split_fields
from galil.sim.registry import OperandKind, Wait, function, handler, operand

__all__ = ["IO"]


class IO(Room):
    """The controller's general-purpose inputs, outputs and analog channels."""

    def reset(self) -> None:
        spec = self.machine.spec
        self.first = spec.io_first
        self.inputs = [True] * spec.digital_inputs
        self.outputs = [False] * spec.digital_outputs
        self.analog_in = [0.0] * spec.analog_inputs
        self.analog_out = [0.0] * spec.analog_outputs
        self.aq = [2.0] * spec.analog_inputs

    def burn(self, name: str) -> object | None:
        # The BN table: SB CB OP (the outputs) and AQ; the inputs are the outside world's.
        return (list(self.outputs), list(self.aq)) if name == "BN" else None

    def restore(self, name: str, saved: object) -> None:
        assert isinstance(saved, tuple)
        self.outputs, self.aq = saved

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
        """Test hook: put ``volts`` on analog input ``n`` (clipped to the input's range)."""
        k = self.channel(n, len(self.analog_in))
        lo, hi = self.machine.spec.analog_input_range(int(n))
        self.analog_in[k] = min(max(float(volts), lo), hi)

    def _input_ranges(self) -> list[tuple[float, float]]:
        spec = self.machine.spec
        return [spec.analog_input_range(self.first + k) for k in range(len(self.analog_in))]

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
        return round(self.analog_in[self.channel(n, len(self.analog_in))], 4)

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
        lo, hi = self.machine.spec.analog_out_range
        if not lo <= volts <= hi:
            raise Refused(6, "AO out of range")
        self.analog_out[k] = volts
        return ""

    @handler("AQ")
    def aq_command(self, args: str) -> str:
        fields = split_fields(args)
        if len(fields) != 2:
            raise Refused(50, "AQ n,range")
        i = self.machine.interp
        k = self.channel(i.evaluate(fields[0]), len(self.analog_in))
        code = i.evaluate(fields[1])
        if abs(code) not in (1, 2, 3, 4):
            raise Refused(6, "AQ range is ±1..±4")
        self.aq[k] = code
        return ""

    @handler("AI")
    def ai(self, args: str) -> Wait:
        """AI n: hold until input n is high (``AI -n``: low)."""
        n = self.machine.interp.evaluate(args)
        want = n > 0
        k = self.channel(abs(n), len(self.inputs))
        return Wait(lambda: self.inputs[k] == want)

    # ---- the data record -----------------------------------------------------------------
    def fill_record(self, buf: np.ndarray[Any, Any], letters: str) -> None:
        """Put the inputs, outputs and analog values into the record fields that exist."""
        names = buf.dtype.names or ()
        if "inputs" in names:
            unconnected = ~((1 << len(self.inputs)) - 1)  # banks the model lacks read high
            _put_bits(buf, "inputs", self.input_bits() | unconnected)
        if "outputs" in names:
            _put_bits(buf, "outputs", self.output_bits())
        ranges = self._input_ranges()
        if "analog_in" in names:
            if buf.dtype["analog_in"].shape:  # the RIO's eight
                _put_counts(buf, "analog_in", self.analog_in, ranges)
            else:  # the DMC-30010's input 2 (input 1 is in its axis block)
                _put_counts(buf, "analog_in", self.analog_in[1:2], ranges[1:2])
        if "analog_out" in names:
            _put_counts(buf, "analog_out", self.analog_out, [_FULL_SCALE] * len(self.analog_out))
        for letter in letters:
            # An axis block's analog input is the input of the axis's number (gclib: "A axis
            # analog input"); blocks for axes past the model's inputs keep 0.
            block = buf[letter]
            if "analog_in" in (block.dtype.names or ()):
                number = self.machine.spec.axes.index(letter)
                if number < len(self.analog_in):
                    block["analog_in"] = _counts(self.analog_in[number], ranges[number])


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
