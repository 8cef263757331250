"""Commands and replies: raw and prepared commands, queries, compound lines, refusals explained
with TC1, timeouts and resync, the ring buffer, the wire log, threads.
"""

from __future__ import annotations

import logging
import threading

import pytest
from client_fakes import FakeGalil
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.controller import Controller, connect
from galil.errors import (
    CommandError,
    GalilConnectionError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
)
from galil.protocol import commands as cmds


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
    assert peer.log[-2] == "TC1"  # and a marker behind it: the answers are in step
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


def test_resync_delayed_by_a_held_burn_succeeds_on_a_later_try(
    c: Controller, peer: FakeGalil
) -> None:
    # A burn holds its reply (and the marker's) while flash is written: the link says to try
    # again, and once the controller answers, the next command resynchronises. (A silence
    # with no burn given up is a dead link: tests/link/test_silent_link.py.)
    peer.hold.add("BV")
    with pytest.raises(GalilTimeoutError):
        c.command("BV", timeout=0.05)
    peer.silent = True  # the controller answers nothing while it holds BV
    with pytest.raises(GalilConnectionError, match=r"busy with BV .*try again once it is done"):
        c.command("MG 8", timeout=0.05)
    assert not c.link.dead
    with pytest.raises(GalilConnectionError, match=r"busy with BV"):
        c.command("MG 8", timeout=0.05)  # (still the burn: the next try knows it too)
    peer.silent = False
    peer.hold.clear()
    peer.release_held()
    assert c.command("MG 9") == " 9"


def test_garbage_is_a_protocol_error_then_recovers(c: Controller, peer: FakeGalil) -> None:
    peer.extra = lambda cmd: ":::" if cmd == "SHB" else None
    with pytest.raises(ProtocolError, match="no command is pending") as info:
        c.command("SHB")
    assert info.value.model == "DMC-4040"
    peer.extra = None
    assert c.command("MG 4") == " 4"


def test_errors_carry_the_ring_buffer(peer: FakeGalil) -> None:
    c = connect("fakegalil://x", timeout=0.2, history=4)
    for i in range(10):
        c.command(f"MG {i}")
    peer.refuse["BGA"] = 20
    with pytest.raises(CommandError) as info:
        c.command("BGA")
    recent = info.value.recent
    assert len(recent) == 4
    assert recent[0] == "-> 'MG 9'  <- ' 9'"
    assert recent[-3] == "-> 'BGA'  <- ?"
    assert recent[-2] == "-> 'TC1'  <- ' 20 Begin not valid with motor off'"
    assert recent[-1] == "-> 'MG \"TCOK1\"'  <- ' TCOK1'"
    c.close()
    with pytest.raises(InvalidArgument):
        connect("fakegalil://x", history=0)


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
