"""Issue 11's "done when": a lab's day one, through the public API, over TCP and over a pty to
``galil sim`` (a separate process on a real clock), on a DMC-50040, a DMC-4240 and a RIO-47120.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import pytest

import galil
from galil.testing import nothing_sent
from galil.units import ureg

LIMITS = "-30000,30000"  # fixed-frame positions of every axis's limit switches


@pytest.fixture(params=["tcp", "pty"])
def served(request: pytest.FixtureRequest, galil_sim: Callable[..., str]) -> Callable[[str], str]:
    """Start ``galil sim`` for a model on TCP or a pty; return a function giving its address."""
    if request.param == "pty" and not hasattr(os, "openpty"):
        pytest.skip("needs a pty")
    where = ["--tcp", "127.0.0.1:0"] if request.param == "tcp" else ["--pty"]

    def start(model: str) -> str:
        return galil_sim("--model", model, *where, "--lag", "0", f"--limits={LIMITS}")

    return start


def _day_one_on_an_axis(dmc: galil.Controller) -> None:
    a = dmc.A
    a.speed, a.accel, a.decel, a.home_speed = 100_000, 2_048_000, 2_048_000, 20_000
    assert not a.homed
    # home: position 0 at the index, stop code 10, and the library says how it knows
    result = a.home().wait(timeout=30)
    assert result.stop_codes == {"A": 10}
    assert a.position == 0
    assert a.homed
    assert "stop code 10" in a.homed.how
    # find the edge: stop code 9, on the home switch now
    assert a.switches.home is False
    assert a.find_edge().wait(timeout=30).stop_codes == {"A": 9}
    assert a.switches.home is True
    assert a.switches.home_input == 0
    # drive onto the forward limit: the switches before and after
    before = a.switches
    assert not before.forward_limit
    assert not before.reverse_limit
    with pytest.raises(galil.MotionError):
        a.jog(200_000).wait(timeout=30)
    after = a.switches
    assert after.forward_limit
    assert not after.reverse_limit
    assert a.stop_code[0] == 2
    # gains and motor type, read back as the controller stores them
    a.kp, a.ki, a.kd = 12.3, 0.5, 80
    assert (a.kp, a.ki, a.kd) == (12.25, 0.5, 80.0)
    dmc.motor_off("A")  # MT only with the motor off
    a.motor_type = galil.MotorType.SERVO_REVERSED
    assert a.motor_type is galil.MotorType.SERVO_REVERSED
    a.motor_type = galil.MotorType.SERVO
    dmc.servo_here("A")
    a.torque_limit, a.error_limit, a.off_on_error = 5.0, 2000, 1
    assert (a.torque_limit, a.error_limit, a.off_on_error) == (5.0, 2000, 1)
    # every bad value is refused before a byte is sent
    with nothing_sent(dmc):
        for name, bad in (("kp", 2000), ("ki", -1), ("motor_type", 3), ("error_limit", 0.5)):
            with pytest.raises(galil.InvalidArgument):
                setattr(a, name, bad)
        with pytest.raises(galil.LimitError):
            a.home_speed = 1e9
        with pytest.raises(galil.InvalidArgument):
            dmc.io.outputs[99] = True
        with pytest.raises(galil.InvalidArgument):
            dmc.io.analog_out[1] = 1.0  # no analog outputs on a DMC motion controller
        with pytest.raises(galil.InvalidArgument):
            dmc.switch_polarity = galil.SwitchPolarity(limit=2)


def _io_day_one(dmc: galil.Controller) -> None:
    first = dmc.model.io_first
    io = dmc.io
    io.outputs[first + 1] = True
    assert io.outputs[first + 1] is True
    io.outputs[first : first + 3] = [True, False, True]
    assert io.outputs[first : first + 4] == (True, False, True, False)
    assert io.inputs[first] is True  # unconnected inputs read high
    assert io.inputs[first : first + 8] == (True,) * 8
    assert io.analog_in[first].to("V").magnitude == 0.0
    with nothing_sent(dmc):
        with pytest.raises(galil.InvalidArgument):
            io.outputs[first - 1] = True
        with pytest.raises(galil.InvalidArgument):
            io.inputs[first + dmc.model.digital_inputs]


@pytest.mark.parametrize("model", ["DMC-50040", "DMC-4240"])
def test_a_motion_controller_does_a_labs_day_one(served: Callable[[str], str], model: str) -> None:
    with galil.connect(served(model), timeout=5) as dmc:
        assert dmc.model.name == model
        _day_one_on_an_axis(dmc)
        _io_day_one(dmc)
        dmc.save()  # BN, within the model's burn timeout


def test_a_rio_does_io_and_refuses_motion(served: Callable[[str], str]) -> None:
    with galil.connect(served("RIO-47120"), timeout=5) as rio:
        assert rio.model.family == "RIO-47xxx"
        assert rio.model.axes == ""
        _io_day_one(rio)
        rio.io.analog_out[0] = 2.5 * ureg.volt
        assert rio.io.analog_out[0].to("V").magnitude == 2.5
        with nothing_sent(rio):
            with pytest.raises(galil.LimitError):
                rio.io.analog_out[0] = 11
            with pytest.raises(galil.InvalidArgument, match="no axes"):
                rio.move({"A": 100})
            with pytest.raises(galil.InvalidArgument, match="no axes"):
                rio.stop()
            with pytest.raises(AttributeError, match="no axes"):
                rio.A  # noqa: B018 - the attribute access is the test
