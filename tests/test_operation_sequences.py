"""Random sequences of valid operations against the simulator, checked after every step.

A hypothesis state machine drives a ``sim://DMC-4040`` through moves (waited or not), jogs and
their speed changes, increments, speed schedules, homing, gearing, vector moves, contours
(and contours a Ctrl-C interrupts at any exchange), soft limits, limit switches, stops,
aborts, motors off and on (``SH`` with handles nobody waited for), AC/DC in motion and in a
stop's ramp, MT/BR/CE, LD (and moves through or off a switch it disables), BP, TM changes,
programs that move an axis (one with IF/ELSE/ENDIF and AT, one with AS and MF/MR), the
``motion()`` guard and the passing of time. After each step:

- a call raises nothing but the library's documented errors; a refusal sent nothing but
  queries and changed none of the axes' settings; a setting "Not Valid while in motion" is
  refused unsent while the library's own motion runs and by the controller (TC 7) only where
  the library cannot know (decisions 0036, 0039), and taken only at rest; MT is refused
  unsent with the motor on (decision 0043);
- a start, a change, a wait or a stop (an axis's, a handle's: ``ST S`` for a sequence) that
  Ctrl-C interrupts at any exchange, or whose link dies at any write or read (reopened by
  the controller itself when the example connects with ``reconnect=True``, by the test's
  ``reconnect()`` otherwise), whatever else runs, leaves the axes it drives at rest once a
  line that is not a query went out (decision 0028), and its settings as they were when only
  queries did;
- an interrupted contour (Ctrl-C, or its link dying) leaves no axis moving or in contour
  mode, no segment held, and the next contour ends where it should (decision 0038); a
  contour a placed switch stops is over as a whole, out of contour mode, the axis on its
  switch (decision 0041);
- a waited move ended where its handle predicted, to the count, with the stop code the docs
  give its kind when nothing interfered with it;
- the library's view agrees with the simulator's: every axis the controller moves is driven
  by a handle the library holds (or follows a master, or runs the test's program), and every
  gearing the library counts on is engaged (unless a limit stopped it, unseen);
- the link is in step (``MG 1``, ``MG 2``).

At the end ``close()`` leaves nothing moving and no thread running.

Deterministic in CI (``derandomize``, no database); run it long with e.g.
``GALIL_SEQ_EXAMPLES=2000 pytest --timeout=0 tests/test_operation_sequences.py`` (and
``GALIL_SEQ_STEPS`` for longer sequences, ``GALIL_SEQ_RANDOM=1`` for other sequences than
CI's).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import threading
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

import galil
from galil import Line
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    LimitError,
    MotionError,
)
from galil.gearing import Gearing
from galil.link import Link
from galil.motion import HOMING_KINDS, GearLink, MoveHandle, MoveResult, Track
from galil.sim.rooms.contour import Contour as SimContour
from galil.sim.rooms.gearing import Gearing as SimGearing
from galil.sim.rooms.tuning import Tuning as SimTuning
from galil.testing import sim_of, transcript

AXES = "ABCD"
EXAMPLES = int(os.environ.get("GALIL_SEQ_EXAMPLES", "40"))
STEPS = int(os.environ.get("GALIL_SEQ_STEPS", "30"))
RANDOM = os.environ.get("GALIL_SEQ_RANDOM", "") not in ("", "0")

axis_st = st.sampled_from(AXES)
# An operand, a variable or an array element, in its number format or not (decision 0032).
_NAME = r"[_A-Za-z][_A-Za-z0-9]*(?:\[-?\d+\])?(?:\{[A-Z$]\d+(?:\.\d+)?\})?"
_READ_ONLY = re.compile(
    rf"MG {_NAME}(?:\s*,\s*{_NAME})*"
    r"|UL|LA|LV|QU [A-Za-z0-9\[\],]*|QZ|TC1|MG \"TCOK\d+\""
)
# What must not change when a call is refused.
_SETTINGS = ("SP", "AC", "DC", "IT", "BL", "FL", "MO", "JG", "HV", "MT", "BR", "CE", "LD")
_VALUES: dict[str, list[float]] = {
    "speed": [2000, 10000, 25000, 60000],
    "accel": [20480, 102400, 256000, 1024000],
    "decel": [20480, 102400, 256000, 1024000],
    "smoothing": [1.0, 0.5, 0.25, 0.0625],
}
# The settings the controller takes only at rest (DC: not in a position move).
_STILL = ("decel", "motor_type", "brush", "encoder_config")
# A start refused for a limit switch (galil.moves, galil.homing): which axis, which switch;
# a follower's too (a start of its master: decision 0053).
_SWITCH_REFUSAL = re.compile(
    r"(?:axis|on) ([A-H]) (?:is geared to [A-HS] at \S+: it )?would start towards its active "
    r"(forward|reverse) limit switch"
)
# The stop code a move of each kind ends with when nothing interferes (docs/homing.md, a
# position move's normal end).
_END_CODE = {"position": 1, "schedule": 1, "home": 10, "edge": 9, "index": 10, "vector": 101}
# Three routines that move D behind the library: a plain one, one that picks its direction
# with IF/ELSE/ENDIF and paces its start with AT (decision 0037), and one that waits for D to
# be at rest (AM: its PR is not refused with TC 7 in the library's move), moves it 700 counts
# (forwards below 0, else backwards), waits with AS, then with MF or MR for D to cross the
# middle of its move (decision 0042).
PROGRAM = (
    "#SEQMOVE\nPRD=700\nBGD\nAMD\nEN\n"
    "#SEQIF\nAT 0\nIF (_RPD < 0)\nPRD=700\nELSE\nPRD=-700\nENDIF\nAT 20\nBGD\nAMD\nEN\n"
    "#SEQTRIP\nAMD\np=_TPD\nIF (_RPD < 0)\nPRD=700;BGD\nASD\nMFD=p+350\nELSE\nPRD=-700;BGD\nASD\n"
    "MRD=p-350\nENDIF\nAMD\nEN"
)


@dataclass
class Running:
    """A handle the machine started and has not waited for."""

    handle: MoveHandle
    interfered: bool = False  # a stop, an abort, a switch: its end code may differ
    # The test's program may have moved its axis behind the library, or SH put the reference
    # where the (lagging) motor is: its end is not the prediction's business.
    unpredictable: bool = False
    superseded: bool = False  # other motion started on its axes since (its end is older)
    # A switch was placed, LD or a soft limit changed on its axes since it started: what
    # stopped it is not known (a limit's end is not checked against the limits now).
    limits_changed: bool = False


@contextlib.contextmanager
def _interrupted(link: object, at: int, *, after: bool) -> Iterator[None]:
    """Raise ``KeyboardInterrupt`` at the ``at``-th exchange or pause on ``link`` (counting
    from 0): before it goes out, or once it is done."""
    with _tripped(link, ("transact", "pause"), at, after=after, error=KeyboardInterrupt):
        yield


@contextlib.contextmanager
def _dropped(
    link: Link,
    at: int,
    *,
    after: bool,
    threads: Callable[[threading.Thread], bool] | None = None,
    tripped: list[bool] | None = None,
) -> Iterator[None]:
    """The link dies at the ``at``-th read or write this thread (or ``threads``) makes on its
    transport (counting from 0): before it goes out or is read, or once it is done (a read's
    bytes lost), as a cable pulled or a socket reset does. ``reconnect()`` (or the
    controller's own) reopens it onto the same simulator."""
    with _tripped(
        link.transport,
        ("write", "read"),
        at,
        after=after,
        error=GalilConnectionError,
        threads=threads,
        tripped=tripped,
    ):
        yield


@contextlib.contextmanager
def _tripped(
    target: object,
    names: tuple[str, ...],
    at: int,
    *,
    after: bool,
    error: type[BaseException],
    threads: Callable[[threading.Thread], bool] | None = None,
    tripped: list[bool] | None = None,
) -> Iterator[None]:
    """Raise ``error`` at the ``at``-th call of ``target``'s ``names`` made by this thread
    (or by the ``threads`` it says), and note it in ``tripped``."""
    calls = 0
    me = threading.current_thread()
    counts = threads or (lambda t: t is me)  # (not the message poller's calls)

    def tripping(method: Callable[..., object]) -> Callable[..., object]:
        def call(*args: object, **kwargs: object) -> object:
            nonlocal calls
            if not counts(threading.current_thread()):
                return method(*args, **kwargs)
            calls += 1
            hit = calls == at + 1
            if hit and tripped is not None:
                tripped.append(True)
            if hit and not after:
                raise error(f"tripped before call {at}")
            out = method(*args, **kwargs)
            if hit:
                raise error(f"tripped after call {at}")
            return out

        return call

    for name in names:
        setattr(target, name, tripping(getattr(target, name)))
    try:
        yield
    finally:
        for name in names:
            delattr(target, name)


@contextlib.contextmanager
def _limit_stopped(axes: str, into: list[MotionError]) -> Iterator[None]:
    """Keep the ``MotionError`` of a contour on ``axes`` a limit stopped (stop code 2 or 3 on
    one of them), or of one that ran to its end and a limit stopped a follower of on the way
    ("a follower stopped early", decision 0049), or of one that ended short of its path with
    no stop code to say why (decision 0071), in ``into`` instead of raising it (it sent the
    contour: not a refusal). One naming only followers that a limit had dropped before
    ("nobody waited for") refused the contour unsent (so does any other error)."""
    try:
        yield
    except MotionError as exc:
        own = {exc.stop_codes.get(a) for a in axes}
        text = exc.args[0]
        follower = text.startswith("a follower stopped early") and exc.axis not in axes
        # (one that ended short of its path with no stop code to say why: decision 0071)
        short = "not at the end of its path" in text
        if (
            not follower
            and not short
            and ("stopped by the controller" not in text or not {2, 3} & own)
        ):
            raise
        into.append(exc)


_Call = Callable[[], object]
_Pick = Callable[["OperationSequences", st.DataObject, str], "tuple[_Call | None, str]"]


def _waited(run: Running) -> tuple[MoveResult | None, MotionError | None]:
    """Wait for ``run``'s handle (5 s for a jog): its result, or the ``MotionError`` of a
    limit (or of a follower's), or neither (it timed out). Nothing else is read."""
    h = run.handle
    try:
        with warnings.catch_warnings():
            if run.unpredictable:  # (not the library's doing)
                warnings.simplefilter("ignore", RuntimeWarning)
            return h.wait(timeout=5.0 if math.isinf(h.duration) else None), None
    except MotionError as exc:  # a limit stopped it (or a follower of it)
        return None, exc
    except GalilTimeoutError:
        return None, None


def _wait_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    """A wait for a handle the machine holds (on ``a`` if there is one)."""
    runs = [r for r in m.running if a in r.handle.axes] or m.running
    if not runs:
        return None, ""
    run = data.draw(st.sampled_from(runs))
    return (lambda: (run, *_waited(run))), run.handle.axes


def _handle_stop_call(
    m: OperationSequences, data: st.DataObject, a: str
) -> tuple[_Call | None, str]:
    """A stop of a handle the machine holds (``ST S`` for a vector sequence: decision 0073)."""
    runs = [r for r in m.running if a in r.handle.axes] or m.running
    if not runs:
        return None, ""
    h = data.draw(st.sampled_from(runs)).handle
    axes = h.axes
    if h.kind == "vector":  # (ST S reaches the sequence running now: decision 0034)
        axes += "".join(r.handle.axes for r in m.running if r.handle.kind == "vector")
    return h.stop, "".join(dict.fromkeys(axes))


def _gear_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    master = data.draw(st.sampled_from([x for x in AXES if x != a]))
    return (lambda: m.dmc.axes[a].gear_to(master, 2.0)), a


def _other(a: str) -> str:
    return "C" if a != "C" else "B"


def _start_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    """A start (or a change) of the motion of ``a``, its arguments drawn now."""
    ax = m.dmc.axes[a]
    kind = data.draw(st.sampled_from(["move", "jog", "jog_speed", "increment", "schedule"]))
    if kind == "move":
        amount = data.draw(st.integers(-9000, 9000))
        return (lambda: ax.move_by(amount)), a
    if kind == "jog":
        speed = data.draw(st.sampled_from([-9000, 6000]))
        return (lambda: ax.jog(speed)), a
    if kind == "jog_speed":
        return (lambda: setattr(ax, "jog_speed", 4000)), a
    if kind == "increment":
        return (lambda: ax.increment(1500)), a
    return (lambda: ax.speed_schedule(9000, [(3000, 6000)], speed=12000)), a


def judge_refused_setting(
    a: str, what: str, refused: CommandError, followed: Track | None, over: bool
) -> None:
    """A setting the controller refused (TC 7, "Not valid while running"): only one it takes
    at rest, only where the library cannot know the axis moves, or its prediction (``followed``)
    had the motion ``over`` already."""
    assert what in _STILL, refused
    assert refused.code == 7, refused
    assert followed is None or over, (a, followed, refused)


def _setting_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    """SP, AC or DC, in motion or not (decision 0070); not SP in a jog, which it leaves alone
    (nothing to stop then)."""
    what = data.draw(st.sampled_from(["speed", "accel", "decel"]))
    value = data.draw(st.sampled_from(_VALUES[what]))
    handle = m.dmc.tracker.active(a)
    track = None if handle is None else handle.track(a)
    if what == "speed" and track is not None and track.kind == "jog":
        return None, a
    followed = m._followed(a)
    over = handle is not None and m.dmc.link.clock() >= handle.started_at + handle.duration

    def call() -> None:
        refused: CommandError | None = None
        try:
            setattr(m.dmc.axes[a], what, value)
        except CommandError as exc:
            refused = exc
        if refused is not None:
            judge_refused_setting(a, what, refused, followed, over)

    return call, a


def _home_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    how = data.draw(st.sampled_from(["home", "find_edge", "find_index"]))
    switch = m.sim.home_switch(a)
    return (lambda: getattr(m.dmc.axes[a], how)(switch=switch)), a


def _gearing_call(m: OperationSequences, data: st.DataObject, a: str) -> tuple[_Call | None, str]:
    """A gearing of ``a`` the machine holds turned off, or given a new ratio (decision 0069)."""
    gearing = m.gearings.get(a)
    if gearing is None:
        return None, a
    if data.draw(st.booleans()):
        return gearing.off, a
    ratio = data.draw(st.sampled_from([-0.5, 1.0, 3.0]))
    return (lambda: gearing.set_ratio(ratio)), a


#: The calls the ``interrupted`` rule interrupts: each gives the call and the axes it drives.
_INTERRUPTIBLE: dict[str, _Pick] = {
    "start": _start_call,
    "move together": lambda m, d, a: (
        (lambda: m.dmc.move({a: 4000, _other(a): -3000}, relative=True)),
        a + _other(a),
    ),
    "home": _home_call,
    "setting": _setting_call,
    "gear": _gear_call,
    "gearing": _gearing_call,
    "vector": lambda m, d, a: (
        (lambda: m.dmc.vector_move("AB", [Line(3000, -2000), Line(2000, 3000)], speed=20000)),
        "AB",
    ),
    "wait": _wait_call,
    "stop": lambda m, d, a: ((lambda: m.dmc.axes[a].stop()), a),
    "handle stop": _handle_stop_call,
}


#: What reopening a link sends (its handshake: galil.handshake): no motion, no setting.
_HANDSHAKE = re.compile(r"\x12\x16|CW [12]|EO 0")


def _queries_only(lines: list[str]) -> list[str]:
    """The lines of ``lines`` that are neither queries nor a reopened link's handshake."""
    return [
        line
        for line in lines
        if not _HANDSHAKE.fullmatch(line)
        and not all(_READ_ONLY.fullmatch(part.strip()) for part in line.split(";"))
    ]


class OperationSequences(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.dmc = galil.connect("sim://DMC-4040")
        self.sim = sim_of(self.dmc)
        self.running: list[Running] = []
        self.gearings: dict[str, Gearing] = {}
        self.program_axis_free = True
        # The sides of each axis with a switch placed (2 forward, 3 reverse: its stop code).
        self.placed: dict[str, set[int]] = {a: set() for a in AXES}
        # Gearings of the program's axis D in place while the program ran: once a limit drops
        # one, the program may move D (#SEQTRIP waits with AMD), so D's stop code no longer
        # tells of the drop, which the library learns at the master's next start.
        self.program_gears: list[GearLink] = []
        self.threads_before = set(threading.enumerate())

    # -- helpers ----------------------------------------------------------------------------
    def _settings(self) -> list[float]:
        return self.dmc.query_operands([f"_{op}{a}" for a in AXES for op in _SETTINGS])

    @contextlib.contextmanager
    def refusable(self, *allowed: type[GalilError]) -> Iterator[list[GalilError]]:
        """Run a call that may be refused with one of ``allowed``: then it sent nothing but
        queries and the axes' settings are as they were. Yields a list that then holds the
        refusal."""
        before = self._settings()
        gears = dict(self.dmc.tracker.gears)
        caught: list[GalilError] = []
        with transcript(self.dmc) as sent:
            try:
                yield caught
            except allowed as exc:
                caught.append(exc)
        if not caught:
            return
        refused = caught[0]
        others = _queries_only(sent.lines)
        assert not others, f"{type(refused).__name__} ({refused}) after sending {others!r}"
        assert self._settings() == before, f"settings changed by a refusal: {refused}"
        if (found := _SWITCH_REFUSAL.search(str(refused))) is not None:
            # A start refused for a switch: it is active and LD does not disable it (a start
            # towards a disabled switch is taken: decision 0046).
            a, side = found.groups()
            active, ld = self.dmc.query_operands([f"_L{side[0].upper()}{a}", f"_LD{a}"])
            assert not active, f"{refused}: the switch is not active"
            assert not round(ld) & (1 if side == "forward" else 2), f"{refused}: LD {ld:g}"
        if not isinstance(refused, MotionError):  # (refuse_dropped forgets the gearing)
            assert self.dmc.tracker.gears == gears, f"gearing changed by a refusal: {refused}"

    def interfere(self, letters: str = AXES, *, unpredictable: bool = False) -> None:
        for run in self.running:
            touched = set(run.handle.axes + run.handle.followers)
            if touched & set(letters):
                run.interfered = True
                run.unpredictable = run.unpredictable or unpredictable

    def limits_changed(self, letters: str) -> None:
        for run in self.running:
            if set(run.handle.axes + run.handle.followers) & set(letters):
                run.limits_changed = True

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
        self.judge_wait(run, *_waited(run))

    def judge_wait(
        self, run: Running, result: MoveResult | None, limited: MotionError | None
    ) -> None:
        """What a wait for ``run`` came to: its result, the ``MotionError`` of a limit, or
        neither (it timed out)."""
        h = run.handle
        if limited is not None:
            assert set(limited.stop_codes.values()) & {2, 3}, limited
            if run in self.running:
                self.running.remove(run)
            if not (run.interfered or run.limits_changed or run.superseded):
                self.limit_stop_explained(h, limited)
            return
        if result is None:
            assert math.isinf(h.duration) or run.interfered, h
            return
        if run in self.running:
            self.running.remove(run)
        self.check_result(run, result)

    def limit_stop_explained(self, h: MoveHandle, exc: MotionError) -> None:
        """A limit ended a move no limit changed for since it began (nor other motion on its
        axes, which would have moved them since): each axis with SC 2 (3) is beyond its
        forward (reverse) soft limit or on its active forward (reverse) switch, one LD does
        not disable (decision 0046). A sequence (or a gearing) stops as a whole with the code
        of the axis that ran into the limit, and its ramp down follows the path, which may
        take that axis back off its switch: one of its axes has such a soft limit, or such a
        switch placed that LD does not disable."""
        limited = {a: c for a, c in exc.stop_codes.items() if c in (2, 3)}
        names = [f"_{op}{a}" for a in limited for op in ("RP", "FL", "BL", "LF", "LR", "LD")]
        values = dict(zip(names, self.dmc.query_operands(names), strict=True))

        def explains(a: str, code: int, *, whole: bool) -> bool:
            rp, ld = values[f"_RP{a}"], round(values[f"_LD{a}"])
            enabled = not ld & (1 if code == 2 else 2)
            if whole:
                soft = values[f"_FL{a}"] < 2**31 - 1 if code == 2 else values[f"_BL{a}"] > -(2**31)
                return soft or (code in self.placed[a] and enabled)
            if code == 2:  # (LD leaves the soft limits on)
                return rp >= values[f"_FL{a}"] or (not values[f"_LF{a}"] and enabled)
            return rp <= values[f"_BL{a}"] or (not values[f"_LR{a}"] and enabled)

        whole = h.kind == "vector" or bool(h.followers)
        for a, code in limited.items():
            by = limited if whole else [a]
            assert any(explains(x, code, whole=whole) for x in by), (a, code, values, exc)

    def supersede(self, letters: str) -> None:
        for run in self.running:
            if set(run.handle.axes) & set(letters):
                run.superseded = True

    def started(self, handle: MoveHandle, wait: bool) -> None:
        run = Running(handle)
        if "D" in handle.axes + handle.followers and not self.program_axis_free:
            # The test's program may still begin its move on D (#SEQIF waits with AT first).
            run.interfered = run.unpredictable = True
        for old in self.running:
            if old.handle is handle:
                # An increment hands back the move in progress's own handle: what happened to
                # that move before (a stop of some of its axes) still shows in its end codes.
                run.interfered |= old.interfered
                run.unpredictable |= old.unpredictable
        self.running = [r for r in self.running if r.handle is not handle]
        self.supersede(handle.axes + handle.followers)
        self.running.append(run)
        if wait:
            self.wait(run)

    # -- setup ------------------------------------------------------------------------------
    @initialize(reconnect=st.booleans())
    def setup(self, reconnect: bool) -> None:
        if reconnect:  # (a dead link reopened by itself: a query that met it asked again)
            self.dmc.close()
            self.dmc = galil.connect("sim://DMC-4040", reconnect=True)
            self.sim = sim_of(self.dmc)
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
        self.set_setting(a, what, _VALUES[what][i])

    @rule(
        data=st.data(),
        what=st.sampled_from(["accel", "decel"]),
        i=st.integers(0, 3),
        order=st.sampled_from(["set", "stop, set", "set, stop"]),
        wait=st.booleans(),
    )
    def ramp_in_motion(
        self, data: st.DataObject, what: str, i: int, order: str, wait: bool
    ) -> None:
        """AC or DC on an axis the library moves: in a jog, in a position move (DC refused
        unsent), in the ramp down after an ST (DC taken: decision 0039); the handle's
        prediction follows (checked when it is waited for)."""
        if not self.running:
            return
        run = data.draw(st.sampled_from(self.running))
        a = data.draw(st.sampled_from(run.handle.axes))
        if order == "stop, set":
            self.dmc.stop(a)
            self.interfere(a)
        self.set_setting(a, what, _VALUES[what][i])
        if order == "set, stop":
            self.dmc.stop(a)
            self.interfere(a)
        if wait and run in self.running:
            self.wait(run)

    @rule(
        data=st.data(),
        what=st.sampled_from(["motor_type", "brush", "encoder_config"]),
        i=st.integers(0, 1),
    )
    def motor_setting(self, data: st.DataObject, what: str, i: int) -> None:
        """MT, BR and CE, "Not Valid while in motion": refused unsent while the library's own
        motion runs (decisions 0036, 0048), by the controller (TC 7) otherwise; MT also with
        the motor on, after reading ``_MO`` (decision 0043). Taken, each reads back."""
        moving = [a for r in self.running for a in r.handle.axes + r.handle.followers]
        a = data.draw(st.sampled_from(sorted(set(moving)) or list(AXES)))
        values = {"motor_type": [1, -1], "brush": [0, 1], "encoder_config": [10, 0]}
        self.set_setting(a, what, values[what][i])

    def set_setting(self, a: str, what: str, value: float) -> None:
        """Set ``what`` on ``a``: only a setting "Not Valid while in motion" may be refused,
        unsent where the library knows the axis moves, by the controller (TC 7) only where
        the library cannot know; MT is refused unsent with the motor on, taken only with it
        off (decision 0043)."""
        motor_on = what == "motor_type" and not self.dmc.query_operands([f"_MO{a}"])[0]
        handle = self.dmc.tracker.active(a)
        track = self.dmc.tracker.track(a)
        followed = self._followed(a)
        over = handle is not None and self.dmc.link.clock() >= handle.started_at + handle.duration
        by_controller: CommandError | None = None
        try:
            with self.refusable(InvalidArgument) as refused:
                self.write_setting(a, what, value)
        except CommandError as exc:
            by_controller = exc
        if refused and motor_on and "motor off" in str(refused[0]):
            pass  # MT with the motor on: the reference's "must be in the motor off state"
        elif refused:
            assert what in _STILL, (a, what, refused)
            assert track is not None, (a, what, refused)
            jog_or_stop = track.kind == "jog" or (track.kind == "position" and track.stopped)
            assert what != "decel" or not jog_or_stop, (a, track, refused)
        if by_controller is not None:
            judge_refused_setting(a, what, by_controller, followed, over)
            if followed is not None:
                # Sent because its prediction had the motion over: the controller may still
                # see its last samples, not more.
                self.dmc.sleep(0.01)
                assert not self.dmc.query_operands([f"_BG{a}"])[0], (a, followed, by_controller)
        elif not refused and what in _STILL and what != "decel":
            # Taken: then the axis was at rest (or began only since: a program), and MT
            # found the motor off; it reads back.
            assert not motor_on, f"{what} taken with {a}'s motor on"
            moving = self.dmc.query_operands([f"_BG{a}"])[0]
            assert not moving or not self._free(a), f"{what} taken while {a} moves"
            assert getattr(self.dmc.axes[a], what) == value, (a, what, value)

    def write_setting(self, a: str, what: str, value: float) -> None:
        setattr(self.dmc.axes[a], what, value)

    def _followed(self, a: str) -> Track | None:
        """The library's track of the motion on ``a`` when it predicts it to the count (a
        free axis, nothing behind its back; not homing, whose switches it does not know: its
        prediction is only the start, so "over by its prediction" says nothing)."""
        handle = self.dmc.tracker.active(a)
        track = None if handle is None else handle.track(a)
        if track is None or not track.exact or track.kind in HOMING_KINDS or not self._free(a):
            return None
        run = next((r for r in self.running if r.handle is handle), None)
        return None if run is not None and run.unpredictable else track

    @rule(
        a=axis_st,
        low=st.sampled_from([None, -20000, -5000]),
        high=st.sampled_from([None, 5000, 20000]),
    )
    def soft_limits(self, a: str, low: int | None, high: int | None) -> None:
        self.dmc.axes[a].soft_limits = (low, high)
        self.limits_changed(a)

    @rule(
        a=axis_st,
        which=st.sampled_from(["forward", "reverse"]),
        where=st.sampled_from([None, -500, 500, 3000, 15000]),
    )
    def place_limit_switch(self, a: str, which: str, where: int | None) -> None:
        """A switch ``where`` counts ahead of ``a`` in the ``which`` direction, or behind it
        (negative: ``a`` is on it at once, and a start that way needs ``LD``)."""
        here = self.sim.machine_position(a)
        pos = None if where is None else here + (where if which == "forward" else -where)
        self.sim.place_limit_switches(a, **{which: pos})
        code = 2 if which == "forward" else 3
        if pos is None:
            self.placed[a].discard(code)
        else:
            self.placed[a].add(code)
        self.interfere(a)
        self.limits_changed(a)

    @rule(
        a=axis_st,
        which=st.sampled_from(["forward", "reverse"]),
        where=st.sampled_from([-500, 500]),
        disabled=st.booleans(),
    )
    def through_switch(self, a: str, which: str, where: int, disabled: bool) -> None:
        """A switch placed ``where`` counts ahead (behind: ``a`` is on it), disabled by LD or
        not, and a waited move of 3000 counts that way: through a disabled switch it ends as
        predicted, a start on one is taken (decision 0046); an enabled one stops it, or the
        start is refused unsent (``wait`` and ``refusable`` check which)."""
        self.place_limit_switch(a, which, where)
        bit = galil.LimitDisable.FORWARD if which == "forward" else galil.LimitDisable.REVERSE
        ld = galil.LimitDisable(round(self.dmc.query_operands([f"_LD{a}"])[0]))
        self.limit_disable(a, galil.LimitDisable(ld | bit if disabled else ld & ~bit))
        self.move(a, True, 3000 if which == "forward" else -3000, True)

    @rule(a=axis_st, ld=st.sampled_from(list(galil.LimitDisable)))
    def limit_disable(self, a: str, ld: galil.LimitDisable) -> None:
        """``LD``, valid in motion (decision 0046): a disabled switch stops nothing and refuses
        no start (the refusals and the limit ends are checked against ``_LD``); a switch
        enabled under an axis moving into it stops it at once (interference). A move that only
        lost a switch since it started still ends as predicted."""
        before = galil.LimitDisable(round(self.dmc.query_operands([f"_LD{a}"])[0]))
        self.dmc.axes[a].limit_disable = ld
        assert self.dmc.axes[a].limit_disable == ld
        self.limits_changed(a)
        enabled = (before.forward and not ld.forward) or (before.reverse and not ld.reverse)
        if enabled:
            self.interfere(a)

    @rule(a=axis_st, position=st.sampled_from([0, -7000, 12000]), shift=st.booleans())
    def define_position(self, a: str, position: int, shift: bool) -> None:
        self.judge_define(
            a, position, lambda: self.dmc.axes[a].define_position(position, shift_limits=shift)
        )

    def judge_define(self, a: str, position: int, define: Callable[[], object]) -> None:
        """DP (decision 0058) by ``define``: refused unsent while the axis moves, follows a
        gearing, may lead one, or (limits kept) would be beyond a soft limit; taken, RP reads
        ``position``, the motor stays where it is, and a move nobody waited for ends in the
        old counts (so its final position is not today's RP)."""
        tracker = self.dmc.tracker
        before = self.sim.machine_position(a)
        with self.refusable(InvalidArgument, LimitError) as refused:
            define()
        if refused:
            text = str(refused[0])
            if isinstance(refused[0], LimitError) or f"axis {a} moves" in text:
                return
            if "may be the gear master" in text:  # (a program's gearing of D)
                assert "D (GR" in text, text
                assert "D" not in tracker.gears, text
            elif "is the gear master" in text:
                assert tracker.followers(a), text
            else:
                assert a in tracker.gears or a in tracker.found, text
            return
        self.supersede(a)
        self.limits_changed(a)
        assert self.dmc.query_operands([f"_RP{a}"])[0] == position
        assert self.sim.machine_position(a) == before

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
        """A jog, or a new speed for the library's jog in progress; the controller's TC 13
        only where a program may have replaced that jog by a move of its own (the library
        cannot see it: a limit stopped the jog unseen, and the program's move overwrote the
        stop code)."""
        try:
            with self.refusable(InvalidArgument, MotionError):
                self.started(self.dmc.axes[a].jog(speed), False)
        except CommandError as exc:
            self.judge_tc13(a, exc)

    @rule(a=axis_st, speed=st.sampled_from([-8000, 1000, 12000]))
    def set_jog_speed(self, a: str, speed: int) -> None:
        try:
            with self.refusable(InvalidArgument, MotionError):
                self.dmc.axes[a].jog_speed = speed
        except CommandError as exc:  # documented: a move the library did not start (TC 13)
            self.judge_tc13(a, exc)

    def judge_tc13(self, a: str, refused: CommandError) -> None:
        """JG refused by the controller: only on an axis something else moves."""
        assert not self._free(a), refused
        assert refused.code == 13, refused

    @rule(a=axis_st, n=st.sampled_from([-2000, -3, 5, 1500]))
    def increment(self, a: str, n: int) -> None:
        refused: CommandError | None = None
        try:
            with self.refusable(InvalidArgument, MotionError):
                self.started(self.dmc.axes[a].increment(n), False)
        except CommandError as exc:  # documented: a reversal of the program's move (TC 16)
            refused = exc
        if refused is not None:
            assert not self._free(a), refused
            assert refused.code == 16, refused

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
        stopped: list[MotionError] = []
        with (
            self.refusable(InvalidArgument, MotionError) as refused,
            _limit_stopped(axes, stopped),
        ):
            self.dmc.contour(axes, path, dt=3)
        if refused:
            return
        if stopped and "not at the end of its path" in stopped[0].args[0]:
            # Only where the test's program may stop or move an axis (decision 0071).
            assert not self._free(stopped[0].axis or ""), stopped[0]
            return
        if not stopped or stopped[0].args[0].startswith("a follower stopped early"):
            after = self.dmc.query_operands([f"_RP{a}" for a in axes])
            assert after == list(np.add(before, path[-1])), (before, after, stopped)
        if stopped:
            self.contour_stopped_at_a_switch(axes, stopped[0])

    def contour_stopped_at_a_switch(self, axes: str, exc: MotionError) -> None:
        """A placed switch stopped the contour (decision 0041): the whole contour is over,
        out of contour mode, and the axis that ran into it is on it. Or the contour ran to
        its end (51) and a limit stopped a follower of it on the way: the error names it, the
        follower is beyond that soft limit or on that switch, and the library forgot its
        gearing (decision 0049)."""
        assert not self.sim.room(SimContour).axes(), exc
        assert not any(self.dmc.query_operands([f"_BG{a}" for a in axes])), exc
        codes = exc.stop_codes
        for a in axes:
            if codes[a] in (2, 3) and not exc.args[0].startswith("a follower stopped early"):
                assert self.dmc.query_operands([f"_L{'F' if codes[a] == 2 else 'R'}{a}"]) == [0]
            elif self._free(a):  # (the test's program may have moved D since: its own code)
                assert codes[a] == 51, exc
        for f in set(codes) - set(axes):  # (the followers read at the contour's end)
            if f"{f}, geared to " in exc.args[0]:
                assert codes[f] in (2, 3), exc
                assert f not in self.dmc.tracker.gears, exc
                self.follower_limit_explained(f, codes[f], exc)

    def follower_limit_explained(self, f: str, code: int, exc: MotionError) -> None:
        """A follower a limit stopped (SC 2, 3) is beyond its forward (reverse) soft limit, or
        on its active forward (reverse) switch, one LD does not disable (decision 0046)."""
        ops = ("RP", "FL", "BL", "LF", "LR", "LD")
        rp, fl, bl, lf, lr, ld = self.dmc.query_operands([f"_{op}{f}" for op in ops])
        enabled = not round(ld) & (1 if code == 2 else 2)
        if code == 2:
            assert rp >= fl or (not lf and enabled), (f, rp, fl, lf, ld, exc)
        else:
            assert rp <= bl or (not lr and enabled), (f, rp, bl, lr, ld, exc)

    @rule(
        axes=st.sampled_from(["A", "BC", "AD"]),
        reach=st.integers(-3000, 3000),
        at=st.integers(0, 12),
        after=st.booleans(),
        drop=st.sampled_from([False, False, True]),
        read=st.booleans(),
    )
    def interrupted_contour(
        self, axes: str, reach: int, at: int, after: bool, drop: bool, read: bool
    ) -> None:
        """Ctrl-C at the contour's ``at``-th exchange with the controller (before it went out
        or once it did), or (``drop``) the link dying at its ``at``-th write or read, before
        or after the pre-loaded segments start (decision 0038): nothing runs on, no axis
        stays in contour mode, and the next contour works."""
        if not all(map(self._free, axes)) or not self.idle(axes):
            return  # (the contour is refused: the plain rule has that)
        path = np.outer(np.linspace(0, 1, 12), np.arange(1, len(axes) + 1) * reach).round()
        self.supersede(axes)  # (even if refused: harmless)
        interrupted = False
        stopped: list[MotionError] = []
        if drop:
            at = 2 * at + read
        trip = _dropped if drop else _interrupted
        cut = (KeyboardInterrupt, GalilConnectionError) if drop else (KeyboardInterrupt,)
        with self.refusable(InvalidArgument, MotionError):
            try:
                with _limit_stopped(axes, stopped), trip(self.dmc.link, at, after=after):
                    self.dmc.contour(axes, path, dt=3)
            except MotionError as exc:
                if not isinstance(exc.__cause__, cut):
                    raise
                interrupted = True  # (its stop not confirmed: checked below all the same)
            except cut:
                interrupted = True
        if self.dmc.link.dead:
            assert drop, "a Ctrl-C left the link dead"
            self.dmc.reconnect()
        if stopped:
            self.contour_stopped_at_a_switch(axes, stopped[0])
        if not interrupted:
            return
        self.interfere(axes + "".join(self.dmc.tracker.followers(axes)))
        contour = self.sim.room(SimContour)
        assert not contour.axes(), f"left in contour mode: {contour.axes()}"
        assert not contour.held, f"segments held: {contour.held}"
        self.dmc.sleep(0.5)  # (the ST's ramp down, at the smallest DC)
        names = [f"_{op}{a}" for a in axes for op in ("BG", "RP")]
        before = self.dmc.query_operands(names)
        self.dmc.sleep(0.5)
        assert before == self.dmc.query_operands(names), "a contour axis moves on"
        assert not any(before[0::2]), "a contour axis moves on"
        self.contour(axes, reach)

    @rule(
        data=st.data(),
        op=st.sampled_from(sorted(_INTERRUPTIBLE)),
        a=axis_st,
        at=st.integers(0, 4),
        after=st.booleans(),
        drop=st.sampled_from([False, False, True]),
    )
    def interrupted(
        self, data: st.DataObject, op: str, a: str, at: int, after: bool, drop: bool
    ) -> None:
        """Ctrl-C at the ``at``-th exchange or pause of a start, a change, a wait or a stop,
        whatever runs meanwhile, or (``drop``) the link dying at the ``at``-th write or read
        under it (decision 0028): once a line that is not a query went out, the axes the
        call drives come to rest (a stop's ramp) and stay there, every gearing engaged is
        one the library knows (the invariants), and the link stays in step (a dead one is
        reopened by ``reconnect()``, as a user would). Only queries out: the settings are
        as they were (a wait excepted: a speed schedule's routine sets SP as time passes).
        Not interrupted (``at`` beyond its calls; a query asked again on the reopened link):
        the call's handle or gearing is the machine's like any other."""
        call, letters = _INTERRUPTIBLE[op](self, data, a)
        if call is None:
            return
        if drop:
            at = 2 * at + data.draw(st.integers(0, 1), label="read")
        trip = _dropped if drop else _interrupted
        cut: tuple[type[BaseException], ...] = (KeyboardInterrupt,)
        if drop:
            cut = (KeyboardInterrupt, GalilConnectionError)
        drives = letters + "".join(self.dmc.tracker.followers(letters))
        settings_before = self._settings()
        interrupted = False
        out: object = None
        by_controller: CommandError | None = None
        unconfirmed: MotionError | None = None
        with (
            self.refusable(InvalidArgument, LimitError, MotionError) as refused,
            transcript(self.dmc) as sent,
        ):
            try:
                with trip(self.dmc.link, at, after=after):
                    out = call()
            except MotionError as exc:
                if not isinstance(exc.__cause__, cut):
                    raise
                unconfirmed, interrupted = exc, True
            except cut:
                interrupted = True
            except CommandError as exc:  # a program's move in the way (TC 13, TC 16)
                by_controller = exc
        if self.dmc.link.dead:
            assert drop, "a Ctrl-C left the link dead"
            self.dmc.reconnect()
        if unconfirmed is not None:
            # The guard's stop could not be confirmed: only where something else moves the
            # axis on (the test's program, a master).
            assert unconfirmed.moving, unconfirmed
            assert not any(map(self._free, unconfirmed.moving)), unconfirmed
        if by_controller is not None:
            assert not self._free(a), by_controller
            assert by_controller.code in (13, 16), by_controller
            return
        how = "dropped" if drop else "interrupted"
        event(f"{how} {op}: {'refused' if refused else 'ran' if not interrupted else 'cut'}")
        if refused:
            return
        if not interrupted:
            self.took(op, a, out)
            if op == "handle stop":
                self.interfere(drives)
            return
        self.interfere(drives)
        self.supersede(letters)
        if op == "gear" or (op == "gearing" and a not in self.dmc.tracker.gears):
            self.gearings.pop(a, None)
        if not _queries_only(sent.lines):
            # (A wait lets time pass: a speed schedule's routine sets SP as it goes.)
            if op != "wait":
                assert self._settings() == settings_before, f"{op} on {a}: settings changed"
            return
        event(f"{how} {op}: cut after a line went out")
        self.dmc.sleep(3.5)  # (the slowest ramp down: SP 60 000 at DC 20 480 takes 2.9 s)
        free = [x for x in drives if self._free(x)]
        names = [f"_{q}{x}" for x in free for q in ("BG", "RP")]
        before = self.dmc.query_operands(names)
        self.dmc.sleep(0.5)
        later = self.dmc.query_operands(names)
        where = f"{op} on {a} interrupted at {at} ({'after' if after else 'before'})"
        assert not any(before[0::2]), f"{where}: {free} still moving {before}"
        assert before == later, f"{where}: {free} moved on"

    def took(self, op: str, a: str, out: object) -> None:
        """An interruptible call ran to its end: keep what it started."""
        if isinstance(out, MoveHandle):
            self.started(out, False)
        elif isinstance(out, Gearing):
            self.gearings[a] = out
            self.supersede(a)
        elif isinstance(out, tuple):  # a wait: (the run, its result or the limit's error)
            run, result, limited = out
            self.judge_wait(run, result, limited)
        elif op == "stop":
            self.interfere(a)
        elif op == "gearing" and a not in self.dmc.tracker.gears:
            self.gearings.pop(a, None)  # (turned off)

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
            axes = run.handle.axes
            if run.handle.kind == "vector":  # ST S: the sequence running now (decision 0034)
                axes += "".join(r.handle.axes for r in self.running if r.handle.kind == "vector")
            self.interfere(axes)

    @rule()
    def abort(self) -> None:
        # An AB in a limit's ramp down replaces its stop code (7): the handle cannot know
        # of the limit any more, and predicts the abort of the move the limit cut short.
        codes = self.dmc.query_operands([f"_SC{a}" for a in AXES])
        limited = "".join(a for a, c in zip(AXES, codes, strict=True) if c in (2, 3))
        self.dmc.abort()
        self.interfere()
        self.interfere(limited, unpredictable=True)

    @rule(a=axis_st, on=st.booleans())
    def motor(self, a: str, on: bool) -> None:
        if on:
            # SH puts a motor-off axis's reference at its (lagging) encoder: a handle not seen
            # done keeps the end it had (decision 0036), so only the position now may differ.
            if not self.dmc.query_operands([f"_MO{a}"])[0]:
                # In motion (whoever moves it) refused unsent, not TC 7 (decision 0045).
                with self.refusable(InvalidArgument) as refused:
                    self.dmc.servo_here(a)
                if refused:  # (no time passes between the library's _BG and this one)
                    assert self.dmc.query_operands([f"_BG{a}"]) == [1], refused
                return
            self.dmc.servo_here(a)
            self.supersede(a)
        else:
            with self.refusable(InvalidArgument):  # (in motion: the controller refuses MO)
                self.dmc.motor_off(a)

    @rule(often=st.integers(0, 1))
    def burn(self, often: int) -> None:
        """``BP`` (rarely: it holds the link for the burn's time): refused unsent while the
        library's own motion runs, or a program of the user's (its TC 17: decision 0087);
        the controller's TC 7 only for motion the library did not start (a program, a
        follower), its TC 17 while a program thread runs unseen (decision 0047); burned only
        then."""
        if often:
            return
        tuning = self.sim.room(SimTuning)
        burns = tuning.burns["BP"]
        by_controller: CommandError | None = None
        try:
            with self.refusable(InvalidArgument) as refused:
                self.dmc.programs.burn()
        except CommandError as exc:
            by_controller = exc
        if refused and "TC 17" in str(refused):
            threads = range(self.dmc.model.threads)
            assert max(self.dmc.query_operands([f"_XQ{t}" for t in threads])) >= 0, refused
        elif refused:
            assert any(self.dmc.tracker.active(a) for a in AXES), refused
            assert any(self.dmc.query_operands([f"_BG{a}" for a in AXES])), refused
        elif by_controller is not None:
            *bg, xq0, xq1 = self.dmc.query_operands([f"_BG{a}" for a in AXES] + ["_XQ0", "_XQ1"])
            if by_controller.code == 17:
                assert max(xq0, xq1) >= 0, by_controller
            else:
                assert by_controller.code == 7, by_controller
                moving = [a for a, b in zip(AXES, bg, strict=True) if b]
                assert moving, by_controller
                known = [a for a in moving if self._free(a) and self._followed(a) is not None]
                assert not known, (known, by_controller)
        assert tuning.burns["BP"] == burns + (not refused and by_controller is None)

    @rule(
        values=st.lists(
            st.integers(-8_000_000_000, 8_000_000_000).map(lambda v: v / 4), min_size=1, max_size=60
        )
    )
    def array_round_trip(self, values: list[float]) -> None:
        """``QD`` then ``QU`` (bulk transfers: decisions 0064, 0067) whatever runs meanwhile:
        the array reads back what was written, and the link stays in step."""
        arrays = self.dmc.arrays
        arrays.define("fz", len(values), replace=True)
        arrays.download("fz", values)
        assert arrays.upload("fz").tolist() == values

    @rule(seconds=st.sampled_from([0.01, 0.1, 0.5, 2.0]))
    def sleep(self, seconds: float) -> None:
        self.dmc.sleep(seconds)

    @rule(data=st.data())
    def wait_one(self, data: st.DataObject) -> None:
        if self.running:
            self.wait(data.draw(st.sampled_from(self.running)))

    @rule(label=st.sampled_from(["#SEQMOVE", "#SEQIF", "#SEQTRIP"]))
    def run_program(self, label: str) -> None:
        with self.refusable(InvalidArgument):
            self.dmc.programs.download(PROGRAM)
            self.dmc.programs.run(label, thread=1)
            self.program_axis_free = False
            if (gear := self.dmc.tracker.gears.get("D")) is not None:
                self.program_gears.append(gear)
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
        gear = tracker.gears.get("D")
        running = not self.program_axis_free
        if running and gear is not None and not any(k is gear for k in self.program_gears):
            self.program_gears.append(gear)  # (geared while the program runs: it may move D)
        if values[-1] < 0 and not bg["D"]:
            self.program_axis_free = True
        sim_gears = self.sim.room(SimGearing)
        servo = sim_gears.machine.servo
        for a in AXES:
            engaged = sim_gears.geared(servo.axes[a]) is not None
            known = tracker.gears.get(a)
            if engaged:
                assert known is not None, f"{a} follows on the controller, not in the library"
            elif known is not None and not any(k is known for k in self.program_gears):
                assert known.dropped_by(sc[a]), f"the library counts on {a}'s gearing: SC {sc[a]}"
            if bg[a] and known is None and (a != "D" or self.program_axis_free):
                assert tracker.active(a) is not None, f"{a} moves and no handle drives it"

    def teardown(self) -> None:
        dmc, sim = self.dmc, self.sim
        # The test's program may move D on after the close (for ever: a host JG before its BG
        # turns that BG into a jog), and gearing stays engaged: what is geared to D, or to
        # those, follows it (a random run found B geared to the program's D moving on).
        carried = {"D"}
        gears = {f: g.master for f, g in dmc.tracker.gears.items()}
        while grown := {f for f, m in gears.items() if m in carried} - carried:
            carried |= grown
        dmc.close()
        sim.advance(30.0)
        before = [sim.motion(a).reference for a in AXES]
        sim.advance(1.0)
        after = [sim.motion(a).reference for a in AXES]
        moved = [a for a, x, y in zip(AXES, before, after, strict=True) if x != y]
        left = [t for t in threading.enumerate() if t not in self.threads_before and t.is_alive()]
        assert not left, left
        assert not moved or (set(moved) <= carried and not self.program_axis_free), moved


OperationSequences.TestCase.settings = settings(
    max_examples=EXAMPLES,
    stateful_step_count=STEPS,
    derandomize=not RANDOM,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
test_operation_sequences = OperationSequences.TestCase
