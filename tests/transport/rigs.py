"""Every transport with a real peer behind it, for the contract suite (test_contract.py).

A rig is an open transport, what its peer answers to ``MG n``, how to make the peer go away,
and the capabilities the transport must offer. Peers: a loopback TCP server thread, a pty
(pyserial and the PCI transport open its slave end; a thread answers on the master), pyserial's
``loop://``, pyusb's real code on a fake backend, and the simulator's in-process link (also as
a serial line of 9600 baud in simulated time).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from fake_usb import FakeBackend, FakeUsbDevice
from transport_peers import LineAnswerer, answer, answering, open_pty, serving_tcp

import galil.sim.link
from galil.transport import (
    ByteRate,
    ControllerClock,
    HandleSource,
    MessagesOnly,
    Transport,
    open_transport,
)

CAPABILITIES: tuple[type, ...] = (ControllerClock, HandleSource, MessagesOnly, ByteRate)

# Small enough that a pty's buffers hold every answer while the host is still writing.
USB_MAX_TRANSFER = 100


@dataclass
class Rig:
    """One transport, open, with its peer.

    Attributes:
        transport: the open transport under test.
        kind: what ``transport.kind`` must say.
        answer: the bytes the peer sends back for one command line (CR stripped), for
            ``MG <integer>`` commands.
        capabilities: the capability Protocols the transport offers, exactly.
        vanish: make the peer go away (unplug, hang up, drop the connection); ``None`` where
            nothing can (an in-process peer).
        repr_gap: why this transport's ``repr`` does not say open/closed, if it does not.
        holds: the most bytes the peer keeps before the host must read (``None``: more than
            any test writes at once).
    """

    transport: Transport
    kind: str
    answer: Callable[[bytes], bytes]
    capabilities: frozenset[type]
    vanish: Callable[[], None] | None = None
    repr_gap: str = ""
    holds: int | None = None


def _echo(line: bytes) -> bytes:
    return line + b"\r"


def _sim_answer(line: bytes) -> bytes:
    # The controller prints numbers in its default format 10.4.
    return b" " + line[3:] + b".0000\r\n:"


@contextlib.contextmanager
def tcp_rig() -> Iterator[Rig]:
    with serving_tcp() as peer:
        t = open_transport(f"tcp://127.0.0.1:{peer.port}")

        def vanish() -> None:
            assert peer.accepted.acquire(timeout=2), "the server never accepted"
            peer.drop_all()

        caps = frozenset({HandleSource, MessagesOnly, ByteRate})
        yield Rig(t, "ethernet", answer, caps, vanish)
        t.close()


@contextlib.contextmanager
def _pty_rig(address: Callable[[str], str], kind: str, caps: frozenset[type]) -> Iterator[Rig]:
    with open_pty() as pair, answering(pair) as responder:

        def vanish() -> None:
            responder.stop()
            pair.hang_up()

        t = open_transport(address(pair.path))
        yield Rig(t, kind, answer, caps, vanish)
        t.close()


def serial_pty_rig() -> contextlib.AbstractContextManager[Rig]:
    return _pty_rig(lambda path: path, "serial", frozenset({ByteRate}))


def pci_rig() -> contextlib.AbstractContextManager[Rig]:
    # A pty slave stands in for Galil's driver node: a byte stream that polls like one.
    return _pty_rig(lambda path: f"pci://{path}", "pci", frozenset())


@contextlib.contextmanager
def serial_loop_rig() -> Iterator[Rig]:
    t = open_transport("loop://")
    # pyserial's loop:// echoes through a queue of 4096 bytes; a longer write waits for reads.
    yield Rig(t, "serial", _echo, frozenset({ByteRate}), holds=4096)
    t.close()


@contextlib.contextmanager
def usb_rig() -> Iterator[Rig]:
    answerer = LineAnswerer()
    dev = FakeUsbDevice(answerer.feed, max_transfer=USB_MAX_TRANSFER)
    t = open_transport("usb://1079:4040", backend=FakeBackend(dev))

    def vanish() -> None:
        dev.unplugged = True

    yield Rig(t, "usb", answer, frozenset(), vanish)
    t.close()


@contextlib.contextmanager
def sim_rig() -> Iterator[Rig]:
    t = galil.sim.link.open_transport("sim://DMC-4040")
    yield Rig(t, "sim", _sim_answer, frozenset({ControllerClock}))
    t.close()


@contextlib.contextmanager
def sim_serial_rig() -> Iterator[Rig]:
    t = galil.sim.link.open_transport("sim://DMC-4040?baud=9600")
    yield Rig(t, "sim", _sim_answer, frozenset({ControllerClock, ByteRate}))
    t.close()


RIGS: dict[str, Callable[[], contextlib.AbstractContextManager[Rig]]] = {
    "tcp": tcp_rig,
    "serial-pty": serial_pty_rig,
    "serial-loop": serial_loop_rig,
    "usb": usb_rig,
    "pci": pci_rig,
    "sim": sim_rig,
    "sim-serial": sim_serial_rig,
}
