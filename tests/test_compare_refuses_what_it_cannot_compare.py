"""compare() refuses what would compare as exact whatever the axis did: a recording outside
the motion, a field no axis of the prediction was recorded in, and a field that is no position.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

import galil
from galil.notebook import compare
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated("DMC-4040") as controller:
        x = controller.A
        x.speed, x.accel, x.decel = 40_000, 400_000, 400_000
        yield controller


def test_a_capture_that_ended_before_the_move_began_is_refused(dmc: galil.Controller) -> None:
    rec = dmc.capture(["_RPA", "_TPA"], every=2, seconds=0.1).wait()
    move = dmc.A.move_by(20_000)
    move.wait()
    with pytest.raises(galil.InvalidArgument, match=r"1 value\(s\) within its predicted motion"):
        compare(move, rec)


def test_data_records_taken_after_the_move_are_refused(dmc: galil.Controller) -> None:
    move = dmc.A.move_by(20_000)
    move.wait()
    with dmc.records(period=8) as stream:
        records = stream.take(10)
    with pytest.raises(galil.InvalidArgument, match=r"0 value\(s\) within"):
        compare(move, records)


def test_positions_given_by_hand_outside_the_motion_are_refused(dmc: galil.Controller) -> None:
    plan = dmc.A.plan_by(20_000)
    late = plan.t[-1] + np.array([0.1, 0.2, 0.3])
    with pytest.raises(galil.InvalidArgument, match="within its predicted motion"):
        compare({"A": plan}, {"A": (late, np.full(3, 20_000.0))})
    # Two values inside are enough to compare.
    t = np.array([0.0, plan.duration])
    assert compare({"A": plan}, {"A": (t, np.array([0.0, 20_000.0]))})["A"].worst == 0


def test_a_capture_of_the_encoder_only_names_what_it_recorded(dmc: galil.Controller) -> None:
    cap = dmc.capture(["_TPA"], every=2, seconds=0.8)
    move = dmc.A.move_by(20_000)
    rec = cap.wait()
    with pytest.raises(
        galil.InvalidArgument, match=r"recorded _TPA \(compare with field='position'\)"
    ):
        compare(move, rec)
    assert compare(move, rec, field="position")["A"].t.size == len(rec)


def test_the_following_error_is_not_compared_with_a_position(dmc: galil.Controller) -> None:
    cap = dmc.capture(["_TEA", "_RPA"], every=2, seconds=0.8)
    move = dmc.A.move_by(20_000)
    rec = cap.wait()
    with pytest.raises(galil.InvalidArgument, match=r"'error' \(_TE\) is not a position"):
        compare(move, rec, field="error")
    assert compare(move, rec)["A"].worst == 0
