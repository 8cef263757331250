"""Captures on the controller and data records, lined up with predictions by controller time."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

import galil
from galil.demo import record_motion
from galil.notebook import compare
from galil.protocol.records import SAMPLE_WRAP
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        yield controller


def exact(handle: galil.MoveHandle | galil.ContourResult, rec: galil.Recording, a: str) -> int:
    """How many recorded values fall inside the prediction; each must equal it exactly."""
    profile = handle.profiles[a]
    begin = handle.begin[a] if isinstance(handle, galil.MoveHandle) else handle.begin
    assert begin is not None
    k = rec.samples - begin
    inside = (k >= 0) & (k <= profile.samples)
    np.testing.assert_array_equal(rec[f"_RP{a}"][inside], profile.position[k[inside]])
    return int(inside.sum())


def test_a_capture_armed_with_a_move_is_its_prediction_at_every_recorded_sample(
    dmc: galil.Controller,
) -> None:
    x = dmc.A.set_scale(counts_per=2000 / mm)
    x.speed, x.accel, x.decel = 20 * mm / s, 200 * mm / s**2, 100 * mm / s**2
    plan = x.plan_to(5 * mm)
    cap = dmc.capture(["_RPA", "_TPA", "_TEA", "_TVA"], every=2, seconds=plan.duration)
    move = x.move_to(5 * mm)
    rec = cap.wait()
    assert rec.start == move.begin["A"]  # no time passed between the two lines
    assert exact(move, rec, "A") == len(rec) == plan.samples // 2 + 1
    assert rec.samples[-1] - rec.start == 2 * (len(rec) - 1)
    assert rec.t[1] == pytest.approx(2 * dmc.sample_period)
    assert np.all(rec["_TPA"] - rec["_RPA"] == -rec["_TEA"])
    assert rec["_TVA"].max() > 0
    assert compare(move, rec)["A"].worst == 0
    assert repr(cap).endswith("uploaded>")
    assert dmc.arrays.list() == {}  # its arrays are freed once uploaded


def test_compare_measures_how_far_a_recording_strays_from_its_prediction(
    dmc: galil.Controller,
) -> None:
    plan = dmc.A.plan_by(5000)
    cap = dmc.capture(["_RPA"], every=2, seconds=plan.duration)
    move = dmc.A.move_by(5000)
    dmc.sleep(plan.duration / 2)
    dmc.link.command_line(["ST A"])  # the library does not know: the recording strays
    with pytest.raises(galil.MotionError, match="did not send"):  # (decision 0105)
        move.wait()
    rec = cap.wait()
    got = compare(move, rec)["A"]
    k = rec.samples - move.begin["A"]  # type: ignore[operator]
    inside = k <= plan.samples
    expected = plan.position[k[inside]]
    np.testing.assert_array_equal(got.difference[inside], rec["_RPA"][inside] - expected)
    assert got.worst == np.max(np.abs(rec["_RPA"][inside] - expected)) > 1000
    # (t, positions) by hand: one sample 7 counts off is a worst of 7.
    shifted = plan.position.astype(float)
    shifted[10] += 7
    assert compare({"A": plan}, {"A": (plan.t, shifted)})["A"].worst == 7


def test_a_capture_of_a_contour_every_4_samples_is_exact(dmc: galil.Controller) -> None:
    path = 3000 * (1 - np.cos(np.linspace(0, math.pi, 40))) / 2
    cap = dmc.capture(["_RPB"], every=4, seconds=0.2)
    result = dmc.contour("B", path, dt=2)
    rec = cap.wait()
    assert result.begin is not None
    assert exact(result, rec, "B") > 30


def test_every_sample_is_refused_the_controller_records_every_2_at_most(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=r"every 2\*\*n samples"):
        dmc.capture(["_RPA"], every=1, count=10)


@pytest.mark.parametrize(
    ("sources", "options", "words"),
    [
        (["_XXA"], {"count": 10}, "cannot record"),
        (["_RPE"], {"count": 10}, "unknown axis"),
        ("_RPA", {"count": 10}, "list of operands"),
        (["_RPA", "_RPA"], {"count": 10}, "twice"),
        ([f"_{op}{a}" for op in ("TP", "RP", "TE") for a in "ABC"], {"count": 10}, "1 to 8"),
        (["_RPA"], {"every": 3, "count": 10}, "2, 4, 8"),
        (["_RPA"], {"count": 0}, "positive"),
        (["_RPA"], {}, r"\(count=\) or for how long"),
        (["_RPA"], {"count": 10, "seconds": 1.0}, r"\(count=\) or for how long"),
        (["_RPA", "_TPA"], {"count": 12_001}, "array elements"),
        (["_RPA"], {"seconds": -1.0}, "positive"),
    ],
)
def test_a_bad_capture_is_refused_before_a_byte(
    dmc: galil.Controller, sources: object, options: dict[str, object], words: str
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=words):
        dmc.capture(sources, **options)  # type: ignore[arg-type]


def test_one_recording_at_a_time_and_a_stopped_one_keeps_what_it_has(
    dmc: galil.Controller,
) -> None:
    with dmc.capture(["_RPA"], every=8, count=1000) as cap:
        with (
            nothing_sent(dmc, allow_queries=True),
            pytest.raises(galil.InvalidArgument, match="recording already"),
        ):
            dmc.capture(["_TPA"], every=2, count=10)
        dmc.A.jog(5000)
        dmc.sleep(0.1)
        dmc.A.stop()
    rec = cap.result
    assert rec is not None
    assert 10 <= len(rec) < 20  # about 0.1 s at 8 samples per value, then RC 0
    assert rec["_RPA"][-1] > rec["_RPA"][0]
    assert cap.stop() is rec


def test_a_capture_not_read_before_the_next_starts_refuses_to_read_the_next_ones_values(
    dmc: galil.Controller,
) -> None:
    """Every capture records into the same arrays: one finished and not read back when
    the next starts has lost its values. Its wait() and stop() refuse (they read, and stop
    would end, the later recording); the later capture reads its own values whole."""
    first = dmc.capture(["_RPA"], every=2, count=10)
    dmc.sleep(0.05)
    assert first.done
    move = dmc.A.move_by(1000)
    second = dmc.capture(["_RPA"], every=2, count=10)
    move.wait()
    for read in (first.wait, first.stop):
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="reused"):
            read()
    values = second.wait()["_RPA"]
    assert len(values) == 10
    assert values[-1] > values[0]  # the move, recorded by the second capture


def test_a_capture_refused_for_a_recording_under_way_leaves_the_earlier_one_readable(
    dmc: galil.Controller,
) -> None:
    first = dmc.capture(["_RPA"], every=2, count=100)
    with pytest.raises(galil.InvalidArgument, match="recording already"):
        dmc.capture(["_TPA"], every=2, count=10)
    assert len(first.wait()["_RPA"]) == 100


def test_records_carry_controller_time_and_a_period_in_seconds(dmc: galil.Controller) -> None:
    dmc.sleep(70.0)  # past a wrap of the record's 16-bit sample counter
    now = round(dmc.query_number("MG TIME"))
    assert now > SAMPLE_WRAP
    rec = dmc.record()
    assert rec["time"] == now
    assert rec["time"] % SAMPLE_WRAP == rec["sample"]
    assert galil.decode_fields(rec).time == now
    with dmc.records(seconds=8 / 1024) as stream:
        assert stream.period == 8
        assert stream.period_seconds == pytest.approx(8 / 1024)
        got = stream.take(3)
    assert np.all(np.diff(got["time"]) == 8)
    assert stream.missed == 0
    with pytest.raises(galil.InvalidArgument, match="whole number"):
        dmc.records(seconds=0.0007)  # 0.7 samples
    assert dmc.records(seconds=0.01).period == 10  # 2.3 % shorter, as EPICS's "ms" are
    with pytest.raises(galil.InvalidArgument, match="not both"):
        dmc.records(8, seconds=8 / 1024)
    assert dmc.records(seconds=16 / 1024 * ureg.s).period == 16


@pytest.mark.parametrize("bad", [float("inf"), float("nan"), 0, -0.01, True, "0.01"])
def test_a_record_period_in_seconds_must_be_a_positive_finite_time(
    dmc: galil.Controller, bad: object
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="seconds"):
        dmc.records(seconds=bad)


def test_a_late_poll_is_counted_as_missed_records(
    dmc: galil.Controller, caplog: pytest.LogCaptureFixture
) -> None:
    with dmc.records(16) as stream:
        stream.get()
        stream.get()
        dmc.sleep(5 * 16 / 1024)  # nobody asked for four records
        with caplog.at_level(logging.WARNING, logger="galil.records"):
            late = stream.get()
    assert stream.missed == 4
    assert stream.gaps == [(int(late["time"]), 4)]
    assert "4 data record(s) missing" in caplog.text
    assert "4 missed" in repr(stream)


def test_pushed_records_keep_counting_across_the_16_bit_wrap() -> None:
    sim = SimController("DMC-4040", ManualClock())
    sim.advance((SAMPLE_WRAP - 600) / 1024)
    with (
        SimTcpServer(sim) as srv,
        galil.connect(srv.url, timeout=2.0) as c,
        c.records(256) as stream,
    ):
        srv.advance(1.5)
        recs = stream.take(5, timeout=5.0)
    assert recs["time"][0] < SAMPLE_WRAP < recs["time"][-1]
    assert np.all(np.diff(recs["time"]) == 256)
    assert np.all(recs["time"] % SAMPLE_WRAP == recs["sample"])


def test_interrupts_need_an_ethernet_handle(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="Ethernet handle"):
        dmc.interrupts.enable()
    with pytest.raises(galil.InvalidArgument):
        dmc.interrupts.enable(axes="E")
    assert not dmc.interrupts.enabled


@pytest.fixture(scope="module")
def recorded_runs() -> dict[str, object]:
    """A move, a jog and a contour over TCP, each recorded by a capture and data records,
    the way the demo (and the notebook) records them: through the public API only."""
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as dmc:
        x = dmc.A.set_scale(counts_per=2000 / mm)
        x.speed, x.accel, x.decel = 40 * mm / s, 400 * mm / s**2, 400 * mm / s**2

        def move() -> galil.MoveHandle:
            handle = x.move_to(4 * mm)
            handle.wait()
            return handle

        def jog() -> galil.MoveHandle:
            handle = x.jog(10 * mm / s)
            dmc.sleep(0.1)
            x.jog(-5 * mm / s)
            dmc.sleep(0.1)
            x.stop()
            handle.wait()
            return handle

        path = 2000 * (1 - np.cos(np.linspace(0, math.pi, 30))) / 2
        return {
            "move": record_motion(dmc, "move", "A", move, 0.6),
            "jog": record_motion(dmc, "jog", "A", jog, 0.8),
            "contour": record_motion(
                dmc, "contour", "B", lambda: dmc.contour("B", path, dt=2), 0.3
            ),
        }


@pytest.mark.parametrize("name", ["move", "jog", "contour"])
def test_a_motion_compared_with_data_records_and_a_capture_is_0_counts_off(
    recorded_runs: dict[str, object], name: str
) -> None:
    run = recorded_runs[name]
    assert run.worst() == {"capture": 0, "data records": 0}  # type: ignore[attr-defined]
    handle, letter = run.handle, run.letter  # type: ignore[attr-defined]
    profile = handle.profiles[letter]
    begin = handle.begin[letter] if isinstance(handle, galil.MoveHandle) else handle.begin
    # Both recordings cover the whole motion, and the motion moved.
    for samples in (run.capture.samples, run.records["time"]):  # type: ignore[attr-defined]
        assert samples[0] <= begin + 2
        assert samples[-1] >= begin + profile.samples
    assert np.ptp(run.capture.position(letter)) > 100  # type: ignore[attr-defined]
