"""Path segments and their layout: validation, whole-count lengths, exact end points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from galil.errors import InvalidArgument
from galil.predict import Arc, Line, LinearInterp
from galil.predict.path import PathLayout, path_kind, quantise_angle


def layout(*segments: Line | Arc | LinearInterp, axes: int = 2) -> PathLayout:
    lay = PathLayout(axes)
    for seg in segments:
        lay.append(seg)
    return lay


def test_segments_accept_whole_numbers_of_any_integer_type() -> None:
    assert Line(np.int32(3), 4.0) == Line(3, 4)
    assert Line(3, 4).length == 5.0
    assert LinearInterp([np.int64(1), 2, 2]).increments == (1, 2, 2)
    assert LinearInterp((1, 2, 2)).length == 3.0
    assert Arc(1000, 0, 90).length == pytest.approx(1000 * math.pi / 2)


@pytest.mark.parametrize(
    "make",
    [
        lambda: Line(1.5, 0),
        lambda: Line(True, 0),
        lambda: Line("1", 0),
        lambda: Arc(0, 0, 90),
        lambda: Arc(-5, 0, 90),
        lambda: Arc(100, 0, 0),
        lambda: Arc(100, math.nan, 90),
        lambda: Arc(100, 0, math.inf),
        lambda: LinearInterp(()),
        lambda: LinearInterp(tuple(range(9))),
        lambda: LinearInterp("12"),
        lambda: LinearInterp((1, 2.5)),
    ],
)
def test_malformed_segments_are_refused(make: object) -> None:
    with pytest.raises(InvalidArgument):
        make()  # type: ignore[operator]


def test_kinds_cannot_mix_and_vector_mode_needs_two_axes() -> None:
    assert path_kind(Line(1, 0)) == path_kind(Arc(10, 0, 90)) == "vector"
    assert path_kind(LinearInterp((1,))) == "linear"
    with pytest.raises(InvalidArgument):
        path_kind("VP 1,2")  # type: ignore[arg-type]
    lay = layout(Line(100, 0))
    with pytest.raises(InvalidArgument):
        lay.append(LinearInterp((1, 2)))
    with pytest.raises(InvalidArgument):
        PathLayout(3).append(Line(1, 2))
    with pytest.raises(InvalidArgument):
        PathLayout(3).append(LinearInterp((1, 2)))
    with pytest.raises(InvalidArgument):
        PathLayout(9)


def test_quarter_arcs_land_exactly_on_their_integer_end_points() -> None:
    lay = layout(Line(8000, 0), Arc(1000, 270, 90), Line(0, 8000), Arc(1000, 0, 90))
    path = lay.snapshot()
    assert path.end.tolist() == [[8000, 0], [9000, 1000], [9000, 9000], [8000, 10000]]
    assert path.centre[1].tolist() == [8000, 1000]
    assert path.project([path.length])[:, 0].tolist() == [8000, 10000]


def test_a_whole_turn_ends_exactly_where_it_started() -> None:
    for start in (0.0, 45.0, 123.456, -90.0):
        path = layout(Line(17, -3), Arc(5000, start, -720)).snapshot()
        assert path.end[1].tolist() == [17.0, -3.0]
        assert path.project([path.length])[:, 0].tolist() == [17, -3]


def test_segment_counts_are_the_rounded_running_length() -> None:
    segs = [Line(1, 1), Line(2, 1), Arc(100, 10, 33.3), Line(3, 0)]
    path = layout(*segs).snapshot()
    cum = np.cumsum(path.lengths)
    assert path.bounds[1:].tolist() == [math.floor(c + 0.5) for c in cum]
    assert int(path.counts.sum()) == path.length
    assert abs(path.length - path.ideal_length) <= 0.5


def test_a_line_after_a_fractional_arc_ends_on_whole_counts() -> None:
    # An arc from 45 degrees ends off the count grid; the next VP is absolute in whole counts.
    path = layout(Arc(1000, 45, 45), Line(100, 0)).snapshot()
    assert not float(path.end[0][0]).is_integer()
    assert path.start[1].tolist() == path.end[0].tolist()
    assert path.end[1].tolist() == [float(np.floor(path.end[0][0] + 0.5)) + 100, 293.0]


def test_arc_angles_round_to_the_controller_step() -> None:
    assert quantise_angle(10.001) == pytest.approx(10.0)
    assert quantise_angle(1 / 512) == 1 / 256  # halves round up
    with pytest.raises(InvalidArgument):
        PathLayout(2).append(Arc(100, 0, 0.001))  # rounds to no sweep at all


def test_projection_puts_every_count_of_path_on_its_segment() -> None:
    path = layout(Line(300, 400), Line(0, 0), Line(-300, 0)).snapshot()
    s = np.arange(path.length + 1)
    seg = path.segment_of(s)
    # the zero-length segment is never the one a sample is in
    assert set(seg.tolist()) == {0, 2}
    assert seg[500] == 0
    assert seg[501] == 2
    xy = path.project(s)
    assert xy[:, 500].tolist() == [300, 400]
    assert np.array_equal(xy[0, :501], np.floor(s[:501] * 0.6 + 0.5))
    assert np.array_equal(xy[1, :501], np.floor(s[:501] * 0.8 + 0.5))
