"""The data record (QR, DR): every field says what the controller's own answers say.

The record is built from the dtypes of :mod:`galil.protocol.records` (whose offsets are checked
against gclib in ``tests/protocol``); here it is decoded with the same dtypes and each field
compared with the simulator's replies to ``MG``/``TP``/``TS``..., across the layouts it fills
(40x0, 18x6, 21x3, 18x2 and the DMC-30010's unsourced general block).
"""

from __future__ import annotations

from typing import Any

import pytest

from galil.protocol.records import decode_record, record_to_dict
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController

PROGRAM = b"#W\rWT 10000\rEN\r\\"
#: Fields the simulator fills; every other byte of a record is zero.
FILLED_GENERAL = {"header", "axes_present", "size", "sample", "inputs", "error_code"}
FILLED_GENERAL |= {"thread_status", "contour_buffer", "general_status"}
FILLED_GENERAL |= {f"{p}_{n}" for p in "st" for n in ("segments", "status", "distance", "buffer")}
FILLED_AXIS = {"status", "switches", "stop_code", "reference", "position", "error"}
FILLED_AXIS |= {"aux_position", "velocity"}


def ask(sim: SimController, line: str) -> bytes:
    """The reply to ``line``, without the echo of the line (echo is on)."""
    sent = line.encode() + b"\r"
    reply = sim.feed(sent)
    return reply[len(sent) :] if reply.startswith(sent) else reply


def number(sim: SimController, query: str) -> int:
    return round(float(ask(sim, query)[:-3]))


def busy(model: str) -> SimController:
    """A controller doing a bit of everything: jogs, a limit stop, motor off, contour, a thread."""
    sim = SimController(model, ManualClock(), servo_lag=0.01)
    axes = sim.spec.axes
    assert sim.feed(b"DL\r" + PROGRAM) == b"::"
    assert sim.feed(b"XQ #W,1\r") == b":"  # a thread running
    assert b"?" not in sim.feed(b"JG -5000;BG A\r")
    if len(axes) > 1:
        assert b"?" not in sim.feed(b"PA ,3000;BG B\r")
    if len(axes) > 2:
        assert b"?" not in sim.feed(b"MO C\r")
    if len(axes) > 3 and sim.spec.contour_buffer > 1:
        assert b"?" not in sim.feed(b"CM D;CD ,,,100=7;CD ,,,100=7;CD ,,,100=7\r")
    sim.advance(0.05)
    sim.set_limit_switch("A", "reverse", True)  # A starts its limit stop
    sim.advance(0.002)
    assert sim.feed(b"XX;EO 1\r") == b"?:"  # TC 1, and echo on (general status bit 0)
    return sim


def expected_status(sim: SimController, letter: str) -> int:
    m = sim.motion(letter)
    word = 0
    if m.moving:
        word |= 0x8000
        if m.profiler.mode == "position":
            word |= 0x4000 | 0x2000  # B was started by PA
        if m.profiler.velocity < 0:
            word |= 0x0080
        if m.profiler.stop_code in (2, 3, 4):
            word |= 0x0010 | 0x0008  # stopping, in the ramp that ends the motion
        # (B, started by PA, is still accelerating: neither slewing nor decelerating)
    if m.profiler.mode == "contour":
        word |= 0x0040
    if not m.motor_on:
        word |= 0x0001
    return word


def check_axis(sim: SimController, letter: str, block: dict[str, Any]) -> None:
    assert block["reference"] == number(sim, f"RP{letter}")
    assert block["position"] == number(sim, f"TP{letter}")
    assert block["aux_position"] == number(sim, f"TD{letter}")
    assert block["error"] == number(sim, f"TE{letter}")
    assert block["stop_code"] == number(sim, f"SC{letter}")
    assert block["switches"] == number(sim, f"TS{letter}") & 0x0E
    assert block["velocity"] == round(64 * sim.motion(letter).velocity)
    assert block["status"] == expected_status(sim, letter)
    assert all(v == 0 for k, v in block.items() if k not in FILLED_AXIS)


@pytest.mark.parametrize("model", ["DMC-4040", "DMC-1806", "DMC-2183", "DMC-18x2", "DMC-30010"])
def test_every_field_of_the_record_matches_the_controllers_answers(model: str) -> None:
    sim = busy(model)
    data = sim.record()
    rec = record_to_dict(decode_record(data, sim.spec))
    n = sim.spec.qz[0] if sim.spec.qz else 0
    assert (rec["header"], rec["axes_present"], rec["size"]) == (0x87, (1 << n) - 1, len(data))
    for letter in sim.spec.axes[:n]:
        check_axis(sim, letter, rec.pop(letter))
    assert "general" not in rec  # every model's general block is decoded (30010 included)
    assert rec["sample"] == sim.sample & 0xFFFF
    assert rec["inputs"] == [0xFF] * (2 if model == "DMC-30010" else 10)
    assert rec["error_code"] == number(sim, "MG _TC") == 1
    if "thread_status" in rec:
        assert rec["thread_status"] == number(sim, "MG _NO") == 0b10
        assert rec["contour_buffer"] == number(sim, "MG _CM")
    else:
        assert rec["general_status"] == number(sim, "TB") & 0x81 == 0x81
    if "s_buffer" in rec:  # no sequence: an empty buffer, no segments, no distance
        assert rec["s_buffer"] == number(sim, "MG _LMS") == sim.spec.vector_buffer
        assert rec.get("t_buffer", rec["s_buffer"]) == rec["s_buffer"]
    planes = [k for k in rec if k[:2] in ("s_", "t_") and not k.endswith("_buffer")]
    assert planes
    assert all(rec[k] == 0 for k in planes)
    assert all(v == 0 or v == [0] * len(v) for k, v in rec.items() if k not in FILLED_GENERAL), rec


def test_qr_with_axes_sends_those_blocks_and_says_so_in_the_header() -> None:
    sim = busy("DMC-4040")
    reply = ask(sim, "QR DB")
    assert reply.endswith(b":")
    rec = record_to_dict(decode_record(reply[:-1], sim.spec))
    assert rec["axes_present"] == 0b1010
    assert rec["size"] == 4 + 52 + 26 + 2 * 36 == len(reply) - 1
    check_axis(sim, "B", rec["B"])
    check_axis(sim, "D", rec["D"])
    assert "A" not in rec
    assert ask(sim, "QR I") == sim.record() + b":"


def test_dr_streams_a_record_every_period_at_its_exact_sample() -> None:
    sim = SimController("DMC-4040", ManualClock())
    port = sim.open_port("records")
    assert sim.feed(b"JG 1000;BG A\r") == b"::"
    assert sim.feed(b"DR 8\r", port=port) == b":"
    start = sim.sample
    out = b""
    for chunk in (0.001, 0.013, 0.0005, 0.02, 0.007):  # the host polls at odd times
        sim.advance(chunk)
        out += sim.poll(port=port)
    size = sim.spec.record_size
    assert size is not None
    records = [out[i : i + size] for i in range(0, len(out), size)]
    assert b"".join(records) == out  # no ':' between streamed records
    samples = [decode_record(r, sim.spec)["sample"] for r in records]
    assert samples == list(range(start + 8, sim.sample + 1, 8))
    assert sim.feed(b"DR 0;MG _DR\r", port=port) == b": 0.0000\r\n:"


@pytest.mark.parametrize(
    ("model", "blocks", "general"),
    [("DMC-4040", "ABCD", None), ("DMC-2183", "ABCDEFGH", None), ("DMC-30010", "A", 2)],
)
def test_analog_inputs_are_in_their_axis_blocks_and_the_30010s_second_in_the_general_block(
    model: str, blocks: str, general: int | None
) -> None:
    sim = SimController(model, ManualClock())
    volts = [(-1) ** n * 1.25 * (n + 1) for n in range(sim.spec.analog_inputs)]
    if model == "DMC-30010":
        volts[1] = 1.25  # (its input 2 reads 0-5 V: 13107.2 counts/V, unsigned; EPICS)
    for n, v in enumerate(volts, start=1):
        sim.set_analog_input(n, v)
        assert number(sim, f"MG @AN[{n}]*10000") == round(v * 10000)

    def counts(v: float) -> int:  # ±10 V: 3276.8 counts/V, two's complement
        return round(v * 32768 / 10) & 0xFFFF

    rec = record_to_dict(decode_record(sim.record(), sim.spec))
    for k, letter in enumerate(blocks):
        want = counts(volts[k]) if k < len(volts) else 0
        assert rec[letter]["analog_in"] == want, letter
    if general is not None:
        assert rec["analog_in"] == round(volts[general - 1] * 13107.2) == 16384


def test_the_18x2_record_ends_each_axis_block_in_two_reserved_bytes() -> None:
    sim = SimController("DMC-18x2", ManualClock())
    sim.set_analog_input(1, 5.0)
    data = sim.record()
    assert len(data) == 4 + 24 + 16 + 4 * 28  # gclib GDataRecord1802 after the QR header
    rec = record_to_dict(decode_record(data, sim.spec))
    assert rec["A"]["reserved"] == 0  # not the analog input: the 18x2 puts none there
    assert "analog_in" not in rec["A"]
    # gclib's current GDataRecord1802 (no header: "Software removes it from QR"): axis B's
    # block at 68-95, its reference and motor positions at 72 and 76; on the wire 4 bytes
    # later. (The older revision's 26-byte blocks would put them at 70 and 74.)
    assert ask(sim, "DPB=4660") == b":"
    body = sim.record()[4:]
    assert int.from_bytes(body[72:76], "little", signed=True) == 4660 == number(sim, "RPB")
    assert int.from_bytes(body[76:80], "little", signed=True) == 4660 == number(sim, "TPB")
