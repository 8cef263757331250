"""A position on an axis with an offset (and a reversed sign) reads back as it was given:
counts to a position is rounded once, ``(sign * counts + offset * k) / k``, everywhere."""

from __future__ import annotations

import numpy as np

from galil.controller import Controller
from galil.testing import simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def _offset_stage(dmc: Controller) -> None:
    x = dmc.A.set_scale(counts_per=800 / mm, offset=12.5 * mm, sign=-1)
    x.speed = 20 * mm / s
    x.accel = x.decel = 1000 * mm / s**2


def scan(dmc: Controller, points: list[object]) -> list[object]:
    """docs/testing.md's scan, on the offset stage."""
    x = dmc.A
    reached: list[object] = []
    for point in points:
        x.move_to(point).wait()  # type: ignore[arg-type]
        dmc.sleep(0.2)
        reached.append(x.reference_position)
    return reached


def test_scan_on_an_offset_stage_reaches_every_point_exactly() -> None:
    with simulated("DMC-4040") as dmc:
        _offset_stage(dmc)
        points: list[object] = [0.1 * mm, 2.5 * mm, 4.3 * mm, 13.7 * mm]
        assert scan(dmc, points) == points


def test_plans_and_scale_read_positions_as_given() -> None:
    with simulated("DMC-4040") as dmc:
        _offset_stage(dmc)
        x = dmc.A
        assert x.plan_to(0.1 * mm).q.end == 0.1 * mm  # type: ignore[attr-defined]
        scale = x.scale
        assert scale is not None
        counts = np.array([round(scale.position_to_counts(v * mm)) for v in (0.1, 4.3, 13.7)])
        back = scale.counts_to_position(counts.astype(np.float64))
        assert list(back.m_as("mm")) == [0.1, 4.3, 13.7]


def test_vector_plan_positions_read_as_given() -> None:
    from galil import Line

    with simulated("DMC-4040") as dmc:
        _offset_stage(dmc)
        dmc.B.set_scale(counts_per=800 / mm)
        dmc.A.move_to(0.1 * mm).wait()
        plan = dmc.plan_vector(
            "AB", [Line(4.2 * mm, 0 * mm)], speed=20 * mm / s, accel=400 * mm / s**2
        )
        assert plan.position("A")[0] == 0.1
        assert plan.position("A")[-1] == 4.3
