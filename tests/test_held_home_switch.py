"""A home switch held by the simulator's test hook: HM and FE search from the input TS reads.

``sim.set_home_switch(axis, pressed=True/False)`` holds the home input at one level whatever
the position. The controller's homing knows only that input, so the search starts the way it
reads and meets an edge only when the hold ends; the host predicts nothing it cannot know
(decision 0088). Everything here goes through the public API over ``sim://``.
"""

from __future__ import annotations

import pytest

import galil
from galil.testing import sim_of, simulated


@pytest.mark.parametrize("pressed", [True, False])
def test_find_edge_starts_the_way_a_held_home_input_reads(pressed: bool) -> None:
    # (FE drove by the switch's geometry, in reverse from 0 whatever the hold, and stopped
    # at the geometric edge while TS still read the held level)
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        # the flag covers what is below -10,000 (pressed: held tripped at 0 where it is not)
        # or what is below +10,000 (released: held open at 0 where it is tripped)
        sim.set_home_switch("A", edge=-10_000 if pressed else 10_000, pressed=pressed)
        assert x.switches.home is pressed  # (default CN: the input is active low)
        handle = x.find_edge()
        dmc.sleep(0.2)
        # default CN: in reverse while the input is high, forward while it is low
        direction = 1 if pressed else -1
        assert direction * x.reference_position > 3000
        assert x.switches.home is pressed
        x.stop()
        assert handle.wait(timeout=5).stop_codes == {"A": 4}


@pytest.mark.parametrize("pressed", [True, False])
def test_a_home_switch_held_for_ever_meets_no_edge_and_the_search_runs_to_a_limit(
    pressed: bool,
) -> None:
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        sim.set_home_switch("A", edge=-10_000 if pressed else 10_000, pressed=pressed)
        sim.place_limit_switches("A", forward=60_000, reverse=-60_000)
        with pytest.raises(galil.MotionError, match="limit"):
            x.find_edge().wait(timeout=30)
        assert x.stop_code[0] == (2 if pressed else 3)
        assert abs(sim.machine_position("A")) >= 60_000  # past the geometric edge, on
        assert x.switches.home is pressed


def test_releasing_a_held_home_switch_is_the_edge_find_edge_stops_at() -> None:
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        sim.set_home_switch("A", pressed=True)  # flag below -10,000; held tripped at 0
        handle = x.find_edge()
        dmc.sleep(0.5)
        released_at = sim.machine_position("A")
        assert released_at > 5000  # forward, away from the geometric edge
        sim.set_home_switch("A", pressed=None)  # the input follows the flag: high here
        result = handle.wait(timeout=5)
        assert result.stop_codes == {"A": 9}
        # decelerated from where it was released (SP 25,000, DC 256,000: ~1,220 counts)
        assert released_at < sim.machine_position("A") < released_at + 2000
        assert not x.switches.home


def test_home_after_a_hold_ends_finds_the_flag_and_its_index() -> None:
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        sim.set_servo_lag(0.0)
        x.home_speed = 20_000
        sim.set_home_switch("A", pressed=True)  # flag below -10,000; index every 4,000
        handle = x.home()
        dmc.sleep(0.3)
        assert sim.machine_position("A") > 3000  # stage 1 forward, as the input reads low
        sim.set_home_switch("A", pressed=None)  # high here: stage 1 ends, stage 2 goes back
        result = handle.wait(timeout=30)
        assert result.stop_codes == {"A": 10}
        # back over the flag's edge at HV, then forward to the first index above it
        assert sim.machine_position("A") == -8000
        assert x.position == 0
        assert x.homed


@pytest.mark.parametrize("start", ["home", "find_edge"])
def test_a_switch_the_input_contradicts_is_not_predicted(start: str) -> None:
    # (the host predicted from the geometry, reverse from 0 and an exact end, while the
    # controller searched forward from the held input)
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        x.home_speed = 20_000
        sim.set_home_switch("A", pressed=True)
        handle: galil.MoveHandle = getattr(x, start)(switch=sim.home_switch("A"))
        assert "home input reads low" in handle.notes["A"]
        assert handle.duration == float("inf")
        track = handle.track("A")
        assert track is not None
        assert not track.exact
        dmc.sleep(0.3)
        sim.set_home_switch("A", pressed=None)
        result = handle.wait(timeout=30)
        assert result.stop_codes == {"A": 9 if start == "find_edge" else 10}
        assert result.predicted == {}  # (no end claimed)


def test_a_switch_the_input_agrees_with_is_still_predicted_exactly() -> None:
    # (a guard against refusing too much: a hold ended before the start changes nothing)
    with simulated("DMC-4040") as dmc:
        sim, x = sim_of(dmc), dmc.A
        sim.set_servo_lag(0.0)
        x.home_speed = 20_000
        sim.set_home_switch("A", pressed=False)  # held open where the flag is open anyway
        sim.set_home_switch("A", pressed=None)
        handle = x.home(switch=sim.home_switch("A"))
        assert "exact" in handle.notes["A"]
        assert handle.wait(timeout=30).deviation == {"A": 0}
