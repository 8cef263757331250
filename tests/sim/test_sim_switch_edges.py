"""Limit switches at the edges: a switch placed exactly where a motion ends, and an axis that
turns towards a switch already active inside one long advance (decision 0054).

Each run is made twice, its time in one ``advance`` and one servo sample at a time: both must
give the same bytes (a stop found only at a step boundary lands later in the one advance).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import pytest
from sim_scripts import Script, play

from galil.sim.controller import SimController


def one_go_and_per_sample(script: Script) -> list[float]:
    """The fields of the last reply, the same whether time passes in one go or per sample."""
    coarse = play(script, per_sample=False)
    assert play(script, per_sample=True) == coarse
    last = coarse.rstrip(b":").rsplit(b":", 1)[-1]
    return [float(v) for v in re.findall(rb"-?\d+\.\d+", last)]  # (" 2.0000-5859.0000")


def press(axis: str, which: str) -> Callable[[SimController], None]:
    return lambda sim: sim.set_limit_switch(axis, which, True)


def place_forward(axis: str, at: int) -> Callable[[SimController], None]:
    return lambda sim: sim.place_limit_switches(axis, forward=at)


@pytest.mark.parametrize(("which", "sign", "code"), [("forward", 1, 2), ("reverse", -1, 3)])
def test_a_jog_reversed_towards_a_pressed_switch_stops_where_it_turns_not_at_the_advance_end(
    which: str, sign: int, code: int
) -> None:
    # The jog runs away from the pressed switch; the new JG ramps it through zero and on
    # towards it inside the one long advance, which must stop it where it turns.
    sc, rp = one_go_and_per_sample(
        [
            press("A", which),
            f"AC 100000;DC 100000;JG {-sign * 20000};BG A",
            300,
            f"JG {sign * 20000}",
            700,
            "MG _SCA,_RPA",
        ]
    )
    assert sc == code
    assert sign * rp < 0  # stopped still on the side it ran to (DC ramps it down)


def test_a_follower_whose_master_turns_towards_its_pressed_switch_stops_at_its_first_step() -> None:
    # The master's move back ends inside the advance: the follower is at rest again at the
    # step's end, having run towards its pressed switch all along.
    sc, rp, master = one_go_and_per_sample(
        [
            press("C", "forward"),
            "GA ,,A;GR ,,1;PR -3000;BG A",
            600,
            "PR 3000;BG A",
            600,
            "MG _SCC,_RPC,_RPA",
        ]
    )
    assert (sc, master) == (2, 0)  # C's gearing is off; A ran its move
    assert -3000 < rp < -2900


def test_a_follower_resting_on_its_placed_switch_is_stopped_when_its_master_moves_on() -> None:
    # The reporter's case: a ratio-1 follower of a contour axis ends exactly on its placed
    # switch, which its motor reaches after the motion (servo lag): active, no stop. A second
    # contour moves it further in: stopped at its first step, not run through the switch.
    lf, sc, rp = one_go_and_per_sample(
        [
            place_forward("C", 3000),
            "GA ,,CA;GR ,,1;CM A;DT 4",
            "CD 1000;CD 1000;CD 1000;CD 0=0",
            600,
            "MG _LFC,_SCC,_RPC",
            "CM A;DT 4",
            "CD 1000;CD 0=0",
            600,
            "MG _LFC,_SCC,_RPC",
        ]
    )
    assert (lf, sc) == (0, 2)
    assert 3000 < rp < 3100  # one contour sample in (62 counts), not 4000


_ENDS_AT_3000: dict[str, tuple[str, Sequence[str], str]] = {
    # path: (axis, lines, its stop code after a motion that ended as asked)
    "move": ("A", ["SP 20000;PA 3000;BG A"], "1"),
    "contour": ("A", ["CM A;DT 4", "CD 1000;CD 1000;CD 1000;CD 0=0"], "51"),
    "vector": ("A", ["VM AB;VS 20000;VP 3000,0;VE;BG S"], "101"),
    "follower": ("C", ["GA ,,CA;GR ,,1;CM A;DT 4", "CD 1000;CD 1000;CD 1000;CD 0=0"], "0"),
}


@pytest.mark.parametrize("path", sorted(_ENDS_AT_3000))
def test_a_switch_placed_where_a_motion_ends_reads_active_and_stops_nothing(path: str) -> None:
    # The switch is active with the motor at its position (at and beyond); the motor gets
    # there after the motion ended (servo lag), so nothing moves towards it: the motion
    # keeps the stop code of its end, the same on every path (decision 0054).
    axis, lines, code = _ENDS_AT_3000[path]
    tp, lf, sc = one_go_and_per_sample(
        [place_forward(axis, 3000), *lines, 800, f"MG _TP{axis},_LF{axis},_SC{axis}"]
    )
    assert (tp, lf, sc) == (3000, 0, float(code))


def test_a_switch_placed_where_a_move_ended_refuses_the_next_start_towards_it() -> None:
    sim = SimController("DMC-4040")
    sim.place_limit_switches("A", forward=3000)
    sim.feed(b"PA 3000;BG A\r")
    sim.advance(0.5)
    assert sim.feed(b"PR 10;BG A\r").endswith(b"?")
    assert sim.feed(b"TC\r").split()[0] == b"22"
    assert sim.feed(b"PR -10;BG A\r").endswith(b":")
