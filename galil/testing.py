"""Helpers for testing your own scripts against the simulator, without hardware.

::

    from galil.testing import simulated, nothing_sent

    def test_my_scan():
        with simulated("DMC-4040") as dmc:      # a Controller on an in-process simulator
            run_my_scan(dmc)                      # waits advance simulated time, not real time
            assert dmc.A.reference_position == 1000

In a ``conftest.py``, ``from galil.testing import galil_sim`` gives a ``galil_sim`` fixture.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

from galil.controller import Controller, connect
from galil.errors import InvalidArgument
from galil.protocol.commands import READ_FORMAT
from galil.sim.controller import SimController

__all__ = ["Transcript", "nothing_sent", "sim_of", "simulated", "transcript"]


@contextlib.contextmanager
def simulated(model: str = "DMC-4040", **options: object) -> Iterator[Controller]:
    """A :class:`~galil.controller.Controller` connected to a fresh in-process simulator.

    The simulator runs on a manual clock: time passes only while the client waits for a reply
    or pauses (``controller.sleep``, ``MoveHandle.wait``), so tests run at simulation speed and
    never depend on the machine's speed.

    Args:
        model: the simulated model.
        **options: passed to :func:`galil.connect` (e.g. ``timeout``).
    """
    dmc = connect(f"sim://{model}", **options)
    try:
        yield dmc
    finally:
        dmc.close()


def sim_of(controller: Controller) -> SimController:
    """The simulator behind an in-process ``sim://`` connection.

    Raises:
        InvalidArgument: the controller is not connected to an in-process simulator.
    """
    sim = getattr(controller.transport, "controller", None)
    if sim is None or not hasattr(sim, "set_limit_switch"):
        raise InvalidArgument("this controller is not connected to an in-process simulator")
    return sim  # type: ignore[no-any-return]


@dataclass
class Transcript:
    """The command lines a block sent, in order (CR stripped)."""

    lines: list[str] = field(default_factory=list)
    raw: bytearray = field(default_factory=bytearray)

    def assert_sent(self, expected: Sequence[str]) -> None:
        """Assert the block sent exactly these lines (compound lines as sent, e.g. ``PAA=1;BGA``).

        Raises:
            AssertionError: with both transcripts.
        """
        if list(expected) != self.lines:
            raise AssertionError(f"sent {self.lines!r}, expected {list(expected)!r}")

    def assert_contains(self, line: str) -> None:
        """Assert one sent line equals ``line``."""
        if line not in self.lines:
            raise AssertionError(f"{line!r} was not sent; sent {self.lines!r}")


@contextlib.contextmanager
def transcript(controller: Controller) -> Iterator[Transcript]:
    """Record every command line the block sends over ``controller``'s command link."""
    record = Transcript()

    def hook(direction: str, data: bytes) -> None:
        if direction == "out":
            record.raw += data
            text = data.decode("latin-1")
            record.lines += [part for part in text.split("\r") if part]

    remove = controller.wire_log.add(hook)
    try:
        yield record
    finally:
        remove()


# Lines that only read: operands, variables and array elements or sizes (MG), the program
# (UL), array listings, and the explanation of a '?' (TC1, and the quoted marker the link
# sends behind it).
_MG_ITEM = rf"[_A-Za-z][_A-Za-z0-9]*(?:\[-?\d+\])?(?:{re.escape(READ_FORMAT)})?"
_READ_ONLY = re.compile(
    rf"MG {_MG_ITEM}(?:\s*,\s*{_MG_ITEM})*|UL|LA|LV|QU [A-Za-z0-9\[\],]*|QZ|TC1|MG \"TCOK\d+\""
)


@contextlib.contextmanager
def nothing_sent(controller: Controller, *, allow_queries: bool = False) -> Iterator[Transcript]:
    """Assert the block puts no byte on the wire (e.g. around a call that must be refused).

    Args:
        controller: the connection to watch.
        allow_queries: accept lines that only read operands or variables (``MG _RPA,_BLA``):
            for refusals that need the controller's state (a soft limit, a busy axis), where
            what matters is that nothing that changes the controller went out.

    Yields:
        The :class:`Transcript` of what was sent (empty unless ``allow_queries``).

    Raises:
        AssertionError: something (else) was written; the message shows what.
    """
    before = controller.bytes_sent
    with transcript(controller) as record:
        yield record
    if allow_queries:
        others = [
            line
            for line in record.lines
            if not all(_READ_ONLY.fullmatch(part.strip()) for part in line.split(";"))
        ]
        if others:
            raise AssertionError(f"commands other than queries went onto the wire: {others!r}")
        return
    if controller.bytes_sent != before or record.raw:
        raise AssertionError(f"bytes went onto the wire: {bytes(record.raw)!r}")


try:  # the fixture only exists where pytest does
    import pytest
except ImportError:  # pragma: no cover - pytest is a test-time dependency
    pass
else:

    @pytest.fixture
    def galil_sim() -> Iterator[Controller]:
        """A Controller on a fresh in-process DMC-4040 simulator (manual clock)."""
        with simulated() as dmc:
            yield dmc
