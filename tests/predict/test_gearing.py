"""Electronic gearing: ratio quantisation and the follower's reference, sample by sample."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil import predict
from galil.errors import InvalidArgument, LimitError
from galil.predict import GearFollower, Line, gear, gear_profile, quantise_ratio, vector


def test_ratios_are_truncated_to_one_65536th_within_127() -> None:
    assert quantise_ratio(0.25) == 0.25
    assert quantise_ratio(1.35) == 88473 / 65536  # 1.35 * 65536 = 88473.6, truncated
    assert quantise_ratio(-1.35) == -88473 / 65536
    assert quantise_ratio(127) == 127
    for bad in (127.5, -200, float("nan")):
        with pytest.raises(LimitError) as err:
            quantise_ratio(bad)
        assert err.value.name == "GR"


def test_a_follower_is_the_ratio_times_the_master_motion_at_every_sample() -> None:
    master = predict.move(12_345, 20_000, 256_000, 256_000, start=1000)
    for ratio in (0.25, -5.0, 1.0):
        follower = gear(master.position, ratio, start=-7)
        assert np.array_equal(follower, np.floor(-7 + ratio * (master.position - 1000) + 0.5))
    odd = gear(master.position, 1 / 3)
    q = quantise_ratio(1 / 3)
    assert np.array_equal(odd, np.floor(q * (master.position - 1000) + 0.5))


def test_a_follower_profile_carries_the_master_time_base() -> None:
    master = predict.move(8000, 20_000, 256_000, 256_000)
    follower = gear_profile(master, -0.5, start=100)
    assert follower.samples == master.samples
    assert follower.end == 100 - 4000
    assert follower.peak_speed == pytest.approx(10_000)


def test_a_follower_can_gear_to_the_vector_distance_of_a_sequence() -> None:
    seq = vector([Line(3000, 4000), Line(-3000, 4000)], 20_000, 256_000, 256_000)
    follower = gear(seq.path, 2.0)  # GA S: the vector move is the master
    assert follower[-1] == 20_000
    assert np.array_equal(follower, 2 * seq.path)


def test_a_ratio_change_carries_on_from_the_exact_follower_position() -> None:
    f = GearFollower(0.5, master=0, position=0)
    assert f.follow([0, 1, 2, 3]).tolist() == [0, 1, 1, 2]  # 1.5 rounds up to 2
    f.set_ratio(2.0)
    assert f.follow([4, 5]).tolist() == [4, 6]  # from 1.5 exactly, not from 2
    assert f.position == 6
    assert f.ratio == 2.0


def test_bad_master_positions_are_refused() -> None:
    with pytest.raises(InvalidArgument):
        gear([[1, 2]], 1.0)
    with pytest.raises(InvalidArgument):
        gear([0.5, 1.0], 1.0)
    with pytest.raises(InvalidArgument):
        GearFollower(1 / 3, master=0, position=0)  # not a multiple of the resolution
    assert gear([], 1.0).size == 0


@settings(max_examples=50, deadline=None)
@given(
    master=st.lists(st.integers(-(2**31), 2**31 - 1), min_size=1, max_size=200),
    steps=st.integers(-127 * 65536, 127 * 65536),
    chunks=st.lists(st.integers(1, 50), min_size=1, max_size=5),
)
def test_a_follower_gives_the_same_positions_however_it_is_fed(
    master: list[int], steps: int, chunks: list[int]
) -> None:
    ratio = steps / 65536
    whole = gear(master, ratio, start=3)
    f = GearFollower(ratio, master=master[0], position=3)
    parts, i, done = [], 0, 0
    while done < len(master):
        n = chunks[i % len(chunks)]
        parts.append(f.follow(master[done : done + n]))
        done += n
        i += 1
    assert np.array_equal(np.concatenate(parts), whole)
    exact = [3 * 65536 + steps * (m - master[0]) for m in master]
    assert whole.tolist() == [(x + 32768) // 65536 for x in exact]
