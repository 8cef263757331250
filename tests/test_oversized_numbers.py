"""Numbers no float holds (a 400-digit int), sleeps and streams longer than anything can count:
typed errors, nothing sent, the link as it was."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil.testing import nothing_sent, simulated
from galil.units import ureg

HUGE = 10**400


def _cases(dmc: galil.Controller) -> dict[str, Callable[[], object]]:
    a, b = dmc.A, dmc.B
    return {
        "move_to": lambda: a.move_to(HUGE),
        "move_by": lambda: a.move_by(HUGE),
        "jog": lambda: a.jog(HUGE),
        "increment": lambda: a.increment(HUGE),
        "speed": lambda: setattr(a, "speed", HUGE),
        "accel": lambda: setattr(a, "accel", HUGE),
        "soft_limits": lambda: setattr(a, "soft_limits", (-HUGE, HUGE)),
        "kp": lambda: setattr(a, "kp", HUGE),
        "ki": lambda: setattr(a, "ki", HUGE),
        "kd": lambda: setattr(a, "kd", HUGE),
        "error_limit": lambda: setattr(a, "error_limit", HUGE),
        "gear_to": lambda: b.gear_to("A", HUGE),
        "set_scale counts_per": lambda: a.set_scale(HUGE / ureg.mm),
        "set_scale offset": lambda: a.set_scale(1000 / ureg.mm, offset=HUGE * ureg.mm),
        "set_scale sign": lambda: a.set_scale(1000 / ureg.mm, sign=True),  # type: ignore[arg-type]
        "sleep": lambda: dmc.sleep(1e300),
        "records": lambda: dmc.records(seconds=1e308),
        "watchdog": lambda: dmc.watchdog(1e308),
        "smoothing": lambda: setattr(a, "smoothing", HUGE),
    }


NAMES = ["move_to", "move_by", "jog", "increment", "speed", "accel", "soft_limits", "kp"]
NAMES += ["ki", "kd", "error_limit", "gear_to", "set_scale counts_per", "set_scale offset"]
NAMES += ["set_scale sign", "sleep", "records", "watchdog", "smoothing"]


def test_every_case_is_listed() -> None:
    with simulated("DMC-4040") as dmc:
        assert sorted(_cases(dmc)) == sorted(NAMES)


@pytest.mark.parametrize("case", NAMES)
def test_numbers_nothing_can_hold_get_typed_errors_and_nothing_is_sent(case: str) -> None:
    with simulated("DMC-4040") as dmc:
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            _cases(dmc)[case]()
        assert dmc.A.scale is None
        assert dmc.query_number("MG 1+1") == 2
        dmc.A.move_by(100).wait()  # the link and the axis are as they were


def test_an_analog_output_of_a_number_no_float_holds_is_refused_unsent() -> None:
    with simulated("DMC-30010") as dmc:  # a DMC with analog outputs
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.io.analog_out[1] = HUGE
        dmc.io.analog_out[1] = 2
        assert dmc.io.analog_out[1].to("V").magnitude == 2


def test_smoothing_takes_numpy_numbers_like_python_ones() -> None:
    with simulated("DMC-4040") as dmc:
        dmc.A.smoothing = np.float32(0.5)
        assert dmc.A.smoothing == 0.5
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
            dmc.A.smoothing = np.bool_(True)


def test_a_speed_schedule_too_long_to_predict_is_refused_before_anything_moves() -> None:
    with simulated("DMC-4040") as dmc:
        with nothing_sent(dmc, allow_queries=True), pytest.raises(galil.LimitError) as info:
            dmc.A.speed_schedule(2_000_000_000, [(50_000, 2000)])  # 11 days at 2000 c/s
        assert info.value.name == "samples"
        assert dmc.A.moving is False
        handle = dmc.A.speed_schedule(40_000, [(10_000, 5000)])  # an ordinary one still runs
        handle.wait()
        assert dmc.A.reference_position == 40_000
