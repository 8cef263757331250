"""The Ethernet message handle: ``CF I`` on a second connection to the command port."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator

import pytest
from client_fakes import FakeGalil, _split

import galil.controller


class HandleServer:
    """A Galil-like TCP server: every connection is a handle; ``CF I`` claims messages."""

    def __init__(self, refuse_cf: bool = False) -> None:
        self.galil = FakeGalil()
        self.refuse_cf = refuse_cf
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.handles: list[socket.socket] = []
        self.message_handle: socket.socket | None = None
        self.claimed = threading.Event()
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            self.handles.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        while True:
            try:
                data = conn.recv(4096)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b"\r" in buf:
                line, buf = buf.split(b"\r", 1)
                for cmd in _split(line.decode("latin-1")):
                    if cmd == "CF I":
                        if self.refuse_cf:
                            conn.sendall(b"?")
                            continue
                        self.message_handle = conn
                        conn.sendall(b":")
                        self.claimed.set()
                        continue
                    reply = self.galil.answer(cmd)
                    if reply:
                        conn.sendall(reply)

    def emit(self, text: str) -> None:
        assert self.message_handle is not None
        self.message_handle.sendall(text.encode() + b"\r\n")

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.server.shutdown(socket.SHUT_RDWR)
        self.server.close()
        for h in self.handles:
            with contextlib.suppress(OSError):
                h.shutdown(socket.SHUT_RDWR)
            h.close()


@pytest.fixture
def handle_server() -> Iterator[HandleServer]:
    srv = HandleServer()
    yield srv
    srv.close()


def test_second_handle_carries_messages(handle_server: HandleServer) -> None:
    with galil.controller.connect(f"tcp://127.0.0.1:{handle_server.port}", timeout=1.0) as c:
        assert handle_server.claimed.wait(2)
        assert c.transport.secondary is not None
        assert "CW 1" not in handle_server.galil.log  # no marking needed on Ethernet
        handle_server.emit("from program")
        assert c.messages.get(timeout=2) == "from program"
        assert c.command("MG 3") == " 3"
        assert any("second Ethernet handle" in r for r in c.recent)
    assert handle_server.galil.log[-1] != "CW 2"


def test_refused_cf_falls_back_to_marking() -> None:
    srv = HandleServer(refuse_cf=True)
    try:
        with pytest.warns(RuntimeWarning, match="no second Ethernet handle"):
            c = galil.controller.connect(f"tcp://127.0.0.1:{srv.port}", timeout=1.0)
        assert srv.galil.log[-2:] == ["CW 1", "MG _GRA,_GRB,_GRC,_GRD"]
        assert c.transport.secondary is None
        assert c.command("MG 2") == " 2"
        c.close()
        assert srv.galil.log[-1] == "CW 2"
    finally:
        srv.close()


def test_unsolicited_off_leaves_the_controller_alone(handle_server: HandleServer) -> None:
    with galil.controller.connect(
        f"tcp://127.0.0.1:{handle_server.port}", timeout=1.0, unsolicited=False
    ) as c:
        assert c.command("MG 1") == " 1"
    # (a read of the gear ratios, decision 0055: nothing changed)
    assert handle_server.galil.log == ["\x12\x16", "MG _GRA,_GRB,_GRC,_GRD", "MG 1"]
    assert not handle_server.claimed.is_set()
