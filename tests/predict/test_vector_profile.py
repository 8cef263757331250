"""The vector profile: closed form, path fidelity, exact ends, the stepping engine."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import CommandError, InvalidArgument, LimitError
from galil.predict import Arc, Line, LinearInterp, VectorProfile, VectorProfiler, vector

TS = 1 / 1024
SETTINGS = settings(max_examples=40, deadline=None)
#: A 10000-count square with 1000-count rounded corners, counter-clockwise from the origin.
ROUNDED_SQUARE = (
    Line(8000, 0),
    Arc(1000, 270, 90),
    Line(0, 8000),
    Arc(1000, 0, 90),
    Line(-8000, 0),
    Arc(1000, 90, 90),
    Line(0, -8000),
    Arc(1000, 180, 90),
)


def distance_from_ideal(profile: VectorProfile) -> np.ndarray:
    """Distance of every sample (axes 0 and 1) from its segment's ideal line or circle."""
    lay = profile.layout
    p = (profile.position[:2] - np.array(profile.start)[:2, None]).T.astype(float)
    idx = profile.segment
    out = np.empty(len(p))
    for k, (pt, i) in enumerate(zip(p, idx, strict=True)):
        if lay.arc[i]:
            out[k] = abs(math.dist(pt, lay.centre[i]) - lay.radius[i])
        else:
            a, b = lay.start[i][:2], lay.end[i][:2]
            d = b - a
            t = 0.0 if not d.any() else float(np.clip(np.dot(pt - a, d) / np.dot(d, d), 0, 1))
            out[k] = math.dist(pt, a + t * d)
    return out


def closed_form(length: float, vs: float, va: float, vd: float, t: float) -> float:
    """The continuous trapezoid (or triangle) along the path at time t."""
    peak = min(vs, math.sqrt(2 * length * va * vd / (va + vd)))
    ta, td = peak / va, peak / vd
    tc = (length - peak * peak / (2 * va) - peak * peak / (2 * vd)) / peak
    if t <= ta:
        return 0.5 * va * t * t
    if t <= ta + tc:
        return peak * ta / 2 + peak * (t - ta)
    if t <= ta + tc + td:
        u = ta + tc + td - t
        return length - 0.5 * vd * u * u
    return length


@pytest.mark.parametrize(
    ("dx", "dy", "shape"), [(30_000, 40_000, "trapezoid"), (-600, 800, "triangle")]
)
def test_a_straight_line_follows_the_closed_form_vector_profile(
    dx: int, dy: int, shape: str
) -> None:
    vs, va, vd = 40_000, 256_000, 512_000
    p = vector([Line(dx, dy)], vs, va, vd)
    length = math.hypot(dx, dy)
    assert p.shape == shape
    assert p.length == length
    peak = min(vs, math.sqrt(2 * length * va * vd / (va + vd)))
    exact = length / peak + peak / (2 * va) + peak / (2 * vd)
    assert abs(p.duration - exact) <= 2 * TS
    ideal = np.array([closed_form(length, vs, va, vd, t) for t in p.t])
    assert np.max(np.abs(p.path - ideal)) <= vs * TS + 2
    assert p.speed.max() <= vs
    assert p.peak_speed == pytest.approx(peak)
    # each axis is the path position times the direction cosine, rounded half up
    assert np.array_equal(p.position[0], np.floor(p.path * dx / length + 0.5))
    assert np.array_equal(p.position[1], np.floor(p.path * dy / length + 0.5))
    assert p.end == (dx, dy)


def test_the_path_advances_exactly_like_a_single_axis_move() -> None:
    p = vector([Line(3000, 4000), Line(-3000, 4000)], 20_000, 256_000, 128_000, smoothing=0.25)
    m = predict.move(10_000, 20_000, 256_000, 128_000, smoothing=0.25)
    n = p.samples + 1
    assert np.array_equal(p.path, m.position[:n])
    # (move() may hold the end for a few more samples: its smoothed end is found page-wise)
    assert (m.position[n:] == 10_000).all()
    sharp = predict.move(10_000, 20_000, 256_000, 128_000)
    assert np.array_equal(vector([Line(6000, 8000)], 20_000, 256_000, 128_000).path, sharp.position)


def test_a_rounded_square_is_continuous_on_its_path_and_closes_exactly() -> None:
    vs = 60_000
    p = vector(ROUNDED_SQUARE, vs, 1_024_000, 1_024_000, start=(500, -250))
    assert p.start == p.end == (500, -250)
    assert p.stop_code == 101
    assert set(p.segment.tolist()) == set(range(8))
    steps = np.abs(np.diff(p.position, axis=1))
    assert steps.max() <= math.ceil(vs * TS) + 1
    assert distance_from_ideal(p).max() <= 1.0
    # the segments run in order, and each one's end (its corner) is exactly on the path
    bounds = p.layout.bounds
    assert p.layout.project(bounds[1:]).T.tolist() == p.layout.end.tolist()
    for i in range(7):
        assert p.samples_of(i)[1] < p.samples_of(i + 1)[0]


def test_a_full_circle_closes_on_its_start_point() -> None:
    for start_angle in (0, 37.5, 200):
        p = vector([Arc(25_000, start_angle, 360)], 100_000, 2_048_000, 2_048_000, start=(3, 4))
        assert p.end == (3, 4)
        assert distance_from_ideal(p).max() <= 1.0
        assert p.length == round(2 * math.pi * 25_000)
        # the farthest sample is a diameter away
        span = np.hypot(*(p.position - np.array([[3], [4]])))
        assert abs(span.max() - 50_000) <= 1.5


def test_clockwise_arcs_turn_the_other_way() -> None:
    ccw = vector([Arc(1000, 0, 90)], 10_000, 256_000, 256_000)
    cw = vector([Arc(1000, 0, -90)], 10_000, 256_000, 256_000)
    assert ccw.end == (-1000, 1000)
    assert cw.end == (-1000, -1000)
    assert np.array_equal(ccw.position[1], -cw.position[1])


def test_linear_interpolation_moves_several_axes_in_step() -> None:
    segs = [LinearInterp((1000, 2000, -2000)), LinearInterp((0, 0, 4000))]
    p = vector(segs, 20_000, 256_000, 256_000, start=(1, 2, 3))
    assert p.axes == 3
    assert p.layout.kind == "linear"
    assert p.end == (1001, 2002, 2003)
    assert p.length == 7000
    first = p.segment == 0
    assert np.array_equal(p.position[0][first] - 1, np.floor(p.path[first] * 1000 / 3000 + 0.5))


def test_a_model_quantises_vs_va_vd_and_vt() -> None:
    p = vector([Line(5000, 0)], 20_001, 100_000, 200_000, smoothing=0.3, model="DMC-4040")
    assert p.speed_settings == (20_000, 99_328, 199_680, round(0.3 * 256) / 256)
    with pytest.raises(LimitError) as err:
        vector([Line(5000, 0)], 16_000_000, 100_000, 100_000, model="DMC-4143")
    assert err.value.name == "VS"
    with pytest.raises(LimitError) as err:
        vector([Line(5000, 0)], 10_000, 2e9, 100_000, model="DMC-4040")
    assert err.value.name == "VA"


def test_smoothing_keeps_the_path_and_lengthens_the_motion() -> None:
    sharp = vector(ROUNDED_SQUARE, 50_000, 512_000, 512_000)
    smooth = vector(ROUNDED_SQUARE, 50_000, 512_000, 512_000, smoothing=0.05)
    assert smooth.samples > sharp.samples
    assert smooth.end == sharp.end == (0, 0)
    assert distance_from_ideal(smooth).max() <= 1.0


def test_mixed_segment_kinds_and_empty_paths_are_refused() -> None:
    with pytest.raises(LimitError) as err:
        vector([Line(100, 0), LinearInterp((1, 2))], 1000, 10240, 10240)
    assert err.value.name == "TC 33"
    assert "segment 1" in str(err.value)
    with pytest.raises(InvalidArgument):
        vector([], 1000, 10240, 10240)
    with pytest.raises(InvalidArgument):
        vector([Line(100, 0)], 0, 10240, 10240)


def test_the_engine_refuses_what_the_controller_would() -> None:
    eng = VectorProfiler(buffer=2)
    with pytest.raises(CommandError) as err:
        eng.begin(1000, 10240, 10240)
    assert err.value.code == 24
    eng.add(Line(100, 0))
    with pytest.raises(CommandError) as err:
        eng.add(LinearInterp((1, 2)))
    assert err.value.code == 33
    eng.add(Arc(100, 270, 90))
    with pytest.raises(CommandError) as err:
        eng.add(Line(0, 100))
    assert err.value.code == 32
    assert eng.free_slots == 0
    eng.begin(10_000, 102_400, 102_400)
    with pytest.raises(CommandError) as err:
        eng.begin(10_000, 102_400, 102_400)
    assert err.value.code == 21
    eng.end()
    with pytest.raises(InvalidArgument):
        eng.add(Line(1, 0))


def test_segments_streamed_during_motion_extend_the_path_and_free_slots() -> None:
    eng = VectorProfiler(buffer=3, position=(10, 20))
    eng.extend(ROUNDED_SQUARE[:3])
    eng.begin(50_000, 512_000, 512_000)
    assert eng.moving
    assert eng.stop_code == 100
    assert eng.end_sample is None  # no VE yet: the end is not known
    sent = 3
    while eng.moving and eng.sample < 10_000:
        eng.advance(16)
        while sent < len(ROUNDED_SQUARE) and eng.free_slots > 0:
            eng.add(ROUNDED_SQUARE[sent])
            sent += 1
        if sent == len(ROUNDED_SQUARE) and not eng.ended:
            eng.end()
    assert not eng.moving
    assert eng.stop_code == 101
    assert eng.position == (10, 20)
    assert eng.segments_completed == 8
    assert eng.distance == eng.length


def test_without_ve_the_sequence_waits_at_the_end_of_its_segments() -> None:
    eng = VectorProfiler()
    eng.add(Line(1000, 0))
    eng.begin(20_000, 256_000, 256_000)
    eng.advance(2000)
    assert eng.moving  # still a running sequence, at rest
    assert eng.position == (1000, 0)
    assert eng.velocity == 0
    eng.add(Line(0, 500))  # resumes from rest
    eng.advance(10)
    assert eng.position[1] > 0
    eng.end()
    eng.advance(2000)
    assert not eng.moving
    assert eng.position == (1000, 500)
    # a segment after the end starts a new sequence from there
    eng.add(Line(-1000, 0))
    eng.begin(20_000, 256_000, 256_000)
    assert eng.length == 1000
    eng.end()
    eng.advance(2000)
    assert eng.position == (0, 500)


def test_stop_decelerates_along_the_path_at_vd() -> None:
    eng = VectorProfiler()
    eng.extend(ROUNDED_SQUARE)
    eng.end()
    eng.begin(50_000, 512_000, 256_000)
    first = eng.advance(600)
    v_before = eng.velocity
    eng.stop()
    assert eng.stop_code == 4
    end = eng.end_sample
    assert end is not None
    ramp = eng.advance(end - eng.sample)
    assert not eng.moving
    assert eng.stop_code == 4
    assert eng.distance < eng.length
    assert (end - 600) * TS == pytest.approx(v_before / 256_000, abs=2 * TS)
    with pytest.raises(InvalidArgument):
        eng.set_position((0,))  # one value for two axes
    whole = np.concatenate([first, ramp], axis=1)
    assert np.abs(np.diff(whole, axis=1)).max() <= math.ceil(50_000 * TS) + 1


def test_abort_stops_at_once() -> None:
    eng = VectorProfiler()
    eng.extend(ROUNDED_SQUARE)
    eng.begin(50_000, 512_000, 512_000)
    eng.advance(300)
    here = eng.position
    eng.abort()
    assert not eng.moving
    assert eng.stop_code == 7
    assert eng.advance(5)[:, -1].tolist() == list(here)


segments = st.one_of(
    st.builds(Line, st.integers(-4000, 4000), st.integers(-4000, 4000)),
    st.builds(
        Arc,
        st.integers(10, 3000),
        st.sampled_from([0, 90, 180, 270, 30, 45.5, -60]),
        st.sampled_from([90, -90, 180, 360, -360, 45, 12.5, -200]),
    ),
)


@SETTINGS
@given(
    segs=st.lists(segments, min_size=1, max_size=5),
    speed=st.integers(20_000, 200_000),
    accel=st.integers(50, 2000).map(lambda k: k * 1024),
    smoothing=st.sampled_from([1.0, 0.5, 0.125]),
    chunks=st.lists(st.integers(1, 400), min_size=1, max_size=6),
)
def test_stepping_gives_the_one_shot_prediction_however_it_is_chunked(
    segs: list[Line | Arc], speed: int, accel: int, smoothing: float, chunks: list[int]
) -> None:
    p = vector(segs, speed, accel, accel, smoothing=smoothing, start=(5, -5))
    eng = VectorProfiler(position=(5, -5))
    eng.extend(segs)
    eng.end()
    eng.begin(speed, accel, accel, smoothing)
    parts = [np.array([[5], [-5]])]
    i = 0
    while eng.sample < p.samples:
        n = min(chunks[i % len(chunks)], p.samples - eng.sample)
        parts.append(eng.advance(n))
        i += 1
    assert not eng.moving
    assert np.array_equal(np.concatenate(parts, axis=1), p.position)


@SETTINGS
@given(
    segs=st.lists(segments, min_size=2, max_size=5),
    split=st.integers(1, 4),
    at=st.integers(0, 300),
    chunks=st.lists(st.integers(1, 300), min_size=2, max_size=5),
)
def test_a_streamed_sequence_is_chunking_independent_and_ends_on_its_end_point(
    segs: list[Line | Arc], split: int, at: int, chunks: list[int]
) -> None:
    split = min(split, len(segs) - 1)

    def run(sizes: list[int]) -> np.ndarray:
        eng = VectorProfiler()
        eng.extend(segs[:split])
        eng.begin(80_000, 1_024_000, 1_024_000)
        out = [np.zeros((2, 1), dtype=np.int64), eng.advance(at)]
        eng.extend(segs[split:])
        eng.end()
        i = 0
        while eng.moving:
            assert eng.sample < 200_000
            out.append(eng.advance(sizes[i % len(sizes)]))
            i += 1
        return np.concatenate(out, axis=1)

    a, b = run(chunks), run([1000])
    n = min(a.shape[1], b.shape[1])
    assert np.array_equal(a[:, :n], b[:, :n])
    assert (a[:, n:] == a[:, -1:]).all()
    assert (b[:, n:] == b[:, -1:]).all()
    whole = vector(segs, 80_000, 1_024_000, 1_024_000)
    assert tuple(a[:, -1]) == whole.end


@SETTINGS
@given(segs=st.lists(segments, min_size=1, max_size=6))
def test_path_length_is_conserved_from_segments_to_samples(segs: list[Line | Arc]) -> None:
    p = vector(segs, 150_000, 2_048_000, 2_048_000)
    lay = p.layout
    assert int(lay.counts.sum()) == p.length == lay.bounds[-1]
    assert abs(p.length - math.fsum(lay.lengths.tolist())) <= 0.5
    assert p.path[0] == 0
    assert p.path[-1] == p.length
    assert (np.diff(p.path) >= 0).all()
    assert p.end == tuple(int(v) for v in np.floor(lay.end[-1] + 0.5))
    assert distance_from_ideal(p).max() <= 1.0


@pytest.mark.parametrize(
    ("args", "kwargs", "message"),
    [
        ((-1,), {}, "a path has 1 to 8 axes, got -1"),  # was "position has 0 values for -1 axes"
        ((9,), {}, "a path has 1 to 8 axes"),
        ((2,), {"sample_period": math.nan}, "sample period must be positive"),
        ((2,), {"buffer": 0}, "segment buffer must hold at least 1"),
        ((2,), {"position": (1, 2, 3)}, "position has 3 values for 2 axes"),
    ],
)
def test_a_vector_profiler_refuses_a_bad_plane_with_a_message_naming_it(
    args: tuple[int], kwargs: dict[str, object], message: str
) -> None:
    with pytest.raises(InvalidArgument, match=message):
        VectorProfiler(*args, **kwargs)  # type: ignore[arg-type]


def test_a_running_vector_sequence_refuses_what_the_controller_would() -> None:
    eng = VectorProfiler(2)
    assert (eng.segment, eng.kind) == (0, None)
    eng.add(Line(1000, 0))
    with pytest.raises(InvalidArgument, match="vector speed must be > 0"):
        eng.begin(0, 100_000, 100_000)
    assert not eng.moving
    eng.begin(10_000, 100_000, 100_000)
    assert eng.kind == "vector"
    with pytest.raises(InvalidArgument, match="origin of a running sequence"):
        eng.set_position((0, 0))
    with pytest.raises(InvalidArgument, match="clear the sequence while it runs"):
        eng.clear()
    with pytest.raises(InvalidArgument, match="sample count must be >= 0"):
        eng.advance(-1)
    eng.advance(50)
    eng.stop()
    with pytest.raises(InvalidArgument, match="stopping"):
        eng.add(Line(10, 0))
    assert eng.moving  # the stop runs on, undisturbed
    eng.advance(2000)
    assert (eng.moving, eng.stop_code) == (False, 4)
    eng.clear()
    assert eng.segments == 0


def test_a_vector_profile_refuses_an_axis_it_does_not_have() -> None:
    prof = vector([Line(1000, 0)], 10_000, 100_000, 100_000)
    for i in (-1, 2):
        with pytest.raises(InvalidArgument, match=r"outside 0\.\.1"):
            prof.axis(i)
    assert prof.samples_of(5) == (-1, -1)
    assert prof.samples_of(0) == (0, prof.samples)
    with pytest.raises(InvalidArgument, match="sample_period must be positive"):
        vector([Line(10, 0)], 1000, 1000, 1000, sample_period=0)
