"""Connecting: identification, the handshake, options, closing and reconnecting (against a
scriptable firmware stand-in, tests/client_fakes.py).
"""

from __future__ import annotations

import socket
import threading
import warnings
from typing import Any

import pytest
from client_fakes import FakeGalil

from galil.controller import Controller, connect
from galil.errors import (
    GalilConnectionError,
    InvalidArgument,
)
from galil.sim.server import SimTcpServer


def test_connect_identifies_and_marks_unsolicited(c: Controller, peer: FakeGalil) -> None:
    assert c.model.name == "DMC-4040"
    assert c.identity is not None
    assert c.identity.firmware == "1.2f"
    # (then every axis's gear ratio, read once: decision 0055)
    assert peer.log[:4] == ["\x12\x16", "MG _CW{Z10.4}", "CW 1", "MG _GRA,_GRB,_GRC,_GRD"]
    assert peer.cw == 1
    assert c.bytes_sent == len(b"\x12\x16\rMG _CW{Z10.4}\rCW 1\rMG _GRA,_GRB,_GRC,_GRD\r")
    assert c.transport.kind == "serial"
    assert "DMC-4040" in repr(c)


def test_close_restores_cw_and_is_idempotent(peer: FakeGalil) -> None:
    peer.cw = 2
    c = connect("fakegalil://x", timeout=0.2)
    assert peer.cw == 1
    c.close()
    assert peer.cw == 2
    assert peer.log[-1] == "CW 2"
    c.close()
    assert c.closed
    with pytest.raises(GalilConnectionError, match="closed"):
        c.command("TPA")


def test_context_manager_closes(peer: FakeGalil) -> None:
    with connect("fakegalil://x", timeout=0.2) as c:
        assert c.command("MG 5") == " 5"
    assert c.closed
    assert peer.links[0].closed


def test_identify_refused_with_model_warns_and_connects(peer: FakeGalil) -> None:
    peer.refuse["\x12\x16"] = 1
    with pytest.warns(RuntimeWarning, match="refused"):
        c = connect("fakegalil://x", timeout=0.2, model="DMC-4080")
    assert c.model.name == "DMC-4080"
    assert c.identity is None
    c.close()


def test_identify_refused_without_model_fails(peer: FakeGalil) -> None:
    peer.refuse["\x12\x16"] = 1
    with pytest.raises(GalilConnectionError, match=r"cannot identify.*model="):
        connect("fakegalil://x", timeout=0.2)
    assert peer.links[0].closed


def test_unknown_identity_string(peer: FakeGalil) -> None:
    peer.identity = "ACME 3000"
    with pytest.raises(GalilConnectionError, match="not a Galil identification"):
        connect("fakegalil://x", timeout=0.2)


def test_silent_peer_is_a_connection_error(peer: FakeGalil) -> None:
    peer.silent = True
    with pytest.raises(GalilConnectionError, match="no answer to \\^R\\^V"):
        connect("fakegalil://x", timeout=0.05)


def test_model_mismatch_warns_and_trusts_the_controller(peer: FakeGalil) -> None:
    with pytest.warns(RuntimeWarning, match="DMC-1806 was given but the controller says DMC4040"):
        c = connect("fakegalil://x", timeout=0.2, model="DMC-1806")
    assert c.model.name == "DMC-4040"
    c.close()


def test_cw_refused_warns_but_connects(peer: FakeGalil) -> None:
    peer.refuse["CW 1"] = 6
    with pytest.warns(RuntimeWarning, match="refused CW 1"):
        c = connect("fakegalil://x", timeout=0.2)
    assert c.command("MG 1") == " 1"
    c.close()
    assert "CW 2" not in peer.log  # nothing to restore


def test_no_handshake_sends_nothing(peer: FakeGalil) -> None:
    c = connect("fakegalil://x", handshake=False, model="DMC-4040")
    assert c.bytes_sent == 0
    assert peer.log == []
    assert c.identity is None
    c.close()
    assert peer.log == []
    with pytest.raises(InvalidArgument, match="model="):
        connect("fakegalil://x", handshake=False)


@pytest.mark.parametrize(
    "options",
    [{"model": 123}, {"handshake": "no"}, {"unsolicited": "x"}, {"echo": 1}],
)
def test_client_options_of_the_wrong_type_are_refused_before_a_byte(
    peer: FakeGalil, options: dict[str, object]
) -> None:
    with pytest.raises(InvalidArgument, match=next(iter(options))):
        connect("fakegalil://x", **options)
    assert peer.log == []


def test_transport_options_are_passed_on_and_checked(peer: FakeGalil) -> None:
    with pytest.raises(InvalidArgument, match="unknown option"):
        connect("fakegalil://x", baudrate=9600)


def test_connect_accepts_an_open_transport(peer: FakeGalil) -> None:
    c = connect(peer.open(), timeout=0.2)
    assert c.command("MG 2") == " 2"
    with pytest.raises(GalilConnectionError, match="reconnect needs an address"):
        c.reconnect()
    c.close()
    with pytest.raises(InvalidArgument, match="need an address"):
        connect(peer.open(), baudrate=1)


@pytest.mark.parametrize("bad", [0, -1, "1", True, float("nan")])
def test_bad_timeouts_are_refused(c: Controller, bad: Any) -> None:
    sent = c.bytes_sent
    with pytest.raises(InvalidArgument, match="timeout"):
        c.command("TPA", timeout=bad)
    assert c.bytes_sent == sent


def test_dead_link_and_reconnect(c: Controller, peer: FakeGalil) -> None:
    peer.links[0].dead = True
    with pytest.raises(GalilConnectionError, match="died") as info:
        c.command("MG 1")
    assert isinstance(info.value, ConnectionError)
    c.reconnect()
    assert len(peer.links) == 2
    assert c.command("MG 2") == " 2"
    assert peer.links[0].closed


def test_axes_and_letters(c: Controller) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        axes = c.axes
    assert list(axes) == ["A", "B", "C", "D"]
    assert c.A is axes["A"]
    with pytest.raises(AttributeError):
        _ = c.E
    with pytest.raises(AttributeError):
        _ = c.nothing
    assert c.sample_period == pytest.approx(1 / 1024)


def test_a_silent_tcp_peer_is_named_by_its_address_without_a_baud_rate() -> None:
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]
    held: list[socket.socket] = []
    taker = threading.Thread(target=lambda: held.append(srv.accept()[0]), daemon=True)
    taker.start()
    try:
        with pytest.raises(GalilConnectionError) as info:
            connect(f"tcp://127.0.0.1:{port}", timeout=0.2)
        text = str(info.value).splitlines()[0]
        assert f"no answer to ^R^V on the TCP link to 127.0.0.1:{port}" in text
        assert "baud" not in text  # (Ethernet has none)
        assert "<TcpTransport" not in text
    finally:
        taker.join(2)
        for s in (*held, srv):
            s.close()


def test_a_connect_the_controller_drops_says_it_may_have_no_free_handle() -> None:
    with SimTcpServer() as server:
        opened = [connect(server.url, timeout=1.0) for _ in range(4)]  # 2 handles each
        try:
            with pytest.raises(GalilConnectionError) as info:
                connect(server.url, timeout=1.0)  # all eight taken: dropped at once
            text = str(info.value)
            # (dropped once the connection was made, or reset while it was being made)
            assert "before it answered ^R^V" in text or "Connection reset" in text
            assert "no free Ethernet handle" in text
            assert "reconnect()" not in text  # (connect() returned no object to call it on)
        finally:
            for c in opened:
                c.close()


def test_a_warning_at_connect_points_at_the_callers_line() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        c = connect("sim://DMC-4040", model="DMC-4020")  # (the controller says DMC4040)
    c.close()
    assert [w.filename for w in caught if w.category is RuntimeWarning] == [__file__]


_HELD: list[socket.socket] = []  # (connections a silent peer keeps open until the test ends)


def _peer(answer: bytes, then_close: bool) -> tuple[socket.socket, threading.Thread]:
    """A TCP peer that is no Galil controller: it reads what comes, sends ``answer`` and
    closes at once (``then_close``) or keeps the connection open and says nothing more."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    held = _HELD

    def serve() -> None:
        conn, _ = srv.accept()
        conn.recv(100)
        conn.sendall(answer)
        if then_close:
            conn.close()
        else:
            held.append(conn)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return srv, thread


def test_a_peer_that_answers_and_hangs_up_is_named_not_a_galil_controller() -> None:
    srv, thread = _peer(b"HTTP/1.1 400 Bad Request\r\nconnection: close\r\n\r\n", True)
    port = srv.getsockname()[1]
    try:
        with pytest.raises(GalilConnectionError) as info:
            connect(f"tcp://127.0.0.1:{port}", timeout=1.0)
        text = str(info.value).splitlines()[0]
        assert f"what answered ^R^V on the TCP link to 127.0.0.1:{port} was " in text
        assert "b'HTTP/1.1 400 Bad Request\\r\\n" in text
        assert "that is not a Galil controller" in text
        assert "Ethernet handle" not in text
    finally:
        thread.join(2)
        srv.close()


def test_a_peer_that_says_something_else_is_quoted() -> None:
    srv, thread = _peer(b"SSH-2.0-OpenSSH_8.9\r\n", False)
    port = srv.getsockname()[1]
    try:
        with pytest.raises(GalilConnectionError) as info:
            connect(f"tcp://127.0.0.1:{port}", timeout=0.2)
        text = str(info.value).splitlines()[0]
        assert "(21 bytes came, none ending a reply: b'SSH-2.0-OpenSSH_8.9\\r\\n')" in text
    finally:
        thread.join(2)
        for s in (*_HELD, srv):
            s.close()
        _HELD.clear()
