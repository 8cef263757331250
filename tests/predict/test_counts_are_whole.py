"""One rule for a fraction of a count (decision 0092): a value given in counts (the predictor,
``galil plan`` without ``--scale``, an axis without a scale) must be a whole number, and is
refused otherwise; a value in user units (an axis with a scale, ``galil plan --scale``) is
rounded to the nearest count. The predictor also refuses what the controller's 32-bit ``PR``
and ``PA`` cannot hold, with a model or without.

Before: ``predict.move(10.7, ...)`` truncated to 10, ``dmc.A.plan_by(10.7)`` rounded to 11,
``galil plan 1000.7`` refused; ``predict.move`` took ``"1000"`` and ``True``; and
``predict.move(10**12, ..., model="DMC-4040")`` returned a profile of 512 G samples.
"""

from __future__ import annotations

from collections.abc import Callable
from fractions import Fraction
from typing import Any

import numpy as np
import pytest

import galil
from galil import cli, predict
from galil.errors import InvalidArgument, LimitError
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm = ureg.mm
RATES = (20_000, 256_000, 256_000)

#: The predictor's entry points that take a distance (or a start) in counts.
ENTRIES: dict[str, Callable[[object], Any]] = {
    "move": lambda d: predict.move(d, *RATES),
    "move with a model": lambda d: predict.move(d, *RATES, model="DMC-4040"),
    "move, smoothed": lambda d: predict.move(d, *RATES, smoothing=0.5),
    "plan_move": lambda d: predict.plan_move(d, *RATES),
    "speed_schedule": lambda d: predict.speed_schedule(d, 10_000, [], 256_000, 256_000),
    "move's start": lambda d: predict.move(100, *RATES, start=d),
    "jog's start": lambda d: predict.jog(1000, 256_000, 256_000, start=d, duration=0.01),
    "contour's start": lambda d: predict.contour([10, 20], dt=1, start=d),
}


@pytest.mark.parametrize("entry", ENTRIES)
@pytest.mark.parametrize("value", [10.7, -10.5, 2.5, np.float64(99.9), Fraction(3, 2)])
def test_the_predictor_refuses_a_fraction_of_a_count(entry: str, value: object) -> None:
    with pytest.raises(InvalidArgument, match="is not a whole number of counts"):
        ENTRIES[entry](value)


@pytest.mark.parametrize("entry", ENTRIES)
@pytest.mark.parametrize("value", ["1000", True, np.bool_(True), None, float("nan")])
def test_the_predictor_refuses_what_is_not_a_number_of_counts(entry: str, value: object) -> None:
    with pytest.raises(InvalidArgument, match="must be a whole number of counts"):
        ENTRIES[entry](value)


@pytest.mark.parametrize("value", [1000, 1000.0, np.int32(1000), np.float32(1000), Fraction(1000)])
def test_the_predictor_takes_whole_counts_of_any_real_type(value: object) -> None:
    p = predict.move(value, *RATES)
    assert (p.end, p.distance) == (1000, 1000)
    assert predict.plan_move(value, *RATES).distance == 1000


def test_a_whole_count_within_float_error_of_a_conversion_is_that_count() -> None:
    d = 0.1 * 3 * 10_000  # 3000.0000000000005
    assert d != 3000
    assert predict.move(d, *RATES).end == 3000


@pytest.mark.parametrize("model", [None, "DMC-4040"])
@pytest.mark.parametrize("distance", [10**12, -(2**31) - 1, 2**31])
def test_the_predictor_refuses_a_distance_beyond_32_bits(model: str | None, distance: int) -> None:
    with pytest.raises(LimitError, match="outside the 32-bit position range") as info:
        predict.move(distance, 2000, 256_000, 256_000, model=model)
    assert info.value.name == "PR"
    assert info.value.value == distance


def test_the_predictor_refuses_a_target_beyond_32_bits() -> None:
    with pytest.raises(LimitError, match="the target") as info:
        predict.move(2, *RATES, start=2**31 - 1)
    assert info.value.name == "PA"
    with pytest.raises(LimitError):
        predict.speed_schedule(10_000, 10_000, [], 256_000, 256_000, start=2**31 - 5000)


def test_the_predictor_takes_the_longest_distances_the_controller_does() -> None:
    for d in (2**31 - 1, -(2**31)):
        p = predict.move(d, 22_000_000, 1_073_740_800, 1_073_740_800, model="DMC-4040")
        assert p.end == d


def test_an_axis_without_a_scale_refuses_a_fraction_of_a_count() -> None:
    with simulated("DMC-4040") as dmc:
        a = dmc.A
        calls: list[Callable[[], object]] = [
            lambda: a.plan_by(10.7),
            lambda: a.plan_to(-10.5),
            lambda: a.move_by(2.5 * ureg.count),
            lambda: dmc.move({"A": 10.7}),
            lambda: a.increment(0.5),
            lambda: a.define_position(1.5),
            lambda: setattr(a, "soft_limits", (-100.5, 100)),
            lambda: a.speed_schedule(1000.5, [(500, 1000)]),
        ]
        for call in calls:
            with nothing_sent(dmc), pytest.raises(InvalidArgument, match="not a whole number"):
                call()
        assert a.plan_by(10.0).end == 10
        assert a.plan_by(np.int64(10)).end == 10


def test_an_axis_with_a_scale_rounds_its_units_to_the_nearest_count() -> None:
    with simulated("DMC-4040") as dmc:
        x = dmc.A.set_scale(counts_per=2000 / mm)
        assert x.plan_by(0.0053 * mm).distance == 11  # 10.6 counts
        assert x.plan_by(-0.0053 * mm).distance == -11
        assert x.plan_to(0.0021 * mm).end == 4  # 4.2 counts


def test_galil_plan_follows_the_predictor(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["plan", "1000.7"]) == 2
    err = capsys.readouterr().err
    with pytest.raises(InvalidArgument) as info:
        predict.move(1000.7, *RATES)
    assert "1000.7 is not a whole number of counts" in err
    assert "1000.7 is not a whole number of counts" in str(info.value)
    assert cli.main(["plan", "1000.0"]) == 0
    assert "0 → 1000 counts" in capsys.readouterr().out


def test_galil_plan_rounds_units_of_its_scale_as_an_axis_does(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # 12.50004 mm is 25000.08 counts: an axis with this scale moves 25000 (before, the command
    # refused it as "not a whole number").
    args = ["plan", "12.50004mm", "--scale", "2000/mm"]
    assert cli.main(args) == 0
    assert "(0 → 25000 counts)" in capsys.readouterr().out
    with simulated("DMC-4040") as dmc:
        assert dmc.A.set_scale(counts_per=2000 / mm).plan_by(12.50004 * mm).distance == 25000


def test_a_refused_fraction_names_the_rule_for_scaled_axes() -> None:
    with simulated("DMC-4040") as dmc, pytest.raises(galil.InvalidArgument) as info:
        dmc.B.plan_by(10.7)
    assert "an axis without a scale takes whole counts" in str(info.value)
    assert "rounded to the nearest count" in str(info.value)
