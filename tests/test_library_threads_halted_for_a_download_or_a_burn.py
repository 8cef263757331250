"""The library's threads halted for a download or a burn (decisions 0087, 0094): whatever came
of it, the routines that ran run again with a fresh heartbeat; a thread whose ``XQ`` the
controller refused is forgotten and said; one whose ``XQ`` may have gone out stays held."""

from __future__ import annotations

import logging
from collections.abc import Callable

import pytest
from client_fakes import Interrupt, pull_cable_after
from program_helpers import input_wait_started

import galil
from galil.testing import sim_of, simulated
from galil.watchdog import Watchdog

_USER = "#MAIN\nWT 10\nEN\n"

#: What downloads a program with the watchdog running: the user's, and an input wait's
#: routine (installed beside it).
_DOWNLOADS: dict[str, Callable[[galil.Controller], object]] = {
    "programs.download": lambda dmc: dmc.programs.download(_USER),
    "io.wait_for_input": lambda dmc: dmc.io.wait_for_input(2, high=False, timeout=0.1),
}
_BURNS: dict[str, Callable[[galil.Controller], object]] = {
    "save": lambda dmc: dmc.save(),
    "save_program": lambda dmc: dmc.save_program(),
}


def _on_write(dmc: galil.Controller, change: Callable[[bytes], bytes]) -> Callable[[], None]:
    """Pass every write through ``change`` (which may raise, as a Ctrl-C would); return what
    puts the link's own write back."""
    transport = dmc.link.transport
    assert transport is not None
    write = transport.write

    def changed(data: bytes) -> None:
        write(change(data))

    transport.write = changed  # type: ignore[method-assign]

    def undo() -> None:
        transport.write = write  # type: ignore[method-assign]

    return undo


def _failing(dmc: galil.Controller, command: bytes, failure: str) -> Callable[[bytes], bytes]:
    """A change that fails ``command``'s write after the host was silent for a second (the
    library's threads halted): a download with a line too long (the controller refuses it:
    TC 60), or a Ctrl-C before the line goes out."""

    def change(data: bytes) -> bytes:
        if command + b"\r" not in data:
            return data
        sim_of(dmc).advance(1.0)  # (the host silent, longer than the watchdog's timeout)
        if failure == "interrupted":
            raise Interrupt
        assert command == b"DL"
        return b"DL\r'" + b"x" * 100 + data[2:]  # (a comment line past 80 characters)

    return change


_FAILURES: dict[str, type[BaseException]] = {
    "refused": galil.CommandError,
    "interrupted": Interrupt,
}


def _guards_with_a_fresh_heartbeat(dmc: galil.Controller, dog: Watchdog) -> None:
    """The routine runs, measures the host's silence from a beat of its restart, and stops
    a jog once the host is silent beyond its timeout."""
    assert dog.running
    assert dog.beating
    fired_at_once = dog.fired  # (measured from a beat before the halt, it would have)
    assert not fired_at_once
    jog = dmc.A.jog(20_000)
    dmc.sleep(1.0)  # the host beats on: the jog goes on
    assert dmc.A.moving
    sim_of(dmc).advance(dog.timeout + 0.3)  # the host silent beyond the timeout
    assert not sim_of(dmc).motion("A").moving
    assert dog.fired
    assert jog.done


@pytest.mark.parametrize("failure", sorted(_FAILURES))
@pytest.mark.parametrize("download", sorted(_DOWNLOADS))
def test_a_download_that_fails_leaves_the_watchdog_running_with_a_fresh_heartbeat(
    download: str, failure: str
) -> None:
    with simulated() as dmc:
        dmc.programs.download("#A\nEN\n")
        dog = dmc.watchdog(0.2)
        undo = _on_write(dmc, _failing(dmc, b"DL", failure))
        with pytest.raises(_FAILURES[failure]):
            _DOWNLOADS[download](dmc)
        undo()
        assert dmc.programs.upload() == "#A\nEN"  # (the controller kept its program)
        _guards_with_a_fresh_heartbeat(dmc, dog)


@pytest.mark.parametrize("burn", sorted(_BURNS))
def test_a_burn_cut_short_leaves_the_watchdog_running_with_a_fresh_heartbeat(burn: str) -> None:
    """Decision 0087, kept: a burn starts the library's threads again whatever came of it."""
    with simulated() as dmc:
        dog = dmc.watchdog(0.2)
        command = b"BN" if burn == "save" else b"BP"
        undo = _on_write(dmc, _failing(dmc, command, "interrupted"))
        with pytest.raises(Interrupt):
            _BURNS[burn](dmc)
        undo()
        _guards_with_a_fresh_heartbeat(dmc, dog)


def _refuse_the_restart(data: bytes) -> bytes:
    # (the controller refuses an XQ of a label it does not hold)
    return data.replace(b"XQ #GWDOG,7", b"XQ #GWNOT,7")


@pytest.mark.parametrize("call", sorted(_BURNS.keys() | {"programs.download"}))
def test_a_library_thread_whose_restart_is_refused_is_forgotten_and_said(
    call: str, caplog: pytest.LogCaptureFixture
) -> None:
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        undo = _on_write(dmc, _refuse_the_restart)
        with (
            caplog.at_level(logging.WARNING, logger="galil"),
            pytest.raises(galil.CommandError) as info,
        ):
            {**_BURNS, **_DOWNLOADS}[call](dmc)
        undo()
        assert info.value.command == "XQ #GWDOG,7"
        assert info.value.code == 10  # (undefined label)
        assert not dog.running
        dmc.programs.download(_USER)
        dmc.programs.run("#MAIN", thread=7)  # (the library's no more: not refused)
        assert dmc.programs.threads.keys() == {7}  # the user's, not taken for the library's
        dmc.programs.halt()
        what = {"save": "BN", "save_program": "BP"}.get(call, "DL")
        assert (
            f"thread 7 (#GWDOG: the watchdog), halted for {what}, was not started again: its "
            "XQ was refused"
        ) in caplog.text
        assert "nothing guards the motion: start a new watchdog" in caplog.text


def test_the_library_threads_after_one_whose_restart_is_refused_are_started_again(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Two of the library's routines halted for a burn (an input wait's on thread 7, the
    watchdog's on 6): the wait's XQ refused, the watchdog still starts again."""
    with simulated() as dmc:
        waiting, ended = input_wait_started(dmc, timeout=2)
        dog = dmc.watchdog(0.5)
        assert dog.thread == 6
        undo = _on_write(dmc, lambda data: data.replace(b"XQ #GINWAIT,7", b"XQ #GWNOT,7"))
        with caplog.at_level(logging.WARNING, logger="galil"), pytest.raises(galil.CommandError):
            dmc.save()
        undo()
        assert dog.running  # (before: never started again, the restart ended at thread 7)
        assert "thread 7 (#GINWAIT: wait_for_input), halted for BN" in caplog.text
        assert 7 not in dmc.routines.threads
        waiting.join(10.0)
        assert len(ended) == 1
        assert isinstance(ended[0], galil.GalilTimeoutError)  # (its routine no longer ran)
        _guards_with_a_fresh_heartbeat(dmc, dog)


@pytest.mark.parametrize("call", sorted(_BURNS.keys() | {"programs.download"}))
def test_a_library_thread_whose_restart_may_have_gone_out_stays_held_and_is_halted_later(
    call: str,
) -> None:
    """The link died as the restart's XQ went out: the routine runs on the controller, so the
    library still holds its thread (as ``Routines.start`` does: decision 0076), and the
    watchdog's stop halts it once the link is reopened, before it fires on new motion."""
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        pull_cable_after(dmc.link.transport, b"XQ #GWDOG,7")
        with pytest.raises(galil.GalilConnectionError):
            {**_BURNS, **_DOWNLOADS}[call](dmc)
        dog.stop()  # the HX cannot go out now
        assert dog.halt_pending
        dmc.reconnect()
        assert dmc.query_operands(["_XQ7"]) == [-1]
        jog = dmc.A.jog(20_000)
        dmc.sleep(1.0)  # no heartbeat since the stop: a routine left running fires
        assert dmc.A.moving
        assert not dog.fired
        jog.stop()


def _pull_cable_before(dmc: galil.Controller, command: bytes) -> None:
    """The cable is pulled as ``command``'s line is about to go out: the write fails, the
    link is dead, and nothing of the line reached the controller."""
    transport = dmc.link.transport
    assert transport is not None
    write = transport.write

    def dying(data: bytes) -> None:
        if command + b"\r" in data or data.startswith(command):
            transport.close()
        write(data)

    transport.write = dying  # type: ignore[method-assign]


@pytest.mark.parametrize("call", sorted(_BURNS.keys() | {"programs.download"}))
def test_a_watchdog_halted_for_a_download_or_a_burn_the_link_died_under_guards_after_reconnect(
    call: str, caplog: pytest.LogCaptureFixture
) -> None:
    """The link died before the download's or the burn's line went out: the restart's XQ
    cannot go out either, so it is "not sent" (not "fate unknown"), the library keeps the
    thread, and reconnect() starts the routine again with a fresh heartbeat: it guards."""
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        _pull_cable_before(dmc, {"save": b"BN", "save_program": b"BP"}.get(call, b"DL"))
        with (
            caplog.at_level(logging.WARNING, logger="galil.routines"),
            pytest.raises(galil.GalilConnectionError),
        ):
            {**_BURNS, **_DOWNLOADS}[call](dmc)
        assert dmc.link.dead
        said = [r.getMessage() for r in caplog.records if r.name == "galil.routines"]
        assert any("XQ was not sent (the link is dead)" in m and "reconnect()" in m for m in said)
        assert not any("fate is unknown" in m for m in said)
        sim_of(dmc).advance(1.0)  # the host silent longer than the timeout, the routine halted
        dmc.reconnect()
        assert "beating" in repr(dog)
        assert "not running" not in repr(dog)
        _guards_with_a_fresh_heartbeat(dmc, dog)
