"""Interrupt packets, named record fields and the 16-bit sample counter, from bytes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from galil.errors import InvalidArgument
from galil.models import get_model
from galil.protocol import commands as c
from galil.protocol.interrupts import InterruptParser, decode_status, packet
from galil.protocol.records import (
    SAMPLE_WRAP,
    AxisStatus,
    Switches,
    decode_fields,
    decode_record,
    extend_sample,
    record_dtype,
    with_time,
)

MODEL = get_model("DMC-4040")


def test_the_manuals_example_packet_decodes() -> None:
    events = InterruptParser().feed(bytes.fromhex("01D0F1DBE106"))
    assert [str(e) for e in events] == [
        "axis A done",
        "UI 1",
        "program stopped ($DB)",
        "input 1 low",
    ]


def test_status_bytes_by_kind() -> None:
    assert decode_status(0xFF).number == 15
    assert decode_status(0xD7).axis == "H"
    assert decode_status(0xD8).kind == "all_done"
    assert decode_status(0xC8).kind == "position_error"
    assert decode_status(0xC0).kind == "limit"
    assert decode_status(0xA0).kind == "unknown"
    with pytest.raises(InvalidArgument):
        decode_status(256)


statuses = st.lists(st.integers(0x80, 0xFF), min_size=1, max_size=16)


@given(st.lists(statuses, min_size=1, max_size=5), st.data())
def test_packets_split_anywhere_give_their_statuses_in_order(
    batches: list[list[int]], data: st.DataObject
) -> None:
    stream = b"".join(packet(b) for b in batches)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    parser = InterruptParser()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += parser.feed(stream[a:b])
    assert [e.status for e in got] == [s for b in batches for s in b]


@pytest.mark.parametrize("data", [b"\x02\xf0\x03", b"\x01\xf0\x09", b"\x01\x05"])
def test_a_malformed_packet_is_dropped_and_said(data: bytes) -> None:
    parser = InterruptParser()
    assert parser.feed(data) == []
    assert len(parser.take_dropped()) == 1
    assert parser.take_dropped() == []  # (said once)
    assert [e.status for e in parser.feed(packet([0xF2]))] == [0xF2]  # and it goes on


@pytest.mark.parametrize("bad", [b"\x02\xf0\x03", b"\x01\xf0\x09", b"\x01\x05", b"\xaa"])
def test_the_good_packets_around_a_malformed_one_in_one_read_are_kept(bad: bytes) -> None:
    parser = InterruptParser()
    got = parser.feed(packet([0xF1]) + bad + packet([0xD0, 0xF4]))
    assert [e.status for e in got] == [0xF1, 0xD0, 0xF4]
    assert len(parser.take_dropped()) == 1


def test_a_packet_cut_short_does_not_swallow_the_next_one() -> None:
    # 01 D0 (no length byte) then a good UI 3: the UI 3 was taken as the cut packet's length.
    parser = InterruptParser()
    assert parser.feed(b"\x01\xd0") == []
    assert [e.number for e in parser.feed(packet([0xF3]))] == [3]
    assert parser.take_dropped() == ["interrupt packet cut short: 01 d0"]
    assert [e.number for e in parser.feed(packet([0xF4]))] == [4]


def test_each_datagram_is_parsed_on_its_own() -> None:
    parser = InterruptParser(datagram=True)
    assert parser.feed(b"\x01\xd0\xd1") == []  # a datagram cut short: dropped at once
    assert parser.take_dropped() == ["interrupt datagram cut short: 01 d0 d1"]
    assert [e.status for e in parser.feed(b"\xd2\x03" + packet([0xF5]))] == [0xF5]
    assert len(parser.take_dropped()) == 1  # (its rest, which starts no packet)
    stream = InterruptParser()  # a stream (TCP) keeps a packet split over two reads
    assert stream.feed(b"\x01\xd0") == []
    assert [e.status for e in stream.feed(b"\xd1\x04")] == [0xD0, 0xD1]


@pytest.mark.parametrize("bad", [[], [0x10], list(range(0x80, 0x91)), [True]])
def test_a_packet_is_only_built_from_status_bytes(bad: list[int]) -> None:
    with pytest.raises(InvalidArgument):
        packet(bad)


@given(st.integers(0, 2**40), st.integers(-(2**15) + 1, 2**15 - 1))
def test_the_16_bit_counter_extends_to_the_sample_near_time(sample: int, offset: int) -> None:
    near = sample + offset
    assert extend_sample(sample % SAMPLE_WRAP, near) == sample


def test_the_issues_example_lines_up() -> None:
    # The record said 63964 while MG TIME said 129502: the record is from sample 129500.
    assert extend_sample(63964, 129502) == 129500


def test_status_word_and_switch_byte_by_name() -> None:
    s = AxisStatus.from_word(0x8000 | 0x4000 | 0x2000 | 0x0080 | 0x0001)
    assert (s.moving, s.position_mode, s.absolute, s.negative, s.motor_off) == (True,) * 5
    assert (s.contour, s.homing, s.stopping, s.slewing) == (False,) * 4
    assert s.raw == 0xE081
    w = Switches.from_byte(0x80 | 0x08 | 0x02)
    assert w.latch_occurred
    assert w.home
    assert not w.forward_limit  # bit 3 set: the forward switch is inactive
    assert w.reverse_limit  # bit 2 clear: the reverse switch is active


def test_a_record_with_its_time_decodes_by_name() -> None:
    dtype = record_dtype(MODEL)
    buf = np.zeros(1, dtype)
    buf["header"], buf["axes_present"], buf["size"] = 0x87, 0x0F, dtype.itemsize
    buf["sample"] = 1234
    buf["thread_status"] = 0b101
    buf["B"]["status"] = 0x8040
    buf["B"]["stop_code"] = 50
    buf["B"]["velocity"] = 64 * 300
    buf["B"]["reference"] = -77
    rec = with_time(decode_record(buf.tobytes(), MODEL), 66770)
    assert rec["time"] == 66770
    assert rec["B"]["reference"] == -77  # the record's own fields are unchanged
    fields = decode_fields(rec)
    assert fields.time == 66770
    assert fields.sample == 1234
    assert fields.threads == frozenset({0, 2})
    b = fields.axes["B"]
    assert b.status.moving
    assert b.status.contour
    assert b.velocity == 300
    assert b.stop_text.lower() == "contour running"
    with pytest.raises(InvalidArgument):
        with_time(rec, 1)


def test_the_30010_general_block_is_decoded() -> None:
    model = get_model("DMC-30010")
    dtype = record_dtype(model)
    assert dtype.itemsize == 74
    buf = np.zeros(1, dtype)
    buf["header"], buf["axes_present"], buf["size"] = 0x87, 1, 74
    buf["inputs"] = [0xFE, 0x7F]
    buf["analog_in"] = 40000
    buf["analog_out"] = [-3277, 3277]
    buf["contour_buffer"] = 511
    rec = decode_record(buf.tobytes(), model)
    assert rec["analog_out"].tolist() == [-3277, 3277]
    assert decode_fields(rec).inputs == (0xFE, 0x7F)
    assert rec["contour_buffer"] == 511


def test_program_array_and_capture_builders() -> None:
    assert c.dm("pos", 100, model=MODEL).text == "DM pos[100]"
    assert c.da("pos", "vel").text == "DA pos[],vel[]"
    assert c.ra("a", "b", model=MODEL).text == "RA a[],b[]"
    assert c.rd("_RPA", "_TEB", "_TI0", model=MODEL).text == "RD _RPA,_TEB,_TI0"
    assert c.rd("_TTA", "TIME", model=MODEL).text == "RD _TTA,TIME"  # (as the simulator's)
    assert c.rc(2, 500, model=MODEL).text == "RC 1,500"
    assert c.rc(256).text == "RC 8"
    assert c.rc(0).text == "RC 0"
    assert c.ui(15).text == "UI 15"
    assert c.ei(0x1FF, None, 3).text == "EI 511,,3"
    assert c.ei(1, 2).text == "EI 1,2"
    assert c.la().returns_data
    assert c.lv().returns_data


@pytest.mark.parametrize(
    "build",
    [
        lambda: c.rc(1, model=MODEL),  # every sample: RC n starts at 2 samples
        lambda: c.rc(6, model=MODEL),
        lambda: c.rc(512, model=MODEL),
        lambda: c.rc(2, 0, model=MODEL),
        lambda: c.rd("_XXA", model=MODEL),
        lambda: c.rd("_RPE", model=MODEL),  # no axis E on a DMC-4040
        lambda: c.rd("_TI", model=MODEL),  # the bank is given: _TI0 (decision 0097)
        lambda: c.rd("_SHA", model=MODEL),  # listed by the old manuals only (0097)
        lambda: c.rd(*(["_TPA"] * 9), model=MODEL),
        lambda: c.ra(model=MODEL),
        lambda: c.dm("arr", 0, model=MODEL),
        lambda: c.dm("arr", 24_001, model=MODEL),
        lambda: c.dm("SPA", 10, model=MODEL),
        lambda: c.dm("toolongname", 10, model=MODEL),
        lambda: c.da(),
        lambda: c.da("a b"),
        lambda: c.ui(16),
        lambda: c.ei(-1),
        lambda: c.ei(1, None, 8),
        lambda: c.array_name("2x"),
        lambda: c.variable_name("TIME"),
    ],
)
def test_bad_arguments_are_refused_by_the_builders(build: object) -> None:
    with pytest.raises(InvalidArgument):
        build()  # type: ignore[operator]


def test_the_18x2_axis_blocks_are_28_bytes_as_in_gclib() -> None:
    dtype = record_dtype(get_model("DMC-18x2"))
    assert dtype.itemsize == 4 + 24 + 16 + 4 * 28
    fields = dtype.fields
    assert fields is not None
    # gclib GDataRecord1802 offsets (which omit the 4-byte QR header): A at 40, B at 68.
    assert [fields[a][1] - 4 for a in "ABCD"] == [40, 68, 96, 124]
    block = dtype["A"]
    assert block.fields is not None
    assert block.fields["reference"][1] == 44 - 40
    assert block.fields["torque"][1] == 64 - 40
    assert block.names is not None
    assert block.names[-1] == "reserved"
    # The same sizes from a QZ reply (the 21x3's) decode the analog input there.
    assert record_dtype((8, 24, 16, 28))["A"].names[-1] == "analog_in"
