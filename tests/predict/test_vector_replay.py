"""Re-predicting a sequence from what was sent when, and previewing it without committing."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from galil import predict
from galil.errors import InvalidArgument
from galil.predict import Arc, Line, VectorProfiler
from galil.predict.vector import SequenceEvent, replay

SQUARE = [Line(8000, 0), Arc(1000, 270, 90), Line(0, 8000), Arc(1000, 0, 90)]
VS, VA, VD = 30_000, 256_000, 512_000


def test_a_replay_without_events_is_the_one_shot_prediction() -> None:
    one = predict.vector(SQUARE, VS, VA, VD, start=(5, -7))
    again = replay(SQUARE, VS, VA, VD, start=(5, -7))
    np.testing.assert_array_equal(again.position, one.position)
    np.testing.assert_array_equal(again.path, one.path)
    assert again.shape == one.shape
    assert again.stop_code == 101


def test_segments_in_time_give_the_same_path_as_all_at_once() -> None:
    deadlines = predict.segment_deadlines(predict.vector(SQUARE, VS, VA, VD))
    events = [SequenceEvent(int(deadlines[i]), "add", (SQUARE[i],)) for i in range(2, 4)]
    streamed = replay(SQUARE[:2], VS, VA, VD, ended=False, events=events)
    one = predict.vector(SQUARE, VS, VA, VD)
    assert streamed.end == one.end
    assert abs(streamed.samples - one.samples) <= 2
    assert np.max(np.abs(streamed.position[:, : one.samples] - one.position[:, :-1])) <= 1


def test_a_late_segment_makes_the_sequence_wait_at_rest() -> None:
    late = replay(
        [Line(1000, 0)],
        VS,
        VA,
        VD,
        ended=False,
        events=[SequenceEvent(2000, "add", (Line(0, 1000),))],
    )
    assert late.end == (1000, 1000)
    rest = np.flatnonzero(late.speed == 0)
    assert rest.size > 1000  # it stood still until the segment came
    assert late.shape == "changed"


def test_stop_and_abort_events_end_the_sequence() -> None:
    stopped = replay(SQUARE, VS, VA, VD, events=[SequenceEvent(300, "stop")])
    aborted = replay(SQUARE, VS, VA, VD, events=[SequenceEvent(300, "abort")])
    assert (stopped.stop_code, aborted.stop_code) == (4, 7)
    assert aborted.samples == 300
    assert stopped.samples > 300
    np.testing.assert_array_equal(stopped.position[:, :301], aborted.position)
    with pytest.raises(InvalidArgument, match="event kind"):
        SequenceEvent(1, "pause")


def test_a_preview_commits_nothing_and_a_copy_is_independent() -> None:
    eng = VectorProfiler(2, position=(100, 200))
    eng.extend(SQUARE[:2])
    eng.begin(VS, VA, VD)
    eng.advance(50)
    ahead = eng.preview(500)
    snapshot = copy.deepcopy(eng)
    np.testing.assert_array_equal(eng.advance(500), ahead)
    eng.add(SQUARE[2])  # the copy keeps its own path
    assert snapshot.segments == 2
    assert eng.segments == 3
    np.testing.assert_array_equal(snapshot.advance(500), ahead)
