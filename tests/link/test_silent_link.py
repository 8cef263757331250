"""A resynchronisation that hears not one byte marks the link dead (decision 0089); one that
hears a reply still draining, or waits behind a burn, leaves it open (decision 0081)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from client_fakes import SimLinkWrapper

import galil
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.proxy import FaultProxy
from galil.sim.server import SimTcpServer

FAST = galil.ReconnectPolicy(attempts=3, delay=0.01)


@pytest.fixture
def proxy() -> Iterator[FaultProxy]:
    """A simulator behind a loopback proxy that can fall silent without closing anything."""
    sim = SimController("DMC-4040", ManualClock())
    with SimTcpServer(sim) as server, FaultProxy(server.address) as proxy:
        yield proxy


def test_a_tcp_link_gone_silent_without_closing_is_reopened_by_the_automatic_reconnect(
    proxy: FaultProxy, caplog: pytest.LogCaptureFixture
) -> None:
    with galil.connect(proxy.url, reconnect=FAST, timeout=0.3) as dmc:
        assert dmc.query_number("MG 1") == 1
        proxy.hush()  # a switch restarted: no reset reaches the host, nothing more comes
        with pytest.raises(galil.GalilTimeoutError):
            dmc.query_number("MG 2")  # (a slow reply, for all the link can tell yet)
        with caplog.at_level(logging.WARNING, logger="galil.controller"):
            assert dmc.query_number("MG 3") == 3  # its resync hears nothing: reopened
        assert "not one byte came back" in caplog.text
        assert "reconnected" in caplog.text
        assert not dmc.link.dead
        assert dmc.query_number("MG 4") == 4


def test_a_tcp_link_gone_silent_without_a_policy_is_dead_and_says_reconnect(
    proxy: FaultProxy,
) -> None:
    with galil.connect(proxy.url, timeout=0.3) as dmc:
        proxy.hush()
        with pytest.raises(galil.GalilTimeoutError):
            dmc.command("MG 2")
        with pytest.raises(galil.GalilConnectionError) as info:
            dmc.command("MG 3")
        message = str(info.value)
        assert "not one byte came back within 0.3 s" in message
        assert "call reconnect()" in message
        assert "burn" not in message  # nothing was burned: no burn to blame
        assert dmc.link.dead
        assert "dead" in repr(dmc)
        with pytest.raises(galil.GalilConnectionError, match=r"died .*reconnect\(\)"):
            dmc.command("MG 4")  # at once, without another wait
        dmc.reconnect()
        assert dmc.query_number("MG 5") == 5


@dataclass
class _Draining(SimLinkWrapper):
    """A reply that keeps arriving (a line per read, as a long ``UL`` on a slow line) until
    ``until`` on the controller's clock, while the controller gets nothing written."""

    until: float = -1.0

    def write(self, data: bytes) -> None:
        if self.inner.controller_time() >= self.until:
            self.inner.write(data)

    def read(self, timeout: float) -> bytes:
        if self.inner.controller_time() < self.until:
            self.inner.let_time_pass(0.01)  # (a line takes its time, even to a zero timeout)
            return b"#LINE\r\n"
        return self.inner.read(timeout)


def test_a_resync_that_hears_a_reply_still_draining_leaves_the_link_open_and_blames_no_burn() -> (
    None
):
    wire = _Draining(SimLink(SimController("DMC-4040", ManualClock())))
    with galil.Controller(lambda: wire, timeout=0.2) as dmc:
        wire.until = wire.controller_time() + 1.0  # a second of reply to come
        with pytest.raises(galil.GalilTimeoutError):
            dmc.command("MG 1")
        with pytest.raises(galil.GalilConnectionError) as info:
            dmc.command("MG 2")  # gives up after its 0.2 s, not when the bytes stop
        message = str(info.value)
        assert "bytes came but not the answer to its marker" in message
        assert "try again once it is done" in message
        assert "burn" not in message
        assert not dmc.link.dead
        assert wire.controller_time() < wire.until
        wire.until = -1.0  # the reply is over
        assert dmc.command("MG 3") == " 3.0000"


@dataclass
class Rebooting(SimLinkWrapper):
    """After ``RS`` the controller hears and says nothing for ``boot`` s of its clock."""

    boot: float = 2.5
    until: float = -1.0

    def write(self, data: bytes) -> None:
        if self.inner.controller_time() < self.until:
            return  # booting
        self.inner.write(data)
        if b"RS\r" in data:
            self.inner.read(0)
            self.until = self.inner.controller_time() + self.boot

    def read(self, timeout: float) -> bytes:
        if self.inner.controller_time() < self.until:
            self.inner.let_time_pass(timeout)
            return b""
        return self.inner.read(timeout)


@pytest.mark.parametrize("boot", [2.5, 30.0])
def test_a_reset_waits_out_a_silent_reboot_on_a_link_without_an_address(boot: float) -> None:
    # A controller built on a transport object cannot be reopened: a reboot's silence, longer
    # than the link's timeout, must not mark its link dead (decision 0089 amended). A reboot
    # longer than reset()'s timeout fails, and says the controller is still silent.
    wire = Rebooting(SimLink(SimController("DMC-4040", ManualClock())), boot=boot)
    dmc = galil.Controller(wire, timeout=0.5)
    try:
        if boot < 10:
            dmc.reset(timeout=10)
            assert dmc.query_number("MG 7") == 7
        else:
            with pytest.raises(galil.GalilConnectionError, match="still silent after its reset"):
                dmc.reset(timeout=3)
        assert not dmc.link.dead
    finally:
        dmc.close()
