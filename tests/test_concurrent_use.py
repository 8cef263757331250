"""One Controller shared between threads, as a lab GUI or a RunEngine beside a monitor uses it.

The races are made deterministic: a thread is paused at a chosen point (right after one of its
link calls, outside the link's lock), another thread acts meanwhile, and the first one goes on
once the second has finished or is found waiting for the tracker's lock
(:attr:`galil.motion.MotionTracker.lock`). Nothing here waits for motion in real time: the
in-process simulator's clock runs only while someone waits for it.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from concurrency import hammer

import galil
import galil.aio as aio
from galil.errors import GalilError, InvalidArgument, MotionError
from galil.sim.server import SimTcpServer
from galil.testing import simulated

SETTLE = 10.0  # seconds: a bound for a thread that is never expected to take it


class _WatchedLock:
    """The tracker's lock, telling when a thread has to wait for it."""

    def __init__(self, contended: threading.Event) -> None:
        self._lock = threading.RLock()
        self._contended = contended

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        if self._lock.acquire(blocking=False):
            return True
        self._contended.set()
        return self._lock.acquire(blocking, timeout)

    def release(self) -> None:
        self._lock.release()

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


class Interleaving:
    """Thread ``first`` runs until just after a chosen link call; ``second`` runs meanwhile.

    ``pause_after(method, when)`` wraps ``controller.link.<method>`` (``on``'s method, given
    ``on``): the first call that ``when(args)`` accepts, made on the ``first`` thread,
    returns its result only once the ``second`` thread has finished or waits for the
    tracker's lock.
    """

    def __init__(self, c: galil.Controller, monkeypatch: pytest.MonkeyPatch) -> None:
        self.c = c
        self._monkeypatch = monkeypatch
        self._reached = threading.Event()
        self._settled = threading.Event()  # the second thread finished or waits for the lock
        self._go = threading.Event()
        self.results: dict[str, Any] = {}
        self.lines: dict[str, list[str]] = {"first": [], "second": []}
        monkeypatch.setattr(c.tracker, "lock", _WatchedLock(self._settled), raising=False)
        c.wire_log.add(self._record)

    def _record(self, direction: str, data: bytes) -> None:
        who = threading.current_thread().name
        if direction == "out" and who in self.lines:
            self.lines[who] += [p for p in data.decode("latin-1").split("\r") if p]

    def pause_after(
        self, method: str, when: Callable[[tuple[Any, ...]], bool], on: object = None
    ) -> None:
        target = self.c.link if on is None else on  # (or the tracker, say)
        real = getattr(target, method)

        def paused(*args: Any, **kwargs: Any) -> Any:
            out = real(*args, **kwargs)
            mine = threading.current_thread().name == "first"
            if mine and not self._reached.is_set() and when(args):
                self._reached.set()
                assert self._go.wait(SETTLE)
            return out

        self._monkeypatch.setattr(target, method, paused)

    def run(self, first: Callable[[], Any], second: Callable[[], Any]) -> dict[str, Any]:
        """Run both; return what each returned or raised, by name."""
        t1 = threading.Thread(target=self._call, args=("first", first), name="first")
        t1.start()
        assert self._reached.wait(SETTLE), "the first thread never reached its pause"
        t2 = threading.Thread(target=self._call, args=("second", second), name="second")
        t2.start()
        assert self._settled.wait(SETTLE)
        self._go.set()
        t1.join(SETTLE)
        t2.join(SETTLE)
        assert not t1.is_alive()
        assert not t2.is_alive()
        return self.results

    def _call(self, name: str, fn: Callable[[], Any]) -> None:
        try:
            self.results[name] = fn()
        except Exception as exc:  # reported by the test
            self.results[name] = exc
        finally:
            if name == "second":
                self._settled.set()


def _names(args: tuple[Any, ...]) -> list[str]:
    return list(args[0])


def _line(args: tuple[Any, ...]) -> str:
    return ";".join(cmd.text for cmd in args[0])


@pytest.fixture
def c() -> Iterator[galil.Controller]:
    """A DMC-4040 simulator (manual clock), axes A-D at 10000 counts/s, 100000 counts/s²."""
    with simulated("DMC-4040") as dmc:
        for a in "ABCD":
            axis = dmc.axis(a)
            axis.speed = 10_000
            axis.accel = axis.decel = 100_000
        yield dmc


def _result_of(handle: galil.MoveHandle) -> galil.MoveResult:
    """The handle's result; a prediction that missed the end fails the test (the warning)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        return handle.wait(10)


# ----------------------------------------------------------- two starts on one axis at once


def test_a_move_started_between_anothers_state_read_and_its_line_is_refused_unsent(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: both read A idle; the later line was rejected by the controller (TC 21 said
    of ``PAA=...``: "Begin not valid while running"). Now the second waits for the first's
    handle, then is refused as busy with nothing but its state read sent."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: "_BGA" in _names(args))
    got = run.run(lambda: c.A.move_by(1000), lambda: c.A.move_by(2000))
    assert isinstance(got["first"], galil.MoveHandle), got
    assert isinstance(got["second"], InvalidArgument), got
    assert "already moving" in str(got["second"])
    assert all(line.startswith("MG _") for line in run.lines["second"]), run.lines
    assert _result_of(got["first"]).final == {"A": 1000}


def test_an_increment_never_lands_on_a_move_another_thread_started_meanwhile(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: ``IPA=1000`` went to the other thread's move (accepted: it lengthened it), both
    calls returned handles, the first one's prediction was 1000 counts short and the tracker
    lost it. Now one of them is refused."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: "_SPA" in _names(args))  # execute_move's
    got = run.run(lambda: c.A.increment(1000), lambda: c.A.move_by(2000))
    assert isinstance(got["first"], galil.MoveHandle), got
    assert isinstance(got["second"], InvalidArgument), got
    assert not any(("PAA=" in ln or "IPA=" in ln) for ln in run.lines["second"]), run.lines
    assert _result_of(got["first"]).final == {"A": 1000}
    assert c.tracker.active("A") is None


def test_a_second_jog_changes_the_first_ones_speed_through_its_handle(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the later ``JGA=5000;BG A`` line changed the other thread's jog (JG accepted)
    and failed at ``BG`` (TC 21): half sent, the running jog's handle not told. Now the
    second jog finds the first running and changes its speed as a jog in progress does."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: "_BGA" in _names(args))
    got = run.run(lambda: c.A.jog(-3000), lambda: c.A.jog(5000))
    assert isinstance(got["first"], galil.MoveHandle), got
    assert got["second"] is got["first"], got
    c.sleep(0.5)
    handle = got["first"]
    assert c.query_number("MG _TVA") == pytest.approx(5000, abs=10)
    c.stop("A")
    result = _result_of(handle)
    assert result.stop_codes == {"A": 4}
    assert result.deviation == {"A": 0}  # the prediction followed both JGs and the stop


def test_two_speed_schedules_at_once_one_is_refused_before_its_download(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: both read thread 0 free; the second's download (same label) replaced the first's
    routine between the first's download and its ``XQ``, ran, and the first's ``XQ`` came
    back as TC 19 ("Application strand already executing"). Now the second waits and is
    refused: thread 0 runs the first schedule; nothing of it is downloaded."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("command_line", lambda args: _line(args).startswith("gsbegin"))
    got = run.run(
        lambda: c.A.speed_schedule(4000, [(2000, 5000)]),
        lambda: c.B.speed_schedule(6000, [(3000, 4000)]),
    )
    assert isinstance(got["first"], galil.MoveHandle), got
    assert isinstance(got["second"], InvalidArgument), got
    assert "thread 0" in str(got["second"])
    assert not any(line.startswith(("DL", "XQ")) for line in run.lines["second"]), run.lines
    assert _result_of(got["first"]).final == {"A": 4000}
    assert c.B.reference_position == 0


# ---------------------------------------------- a stop between a start's line and its handle


def test_a_stop_from_another_thread_reaches_a_move_being_started(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the stop fell between the move's line and its handle: the handle predicted
    the whole move and its end missed by 20000 counts (a RuntimeWarning). Now the stop waits
    for the handle, which follows it."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("command_line", lambda args: "BG" in _line(args))
    got = run.run(lambda: c.A.move_by(20_000), lambda: c.stop())
    handle = got["first"]
    assert isinstance(handle, galil.MoveHandle), got
    assert got["second"] is None
    result = _result_of(handle)
    assert result.stop_codes == {"A": 4}
    assert result.deviation == {"A": 0}


def test_a_stop_from_another_thread_cancels_a_schedule_being_started(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: a stop right after the schedule's ``XQ`` did not reach its handle: its
    prediction missed the end by 40000 counts and its cancellation (halt the routine, put
    ``SP`` back) never ran."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("command_line", lambda args: _line(args).startswith("XQ"))
    got = run.run(
        lambda: c.A.speed_schedule(40_000, [(20_000, 20_000)], speed=5000), lambda: c.stop()
    )
    handle = got["first"]
    assert isinstance(handle, galil.MoveHandle), got
    assert _result_of(handle).stop_codes == {"A": 4}
    assert c.query_number("MG _XQ0") < 0  # the routine halted
    assert c.query_number("MG _SPA") == 10_000  # back as before the schedule


# ----------------------------------------------------------------- callbacks that call back


def test_move_callbacks_that_fail_are_logged_and_the_wait_still_returns(
    c: galil.Controller, caplog: pytest.LogCaptureFixture
) -> None:
    """Before: the first failing callback's error came out of ``wait()`` (or killed the
    watcher thread, or stood in for the move's result as its ``GalilError``) and the
    callbacks after it never ran."""
    seen: list[str] = []

    def fails(h: galil.MoveHandle) -> None:
        raise GalilError("a callback's own mistake")

    handle = c.A.move_by(1000)
    handle.add_callback(fails)
    handle.add_callback(lambda h: seen.append("second"))
    with caplog.at_level(logging.ERROR, logger="galil.motion"):
        assert _result_of(handle).final == {"A": 1000}
        handle.add_callback(fails)  # (done already: called at once, logged too)
    assert seen == ["second"]
    failures = [r for r in caplog.records if "callback" in r.getMessage()]
    assert len(failures) == 2
    assert all(r.exc_info and "own mistake" in str(r.exc_info[1]) for r in failures)


def test_callbacks_call_back_into_the_controller_from_their_threads() -> None:
    """Over TCP (real time: the watcher, message and record threads run): a move's
    done-callback, a message subscriber and a data-record callback each query, start a short
    move and wait for it, and stop an axis, from the thread that delivers to them."""
    done = {name: threading.Event() for name in ("move", "message", "record")}
    where: dict[str, str] = {}
    errors: list[BaseException] = []

    def calls_back(c: galil.Controller, name: str, axis: str) -> Callable[[object], None]:
        def callback(_: object) -> None:
            if name in where:
                return
            where[name] = threading.current_thread().name
            try:
                assert c.query_number("MG 7") == 7
                c.axis(axis).move_by(20).wait(5)
                c.stop(axis)
            except BaseException as exc:  # reported below
                errors.append(exc)
            done[name].set()

        return callback

    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as c:
        for a in "BCD":
            c.axis(a).speed, c.axis(a).accel, c.axis(a).decel = 10_000, 1e6, 1e6
        c.A.speed = 10_000
        handle = c.A.move_by(20)
        handle.add_callback(calls_back(c, "move", "B"))
        unsubscribe = c.subscribe(calls_back(c, "message", "C"))
        with c.records(64) as stream:
            stream.subscribe(calls_back(c, "record", "D"))
            c.programs.download('#A\nMG "hello"\nEN')
            c.programs.run()
            for name, event in done.items():
                assert event.wait(SETTLE), name
        unsubscribe()
        assert errors == []
        assert c.query_operands(["_RPB", "_RPC", "_RPD"]) == [20, 20, 20]
    assert "MainThread" not in where.values(), where


# ------------------------------------------------------ a stop during a multi-exchange stream


@pytest.mark.parametrize("how", ["stop", "abort"])
def test_a_stop_from_another_thread_ends_a_contour_with_a_motion_error(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """Before: the next ``CD`` line was refused (TC 41, "Contouring record range error"),
    raised as a ``CommandError`` that did not say what happened."""
    run = Interleaving(c, monkeypatch)
    polls = [0]

    def third_poll(args: tuple[Any, ...]) -> bool:
        if _names(args)[:2] == ["_CM", "_TC"]:  # (then the stop codes)
            polls[0] += 1
        return polls[0] == 3

    run.pause_after("query_operands", third_poll)
    path = np.cumsum(np.full(3000, 20.0))
    got = run.run(lambda: c.contour("A", path, dt=2), c.stop if how == "stop" else c.abort)
    error = got["first"]
    assert isinstance(error, MotionError), got
    assert ("ST" if how == "stop" else "AB") in str(error)
    assert "segments" in str(error)
    assert c.query_number("MG 12345") == 12345  # the link in step
    assert c.query_number("MG _BGA") == 0
    c.A.move_by(100).wait(5)  # out of contour mode: an ordinary move runs


def test_a_stop_from_another_thread_ends_a_streamed_vector_path(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A path longer than the buffer, stopped while it streams: the call returns its handle,
    stopped, with nothing sent after the stop."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: "_LMS" in _names(args))
    segments = [galil.Line(10, 5 if i % 2 else -5) for i in range(700)]
    got = run.run(lambda: c.vector_move("AB", segments, speed=20_000), c.stop)
    handle = got["first"]
    assert isinstance(handle, galil.MoveHandle), got
    assert handle.stopped
    after = run.lines["first"][-1:]
    assert not any(line.startswith(("LI", "VE", "LE")) for line in after), run.lines["first"]
    handle.wait(10)
    assert c.query_number("MG 12345") == 12345


# ------------------------------------------- a check at rest or motor off, and its setting's line


def test_a_servo_here_from_another_thread_waits_for_a_motor_type_set_with_the_motor_off(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: ``SH`` fell between the ``_MOA`` read that found the motor off and the ``MT``
    line, which the controller refused (TC 135, a plain ``CommandError``). Now ``SH`` waits
    for the line: both go through."""
    c.motor_off("A")
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: "_MOA" in _names(args))
    stepper = galil.MotorType.STEPPER_ACTIVE_LOW
    got = run.run(lambda: setattr(c.A, "motor_type", stepper), lambda: c.servo_here("A"))
    assert got == {"first": None, "second": None}, got
    assert c.A.motor_type is stepper
    assert c.query_number("MG _MOA") == 0


@pytest.mark.parametrize(
    ("name", "value"), [("brush", 1), ("encoder_config", galil.EncoderConfig(main=2))]
)
def test_a_move_from_another_thread_waits_for_a_setting_checked_at_rest(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch, name: str, value: object
) -> None:
    """Before: a move started between the check that found A at rest and the ``BR``/``CE``
    line, which the controller refused (TC 7, a plain ``CommandError``, the setting lost).
    Now the move waits for the line: both go through."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("active", lambda args: args == ("A",), on=c.tracker)
    got = run.run(lambda: setattr(c.A, name, value), lambda: c.A.move_by(1000))
    assert got["first"] is None, got
    assert isinstance(got["second"], galil.MoveHandle), got
    assert getattr(c.A, name) == value
    assert _result_of(got["second"]).final == {"A": 1000}


def test_a_move_from_another_thread_waits_for_a_motor_off_checked_at_rest(
    c: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: a move started between ``MO``'s ``_BGA`` read and its line, which the
    controller refused (TC 7, a plain ``CommandError``) and A kept moving. Now the move waits
    and is refused unsent: the motor is off."""
    run = Interleaving(c, monkeypatch)
    run.pause_after("query_operands", lambda args: _names(args) == ["_BGA"])
    got = run.run(lambda: c.motor_off("A"), lambda: c.A.move_by(1000))
    assert got["first"] is None, got
    assert isinstance(got["second"], InvalidArgument), got
    assert "motor off" in str(got["second"])
    assert all(line.startswith("MG _") for line in run.lines["second"]), run.lines
    assert c.query_number("MG _MOA") == 1


# ------------------------------------------------------------- three threads, two axes at once


def test_moves_jogs_and_polls_from_three_threads_each_get_their_own(c: galil.Controller) -> None:
    """A moves and waits in one thread, B jogs and stops in another, a third polls: every
    reply goes to its caller, every handle's end is its prediction, the tracker ends idle."""
    errors: list[str] = []
    rounds = 12

    def mover() -> None:
        for i in range(rounds):
            result = _result_of(c.A.move_by(500 + 10 * i))
            if result.deviation != {"A": 0}:
                errors.append(f"A {i}: {result}")

    def jogger() -> None:
        for i in range(rounds):
            handle = c.B.jog(3000 if i % 2 else -3000)
            c.sleep(0.01)
            handle.stop()
            result = _result_of(handle)
            if result.stop_codes != {"B": 4} or result.deviation != {"B": 0}:
                errors.append(f"B {i}: {result}")

    def guarded(fn: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                fn()
            except Exception as exc:  # reported below
                errors.append(repr(exc))

        return run

    pool = [threading.Thread(target=guarded(f)) for f in (mover, jogger)]
    for t in pool:
        t.start()
    errors += hammer(c, threads=2, per_thread=60)
    for t in pool:
        t.join(60)
    assert errors == []
    assert c.A.reference_position == sum(500 + 10 * i for i in range(rounds))
    assert c.tracker.active("A") is None
    assert c.tracker.active("B") is None


# -------------------------------------------------------- the async API beside the sync one


def test_the_async_api_on_the_loop_and_the_sync_one_on_a_thread_share_a_controller() -> None:
    """Decision 0012: the async controller runs the thread-safe sync core on worker threads,
    so its ``sync`` controller may be used from another thread at the same time."""

    async def body() -> None:
        ac = await aio.connect("sim://DMC-4040")
        try:
            sync = ac.sync
            for a in "AB":
                sync.axis(a).speed = 10_000
                sync.axis(a).accel = sync.axis(a).decel = 100_000
            seen: list[Any] = []

            def other_thread() -> None:
                handle = sync.B.jog(4000)
                sync.sleep(0.05)
                sync.B.stop()
                seen.append(_result_of(handle))
                seen.extend(hammer(sync, threads=1, per_thread=20))

            t = threading.Thread(target=other_thread)
            t.start()
            results = []
            for _ in range(3):
                results.append(await (await ac.A.move_by(1000)))
            await asyncio.get_running_loop().run_in_executor(None, t.join, 30)
            assert [r.deviation for r in results] == [{"A": 0}] * 3
            assert len(seen) == 1  # (and no mismatched poll)
            assert seen[0].stop_codes == {"B": 4}
            assert await ac.query_number("MG _RPA") == 3000
        finally:
            await ac.aclose()

    asyncio.run(asyncio.wait_for(body(), 30))
