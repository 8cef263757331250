"""A contour that runs into a limit switch ends with the stop reported (decision 0041).

The controller stops the whole contour at the switch (stop code 2 or 3 on that axis, 51 on the
others) and leaves contour mode; ``controller.contour`` raises :class:`galil.MotionError` with
the stop codes, and sends no ``CD`` once the stop is seen: not while the buffer is being fed,
nor at the end (``CD 0=0``), nor while it waits for the last segments.

"Seen" is what a host can promise: a line written before any reply that told of the stop came
back may reach the controller after it (over a real link the stop can come between a poll's
reply and the next line). The controller refuses such a ``CD``, and the stream reports the
stop, not the refusal. On the in-process simulator (a manual clock) no time passes between a
reply and the next line, so there no ``CD`` reaches the controller after the stop at all.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import numpy as np
import pytest

import galil
from galil.sim.controller import SimController
from galil.sim.parse import next_command
from galil.testing import sim_of, simulated


def ramp(to: float, segments: int) -> np.ndarray:
    """A two-axis path: A to ``to``, B to half of it, at constant speed."""
    a = np.linspace(to / segments, to, segments)
    return np.column_stack([a, a / 2])


def check_stopped_at_switch(
    dmc: galil.Controller, sim: SimController, path: np.ndarray, switch: int
) -> tuple[galil.MotionError, int]:
    """Run the contour into the switch; the error and the sample where A came to rest."""
    t0 = sim.start_trace("A")
    with pytest.raises(galil.MotionError, match="stopped by the controller") as caught:
        dmc.contour("AB", path, dt=1)
    exc = caught.value
    trace = sim.stop_trace("A")["A"]
    assert exc.axis == "A"
    assert exc.stop_codes == {"A": 2, "B": 51}
    assert exc.position == trace[-1]
    assert switch <= trace[-1] < path[-1, 0]
    stop = t0 + int(np.flatnonzero(trace != trace[-1])[-1]) + 1  # where A came to rest
    bg_a, bg_b, cm = dmc.query_operands(["_BGA", "_BGB", "_CM"])
    assert (bg_a, bg_b, cm) == (0, 0, 511)  # (no refused CD ran, nor started a contour)
    return exc, stop


def cds_run_after(sim: SimController, stop: int) -> list[str]:
    """The ``CD`` commands the simulator ran at or after ``stop``, the sample where the contour
    stopped (one run at that sample already finds it over: ``_SC`` reads the stop there)."""
    return [text for k, text in sim.command_log if k >= stop and text.startswith("CD")]


def split(data: bytes) -> list[str]:
    """The commands in bytes the host wrote, split as the simulator splits them."""
    out, rest = [], data.decode("latin-1")
    while (found := next_command(rest)) is not None:
        out.append(found[0])
        rest = rest[found[1] :]
    return out


@contextlib.contextmanager
def writes_of(dmc: galil.Controller) -> Iterator[list[list[str]]]:
    """The commands the block wrote to the command link, one list per write."""
    writes: list[list[str]] = []
    remove = dmc.wire_log.add(
        lambda way, data: writes.append(split(data)) if way == "out" else None
    )
    try:
        yield writes
    finally:
        remove()


def cds_written_once_the_stop_was_answered(
    sim: SimController, writes: list[list[str]], stop: int
) -> list[str]:
    """The ``CD`` commands written after a write the controller ran (any part of) at or after
    ``stop``, the sample where the contour stopped.

    The link writes a line (or a batch of lines) and reads every reply before it writes again,
    so by a later write the host had read the replies to that one, which tell of the stop: its
    ``_SC`` poll reads the stop codes, its ``CD`` was refused. A ``CD`` in the very write that
    first reached the stopped controller went out before any such reply, and is not counted.
    """
    commands = [(w, text) for w, texts in enumerate(writes) for text in texts]
    log = list(sim.command_log)[-len(commands) :]
    assert [text for _, text in log] == [text for _, text in commands]  # one to one
    first = min(w for (w, _), (k, _) in zip(commands, log, strict=True) if k >= stop)
    return [text for w, text in commands if w > first and text.startswith("CD")]


def test_a_long_contour_into_a_switch_raises_and_stops_feeding() -> None:
    # 3000 segments: the switch is reached while the stream still feeds the buffer.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=20_000)
        _, stop = check_stopped_at_switch(dmc, sim, ramp(60_000, 3000), 20_000)
        assert cds_run_after(sim, stop) == []  # nothing fed once the contour was over
        # Away from the switch, the next contour runs and ends as usual.
        result = dmc.contour("AB", -ramp(5000, 50), dt=1)
        assert dmc.query_operands(["_SCA", "_SCB"]) == [51, 51]
        assert result.increments.shape == (50, 2)


def test_a_short_contour_sent_whole_into_a_switch_raises_at_its_end() -> None:
    # 200 segments fit the buffer: the stop comes while the stream waits for the end.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=1000)
        _, stop = check_stopped_at_switch(dmc, sim, ramp(4000, 200), 1000)
        assert cds_run_after(sim, stop) == []  # no CD 0=0 once the contour was over


def test_a_contour_into_a_switch_over_tcp_raises_and_stops_feeding(
    tcp: tuple[galil.Controller, SimController],
) -> None:
    # The simulator runs in real time here: the stop can come between a poll's reply (still
    # "Contour running") and the batch written after it, which then reaches the controller
    # after the stop and is refused (made to happen: test_a_batch_on_its_way_as_...).
    dmc, sim = tcp
    sim.place_limit_switches("A", forward=12_000)
    with writes_of(dmc) as writes:
        _, stop = check_stopped_at_switch(dmc, sim, ramp(40_000, 1500), 12_000)
    assert cds_written_once_the_stop_was_answered(sim, writes, stop) == []


def run_on_to_the_stop(
    sim: SimController, poll: bytes, when: Callable[[list[float]], bool]
) -> Callable[[str, bytes], None]:
    """A wire hook: once the reply to ``poll`` that ``when`` (its numbers) picks has come in,
    the simulator runs on until axis A has stopped. The host has read a contour still running,
    and its next line reaches a controller whose contour is over: what a real link does to a
    line on its way as the stop comes."""
    after_poll = fired = False

    def hook(way: str, data: bytes) -> None:
        nonlocal after_poll, fired
        if way == "out":
            after_poll = data == poll
        elif after_poll and not fired and when([float(v) for v in data.split(b"\r")[0].split()]):
            fired = True
            motion = sim.motion("A")
            for _ in range(5000):
                if not motion.moving:
                    return
                sim.advance(sim.sample_period)
            raise AssertionError("the contour never reached the switch")

    return hook


def test_a_batch_on_its_way_as_the_stop_comes_is_refused_and_the_stop_raised() -> None:
    # The poll before a batch reads the contour running (50) with room for a batch; the batch
    # reaches the controller after the switch stopped it. The simulator refuses every CD
    # of it (contour mode is over: none runs, _CM reads the buffer empty); the stream raises
    # the stop, not the refusal, and feeds nothing more.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=4000)
        depth = dmc.model.contour_buffer
        room = depth // 4 + 1  # (the free slots a refill waits for)
        refill = run_on_to_the_stop(sim, b"MG _CM,_TC,_SCA,_SCB\r", lambda v: room <= v[0] < depth)
        dmc.wire_log.add(refill)  # (511 free: the poll before the first batch)
        with writes_of(dmc) as writes:
            exc, stop = check_stopped_at_switch(dmc, sim, ramp(60_000, 3000), 4000)
        refused = exc.__cause__
        assert isinstance(refused, galil.CommandError)  # (explained by the stop)
        assert refused.command.startswith("CD")
        assert len(cds_run_after(sim, stop)) >= room - 1  # the whole batch came after the stop
        assert cds_written_once_the_stop_was_answered(sim, writes, stop) == []


def test_a_contour_end_on_its_way_as_the_stop_comes_raises_the_stop() -> None:
    # All 200 segments fit the buffer; the stop comes between the last look at the buffer
    # and CD 0=0, which the controller refuses: the stream raises the stop.
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.place_limit_switches("A", forward=1000)
        dmc.wire_log.add(run_on_to_the_stop(sim, b"MG _CM\r", lambda v: True))
        with writes_of(dmc) as writes:
            exc, stop = check_stopped_at_switch(dmc, sim, ramp(4000, 200), 1000)
        refused = exc.__cause__
        assert isinstance(refused, galil.CommandError)
        assert refused.command == "CD 0,0=0"
        assert cds_run_after(sim, stop) == ["CD 0,0=0"]
        assert cds_written_once_the_stop_was_answered(sim, writes, stop) == []


@pytest.mark.parametrize("stale", [1, 2])
def test_a_stop_code_left_from_before_the_contour_is_not_read_as_its_stop(
    monkeypatch: pytest.MonkeyPatch, stale: int
) -> None:
    # Whether a controller sets _SC to 50 at CM is not sourced: one that kept the code of
    # the motion before (a move's 1, a limit's 2) all through the contour must not make a
    # contour that ran to its end look stopped. Only on an axis seen reading 50 is a stop
    # code the contour's stop (decision 0041).
    with simulated() as dmc:
        sim = sim_of(dmc)
        operands = sim._m.interp.axis_operands  # (the simulator's own _SC, the lowest layer)
        real = operands["SC"]
        monkeypatch.setitem(operands, "SC", lambda ax: stale if real(ax) in (50, 51) else real(ax))
        result = dmc.contour("AB", ramp(4000, 200), dt=1)
        assert result.increments.shape == (200, 2)
        assert dmc.query_operands(["_RPA", "_RPB"]) == [4000, 2000]
