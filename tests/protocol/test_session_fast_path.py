"""The session's fast path (a lone command not given to the parser) changes no outcome."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument, ProtocolError
from galil.protocol import commands as c
from galil.protocol.commands import Command, Expect, pack
from galil.protocol.framing import Unsolicited
from galil.protocol.session import Completed, Session


class ParsedSession(Session):
    """A session that always hands its commands to the parser (no fast path)."""

    def send(self, cmd: Command | str) -> bytes:
        wire = super().send(cmd)
        if self._lazy:
            self._register()
        return wire


COMMANDS = [
    c.pr(A=1000),
    c.tp("A"),
    c.st(),
    c.tc(1),
    Command("MG _TPA", Expect.ANY),
    Command("TH", Expect.DATA),
    Command("XX", Expect.data(0)),
]
REPLIES = [
    b":",
    b" 1000\r\n:",
    b"?",
    b" 1\r\n 2\r\n:",
    b"\xc8\xe9\x8d\x8a:",  # a marked unsolicited line, then the ':'
    b"\r\n:",
    b"::",
    b"",
    b"1 Unrecognized command\r\n:",
]


def run(session: Session, steps: list[tuple[int, int, int]]) -> list[object]:
    out: list[object] = []
    for cmd_i, reply_i, cut in steps:
        reply = REPLIES[reply_i]
        try:
            out.append(session.send(COMMANDS[cmd_i]))
            for part in (reply[:cut], reply[cut:]):
                out.append(session.receive_data(part))
        except ProtocolError:
            out.append("protocol error")
            session.resync("TOKEN")
            out.append(session.receive_data(Session.marker_reply("TOKEN")))
        out.append(session.pending)
    return out


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, len(COMMANDS) - 1),
            st.integers(0, len(REPLIES) - 1),
            st.integers(0, 12),
        ),
        max_size=10,
    )
)
def test_fast_path_gives_what_the_parser_gives(steps: list[tuple[int, int, int]]) -> None:
    assert run(Session(), steps) == run(ParsedSession(), steps)


def test_plain_and_query_replies_complete_without_the_parser() -> None:
    s = Session()
    cmd = c.pr(A=5)
    assert s.send(cmd) == b"PRA=5\r"
    assert s.receive_data(b":") == [Completed(cmd, True)]
    query = c.tp("A")
    s.send(query)
    assert s.receive_data(b" 5\r\n:") == [Completed(query, True, " 5")]
    assert s.pending == 0
    assert s._parser.idle
    assert s._parser.pending == 0  # the parser never saw either command


def test_a_rejection_or_a_split_reply_goes_through_the_parser() -> None:
    s = Session()
    cmd = c.pr(A=5)
    s.send(cmd)
    assert s.receive_data(b"?") == [Completed(cmd, False)]
    query = c.tp("A")
    s.send(query)
    assert s.receive_data(b" 5\r") == []
    assert s.receive_data(b"\n:") == [Completed(query, True, " 5")]
    s.send(cmd)  # the parser is idle again: the fast path is back
    assert s.receive_data(b":") == [Completed(cmd, True)]


def test_a_lone_colon_for_a_query_is_out_of_step() -> None:
    s = Session()
    s.send(c.tp("A"))
    with pytest.raises(ProtocolError):
        s.receive_data(b":")
    assert s.out_of_step


def test_unsolicited_before_the_reply() -> None:
    s = Session()
    cmd = c.st()
    s.send(cmd)
    assert s.receive_data(b"\xc8\xc9\x8d\x8a:") == [Unsolicited("HI"), Completed(cmd, True)]


def test_commands_and_completions_are_immutable_values() -> None:
    cmd = c.pr(A=1)
    assert cmd == Command("PRA=1")
    assert hash(cmd) == hash(Command("PRA=1"))
    assert repr(cmd).startswith("Command(text='PRA=1'")
    with pytest.raises(AttributeError):
        cmd.text = "BG"  # type: ignore[misc]
    done = Completed(cmd, True)
    assert (done.text, done.record) == ("", None)
    with pytest.raises(AttributeError):
        done.ok = False  # type: ignore[misc]


def test_pack_refuses_a_single_command() -> None:
    with pytest.raises(InvalidArgument):
        pack(c.pr(A=1))  # type: ignore[arg-type]
