"""Controller behaviour against a scriptable firmware stand-in (tests/client_fakes.py)."""

from __future__ import annotations

import logging
import queue
import threading
import warnings
from collections.abc import Iterator
from typing import Any
from urllib.parse import SplitResult

import pytest
from client_fakes import FakeGalil, FakeLink
from hypothesis import given, settings
from hypothesis import strategies as st

import galil.transport as transport_registry
from galil.client import Controller, connect
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
)
from galil.protocol import commands as cmds


@pytest.fixture
def peer() -> Iterator[FakeGalil]:
    fake = FakeGalil()

    def opener(url: SplitResult, **options: Any) -> FakeLink:
        if options:
            raise InvalidArgument(f"unknown option(s) {sorted(options)}")
        return fake.open()

    transport_registry.register_scheme("fakegalil", opener, replace=True)
    yield fake
    transport_registry._registry.pop("fakegalil", None)


@pytest.fixture
def c(peer: FakeGalil) -> Iterator[Controller]:
    ctl = connect("fakegalil://x", timeout=0.2)
    yield ctl
    ctl.close()


# -- connect and handshake ------------------------------------------------------------------


def test_connect_identifies_and_marks_unsolicited(c: Controller, peer: FakeGalil) -> None:
    assert c.model.name == "DMC-4040"
    assert c.identity is not None
    assert c.identity.firmware == "1.2f"
    assert peer.log[:3] == ["\x12\x16", "MG _CW", "CW 1"]
    assert peer.cw == 1
    assert c.bytes_sent == len(b"\x12\x16\rMG _CW\rCW 1\r")
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


# -- commands and queries -------------------------------------------------------------------


def test_command_and_typed_queries(c: Controller, peer: FakeGalil) -> None:
    assert c.command("SHA") == ""
    assert c.command("MG 12.5") == " 12.5"
    assert c.query_number("MG 12.5") == 12.5
    assert c.query_numbers("MG 1, -2, 3.5") == [1.0, -2.0, 3.5]
    peer.variables["speed"] = 2500
    assert c.query_operands(["speed", "_CW"]) == [2500.0, 1.0]


def test_query_number_refuses_non_numbers(c: Controller) -> None:
    with pytest.raises(ProtocolError, match="answered 2 numbers"):
        c.query_number("MG 1,2")
    with pytest.raises(ProtocolError, match="answered"):
        c.query_numbers("MG abc")
    with pytest.raises(ProtocolError, match="answered"):
        c.query_numbers("SHA")


def test_query_operands_splits_long_lists_into_pipelined_lines(
    c: Controller, peer: FakeGalil
) -> None:
    names = [f"v{i}" for i in range(40)]
    for i, n in enumerate(names):
        peer.variables[n] = i
    before = len(peer.log)
    assert c.query_operands(names) == [float(i) for i in range(40)]
    lines = peer.log[before:]
    assert len(lines) > 1
    assert all(len(line) + 1 <= c.model.line_length for line in lines)
    assert c.query_operands([]) == []
    with pytest.raises(InvalidArgument):
        c.query_operands(["bad name"])


def test_stray_semicolon_sends_nothing(c: Controller, peer: FakeGalil) -> None:
    before = list(peer.log)
    sent = c.bytes_sent
    with c.wire_log.capture() as wire, pytest.raises(InvalidArgument, match="allow_compound"):
        c.command("SHA;MO")
    assert wire.sent == b""
    assert c.bytes_sent == sent
    assert peer.log == before


def test_compound_only_when_asked(c: Controller, peer: FakeGalil) -> None:
    assert c.command("a=1;MG a", allow_compound=True) == " 1.0000"
    assert c.command_line(["SHA", "MG 3", cmds.bg("A")]) == ["", " 3", ""]
    assert peer.log[-3:] == ["SHA", "MG 3", "BG A"]
    assert c.command_line([]) == []
    with pytest.raises(InvalidArgument, match="already compound"):
        c.command_line(["SHA;BGA"])
    with pytest.raises(InvalidArgument, match="list of commands"):
        c.command_line("SHA")  # type: ignore[arg-type]


def test_quoted_semicolon_is_one_command(c: Controller) -> None:
    assert c.command('MG "a;b"') == " a;b"


@pytest.mark.parametrize("text", ["TP\rSHA", "TP\n", "MG \u00e9"])
def test_unsendable_text_is_refused_before_the_wire(c: Controller, text: str) -> None:
    sent = c.bytes_sent
    with pytest.raises(InvalidArgument):
        c.command(text)
    assert c.bytes_sent == sent


def test_prepared_commands(c: Controller, peer: FakeGalil) -> None:
    assert c.send(cmds.mg_operand("_CW")) == " 1.0000"
    done = c.exchange(cmds.sh("AB"))
    assert done.ok
    assert done.command.text == "SH AB"
    assert c.send_many([cmds.assign("x", 2), cmds.mg_operand("x")]) == ["", " 2.0000"]
    assert c.send_many([]) == []
    with pytest.raises(InvalidArgument):
        c.exchange("SH")  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument):
        c.send_many(["SH"])  # type: ignore[list-item]


def _unquoted_semicolon(text: str) -> bool:
    quoted = False
    for ch in text:
        if ch == '"':
            quoted = not quoted
        elif ch == ";" and not quoted:
            return True
    return False


@settings(max_examples=150, deadline=None)
@given(st.text(alphabet=st.characters(min_codepoint=1, max_codepoint=300), max_size=30))
def test_any_text_is_sent_verbatim_or_refused_unsent(text: str) -> None:
    fake = FakeGalil()
    c = Controller(fake.open(), timeout=0.05)
    with c.wire_log.capture() as wire:
        try:
            c.command(text)
            refused = False
        except InvalidArgument:
            refused = True
        except (CommandError, ProtocolError, GalilTimeoutError):
            # Sent; the stand-in answers queries like "QZ" or "QU" with a bare ':'.
            refused = False
    c.close()
    if refused:
        assert wire.sent == b""
    else:
        assert text.isascii()
        assert "\r" not in text
        assert "\n" not in text
        assert not _unquoted_semicolon(text)
        assert wire.sent.startswith(text.encode("ascii") + b"\r")


# -- errors ---------------------------------------------------------------------------------


def test_question_mark_is_explained_with_tc1(c: Controller, peer: FakeGalil) -> None:
    peer.refuse["BG A"] = 20
    with pytest.raises(CommandError) as info:
        c.command("BG A")
    err = info.value
    assert err.code == 20
    assert err.text == "Begin not valid with motor off"
    assert err.command == "BG A"
    assert err.model == "DMC-4040"
    assert "'BG A' rejected by DMC-4040: TC 20 Begin not valid with motor off" in str(err)
    assert any("'BG A'" in r and "?" in r for r in err.recent)
    assert peer.log[-1] == "TC1"
    assert c.command("MG 1") == " 1"  # the link is fine afterwards


def test_rejected_part_of_a_compound_line_is_named(c: Controller, peer: FakeGalil) -> None:
    peer.refuse["BG B"] = 20
    with pytest.raises(CommandError) as info:
        c.command_line(["SHA", "BG B", "MG 1"])
    assert info.value.command == "BG B"


def test_tc1_refused_too(c: Controller, peer: FakeGalil) -> None:
    peer.refuse["XX"] = 1
    peer.refuse["TC1"] = 1
    with pytest.raises(CommandError) as info:
        c.command("XX")
    assert info.value.code is None
    assert "TC1 was refused" in info.value.text


def test_timeout_then_resync(c: Controller, peer: FakeGalil) -> None:
    peer.hold.add("MG 7")
    with pytest.raises(GalilTimeoutError, match=r"no reply to 'MG 7' within 0.05 s") as info:
        c.command("MG 7", timeout=0.05)
    assert isinstance(info.value, TimeoutError)
    assert any("timeout" in r for r in info.value.recent)
    peer.hold.clear()
    peer.release_held()  # the late reply must not be taken for the next command's
    assert c.command("MG 8") == " 8"
    assert any(line.startswith('MG "SYNC') for line in peer.log)
    assert any("back in step" in r for r in c.recent)


def test_resync_impossible_says_so(c: Controller, peer: FakeGalil) -> None:
    peer.hold.add("MG 7")
    with pytest.raises(GalilTimeoutError):
        c.command("MG 7", timeout=0.05)
    peer.silent = True
    with pytest.raises(GalilConnectionError, match=r"did not resynchronise.*reconnect"):
        c.command("MG 8", timeout=0.05)


def test_garbage_is_a_protocol_error_then_recovers(c: Controller, peer: FakeGalil) -> None:
    peer.extra = lambda cmd: ":::" if cmd == "SHB" else None
    with pytest.raises(ProtocolError, match="no command is pending") as info:
        c.command("SHB")
    assert info.value.model == "DMC-4040"
    peer.extra = None
    assert c.command("MG 4") == " 4"


def test_dead_link_and_reconnect(c: Controller, peer: FakeGalil) -> None:
    peer.links[0].dead = True
    with pytest.raises(GalilConnectionError, match="died") as info:
        c.command("MG 1")
    assert isinstance(info.value, ConnectionError)
    c.reconnect()
    assert len(peer.links) == 2
    assert c.command("MG 2") == " 2"
    assert peer.links[0].closed


def test_errors_carry_the_ring_buffer(peer: FakeGalil) -> None:
    c = connect("fakegalil://x", timeout=0.2, history=4)
    for i in range(10):
        c.command(f"MG {i}")
    peer.refuse["BGA"] = 20
    with pytest.raises(CommandError) as info:
        c.command("BGA")
    recent = info.value.recent
    assert len(recent) == 4
    assert recent[0] == "-> 'MG 8'  <- ' 8'"
    assert recent[-2] == "-> 'BGA'  <- ?"
    assert recent[-1] == "-> 'TC1'  <- ' 20 Begin not valid with motor off'"
    c.close()
    with pytest.raises(InvalidArgument):
        connect("fakegalil://x", history=0)


# -- unsolicited messages -------------------------------------------------------------------


def test_unsolicited_inside_a_reply_is_split_out(c: Controller, peer: FakeGalil) -> None:
    peer.extra = lambda cmd: (
        " 4" + "".join(chr(b | 0x80) for b in b"hello\r\n") + "2\r\n:" if cmd == "MG 42" else None
    )
    assert c.command("MG 42") == " 42"
    assert c.messages.get(timeout=1) == "hello"
    assert any("hello" in r and "unsolicited" in r for r in c.recent)


def test_messages_arrive_while_idle(c: Controller, peer: FakeGalil) -> None:
    q = c.messages
    peer.emit("done moving")
    assert q.get(timeout=2) == "done moving"
    with pytest.raises(queue.Empty):
        q.get(timeout=0.01)
    with pytest.raises(queue.Empty):
        q.get_nowait()


def test_subscribers_get_lines_and_may_send_commands(c: Controller, peer: FakeGalil) -> None:
    got: list[tuple[str, str]] = []
    event = threading.Event()

    def callback(line: str) -> None:
        got.append((line, c.command("MG 9")))  # no deadlock: called outside the link lock
        event.set()

    def broken(line: str) -> None:
        raise RuntimeError("callback bug")

    unsubscribe = c.subscribe(callback)
    c.subscribe(broken)
    peer.emit("hi")
    assert event.wait(2)
    assert got == [("hi", " 9")]
    unsubscribe()
    peer.emit("again")
    assert c.messages.get(timeout=2) == "hi"
    assert c.messages.get(timeout=2) == "again"
    assert got == [("hi", " 9")]
    with pytest.raises(InvalidArgument):
        c.subscribe("nope")  # type: ignore[arg-type]


def test_message_queue_is_bounded(peer: FakeGalil) -> None:
    c = connect("fakegalil://x", timeout=0.2, max_messages=3)
    for i in range(5):
        peer.emit(f"m{i}", marked=True)
    c.command("MG 0")
    assert c.messages_queue.drain() == ["m2", "m3", "m4"]
    assert c.messages_queue.dropped == 2
    assert "dropped" in repr(c.messages_queue)
    c.close()


# -- observability --------------------------------------------------------------------------


def test_wire_bytes_logged_at_debug(c: Controller, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.DEBUG, logger="galil.wire"):
        c.command("MG 6")
    wire = [r.getMessage() for r in caplog.records if r.name == "galil.wire"]
    assert wire == ["-> b'MG 6\\r'", "<- b' 6\\r\\n:'"]


def test_wire_hooks_see_both_directions(c: Controller) -> None:
    seen: list[tuple[str, bytes]] = []
    remove = c.wire_log.add(lambda d, b: seen.append((d, b)))
    c.command("MG 1")
    remove()
    c.command("MG 2")
    assert seen == [("out", b"MG 1\r"), ("in", b" 1\r\n:")]
    received = c.bytes_received
    c.command("MG 3")
    assert c.bytes_received == received + len(b" 3\r\n:")


# -- threads --------------------------------------------------------------------------------


def test_threads_each_get_their_own_reply(c: Controller) -> None:
    errors: list[str] = []

    def worker(k: int) -> None:
        for i in range(300):
            n = k * 100000 + i
            reply = c.command(f"MG {n}")
            if reply != f" {n}":
                errors.append(f"{n}: {reply!r}")

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


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
