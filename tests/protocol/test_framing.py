"""The frame parser and the session: splits, unsolicited bytes, echo, DL/UL/QU, resync."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import ProtocolError
from galil.protocol import commands as c
from galil.protocol.commands import Command, Expect, pack
from galil.protocol.framing import Ack, FrameParser, Record, Rejected, Reply, Unsolicited
from galil.protocol.session import Completed, Session


def high(text: str) -> bytes:
    """Unsolicited text as CW1 sends it: every byte with bit 7 set."""
    return bytes(b | 0x80 for b in text.encode("ascii"))


def record(size: int, fill: int = 0x11) -> bytes:
    return bytes([0x87, 0x0F, size & 0xFF, size >> 8]) + bytes([fill]) * (size - 4)


def feed_split(session: Session, data: bytes, cuts: list[int]) -> list[Completed | Unsolicited]:
    out: list[Completed | Unsolicited] = []
    start = 0
    for cut in [*sorted(cuts), len(data)]:
        out += session.receive_data(data[start:cut])
        start = cut
    return out


def summary(events: list[Completed | Unsolicited]) -> list[tuple[str, ...]]:
    rows: list[tuple[str, ...]] = []
    for e in events:
        if isinstance(e, Unsolicited):
            rows.append(("U", e.line))
        else:
            rows.append((e.command.text, str(e.ok), e.text, repr(e.record)))
    return rows


SCENARIO_CMDS = [
    c.pr(A=1000),
    c.bg("A"),
    c.tp("AB"),
    c.mg("x:y"),
    c.tc(),
    c.qr(),
    c.ul(),
    c.qu("arr"),
    c.dl(["#A", "EN"]),
]
SCENARIO_REPLY = (
    b":"
    + b"?"
    + b" 1000, -5\r\n:"
    + b"x:y\r\n:"
    + b" 1 Unrecognized command\r\n:"
    + record(12)
    + b":"
    + b"#A\r\nMG 1\r\nEN\r\n\x1a:"
    + b"1.0000\r\n2.0000\r\n\x1a:"
    + b"::"
)
EXPECTED = [
    ("PRA=1000", "True", "", "None"),
    ("BG A", "False", "", "None"),
    ("TP AB", "True", " 1000, -5", "None"),
    ('MG "x:y"', "True", "x:y", "None"),
    ("TC1", "True", " 1 Unrecognized command", "None"),
    ("QR", "True", "", repr(record(12))),
    ("UL", "True", "#A\r\nMG 1\r\nEN", "None"),
    ("QU arr[],,,1", "True", "1.0000\r\n2.0000", "None"),
    ("DL", "True", "", "None"),
]


def run_scenario(data: bytes, cuts: list[int], echo: bool = False) -> list[tuple[str, ...]]:
    session = Session(echo=echo)
    for cmd in SCENARIO_CMDS:
        session.send(cmd)
    out = feed_split(session, data, cuts)
    assert session.pending == 0
    return summary(out)


def test_whole_scenario() -> None:
    assert run_scenario(SCENARIO_REPLY, []) == EXPECTED


def test_split_at_every_byte() -> None:
    for cut in range(1, len(SCENARIO_REPLY)):
        assert run_scenario(SCENARIO_REPLY, [cut]) == EXPECTED, cut
    assert run_scenario(SCENARIO_REPLY, list(range(1, len(SCENARIO_REPLY)))) == EXPECTED


def test_high_bit_unsolicited_interleaved_anywhere_outside_records() -> None:
    noise = high("Hi\r\n")
    body = SCENARIO_REPLY
    rec_start = body.index(record(12))
    rec_end = rec_start + 12
    for at in range(len(body) + 1):
        if rec_start < at < rec_end:
            continue  # inside a record the bytes are data
        data = body[:at] + noise + body[at:]
        rows = run_scenario(data, [at + 2])
        assert [r for r in rows if r[0] != "U"] == EXPECTED, at
        assert ("U", "Hi") in rows


def test_record_bytes_with_high_bit_are_data() -> None:
    session = Session()
    session.send(c.qr(model=None))
    payload = bytes([0x87, 0x01, 10, 0]) + high("Hi\r\n") + b"\xff\x8a"
    out = session.receive_data(payload + b":")
    assert out == [Completed(c.qr(), True, "", payload)]


def test_multi_command_line_one_terminator_each() -> None:
    session = Session()
    line = pack([c.assign("a", 1), c.assign("b", 2), c.mg_operand("a"), c.bg("A")])[0]
    wire = session.send(line)
    assert wire == b"a=1;b=2;MG a{Z10.4};BG A\r"
    out = session.receive_data(b":: 1.0000\r\n:?")
    assert [(e.command.text, e.ok, e.text) for e in out if isinstance(e, Completed)] == [
        ("a=1", True, ""),
        ("b=2", True, ""),
        ("MG a{Z10.4}", True, " 1.0000"),
        ("BG A", False, ""),
    ]


def test_raw_string_line() -> None:
    session = Session()
    assert session.send("a=1;MG a") == b"a=1;MG a\r"
    out = session.receive_data(b":1.0000\r\n:")
    assert [(e.command.text, e.text) for e in out if isinstance(e, Completed)] == [
        ("a=1", ""),
        ("MG a", "1.0000"),
    ]


def test_echo_is_stripped() -> None:
    echoed = b"PRA=1000\r:BG A\r\n?TP AB\r\n 1000, -5\r\n:"
    session = Session(echo=True)
    for cmd in SCENARIO_CMDS[:3]:
        session.send(cmd)
    for cut in range(len(echoed) + 1):
        s = Session(echo=True)
        for cmd in SCENARIO_CMDS[:3]:
            s.send(cmd)
        assert summary(feed_split(s, echoed, [cut])) == EXPECTED[:3]


def test_echo_missing_is_a_protocol_error() -> None:
    session = Session(echo=True)
    session.send(c.pr(A=1))
    with pytest.raises(ProtocolError):
        session.receive_data(b":")
    assert session.out_of_step


def test_reply_shape_mismatch_raises_and_goes_out_of_step() -> None:
    cases: list[tuple[Command, bytes]] = [
        (c.pr(A=1), b"5\r\n:"),  # data for a plain command: someone else's reply
        (c.tp("A"), b":"),  # no data for a query
        (c.tp("A"), b"1\r\n2\r\n:"),  # two lines where one is expected
        (c.qr(), b"abc"),  # text where a record should start
        (c.qr(model=None), bytes([0x87, 0, 3, 0])),  # header size below 4
        (c.dl(["#A"]), b"5\r\n:"),
    ]
    for cmd, reply in cases:
        session = Session()
        session.send(cmd)
        with pytest.raises(ProtocolError):
            session.receive_data(reply)
        assert session.out_of_step, cmd
        assert session.pending == 0
        with pytest.raises(ProtocolError):
            session.send(c.bg())


def test_reply_with_nothing_pending_is_a_protocol_error() -> None:
    session = Session()
    with pytest.raises(ProtocolError):
        session.receive_data(b":")
    assert session.out_of_step


def test_record_size_checked_against_model() -> None:
    from galil.models import get_model

    model = get_model("DMC-4040")
    session = Session()
    session.send(c.qr(model=model))
    with pytest.raises(ProtocolError):
        session.receive_data(record(20))


def test_resync_after_timeout() -> None:
    session = Session()
    session.send(c.tp("A"))
    assert [cmd.text for cmd in session.abandon()] == ["TP A"]
    assert session.out_of_step
    wire = session.resync("TOKEN1")
    assert wire == b'\\\rMG "TOKEN1"\r'
    assert session.resyncing
    # late reply to the abandoned TP, the '?' for '\', then the marker, split anywhere
    late = b" 1000\r\n:" + high("msg\r\n") + b"?" + record(8)[:5] + b"TOKEN1\r\n:"
    for cut in range(len(late)):
        s = Session()
        s.resync("TOKEN1")
        assert feed_split(s, late, [cut]) == []
        assert not s.out_of_step
        s.send(c.bg("A"))
        assert s.receive_data(b":") == [Completed(c.bg("A"), True)]
    assert Session.marker_reply("TOKEN1") == b"TOKEN1\r\n:"


def test_unsolicited_output_right_after_the_resync_marker_is_kept() -> None:
    # The marker and a CW1 message in one chunk, or split anywhere: the message survives.
    tail = b"junk?" + b"TOKEN1\r\n:" + high("after\r\n")
    for cut in range(len(tail) + 1):
        s = Session()
        s.resync("TOKEN1")
        events = feed_split(s, tail, [cut])
        assert [e.line for e in events if isinstance(e, Unsolicited)] == ["after"], cut
        assert not s.out_of_step


def test_resync_tokens_differ() -> None:
    session = Session()
    assert session.resync() != session.resync()
    with pytest.raises(ProtocolError):
        session.resync('a"b')


def test_unsolicited_only_parser() -> None:
    parser = FrameParser(unsolicited_only=True)
    events = parser.feed(b"hello\r\n" + high("world\r\n") + b":?\r\n\r\npartial")
    assert events == [Unsolicited("hello"), Unsolicited("world"), Unsolicited(":?")]
    assert parser.feed(b"\n") == [Unsolicited("partial")]


def test_parser_events_directly() -> None:
    parser = FrameParser()
    parser.expect(Expect.ACK)
    parser.expect(Expect.DATA)
    parser.expect(Expect.record(None))
    parser.expect(Expect.CTRL_Z)
    parser.expect(Expect.DOUBLE_ACK)
    events = parser.feed(b": 5\r\n:" + record(6) + b":\x1a:?:")
    assert events == [Ack(), Reply(" 5"), Record(record(6)), Reply(""), Rejected(), Ack()]
    assert parser.pending == 0


def test_runaway_reply_is_refused() -> None:
    parser = FrameParser(max_reply=16)
    parser.expect(Expect.DATA)
    with pytest.raises(ProtocolError):
        parser.feed(b"x" * 40)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.sampled_from(SCENARIO_CMDS), max_size=6),
    st.binary(max_size=200),
    st.booleans(),
    st.integers(1, 50),
)
def test_fuzz_any_bytes_give_events_or_protocol_error(
    cmds: list[Command], data: bytes, echo: bool, chunk: int
) -> None:
    session = Session(echo=echo)
    for cmd in cmds:
        session.send(cmd)
    for i in range(0, len(data), chunk):
        try:
            out = session.receive_data(data[i : i + chunk])
        except ProtocolError:
            assert session.out_of_step
            return
        assert all(isinstance(e, Completed | Unsolicited) for e in out)
    assert session.pending <= len(cmds)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.booleans())
def test_fuzz_raw_parser(data: bytes, only: bool) -> None:
    parser = FrameParser(unsolicited_only=only)
    for kind in (Expect.ANY, Expect.record(None), Expect.CTRL_Z, Expect.DOUBLE_ACK, Expect.DATA):
        parser.expect(kind)
    try:
        events = parser.feed(data)
    except ProtocolError:
        return
    assert all(isinstance(e, Ack | Rejected | Reply | Unsolicited | Record) for e in events)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(1, len(SCENARIO_REPLY) - 1), max_size=8))
def test_any_split_gives_the_same_events(cuts: list[int]) -> None:
    assert run_scenario(SCENARIO_REPLY, cuts) == EXPECTED
