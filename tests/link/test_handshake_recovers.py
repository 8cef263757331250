"""The handshake gets past what a controller or the way to it may say before it answers: a
download left open, stray bytes, a running program's output (decision 0089)."""

from __future__ import annotations

import contextlib
import socket
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from client_fakes import FakeGalil, SimLinkWrapper

import galil
from galil.controller import connect
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink


@dataclass
class _Say(SimLinkWrapper):
    """Bytes of its own in front of the controller's answer to the first write holding
    ``after``; every write kept in ``sent``."""

    after: bytes = b"\x12\x16"
    stray: bytes = b""
    sent: list[bytes] = field(default_factory=list)
    _due: bytes = b""

    def write(self, data: bytes) -> None:
        self.sent.append(data)
        if self.stray and self.after in data:
            self._due, self.stray = self.stray, b""
        self.inner.write(data)

    def read(self, timeout: float) -> bytes:
        got = self.inner.read(timeout)
        if self._due and got:
            got, self._due = self._due + got, b""
        return got


def _sim(**kw: bytes) -> tuple[SimController, _Say]:
    sim = SimController("DMC-4040", ManualClock())
    return sim, _Say(SimLink(sim), **kw)


def test_a_controller_left_in_download_mode_is_connected_to_and_its_download_ended() -> None:
    sim, wire = _sim()
    sim.feed(b"DL\r#A\rMG 1\r")  # a host died half way through a download (no "\" sent)
    with galil.Controller(lambda: wire, timeout=0.5) as dmc:
        assert dmc.model.name == "DMC-4040"
        assert dmc.command("MG 5") == " 5.0000"
    assert wire.sent[0] == b"\x12\x16\r"
    assert wire.sent[1].startswith(b"\\\r")  # then the resync, which ends the download


def test_a_controller_that_answers_at_once_gets_no_backslash() -> None:
    _, wire = _sim()
    with galil.Controller(lambda: wire, timeout=0.5) as dmc:
        assert dmc.model.name == "DMC-4040"
    assert not any(b"\\" in data for data in wire.sent)


@pytest.mark.parametrize(
    "stray",
    [b"::", b"Welcome\r\n:", b"Welcome\r\n"],
    ids=["colons", "a gateway's banner", "a line"],
)
def test_stray_bytes_before_the_identity_are_resynchronised_and_the_controller_identified(
    stray: bytes,
) -> None:
    _, wire = _sim(stray=stray)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dmc = galil.Controller(lambda: wire, timeout=0.5)
    with dmc:
        assert dmc.model.name == "DMC-4040"
        assert dmc.identity is not None
        assert dmc.identity.firmware == "1.2f-sim"
        assert dmc.command("MG 5") == " 5.0000"


def test_a_programs_line_before_the_identity_is_passed_over() -> None:
    # CW 2 (the factory default): an #AUTO program's MG is not marked before the link sets
    # CW 1, and comes in front of the identity; the identity is the last line, taken as is.
    _, wire = _sim(stray=b"Waiting for host\r\n")
    with galil.Controller(lambda: wire, timeout=0.5) as dmc:
        assert dmc.model.name == "DMC-4040"
        assert not any("resynchronising" in line for line in dmc.link.recent)


def test_output_in_front_of_cw_1_is_no_refusal_and_the_cw_is_restored_at_close() -> None:
    sim, wire = _sim(after=b"CW 1", stray=b"Waiting for host\r\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (no "refused CW 1")
        dmc = galil.Controller(lambda: wire, timeout=0.5)
    assert dmc.messages_room.marking
    assert dmc.command("MG _CW") == " 1.0000"
    dmc.close()
    assert sim.feed(b"MG _CW\r") == b" 2.0000\r\n:"  # the factory default, as it was


@pytest.fixture
def colons() -> Iterator[int]:
    """A TCP peer (not a Galil) that answers ``::`` to whatever it gets; its port."""
    srv = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            conn, _ = srv.accept()
            held.append(conn)
            while data := conn.recv(100):
                conn.sendall(b"::" * len(data))

    taker = threading.Thread(target=serve, daemon=True)
    taker.start()
    yield srv.getsockname()[1]
    for s in (*held, srv):
        s.close()
    taker.join(2)


def test_a_peer_that_only_answers_colons_is_a_connection_error_saying_what_arrived(
    colons: int,
) -> None:
    with pytest.raises(galil.GalilConnectionError) as info:
        connect(f"tcp://127.0.0.1:{colons}", timeout=0.2)
    text = str(info.value).splitlines()[0]
    assert f"the answer to ^R^V on the TCP link to 127.0.0.1:{colons} did not fit" in text
    assert "Ack() arrived but no command is pending" in text
    assert "could not resynchronise" in text
    assert "reconnect()" not in text  # (connect() returned no object to call it on)


def test_a_silent_peer_gets_a_resync_and_the_error_names_a_download_left_open(
    peer: FakeGalil,
) -> None:
    peer.silent = True
    with pytest.raises(galil.GalilConnectionError) as info:
        connect("fakegalil://x", timeout=0.05)
    text = str(info.value).splitlines()[0]
    assert text.startswith("no answer to ^R^V on the ")
    assert "nor a byte to the resynchronisation after it" in text
    assert "ends a download a host left open with DL" in text
    assert peer.log[:2] == ["\x12\x16", "\\"]  # ^R^V, then the resync's \ and marker
