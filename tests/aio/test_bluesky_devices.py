"""galil.bluesky under a real bluesky RunEngine, against the simulator served over TCP.

The simulator runs in real time here (a RunEngine waits on the wall clock); moves are made
short with high speeds so the whole file takes a few seconds.
"""

from __future__ import annotations

import asyncio
import math
import re
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from typing import Any, TypeVar

import numpy as np
import pytest

pytest.importorskip("ophyd_async")

import bluesky.plan_stubs as bps
import bluesky.plans as bp
from bluesky import RunEngine
from bluesky.run_engine import RunEngineInterrupted, call_in_bluesky_event_loop
from client_fakes import pull_cable_after
from ophyd_async.core import soft_signal_rw

import galil
from galil.bluesky import ContourPath, GalilContourFlyer, GalilMotor, release_all
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, sim_of
from galil.units import ureg

mm, s = ureg.mm, ureg.s
T = TypeVar("T")
Docs = list[tuple[str, dict[str, Any]]]


def in_loop(coro: Coroutine[Any, Any, T]) -> T:
    return call_in_bluesky_event_loop(coro)  # type: ignore[no-any-return]


@pytest.fixture
def server() -> Iterator[SimTcpServer]:
    with SimTcpServer() as srv:
        yield srv


@pytest.fixture
def engine() -> Iterator[RunEngine]:
    run_engine = RunEngine({}, context_managers=[])
    yield run_engine
    in_loop(release_all())
    run_engine.loop.call_soon_threadsafe(run_engine.loop.stop)
    run_engine._th.join(5)
    run_engine.loop.close()


@pytest.fixture
def docs(engine: RunEngine) -> Docs:
    out: Docs = []
    engine.subscribe(lambda name, doc: out.append((name, doc)))
    return out


def motor(url: str, name: str = "x", speed: float = 200.0) -> GalilMotor:
    m = GalilMotor(url, "A", name=name, scale=2000 / mm)
    in_loop(m.connect())
    in_loop(m.axis.set_speed(speed * mm / s))
    in_loop(m.axis.set_accel(5000 * mm / s**2))
    in_loop(m.axis.set_decel(5000 * mm / s**2))
    return m


def detector() -> Any:
    det = soft_signal_rw(float, 1.0, name="det")
    in_loop(det.connect())
    return det


def events(docs: Docs, key: str) -> list[float]:
    return [d["data"][key] for name, d in docs if name == "event"]


def test_a_scan_reads_back_every_position_in_user_units(
    server: SimTcpServer, engine: RunEngine, docs: Docs
) -> None:
    x = motor(server.url)
    engine(bp.scan([detector()], x, 0, 10, 5))
    one_count = 0.0005 + 1e-9
    assert events(docs, "x") == pytest.approx([0, 2.5, 5, 7.5, 10], abs=one_count)
    descriptor = next(d for name, d in docs if name == "descriptor")
    assert descriptor["data_keys"]["x"]["units"] == "mm"
    assert descriptor["data_keys"]["x"]["precision"] == 4
    assert descriptor["hints"]["x"]["fields"] == ["x"]


def test_a_relative_scan_moves_around_where_the_motor_is(
    server: SimTcpServer, engine: RunEngine, docs: Docs
) -> None:
    x = motor(server.url)
    engine(bps.mv(x, 4))
    engine(bp.rel_scan([detector()], x, -1, 1, 3))
    assert events(docs, "x") == pytest.approx([3, 4, 5], abs=0.0006)
    assert in_loop(x.locate())["readback"] == pytest.approx(4, abs=0.0006)  # back at the start


def test_mv_reports_progress_from_the_prediction(server: SimTcpServer, engine: RunEngine) -> None:
    x = motor(server.url, speed=50.0)
    updates: list[dict[str, Any]] = []

    def hook(statuses: Any) -> None:
        for st in statuses or ():
            if hasattr(st, "watch"):  # the move's; not the stage and read statuses
                st.watch(lambda **kw: updates.append(kw))

    engine.waiting_hook = hook
    engine(bps.mv(x, 5))
    # The first and the last update at least (a 0.11 s move over a real-time TCP server: on a
    # loaded machine the polls between them can be few or none).
    assert len(updates) >= 2
    first, last = updates[0], updates[-1]
    assert first["unit"] == "mm"
    assert first["precision"] == 4
    assert first["target"] == 5
    assert first["initial"] == pytest.approx(0, abs=0.001)
    # Known from the first update: 5 mm at 50 mm/s with 10 ms ramps, as predicted.
    assert first["time_elapsed"] + first["time_remaining"] == pytest.approx(0.11, abs=0.005)
    left = [u["time_remaining"] for u in updates]
    assert left == sorted(left, reverse=True)
    assert left[-1] == 0
    assert last["fraction"] == 1.0
    assert last["current"] == pytest.approx(5, abs=0.001)
    loc = in_loop(x.locate())
    assert loc["setpoint"] == 5
    assert loc["readback"] == pytest.approx(5, abs=0.001)


@pytest.mark.parametrize("display", [None, "VF 1.0"])  # a program's VF: reads stay exact
def test_a_fly_scan_returns_the_recorded_points_beside_the_prediction(
    server: SimTcpServer, engine: RunEngine, docs: Docs, display: str | None
) -> None:
    if display is not None:
        server.controller.feed(display.encode() + b"\r")
    flyer = GalilContourFlyer(server.url, "A", name="fly", scales={"A": 2000 / mm})
    in_loop(flyer.connect())
    path = np.linspace(0.1, 3.2, 32) * mm  # 32 segments of 8 samples

    def fly() -> Any:
        yield from bps.open_run()
        yield from bps.prepare(flyer, ContourPath(path, dt=3), wait=True)
        yield from bps.kickoff(flyer, wait=True)
        yield from bps.complete(flyer, wait=True)
        yield from bps.collect(flyer)
        yield from bps.close_run()

    engine(fly())
    assert flyer.predicted["A"].samples == 32 * 8
    page = next(d for name, d in docs if name == "event_page")
    data = page["data"]
    samples = np.array(data["fly-sample"])
    assert np.all(np.diff(samples) == 8)  # one record per segment
    assert len(samples) >= 32
    assert data["fly-A-reference"] == pytest.approx(data["fly-A-predicted"], abs=1e-9)
    assert data["fly-A-predicted"][-1] == pytest.approx(3.2)
    # The encoder follows the reference through the simulator's 3 ms servo lag: at the path's
    # 12.4 mm/s it trails by up to 0.04 mm when the last record is taken.
    assert data["fly-A-position"][-1] == pytest.approx(3.2, abs=0.05)
    assert data["fly-A-position"][-1] <= data["fly-A-reference"][-1]
    descriptor = next(d for name, d in docs if name == "descriptor")
    assert descriptor["data_keys"]["fly-A-predicted"]["units"] == "mm"


def test_abort_in_the_middle_of_a_move_stops_the_axis(
    server: SimTcpServer, engine: RunEngine, docs: Docs
) -> None:
    x = motor(server.url, speed=20.0)
    moving = threading.Event()
    engine.waiting_hook = lambda sts: [
        st.watch(lambda **kw: moving.set()) for st in sts or () if hasattr(st, "watch")
    ]

    def abort_when_moving() -> None:
        if moving.wait(10):
            engine.abort("test")

    aborter = threading.Thread(target=abort_when_moving)
    aborter.start()
    with pytest.raises(RunEngineInterrupted):
        engine(bp.scan([detector()], x, 50, 100, 2))  # the first move, to 50 mm, takes 2.5 s
    aborter.join(10)
    stop = next(d for name, d in docs if name == "stop")
    assert stop["exit_status"] == "abort"
    assert any(text.startswith("ST") for _, text in server.controller.command_log)
    axis = x.axis

    async def settled() -> float:
        while await axis.moving():
            await x.controller.sleep(0.01)
        return float(await x.readback.get_value())

    assert 0 < in_loop(settled()) < 50
    assert in_loop(axis.stop_code())[0] == 4


def test_stop_with_failure_makes_the_move_fail(server: SimTcpServer, engine: RunEngine) -> None:
    x = motor(server.url, speed=20.0)

    async def body() -> BaseException | None:
        status = x.set(50)
        while not await x.axis.moving():
            await x.controller.sleep(0.005)
        await x.stop(success=False)
        try:
            await status
        except RuntimeError as exc:
            return exc
        return None

    error = in_loop(body())
    assert error is not None
    assert "was stopped" in str(error)


def test_a_target_beyond_a_soft_limit_is_refused_before_moving(
    server: SimTcpServer, engine: RunEngine
) -> None:
    x = motor(server.url)
    in_loop(x.axis.set_soft_limits((-5 * mm, 5 * mm)))
    with pytest.raises(galil.LimitError):
        in_loop(x.check_value(6))
    in_loop(x.check_value(4))
    assert not any(re.search(r"(^|;)BG", text) for _, text in server.controller.command_log)


def test_mock_mode_moves_a_simulator_instantly(engine: RunEngine, docs: Docs) -> None:
    x = GalilMotor("tcp://127.0.0.1:1", "A", name="x", scale=2000 / mm)
    y = GalilMotor("tcp://127.0.0.1:1", "B", name="y")
    in_loop(x.connect(mock=True))
    in_loop(y.connect(mock=True))
    assert x.controller is y.controller  # one simulated controller for one address
    engine(bp.grid_scan([detector()], x, 0, 1, 2, y, 0, 100, 2))
    assert events(docs, "x") == pytest.approx([0, 0, 1, 1], abs=0.0006)
    assert events(docs, "y") == pytest.approx([0, 100, 0, 100], abs=1)  # counts: no scale
    in_loop(x.disconnect())
    assert not y.controller.closed  # y still holds it
    in_loop(y.disconnect())


def mock_motor(address: str, name: str = "x") -> GalilMotor:
    """A motor on an in-process simulator (manual clock: moves take no wall-clock time)."""
    m = GalilMotor(address, "A", name=name, scale=2000 / mm)
    in_loop(m.connect(mock=True))
    in_loop(m.axis.set_speed(20 * mm / s))
    return m


def test_a_relative_scan_of_a_motor_moved_outside_bluesky_moves_around_where_it_is(
    engine: RunEngine, docs: Docs
) -> None:
    x = mock_motor("tcp://127.0.0.1:2")

    async def move_outside_bluesky() -> None:
        await (await x.axis.move_to(4 * mm))

    in_loop(move_outside_bluesky())
    assert in_loop(x.locate())["setpoint"] == 4
    engine(bp.rel_scan([detector()], x, -1, 1, 3))
    assert events(docs, "x") == pytest.approx([3, 4, 5], abs=0.0006)
    assert in_loop(x.locate()) == {"setpoint": 4, "readback": pytest.approx(4, abs=0.0006)}


async def _settled(x: GalilMotor) -> float:
    while await x.axis.moving():
        await x.controller.sleep(0.01)
    return float(await x.readback.get_value())


async def _failure_of(status: Any) -> BaseException | None:
    try:
        await status
    except RuntimeError as exc:
        return exc
    return None


@pytest.mark.parametrize("turns", [0, 1, 5])
def test_a_stop_before_the_move_has_begun_keeps_it_from_beginning(
    engine: RunEngine, turns: int
) -> None:
    x = mock_motor(f"tcp://127.0.0.1:{10 + turns}")

    async def body() -> BaseException | None:
        status = x.set(50)
        for _ in range(turns):  # the set task may have begun, not the move
            await asyncio.sleep(0)
        await x.stop(success=False)
        return await _failure_of(status)

    error = in_loop(body())
    assert error is not None
    assert "was stopped" in str(error)
    assert in_loop(_settled(x)) == 0
    sent = [text for _, text in sim_of(x.controller.sync).command_log]
    assert not any(re.search(r"(^|;)BG", text) for text in sent)


def test_a_stop_while_the_move_is_being_started_stops_it(engine: RunEngine) -> None:
    x = mock_motor("tcp://127.0.0.1:20")
    axis = x.axis
    start = axis.move_to

    async def stopped_on_the_way(target: Any) -> Any:
        await x.stop(success=False)  # its ST goes out before the move's BG
        return await start(target)

    axis.move_to = stopped_on_the_way  # type: ignore[method-assign]

    async def body() -> BaseException | None:
        return await _failure_of(x.set(50))

    error = in_loop(body())
    assert error is not None
    assert "was stopped" in str(error)
    sent = [text for _, text in sim_of(x.controller.sync).command_log]
    begin = next(i for i, t in enumerate(sent) if re.search(r"(^|;)BG", t))
    assert any(t.startswith("ST") for t in sent[begin:])
    assert in_loop(_settled(x)) < 1


def test_a_set_that_times_out_stops_the_axis(engine: RunEngine) -> None:
    x = mock_motor("tcp://127.0.0.1:3")

    async def body() -> float:
        with pytest.raises(galil.GalilTimeoutError):
            await x.set(50, timeout=0.05)
        return await _settled(x)

    assert in_loop(body()) < 5
    assert in_loop(x.axis.stop_code())[0] == 4


def test_a_set_whose_link_dies_mid_move_fails_and_the_axis_is_stopped(engine: RunEngine) -> None:
    x = mock_motor("tcp://127.0.0.1:4")
    link = x.controller.sync.link
    pull_cable_after(link.transport, b"MG _BGA,_RPA,_SCA")  # (mid-move, at the first poll)

    async def body() -> float:
        with pytest.raises(galil.GalilConnectionError, match="reopened and A stopped"):
            await x.set(50)  # 2.5 s at 20 mm/s
        return await _settled(x)

    assert in_loop(body()) < 50
    assert in_loop(x.axis.stop_code())[0] == 4
    assert not link.dead


@pytest.mark.parametrize("timeout", [math.inf, math.nan, -1, "5", True], ids=repr)
def test_a_bad_set_timeout_fails_the_status_before_anything_is_sent(
    engine: RunEngine, timeout: object
) -> None:
    # As every wait's timeout (galil.link.check_wait_timeout): before, the move began and
    # was stopped again (inf, NaN, -1), or "5" and True were taken for seconds.
    x = mock_motor("tcp://127.0.0.1:30")

    async def body() -> None:
        with nothing_sent(x.controller.sync), pytest.raises(galil.InvalidArgument, match="timeout"):
            await x.set(1, timeout=timeout)  # type: ignore[arg-type]

    in_loop(body())


@pytest.mark.parametrize("settle", [math.inf, math.nan, -1, "5", True, None], ids=repr)
def test_a_bad_settle_timeout_is_refused(settle: object) -> None:
    with pytest.raises(galil.InvalidArgument, match="settle_timeout"):
        GalilMotor("sim://DMC-4040", "A", settle_timeout=settle)  # type: ignore[arg-type]


def test_numpy_numbers_are_positions(engine: RunEngine, docs: Docs) -> None:
    x = mock_motor("tcp://127.0.0.1:4")
    engine(bp.list_scan([detector()], x, np.arange(3)))
    assert events(docs, "x") == pytest.approx([0, 1, 2], abs=0.0006)

    async def move(value: Any) -> None:
        await x.set(value)

    in_loop(move(np.float32(0.5)))
    assert in_loop(x.locate())["setpoint"] == 0.5
    with pytest.raises(galil.InvalidArgument):
        in_loop(move(True))


# -- the flyer takes turns with other threads and is stopped by close() ----------------------
class _Held:
    """Holds the first link call of one kind on the thread that makes it (the flyer's
    worker), until :meth:`go`; tells whether a thread has had to wait for the tracker's lock
    meanwhile."""

    def __init__(self, c: galil.Controller, monkeypatch: pytest.MonkeyPatch) -> None:
        self.reached = threading.Event()
        self.contended = threading.Event()
        self._go = threading.Event()
        real = c.tracker.lock
        contended = self.contended

        class Watched:
            def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
                if real.acquire(blocking=False):
                    return True
                contended.set()
                return real.acquire(blocking, timeout)

            def release(self) -> None:
                real.release()

            def __enter__(self) -> bool:
                return self.acquire()

            def __exit__(self, *exc: object) -> None:
                self.release()

        monkeypatch.setattr(c.tracker, "lock", Watched(), raising=False)
        self._c = c
        self._monkeypatch = monkeypatch

    def before(self, method: str, when: Callable[[Any], bool]) -> None:
        """Hold the first ``link.<method>(first, ...)`` call ``when(first)`` accepts, before
        it is sent."""
        real = getattr(self._c.link, method)

        def held(first: Any, *args: Any, **kwargs: Any) -> Any:
            if not self.reached.is_set() and when(first):
                self.reached.set()
                assert self._go.wait(10)
            return real(first, *args, **kwargs)

        self._monkeypatch.setattr(self._c.link, method, held)

    def go(self) -> None:
        self._go.set()


def mock_flyer(address: str) -> GalilContourFlyer:
    flyer = GalilContourFlyer(address, "A", name="fly")
    in_loop(flyer.connect(mock=True))
    return flyer


async def _fly(flyer: GalilContourFlyer, path: Any, dt: int) -> None:
    await flyer.prepare(ContourPath(path, dt=dt))
    await flyer.kickoff()


async def _completed(flyer: GalilContourFlyer) -> Exception | None:
    """What ``complete()`` failed with (``None``: the flight ended well)."""
    try:
        await flyer.complete()
    except Exception as exc:  # reported by the test
        return exc
    return None


def test_close_during_a_flight_stops_the_contour_axes(
    engine: RunEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (the flyer's stream had no StopWatch: close() sent no ST, and the queued segments ran on)
    flyer = mock_flyer("tcp://127.0.0.1:40")
    c = flyer.controller.sync
    sim = sim_of(c)
    polls = [0]

    def third_poll(names: Any) -> bool:  # the stream is feeding its buffer
        polls[0] += list(names)[:2] == ["_CM", "_TC"]  # (then the stop codes)
        return polls[0] == 3

    held = _Held(c, monkeypatch)
    held.before("query_operands", third_poll)
    in_loop(_fly(flyer, np.cumsum(np.full(3000, 20.0)), 2))  # six buffers
    assert held.reached.wait(10)
    in_loop(flyer.controller.aclose())  # Controller.close(), while the stream waits
    held.go()
    assert isinstance(in_loop(_completed(flyer)), galil.GalilError)
    assert "ST A" in [text for _, text in sim.command_log]
    sim.advance(2.0)
    assert sim.feed(b"MG _BGA\r").split(b"\r")[0].strip() == b"0.0000"


def test_a_move_on_a_contour_axis_from_another_thread_is_refused_while_it_flies(
    engine: RunEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (the flight neither read the state again nor took turns: the move began between
    # prepare() and CM, and the CM was refused with TC 7 while the move ran)
    flyer = mock_flyer("tcp://127.0.0.1:41")
    c = flyer.controller.sync
    held = _Held(c, monkeypatch)
    held.before("command_line", lambda parts: any(str(p).startswith("CM") for p in parts))
    in_loop(_fly(flyer, np.linspace(20, 640, 32), 3))
    assert held.reached.wait(10)  # the flight is about to send CM
    got: list[BaseException | galil.MoveHandle] = []

    def move() -> None:
        try:
            got.append(c.A.move_by(100))
        except galil.GalilError as exc:
            got.append(exc)

    mover = threading.Thread(target=move)
    mover.start()
    while not held.contended.is_set() and mover.is_alive():
        mover.join(0.001)  # until the move waits for the flight's start (or, before, ran)
    held.go()
    mover.join(10)
    assert len(got) == 1
    assert isinstance(got[0], galil.InvalidArgument), got
    assert "already moving" in str(got[0])
    assert in_loop(_completed(flyer)) is None
    assert flyer.predicted["A"].end == 640


def test_the_flyers_stop_during_a_flight_ends_its_stream(
    engine: RunEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (the stream did not hear of the flyer's ST: it sent its next CD lines after it)
    flyer = mock_flyer("tcp://127.0.0.1:42")
    c = flyer.controller.sync
    sim = sim_of(c)
    polls = [0]

    def third_poll(names: Any) -> bool:
        polls[0] += list(names)[:2] == ["_CM", "_TC"]  # (then the stop codes)
        return polls[0] == 3

    held = _Held(c, monkeypatch)
    held.before("query_operands", third_poll)
    in_loop(_fly(flyer, np.cumsum(np.full(3000, 20.0)), 2))
    assert held.reached.wait(10)
    in_loop(flyer.stop())  # ST A, while the stream waits on the link
    held.go()
    deadline = time.monotonic() + 10
    while "CD 0=0" not in [t for _, t in sim.command_log]:  # the stream's own end
        assert time.monotonic() < deadline
        threading.Event().wait(0.005)
    sent = [t for _, t in sim.command_log]
    after = sent[sent.index("ST A") :]
    assert [t for t in after if t.startswith("CD")] == ["CD 0=0"]


# -- a shared controller whose sync side was closed directly -------------------------------
def test_a_shared_controller_closed_behind_the_devices_back_still_ends_its_worker(
    engine: RunEngine, server: SimTcpServer
) -> None:
    first = motor(server.url)
    controller = first.controller
    controller.sync.close()  # (not aclose(): the worker's threads stay up)
    assert not controller.worker.closed
    second = motor(server.url, name="y")  # a new connection replaces the closed one
    replacement = second.controller
    assert replacement is not controller
    assert controller.worker.closed
    replacement.sync.close()
    in_loop(release_all())
    assert replacement.worker.closed
