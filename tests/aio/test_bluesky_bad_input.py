"""galil.bluesky's constructors and methods with the bad values of the sync fuzz (decision
0026): a ``GalilError`` (``InvalidArgument``), before anything is sent, or a value taken on
purpose. The devices run in ophyd-async's mock mode (an in-process simulator)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

pytest.importorskip("ophyd_async")

from test_public_api_bad_input import BAD

import galil
from galil.bluesky import ContourPath, GalilContourFlyer, GalilMotor, release_all
from galil.testing import nothing_sent
from galil.units import ureg

ALL = {label for label, _ in BAD}
TEXT = {"'x'", "''", "2000 chars"}  # text judged at connect() (the model's axes, the bus)

#: Constructors: a valid value per parameter, and the bad values taken on purpose.
CONSTRUCTORS: list[tuple[Callable[..., object], dict[str, object], dict[str, set[str]]]] = [
    (
        GalilMotor,
        {
            "address": "sim://DMC-4040",
            "axis": "A",
            "name": "m",
            "scale": 2000 / ureg.mm,
            "offset": None,
            "sign": 1,
            "in_position": None,
            "settle_timeout": 0.5,
        },
        {
            "address": TEXT,
            "axis": {"'x'", "2000 chars"},
            "name": TEXT,
            "scale": {"None"},  # no scale: counts
            "offset": {"None"},
            "sign": {"-1"},  # a reversed axis
            "in_position": {"None"},  # one count
        },
    ),
    (
        GalilContourFlyer,
        {"address": "sim://DMC-4040", "axes": "AB", "name": "f", "scales": None},
        {"address": TEXT, "axes": {"'x'", "2000 chars"}, "name": TEXT, "scales": {"None", "{}"}},
    ),
]


@pytest.mark.parametrize(
    ("make", "valid", "accepts"), CONSTRUCTORS, ids=lambda v: getattr(v, "__name__", "")
)
def test_constructors_refuse_bad_values(
    make: Callable[..., object], valid: dict[str, object], accepts: dict[str, set[str]]
) -> None:
    make(**valid)
    problems = []
    for param in valid:
        for label, bad in BAD:
            try:
                make(**{**valid, param: bad})
            except galil.GalilError:
                continue
            except Exception as exc:
                problems.append(f"{param}={label}: bare {type(exc).__name__}: {exc!s:.100}")
                continue
            if label not in accepts.get(param, set()):
                problems.append(f"{param}={label}: taken")
    assert not problems, "\n".join(problems)


def _run(body: Callable[[], Coroutine[Any, Any, list[str]]]) -> list[str]:
    async def wrapped() -> list[str]:
        try:
            return await body()
        finally:
            await release_all()

    return asyncio.run(asyncio.wait_for(wrapped(), 30))


#: Methods: (name, call with the bad value, labels taken on purpose).
METHODS: list[tuple[str, Callable[[GalilMotor, GalilContourFlyer, object], Any], set[str]]] = [
    ("motor.set(value)", lambda m, f, v: m.set(v), {"-1"}),
    ("motor.set(timeout)", lambda m, f, v: m.set(10, timeout=v), {"None"}),  # None: for ever
    ("motor.check_value", lambda m, f, v: m.check_value(v), {"-1"}),
    ("motor.stop", lambda m, f, v: m.stop(v), {"True"}),
    ("motor.velocity.set", lambda m, f, v: m.velocity.set(v), set()),
    ("motor.acceleration.set", lambda m, f, v: m.acceleration.set(v), set()),
    ("motor.deceleration.set", lambda m, f, v: m.deceleration.set(v), set()),
    ("flyer.prepare", lambda m, f, v: f.prepare(v), set()),
    ("flyer.prepare(path)", lambda m, f, v: f.prepare(ContourPath(v, 2)), set()),
    ("flyer.prepare(dt)", lambda m, f, v: f.prepare(ContourPath([[10, 10]], v)), set()),
    (
        "flyer.prepare(record_period)",
        lambda m, f, v: f.prepare(ContourPath([[10, 10]], 2, v)),
        {"None"},
    ),
    ("flyer.stop", lambda m, f, v: f.stop(v), {"True"}),
]


@pytest.mark.parametrize(("name", "call", "accepts"), METHODS, ids=[m[0] for m in METHODS])
def test_methods_refuse_bad_values_before_anything_is_sent(
    name: str, call: Callable[[GalilMotor, GalilContourFlyer, object], Any], accepts: set[str]
) -> None:
    async def body() -> list[str]:
        motor = GalilMotor("sim://DMC-4040", "A", name="m")
        flyer = GalilContourFlyer("sim://DMC-4040", "AB", name="f")
        await motor.connect(mock=True)
        await flyer.connect(mock=True)
        problems = []
        for label, bad in BAD:
            refused: BaseException | None = None
            try:
                with nothing_sent(motor.controller.sync, allow_queries=True):
                    try:
                        await call(motor, flyer, bad)
                    except galil.GalilError as exc:
                        refused = exc
                    except Exception as exc:
                        refused = exc
                        problems.append(f"{name}({label}): bare {type(exc).__name__}: {exc!s:.99}")
            except AssertionError as sent:
                if refused is not None:
                    problems.append(f"{name}({label}): refused after sending: {sent!s:.99}")
            if refused is None:
                if label not in accepts:
                    problems.append(f"{name}({label}): taken")
                await motor.controller.stop()
        return problems

    assert not _run(body)


def test_a_quantity_for_a_position_is_refused_naming_the_motors_unit() -> None:
    # bluesky plans carry plain numbers; a scientist's first try is often 10 * ureg.mm.
    async def body() -> list[str]:
        motor = GalilMotor("sim://DMC-4040", "A", name="m", scale=2000 / ureg.mm)
        counts = GalilMotor("sim://DMC-4040", "B", name="n")
        await motor.connect(mock=True)
        await counts.connect(mock=True)
        said = []
        for device in (motor, counts):
            with pytest.raises(galil.InvalidArgument) as info:
                await device.set(10 * ureg.mm)
            said.append(str(info.value))
        return said

    in_mm, in_counts = _run(body)
    assert "m: a position is a number (in mm, the motor's unit), not" in in_mm
    assert "n: a position is a number (in counts, the motor's unit), not" in in_counts


@pytest.mark.parametrize("extra", [{"offset": 100}, {"sign": -1}, {"offset": 0 * ureg.mm}])
def test_an_offset_or_a_sign_without_a_scale_is_refused(extra: dict[str, Any]) -> None:
    # (they were dropped silently: mv(b, 1000) sent _RPB = 1000 with sign=-1, offset=100)
    with pytest.raises(galil.InvalidArgument, match="offset and sign belong to a scale"):
        GalilMotor("sim://DMC-4040", "B", **extra)
