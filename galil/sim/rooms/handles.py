"""Handles: ``TH``, ``CF``, ``WH``, closing one with ``IH`` and the status byte ``TB``.

The handles themselves (their letters, their output, the routing of unsolicited output) are the
core's :class:`~galil.sim.ports.Ports`; this room answers the commands about them. ``CF I``
routes unsolicited output to the handle that sends it (how a host claims its messages), ``CF S``
back to the main port, ``CF A``-``CF H`` to a named handle. ``IHm=>-1`` closes handle ``m``
(``S``: the one the command came on); ``IHT=>-1``, ``-2`` and ``-3`` close every other UDP
handle, TCP handle, or handle (driver code: gclib's HwIO, the EPICS driver; opening a handle
with ``IH`` is not simulated).
"""

from __future__ import annotations

from galil.sim.machine import Room
from galil.sim.parse import Refused
from galil.sim.ports import HANDLES, Port
from galil.sim.registry import handler, operand
from galil.sim.rooms.records import Records

__all__ = ["Handles"]


class Handles(Room):
    """TH, CF, WH, IH (closing), TB."""

    requires = (Records,)

    @handler("TH")
    def th(self, args: str) -> str:
        # A model without Ethernet (DMC-1500 serial, the PCI cards) has no handles to tell:
        # refused as a command it does not have [unsourced: the code it answers].
        if not self.machine.spec.has_ethernet:
            raise Refused(1, "TH on a model without Ethernet")
        return self.machine.ports.describe()

    @handler("CF")
    def cf(self, args: str) -> str:
        ports = self.machine.ports
        caller = self.machine.interp.caller
        a = args.strip().upper()
        if a == "I":
            if not isinstance(caller, Port):
                raise Refused(6, "CF I names the sending handle; a program has none")
            ports.route = caller.number
        elif a == "S":
            # The main port: on the simulator's TCP server, its message port.
            ports.route = None
        elif len(a) == 1 and a in HANDLES:
            ports.route = ports.handle(a).number
        else:
            raise Refused(6, "CF takes I, S or a handle letter A-H")
        return ""

    @handler("IH", equals=True)
    def ih(self, args: str) -> str:
        target, arrow, value = args.strip().upper().partition("=>")
        if not arrow or not target:
            raise Refused(6, "the simulator's IH only closes handles: IHm=>-1, IHT=>-1/-2/-3")
        caller = self.machine.interp.caller
        own = caller.number if isinstance(caller, Port) else None
        ports = self.machine.ports
        if target == "T" and value in ("-1", "-2", "-3"):
            kinds = {"-1": ("UDP",), "-2": ("TCP",), "-3": ("UDP", "TCP")}[value]
            doomed = [
                p.number
                for p in ports.ports.values()
                if p.letter and p.number != own and p.name.startswith(kinds)
            ]
        elif value == "-1" and target == "S":
            if own is None or not isinstance(caller, Port) or not caller.letter:
                raise Refused(6, "IHS names the sending handle; this is not one")
            doomed = [own]
        elif value == "-1" and len(target) == 1 and target in HANDLES:
            doomed = [ports.handle(target).number]
        else:
            raise Refused(6, "the simulator's IH only closes handles: IHm=>-1, IHT=>-1/-2/-3")
        for number in doomed:
            self.machine.close_port(number)
        return ""

    @handler("WH")
    def wh(self, args: str) -> str:
        if args.strip():
            raise Refused(6, "WH takes no argument")
        caller = self.machine.interp.caller
        if isinstance(caller, Port) and caller.letter:
            return f"IH{caller.letter}\r\n"
        return "RS232\r\n"

    @operand("WH")
    def handle_number(self) -> float:
        caller = self.machine.interp.caller
        if isinstance(caller, Port) and caller.letter:
            return float(HANDLES.index(caller.letter))
        return -1.0

    @handler("TB")
    def tb(self, args: str) -> str:
        if args.strip():
            raise Refused(6, "TB takes no argument")
        return self.machine.interp.num(self.status_byte(), "3.0") + "\r\n"

    @operand("TB")
    def status_byte(self) -> float:
        """Program running (b7), data record active (b6), contouring (b5), echo (b0)."""
        m = self.machine
        value = 0x80 if m.programs.threads else 0
        if any(ax.contour for ax in m.servo.axes.values()):
            value |= 0x20
        if m.room(Records).stream is not None:
            value |= 0x40  # "data record active" on the families that report it
        return value | (1 if m.ports.echo else 0)
