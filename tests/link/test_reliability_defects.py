"""Defects found by testing the link as a tester would, each pinned through the public API:
callbacks that send commands, concurrent reconnects, leaks after close, programs overwritten
by a bad label, untyped errors from odd input, messages lost in a resync.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest
from concurrency import handles_closed

import galil
from galil.protocol import commands as cmds
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.server import SimPtyServer, SimTcpServer
from galil.testing import nothing_sent, simulated
from galil.units import ureg


def _galil_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("galil")]


@pytest.mark.parametrize("bus", ["pty", "tcp"])
def test_a_callback_may_send_commands_on_every_transport(bus: str) -> None:
    # A program prints a line every few ms, so lines also arrive while a callback's own
    # command is in flight (on a serial link, in the middle of its reply).
    sim = SimController("DMC-4040", RealTimeClock())
    server = SimPtyServer(sim) if bus == "pty" else SimTcpServer(sim)
    answers: queue.Queue[str] = queue.Queue()
    ticker = ["#TICK", "n=0", "#LOOP", 'MG "tick", n', "n=n+1", "WT 4", "JP #LOOP,n<40", "EN"]
    with server:
        address = server.path if bus == "pty" else server.url
        with galil.connect(address, timeout=2.0) as dmc:

            def on_line(line: str) -> None:
                answers.put(f"{dmc.command('MG 40+2').strip()} after {line.split()[0]}")

            dmc.subscribe(on_line)
            assert dmc.exchange(cmds.dl(ticker)).ok
            dmc.command_line([cmds.xq("#TICK", 1)])
            got = [answers.get(timeout=10) for _ in range(40)]
            assert got == ["42.0000 after tick"] * 40
            assert dmc.query_number("MG 7") == 7  # the link is still in step


def test_reconnect_from_many_threads_at_once_succeeds_and_close_leaks_nothing() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as server:
        dmc = galil.connect(server.url, timeout=2.0)
        errors: list[BaseException] = []

        def again() -> None:
            try:
                dmc.reconnect()
                assert dmc.query_number("MG 5") == 5
            except BaseException as exc:
                errors.append(exc)

        workers = [threading.Thread(target=again) for _ in range(40)]
        for w in workers:
            w.start()
        for w in workers:
            w.join(30)
        assert errors == []
        close_threads = [threading.Thread(target=dmc.close) for _ in range(8)]
        for t in close_threads:
            t.start()
        for t in close_threads:
            t.join(10)
        assert dmc.closed
        handles_closed(sim, 0)  # TH lists no TCP handle left
        deadline = time.monotonic() + 5
        while _galil_threads() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert _galil_threads() == []


def test_a_bad_schedule_label_leaves_the_users_program_alone() -> None:
    program = ["#USER", "uv=1", "EN"]
    with simulated() as dmc:
        assert dmc.exchange(cmds.dl(program)).ok
        for label in ("1BAD", "TOOLONGLABEL", "A B", 7):
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="label"):
                dmc.A.speed_schedule(10_000, [(5000, 2000)], label=label)  # type: ignore[arg-type]
        assert dmc.exchange(cmds.ul()).text.split("\r\n")[:3] == program


def test_odd_values_are_refused_with_typed_errors_before_the_wire() -> None:
    mm = ureg.mm
    with simulated() as dmc:
        x = dmc.A.set_scale(counts_per=1000 / mm)
        bad, limit = galil.InvalidArgument, galil.LimitError
        cases = [
            (bad, lambda: x.move_to(complex(1, 2) * mm)),
            (bad, lambda: x.move_to(np.array([1.0, 2.0]) * mm)),
            (bad, lambda: x.move_to(10)),  # no units on a scaled axis
            (bad, lambda: dmc.B.move_to(np.array([1, 2]))),
            (bad, lambda: dmc.contour("A", "abc", dt=2)),  # type: ignore[arg-type]
            (bad, lambda: dmc.contour("B", ["1", "2"], dt=2)),  # type: ignore[arg-type]
            (bad, lambda: dmc.contour("B", np.array([1 + 1j, 2]), dt=2)),  # type: ignore[arg-type]
            (limit, lambda: dmc.contour("B", np.array([1.0, 2.0**63]), dt=2)),
            (limit, lambda: dmc.contour("B", np.array([0, -(2**63)], dtype=np.int64), dt=2)),
            (bad, lambda: dmc.sleep(float("inf"))),
        ]
        for error, case in cases:
            with nothing_sent(dmc, allow_queries=True), pytest.raises(error):
                case()
        move = dmc.B.move_to(10)
        with nothing_sent(dmc), pytest.raises(bad, match="timeout"):
            move.wait(timeout=float("inf"))
        move.wait()
        assert dmc.query_number("MG 1") == 1


def test_messages_right_after_a_resync_marker_are_delivered() -> None:
    sim = SimController("DMC-4040", ManualClock())
    state = {"drop": False, "after_marker": False}

    def faults(data: bytes) -> list[tuple[float, bytes]]:
        if state["drop"]:
            state["drop"] = False
            return []  # a reply lost on the way
        if state["after_marker"] and b"SYNC" in data:
            state["after_marker"] = False
            return [(0.0, data + bytes(b | 0x80 for b in b"right after\r\n"))]
        return [(0.0, data)]

    link = SimLink(sim, faults=faults)
    with galil.connect(link, timeout=0.1) as dmc:
        state["drop"] = True
        with pytest.raises(galil.GalilTimeoutError):
            dmc.command("MG 9")  # no reply in time: the next command resynchronises
        state["after_marker"] = True
        assert dmc.query_number("MG 3") == 3
        assert dmc.messages.get(timeout=1) == "right after"
