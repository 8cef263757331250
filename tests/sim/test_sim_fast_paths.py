"""The servo loop's short-step path (a host polling) matches its long-step path."""

from __future__ import annotations

import engine_expect
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.predict.engine import AxisProfiler
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.motion import AxisMotion

TS = 1 / 1024


def started(line: bytes, lag: float) -> SimController:
    sim = SimController("DMC-4040", ManualClock(), servo_lag=lag)
    assert b"?" not in sim.feed(line)
    return sim


def read(sim: SimController, query: bytes) -> list[int]:
    return [int(v) for v in sim.feed(query)[:-3].split(b",")]


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.integers(1, 60), min_size=1, max_size=5),
    st.sampled_from([0.0, 0.003, 0.02]),
    st.booleans(),
)
def test_polled_in_short_steps_equals_one_long_step(
    steps: list[int], lag: float, jog: bool
) -> None:
    line = (
        b"JG 10000,-20000,30000,-40000;AC 102400,,,;BG\r"
        if jog
        else b"PR 3000,-2500,7000,-100;SP 20000,9000,70000,4000;BG\r"
    )
    short, long = started(line, lag), started(line, lag)
    total = 0
    i = 0
    while total < 900:
        n = steps[i % len(steps)]
        short.advance(n * TS)
        short.feed(b"TP\r")  # a host polling between steps
        total += n
        i += 1
    long.advance(total * TS)
    assert short.sample == long.sample == total
    # The reference is bit-identical however the loop is chunked.
    assert read(short, b"RP\r") == read(long, b"RP\r")
    assert short.feed(b"MG _BGA,_BGB,_BGC,_BGD\r") == long.feed(b"MG _BGA,_BGB,_BGC,_BGD\r")
    # The motor's lag is evaluated two ways (recursion, paged closed form): within a count.
    for a, b in zip(read(short, b"TP\r"), read(long, b"TP\r"), strict=True):
        assert abs(a - b) <= 1
    for a, b in zip(read(short, b"TV\r"), read(long, b"TV\r"), strict=True):
        assert abs(a - b) <= 8


def test_a_trippoint_firing_on_the_last_sample_of_a_step_releases_there() -> None:
    # The servo loop runs a jog in steps of 2048 samples; AD is set to the distance reached
    # on the first step's last sample. The bisection inside the step must leave the axes on
    # that sample, not one short (the reply then came a sample late).
    prof = AxisProfiler(sample_period=TS)
    prof.begin_jog(10000, 1024000, 1024000)
    r = prof.advance(2048)
    assert r[-2] < r[-1]
    # (AD is program-only: a thread waits on it, and prints the sample it went on at.)
    sim = SimController("DMC-4040", ManualClock(), servo_lag=0.0)
    program = f"DL\r#T\rJG 10000;AC 1024000;DC 1024000;BG A\rAD {r[-1]}\rMG TIME,_RPA\rEN\r\\"
    assert sim.feed(program.encode()) == b"::"
    assert sim.feed(b"XQ #T\r") == b":"
    assert sim.advance_until_output(3.0) == f" 2048.0000 {r[-1]:.4f}\r\n".encode()
    assert sim.sample == 2048


@settings(max_examples=30, deadline=None)
@given(
    st.integers(49, 3000),
    st.sampled_from([0.0, 0.003, 0.02]),
    st.integers(-50_000, 50_000),
)
def test_an_axis_at_rest_stays_exactly_where_it_is_in_long_steps(
    rest: int, lag: float, distance: int
) -> None:
    sim = started(f"PR {distance},,,;BG\r".encode(), lag)
    sim.advance(4.0)  # well after the move: the motor has settled on the target
    before = read(sim, b"TP\r"), read(sim, b"TV\r")
    sim.advance(rest * TS)  # one long step of an axis at rest
    assert (read(sim, b"TP\r"), read(sim, b"TV\r")) == before
    assert read(sim, b"TP\r")[0] == distance


@settings(max_examples=40, deadline=None)
@given(
    st.integers(49, 4000),
    st.sampled_from([0.001, 0.003, 0.02, 0.5, 5.0]),
    st.integers(-50_000, 50_000),
)
def test_a_long_step_gives_the_encoder_and_tv_of_the_lag_sample_by_sample(
    n: int, lag: float, distance: int
) -> None:
    # One long step of a moving axis: the closed form of the lag (a dot product over the
    # samples whose weight still counts, or the paged filter for a lag slower than that)
    # against the recursion run sample by sample; a slow lag (5 s) keeps every sample.
    sim = started(f"PR {distance},,,;SP 100000,,,;BG\r".encode(), lag)
    sim.advance(n * TS)
    prof = engine_expect.move(distance, sp=100000)
    refs = [int(r) for r in prof.advance(n)]
    encoders = engine_expect.lagged(refs, lag)
    assert read(sim, b"RP\r")[0] == refs[-1]
    assert abs(read(sim, b"TP\r")[0] - encoders[-1]) <= 1
    assert abs(read(sim, b"TV\r")[0] - engine_expect.tv(encoders)) <= 1


@pytest.mark.parametrize("lag", [0.003, 5.0])
def test_a_chunk_longer_than_the_lag_tail_follows_the_recursion(lag: float) -> None:
    # 5,000 samples in one call: a fast lag drops the weights lost in rounding, a slow one
    # (whose weights outlast the tail) goes through the paged filter.
    m = AxisMotion(TS, 0, lag)
    m.profiler.begin_move(300_000, 100000, 256000, 256000)
    refs = [int(r) for r in m.advance(5000)]
    assert m.encoder == engine_expect.lagged(refs, lag)[-1]
