"""Item 4 of issue 6: contour streaming, buffer pacing, underrun and infeasible links."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from axis_helpers import assert_follows

import galil
from galil.contour import ContourStream, sample_path
from galil.errors import InvalidArgument, LimitError
from galil.sim.controller import SimController
from galil.sim.faults import FaultPlan
from galil.testing import nothing_sent, sim_of, simulated, transcript


def _ramp(n: int, step: float = 37.3) -> np.ndarray:
    """A path of ``n`` segments with non-integer steps (the planner must carry the fractions)."""
    return np.cumsum(np.full(n, step)) + 40 * np.sin(np.arange(n) / 50)


def test_long_contour_keeps_the_buffer_fed(
    dmc: galil.Controller, capsys: pytest.CaptureFixture[str]
) -> None:
    sim = sim_of(dmc)
    dmc.A.move_to(1000).wait()
    path = _ramp(2000)  # four times the 511-deep buffer
    t0 = sim.start_trace("A")
    wire: list[tuple[str, bytes]] = []
    remove = dmc.wire_log.add(lambda direction, data: wire.append((direction, data)))
    result = dmc.contour("A", path, dt=1, progress=True)
    remove()
    trace = sim.stop_trace("A")["A"]
    log = [text for k, text in sim.command_log if k >= t0]
    cds = [text for text in log if text.startswith("CD ") and text != "CD 0=0"]
    at = log.index("MG _TC")  # after the state read: the error code, then contour mode
    assert log[at : at + 3] == ["MG _TC", "CM A", "DT -1"]  # held until the buffer is full
    start = log.index("DT 1")
    assert log[at + 3 : start] == ["MG _CM,_TC,_SCA", *cds[:510]]  # pre-loaded: full, one spare
    assert log[start + 1].startswith("MG TIME")  # the stream's begin: the DT that starts it
    assert len(cds) == 2000
    assert log[-1].startswith("MG")
    assert "CD 0=0" in log
    assert log.index("CD 0=0") > max(i for i, t in enumerate(log) if t in cds)
    sent = np.array([int(t[3:]) for t in cds])
    np.testing.assert_array_equal(sent, result.increments[:, 0])
    assert 1000 + sent.sum() == round(path[-1]) + 1000 == dmc.A.reference_position
    assert 0 < result.low_water < 511  # filled, never overfilled (a CD never waited for room)
    assert result.low_water == min(_free_places(wire))  # the fewest any _CM reply gave
    assert result.lines < 2000 / 4  # several segments per line
    started = min(k for k, text in sim.command_log if k >= t0 and text == "DT 1")
    assert result.begin == started
    assert_follows(trace, t0, result.profiles["A"], started)
    assert dmc.A.stop_code[0] == 51
    assert "contour A" in capsys.readouterr().err
    assert result.duration == pytest.approx(2000 * 2 * dmc.sample_period)


def test_two_axis_contour_from_sample_path(dmc: galil.Controller) -> None:
    a, b = 6000.0, 0.120  # the manual's 1 - cos move
    t = sample_path(
        lambda t: a * t / b - a / (2 * math.pi) * np.sin(2 * math.pi * np.minimum(t, b) / b),
        b,
        2,
        dmc.sample_period,
    )
    path = np.stack([t, -0.5 * t], axis=1)
    result = dmc.contour("BD", path, dt=2)
    assert result.axes == "BD"
    assert dmc.query_operands(["_RPB", "_RPD"]) == [6000, -3000]


def _slow_link(delay: float) -> tuple[SimController, FaultPlan]:
    """A link where every reply costs ``delay`` seconds of the controller's (manual) time.

    A FaultPlan delay on a manual clock only holds bytes back; this plan also lets the
    controller's clock run while the host waits, as a slow link would.
    """
    sim = SimController("DMC-4040")
    plan = FaultPlan(delay=delay)

    def hook(data: bytes) -> list[tuple[float, bytes]]:
        sim.advance(delay)
        return plan(data)

    return sim, hook  # type: ignore[return-value]


def test_underrun_raises(dmc: galil.Controller) -> None:
    sim, hook = _slow_link(0.5)  # half a second per reply: longer than the refill margin
    with galil.connect("sim://DMC-4040", controller=sim, faults=hook) as slow:
        with pytest.raises(galil.ContourUnderrunError) as info:
            slow.contour("A", _ramp(2000), dt=1)
        assert info.value.code == 42
        assert 0 < info.value.segment < 2000
        assert "too slowly" in str(info.value)
        # The stream ended contour mode; the axis can move again once the buffer drained.
        slow.sleep(2.0)
        assert slow.A.moving is False
        slow.A.move_by(100).wait()


def test_a_buffer_that_ran_dry_before_the_last_batch_was_in_raises(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The host is late with its LAST batch: the _TC read before that batch found the buffer
    # fed, and the buffer ran dry before the batch was in. Before, nothing read the 42 after
    # it: the path paused on its way and contour() returned as if it had run on time.
    sim = SimController("DMC-4040")
    path = _ramp(1200)
    fed = [0]
    feed = sim.feed

    def late_last_batch(data: bytes, port: int = 0) -> bytes:
        segments = data.count(b"CD ")
        if 0 < fed[0] < len(path) <= fed[0] + segments:
            sim.advance(2.0)  # the host stalled: the 511 queued segments (1 s) ran out
        fed[0] += segments
        return feed(data, port)

    monkeypatch.setattr(sim, "feed", late_last_batch)
    with galil.connect("sim://DMC-4040", controller=sim) as dmc:
        with pytest.raises(galil.ContourUnderrunError) as info:
            dmc.contour("A", path, dt=1)
        assert info.value.code == 42
        assert len(path) - 511 < info.value.segment < len(path)  # (the last batch's first)
        assert "too slowly" in str(info.value)
        dmc.sleep(2.0)  # the stream ended contour mode; the axis moves again once drained
        assert dmc.A.moving is False
        dmc.A.move_by(100).wait()


def test_fast_enough_link_does_not_underrun() -> None:
    sim, hook = _slow_link(0.002)
    with galil.connect("sim://DMC-4040", controller=sim, faults=hook) as dmc:
        result = dmc.contour("A", _ramp(1500), dt=1)
        assert result.increments.shape == (1500, 1)


def _free_places(wire: list[tuple[str, bytes]]) -> list[float]:
    """Every ``_CM`` the library read (the first number of the reply to an ``MG _CM...``)."""
    return [
        float(reply.split()[0])
        for (d, line), (_, reply) in itertools.pairwise(wire)
        if d == "out" and line.startswith(b"MG _CM")
    ]


def test_a_short_contour_reports_how_full_the_buffer_got(dmc: galil.Controller) -> None:
    wire: list[tuple[str, bytes]] = []
    remove = dmc.wire_log.add(lambda direction, data: wire.append((direction, data)))
    result = dmc.contour("A", _ramp(300), dt=1)  # fits in the 511-deep buffer at once
    remove()
    assert 511 - 300 <= result.low_water == min(_free_places(wire)) < 511


def test_one_deep_buffer_paces_with_wc() -> None:
    with simulated("DMC-1500") as dmc:
        sim = sim_of(dmc)
        path = _ramp(40, step=120.0)
        t0 = sim.start_trace("A")
        result = dmc.contour("X", path, dt=3)
        trace = sim.stop_trace("A")["A"]
        lines = [text for k, text in sim.command_log if k >= t0]
        assert lines.count("WC") == 40
        assert result.lines == 40
        first_cd = min(k for k, text in sim.command_log if k >= t0 and text.startswith("CD "))
        assert_follows(trace, t0, result.profiles["A"], first_cd)
        assert dmc.X.reference_position == round(path[-1])
        # The DMC-1500's CD takes no "=n": DT 0 then CD 0 end contour mode, as its manual says.
        ends = [text for text in lines if text in ("DT 0", "CD 0")]
        assert ends == ["DT 0", "CD 0"]
        assert lines.index("CD 0") == lines.index("DT 0") + 1
        assert not any("=" in text for text in lines if text.startswith("CD"))
        dmc.X.move_by(100).wait()  # out of contour mode: an ordinary move runs


def test_contour_bad_input_sends_nothing(dmc: galil.Controller) -> None:
    with nothing_sent(dmc), pytest.raises(LimitError, match="CD 40000") as info:
        dmc.contour("A", [100, 200, 40_200], dt=1)
    assert info.value.name == "CD"
    assert info.value.axis == "A"
    with nothing_sent(dmc), pytest.raises(LimitError, match="DT 9"):
        dmc.contour("A", [1, 2], dt=9)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="shape"):
        dmc.contour("AB", [1, 2, 3], dt=1)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="distinct"):
        dmc.contour("AA", [[1, 1]], dt=1)
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="NaN"):
        dmc.contour("A", [1, math.nan], dt=1)
    with nothing_sent(dmc), pytest.raises(InvalidArgument):
        dmc.contour("Q", [1], dt=1)
    dmc.A.jog(1000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument, match="moving"):
        dmc.contour("A", [1, 2], dt=1)


@pytest.mark.parametrize("axes", ["A", "BA"])
def test_a_contour_on_an_axis_with_its_motor_off_is_refused_before_cm(
    dmc: galil.Controller, axes: str
) -> None:
    dmc.motor_off("A")  # (the state query reads TS, whose bit 5 is "motor off")
    path = np.column_stack([[100, 200, 300]] * len(axes))
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument) as info:
        dmc.contour(axes, path, dt=2)
    assert "axis A has its motor off; call controller.servo_here()" in str(info.value)
    assert dmc.query_operands(["_RPA", "_RPB", "_MOA"]) == [0, 0, 1]  # nothing moved


def test_contour_past_a_soft_limit_is_refused_before_cm() -> None:
    from galil.errors import LimitError
    from galil.testing import nothing_sent, simulated

    with simulated() as dmc:
        dmc.command("FLB=1000")
        path = [500.0 * (i + 1) for i in range(10)]  # out to 5000 counts
        with nothing_sent(dmc, allow_queries=True), pytest.raises(LimitError) as info:
            dmc.contour("B", path, dt=2)
        assert info.value.name == "FL"
        assert info.value.axis == "B"
        assert dmc.B.reference_position == 0


def test_contour_path_in_millimetres_follows_the_scale() -> None:
    from galil.errors import InvalidArgument
    from galil.testing import nothing_sent, simulated
    from galil.units import ureg

    with simulated() as dmc:
        dmc.B.set_scale(counts_per=2000 / ureg.mm)
        path = np.linspace(0.25, 3.0, 12) * ureg.mm
        result = dmc.contour("B", path, dt=2)
        assert int(result.increments.sum()) == 6000
        assert dmc.B.reference_position.to("mm").magnitude == pytest.approx(3.0)
        with nothing_sent(dmc), pytest.raises(InvalidArgument):
            dmc.contour("B", np.linspace(1, 2, 4) * ureg.s, dt=2)
        with nothing_sent(dmc), pytest.raises(InvalidArgument):
            dmc.contour("C", np.linspace(1, 2, 4) * ureg.mm, dt=2)  # C has no scale


def _interrupt_on_pause(dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, call: int) -> None:
    """Make the link's ``call``-th pause raise KeyboardInterrupt (a Ctrl-C while waiting)."""
    real = dmc.link.pause
    calls = [0]

    def pause(seconds: float) -> None:
        calls[0] += 1
        if calls[0] == call:
            raise KeyboardInterrupt
        real(seconds)

    monkeypatch.setattr(dmc.link, "pause", pause)


def test_interrupted_contour_stream_stops_the_axes(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    _interrupt_on_pause(dmc, monkeypatch, 3)
    with transcript(dmc) as wire, pytest.raises(KeyboardInterrupt):
        dmc.contour("AB", np.stack([_ramp(2000), -_ramp(2000)], axis=1), dt=8)
    monkeypatch.undo()
    wire.assert_contains("ST AB")
    dmc.sleep(0.5)  # a decel, not the 127 s of queued segments
    assert dmc.A.moving is False
    assert dmc.B.moving is False
    dmc.A.move_by(100).wait()  # out of contour mode: an ordinary move runs


def test_contour_interrupted_while_finishing_stops_the_axes(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 20 segments of DT 8 (5 s) fit the buffer at once: the first pause is the finish's wait.
    _interrupt_on_pause(dmc, monkeypatch, 1)
    with transcript(dmc) as wire, pytest.raises(KeyboardInterrupt):
        dmc.contour("A", _ramp(20, step=200.0), dt=8)
    monkeypatch.undo()
    wire.assert_contains("ST A")
    dmc.sleep(0.5)
    assert dmc.A.moving is False
    dmc.A.move_by(100).wait()


def test_contour_that_times_out_stops_the_axes(dmc: galil.Controller) -> None:
    with pytest.raises(galil.GalilTimeoutError):
        dmc.contour("A", _ramp(20, step=200.0), dt=8, timeout=0.5)
    dmc.sleep(0.5)
    assert dmc.A.moving is False


@pytest.mark.parametrize("timeout", ["5", -1, math.nan, math.inf, True])
def test_contour_bad_timeout_sends_nothing(dmc: galil.Controller, timeout: object) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="timeout"):
        dmc.contour("A", [1, 2], dt=1, timeout=timeout)  # type: ignore[arg-type]


def test_a_preload_cut_before_its_start_never_moves_and_leaves_contour_mode(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The pre-load goes out, then a Ctrl-C comes before the DT that would start it: the held
    # segments are dropped (CM clears a buffer that is not running), and no positive DT goes
    # out while any is held.
    real = dmc.link.command_line

    def cut(commands: list[galil.protocol.commands.Command], **kw: object) -> list[str]:
        texts = [c.text for c in commands]
        if "DT 1" in texts and any(t.startswith("CD ") for t in texts):
            real(commands[: texts.index("DT 1")], **kw)  # type: ignore[arg-type]
            raise KeyboardInterrupt
        return real(commands, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(dmc.link, "command_line", cut)
    before = dmc.A.position
    with transcript(dmc) as wire, pytest.raises(KeyboardInterrupt):
        dmc.contour("A", _ramp(2000), dt=1)
    monkeypatch.undo()
    sent = [part for line in wire.lines for part in line.split(";")]
    cleanup = sent[sent.index("ST A") :]
    assert cleanup[:3] == ["ST A", "CM A", "MG _CM"]
    assert cleanup.index("DT 1") > cleanup.index("MG _CM")  # only once the buffer read empty
    assert cleanup[-1] == "CD 0=0"
    dmc.sleep(1.0)
    assert dmc.A.position == before  # nothing of the pre-load ever ran
    assert dmc.query_operands(["_CM"]) == [511]
    dmc.A.move_by(100).wait()  # out of contour mode: an ordinary move runs
    dmc.contour("A", _ramp(600), dt=1)  # and a new stream starts from an empty buffer


def test_cm_drops_segments_held_under_dt_minus_one(dmc: galil.Controller) -> None:
    for line in ("CM A", "DT -1", "CD 100", "CD 100"):
        dmc.command(line)
    assert dmc.query_operands(["_CM"]) == [509]
    dmc.command("CM A")  # not running: the buffer is cleared
    assert dmc.query_operands(["_CM"]) == [511]
    dmc.command("DT 1")
    dmc.sleep(0.1)
    assert dmc.A.position == 0
    dmc.command("CD 0=0")
    dmc.A.move_by(100).wait()


@pytest.mark.parametrize("preload", ["yes", 1, None])
def test_contour_stream_preload_must_be_a_bool(dmc: galil.Controller, preload: object) -> None:
    with nothing_sent(dmc), pytest.raises(InvalidArgument, match="preload"):
        ContourStream(dmc.link, "A", _ramp(10), dt=1, preload=preload)  # type: ignore[arg-type]


def test_a_stream_without_preload_starts_with_its_first_segment(dmc: galil.Controller) -> None:
    sim = sim_of(dmc)
    t0 = sim.start_trace("A")
    stream = ContourStream(dmc.link, "A", _ramp(700), dt=1, preload=False)
    stream.prepare()
    result = stream.finish(stream.feed())
    trace = sim.stop_trace("A")["A"]
    log = [text for k, text in sim.command_log if k >= t0]
    assert "DT -1" not in log
    assert log[log.index("CM A") + 1] == "DT 1"
    first_cd = min(k for k, text in sim.command_log if k >= t0 and text.startswith("CD "))
    assert result.begin == first_cd
    assert_follows(trace, t0, result.profiles["A"], first_cd)


def test_cd_with_minus_one_pauses_the_buffer_until_a_positive_dt(dmc: galil.Controller) -> None:
    # DMC-4103 reference, CD: "t = -1: Pauses contour buffer at the segment with t=-1.
    # Reissue DT to re-engage contour mode", shown as CD 0,0,0=-1 between segments.
    for line in ("CM A", "DT 2", "CD 100", "CD 0=-1", "CD 300", "CD 500"):
        dmc.command(line)
    dmc.sleep(1.0)
    assert dmc.A.position == 100  # the first segment ran; the ones behind the pause wait
    assert dmc.query_operands(["_CM"]) == [509]
    dmc.command("DT 2")  # re-engaged
    dmc.command("CD 0=0")
    dmc.sleep(1.0)
    assert dmc.A.position == 900
    assert dmc.A.moving is False
    dmc.command("CM A")
    with pytest.raises(galil.CommandError) as info:
        dmc.command("CD 5=-1")  # a pause that moves: not in the reference
    assert info.value.code == 41
