"""Checks before a coordinated-motion sequence is sent: each refusal names segment and sample."""

from __future__ import annotations

import numpy as np
import pytest

from galil.errors import InvalidArgument, LimitError
from galil.models import get_model
from galil.predict import (
    Arc,
    Line,
    LinearInterp,
    VectorProfiler,
    axis_rates,
    check_vector,
    quantise_vector,
    segment_deadlines,
    vector,
)

SQUARE = [Line(8000, 0), Arc(1000, 270, 90), Line(0, 8000), Arc(1000, 0, 90), Line(-8000, 0)]


def refusal(segments: list, **kw: object) -> LimitError:
    kw.setdefault("speed", 50_000)
    kw.setdefault("accel", 512_000)
    kw.setdefault("decel", 512_000)
    with pytest.raises(LimitError) as err:
        check_vector(segments, **kw)  # type: ignore[arg-type]
    return err.value


def test_a_good_path_passes_and_returns_its_prediction() -> None:
    p = check_vector(SQUARE, 50_001, 512_000, 512_000, model="DMC-4040", start=(10, 10))
    assert p.speed_settings[0] == 50_000
    assert p.end == (10, 10010)


def test_quantise_vector_follows_the_model_ranges() -> None:
    q = quantise_vector("DMC-4143", speed=15_000_001 - 1, accel=73_422, decel=2048, smoothing=0.5)
    assert (q.speed, q.accel, q.decel, q.smoothing) == (15_000_000, 72_704, 2048, 0.5)
    assert q.sample_period == get_model("DMC-4143").sample_period
    for kwargs, name in (
        ({"speed": 15_000_002}, "VS"),
        ({"speed": 1}, "VS"),
        ({"accel": 0}, "VA"),
        ({"decel": 1_073_741_825}, "VD"),
        ({"smoothing": 0.001}, "VT"),
    ):
        with pytest.raises(LimitError) as err:
            quantise_vector("DMC-4143", **kwargs)  # type: ignore[arg-type]
        assert err.value.name == name
    assert quantise_vector("DMC-4040", speed=20_000_000).speed == 20_000_000


def test_vs_va_and_vd_step_with_tm_as_sp_and_ac_do() -> None:
    # (assumed, docs/decisions/0025 "Predictions at any TM": they kept TM 1000's steps of 2
    # and 1024, so at TM 250 VA 20,000 was planned as 19,456, beneath AC's smallest 16,384
    # step, and VS 80,002 as 80,002 where SP's step is 8)
    q = quantise_vector("DMC-4040", speed=80_006, accel=40_000, decel=20_000, tm=250)
    assert (q.speed, q.accel, q.decel) == (80_000, 32_768, 16_384)
    q = quantise_vector("DMC-4040", speed=4 / 3 * 83_494, accel=1000, decel=500, tm=1500)
    step = 1024 * (1000 / 1500) ** 2  # (and VA/VD's smallest, as AC's)
    assert (q.speed, q.accel, q.decel) == pytest.approx((4 / 3 * 83_494, 2 * step, step))
    assert quantise_vector("DMC-4040", accel=8_000, tm=250).accel == 16_384  # raised to it


def test_mixing_li_with_vp_is_tc_33_at_the_segment_where_it_happens() -> None:
    err = refusal([Line(5000, 0), Line(0, 5000), LinearInterp((1, 1))])
    assert err.name == "TC 33"
    assert "segment 2" in str(err)
    assert err.sample is not None
    assert err.sample > 0


def test_a_too_short_segment_is_tc_30_with_the_sample_the_path_gets_there() -> None:
    err = refusal([Line(5000, 0), Line(0, 0), Line(0, 5000)])
    assert err.name == "TC 30"
    assert "segment 1" in str(err)
    reach = vector([Line(5000, 0), Line(0, 5000)], 50_000, 512_000, 512_000)
    first_after = reach.samples_of(1)[0]
    assert err.sample is not None
    assert abs(err.sample - first_after) <= 1
    assert err.time == pytest.approx(err.sample / 1024)


def test_a_path_over_two_billion_counts_is_tc_31() -> None:
    err = refusal([Line(1_500_000_000, 0), Line(-600_000_000, 0)], speed=20_000_000)
    assert err.name == "TC 31"
    assert "segment 1" in str(err)


def test_more_segments_than_the_buffer_need_streaming() -> None:
    many = [Line(100, 0), Line(0, 100)] * 256 + [Line(1, 1)]
    err = refusal(many, speed=200_000)
    assert err.name == "segment buffer"
    assert "segment 511" in str(err)
    assert err.limit == 511
    p = check_vector(many, 200_000, 2_048_000, 2_048_000, streaming=True)
    assert len(p.layout) == 513


def test_li_and_cr_ranges_are_checked() -> None:
    assert refusal([LinearInterp((8_388_608, 0))]).name == "LI"
    assert refusal([LinearInterp((1,) * 5)], model="DMC-4040").name == "LM axes"
    assert refusal([Line(100, 0), Arc(5, 0, 90)]).name == "CR radius"
    assert refusal([Arc(100, 40_000, 90)]).name == "CR angle"
    assert refusal([Arc(6_000_000, 0, 100)], speed=20_000_000).name == "CR arc"


def test_an_axis_past_its_speed_limit_is_named_with_segment_and_sample() -> None:
    err = refusal([Line(10_000, 0), Line(0, 10_000)], speed_limits=(None, 30_000), axes="XY")
    assert err.name == "axis speed"
    assert err.axis == "Y"
    assert "segment 1" in str(err)
    assert err.sample is not None
    check_vector([Line(10_000, 0), Line(0, 10_000)], 25_000, 512_000, 512_000, speed_limits=30_000)


def test_a_tight_arc_is_refused_for_its_centripetal_acceleration() -> None:
    err = refusal(
        [Line(50_000, 0), Arc(10, 270, 180), Line(-50_000, 0)],
        speed=1_000_000,
        accel=10_240_000,
        decel=10_240_000,
    )
    assert err.name == "axis acceleration"
    assert "segment 1" in str(err)
    assert err.value is not None
    assert err.value > get_model("DMC-4040").ac_max


def test_axis_rates_resolve_the_vector_speed_onto_each_axis() -> None:
    p = vector([Line(3000, 4000), Arc(2000, 0, 90)], 10_000, 102_400, 102_400)
    vel, acc = axis_rates(p)
    line = p.segment == 0
    assert np.allclose(vel[0][line], 0.6 * p.speed[line])
    assert np.allclose(vel[1][line], 0.8 * p.speed[line])
    arc = (p.segment == 1) & (p.speed > 0)
    assert np.allclose(np.hypot(vel[0][arc], vel[1][arc]), p.speed[arc])
    steady = np.zeros_like(arc)
    steady[:-1] = np.isclose(p.speed[:-1], 10_000) & np.isclose(p.speed[1:], 10_000)
    cruise = arc & steady
    assert cruise.any()
    centripetal = np.hypot(acc[0][cruise], acc[1][cruise])
    assert np.allclose(centripetal, 10_000**2 / 2000, rtol=1e-6, atol=1.0)


def test_soft_limits_are_checked_over_the_whole_path_per_axis() -> None:
    # the path swings out to x = 9000 on its way to x = 0: the end alone would pass
    err = refusal(SQUARE, forward_limits=(8_500, None), axes=("X", "Y"))
    assert err.name == "FL"
    assert err.axis == "X"
    assert "segment 1" in str(err)
    assert err.sample is not None
    # y never goes below its start, so BL just below it passes
    check_vector(SQUARE, 50_000, 512_000, 512_000, backward_limits=[None, -1])
    check_vector(SQUARE, 50_000, 512_000, 512_000, forward_limits=10_000, backward_limits=-1)


def test_positions_beyond_32_bits_are_refused() -> None:
    err = refusal([Line(1000, 0)], start=(2_147_483_000, 0))
    assert err.name == "position range"
    assert "segment 0" in str(err)


def test_argument_shapes_are_validated() -> None:
    with pytest.raises(InvalidArgument):
        check_vector([], 1000, 10240, 10240)
    with pytest.raises(InvalidArgument):
        check_vector([Line(1000, 0)], 1000, 10240, 10240, forward_limits=(1, 2, 3))
    with pytest.raises(InvalidArgument):
        check_vector([Line(1000, 0)], 1000, 10240, 10240, axes="XYZ")


def test_segments_sent_by_their_deadlines_keep_the_prediction() -> None:
    segs = [Line(3000, 0), Arc(500, 270, 90), Line(0, 3000), Arc(500, 0, 90), Line(-3000, 0)]
    p = vector(segs, 40_000, 512_000, 512_000)
    deadlines = segment_deadlines(p)
    assert deadlines[0] == 0
    assert (np.diff(deadlines) >= 0).all()

    def streamed(delay: int) -> np.ndarray:
        eng = VectorProfiler()
        eng.add(segs[0])
        eng.begin(40_000, 512_000, 512_000)
        out = []
        for i in range(1, len(segs)):
            out.append(eng.advance(int(deadlines[i]) + delay - eng.sample))
            eng.add(segs[i])
        eng.end()
        while eng.moving:
            out.append(eng.advance(64))
        return np.concatenate(out, axis=1)

    on_time = streamed(0)
    n = p.samples
    assert np.abs(on_time[:, :n] - p.position[:, 1:]).max() <= 1
    late = streamed(40)
    assert late.shape[1] > n + 20  # the controller slowed down waiting for a segment
