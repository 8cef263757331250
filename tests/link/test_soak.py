"""A short fault soak (the long one is ``make soak``): through a TCP proxy that splits, delays,
drops, slips in unsolicited lines and stray ``:``/``?`` on 5 % of the replies, four threads
never read a wrong value, never hang, and never hear "rejected" for a command that ran. And a
real Ctrl-C in the middle of ``wait()`` inside ``motion()`` always puts ``ST`` on the wire.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator

import pytest

import galil
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.proxy import FaultProxy, MixedFaults
from galil.sim.server import SimTcpServer
from galil.soak import soak


def test_a_faulty_link_never_gives_a_wrong_reply_a_hang_or_a_false_rejection() -> None:
    faults = MixedFaults(p=0.05, seed=3)
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address, faults=faults) as proxy,
        galil.connect(proxy.url, timeout=0.25) as dmc,
    ):
        report = soak(dmc, pairs=120, threads=4)
        faults.p = 0.0  # the link heals: it must be in step at once
        assert dmc.query_number("MG 1") == 1
    assert report.pairs == 480
    assert sum(faults.counts.values()) > 10  # faults did happen
    assert (report.wrong, report.hangs, report.rejected_but_ran) == (0, 0, 0), report.examples


@pytest.fixture
def ctrl_c_raises() -> Iterator[None]:
    """SIGINT raises KeyboardInterrupt, as in a terminal, however pytest was started (a shell
    starts background jobs with SIGINT ignored, and Python then installs no handler)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("ctrl_c_raises")
def test_ctrl_c_during_wait_inside_motion_always_sends_st() -> None:
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address, latency=0.003) as proxy,
        galil.connect(proxy.url, timeout=1.0) as dmc,
    ):
        dmc.A.speed, dmc.A.accel, dmc.A.decel = 200_000, 2_000_000, 2_000_000
        for at in (0.0, 0.01, 0.03, 0.07, 0.12):
            timer = threading.Timer(at, lambda: os.kill(os.getpid(), signal.SIGINT))
            interrupted = False
            with dmc.wire_log.capture() as wire:
                try:
                    with dmc.motion("A"):
                        move = dmc.A.move_by(600_000)  # 3 s: far longer than the timer
                        timer.start()
                        move.wait()
                except KeyboardInterrupt:
                    interrupted = True
                finally:
                    timer.cancel()
            deadline = time.monotonic() + 5
            while dmc.A.moving and time.monotonic() < deadline:
                time.sleep(0.01)
            assert interrupted
            assert b"ST A" in bytes(wire.sent)
            assert dmc.A.stop_code[0] == 4
