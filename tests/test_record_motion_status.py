"""What the data record says of motion in progress, read through ``Controller.record()``.

The coordinate planes' blocks (segment count, move status, distance, buffer space: gclib
``s_plane_*``) and the axis status bits for coordinated motion (b8), slewing (b5) and the final
deceleration (b3), galil-protocol.md section 4. Time is the simulator's: ``dmc.sleep`` runs it.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import galil
from galil import Line
from galil.testing import simulated

COORDINATED, SLEWING, STOPPING, FINAL_DECEL, MOVING = 0x0100, 0x0020, 0x0010, 0x0008, 0x8000


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated("DMC-4040") as controller:
        yield controller


def plane(dmc: galil.Controller) -> tuple[galil.RecordFields, dict[str, int]]:
    """A record, decoded and its S block raw, checked against ``_CSS _AVS _LMS`` read just
    before and after it."""
    before = dmc.query_numbers("MG _CSS,_AVS,_LMS")
    rec = dmc.record()
    after = dmc.query_numbers("MG _CSS,_AVS,_LMS")
    raw = {n: int(rec[f"s_{n}"]) for n in ("segments", "status", "distance", "buffer")}
    assert before[0] <= raw["segments"] <= after[0]
    assert before[1] <= raw["distance"] <= after[1]
    assert after[2] <= raw["buffer"] <= before[2]
    return galil.decode_fields(rec), raw


def test_a_vector_sequence_in_progress_fills_the_s_plane_block_and_marks_its_axes(
    dmc: galil.Controller,
) -> None:
    # 50000 counts, then 20000 more, at 20000 counts/s: 2.8 s in, the path is in its second
    # segment at speed.
    handle = dmc.vector_move("AB", [Line(30000, 40000), Line(20000, 0)], speed=20_000)
    dmc.sleep(2.8)
    fields, raw = plane(dmc)
    assert raw["segments"] == 1
    assert 50_000 < raw["distance"] < 70_000
    assert raw["buffer"] == 511 - 1  # one segment left in the buffer
    assert raw["status"] == MOVING | SLEWING
    s = fields.planes["S"]
    assert (s.segments, s.distance, s.buffer) == (1, raw["distance"], 510)
    assert (s.status.moving, s.status.slewing, s.status.final_decel) == (True, True, False)
    for letter in "AB":
        status = fields.axes[letter].status
        assert (status.coordinated, status.moving) == (True, True)
    assert not fields.axes["C"].status.coordinated
    assert not fields.planes["T"].status.moving
    handle.wait()
    fields, raw = plane(dmc)
    assert raw == {"segments": 2, "status": 0, "distance": 70_000, "buffer": 511}
    assert not fields.axes["A"].status.coordinated


def test_the_s_plane_status_shows_its_final_deceleration_and_a_stop(
    dmc: galil.Controller,
) -> None:
    # VD 25600: the last 0.78 s of the sequence (7812 counts) are its final deceleration.
    handle = dmc.vector_move("AB", [Line(60000, 0)], speed=20_000, decel=25_600)
    dmc.sleep(0.02)
    assert plane(dmc)[1]["status"] == MOVING  # still accelerating
    dmc.sleep(3.1)
    fields, raw = plane(dmc)
    assert raw["status"] == MOVING | FINAL_DECEL
    status = fields.planes["S"].status
    assert (status.final_decel, status.slewing) == (True, False)
    handle.wait()
    dmc.vector_move("AB", [Line(60000, 0)], speed=20_000, decel=25_600)
    dmc.sleep(1.0)
    dmc.command("ST S")
    dmc.sleep(0.1)
    fields, raw = plane(dmc)
    assert raw["status"] == MOVING | STOPPING | FINAL_DECEL
    assert fields.planes["S"].status.stopping


def axis_status(dmc: galil.Controller) -> int:
    return int(dmc.record("A")["A"]["status"])


def test_an_axis_at_constant_speed_is_slewing_and_in_its_last_ramp_decelerating(
    dmc: galil.Controller,
) -> None:
    # SP 20000, AC 256000, DC 25600: 0.08 s up, 2.57 s at speed, 0.78 s down (PR, so b14).
    dmc.command_line(["SPA=20000", "ACA=256000", "DCA=25600", "PRA=60000", "BGA"])
    dmc.sleep(0.02)
    assert axis_status(dmc) == MOVING | 0x4000
    dmc.sleep(1.0)
    assert axis_status(dmc) == MOVING | 0x4000 | SLEWING
    status = galil.decode_fields(dmc.record("A")).axes["A"].status
    assert (status.slewing, status.final_decel, status.coordinated) == (True, False, False)
    dmc.sleep(2.0)
    assert axis_status(dmc) == MOVING | 0x4000 | FINAL_DECEL
    dmc.sleep(1.0)
    assert axis_status(dmc) == 0


def test_a_jog_at_speed_is_slewing_and_its_stop_is_a_final_deceleration(
    dmc: galil.Controller,
) -> None:
    dmc.command_line(["JGA=-10000", "BGA"])
    dmc.sleep(0.5)
    negative = 0x0080
    assert axis_status(dmc) == MOVING | negative | SLEWING
    dmc.command("STA")
    dmc.sleep(0.01)
    assert axis_status(dmc) == MOVING | negative | STOPPING | FINAL_DECEL
