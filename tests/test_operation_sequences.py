"""Random sequences of valid operations against the simulator, checked after every step.

A hypothesis state machine drives a ``sim://DMC-4040`` through moves (waited or not), jogs and
their speed changes, increments, speed schedules, homing, gearing, vector moves, contours,
soft limits, limit switches, stops, aborts, motors off and on, TM changes, a program that
moves an axis, the ``motion()`` guard and the passing of time. After each step:

- a call raises nothing but the library's documented errors; a refusal sent nothing but
  queries and changed none of the axes' settings;
- a waited move ended where its handle predicted, to the count, with the stop code the docs
  give its kind when nothing interfered with it;
- the library's view agrees with the simulator's: every axis the controller moves is driven
  by a handle the library holds (or follows a master, or runs the test's program), and every
  gearing the library counts on is engaged (unless a limit stopped it, unseen);
- the link is in step (``MG 1``, ``MG 2``).

At the end ``close()`` leaves nothing moving and no thread running.

Deterministic in CI (``derandomize``, no database); run it long with e.g.
``GALIL_SEQ_EXAMPLES=2000 pytest --timeout=0 tests/test_operation_sequences.py`` (and
``GALIL_SEQ_STEPS`` for longer sequences).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

import galil
from galil import Line
from galil.errors import (
    CommandError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    MotionError,
)
from galil.gearing import Gearing
from galil.motion import MoveHandle, MoveResult
from galil.sim.rooms.gearing import Gearing as SimGearing
from galil.testing import sim_of, transcript

AXES = "ABCD"
EXAMPLES = int(os.environ.get("GALIL_SEQ_EXAMPLES", "40"))
STEPS = int(os.environ.get("GALIL_SEQ_STEPS", "30"))

axis_st = st.sampled_from(AXES)
# An operand, a variable or an array element, in its number format or not (decision 0032).
_NAME = r"[_A-Za-z][_A-Za-z0-9]*(?:\[-?\d+\])?(?:\{[A-Z$]\d+(?:\.\d+)?\})?"
_READ_ONLY = re.compile(
    rf"MG {_NAME}(?:\s*,\s*{_NAME})*"
    r"|UL|LA|LV|QU [A-Za-z0-9\[\],]*|QZ|TC1|MG \"TCOK\d+\""
)
# What must not change when a call is refused.
_SETTINGS = ("SP", "AC", "DC", "IT", "BL", "FL", "MO", "JG", "HV")
# The stop code a move of each kind ends with when nothing interferes (docs/homing.md, a
# position move's normal end).
_END_CODE = {"position": 1, "schedule": 1, "home": 10, "edge": 9, "index": 10, "vector": 101}
PROGRAM = "#SEQMOVE\nPRD=700\nBGD\nAMD\nEN"


@dataclass
class Running:
    """A handle the machine started and has not waited for."""

    handle: MoveHandle
    interfered: bool = False  # a stop, an abort, a switch: its end code may differ
    # The test's program may have moved its axis behind the library, or SH put the reference
    # where the (lagging) motor is: its end is not the prediction's business.
    unpredictable: bool = False
    superseded: bool = False  # other motion started on its axes since (its end is older)


def _queries_only(lines: list[str]) -> list[str]:
    return [
        line
        for line in lines
        if not all(_READ_ONLY.fullmatch(part.strip()) for part in line.split(";"))
    ]


class OperationSequences(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.dmc = galil.connect("sim://DMC-4040")
        self.sim = sim_of(self.dmc)
        self.running: list[Running] = []
        self.gearings: dict[str, Gearing] = {}
        self.program_axis_free = True
        self.threads_before = set(threading.enumerate())

    # -- helpers ----------------------------------------------------------------------------
    def _settings(self) -> list[float]:
        return self.dmc.query_operands([f"_{op}{a}" for a in AXES for op in _SETTINGS])

    @contextlib.contextmanager
    def refusable(self, *allowed: type[GalilError]) -> Iterator[None]:
        """Run a call that may be refused with one of ``allowed``: then it sent nothing but
        queries and the axes' settings are as they were."""
        before = self._settings()
        gears = dict(self.dmc.tracker.gears)
        refused: GalilError | None = None
        with transcript(self.dmc) as sent:
            try:
                yield
            except allowed as exc:
                refused = exc
        if refused is None:
            return
        others = _queries_only(sent.lines)
        assert not others, f"{type(refused).__name__} ({refused}) after sending {others!r}"
        assert self._settings() == before, f"settings changed by a refusal: {refused}"
        if not isinstance(refused, MotionError):  # (refuse_dropped forgets the gearing)
            assert self.dmc.tracker.gears == gears, f"gearing changed by a refusal: {refused}"

    def interfere(self, letters: str = AXES, *, unpredictable: bool = False) -> None:
        for run in self.running:
            touched = set(run.handle.axes + run.handle.followers)
            if touched & set(letters):
                run.interfered = True
                run.unpredictable = run.unpredictable or unpredictable

    def idle(self, letters: str = AXES) -> bool:
        *bg, xq = self.dmc.query_operands([f"_BG{a}" for a in letters] + ["_XQ1"])
        return not any(bg) and xq < 0

    def check_result(self, run: Running, result: MoveResult) -> None:
        h = run.handle
        rp = self.dmc.query_operands([f"_RP{a}" for a in h.axes])
        if run.unpredictable:
            return
        if not run.superseded:
            assert dict(zip(h.axes, map(round, rp), strict=True)) == result.final
        assert all(v == 0 for v in result.deviation.values()), result
        if run.interfered or h.kind == "jog":
            return
        exact = {a for a in h.axes if (t := h.track(a)) is not None and t.exact}
        assert set(result.predicted) == exact, (h, result)
        end = _END_CODE.get(h.kind, 1)
        assert all(c == end for c in result.stop_codes.values()), (h.kind, result)

    def wait(self, run: Running) -> None:
        h = run.handle
        timeout = 5.0 if math.isinf(h.duration) else None
        limited: MotionError | None = None
        try:
            with warnings.catch_warnings():
                if run.unpredictable:  # (not the library's doing)
                    warnings.simplefilter("ignore", RuntimeWarning)
                result = h.wait(timeout=timeout)
        except MotionError as exc:  # a limit stopped it (or a follower of it)
            limited = exc
        except GalilTimeoutError:
            result = None
        if limited is not None:
            assert set(limited.stop_codes.values()) & {2, 3}, limited
            if run in self.running:
                self.running.remove(run)
            return
        if result is None:
            assert math.isinf(h.duration) or run.interfered, h
            return
        if run in self.running:
            self.running.remove(run)
        self.check_result(run, result)

    def supersede(self, letters: str) -> None:
        for run in self.running:
            if set(run.handle.axes) & set(letters):
                run.superseded = True

    def started(self, handle: MoveHandle, wait: bool) -> None:
        run = Running(handle)
        self.running = [r for r in self.running if r.handle is not handle]
        self.supersede(handle.axes + handle.followers)
        self.running.append(run)
        if wait:
            self.wait(run)

    # -- setup ------------------------------------------------------------------------------
    @initialize()
    def setup(self) -> None:
        for a in AXES:
            self.sim.set_home_switch(a, edge=-3000, index_period=2000)
            self.dmc.axes[a].home_speed = 2000

    # -- settings ---------------------------------------------------------------------------
    @rule(
        a=axis_st,
        what=st.sampled_from(["speed", "accel", "decel", "smoothing"]),
        i=st.integers(0, 3),
    )
    def set_parameter(self, a: str, what: str, i: int) -> None:
        values = {
            "speed": [2000, 10000, 25000, 60000],
            "accel": [20480, 102400, 256000, 1024000],
            "decel": [20480, 102400, 256000, 1024000],
            "smoothing": [1.0, 0.5, 0.25, 0.0625],
        }
        refused: CommandError | None = None
        try:
            with self.refusable(InvalidArgument):
                setattr(self.dmc.axes[a], what, values[what][i])
        except CommandError as exc:  # documented on decel: the controller refuses DC in motion
            refused = exc
        if refused is not None:
            assert what == "decel", refused
            assert refused.code == 7, refused

    @rule(
        a=axis_st,
        low=st.sampled_from([None, -20000, -5000]),
        high=st.sampled_from([None, 5000, 20000]),
    )
    def soft_limits(self, a: str, low: int | None, high: int | None) -> None:
        self.dmc.axes[a].soft_limits = (low, high)

    @rule(
        a=axis_st,
        which=st.sampled_from(["forward", "reverse"]),
        where=st.sampled_from([None, 500, 3000, 15000]),
    )
    def place_limit_switch(self, a: str, which: str, where: int | None) -> None:
        here = self.sim.machine_position(a)
        pos = None if where is None else here + (where if which == "forward" else -where)
        self.sim.place_limit_switches(a, **{which: pos})
        self.interfere(a)

    @rule(tm=st.sampled_from([500, 1000, 250]))
    def change_tm(self, tm: int) -> None:
        if self.idle():  # (the controller refuses TM in motion: TC 7)
            self.dmc.command(f"TM {tm}")

    # -- moves ------------------------------------------------------------------------------
    @rule(
        a=axis_st,
        relative=st.booleans(),
        amount=st.integers(-30000, 30000),
        wait=st.booleans(),
    )
    def move(self, a: str, relative: bool, amount: int, wait: bool) -> None:
        ax = self.dmc.axes[a]
        with self.refusable(InvalidArgument, MotionError):
            h = ax.move_by(amount) if relative else ax.move_to(amount)
            self.started(h, wait)

    @rule(axes=st.sampled_from(["AB", "BC", "CD", "AD", "ABC"]), amount=st.integers(-9000, 9000))
    def move_together(self, axes: str, amount: int) -> None:
        with self.refusable(InvalidArgument, MotionError):
            h = self.dmc.move({a: amount for a in axes}, relative=True)
            self.started(h, False)

    @rule(a=axis_st, speed=st.sampled_from([-30000, -4000, 3000, 20000]))
    def jog(self, a: str, speed: int) -> None:
        with self.refusable(InvalidArgument, MotionError):
            self.started(self.dmc.axes[a].jog(speed), False)

    @rule(a=axis_st, speed=st.sampled_from([-8000, 1000, 12000]))
    def set_jog_speed(self, a: str, speed: int) -> None:
        refused: CommandError | None = None
        try:
            with self.refusable(InvalidArgument, MotionError):
                self.dmc.axes[a].jog_speed = speed
        except CommandError as exc:  # documented: a move the library did not start (TC 13)
            refused = exc
        if refused is not None:
            assert not self._free(a), refused
            assert refused.code == 13, refused

    @rule(a=axis_st, n=st.sampled_from([-2000, -3, 5, 1500]))
    def increment(self, a: str, n: int) -> None:
        with self.refusable(InvalidArgument, MotionError):
            self.started(self.dmc.axes[a].increment(n), False)

    @rule(a=axis_st, sign=st.sampled_from([-1, 1]), wait=st.booleans())
    def speed_schedule(self, a: str, sign: int, wait: bool) -> None:
        with self.refusable(InvalidArgument, MotionError):
            h = self.dmc.axes[a].speed_schedule(
                sign * 12000, [(4000, 8000), (8000, 3000)], speed=15000
            )
            self.started(h, wait)

    @rule(a=axis_st, how=st.sampled_from(["home", "find_edge", "find_index"]), wait=st.booleans())
    def home(self, a: str, how: str, wait: bool) -> None:
        switch = self.sim.home_switch(a)
        with self.refusable(InvalidArgument, MotionError):
            self.started(getattr(self.dmc.axes[a], how)(switch=switch), wait)

    @rule(
        follower=axis_st,
        master=st.sampled_from([*AXES, "S"]),
        ratio=st.sampled_from([-1.5, 0.5, 2.0]),
    )
    def gear(self, follower: str, master: str, ratio: float) -> None:
        with self.refusable(InvalidArgument, MotionError):
            self.gearings[follower] = self.dmc.axes[follower].gear_to(master, ratio)
            self.supersede(follower)

    @rule(follower=axis_st)
    def gear_off(self, follower: str) -> None:
        gearing = self.gearings.pop(follower, None)
        if gearing is not None:
            gearing.off()

    @rule(follower=axis_st, ratio=st.sampled_from([-0.5, 1.0, 3.0]))
    def gear_ratio(self, follower: str, ratio: float) -> None:
        gearing = self.gearings.get(follower)
        if gearing is not None:
            with self.refusable(InvalidArgument, MotionError):
                gearing.set_ratio(ratio)

    @rule(
        axes=st.sampled_from(["AB", "CD", "BD"]),
        dx=st.integers(-8000, 8000),
        dy=st.integers(-8000, 8000),
        wait=st.booleans(),
    )
    def vector_move(self, axes: str, dx: int, dy: int, wait: bool) -> None:
        with self.refusable(InvalidArgument, MotionError):
            h = self.dmc.vector_move(axes, [Line(dx, dy), Line(-dy, dx)], speed=20000)
            self.started(h, wait)

    @rule(axes=st.sampled_from(["A", "BC", "AD"]), reach=st.integers(-3000, 3000))
    def contour(self, axes: str, reach: int) -> None:
        path = np.outer(np.linspace(0, 1, 12), np.arange(1, len(axes) + 1) * reach).round()
        before = self.dmc.query_operands([f"_RP{a}" for a in axes])
        self.supersede(axes)  # (even if refused: harmless)
        with self.refusable(InvalidArgument, MotionError):
            self.dmc.contour(axes, path, dt=3)
            after = self.dmc.query_operands([f"_RP{a}" for a in axes])
            assert after == list(np.add(before, path[-1])), (before, after)

    # -- stops, motors, time ----------------------------------------------------------------
    @rule(axes=st.sampled_from(["", "A", "B", "C", "D", "AC"]))
    def stop(self, axes: str) -> None:
        self.dmc.stop(axes)
        self.interfere(axes or AXES)

    @rule(data=st.data())
    def stop_handle(self, data: st.DataObject) -> None:
        if self.running:
            run = data.draw(st.sampled_from(self.running))
            run.handle.stop()
            self.interfere(run.handle.axes)

    @rule()
    def abort(self) -> None:
        self.dmc.abort()
        self.interfere()

    @rule(a=axis_st, on=st.booleans())
    def motor(self, a: str, on: bool) -> None:
        if on:
            self.dmc.servo_here(a)
            self.interfere(a, unpredictable=True)
        else:
            with self.refusable(InvalidArgument):  # (in motion: the controller refuses MO)
                self.dmc.motor_off(a)

    @rule(seconds=st.sampled_from([0.01, 0.1, 0.5, 2.0]))
    def sleep(self, seconds: float) -> None:
        self.dmc.sleep(seconds)

    @rule(data=st.data())
    def wait_one(self, data: st.DataObject) -> None:
        if self.running:
            self.wait(data.draw(st.sampled_from(self.running)))

    @rule()
    def run_program(self) -> None:
        with self.refusable(InvalidArgument):
            self.dmc.programs.download(PROGRAM)
            self.dmc.programs.run("#SEQMOVE", thread=1)
            self.program_axis_free = False
            self.interfere("D", unpredictable=True)

    @rule(a=axis_st, amount=st.integers(-5000, 5000))
    def guarded_failure(self, a: str, amount: int) -> None:
        class BoomError(Exception):
            pass

        with contextlib.suppress(BoomError, InvalidArgument, MotionError), self.dmc.motion():
            self.started(self.dmc.axes[a].move_by(amount), False)
            raise BoomError
        self.interfere()
        assert not any(self.dmc.query_operands([f"_BG{x}" for x in AXES if self._free(x)]))

    # -- invariants -------------------------------------------------------------------------
    def _free(self, a: str) -> bool:
        """Whether ``a`` moves only through the library (no gearing, no program)."""
        return a not in self.dmc.tracker.gears and (a != "D" or self.program_axis_free)

    @invariant()
    def link_in_step(self) -> None:
        assert float(self.dmc.command("MG 1")) == 1
        assert float(self.dmc.command("MG 2")) == 2

    @invariant()
    def library_agrees_with_simulator(self) -> None:
        dmc, tracker = self.dmc, self.dmc.tracker
        names = [f"_{op}{a}" for a in AXES for op in ("BG", "SC")] + ["_XQ1"]
        values = [round(v) for v in dmc.query_operands(names)]
        bg = dict(zip(AXES, values[0:8:2], strict=True))
        sc = dict(zip(AXES, values[1:8:2], strict=True))
        if values[-1] < 0 and not bg["D"]:
            self.program_axis_free = True
        sim_gears = self.sim.room(SimGearing)
        servo = sim_gears.machine.servo
        for a in AXES:
            engaged = sim_gears.geared(servo.axes[a]) is not None
            known = tracker.gears.get(a)
            if engaged:
                assert known is not None, f"{a} follows on the controller, not in the library"
            elif known is not None:
                assert known.dropped_by(sc[a]), f"the library counts on {a}'s gearing: SC {sc[a]}"
            if bg[a] and known is None and (a != "D" or self.program_axis_free):
                assert tracker.active(a) is not None, f"{a} moves and no handle drives it"

    def teardown(self) -> None:
        dmc, sim = self.dmc, self.sim
        dmc.close()
        sim.advance(30.0)
        before = [sim.motion(a).reference for a in AXES]
        sim.advance(1.0)
        after = [sim.motion(a).reference for a in AXES]
        moved = [a for a, x, y in zip(AXES, before, after, strict=True) if x != y]
        left = [t for t in threading.enumerate() if t not in self.threads_before and t.is_alive()]
        assert not left, left
        assert not moved or (moved == ["D"] and not self.program_axis_free), moved


OperationSequences.TestCase.settings = settings(
    max_examples=EXAMPLES,
    stateful_step_count=STEPS,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
test_operation_sequences = OperationSequences.TestCase
