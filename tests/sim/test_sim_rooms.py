"""The simulator's rooms: commands, operands and servo-loop hooks added without the core."""

from __future__ import annotations

import pytest
from engine_expect import TS, move

from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.registry import Args, OperandKind, function, handler, operand
from galil.sim.rooms import ROOMS, Motion, Reports, rooms_with
from galil.sim.servo import Axis, Watch


class Beeper(Room):
    """A room as a later one would be written: its own state, commands, operands and hooks.

    ``ZB n`` beeps (an unsolicited message) n samples from now, at that exact sample, however
    the host lets time pass; ``ZP x`` beeps when axis A's reference first passes x; ``_ZB`` is
    the beeps still due, ``_ZDA`` twice an axis's reference, ``@ZT[x]`` three times x.
    """

    requires = (Motion,)

    def reset(self) -> None:
        self.due: list[int] = []
        self.passing: int | None = None

    @handler("ZB")
    def zb(self, args: str) -> str:
        n = int(self.machine.interp.evaluate(args))
        if n < 1:
            raise Refused(6, "ZB needs a positive delay")
        self.due.append(self.machine.servo.sample + n)
        return ""

    @handler("ZP", Args.VALUES)
    def zp(self, fields: list[tuple[Axis, str]]) -> str:
        self.passing = int(self.machine.interp.evaluate(fields[0][1]))
        return ""

    @operand("ZB")
    def beeps_due(self) -> float:
        return len(self.due)

    @operand("ZD", kind=OperandKind.AXIS)
    def doubled(self, ax: Axis) -> float:
        return 2 * ax.m.reference

    @function("ZT")
    def tripled(self, x: float) -> float:
        return 3 * x

    def horizon(self, k: int) -> int:
        now = self.machine.servo.sample
        return min([k, *(d - now for d in self.due)])

    def watches(self, out: list[Watch]) -> None:
        if self.passing is not None:
            axes, at = self.machine.servo.axes, self.passing
            out.append(lambda: axes["A"].m.reference > at)

    def service(self) -> None:
        now = self.machine.servo.sample
        for d in [d for d in self.due if d <= now]:
            self.due.remove(d)
            self.machine.ports.emit(f"BEEP {now}\r\n")
        if self.passing is not None and self.machine.servo.axes["A"].m.reference > self.passing:
            self.passing = None
            self.machine.ports.emit(f"PASS {now}\r\n")


def beeper() -> SimController:
    return SimController("DMC-4040", ManualClock(), rooms=(*ROOMS, Beeper))


def test_a_room_from_outside_answers_its_commands_and_operands() -> None:
    sim = beeper()
    assert sim.feed(b"ZB 5;ZB 9;MG _ZB\r") == b":: 2.0000\r\n:"
    assert sim.feed(b"ZB 0\r") == b"?"
    assert sim.feed(b"PR 100;BG A\r") == b"::"
    sim.advance(1.0)
    assert sim.poll() == b"BEEP 5\r\nBEEP 9\r\n"
    assert sim.feed(b"MG _ZDA;MG _ZB\r") == b" 200.0000\r\n: 0.0000\r\n:"
    assert sim.feed(b"RS;MG _ZB\r") == b": 0.0000\r\n:"  # its reset hook ran
    assert sim.feed(b"MG @ZT[@ABS[-2]]+1\r") == b" 7.0000\r\n:"


@pytest.mark.parametrize("chunks", [[1.0], [3 * TS, 1.0], [0.001] * 40])
def test_a_room_horizon_hook_acts_at_its_exact_sample(chunks: list[float]) -> None:
    sim = beeper()
    sim.feed(b"ZB 7;ZB 20\r")
    out = b""
    for c in chunks:
        sim.advance(c)
        out += sim.poll()
    assert out == b"BEEP 7\r\nBEEP 20\r\n"


def test_a_room_watch_hook_finds_the_sample_inside_a_step() -> None:
    sim = beeper()
    sim.feed(b"ZPA=1000;PR 3000;BG A\r")
    sim.advance(1.0)  # one step for the servo loop: the watch bisects it
    refs = move(3000).advance(1024)
    first = next(i for i, r in enumerate(refs, start=1) if r > 1000)
    assert sim.poll() == f"PASS {first}\r\n".encode()


def test_a_controller_without_rooms_knows_no_command() -> None:
    sim = SimController("DMC-4040", ManualClock(), rooms=())
    assert sim.feed(b"TP;\x12\x16;MG 1\r") == b"???"
    assert sim.feed(b"x=3\r") == b":"  # variables belong to the interpreter


def test_two_rooms_cannot_answer_one_command_or_operand() -> None:
    class AnotherPR(Room):
        @handler("PR")
        def pr(self, args: str) -> str:
            return ""

    class AnotherTP(Room):
        @operand("TP", kind=OperandKind.AXIS)
        def tp(self, ax: Axis) -> float:
            return 0.0

    class AnotherABS(Room):
        @function("ABS")
        def absolute(self, x: float) -> float:
            return x

    for extra in (AnotherPR, AnotherTP, AnotherABS):
        with pytest.raises(ValueError, match="two rooms answer"):
            SimController(rooms=(*ROOMS, extra))
    with pytest.raises(ValueError, match="two rooms are a Reports"):
        SimController(rooms=(*ROOMS, type("Twice", (Reports,), {})))


def test_a_room_needs_the_rooms_it_requires() -> None:
    with pytest.raises(ValueError, match="needs Motion"):
        SimController(rooms=(Beeper,))


def test_marks_are_checked_when_written() -> None:
    with pytest.raises(ValueError, match="two upper-case letters"):
        handler("pr")
    with pytest.raises(ValueError, match="two upper-case letters"):
        operand("TPA")
    with pytest.raises(ValueError, match="upper-case letters"):
        function("in")


def test_an_override_keeps_its_command_and_a_subclass_replaces_its_room() -> None:
    class Loud(Reports):
        def tp(self, axes: list[Axis]) -> str:
            return "LOUD" + super().tp(axes)

    sim = SimController("DMC-4040", ManualClock(), rooms=rooms_with(Loud))
    assert sim.feed(b"TP A\r") == b"LOUD 0\r\n:"
    assert isinstance(sim.room(Reports), Loud)
    assert len(rooms_with(Loud)) == len(ROOMS)
