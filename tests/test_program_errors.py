"""``programs.wait`` tells a thread that stopped on an error from one that reached ``EN``
(decision 0059): ``_ED``/``_ED1``/``_TC`` read at ``run`` and at the end, through the public
API on ``sim://``, on the async twin, and over TCP loopback."""

from __future__ import annotations

import asyncio

import pytest

import galil
import galil.aio as aio
from galil.sim.server import SimTcpServer
from galil.testing import simulated, transcript

PROGRAM = """
#GOOD
x=1
EN
#BAD
x=1
KPA=-1
x=2
EN
#WORDS
XYZ 5
EN
#SLOW
WT 200
EN
#LOOP
WT 10
JP #LOOP
"""


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        controller.programs.download(PROGRAM)
        yield controller


def test_a_thread_that_reaches_en_is_waited_for_quietly(dmc: galil.Controller) -> None:
    dmc.programs.run("#GOOD")
    with transcript(dmc) as sent:
        dmc.programs.wait()
    assert "UL" not in sent.lines  # (the program is read only after an error)


@pytest.mark.parametrize(
    ("label", "line", "text", "code"),
    [("#BAD", 5, "KPA=-1", 6), ("#WORDS", 9, "XYZ 5", 1)],
)
def test_a_thread_stopped_at_a_bad_line_raises_naming_the_line_its_text_and_code(
    dmc: galil.Controller, label: str, line: int, text: str, code: int
) -> None:
    dmc.programs.run(label, thread=1)
    with pytest.raises(galil.ProgramError) as caught:
        dmc.programs.wait(1)
    e = caught.value
    assert (e.code, e.line, e.command, e.thread, e.waited) == (code, line, text, 1, 1)
    assert isinstance(e, galil.CommandError)
    assert e.text == galil.tc_text(code)
    assert str(e).startswith(f"thread 1 failed on DMC-4040 at program line {line} ({text}): ")
    dmc.programs.wait(1)  # said once


def test_the_same_line_failing_on_a_second_run_is_seen_too(dmc: galil.Controller) -> None:
    # _ED and _ED1 stay 5 and 0: the error code cleared at run() and set again tells it.
    for _ in range(2):
        dmc.programs.run("#BAD")
        with pytest.raises(galil.ProgramError, match="line 5"):
            dmc.programs.wait()
        assert dmc.variables["x"] == 1  # the line after it never ran
    dmc.programs.run("#GOOD")  # the old error's code, cleared at run(), is not taken for its
    dmc.programs.wait()


def test_a_program_with_cmderr_handles_its_own_error(dmc: galil.Controller) -> None:
    dmc.programs.halt()
    dmc.programs.download(PROGRAM + '#CMDERR\nMG "handled",_ED\nEN\n')
    dmc.programs.run("#BAD")
    dmc.programs.wait()
    assert dmc.messages.get(timeout=1) == "handled 5.0000"
    assert dmc.variables["x"] == 2  # thread 0 went on after the failed line


def test_a_thread_halted_by_the_library_or_by_hx_is_no_error(dmc: galil.Controller) -> None:
    dmc.programs.run("#LOOP", thread=2)
    dmc.programs.halt(2)
    dmc.programs.wait(2)
    dmc.programs.run("#LOOP", thread=2)
    dmc.command("HX2")
    dmc.programs.wait(2)


def test_a_thread_ended_by_a_reset_is_no_error(dmc: galil.Controller) -> None:
    dmc.programs.run("#BAD")
    with pytest.raises(galil.ProgramError):
        dmc.programs.wait()
    dmc.programs.run("#SLOW", thread=1)
    dmc.reset()  # RS: _ED and _ED1 read 0 and -1 again
    dmc.programs.wait(1)


def test_a_host_command_refused_while_a_program_runs_is_not_blamed_on_it(
    dmc: galil.Controller,
) -> None:
    dmc.programs.run("#BAD")  # _ED, _ED1 and _TC now tell of an error on line 5
    with pytest.raises(galil.ProgramError):
        dmc.programs.wait()
    dmc.programs.run("#SLOW", thread=3)
    with pytest.raises(galil.CommandError, match="TC 1"):
        dmc.command("XYZ")
    dmc.programs.wait(3)  # _ED is where #BAD failed; the refusal's TC was read by TC1


def test_an_error_in_another_thread_stops_this_one_and_names_that_thread(
    dmc: galil.Controller,
) -> None:
    dmc.programs.run("#LOOP", thread=0)
    dmc.programs.run("#BAD", thread=4)
    with pytest.raises(galil.ProgramError) as caught:
        dmc.programs.wait(0)
    e = caught.value
    assert (e.thread, e.waited, e.line, e.code) == (4, 0, 5, 6)
    assert str(e).startswith("thread 0 stopped because thread 4 failed on DMC-4040 at ")
    assert dmc.programs.threads == {}  # without #CMDERR every thread stops


def test_an_error_of_another_thread_handled_by_cmderr_is_not_blamed_on_this_one(
    dmc: galil.Controller,
) -> None:
    dmc.programs.download(PROGRAM + "#CMDERR\nEN\n")
    dmc.programs.run("#SLOW", thread=2)
    dmc.programs.run("#BAD", thread=4)
    dmc.programs.wait(4)  # halted by its error, which #CMDERR handled
    assert 2 in dmc.programs.threads
    dmc.programs.wait(2)


def test_the_async_wait_raises_the_same_error() -> None:
    async def body() -> None:
        async with await aio.connect("sim://DMC-4040") as c:
            await c.programs.download(PROGRAM)
            await c.programs.run("#BAD", thread=1)
            with pytest.raises(galil.ProgramError, match=r"line 5 \(KPA=-1\): TC 6"):
                await c.programs.wait(1)

    asyncio.run(asyncio.wait_for(body(), 30))


def test_a_program_error_is_told_over_tcp_loopback() -> None:
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url, timeout=2) as dmc:
        dmc.programs.download(PROGRAM)
        dmc.programs.run("#WORDS", thread=1)
        with pytest.raises(galil.ProgramError) as caught:
            dmc.programs.wait(1, timeout=5)
        assert (caught.value.line, caught.value.command, caught.value.code) == (9, "XYZ 5", 1)
