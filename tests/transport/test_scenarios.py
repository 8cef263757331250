"""The same client scenarios on every bus, each with the simulator behind it.

Buses: the in-process ``sim://`` link (messages inline and on a separate handle), TCP to the
simulator's server, a pty (pyserial opens the slave; the simulator serves the master), a fake
pyusb backend whose device is the simulator (pyusb's real code path runs), and the PCI-node
transport on the simulator's pty.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import pytest
from concurrency import hammer
from fake_usb import FakeBackend, FakeUsbDevice

import galil.controller
from galil.controller import Controller
from galil.errors import CommandError, GalilConnectionError, GalilTimeoutError
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimPtyServer, SimTcpServer


@dataclass
class Bus:
    """One way of reaching a simulated controller."""

    name: str
    controller: Controller
    sim: SimController
    threads_commands: int  # commands per thread in the 8-thread scenario
    marks: bool  # unsolicited output shares the command stream (CW1 marking)


def _sim_inline() -> Iterator[Bus]:
    c = galil.controller.connect("sim://DMC-4040")
    yield Bus("sim", c, c.transport.controller, 400, True)  # type: ignore[attr-defined]
    c.close()


def _sim_separate() -> Iterator[Bus]:
    c = galil.controller.connect("sim://DMC-4040?messages=separate")
    yield Bus("sim-separate", c, c.transport.controller, 100, False)  # type: ignore[attr-defined]
    c.close()


def _tcp() -> Iterator[Bus]:
    with SimTcpServer(model="DMC-4040") as srv:
        host, port = srv.address
        c = galil.controller.connect(
            f"tcp://{host}:{port}", message_port=srv.message_address[1], timeout=2.0
        )
        yield Bus("tcp", c, srv.controller, 40, False)
        c.close()


def _pty_serial() -> Iterator[Bus]:
    with SimPtyServer(model="DMC-4040") as srv:
        c = galil.controller.connect(srv.path, timeout=2.0)
        yield Bus("pty", c, srv.controller, 40, True)
        c.close()


def _pci() -> Iterator[Bus]:
    with SimPtyServer(model="DMC-4040") as srv:
        c = galil.controller.connect(f"pci://{srv.path}", timeout=2.0)
        yield Bus("pci", c, srv.controller, 40, True)
        c.close()


def _usb() -> Iterator[Bus]:
    sim = SimController("DMC-4040", RealTimeClock())
    lock = threading.Lock()

    def respond(data: bytes) -> bytes:
        with lock:
            return sim.feed(data)

    def poll() -> bytes:
        with lock:
            return sim.poll()

    dev = FakeUsbDevice(respond, poll=poll)
    c = galil.controller.connect("usb://1079:4040", backend=FakeBackend(dev), timeout=2.0)
    yield Bus("usb", c, sim, 40, True)
    c.close()


BUSES: dict[str, Callable[[], Iterator[Bus]]] = {
    "sim": _sim_inline,
    "sim-separate": _sim_separate,
    "tcp": _tcp,
    "pty": _pty_serial,
    "pci": _pci,
    "usb": _usb,
}


@pytest.fixture(params=list(BUSES))
def bus(request: pytest.FixtureRequest) -> Iterator[Bus]:
    yield from BUSES[request.param]()


def test_identifies_the_model(bus: Bus) -> None:
    c = bus.controller
    assert c.model.name == "DMC-4040"
    assert c.identity is not None
    assert c.identity.raw_model == "DMC4040"
    assert c.transport.kind in ("sim", "ethernet", "serial", "pci", "usb")


def test_commands_and_queries(bus: Bus) -> None:
    c = bus.controller
    assert c.command("speed=2500") == ""
    assert c.query_number("MG speed") == 2500
    assert c.query_operands(["speed", "_TPA", "_TPB"]) == [2500, 0, 0]
    assert c.command("PRA=1000") == ""
    assert c.query_number("MG _PRA") == 1000


def test_rejection_is_explained(bus: Bus) -> None:
    c = bus.controller
    c.command("MO A")
    with pytest.raises(CommandError) as info:
        c.command("BG A")
    err = info.value
    assert err.code == 20
    assert "motor off" in err.text.lower()
    assert err.command == "BG A"
    assert err.model == "DMC-4040"
    assert "rejected by DMC-4040" in str(err)
    c.command("SH A")
    assert c.command("MG 1") in (" 1.0000", "1.0000")


def test_unsolicited_messages_stay_out_of_replies(bus: Bus) -> None:
    c = bus.controller
    q = c.messages
    bus.sim.emit_message("limit reached")
    assert q.get(timeout=5) == "limit reached"
    bus.sim.emit_message("second")
    assert c.query_number("MG 5") == 5
    assert q.get(timeout=5) == "second"


def test_timeout_then_resync(bus: Bus) -> None:
    c = bus.controller
    with pytest.raises(GalilTimeoutError):
        c.command("BV", timeout=0.05)  # the controller holds the ':' while it burns
    # The late ':' of BV must not be taken for the next reply.
    assert c.query_number("MG 77", timeout=3.0) == 77
    assert c.query_number("MG 78") == 78


def test_eight_threads_get_their_own_replies(bus: Bus) -> None:
    assert hammer(bus.controller, threads=8, per_thread=bus.threads_commands) == []


def test_close_restores_marking(bus: Bus) -> None:
    c = bus.controller
    assert bus.sim._cw == (1 if bus.marks else 2)
    c.close()
    assert bus.sim._cw == 2
    assert c.closed
    with pytest.raises(GalilConnectionError):
        c.command("MG 1")


def test_many_commands_on_the_in_process_link() -> None:
    """Thousands of commands from 8 threads at once, each getting its own reply."""
    c: Controller
    with galil.controller.connect("sim://DMC-4040") as c:
        errors: list[str] = []

        def worker(k: int) -> None:
            for i in range(500):
                n = k * 10000 + i
                reply = c.command(f"MG {n}")
                if float(reply) != n:
                    errors.append(f"{n}: {reply!r}")

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        assert c.bytes_sent > 8 * 500 * len("MG 0\r")
