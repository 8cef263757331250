"""Issue 12's "done when", through the public API over TCP and a pty to a real ``galil sim``.

``galil sim`` runs as a child process in real time; the test talks to it as to a controller
on the network or a serial port: ``galil.connect(address)`` and nothing else.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np
import pytest

import galil
from galil.testing import transcript

FILL = """
#FILL
i=0
#LOOP
cube[i]=i*i*i
i=i+1
JP #LOOP,i<8
EN
"""


@pytest.fixture(params=["tcp", "pty"])
def address(request: pytest.FixtureRequest, galil_sim: Callable[..., str]) -> str:
    """The address of a ``galil sim`` child process, over TCP or a pty."""
    if request.param == "pty" and not hasattr(os, "openpty"):
        pytest.skip("needs a pty")
    return galil_sim(*(["--tcp", "127.0.0.1:0"] if request.param == "tcp" else ["--pty"]))


@pytest.fixture
def tcp_address(galil_sim: Callable[..., str]) -> str:
    """The address of a ``galil sim`` child process on TCP."""
    return galil_sim("--tcp", "127.0.0.1:0")


def test_a_program_fills_an_array_on_thread_1_and_stays_beside_a_speed_schedule(
    address: str,
) -> None:
    with galil.connect(address, timeout=2.0) as dmc:
        dmc.arrays.define("cube", 8, replace=True)
        assert dmc.programs.download(FILL).sent
        dmc.programs.run("#FILL", thread=1)
        dmc.programs.wait(1, timeout=5)
        assert 1 not in dmc.programs.threads
        assert dmc.arrays.upload("cube").tolist() == [i**3 for i in range(8)]
        assert dmc.programs.upload() == FILL.strip()

        with transcript(dmc) as sent:
            assert not dmc.programs.download(FILL).sent
        assert sent.lines == ["UL"]  # the program was read, nothing was sent

        # A speed schedule installs its routine beside the program, never over it.
        x = dmc.A
        x.accel = x.decel = 1_024_000
        x.speed_schedule(4000, [(2000, 10_000)], speed=20_000).wait(timeout=5)
        assert dmc.programs.upload() == FILL.strip()
        dmc.programs.run("#FILL", thread=1)  # and it still runs
        dmc.programs.wait(1, timeout=5)


def test_a_user_interrupt_from_a_program_reaches_a_callback_over_tcp(tcp_address: str) -> None:
    with galil.connect(tcp_address, timeout=2.0) as dmc:
        heard: list[galil.Interrupt] = []
        dmc.interrupts.subscribe(heard.append)
        dmc.interrupts.enable(axes="A")
        dmc.programs.download("#TELL\nUI 7\nEN")
        dmc.programs.run("#TELL", thread=3)
        first = dmc.interrupts.get(timeout=5)
        assert (first.kind, first.number) == ("user", 7)
        dmc.A.move_by(500).wait(timeout=5)
        assert str(dmc.interrupts.get(timeout=5)) == "axis A done"
        assert [str(i) for i in heard] == ["UI 7", "axis A done"]


def test_a_capture_over_tcp_lines_up_with_the_move_it_recorded(tcp_address: str) -> None:
    with galil.connect(tcp_address, timeout=2.0) as dmc:
        cap = dmc.capture(["_RPA"], every=2, count=200)
        move = dmc.A.move_by(3000)
        move.wait(timeout=5)
        rec = cap.wait()
        begin = move.begin["A"]
        assert begin is not None
        assert rec.start <= begin  # started first, on its own line
        k = rec.samples - begin
        inside = (k >= 0) & (k <= move.profile.samples)
        assert inside.sum() > 50
        assert np.array_equal(rec["_RPA"][inside], move.profile.position[k[inside]])


def test_a_soft_limit_runs_the_programs_limswi_and_its_message_arrives_over_tcp(
    tcp_address: str,
) -> None:
    with galil.connect(tcp_address, timeout=2.0) as dmc:
        dmc.programs.download(
            '#M\nFL 1500;PR 3000;BG A\nAM A\nMG "done",_SCA\nEN\n#LIMSWI\nMG "limit",_SCA\nRE 1'
        )
        dmc.programs.run("#M", thread=0)
        dmc.programs.wait(0, timeout=5)
        assert dmc.messages.get(timeout=5).strip() == "limit 2.0000"
        assert dmc.messages.get(timeout=5).strip() == "done 2.0000"
        assert dmc.A.stop_code[0] == 2
