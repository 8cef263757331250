"""A wait with no timeout for a jog nobody stopped, on a simulator's manual clock, would
poll for ever when nothing on the controller can stop it: time passes there only while the
host waits. The sync wait refuses it after one query, before anything is sent; a stopped jog,
a timeout, a program or soft limit that may end it, an async wait (another task may stop
it) or a real clock waits as before."""

from __future__ import annotations

import asyncio
import threading

import pytest

import galil
import galil.aio as aio
from galil.errors import GalilTimeoutError, InvalidArgument
from galil.testing import nothing_sent, simulated


def test_waiting_for_an_open_jog_with_no_timeout_is_refused(dmc: galil.Controller) -> None:
    jog = dmc.A.jog(5000)
    with nothing_sent(dmc, allow_queries=True), pytest.raises(InvalidArgument) as info:
        jog.wait()
    said = str(info.value)
    assert "would never end" in said
    assert "Stop it first" in said
    assert "give a timeout" in said
    assert dmc.A.moving  # (refused: the jog goes on)
    jog.stop()
    assert jog.wait().stop_codes == {"A": 4}


def test_a_timeout_still_bounds_an_open_jogs_wait(dmc: galil.Controller) -> None:
    jog = dmc.A.jog(5000)
    with pytest.raises(GalilTimeoutError):
        jog.wait(timeout=0.5)
    jog.stop()
    jog.wait()


def test_a_jog_a_program_may_stop_is_waited_for(dmc: galil.Controller) -> None:
    dmc.programs.download("#STOPPER\nWT 200\nSTA\nEN")
    jog = dmc.A.jog(5000)
    dmc.programs.run("#STOPPER")
    assert jog.wait().stop_codes == {"A": 4}  # (no timeout: the program's ST ends it)


def test_a_jog_towards_a_soft_limit_is_waited_for(dmc: galil.Controller) -> None:
    dmc.A.soft_limits = (None, 2000)
    jog = dmc.A.jog(5000)
    with pytest.raises(galil.MotionError, match="limit"):
        jog.wait()


def test_an_async_wait_is_not_refused_another_task_may_stop_the_jog() -> None:
    async def body() -> int:
        async with await aio.connect("sim://DMC-4040") as c:
            jog = await c.A.jog(5000)
            waiting = asyncio.ensure_future(jog.wait())
            await c.sleep(0.1)
            await jog.stop()
            result = await waiting
            return result.stop_codes["A"]

    assert asyncio.run(asyncio.wait_for(body(), 30)) == 4


def test_on_a_real_clock_the_wait_goes_on_until_the_jog_is_stopped() -> None:
    with simulated("DMC-4040", clock="real") as dmc:
        jog = dmc.A.jog(5000)
        stopper = threading.Timer(0.2, dmc.A.stop)
        stopper.start()
        try:
            result = jog.wait()  # (no timeout: for ever, until another thread stops it)
        finally:
            stopper.join()
        assert result.stop_codes == {"A": 4}
