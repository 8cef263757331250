"""Interrupts: ``EI`` and ``UI``, sent in packets to the handle ``EI`` names.

``EI m,n,h`` enables the events of mask ``m`` (bit k < 8: axis k's profiled motion complete,
bit 8: every axis complete) and names the handle ``h`` (0-7 for A-H) the packets go to;
``EI 0`` clears the mask and the queue. ``UI n`` (0-15) queues status ``0xF0 + n``. Events
are sent at the next step boundary of the servo loop, up to sixteen per packet
(:func:`galil.protocol.interrupts.packet`).

Simplifications, where the controller does more or the sources are silent: the handle must be
a UDP handle, as on a controller (a TCP handle: TC 133); the position-error and limit-switch bits
(9, 10) and the input mask ``n`` are accepted and send nothing; a ``UI`` with no handle named
yet is accepted and its interrupt dropped (there is nowhere to send it).
"""

from __future__ import annotations

from galil.protocol.interrupts import packet
from galil.sim.machine import Machine, Room
from galil.sim.parse import Refused, split_fields
from galil.sim.ports import HANDLES
from galil.sim.registry import handler

__all__ = ["Interrupts"]

_ALL_DONE = 0xD8


class Interrupts(Room):
    """EI, UI, and the packets."""

    def __init__(self, machine: Machine) -> None:
        super().__init__(machine)
        self.reset()

    def reset(self) -> None:
        self.mask = 0
        self.inputs = 0
        self.port: int | None = None
        self.queue: list[int] = []
        self._moving: dict[str, bool] = {}

    @handler("EI")
    def ei(self, args: str) -> str:
        i = self.machine.interp
        fields = split_fields(args)
        if len(fields) > 3:
            raise Refused(6, "EI takes a mask, an input mask and a handle")
        values = [i.evaluate(f) if f.strip() else None for f in fields]
        for v, top in zip(values, (0xFFFF, 0xFF, 7), strict=False):
            if v is not None and (v != int(v) or not 0 <= v <= top):
                raise Refused(6, "EI value out of range")
        port = self.port
        if len(values) > 2 and values[2] is not None:
            handle = self.machine.ports.handle(HANDLES[int(values[2])])
            if handle.name.startswith("TCP"):
                raise Refused(133, "interrupts go to a UDP handle")
            port = handle.number
        if values[0] is not None:
            self.mask = int(values[0])
            if self.mask == 0:
                self.queue.clear()
        if len(values) > 1 and values[1] is not None:
            self.inputs = int(values[1])
        self.port = port
        self._moving = {a.letter: a.m.moving for a in self.machine.servo.axes.values()}
        return ""

    @handler("UI")
    def ui(self, args: str) -> str:
        n = self.machine.interp.evaluate(args) if args.strip() else -1
        if n != int(n) or not 0 <= n < self.machine.spec.user_interrupts:
            raise Refused(6, "UI takes 0 to 15")
        if self.port is not None:
            self.queue.append(0xF0 + int(n))
        return ""

    def port_closed(self, number: int) -> None:
        if self.port == number:
            self.port = None
            self.queue.clear()

    def service(self) -> None:
        if self.mask & 0x1FF and self.port is not None:
            self._motion_events()
        if not self.queue:
            return
        port = self.machine.ports.ports.get(self.port) if self.port is not None else None
        if port is None:
            self.queue.clear()
            return
        while self.queue:
            batch, self.queue = self.queue[:16], self.queue[16:]
            port.out += packet(batch)

    def _motion_events(self) -> None:
        before = self._moving
        now = {a.letter: a.m.moving for a in self.machine.servo.axes.values()}
        self._moving = now
        for k, letter in enumerate(now):
            if self.mask >> k & 1 and before.get(letter) and not now[letter]:
                self.queue.append(0xD0 + k)
        if self.mask >> 8 & 1 and any(before.values()) and not any(now.values()):
            self.queue.append(_ALL_DONE)
