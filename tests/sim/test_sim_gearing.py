"""Electronic gearing on the simulator: the follower is the predictor's GearFollower, fed the
master's positions sample by sample."""

from __future__ import annotations

import numpy as np
import pytest

from galil import predict
from galil.link import parse_numbers_reply
from galil.predict import GearFollower, Line
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

TS = 1 / 1024


def ask(sim: SimController, line: str) -> bytes:
    return sim.feed(line.encode() + b"\r")


def numbers(reply: bytes) -> list[float]:
    return parse_numbers_reply(reply.decode().split("\r\n")[0].lstrip(":"))


def stamp(reply: bytes) -> int:
    return round(float(reply.split(b"\r\n")[-2].lstrip(b":")))


@pytest.fixture
def sim() -> SimController:
    return SimController("DMC-4040", ManualClock())


@pytest.mark.parametrize(
    ("follower", "master", "chunk"), [("B", "A", 0.25), ("A", "C", 0.25), ("A", "C", TS)]
)
def test_a_follower_is_the_ratio_times_the_master_motion_at_every_sample(
    sim: SimController, follower: str, master: str, chunk: float
) -> None:
    ask(sim, f"PR{follower}=333;BG {follower}")
    sim.advance(0.5)
    ask(sim, f"GA{follower}=C{master};GR{follower}=-0.3")
    assert numbers(ask(sim, f"MG _BG{follower},_SC{follower}")) == [1, 0]
    sim.start_trace(follower + master)
    assert ask(sim, f"DL\r#W\rAM {master}\rEN\r\\") == b"::"
    # A thread waiting on AM (a program command, decision 0044) makes the loop bisect steps.
    ask(sim, f"SP{master}=40000;PR{master}=12345;BG {master};XQ #W")
    for _ in range(round(1 / chunk)):
        sim.advance(chunk)
    trace = sim.stop_trace(follower + master)
    ratio = predict.quantise_ratio(-0.3)
    expected = predict.gear(trace[master], ratio, start=333)
    np.testing.assert_array_equal(trace[follower], expected)
    assert trace[follower][-1] == 333 + round(ratio * 12345)


def test_a_new_ratio_carries_on_from_the_exact_follower_position(sim: SimController) -> None:
    ask(sim, "GA ,CA;GR ,0.1")
    t0 = sim.start_trace("AB")
    ask(sim, "JGA=30000;BG A")
    sim.advance(0.4)
    k = stamp(ask(sim, "GR ,-0.7;MG TIME"))
    sim.advance(0.4)
    trace = sim.stop_trace("AB")
    follower = GearFollower(predict.quantise_ratio(0.1), master=0, position=0)
    before = follower.follow(trace["A"][: k - t0 + 1])
    follower.set_ratio(predict.quantise_ratio(-0.7))
    after = follower.follow(trace["A"][k - t0 + 1 :])
    np.testing.assert_array_equal(trace["B"], np.concatenate([before, after]))


def test_stop_or_gr_0_disengages_where_the_follower_is(sim: SimController) -> None:
    ask(sim, "GA ,CA;GR ,2;JGA=20000;BG A")
    sim.advance(0.3)
    here = numbers(ask(sim, "ST B;MG _RPB,_BGB,_SCB"))
    assert here[1:] == [0, 4]
    sim.advance(0.3)
    assert numbers(ask(sim, "MG _RPB"))[0] == here[0]
    ask(sim, "GR ,2")  # engages again, from where both are now
    sim.advance(0.2)
    assert numbers(ask(sim, "GR ,0;MG _BGB,_SCB")) == [0, 1]
    rp = numbers(ask(sim, "MG _RPB"))[0]
    sim.advance(0.2)
    assert numbers(ask(sim, "MG _RPB"))[0] == rp
    assert ask(sim, "PRB=10;BG B;ST A") == b":::"


@pytest.mark.parametrize("release", ["ST C", "AB 1"])
def test_a_master_whose_follower_was_just_released_may_follow_at_once(
    sim: SimController, release: str
) -> None:
    # (in the same sample as the ST or AB, GR still counted C as A's follower: TC 46)
    ask(sim, "GA ,,CA;GR ,,2")
    assert ask(sim, f"{release};GA S;GR 1") == b":::"
    assert numbers(ask(sim, "GR ?")) == [1]


def test_gearing_refusals_have_their_codes(sim: SimController) -> None:
    for line, code in (
        ("GR ,1", 6),  # no master yet
        ("GA A", 46),  # A cannot follow itself
        ("GA ,Q", 4),
        ("GR ,200", 6),
    ):
        assert ask(sim, line).endswith(b"?"), line
        assert numbers(ask(sim, "MG _TC")) == [code], line
    ask(sim, "GA ,CA;GR ,1")
    assert ask(sim, "BG B").endswith(b"?")  # a geared follower's own moves: refused here
    assert numbers(ask(sim, "MG _TC")) == [21]
    assert ask(sim, "GA ,,CB;GR ,,1") == b":?"  # B is a follower: it cannot be a master too
    assert numbers(ask(sim, "MG _TC")) == [46]
    assert ask(sim, "GA CC;GR 1") == b":?"  # A is a master: it cannot follow
    assert numbers(ask(sim, "MG _TC")) == [46]


def test_a_follower_of_s_follows_the_distance_along_every_sequence(sim: SimController) -> None:
    ask(sim, "VM AB;VSS=30000;VP 3000,4000;VE;GA ,,S;GR ,,1.5")
    t0 = sim.start_trace("C")
    begin = stamp(ask(sim, "BG S;MG TIME"))
    sim.advance(1)
    first = predict.vector([Line(3000, 4000)], 30000, 256000, 256000)
    ask(sim, "VP 0,1000;VE")
    second_begin = stamp(ask(sim, "BG S;MG TIME"))
    sim.advance(1)
    trace = sim.stop_trace("C")["C"]
    second = predict.vector([Line(0, 1000)], 30000, 256000, 256000)
    distance = np.concatenate(
        [
            first.path,
            np.full(second_begin - begin - first.samples - 1, first.length),
            first.length + second.path,
        ]
    )
    expected = predict.gear(distance, 1.5)
    np.testing.assert_array_equal(trace[begin - t0 : begin - t0 + expected.size], expected)
    assert numbers(ask(sim, "MG _RPC"))[0] == round(1.5 * (5000 + 1000))
