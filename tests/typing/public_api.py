"""Checked by ``mypy --strict`` in ``make typecheck`` (not run by pytest): the public API's types.

``assert_type`` fails the type check when mypy infers anything else, e.g. ``Any``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pint
from typing_extensions import assert_type

import galil
import galil.units
from galil.axis import ProfileQuantities, UnitProfile
from galil.contour import ContourResult
from galil.gearing import Gearing
from galil.predict import MultiProfile
from galil.units import ureg


def check(dmc: galil.Controller) -> None:
    assert_type(galil.connect("sim://DMC-4040"), galil.Controller)
    assert_type(dmc.A, galil.Axis)
    assert_type(dmc.X, galil.Axis)
    assert_type(dmc.axes["B"], galil.Axis)
    assert_type(dmc.A.move_to(10), galil.MoveHandle)
    assert_type(dmc.A.move_by(10), galil.MoveHandle)
    assert_type(dmc.A.jog(1000), galil.MoveHandle)
    assert_type(dmc.A.plan_to(10), UnitProfile)
    assert_type(dmc.move({"A": 1, "B": 2}), galil.MoveHandle)
    assert_type(dmc.plan({"A": 1}), MultiProfile)
    assert_type(dmc.contour("A", [1.0, 2.0], dt=2), ContourResult)
    assert_type(dmc.records(8), galil.RecordStream)
    assert_type(dmc.A.move_to(10).wait(), galil.MoveResult)
    assert_type(dmc.messages, galil.MessageQueue)
    # issue 11: homing, switches, I/O, settings
    assert_type(dmc.A.home(), galil.MoveHandle)
    assert_type(dmc.A.find_edge(), galil.MoveHandle)
    assert_type(dmc.A.find_index(), galil.MoveHandle)
    assert_type(dmc.A.homed, galil.Homed)
    assert_type(dmc.A.switches, galil.Switches)
    assert_type(dmc.switch_polarity, galil.SwitchPolarity)
    assert_type(dmc.io, galil.IO)
    assert_type(dmc.io.inputs[1], bool)
    assert_type(dmc.io.inputs[1:9], tuple[bool, ...])
    assert_type(dmc.A.kp, float)
    assert_type(dmc.A.error_limit, int)
    assert_type(dmc.A.motor_type, galil.MotorType | float)
    assert_type(dmc.A.limit_disable, galil.LimitDisable)
    dmc.A.limit_disable = galil.LimitDisable.FORWARD
    assert_type(dmc.A.encoder_config, galil.EncoderConfig)
    dmc.A.encoder_config = galil.EncoderConfig(aux=galil.EncoderType.PULSE_DIRECTION)
    # issue 12: programs, arrays, variables, interrupts, capture; issue 17: begin
    assert_type(dmc.capture(["_RPA"], every=2, count=10), galil.Capture)
    assert_type(dmc.capture(["_RPA"], seconds=1.0).wait(), galil.Recording)
    assert_type(dmc.programs.download("#A\nEN").sent, bool)
    assert_type(dmc.programs.threads, dict[int, int])
    assert_type(dmc.arrays.upload("a"), npt.NDArray[np.float64])
    assert_type(dmc.variables["x"], float)
    assert_type(dmc.interrupts.get(1.0), galil.Interrupt)
    assert_type(dmc.contour("A", [1.0], dt=2).begin, int | None)
    assert_type(galil.decode_fields(dmc.record()), galil.RecordFields)


def check_coordinated(dmc: galil.Controller) -> None:
    path = [galil.Line(1000, 0), galil.Arc(500, 270, 90)]
    assert_type(dmc.vector_move("AB", path, speed=20_000), galil.VectorHandle)
    assert_type(dmc.plan_vector("AB", path, speed=20_000), galil.VectorPlan)
    assert_type(dmc.vector_move("AB", path, speed=20_000).wait(), galil.MoveResult)
    assert_type(dmc.B.gear_to(dmc.A, 0.5), Gearing)


def check_units(dmc: galil.Controller) -> None:
    # decision 0099: counts on an axis without a scale, Quantities on one with a scale.
    x = dmc.A
    assert_type(x.position, float | pint.Quantity[float])
    assert_type(x.position, galil.Reading)
    assert_type(x.speed, galil.Reading)
    assert_type(x.soft_limits, tuple[galil.Reading | None, galil.Reading | None])
    x.speed = 5 * ureg.mm / ureg.s
    x.soft_limits = (None, ureg.Quantity(100, "mm"))
    assert_type(x.plan_by(10), UnitProfile)
    assert_type(x.plan_by(ureg.Quantity(10.0, "mm"), speed=np.float32(5), accel=None), UnitProfile)
    assert_type(x.plan_to(np.int64(10)).at(0.5), float)
    assert_type(x.move_to(10, speed=20_000), galil.MoveHandle)
    assert_type(dmc.move({"A": 1, "B": 2.5}, relative=True, decel=1e6), galil.MoveHandle)
    # What mypy now refuses (each ignore is needed: --strict warns of an unused one).
    x.move_to("10")  # type: ignore[arg-type]
    x.move_to(10, sped=5)  # type: ignore[call-arg]
    x.position.to("mm")  # type: ignore[union-attr]
    position = x.position
    if isinstance(position, pint.Quantity):
        assert_type(position, pint.Quantity[float])
    else:
        assert_type(position, float)
    # Scale conversions.
    scale = galil.units.Scale(2000 / ureg.mm)
    assert_type(x.set_scale(ureg.Quantity(2000, "1/mm")), galil.Axis)
    assert_type(scale.position_to_counts(ureg.Quantity(5, "mm")), float)
    assert_type(scale.counts_to_position(100.0), pint.Quantity[float])
    assert_type(scale.counts_to_distance(np.zeros(3)), pint.Quantity[npt.NDArray[np.float64]])
    assert_type(scale.counts_to_rate(100.0, 1), pint.Quantity[float])
    assert_type(scale.counts_per, pint.Quantity[float])
    scale.position_to_counts(5.0)  # type: ignore[arg-type]
    q = x.plan_by(10).q
    assert_type(q, ProfileQuantities)
    assert_type(x.plan_to(25 * ureg.mm).q.end, pint.Quantity[float])
    print(x.plan_to(25 * ureg.mm).q.end.to("inch"))  # (pint types .to() as Any)
    assert_type(q.at(0.2), pint.Quantity[float])
    assert_type(
        q.at(ureg.Quantity(200.0, "ms")),
        pint.Quantity[float] | pint.Quantity[npt.NDArray[np.float64]],
    )
    assert_type(q.peak_speed, pint.Quantity[float])
    assert_type(q.position, pint.Quantity[npt.NDArray[np.float64]])
    # Analog readings are volts.
    assert_type(dmc.io.analog_in[1], pint.Quantity[float])
    assert_type(dmc.io.analog_in[1:3], tuple[pint.Quantity[float], ...])
    assert_type(dmc.io.analog_out[0], pint.Quantity[float])
    dmc.io.analog_out[0] = ureg.Quantity(2.5, "V")
    assert_type(galil.units.get_registry(), pint.UnitRegistry[float])
    assert_type(dmc.record(), np.void)
    assert_type(dmc.record(as_dict=True), dict[str, object])
    assert_type(galil.Line(10 * ureg.mm, 0).dx, galil.Amount)
