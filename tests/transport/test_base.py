"""TransportBase, the shared part of the built-in transports, on a scripted handle."""

from __future__ import annotations

from collections import deque

import pytest
from rigs import CAPABILITIES

from galil.errors import GalilConnectionError
from galil.transport import Transport, timeout_grid
from galil.transport.base import TransportBase


class Handle:
    """A scripted OS handle: what it takes per send, what reads return, what it raises."""

    def __init__(self, takes: list[int] | None = None) -> None:
        self.takes = deque(takes or [])
        self.sent = b""
        self.timeouts: list[float] = []
        self.reads: deque[bytes | Exception] = deque()
        self.fail_timeout: Exception | None = None
        self.fail_release: Exception | None = None
        self.released = 0
        self.waits = 0


class Scripted(TransportBase[Handle]):
    kind = "scripted"

    def __init__(self, handle: Handle) -> None:
        super().__init__(handle, name="unit 1", label="scripted link 1")

    def _send_some(self, handle: Handle, data: memoryview) -> int:
        n = min(len(data), handle.takes.popleft()) if handle.takes else len(data)
        handle.sent += bytes(data[:n])
        return n

    def _wait_writable(self, handle: Handle) -> None:
        handle.waits += 1
        if handle.waits > 3:
            super()._wait_writable(handle)

    def _set_timeout(self, handle: Handle, seconds: float) -> None:
        if handle.fail_timeout is not None:
            raise handle.fail_timeout
        handle.timeouts.append(seconds)

    def _recv(self, handle: Handle, timeout: float) -> bytes:
        item = handle.reads.popleft() if handle.reads else b""
        if isinstance(item, Exception):
            raise item
        return item

    def _release(self, handle: Handle) -> None:
        handle.released += 1
        if handle.fail_release is not None:
            raise handle.fail_release


def test_a_subclass_is_a_transport_without_capabilities_it_lacks() -> None:
    t = Scripted(Handle())
    assert isinstance(t, Transport)
    assert not any(isinstance(t, cap) for cap in CAPABILITIES)
    assert t.secondary is None
    assert repr(t) == "<Scripted unit 1 open>"


def test_read_timeout_is_set_only_when_its_10_ms_step_changes() -> None:
    h = Handle()
    t = Scripted(h)
    for timeout in (1.0, 1.0, 0.995, 0.991, 0.05, 0.05, 0.0, -1.0, 0.0001):
        t.read(timeout)
    assert h.timeouts == [1.0, 0.05, 0.0, 0.01]
    assert timeout_grid(0.991) == 1.0


def test_a_timeout_that_failed_to_set_is_set_again() -> None:
    h = Handle()
    t = Scripted(h)
    h.fail_timeout = OSError(5, "Input/output error")
    with pytest.raises(GalilConnectionError, match="scripted link 1 failed while reading"):
        t.read(0.5)
    h.fail_timeout = None
    t.read(0.5)
    assert h.timeouts == [0.5]


def test_os_errors_become_connection_errors_naming_link_and_action() -> None:
    h = Handle()
    t = Scripted(h)
    cause = ConnectionResetError(104, "Connection reset by peer")
    h.reads.append(cause)
    with pytest.raises(GalilConnectionError) as info:
        t.read(0.1)
    assert str(info.value) == (
        "scripted link 1 failed while reading: [Errno 104] Connection reset by peer"
    )
    assert info.value.__cause__ is cause


def test_connection_errors_of_the_subclass_pass_unchanged() -> None:
    h = Handle()
    t = Scripted(h)
    own = GalilConnectionError("scripted link 1 is gone (peer hung up)")
    h.reads.append(own)
    with pytest.raises(GalilConnectionError) as info:
        t.read(0.1)
    assert info.value is own


def test_other_errors_are_not_taken_for_a_dead_link() -> None:
    h = Handle()
    t = Scripted(h)
    h.reads.append(ValueError("a bug, not the link"))
    with pytest.raises(ValueError, match="a bug"):
        t.read(0.1)


def test_write_loops_until_the_handle_took_everything() -> None:
    h = Handle(takes=[3, 0, 0, 2, 100])
    t = Scripted(h)
    t.write(b"MG 12345\r")
    assert h.sent == b"MG 12345\r"
    assert h.waits == 2  # once per piece of nothing taken


def test_write_gives_up_when_the_handle_takes_nothing() -> None:
    h = Handle(takes=[1, 0, 0, 0, 0])
    t = Scripted(h)
    with pytest.raises(GalilConnectionError, match="scripted link 1 accepted no bytes"):
        t.write(b"MG 1\r")
    assert h.sent == b"M"


def test_close_is_idempotent_and_quiet_about_a_dead_handle() -> None:
    h = Handle()
    h.fail_release = OSError(19, "No such device")
    t = Scripted(h)
    t.close()
    t.close()
    assert h.released == 1
    assert t.closed
    assert repr(t) == "<Scripted unit 1 closed>"
    with pytest.raises(GalilConnectionError, match=r"scripted link 1 is closed \(close\(\)"):
        t.write(b"x")
    with pytest.raises(GalilConnectionError, match="scripted link 1 is closed"):
        t.read(0)


def test_close_closes_the_secondary_handle() -> None:
    first, second = Scripted(Handle()), Scripted(Handle())
    first.secondary = second
    first.close()
    assert second.closed


def test_a_subclass_that_sends_nothing_says_so() -> None:
    class Mute(TransportBase[Handle]):
        kind = "mute"

        def _recv(self, handle: Handle, timeout: float) -> bytes:
            return b""

        def _release(self, handle: Handle) -> None:
            pass

    t = Mute(Handle(), name="m", label="mute link")
    with pytest.raises(NotImplementedError, match="Mute overrides neither"):
        t.write(b"x")
