"""Long paths on a serial line under a watchdog (decision 0100).

A contour's refill and a sequence's setup are hundreds of segments: seconds at 19200 baud.
Sent on one line they held the link for that long, the watchdog's heartbeat could not get
through, and the watchdog the user had set stopped the motion (or, before ``BG S``, left a
sequence to run unguarded). They now go out a short line at a time, the heartbeat riding on
them. A contour that something else stops (the watchdog, another client's ``ST``) says so in
a :class:`~galil.errors.MotionError`, not in a ``TC 41`` naming hundreds of refused ``CD``.

Over the simulator as a serial line in simulated time (``baud=``): its clock runs with the
bytes, so a heartbeat that does not go out on the line does not go out at all.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import galil
from galil import Line
from galil.errors import CommandError, MotionError
from galil.sim.rooms.contour import Contour as SimContour
from galil.testing import sim_of, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def _ramp(n: int = 512) -> np.ndarray:
    """``n`` DT 3 segments on A and B (the reviewer's path: 4 s, a whole buffer and one)."""
    t = np.arange(1, n + 1, dtype=np.float64)
    return np.stack([t * 50, t * 30], axis=1)


def _wave(n: int) -> list[Line]:
    return [Line(1 * mm, 20 * mm * (math.sin((k + 1) / 40) - math.sin(k / 40))) for k in range(n)]


def _on_cd_line(dmc: galil.Controller, n: int, other: bytes) -> None:
    """Another client sends ``other`` just before the ``n``-th line of ``CD`` goes out."""
    sim = sim_of(dmc)
    port = sim.open_port("other client")
    seen: list[int] = []

    def hook(direction: str, data: bytes) -> None:
        if direction == "out" and b"CD " in data:
            seen.append(1)
            if len(seen) == n:
                sim.feed(other, port)

    dmc.wire_log.add(hook)


def test_a_contour_of_a_whole_buffer_on_a_serial_line_runs_under_a_one_second_watchdog() -> None:
    with simulated("DMC-4240", baud=19200) as dmc:
        path = _ramp()
        with dmc.watchdog(1.0) as dog:
            result = dmc.contour("AB", path, dt=3)  # (its pre-load: 3.4 s of bytes)
            assert not dog.fired
        assert dmc.query_operands(["_RPA", "_RPB"]) == [25600, 15360]
        assert result.begin is not None
        assert list(sim_of(dmc).room(SimContour).axes()) == []


def test_a_vector_path_of_a_whole_buffer_on_a_serial_line_runs_under_a_one_second_watchdog() -> (
    None
):
    with simulated("DMC-4240", baud=19200) as dmc:
        for a in "AB":
            dmc.axes[a].set_scale(counts_per=20000 / mm)
        with dmc.watchdog(1.0) as dog:
            # (its setup: 511 segments, 3 s of bytes; the watchdog fired during it, and BG S
            # then ran the path with nothing guarding it)
            handle = dmc.vector_move("AB", _wave(600), speed=40 * mm / s, accel=400 * mm / s**2)
            result = handle.wait()
            assert not dog.fired
            assert dog.running
        assert result.worst == 0
        assert set(result.stop_codes.values()) == {101}


def test_a_contour_another_client_stops_raises_a_motion_error_that_says_so() -> None:
    with simulated("DMC-4240", baud=19200) as dmc:
        _on_cd_line(dmc, 20, b"ST AB\r")  # (after the pre-load: the contour runs)
        with pytest.raises(MotionError) as caught:
            dmc.contour("AB", _ramp(1500), dt=3)
        error = caught.value
        assert not isinstance(error, CommandError)
        text = str(error)
        assert "stopped by an ST or AB the library did not send" in text
        assert "TC 41" in text
        assert "Contour stopped" in text
        assert error.stop_codes == {"A": 51, "B": 51}
        assert len(text.splitlines()[0]) < 400
        assert list(sim_of(dmc).room(SimContour).axes()) == []
        assert dmc.query_number("MG 1") == 1


def test_a_contour_the_watchdog_stops_raises_a_motion_error_naming_the_watchdog() -> None:
    with simulated("DMC-4240", baud=19200) as dmc, dmc.watchdog(1.0) as dog:
        # Another client shortens the watchdog's limit to 2 samples: it fires at once.
        _on_cd_line(dmc, 3, b"gwlimit=2\r")
        with pytest.raises(MotionError, match="stopped by the watchdog") as caught:
            dmc.contour("AB", _ramp(), dt=3)
        assert dog.fired
        assert caught.value.stop_codes == {"A": 51, "B": 51}
        assert "also refused" not in str(caught.value)


def test_a_line_with_many_refused_parts_names_five_and_counts_the_rest() -> None:
    with simulated("DMC-4240") as dmc:
        with pytest.raises(CommandError) as caught:
            dmc.command_line([f"CD {k},0" for k in range(1, 41)])  # (not in contour mode)
        first = str(caught.value).splitlines()[0]
        assert "also refused: 'CD 1,0', 'CD 2,0', 'CD 3,0', 'CD 4,0', 'CD 5,0' and 34 more" in first
        assert "'CD 6,0'" not in first
        assert caught.value.replies == (None,) * 40


def _after_the_start(dmc: galil.Controller, other: bytes, *, then: bytes = b"DT 3") -> None:
    """Another client sends ``other`` just before the first line after the one holding
    ``then`` goes out: after the ``DT`` that starts a pre-loaded path (all its segments in),
    or, with ``then=b"CD 0,0=0"``, while ``finish()`` waits for the contour's end."""
    sim = sim_of(dmc)
    port = sim.open_port("other client")
    state = {"armed": False, "done": False}

    def hook(direction: str, data: bytes) -> None:
        if direction != "out" or state["done"]:
            return
        if state["armed"]:
            state["done"] = True
            sim.feed(other, port)
        elif then in data:
            state["armed"] = True

    dmc.wire_log.add(hook)


def test_a_contour_another_client_stops_after_its_last_segment_raises_a_motion_error() -> None:
    """A path that fits the pre-load, stopped before its end of contour mode goes out: the
    controller refuses ``CD 0,0=0``; that refusal is the stop's evidence, as a refused ``CD``
    is, not a raw ``CommandError``."""
    with simulated("DMC-4240", baud=19200) as dmc:
        _after_the_start(dmc, b"ST AB\r")
        with pytest.raises(MotionError) as caught:
            dmc.contour("AB", _ramp(300), dt=3)
        error = caught.value
        assert not isinstance(error, CommandError)
        text = str(error).splitlines()[0]
        assert "stopped by an ST or AB the library did not send" in text
        assert "after 300 of 300 segments were sent" in text
        assert "the end of contour mode" in text
        assert error.stop_codes == {"A": 51, "B": 51}
        assert list(sim_of(dmc).room(SimContour).axes()) == []
        assert dmc.query_number("MG 1") == 1


def test_a_contour_the_watchdog_stops_after_its_last_segment_names_the_watchdog() -> None:
    with simulated("DMC-4240", baud=19200) as dmc, dmc.watchdog(1.0) as dog:
        _after_the_start(dmc, b"gwlimit=2\r")  # (the watchdog fires at once)
        with pytest.raises(MotionError, match="stopped by the watchdog") as caught:
            dmc.contour("AB", _ramp(300), dt=3)
        assert not isinstance(caught.value, CommandError)
        assert dog.fired
        assert caught.value.stop_codes == {"A": 51, "B": 51}


def test_a_contour_the_watchdog_stops_while_finish_waits_names_the_watchdog() -> None:
    with simulated("DMC-4240", baud=19200) as dmc, dmc.watchdog(1.0) as dog:
        _after_the_start(dmc, b"gwlimit=2\r", then=b"CD 0,0=0")
        with pytest.raises(MotionError) as caught:
            dmc.contour("AB", _ramp(300), dt=3)
        text = str(caught.value).splitlines()[0]
        assert "stopped by the watchdog" in text
        assert "not at the end of its path (15000)" in text
        assert dog.fired
        assert caught.value.stop_codes == {"A": 51, "B": 51}


def test_a_contour_another_client_stops_long_after_the_watchdog_fired_does_not_blame_it() -> None:
    """``gwfire`` stays 1 after a firing: only a firing during the contour names the
    watchdog."""
    with simulated("DMC-4240", baud=19200) as dmc, dmc.watchdog(1.0) as dog:
        dmc.C.jog(2000)
        sim_of(dmc).advance(2.0)  # the host silent: the watchdog fires, and stops C
        assert dog.fired
        assert not dmc.C.moving
        _on_cd_line(dmc, 20, b"ST AB\r")
        with pytest.raises(MotionError) as caught:
            dmc.contour("AB", _ramp(1500), dt=3)
        text = str(caught.value).splitlines()[0]
        assert "stopped by an ST or AB the library did not send" in text
        assert "watchdog" not in text


@pytest.mark.parametrize("other", [b"ST AB\r", b"AB\r"])
def test_a_contour_stopped_during_its_pre_load_says_it_never_started_and_drops_the_held(
    other: bytes,
) -> None:
    with simulated("DMC-4240", baud=19200) as dmc:
        _on_cd_line(dmc, 2, other)  # (in the pre-load, under DT -1: nothing has run)
        with pytest.raises(MotionError) as caught:
            dmc.contour("AB", _ramp(), dt=3)
        text = str(caught.value).splitlines()[0]
        assert "before it started" in text
        assert "segments were sent" not in text
        assert dmc.query_operands(["_CM"]) == [511]  # (the held segments dropped)
        assert list(sim_of(dmc).room(SimContour).axes()) == []
        assert dmc.query_operands(["_RPA", "_RPB"]) == [0, 0]
        dmc.A.move_by(1000).wait()
        assert dmc.A.position == 1000
