"""Every argument in seconds takes a time Quantity too, sync and async alike: ``0.1 * ureg.s``
or ``100 * ureg.ms`` is converted to seconds; a Quantity of another dimension is refused with
InvalidArgument naming the parameter and the dimension expected, before a byte is sent.

Before: ``dmc.sleep(0.1 * s)`` said "seconds must be a finite number of seconds >= 0 ... not
<Quantity(0.1, 'second')>", and so did ``wait(timeout=5 * s)`` and ``capture(seconds=0.1 * s)``,
while the library took Quantities everywhere else.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from aio_helpers import run, sim
from test_wait_timeouts_sync_and_async import ASYNC, SYNC

import galil
from galil.testing import nothing_sent, simulated
from galil.units import ureg

s, ms, mm = ureg.s, ureg.ms, ureg.mm

#: Waits that end at once on an idle simulator given 20 ms (the rest may time out: that is
#: their answer to the timeout, not a refusal of it).
TAKEN = 20 * ms


def _sync_outcome(what: str, timeout: object) -> BaseException | None:
    start, wait, _ = SYNC[what]
    with simulated() as dmc:
        target = start(dmc)
        try:
            wait(target, timeout)
        except Exception as exc:
            return exc
    return None


def _async_outcome(what: str, timeout: object) -> BaseException | None:
    start, wait, _ = ASYNC[what]
    outcome: list[BaseException | None] = [None]

    async def body() -> None:
        async with await sim() as c:
            target = await start(c)
            try:
                await wait(target, timeout)
            except Exception as exc:
                outcome[0] = exc

    run(body)
    return outcome[0]


@pytest.mark.parametrize("what", sorted(SYNC))
def test_a_time_quantity_is_taken_wherever_seconds_are_sync(what: str) -> None:
    error = _sync_outcome(what, TAKEN)
    assert not isinstance(error, galil.InvalidArgument), error


@pytest.mark.parametrize("what", sorted(ASYNC))
def test_a_time_quantity_is_taken_wherever_seconds_are_async(what: str) -> None:
    error = _async_outcome(what, TAKEN)
    assert not isinstance(error, galil.InvalidArgument), error


@pytest.mark.parametrize("what", sorted(SYNC))
def test_a_quantity_that_is_not_a_time_is_refused_naming_the_dimension(what: str) -> None:
    start, wait, named = SYNC[what]
    with simulated() as dmc:
        target = start(dmc)
        for bad in (5 * mm, 10 * ureg.Hz):
            with nothing_sent(dmc), pytest.raises(galil.InvalidArgument) as info:
                wait(target, bad)
            assert named in str(info.value)
            assert "must be a time such as 0.5 * ureg.s" in str(info.value)


def test_sleep_lets_the_time_of_a_quantity_pass() -> None:
    with simulated() as dmc:
        before = float(dmc.command("MG TIME"))
        dmc.sleep(250 * ms)
        dmc.sleep(0.25 * s)
        after = float(dmc.command("MG TIME"))
    assert after - before == pytest.approx(512, abs=3)  # samples at 1024 Hz


def test_a_capture_for_a_time_quantity_records_as_for_its_seconds() -> None:
    with simulated() as dmc:
        capture = dmc.capture(["_RPA"], seconds=100 * ms)
        assert capture.count == 53  # as for seconds=0.1: a value every 2 samples, both ends
        capture.wait()
        with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="must be a time"):
            dmc.capture(["_RPA"], seconds=5 * mm)


def test_a_watchdog_takes_its_timeout_and_interval_as_time_quantities() -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(2 * s, interval=200 * ms)
        assert (dog.timeout, dog.interval) == (2.0, 0.2)
        dog.stop()


def test_an_async_sleep_and_capture_take_time_quantities() -> None:
    async def body() -> Any:
        async with await sim() as c:
            await c.sleep(100 * ms)
            capture = await c.capture(["_RPA"], seconds=0.05 * s)
            return await capture.wait(timeout=2 * s)

    assert len(run(body)) > 0


def test_a_reconnect_policy_keeps_its_delays_in_seconds() -> None:
    policy = galil.ReconnectPolicy(delay=100 * ms, max_delay=2 * s)
    assert (policy.delay, policy.max_delay) == (0.1, 2.0)
    with pytest.raises(galil.InvalidArgument, match="delay"):
        galil.ReconnectPolicy(delay=3 * mm)


def test_an_async_wait_that_times_out_says_its_timeout_in_seconds_not_the_quantity() -> None:
    # Before: "thread 0 still runs after 100 millisecond s", "no ... within 100 millisecond s".
    async def body() -> list[str]:
        async with await sim() as c:
            await c.programs.download("#A\nWT 2000\nEN\n")
            await c.programs.run("#A")
            said = []
            for wait in (
                c.programs.wait(0, 100 * ms),
                c.messages.get(100 * ms),
                c.interrupts.get(100 * ms),
            ):
                with pytest.raises(galil.GalilTimeoutError) as info:
                    await wait
                said.append(str(info.value))
            await c.programs.halt()
            return said

    ran, message, interrupt = run(body)
    assert "thread 0 still runs after 0.1 s" in ran
    assert "no unsolicited message within 0.1 s" in message
    assert "no interrupt within 0.1 s" in interrupt


@pytest.mark.parametrize("thread", [5, np.int64(5), np.int32(5)])
def test_a_watchdog_takes_its_thread_as_any_integer_sync_and_async(thread: object) -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5, thread=thread)  # type: ignore[arg-type]
        assert dog.thread == 5
        assert type(dog.thread) is int
        assert dog.running
        dog.stop()

    async def body() -> tuple[int, bool]:
        async with await sim() as c:
            dog = await c.watchdog(0.5, thread=thread)  # type: ignore[arg-type]
            running = await dog.running()
            await dog.stop()
            return dog.thread, running

    assert run(body) == (5, True)
