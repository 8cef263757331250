"""Every sync operation that starts or changes motion, with an exception at each of its wire
calls: motion never outlives the exception (decision 0028).

Each operation runs once on a fresh simulator to count the transport reads and writes its own
thread makes; then, for each of those calls, again on a fresh simulator with that call raising
(before it does its work, or after: the bytes written, or read and lost), once with
``KeyboardInterrupt`` and once with a transport failure (``GalilConnectionError``, what every
transport makes of an ``OSError``). Afterwards, from the outside (a handle of its own on the
simulator):

- the caller got the ``KeyboardInterrupt`` or a ``GalilError``, except from a stop whose
  dead link was reopened to send the stop again: it has done its job and returns;
- a transport failure left the link saying it is dead, and ``reconnect()`` works;
- within a quarter of a second of controller time (a stop's deceleration) no axis moves, unless the
  operation is documented to leave it so (a follower the library knows is geared), no thread
  runs a program (a speed schedule's routine), no axis is left in contour mode, and the
  gearings engaged are exactly those the library counts on, at its ratios (decision 0069);
- what the operation would have changed for its course only (a speed schedule's speeds)
  reads as before;
- the link answers ``MG 1`` then ``MG 2``.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from client_fakes import SimLinkWrapper, Tripwire

from galil import Line
from galil.controller import Controller
from galil.errors import CommandError, GalilConnectionError, GalilError, MotionError
from galil.motion import MoveHandle
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import open_transport
from galil.sim.rooms.gearing import Gearing as SimGearing

#: Controller time whatever an interrupted operation left stopping may take to come to rest.
SETTLE = 0.25
LONG = 200_000  # counts: 10 s at SP 20 000
ERRORS: list[type[BaseException]] = [KeyboardInterrupt, GalilConnectionError]


@dataclass
class Wire(Tripwire):
    """The simulator's link, raising at the ``at``-th read or write of the armed thread."""

    error: type[BaseException] = KeyboardInterrupt
    armed: int | None = None  # the thread whose calls count

    def _trip(self) -> bool:
        if threading.get_ident() != self.armed:
            return False  # (the message poller's reads are not the operation's)
        return super()._trip()


@dataclass
class Bench:
    """A fresh simulator, a controller on it whose transport is a :class:`Wire`."""

    model: str = "DMC-4040"
    wires: list[Wire] = field(default_factory=list)
    sim: SimController = field(init=False)
    dmc: Controller = field(init=False)

    def __post_init__(self) -> None:
        self.sim = SimController(self.model, ManualClock())
        self.dmc = Controller(self._open, timeout=0.5)

    def _open(self) -> Wire:
        wire = Wire(open_transport(f"sim://{self.model}", controller=self.sim))
        self.wires.append(wire)
        return wire

    @property
    def wire(self) -> Wire:
        return self.wires[-1]

    def ask(self, names: list[str]) -> list[int]:
        """Operands read on a handle of the test's own (not through the library)."""
        port = self.sim.open_port("audit")
        try:
            reply = self.sim.feed(f"MG {','.join(names)}\r".encode(), port)
        finally:
            self.sim.close_port(port)
        text = reply.decode("latin-1").strip().rstrip(":")
        return [round(float(v)) for v in text.replace("-", " -").split()]


# -- the operations ---------------------------------------------------------------------------


def _slow(dmc: Controller) -> None:
    dmc.command("SP 20000,20000,20000,20000")
    dmc.command("AC 1000000,1000000,1000000,1000000")
    dmc.command("DC 1000000,1000000,1000000,1000000")


def _start_a(dmc: Controller) -> Any:
    _slow(dmc)
    return dmc.A.move_by(LONG)


def _start_jog(dmc: Controller) -> Any:
    _slow(dmc)
    return dmc.A.jog(20_000)


def _gear_b(dmc: Controller) -> Any:
    _slow(dmc)
    return dmc.B.gear_to("A", 2)


def _start_vector(dmc: Controller) -> Any:
    return dmc.vector_move("AB", [Line(LONG, LONG // 2)], speed=20_000)


def _found_b(dmc: Controller) -> None:
    """B geared to A behind the library's back, found at the next connect (decision 0055)."""
    _slow(dmc)
    dmc.command("GA ,CA")
    dmc.command("GR ,2")
    dmc.reconnect()


def _homing(dmc: Controller) -> None:
    """Speeds for homing, the home switch and the index pulses far away (seconds of travel)."""
    _slow(dmc)
    dmc.command("HV 5000,5000,5000,5000")
    dmc.command("JG 5000,5000,5000,5000")
    dmc.transport.inner.controller.set_home_switch("A", edge=-LONG, index_period=LONG)


def _guarded(dmc: Controller, _: object) -> object:
    with dmc.motion("AB"):
        a = dmc.A.move_by(LONG)
        b = dmc.B.move_by(LONG)
        a.wait()
        b.wait()
    return None


ZIGZAG = [Line(37, 19 * (-1) ** k) for k in range(600)]  # longer than the S buffer (511)
PROGRAM = "#SLOW\ni=0\n#LOOP\ni=i+1\nWT 100\nJP #LOOP,i<100\nEN"


def _download(dmc: Controller) -> None:
    dmc.programs.download(PROGRAM)


def _running(dmc: Controller) -> None:
    _download(dmc)
    dmc.programs.run("#SLOW", 1)


@dataclass(frozen=True)
class Op:
    """``body(dmc, setup(dmc))``, the operation whose calls raise.

    Attributes:
        goes_on: what it leaves running by design when it raises (tidied by the test).
        every: check each ``every``-th call only (and the last ones), for long streams.
        stops: the operation is a stop (``ST``, ``AB``): when its link dies and the guard
            gets the stop through on the reopened link, it has done its job and returns.
    """

    name: str
    body: Callable[[Controller, Any], object]
    setup: Callable[[Controller], Any] = lambda dmc: None
    goes_on: str = ""
    every: int = 1
    same: tuple[str, ...] = ()  # operands that must read afterwards as they did before
    stops: bool = False


OPS = [
    Op("move_by", lambda d, _: d.A.move_by(LONG), _slow),
    Op("move_to", lambda d, _: d.A.move_to(-LONG), _slow),
    Op("controller.move", lambda d, _: d.move({"A": LONG, "B": -LONG}, relative=True), _slow),
    Op("move_by + wait", lambda d, _: d.A.move_by(LONG).wait(), _slow),
    # (a move's wait lets its predicted time pass at once: a jog's polls find it moving)
    Op("handle.wait", lambda d, h: h.wait(timeout=0.5), _start_jog),
    Op("handle.wait(progress)", lambda d, h: h.wait(timeout=0.5, progress=True), _start_jog),
    Op("jog", lambda d, _: d.A.jog(20_000), _slow),
    Op("jog again (speed change)", lambda d, _: d.A.jog(30_000), _start_jog),
    Op("jog_speed while jogging", lambda d, _: setattr(d.A, "jog_speed", 30_000), _start_jog),
    Op("increment idle", lambda d, _: d.A.increment(LONG), _slow),
    # (SP, AC, DC in motion: the move's prediction follows them from their time stamp)
    Op("speed in a move", lambda d, _: setattr(d.A, "speed", 30_000), _start_a),
    Op("accel in a move", lambda d, _: setattr(d.A, "accel", 512_000), _start_a),
    Op("decel in a jog", lambda d, _: setattr(d.A, "decel", 512_000), _start_jog),
    Op("increment in a move", lambda d, _: d.A.increment(1000), _start_a),
    Op("increment while jogging", lambda d, _: d.A.increment(10), _start_jog),
    Op(
        "speed_schedule",
        lambda d, _: d.B.speed_schedule(LONG, [(LONG // 2, 10_000)]),
        _slow,
        same=("_SPB",),  # (a schedule that did not run its course leaves no speed behind)
    ),
    Op("home", lambda d, _: d.A.home(), _homing),
    Op("find_edge", lambda d, _: d.A.find_edge(), _homing),
    Op("find_index", lambda d, _: d.A.find_index(), _homing),
    Op("gear_to", lambda d, _: d.B.gear_to("A", 2), _slow),
    Op("gearing.set_ratio", lambda d, g: g.set_ratio(3), _gear_b),
    Op("gearing.off", lambda d, g: g.off(), _gear_b),
    Op("gear_off of a gearing found at connect", lambda d, _: d.B.gear_off(), _found_b),
    Op("master move with a follower", lambda d, _: d.A.move_by(LONG // 4), _gear_b),
    Op("vector_move", lambda d, _: d.vector_move("AB", [Line(LONG, LONG // 2)], speed=20_000)),
    Op(
        "vector_move + wait",
        lambda d, _: d.vector_move("AB", [Line(LONG, LONG // 2)], speed=20_000).wait(),
    ),
    Op(
        "vector_move streamed",
        lambda d, _: d.vector_move("AB", ZIGZAG, speed=3000, accel=512_000, decel=512_000),
        every=13,
    ),
    Op("contour", lambda d, _: d.contour("A", np.arange(1, 521) * 100.0, dt=2), every=101),
    Op("controller.stop", lambda d, _: d.stop(), _start_a, stops=True),
    Op("axis.stop", lambda d, _: d.A.stop(), _start_jog, stops=True),
    Op("handle.stop", lambda d, h: h.stop(), _start_a, stops=True),
    Op("vector handle.stop", lambda d, h: h.stop(), _start_vector, stops=True),
    Op("controller.abort", lambda d, _: d.abort(), _start_a, stops=True),
    # (a stop of a follower, or of every axis, turns its gearing off: decision 0069)
    Op("axis.stop of a follower", lambda d, _: d.B.stop(), _gear_b, stops=True),
    Op("controller.stop, a follower", lambda d, _: d.stop(), _gear_b, stops=True),
    Op("controller.abort, a follower", lambda d, _: d.abort(), _gear_b, stops=True),
    Op("motion guard", _guarded, _slow),
    Op("programs.run", lambda d, _: d.programs.run("#SLOW", 1), _download, goes_on="program"),
    Op("programs.wait", lambda d, _: d.programs.wait(1, 0.1), _running, "program", every=7),
]


def _count(op: Op, model: str) -> int:
    """The reads and writes of a clean run of ``op`` (on its own thread)."""
    bench = Bench(model)
    with bench.dmc as dmc:
        ctx = op.setup(dmc)
        bench.wire.armed = threading.get_ident()
        with contextlib.suppress(GalilError):  # (a wait's timeout: the calls up to it count)
            op.body(dmc, ctx)
        bench.wire.armed = None
        return bench.wire.calls


def _points(op: Op, total: int) -> list[int]:
    """Every call of a short operation; of a stream, its first 8, every ``every``-th and its
    last 3."""
    return sorted(
        {*range(min(total, 8)), *range(0, total, op.every), *range(max(0, total - 3), total)}
    )


def _check(bench: Bench, op: Op, where: str, before: list[int]) -> None:
    dmc, sim = bench.dmc, bench.sim
    sim.advance(SETTLE)
    if op.goes_on == "program":
        bench.ask(["_XQ1"])
        sim.feed(b"HX1\r")
    letters = dmc.model.axes
    moving = bench.ask([f"_BG{a}" for a in letters] + ["_BGS"])
    known = set(dmc.tracker.gears) | set(dmc.tracker.found)
    still = [a for a, m in zip(letters + "S", moving, strict=True) if m and a not in known]
    assert not still, f"{where}: {''.join(still)} still moving"
    threads = bench.ask([f"_XQ{n}" for n in range(8)])
    assert all(t < 0 for t in threads), f"{where}: a thread still runs: {threads}"
    axes = sim._m.servo.axes
    contour = [a for a in letters if axes[a].contour]
    assert not contour, f"{where}: {contour} left in contour mode"
    gearing = sim.room(SimGearing)
    engaged = {a for a in letters if gearing.geared(axes[a]) is not None}
    assert engaged == known, f"{where}: geared {sorted(engaged)}, the library counts on {known}"
    for a, gear in dmc.tracker.gears.items():  # (the ratios here are whole numbers)
        assert bench.ask([f"_GR{a}"]) == [gear.ratio], f"{where}: {a}'s ratio is not {gear.ratio}"
    if op.same:
        assert bench.ask(list(op.same)) == before, f"{where}: {op.same} changed"
    assert dmc.query_number("MG 1") == 1, where
    assert dmc.query_number("MG 2") == 2, where


def _raise_at(op: Op, model: str, k: int, after: bool, error: type[BaseException]) -> None:
    where = f"{op.name}: call {k} raising {error.__name__} {'after' if after else 'before'}"
    bench = Bench(model)
    with bench.dmc as dmc:
        ctx = op.setup(dmc)
        before = bench.ask(list(op.same)) if op.same else []
        wire = bench.wire
        wire.at, wire.after, wire.error = k, after, error
        wire.armed = threading.get_ident()
        try:
            op.body(dmc, ctx)
        except (KeyboardInterrupt, GalilError) as exc:
            caught: BaseException | None = exc
        else:
            caught = None
        wire.armed = None
        if caught is None:
            # Only a stop returns, and only once its link was reopened and the stop went out.
            assert op.stops, f"{where}: returned normally"
            assert error is GalilConnectionError, f"{where}: returned normally"
            assert dmc.link.is_open, f"{where}: returned, link closed"
            assert not dmc.link.dead, f"{where}: returned, link dead"
        if error is GalilConnectionError and caught is not None:
            assert dmc.link.dead or isinstance(caught, GalilError), where
            if dmc.link.dead:
                assert "reconnect" in repr(dmc)
                dmc.reconnect()
        _check(bench, op, where, before)
        if isinstance(ctx, MoveHandle):
            # The motion the operation changed or stopped: its handle's prediction is exact
            # or says it is not (a change whose fate is unknown: decision 0072).
            result = ctx.wait(timeout=1.0)
            assert all(v == 0 for v in result.deviation.values()), f"{where}: {result}"


#: The operations also walked on a DMC-4143 (another family: its own TM, contour end, ranges).
ON_41X3 = ["move_by", "handle.wait", "jog", "speed_schedule", "gear_to", "vector_move", "contour"]


CASES = [(op, "DMC-4040") for op in OPS] + [(op, "DMC-4143") for op in OPS if op.name in ON_41X3]


@pytest.mark.parametrize(
    ("op", "model"),
    CASES,
    ids=[op.name if m == "DMC-4040" else f"{op.name} on a {m}" for op, m in CASES],
)
def test_an_exception_at_any_call_leaves_no_motion_running(op: Op, model: str) -> None:
    total = _count(op, model)
    assert total > 0
    ways = [(after, error) for after in (False, True) for error in ERRORS]
    failures, runs = [], 0
    for k in _points(op, total):
        # Inside a stream's steady part each call is like the one before: one way each.
        middle = 8 <= k < total - 3
        for after, error in [ways[k % len(ways)]] if middle else ways:
            runs += 1
            try:
                _raise_at(op, model, k, after, error)
            except AssertionError as exc:
                failures.append(str(exc).splitlines()[0])
    assert not failures, f"{len(failures)} of {runs}:\n" + "\n".join(failures[:30])


@dataclass
class RefuseThirdFeed(SimLinkWrapper):
    """The simulator's link, whose third streamed write of a path starts with a segment the
    controller refuses (``VP`` out of range: ``?``, TC 6), the sequence already running."""

    feeds: int = 0

    def write(self, data: bytes) -> None:
        if data.startswith(b"VP"):
            self.feeds += 1
            if self.feeds == 3:
                data = b"VP 99999999999,0" + data[data.index(b";") :]
        self.inner.write(data)


def test_a_segment_refused_while_streaming_stops_the_running_sequence() -> None:
    sim = SimController("DMC-4040", ManualClock())
    wire = RefuseThirdFeed(open_transport("sim://DMC-4040", controller=sim))
    with Controller(lambda: wire, timeout=0.5) as dmc:
        with pytest.raises(CommandError):
            dmc.vector_move("AB", ZIGZAG, speed=3000, accel=512_000, decel=512_000)
        assert wire.feeds >= 3
        sim.advance(SETTLE)
        assert dmc.query_operands(["_BGS", "_BGA", "_BGB"]) == [0, 0, 0]


#: What close() finds running: a move, a jog, a vector sequence (each not waited for).
CLOSING: dict[str, Callable[[Controller], object]] = {
    "a move": _start_a,
    "a jog": _start_jog,
    "a vector sequence": _start_vector,
}


@pytest.mark.parametrize("running", list(CLOSING))
def test_close_interrupted_at_any_call_still_stops_the_motion_and_closes(running: str) -> None:
    """``close()`` whose exchanges raise, one at a time (decisions 0024, 0073): a Ctrl-C
    goes on once every stop went out and the link is closed; a link that dies under it is
    reopened once to send the stop, and ``close()`` returns. Either way nothing moves after
    a stop's ramp, and the link is closed."""

    def attempt(k: int | None, after: bool, error: type[BaseException]) -> BaseException | None:
        bench = Bench()
        dmc = bench.dmc
        CLOSING[running](dmc)
        wire = bench.wire
        if k is not None:
            wire.at, wire.after, wire.error = k, after, error
        wire.armed = threading.get_ident()
        caught: BaseException | None = None
        try:
            dmc.close()
        except BaseException as exc:  # (judged below)
            caught = exc
        wire.armed = None
        calls.append(wire.calls)
        bench.sim.advance(SETTLE)
        where = f"close with {running}, call {k} raising {error.__name__} after={after}"
        assert bench.ask(["_BGA", "_BGB", "_BGS"]) == [0, 0, 0], where
        assert not dmc.link.is_open, where
        return caught

    calls: list[int] = []
    assert attempt(None, False, KeyboardInterrupt) is None
    total = calls[0]
    assert total > 0
    for k in range(total):
        for after in (False, True):
            caught = attempt(k, after, KeyboardInterrupt)
            assert isinstance(caught, KeyboardInterrupt), (k, after, caught)
            assert attempt(k, after, GalilConnectionError) is None, (k, after)


def test_a_move_waited_after_a_close_that_reopened_its_link_says_close_stopped_it() -> None:
    """A link that dies under close()'s stops is reopened for them (decision 0073); the
    reopen must not leave the controller looking open to the moves it stopped. A wait on
    such a move afterwards says the controller was closed (close() stopped the move), not
    that the axes "could not be stopped and may still be moving" (a false alarm)."""
    reopened = 0
    for k in range(6):
        bench = Bench()
        dmc = bench.dmc
        move = _start_a(dmc)
        wire = bench.wire
        wire.at, wire.after, wire.error = k, False, GalilConnectionError
        wire.armed = threading.get_ident()
        dmc.close()
        wire.armed = None
        if len(bench.wires) == 1:
            continue  # (this call was not one of the stops: no reopen)
        reopened += 1
        bench.sim.advance(SETTLE)
        assert bench.ask(["_BGA"]) == [0]
        with pytest.raises(GalilConnectionError) as caught:
            move.wait(timeout=1)
        assert not isinstance(caught.value, MotionError), (k, caught.value)
        assert "closed" in str(caught.value), (k, caught.value)
        assert not dmc.link.is_open
    assert reopened > 0
