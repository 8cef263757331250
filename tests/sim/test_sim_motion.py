"""The simulator's servo loop runs the predictor's engine: same calls, same samples, same RP."""

from __future__ import annotations

import numpy as np
from engine_expect import TS, in_position_after, lagged, move, references, soft_limit_stop, tv
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.predict.engine import AxisProfiler
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController


def new_sim(lag: float = 0.003) -> SimController:
    return SimController("DMC-4040", ManualClock(), servo_lag=lag)


def ok(sim: SimController, line: str) -> None:
    reply = sim.feed(line.encode() + b"\r")
    assert b"?" not in reply, (line, reply, sim.feed(b"TC1\r"))


def sample_rp(sim: SimController, n: int, axis: str = "A") -> np.ndarray:
    """RP after each of the next n samples, one sample at a time."""
    out = []
    for _ in range(n):
        sim.advance(sim.sample_period)
        out.append(sim.motion(axis).reference)
    return np.array(out, dtype=np.int64)


def test_move_sample_by_sample_matches_engine() -> None:
    sim = new_sim()
    ok(sim, "PR 3000;SP 20000;AC 204800;DC 102400;BG A")
    rp = sample_rp(sim, 400)
    prof = AxisProfiler(sample_period=TS)
    prof.begin_move(3000, 20000, 204800, 102400)
    np.testing.assert_array_equal(rp, prof.advance(400))
    assert not sim.motion("A").moving


def test_bg_reads_one_until_the_engines_last_sample() -> None:
    sim = new_sim()
    ok(sim, "PR 3000;SP 20000;AC 204800;DC 102400;BG A")
    end = len(references(move(3000, 20000, 204800, 102400)))
    done = 0
    while sim.feed(b"MG _BGA\r") == b" 1.0000\r\n:":
        sim.advance(TS)
        done += 1
    assert done == end


@settings(max_examples=60, deadline=None)
@given(
    d=st.integers(-300_000, 300_000),
    sp=st.integers(1000, 250_000).map(lambda v: 2 * v),
    ac=st.integers(1, 2000).map(lambda v: 1024 * v),
    dc=st.integers(1, 2000).map(lambda v: 1024 * v),
    chunks=st.lists(st.floats(0.001, 0.7), min_size=1, max_size=8),
)
def test_chunked_moves_match_the_engine(
    d: int, sp: int, ac: int, dc: int, chunks: list[float]
) -> None:
    sim = new_sim()
    ok(sim, f"PR {d};SP {sp};AC {ac};DC {dc};BG A")
    prof = AxisProfiler(sample_period=TS)
    prof.begin_move(d, sp, ac, dc)
    for c in chunks:
        before = sim.sample
        sim.advance(c)
        ref = prof.advance(sim.sample - before)
        if ref.size:
            assert sim.motion("A").reference == ref[-1]
        assert sim.motion("A").moving == prof.moving
    end = prof.end_sample
    assert end is not None
    sim.advance((max(0, end - sim.sample) + 2) * TS)  # past the end
    assert sim.feed(b"MG _BGA;RPA\r") == f" 0.0000\r\n: {d}\r\n:".encode().replace(b" -", b"-")


def test_jog_speed_change_in_motion_matches_engine() -> None:
    sim = new_sim()
    ok(sim, "JG 5000;AC 51200;DC 51200;BG A")
    a = sample_rp(sim, 300)
    ok(sim, "JG -8000")
    b = sample_rp(sim, 500)
    prof = AxisProfiler(sample_period=TS)
    prof.begin_jog(5000, 51200, 51200)
    first = prof.advance(300)
    prof.set_speed(-8000)
    np.testing.assert_array_equal(a, first)
    np.testing.assert_array_equal(b, prof.advance(500))


def test_ip_sp_ac_changes_and_st_match_engine() -> None:
    sim = new_sim()
    ok(sim, "PR 50000;SP 10000;AC 102400;DC 102400;BG A")
    prof = AxisProfiler(sample_period=TS)
    prof.begin_move(50000, 10000, 102400, 102400)
    steps = [
        ("IP 2000", lambda: prof.increment(2000, 10000, 102400, 102400)),
        ("SP 30000", lambda: prof.set_speed(30000)),
        ("AC 20480", lambda: prof.set_accel(20480)),
        ("ST A", prof.stop),
    ]
    for line, call in steps:
        got = sample_rp(sim, 150)
        np.testing.assert_array_equal(got, prof.advance(150))
        ok(sim, line)
        call()
    np.testing.assert_array_equal(sample_rp(sim, 800), prof.advance(800))
    assert sim.feed(b"SC A\r") == b" 4\r\n:"


def test_dc_in_a_jog_and_in_a_stop_ramp_matches_engine() -> None:
    sim = new_sim()
    ok(sim, "JG 30000;AC 204800;DC 204800;BG A")
    prof = AxisProfiler(sample_period=TS)
    prof.begin_jog(30000, 204800, 204800)
    steps = [
        (150, "DC 20480", lambda: prof.set_decel(20480)),
        (150, "JG 5000", lambda: prof.set_speed(5000)),
        (150, "DC 102400", lambda: prof.set_decel(102400)),  # mid-ramp (1.25 s at DC 20480)
        (150, "JG 20000", lambda: prof.set_speed(20000)),
        (150, "ST A", prof.stop),
        (30, "DC 10240", lambda: prof.set_decel(10240)),  # while ST ramps down (0.2 s at 102400)
    ]
    for n, line, call in steps:
        np.testing.assert_array_equal(sample_rp(sim, n), prof.advance(n))
        ok(sim, line)
        call()
    np.testing.assert_array_equal(sample_rp(sim, 1600), prof.advance(1600))
    assert sim.motion("A").moving  # (the new DC made the stop's ramp longer)
    np.testing.assert_array_equal(sample_rp(sim, 200), prof.advance(200))
    assert not prof.moving
    assert sim.feed(b"SC A;MG _DCA\r") == b" 4\r\n: 10240.0000\r\n:"


def test_dc_is_refused_in_a_position_move_and_in_homing_but_not_after_st() -> None:
    sim = new_sim()
    ok(sim, "PR 50000;SP 20000;BG A")
    assert sim.feed(b"DC 51200\r") == b"?"
    assert sim.feed(b"TC 1\r").startswith(b" 7 ")
    ok(sim, "ST A")
    ok(sim, "DC 51200")  # "directly following an axis stop ... still decelerating"
    sim.set_home_switch("B", edge=-30000)
    ok(sim, "HV ,2000;HM B;BG B")  # (its phases are jogs on the engine)
    assert sim.feed(b"DC ,51200\r") == b"?"
    assert sim.feed(b"MG _DCB\r") == b" 256000.0000\r\n:"


def test_it_smoothing_matches_engine() -> None:
    sim = new_sim()
    ok(sim, "IT 0.25;PR 4000;SP 40000;BG A")
    prof = AxisProfiler(sample_period=TS)
    prof.begin_move(4000, 40000, 256000, 256000, 0.25)
    np.testing.assert_array_equal(sample_rp(sim, 300), prof.advance(300))


def test_contour_matches_engine() -> None:
    sim = new_sim()
    ok(sim, "CM A;DT 2;CD 48;CD 240=3;CD 48=4")
    prof = AxisProfiler(sample_period=TS)
    prof.begin_contour()
    for inc, n in ((48, 2), (240, 3), (48, 4)):
        prof.add_segment(inc, n)
    got = sample_rp(sim, 30)
    np.testing.assert_array_equal(got, prof.advance(30))
    assert got[3] == 12 * 4
    assert got[11] == 288
    assert got[27] == 336


def test_multi_axis_all_match() -> None:
    sim = new_sim()
    ok(sim, "PR 1000,-2000,3000,-4000;SP 9000,8000,7000,6000;BG")
    sim.advance(0.4)
    for letter, (d, sp) in zip(
        "ABCD", ((1000, 9000), (-2000, 8000), (3000, 7000), (-4000, 6000)), strict=False
    ):
        prof = AxisProfiler(sample_period=TS)
        prof.begin_move(d, sp, 256000, 256000)
        assert sim.motion(letter).reference == prof.advance(sim.sample)[-1]


def test_tv_is_averaged_over_a_quarter_second() -> None:
    sim = new_sim(lag=0.0)
    ok(sim, "JG 10240;AC 1073740800;DC 1073740800;BG A")
    sim.advance(0.125)  # half a window at (nearly) full speed
    prof = AxisProfiler(sample_period=TS)
    prof.begin_jog(10240, 1073740800, 1073740800)
    half = [int(r) for r in prof.advance(128)]
    assert sim.feed(b"TVA\r") == f" {tv(half)}\r\n:".encode()
    sim.advance(0.5)
    assert sim.feed(b"TVA\r") == b" 10240\r\n:"


def test_servo_lag_is_first_order() -> None:
    sim = new_sim(lag=0.01)
    ok(sim, "PR 1000;SP 1000000;AC 1073740800;DC 1073740800;BG A")
    sim.advance(0.01)
    refs = [int(r) for r in move(1000, 1000000, 1073740800, 1073740800).advance(sim.sample)]
    m = sim.motion("A")
    assert not m.moving
    assert m.reference == 1000
    # after about one time constant the motor has covered ~63% of the step
    assert m.encoder == lagged(refs, 0.01)[-1]
    sim.advance(0.2)
    assert m.encoder == 1000
    assert m.in_position


def test_mc_releases_where_the_lagging_motor_reaches_the_target() -> None:
    sim = new_sim(lag=0.05)
    # AM and MC are program commands (decision 0044): a thread prints TE as each releases.
    assert sim.feed(b"DL\r#W\rAM A\rMG _TEA\rMC A\rMG _TEA\rEN\r\\\r") == b"::"
    ok(sim, "PR 2000;SP 20000;BG A;XQ #W")
    refs = references(move(2000, 20000))
    te = refs[-1] - lagged(refs, 0.05)[-1]
    assert sim.advance_until_output(5.0) == f" {te}.0000\r\n".encode()
    assert sim.sample == len(refs)
    assert sim.advance_until_output(5.0) == b" 0.0000\r\n"
    assert sim.sample == in_position_after(refs, 0.05)


@settings(max_examples=30, deadline=None)
@given(first=st.integers(1, 120), second=st.integers(1, 120))
def test_soft_limit_stops_on_the_first_sample_beyond_however_time_is_chunked(
    first: int, second: int
) -> None:
    # The servo loop cuts its steps where a host polls; the stop must not depend on where.
    sim = new_sim()
    ok(sim, "FL 500;PR 2000;BG A")
    sim.advance(first * TS)
    sim.advance(second * TS)
    sim.advance(2.0)
    assert sim.feed(b"RPA;SCA\r") == f" {soft_limit_stop(2000, 500)}\r\n: 2\r\n:".encode()


def test_dt_minus_one_holds_the_segments_until_a_positive_dt() -> None:
    sim = new_sim()
    ok(sim, "CM A;DT -1;CD 48;CD 240=3;CD 48")
    assert sim.feed(b"MG _CM\r").split()[0] == b"508.0000"  # three held in the buffer
    sim.advance(0.05)
    assert sim.motion("A").reference == 0  # nothing runs while held
    assert sim.feed(b"MG _TC\r").split()[0] == b"0.0000"  # and it is not running dry
    ok(sim, "DT 2")  # resume: the held segments run, those without their own DT at DT 2
    prof = AxisProfiler(sample_period=TS)
    prof.begin_contour()
    for inc, n in ((48, 2), (240, 3), (48, 2)):
        prof.add_segment(inc, n)
    np.testing.assert_array_equal(sample_rp(sim, 20), prof.advance(20))
    assert sim.motion("A").reference == 336


def test_the_end_of_a_held_stream_waits_behind_it_too() -> None:
    sim = new_sim()
    ok(sim, "CM A;DT -1;CD 100;CD 0=0")
    sim.advance(0.05)
    assert sim.motion("A").reference == 0
    ok(sim, "DT 3")
    sim.advance(0.05)
    assert sim.motion("A").reference == 100
    assert sim.feed(b"MG _BGA\r").split()[0] == b"0.0000"  # the stream ended after it
