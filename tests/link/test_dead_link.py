"""A link that dies says so, and says what to do: reconnect()."""

from __future__ import annotations

import pytest

import galil
from galil.sim.server import SimTcpServer


def _until_it_fails(dmc: galil.Controller) -> galil.GalilConnectionError:
    # The first write after the peer left may still land in the socket buffer.
    for _ in range(5):
        try:
            dmc.command("MG 1")
        except galil.GalilConnectionError as exc:
            return exc
    raise AssertionError("the dead link was never reported")


def test_dead_tcp_link_is_reported_and_reconnect_recovers() -> None:
    with SimTcpServer() as server:
        dmc = galil.connect(server.url, timeout=2.0)
        try:
            assert dmc.command("MG 1").strip() == "1.0000"
            server.stop()  # the controller goes away under the client
            assert "reconnect()" in str(_until_it_fails(dmc))
            assert "dead" in repr(dmc)
            with pytest.raises(galil.GalilConnectionError, match="died"):
                dmc.command("MG 2")
        finally:
            dmc.close()
    with SimTcpServer() as again:
        dmc = galil.connect(again.url)
        dmc.close()
        assert "closed" in repr(dmc)


def test_reconnect_after_the_server_returns() -> None:
    server = SimTcpServer()
    server.start()
    host, port = server.address
    dmc = galil.connect(server.url, timeout=2.0)
    try:
        server.stop()
        _until_it_fails(dmc)
        revived = SimTcpServer(host=host, port=port, message_port=None)
        revived.start()
        try:
            dmc.reconnect()
            assert "open" in repr(dmc)
            assert dmc.command("MG 6*7").strip() == "42.0000"
        finally:
            dmc.close()
            revived.stop()
    finally:
        dmc.close()
