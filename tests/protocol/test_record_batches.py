"""Records decoded a stream at a time are exactly the records decoded one at a time."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument, ProtocolError
from galil.models import get_model
from galil.protocol.records import (
    SAMPLE_WRAP,
    RecordSplitter,
    decode_record,
    decode_records,
    extend_sample,
    follow_samples,
    record_dtype,
    with_time,
    with_times,
)

SPEC = get_model("DMC-4040")


def stream_of(samples: list[int], positions: list[int], letters: str = "ABCD") -> bytes:
    """Records as a controller streams them: header, general block, axis blocks."""
    dtype = record_dtype(SPEC, axes=len(letters), letters=letters)
    out = np.zeros(len(samples), dtype=dtype)
    out["header"] = 0x87
    out["axes_present"] = sum(1 << "ABCDEFGH".index(c) for c in letters)
    out["size"] = dtype.itemsize
    out["sample"] = samples
    out[letters[0]]["position"] = positions
    return out.tobytes()


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 65535), st.integers(-(2**31), 2**31 - 1)), max_size=40))
def test_a_stream_decodes_to_the_records_one_at_a_time(rows: list[tuple[int, int]]) -> None:
    data = stream_of([s for s, _ in rows], [p for _, p in rows])
    batch = decode_records(data, SPEC)
    size = batch.dtype.itemsize if rows else 0
    assert len(batch) == len(rows)
    for i in range(len(rows)):
        one = decode_record(data[i * size : (i + 1) * size], SPEC)
        assert batch[i].tobytes() == one.tobytes()
        assert batch[i].dtype == one.dtype


def test_a_stream_of_some_axis_blocks_names_them_from_its_header() -> None:
    batch = decode_records(stream_of([1, 2], [10, 20], letters="BD"), SPEC)
    assert batch.dtype.names is not None
    assert "B" in batch.dtype.names
    assert "A" not in batch.dtype.names
    assert batch["B"]["position"].tolist() == [10, 20]


@pytest.mark.parametrize(
    ("damage", "why"),
    [
        (lambda d: d[:-1], "not whole records"),
        (lambda d: d[:226] + b"\x07" + d[227:], "not the stream's"),
        (lambda d: b"\x07" + d[1:], "missing header"),
        (lambda d: d[:227] + b"\x03" + d[228:], "not the stream's"),
    ],
)
def test_a_damaged_stream_is_refused(damage: object, why: str) -> None:
    data = stream_of([1, 2, 3], [0, 0, 0])
    with pytest.raises(ProtocolError, match=why):
        decode_records(damage(data), SPEC)  # type: ignore[operator]


@settings(max_examples=300, deadline=None)
@given(
    first=st.integers(0, 10_000_000),
    period=st.integers(1, 40_000),
    steps=st.lists(st.integers(-40_000, 40_000), max_size=30),
    offset=st.integers(-40_000, 40_000),
)
def test_following_samples_at_once_is_extending_them_one_by_one(
    first: int, period: int, steps: list[int], offset: int
) -> None:
    times = [first]
    for s in steps:
        times.append(times[-1] + period + s)
    low = [t % SAMPLE_WRAP for t in times]
    near = first + offset
    expected = []
    guess = near
    for v in low:
        t = extend_sample(v, guess)
        expected.append(t)
        guess = t + period
    assert follow_samples(low, near, period).tolist() == expected


def test_times_join_records_as_with_time_joins_one() -> None:
    batch = decode_records(stream_of([5, 7, 9], [1, 2, 3]), SPEC)
    timed = with_times(batch, [70005, 70007, 70009])
    for i in range(3):
        assert timed[i].tobytes() == with_time(batch[i], 70005 + 2 * i).tobytes()
    with pytest.raises(InvalidArgument):
        with_times(timed, [1, 2, 3])
    with pytest.raises(InvalidArgument):
        with_times(batch, [1, 2])


@pytest.mark.parametrize(("period", "second"), [(4, 4 + 32768), (40_000, 40_000 - 32768)])
def test_half_a_wrap_away_is_settled_as_extend_sample_settles_it(period: int, second: int) -> None:
    low = [0, second % SAMPLE_WRAP]
    expected = [extend_sample(0, 0)]
    expected.append(extend_sample(low[1], expected[0] + period))
    assert follow_samples(low, 0, period).tolist() == expected


@settings(max_examples=100, deadline=None)
@given(n=st.integers(0, 12), cuts=st.lists(st.integers(1, 700), max_size=12))
def test_a_block_is_the_records_cut_one_by_one_joined(n: int, cuts: list[int]) -> None:
    data = stream_of(list(range(n)), list(range(n)))
    one, block = RecordSplitter(SPEC.qz), RecordSplitter(SPEC.qz)
    pieces, whole = [], []
    at = 0
    for cut in [*cuts, len(data)]:
        piece = data[at : at + cut]
        at += cut
        pieces += one.feed(piece)
        whole.append(block.feed_block(piece))
    assert b"".join(whole) == b"".join(pieces) == data
