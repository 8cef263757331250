"""Coordinated paths over a slow serial line (decision 0100).

A contour's refill and a vector sequence's setup are hundreds of segments on one
``command_line``: kilobytes, seconds at 19200 baud. They get the reply timeout of their size at
the link's byte rate, as a bulk transfer (decision 0064), not the link's ordinary 1 s: a path
the link can carry runs. When such a line fails all the same, the contour's ``ST`` waits for the
link to get back in step behind the bytes still on their way (or says the axes may still move),
and a sequence whose setup failed says it never started (``BG S`` was not sent) and leaves the
link in step.

Over the simulator as a serial line in simulated time (``baud=``), so a path of seconds on the
line takes milliseconds here.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest

import galil
from galil import Line
from galil.contour import sample_path
from galil.errors import GalilConnectionError, GalilTimeoutError, MotionError
from galil.sim.rooms.contour import Contour as SimContour
from galil.testing import sim_of, simulated, transcript
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def _circle(
    axes: int, radius: float = 1_000_000
) -> Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]:
    """A circle on ``axes`` axes, a radian a second (and a mirror, a ramp), in counts."""

    def f(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        cols = [np.sin(t), 1 - np.cos(t), -np.sin(t), 0.15 * t][:axes]
        return np.stack(cols, axis=-1) * radius

    return f


def _wave(n: int) -> list[Line]:
    """``n`` short lines in mm (a segment of ~12 bytes each on the wire)."""
    return [Line(1 * mm, 20 * mm * (math.sin((k + 1) / 40) - math.sin(k / 40))) for k in range(n)]


def _in_contour_mode(dmc: galil.Controller) -> list[object]:
    return list(sim_of(dmc).room(SimContour).axes())


@pytest.mark.parametrize(("axes", "baud"), [("AB", 19200), ("ABCD", 115200)])
def test_a_contour_of_a_whole_buffer_runs_on_a_serial_line_that_carries_it(
    axes: str, baud: int
) -> None:
    with simulated("DMC-4240", baud=baud) as dmc:
        ts = dmc.sample_period
        path = sample_path(_circle(len(axes)), duration=4.0, dt=3, sample_period=ts)
        result = dmc.contour(axes, path, dt=3)  # (a 1 s timeout cut its first refill)
        assert len(result.increments) == 512
        ends = dmc.query_operands([f"_RP{a}" for a in axes])
        assert [round(v) for v in ends] == [result.profiles[a].end for a in axes]
        assert _in_contour_mode(dmc) == []
        assert dmc.query_number("MG 1") == 1


def _interrupt_after_first_refill(dmc: galil.Controller, then: Callable[[], None]) -> None:
    """Raise ``KeyboardInterrupt`` on the first reply bytes read after the first ``CD`` line
    went out (the rest of that refill still on the line), then call ``then``."""
    armed: list[bool] = []

    def hook(direction: str, data: bytes) -> None:
        if direction == "out" and b"CD " in data and not armed:
            armed.append(True)
        elif direction == "in" and armed == [True]:
            armed.append(False)
            then()
            raise KeyboardInterrupt

    dmc.wire_log.add(hook)


def test_a_contour_cut_during_a_refill_on_a_slow_line_is_stopped_and_leaves_contour_mode() -> None:
    with simulated("DMC-4240", baud=19200) as dmc:
        ts = dmc.sample_period
        path = sample_path(_circle(2, 100_000), duration=60.0, dt=6, sample_period=ts)
        _interrupt_after_first_refill(dmc, lambda: None)
        with pytest.raises(KeyboardInterrupt):
            dmc.contour("AB", path, dt=6)
        # The ST went out behind the 6 kB of CD lines still on the line (3.4 s at 1920 B/s):
        # the 1 s of an ordinary reply could not get the link back in step for it.
        dmc.sleep(2.0)
        assert dmc.query_operands(["_BGA", "_BGB"]) == [0, 0]
        assert _in_contour_mode(dmc) == []
        at = [round(v) for v in dmc.query_operands(["_RPA", "_RPB"])]
        dmc.sleep(2.0)
        assert [round(v) for v in dmc.query_operands(["_RPA", "_RPB"])] == at
        assert at != [round(v) for v in path[-1]]  # (the path did not run on to its end)
        assert dmc.query_number("MG 1") == 1
        assert dmc.A.move_by(100).wait().final == {"A": at[0] + 100}


def test_a_contour_whose_stop_cannot_be_sent_says_its_axes_may_still_move() -> None:
    with simulated("DMC-4240", baud=19200) as dmc:
        ts = dmc.sample_period
        path = sample_path(_circle(2, 100_000), duration=60.0, dt=6, sample_period=ts)
        broken: list[bool] = []

        def cut(direction: str, data: bytes) -> None:
            if direction == "out" and broken:
                raise GalilConnectionError("the cable is out")

        dmc.wire_log.add(cut)
        _interrupt_after_first_refill(dmc, lambda: broken.append(True))
        with pytest.raises(MotionError, match="may still be moving") as caught:
            dmc.contour("AB", path, dt=6)
        assert caught.value.moving == "AB"
        assert isinstance(caught.value.__cause__, KeyboardInterrupt)
        broken.clear()  # (the cable back: close() stops what the library could not)
        dmc.reconnect()
        dmc.stop()


@pytest.mark.parametrize(
    ("baud", "segments", "axes"), [(19200, 600, "AB"), (9600, 80, "AB"), (115200, 600, "ABCD")]
)
def test_a_path_whose_first_segments_take_seconds_on_the_line_runs(
    baud: int, segments: int, axes: str
) -> None:
    with simulated("DMC-4240", baud=baud) as dmc:
        for a in axes:
            dmc.axes[a].set_scale(counts_per=20000 / mm)
        wave = _wave(segments)
        path = [Line(*(list(seg.deltas) * 2)[: len(axes)]) for seg in wave]
        handle = dmc.vector_move(axes, path, speed=40 * mm / s, accel=400 * mm / s**2)
        result = handle.wait()
        assert result.worst == 0
        assert set(result.stop_codes.values()) == {101}
        assert dmc.query_number("MG 1") == 1


def _drop_setup_replies(armed: list[bool]) -> Callable[[bytes], list[tuple[float, bytes]]]:
    """A fault hook: while ``armed``, the controller's replies made of ``:`` only (a setup
    line's) are lost."""

    def hook(data: bytes) -> list[tuple[float, bytes]]:
        if armed and len(data) >= 5 and set(data) == {ord(":")}:
            return []
        return [(0.0, data)]

    return hook


def test_a_setup_line_that_fails_says_the_sequence_did_not_start_and_the_link_stays_in_step() -> (
    None
):
    armed: list[bool] = []
    with galil.connect("sim://DMC-4240?baud=19200", faults=_drop_setup_replies(armed)) as dmc:
        dmc.A.set_scale(counts_per=20000 / mm)
        dmc.B.set_scale(counts_per=20000 / mm)
        armed.append(True)
        with transcript(dmc) as sent, pytest.raises(GalilTimeoutError) as caught:
            dmc.vector_move("AB", _wave(600), speed=40 * mm / s, accel=400 * mm / s**2)
        text = caught.value.args[0]
        assert "the sequence was not started: BG S was not sent" in text
        assert "out of step" not in text
        assert not [line for line in sent.lines if line.startswith(("BG", "ST"))]
        armed.clear()
        assert dmc.query_operands(["_BGS", "_BGA", "_BGB"]) == [0, 0, 0]
        assert dmc.tracker.unstopped == ""
        assert dmc.query_number("MG 1") == 1  # (in step: no resynchronisation failed)
        assert dmc.vector_move("AB", _wave(50), speed=40 * mm / s).wait().worst == 0
