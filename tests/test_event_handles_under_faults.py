"""A new handle for data records or interrupts whose ``MG _WH`` is answered badly: a typed
error, the handle freed on the controller too (eight handles run out), the link in step."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from concurrency import handles_closed

import galil
from galil.errors import CommandError, ProtocolError
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer

ANSWERS = [
    (b" 9.0000\r\n:", ProtocolError),  # not a handle 0..7
    (b" x\r\n:", ProtocolError),
    (b"?", CommandError),
]

OPEN: dict[str, Callable[[galil.Controller], object]] = {
    "records": lambda dmc: dmc.records(8),
    "interrupts": lambda dmc: dmc.interrupts.enable("A"),
}


@pytest.mark.parametrize("what", list(OPEN))
def test_a_handle_whose_number_is_answered_badly_is_freed_and_the_link_stays_in_step(
    what: str,
) -> None:
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as srv, galil.connect(srv.url, timeout=0.5) as dmc:
        dmc.record()  # the layout (QZ) is known: the next records() sends no QZ
        for answer, error in ANSWERS * 3:  # 9 handles: more than the controller has
            srv.faults = lambda _data, answer=answer: [(0.0, answer)]  # on new handles only
            with pytest.raises(error):
                OPEN[what](dmc)
            srv.faults = None
            assert "UDP" not in sim.describe_handles()  # IHm=>-1 sent for it
            handles_closed(sim, 2)
            assert dmc.query_number("MG 1") == 1
            assert not dmc.interrupts.enabled
        OPEN[what](dmc)  # and the controller still has handles for the next one
