"""``connect(..., reconnect=True)``: a long-running script survives a dropped link. Queries are
asked again on the new link; a command that may have changed something is never repeated."""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator

import numpy as np
import pytest

import galil
from galil.sim.clock import ManualClock, RealTimeClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink
from galil.sim.proxy import FaultProxy
from galil.sim.server import SimTcpServer

FAST = galil.ReconnectPolicy(attempts=3, delay=0.01)


@contextlib.contextmanager
def _dr_stream_through_a_cable(
    period: int, reconnect: galil.ReconnectPolicy | None = FAST
) -> Iterator[tuple[galil.Controller, FaultProxy, galil.RecordStream]]:
    """A real-time simulator behind a cable that can be cut, a controller on it (with the
    automatic reconnect, unless ``reconnect`` is None) and a DR record stream."""
    sim = SimController("DMC-4040", RealTimeClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address) as proxy,
        galil.connect(proxy.url, reconnect=reconnect, timeout=1.0) as dmc,
        dmc.records(period, method="DR") as stream,
    ):
        yield dmc, proxy, stream


def test_a_query_survives_a_pulled_cable_and_the_reconnect_is_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    sim = SimController("DMC-4040", ManualClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address) as proxy,
        galil.connect(proxy.url, reconnect=FAST, timeout=1.0) as dmc,
    ):
        assert dmc.query_number("MG 1") == 1
        with caplog.at_level(logging.WARNING, logger="galil.controller"):
            proxy.cut()
            assert dmc.query_number("MG 2") == 2
            proxy.cut()
            assert dmc.query_operands(["_TPA", "_TPB"]) == [0, 0]
        assert sum("reconnected" in r.getMessage() for r in caplog.records) == 2
        assert proxy.connections >= 4  # command and message handles, twice over


def test_a_command_that_may_have_run_is_not_sent_twice() -> None:
    sim = SimController("DMC-4040", ManualClock())
    with (
        SimTcpServer(sim) as server,
        FaultProxy(server.address) as proxy,
        galil.connect(proxy.url, reconnect=FAST, timeout=1.0) as dmc,
    ):
        dmc.command("count=0")
        proxy.cut()
        with pytest.raises(galil.GalilConnectionError, match="not sent again"):
            dmc.command("count=count+1")
        assert dmc.query_number("MG count") in (0, 1)  # at most once, never twice
        assert dmc.query_number("MG 3") == 3  # and the link works again


def test_a_data_record_stream_goes_on_after_a_reconnect() -> None:
    with _dr_stream_through_a_cable(64) as (dmc, proxy, stream):
        dmc.sleep(0.2)
        assert stream.get(timeout=2) is not None
        proxy.cut()
        assert dmc.query_number("MG 4") == 4  # finds the link dead, reopens it
        stream.take(len(stream) + 1)  # drain what came before
        dmc.sleep(0.2)
        after = stream.get(timeout=2)
        assert int(after["sample"]) > 0


def test_without_an_address_there_is_no_automatic_reconnect() -> None:
    sim = SimController("DMC-4040", ManualClock())

    with pytest.raises(galil.InvalidArgument, match="address"):
        galil.connect(SimLink(sim), reconnect=True)
    for bad in ("yes", 3, galil.ReconnectPolicy):
        with pytest.raises((galil.InvalidArgument, TypeError)):
            galil.connect("sim://DMC-4040", reconnect=bad)
    with pytest.raises(galil.InvalidArgument):
        galil.ReconnectPolicy(attempts=0)


def _swapped() -> tuple[galil.Controller, list[SimController]]:
    """A controller whose link reaches a DMC-4040 first, and a DMC-4020 once reopened (the
    controller at the address swapped, the address reused)."""
    from galil.controller import Controller

    sims = [SimController("DMC-4040", ManualClock()), SimController("DMC-4020", ManualClock())]
    opened: list[SimLink] = []

    def factory() -> SimLink:
        opened.append(SimLink(sims[min(len(opened), 1)]))
        return opened[-1]

    return Controller(factory, timeout=0.5, reconnect=FAST), sims


@pytest.mark.parametrize("how", ["automatic", "reconnect()"])
def test_a_reopen_that_finds_another_controller_is_refused_and_the_link_stays_dead(
    how: str, caplog: pytest.LogCaptureFixture
) -> None:
    dmc, _ = _swapped()
    try:
        assert dmc.query_numbers("TP") == [0, 0, 0, 0]
        dmc.transport.close()  # the first controller goes away
        reopen = (lambda: dmc.query_numbers("TP")) if how == "automatic" else dmc.reconnect
        with (
            caplog.at_level(logging.WARNING, logger="galil.controller"),
            pytest.raises(galil.GalilConnectionError) as info,
        ):
            reopen()
        text = str(info.value)
        assert "reopened to a DMC4020" in text
        assert "not the DMC4040" in text
        assert dmc.link.dead
        assert dmc.model.name == "DMC-4040"  # nothing learned from the other controller
        assert list(dmc.axes) == ["A", "B", "C", "D"]
        with pytest.raises(galil.GalilConnectionError):
            dmc.query_numbers("TP")
        if how == "automatic":
            assert "reconnect 1/3 to DMC-4040 failed" in caplog.text
    finally:
        dmc.close()


def _pulled_while_iterating(stream: galil.RecordStream, proxy: FaultProxy) -> list[int]:
    """Iterate ``stream``, pulling the cable after 3 records, until 3 records came over the
    reopened link (at most 10 s)."""
    times: list[int] = []
    connections = proxy.connections
    after = 0
    start = time.monotonic()
    for rec in stream:
        times.append(int(rec["time"]))
        if len(times) == 3:
            connections = proxy.connections
            proxy.cut()
        after += len(times) > 3 and proxy.connections > connections
        if after == 3 or time.monotonic() - start > 10:
            break
    assert after == 3
    return times


def test_a_loop_over_a_record_stream_goes_on_through_a_reconnect() -> None:
    with _dr_stream_through_a_cable(16) as (_, proxy, stream):
        times = _pulled_while_iterating(stream, proxy)  # the loop alone reopens the link
        assert np.all(np.diff(times) > 0)
        assert not stream.closed


def test_a_loop_over_a_record_stream_whose_link_dies_raises() -> None:
    with _dr_stream_through_a_cable(16, reconnect=None) as (_, proxy, stream):

        def pull_after_three() -> None:
            for n, _ in enumerate(stream, 1):
                if n == 3:
                    proxy.cut()

        with pytest.raises(galil.GalilConnectionError):
            pull_after_three()
        assert not stream.closed
        stream.close()
        assert list(stream) == []  # closed by the user: the loop just ends


def test_records_lost_while_a_reconnect_reopens_the_stream_are_counted_missed() -> None:
    with _dr_stream_through_a_cable(64) as (dmc, proxy, stream):
        times: list[int] = []
        stream.subscribe(lambda rec: times.append(int(rec["time"])))
        stream.take(3)
        proxy.cut()
        time.sleep(0.3)  # (the controller's clock runs on: records are sent to no one)
        assert dmc.query_number("MG 4") == 4  # finds the link dead, reopens it
        stream.take(len(stream) + 3)
        steps = np.diff(times)
        lost = [(t, round(d / 64) - 1) for t, d in zip(times[1:], steps, strict=True) if d > 64]
        assert lost
        assert stream.gaps == lost
        assert stream.missed == sum(n for _, n in lost)
