"""No VF, LZ or PF that a user or a program sets changes what the library reads (decision 0032).

``MG`` prints numbers in the VF format: ``VF 4.0`` prints 123456 as ``9999``, ``VF 1.0`` as
``9``, ``VF -4.0`` in hex (``$FFFF`` when it overflows), and drops the fraction. The library
asks for every number it reads in ``{Z10.4}`` and reads ``QU``/``LV`` with ``VF 10.4`` put in
for them, so positions, speeds, stop codes, the ``MG TIME`` of a move, arrays and variables
stay exact, and the user's setting is still in force afterwards.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import galil
from galil.errors import ProtocolError
from galil.protocol import commands as cmds
from galil.protocol.numbers import parse_plain_read, parse_read, read_one
from galil.protocol.records import SAMPLE_WRAP
from galil.sim.clock import RealTimeClock
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.testing import sim_of, simulated, transcript

SETTINGS = ["VF 4.0", "VF 1.0", "VF -4.0", "VF 4.4", "VF 10.2", "LZ 0", "PF 2.0"]
ARRAY = [1.5, -2.0, 123456.0, 0.25, -2147483648.0, 2147483647.0]


def _set_format(dmc: galil.Controller, setting: str, by: str) -> None:
    if by == "raw":
        dmc.command(setting)
    else:  # a lab program that sets the format for its own display
        dmc.programs.download(f"#FMT\n{setting}\nEN")
        dmc.programs.run("#FMT")
        dmc.programs.wait()


def _prepare(dmc: galil.Controller, idle: float = 12.0) -> None:
    dmc.A.speed, dmc.A.accel, dmc.A.decel = 1_000_000, 10_240_000, 10_240_000
    dmc.A.smoothing = 0.5  # a fraction: VF n.0 would drop it
    dmc.variables["gain"] = 12345.25
    dmc.arrays.define("samples", len(ARRAY))
    dmc.arrays.download("samples", ARRAY)
    dmc.sleep(idle)  # TIME past 9999 (12 s), so VF 4.0 would cut the move's MG TIME


def _check_reads_and_a_move(dmc: galil.Controller, sim: SimController) -> None:
    start = dmc.A.reference_position
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a prediction away from the motion warns: fail on it
        handle = dmc.A.move_by(123456)
        begin = [sample for sample, text in sim.command_log if text == "BG A"][-1]
        result = handle.wait()
    assert handle.begin == {"A": begin}  # the move's MG TIME read exactly
    assert result.stop_codes == {"A": 1}
    assert result.final == result.predicted == {"A": start + 123456}
    assert dmc.A.reference_position == start + 123456
    assert dmc.A.position == start + 123456  # (no servo lag on this simulator)
    assert (dmc.A.speed, dmc.A.accel) == (1_000_000, 10_240_000)
    assert dmc.A.smoothing == 0.5
    assert dmc.A.stop_code[0] == 1
    assert dmc.query_operands(["gain", "_RPA"]) == [12345.25, start + 123456]
    assert dmc.variables["gain"] == 12345.25
    assert dmc.variables.list() == {"gain": 12345.25}
    np.testing.assert_array_equal(dmc.arrays.upload("samples"), ARRAY)
    record = dmc.record("A", as_dict=True)  # QZ's layout, the record, its MG TIME
    assert record["A"]["reference"] == start + 123456
    assert record["time"] > 9999
    assert record["time"] % SAMPLE_WRAP == record["sample"]


@pytest.mark.parametrize("by", ["raw", "program"])
@pytest.mark.parametrize("setting", SETTINGS)
def test_reads_moves_arrays_and_variables_are_exact_whatever_format_is_set(
    setting: str, by: str
) -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.set_servo_lag(0.0)
        _prepare(dmc)
        _set_format(dmc, setting, by)
        shown = dmc.command("MG 123456.5")
        _check_reads_and_a_move(dmc, sim)
        assert dmc.command("MG 123456.5") == shown  # the user's format is still in force


@pytest.mark.parametrize("setting", ["VF 4.0", "VF -4.0"])
def test_reads_over_tcp_are_exact_after_a_program_set_the_format(setting: str) -> None:
    sim = SimController("DMC-4040", RealTimeClock(speed=40.0))  # 12 s pass in 0.3 s
    sim.set_servo_lag(0.0)
    with SimTcpServer(sim) as server, galil.connect(server.url) as dmc:
        _prepare(dmc, idle=0.3)
        _set_format(dmc, setting, "program")
        _check_reads_and_a_move(dmc, server.controller)


def test_homing_ends_at_the_index_whatever_format_is_set() -> None:
    with simulated() as dmc:
        sim = sim_of(dmc)
        sim.set_servo_lag(0.0)
        dmc.sleep(12.0)
        _set_format(dmc, "VF 4.0", "program")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            handle = dmc.A.home(switch=sim.home_switch("A"))
            begin = [sample for sample, text in sim.command_log if text == "BG A"][-1]
            result = handle.wait()
        assert handle.begin == {"A": begin}  # its MG TIME read exactly
        assert result.stop_codes == {"A": 10}
        assert dmc.A.reference_position == result.final["A"] == result.predicted["A"]


def test_the_read_format_is_on_every_item_the_library_reads() -> None:
    names = ["_RPA", "_BGA", "TIME", "gain", "arr[3]", "@IN[1]"] * 4
    lines = cmds.mg_operand_lines(names, 80)
    assert len(lines) > 1
    assert all(len(line.text) + 1 <= 80 for line in lines)
    items = ",".join(line.text.removeprefix("MG ") for line in lines).split(",")
    assert items == [n + "{Z10.4}" for n in names]
    assert cmds.time_stamp().text == "MG TIME{Z10.4}"


@pytest.mark.parametrize(
    ("reply", "values"),
    [
        (" 12.0000-3.5000 0.0001", [12.0, -3.5, 0.0001]),
        ("12.00002.0000", [12.0, 2.0]),  # no blank between them: four decimals end each
        (" 0000000123.0000", [123.0]),  # leading zeros (LZ 0, {F})
        (" 2147483647.0000-2147483648.0000", [2147483647.0, -2147483648.0]),
    ],
)
def test_read_replies_are_numbers_with_four_decimals(reply: str, values: list[float]) -> None:
    assert parse_read(reply) == values


@pytest.mark.parametrize("reply", ["9999", " 9", "$FFFF", "$0001E240.0000", " 1.00", "", "x"])
def test_a_read_reply_in_another_format_is_refused_not_misread(reply: str) -> None:
    with pytest.raises(ProtocolError):
        parse_read(reply)
    with pytest.raises(ProtocolError):
        read_one(reply)


def test_reads_go_plain_and_ask_again_formatted_only_when_the_reply_may_be_another_format() -> None:
    with simulated() as dmc:
        dmc.A.move_by(123456).wait()
        dmc.command("gv=9999")
        with transcript(dmc) as wire:
            assert dmc.query_operands(["_RPA", "_BGA"]) == [123456, 0]
        wire.assert_sent(["MG _RPA,_BGA"])  # the default VF: one plain line, nothing more
        with transcript(dmc) as wire:
            assert dmc.query_operands(["gv"]) == [9999]  # a true 9999 reads 9999
        wire.assert_sent(["MG gv", "MG gv{Z10.4}"])
        dmc.command("VF 4.4")  # 123456 prints as 9999.9999: an overflow
        with transcript(dmc) as wire:
            assert dmc.query_operands(["_RPA", "_BGA"]) == [123456, 0]
        wire.assert_sent(["MG _RPA,_BGA", "MG _RPA{Z10.4},_BGA{Z10.4}"])


@pytest.mark.parametrize(
    ("reply", "values"),
    [
        (" 12.0000-3.5000 0.0001", [12.0, -3.5, 0.0001]),
        (" 19.0000 90.0000 0.9999", [19.0, 90.0, 0.9999]),
        (" 0000000123.0000", [123.0]),
        (" 9999.9999", None),  # VF 4.4's overflow (or a true 9999.9999: asked again)
        ("-99.0000", None),
        (" 9.5000", None),
        (" 123", None),  # VF n.0
        (" 1.50", None),
        ("$FFFF", None),
        ("", None),
    ],
)
def test_a_plain_read_is_taken_only_in_the_default_format(
    reply: str, values: list[float] | None
) -> None:
    assert parse_plain_read(reply) == values
