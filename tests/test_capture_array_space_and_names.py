"""A capture keeps to the array space the user's arrays leave, frees what a failed start set up,
and its arrays' names (gcap0 ..) are not the user's (decision 0097). Arrays take real numbers
only (decision 0026)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from rewritten_replies import lost, rewritten

import galil
from galil.errors import GalilTimeoutError, ProtocolError
from galil.testing import simulated, transcript


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated("DMC-4040") as controller:
        yield controller


def test_a_capture_that_does_not_fit_beside_the_users_arrays_is_refused_before_any_is_set_up(
    dmc: galil.Controller,
) -> None:
    dmc.arrays.define("mine", 20_000)  # of 24,000 elements
    with transcript(dmc) as sent, pytest.raises(galil.InvalidArgument, match="leave 4000 of"):
        dmc.capture(["_RPA", "_TPA"], every=2, count=3000)
    assert sent.lines == ["MG _RC", "LA"]  # read, nothing set up
    assert dmc.arrays.list() == {"mine": 20_000}
    dmc.arrays.delete("mine")
    rec = dmc.capture(["_RPA", "_TPA"], every=2, count=3000).wait()
    assert len(rec) == 3000
    assert dmc.arrays.list() == {}


def test_a_capture_needing_more_arrays_than_are_free_is_refused(dmc: galil.Controller) -> None:
    for i in range(29):  # of 30 arrays
        dmc.arrays.define(f"z{i}", 10)
    with pytest.raises(galil.InvalidArgument, match="1 of 30 arrays"):
        dmc.capture(["_RPA", "_TPA"], every=2, count=10)
    assert len(dmc.arrays.list()) == 29
    assert len(dmc.capture(["_RPA"], every=2, count=10).wait()) == 10  # one fits


@pytest.mark.parametrize(
    ("mark", "error"),
    [(b"DM gcap0", GalilTimeoutError), (b"RC 1,", GalilTimeoutError)],
    ids=["set-up", "rc"],
)
def test_a_capture_whose_start_fails_frees_the_arrays_it_set_up(
    mark: bytes, error: type[Exception]
) -> None:
    dmc, wire = rewritten()
    with dmc:
        dmc.arrays.define("mine", 5)
        wire.once(mark, lost)  # the line ran; its reply is lost
        with pytest.raises(error):
            dmc.capture(["_RPA", "_TPA"], every=2, count=100)
        assert not wire.rules
        assert dmc.query_operands(["_RC"]) == [0]
        assert dmc.arrays.list() == {"mine": 5}  # gcap0 and gcap1 are freed again


def test_a_capture_malformed_at_its_start_frees_its_arrays() -> None:
    dmc, wire = rewritten()
    with dmc:
        wire.once(b"RC 1,", lambda answer: answer.replace(b".0000", b".00x0"))
        with pytest.raises(ProtocolError):
            dmc.capture(["_RPA"], every=2, count=100)
        assert dmc.arrays.list() == {}


@pytest.mark.parametrize("name", ["gcap0", "gcap7"])
def test_a_captures_array_names_are_refused_to_the_user(dmc: galil.Controller, name: str) -> None:
    with transcript(dmc) as sent, pytest.raises(galil.InvalidArgument, match="captures record"):
        dmc.arrays.define(name, 5)
    assert sent.lines == []
    with pytest.raises(galil.InvalidArgument, match="captures record"):
        dmc.arrays.download(name, [1, 2, 3])
    dmc.arrays.define("gcap", 5)  # (other names are the user's)
    dmc.arrays.define("gcap8", 5)
    rec = dmc.capture(["_RPA"], every=2, count=3).wait()
    assert len(rec) == 3
    assert dmc.arrays.list() == {"gcap": 5, "gcap8": 5}


@pytest.mark.parametrize(
    "values",
    [["1"], [True], [1, False], np.array([True, False]), [1 + 2j], "12", [b"1"]],
    ids=["str", "bool", "bool-among-ints", "numpy-bool", "complex", "a-string", "bytes"],
)
def test_array_values_that_are_not_real_numbers_are_refused_before_a_byte(
    dmc: galil.Controller, values: object
) -> None:
    dmc.arrays.define("a", 4)
    with transcript(dmc) as sent, pytest.raises(galil.InvalidArgument):
        dmc.arrays.download("a", values)  # type: ignore[arg-type]
    assert not any(line.startswith("QD") for line in sent.lines)
    assert dmc.arrays.upload("a").tolist() == [0, 0, 0, 0]
    dmc.arrays.download("a", [1, 2.5, np.int64(3), np.float32(4)])  # numbers still are
    assert dmc.arrays.upload("a").tolist() == [1, 2.5, 3, 4]


def test_every_rd_source_the_library_takes_the_simulator_records(
    dmc: galil.Controller,
) -> None:
    sources = ["_TPA", "_TEA", "_DEA", "_TSA", "_SCA", "_TTA", "_RPA", "_TVA", "_TI0", "_OP0"]
    for some in (sources[:8], sources[8:]):  # (8 sources at most)
        rec = dmc.capture(some, every=2, count=4).wait()
        assert rec.sources == tuple(some)
        now = dmc.query_operands(some)  # nothing moves: each value is the operand's
        assert [rec[s].tolist() for s in some] == [[v] * 4 for v in now]
    rec = dmc.capture(["TIME"], every=4, count=3).wait()
    assert np.diff(rec["TIME"]).tolist() == [4, 4]
    assert rec["TIME"][0] == rec.start


@pytest.mark.parametrize("source", ["_AFA", "_SHA", "_RLA", "_NOA", "_TI", "_OP"])
def test_a_source_outside_the_rd_list_is_refused_by_the_library_and_the_simulator_alike(
    dmc: galil.Controller, source: str
) -> None:
    with transcript(dmc) as sent, pytest.raises(galil.InvalidArgument, match="cannot record"):
        dmc.capture([source], every=2, count=4)
    assert sent.lines == []
    with pytest.raises(galil.CommandError, match="TC 1 "):
        dmc.command(f"RD {source}")  # the simulator's RD checks the same list
    dmc.command("RD _TTA")
