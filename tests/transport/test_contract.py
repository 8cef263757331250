"""The Transport contract, checked on every transport with a real peer behind it.

Rigs (tests/transport/rigs.py): TCP to a loopback server thread, serial over a pty and over
pyserial's ``loop://``, USB through pyusb on a fake backend, the PCI transport on a pty, and
the simulator's in-process link. Anything specific to one bus (addresses, options, device
finding, extra handles) is tested in that bus's own file.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from rigs import CAPABILITIES, RIGS, Rig
from transport_peers import read_exactly

from galil.errors import GalilConnectionError
from galil.transport import ByteRate, ControllerClock, Transport

# Peers that can go away under the transport (an in-process peer cannot).
MORTAL = ("tcp", "serial-pty", "usb", "pci")

TIMEOUT = 0.05
SLACK = 0.25  # a loaded machine may wake a reader late; never early


@pytest.fixture(params=list(RIGS))
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    with RIGS[request.param]() as opened:
        yield opened


@pytest.fixture(params=MORTAL)
def mortal_rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    with RIGS[request.param]() as opened:
        yield opened


def clock_of(t: Transport) -> Callable[[], float]:
    """The controller's clock where the transport has one (simulated time), else the host's."""
    return t.controller_time if isinstance(t, ControllerClock) else time.monotonic


def exchange(rig: Rig, data: bytes) -> bytes:
    """Write ``data`` and read back exactly the answers its command lines get."""
    want = b"".join(rig.answer(line) for line in data.split(b"\r")[:-1])
    rig.transport.write(data)
    return read_exactly(rig.transport.read, len(want))


def test_is_a_transport_of_its_kind(rig: Rig) -> None:
    t = rig.transport
    assert isinstance(t, Transport)
    assert t.kind == rig.kind
    assert t.secondary is None


def test_offers_exactly_its_capabilities(rig: Rig) -> None:
    offered = {cap for cap in CAPABILITIES if isinstance(rig.transport, cap)}
    assert offered == rig.capabilities
    if isinstance(rig.transport, ByteRate):
        assert rig.transport.byte_rate > 0


def test_write_then_read_round_trip(rig: Rig) -> None:
    assert exchange(rig, b"MG 42\r") == rig.answer(b"MG 42")
    assert exchange(rig, b"MG 1\rMG 2\r") == rig.answer(b"MG 1") + rig.answer(b"MG 2")


def test_command_written_in_two_parts_arrives_whole(rig: Rig) -> None:
    want = rig.answer(b"MG 123")
    rig.transport.write(b"MG 1")
    rig.transport.write(b"23\r")
    assert read_exactly(rig.transport.read, len(want)) == want


def test_large_write_arrives_whole(rig: Rig) -> None:
    # 18 kB in one write: more than a pty's buffer, USB's transfer size (rigs.USB_MAX_TRANSFER)
    # or one read's chunk, so transports that write in pieces must loop. (loop:// holds less.)
    count = 1500 if rig.holds is None else rig.holds // len(b"MG 100000\r")
    lines = [b"MG %d" % (100000 + i) for i in range(count)]
    want = b"".join(rig.answer(line) for line in lines)
    assert exchange(rig, b"".join(line + b"\r" for line in lines)) == want


def test_read_timeout_returns_nothing_after_about_the_time_asked(rig: Rig) -> None:
    clock = clock_of(rig.transport)
    start = clock()
    assert rig.transport.read(TIMEOUT) == b""
    assert TIMEOUT * 0.9 <= clock() - start < TIMEOUT + SLACK


def test_zero_timeout_polls(rig: Rig) -> None:
    t = rig.transport
    clock = clock_of(t)
    start = clock()
    assert t.read(0) == b""
    assert clock() - start < 0.02  # no waiting (and no simulated time passes)
    t.write(b"MG 7\r")
    want = rig.answer(b"MG 7")
    got = b""
    deadline = time.monotonic() + 2.0
    while len(got) < len(want):  # polls until the answer is there
        assert time.monotonic() < deadline, f"polling got {got!r}"
        got += t.read(0)
        if isinstance(t, ControllerClock):
            # Simulated time passes only when the host lets it (a serial line's reply takes
            # some): between two polls, as real time does between a real host's.
            t.let_time_pass(0.001)
    assert got == want


def test_close_is_idempotent_and_later_calls_raise(rig: Rig) -> None:
    t = rig.transport
    t.close()
    t.close()
    with pytest.raises(GalilConnectionError, match="closed"):
        t.write(b"MG 1\r")
    with pytest.raises(GalilConnectionError, match="closed"):
        t.read(0)


def test_repr_says_open_then_closed(rig: Rig, request: pytest.FixtureRequest) -> None:
    if rig.repr_gap:
        request.applymarker(pytest.mark.xfail(reason=rig.repr_gap, strict=True))
    t = rig.transport
    assert "open" in repr(t)
    assert "closed" not in repr(t)
    t.close()
    assert "closed" in repr(t)


def until_it_fails(operation: Callable[[], object], seconds: float = 2.0) -> None:
    """Repeat ``operation`` until it raises (returns quietly if it never does)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        operation()


def test_peer_going_away_fails_reads_with_a_connection_error(mortal_rig: Rig) -> None:
    assert mortal_rig.vanish is not None
    mortal_rig.vanish()
    # What was already on its way may still be read before the error.
    with pytest.raises(GalilConnectionError):
        until_it_fails(lambda: mortal_rig.transport.read(TIMEOUT))


def test_peer_going_away_fails_writes_with_a_connection_error(mortal_rig: Rig) -> None:
    assert mortal_rig.vanish is not None
    mortal_rig.vanish()
    # TCP takes a write or two into its buffer before the peer's reset says it is gone.
    with pytest.raises(GalilConnectionError):
        until_it_fails(lambda: mortal_rig.transport.write(b"MG 1\r"))
