"""Variable and array names as the controller reads them, and ``controller.variables`` as a
``MutableMapping`` (decision 0060), sync and async, on the in-process simulator.

A command is two upper-case letters and names are case-sensitive (DMC-2x00 user manual:
"Variables are case sensitive"; the DMC-4103 reference's own examples use ``date``, ``len``,
``ta0``), so a lower-case name that begins like a command is a name; an upper-case one the
controller would read as a command (``DA``, ``CD0``, ``SPA``) is refused before a byte.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import MutableMapping

import pytest

import galil
import galil.aio as aio
from galil.arrays import LIBRARY_VARIABLES
from galil.io import _input_routine
from galil.motion import SCHEDULE_BEGIN
from galil.protocol import commands as cmds
from galil.testing import nothing_sent, sim_of, simulated, transcript
from galil.watchdog import watchdog_routine

#: A scientist's first names, and those of the DMC-4103 reference's examples (``date``,
#: ``len``, ``ta0``): each begins with a command's letters in lower case.
LOWER_CASE = ["data", "scan", "idx", "mode", "res", "tab", "pts", "big", "date", "len", "ta0"]
#: Mixed case: the first two letters are not both upper case, so no command.
MIXED_CASE = ["Data", "dA", "Scan"]
#: What the controller would read as a command, or a keyword: refused.
CLASHES = ["DA", "DATA", "CD0", "SPA", "SPa", "PR", "BGAB", "TIME", "ELSE"]


@pytest.fixture
def dmc() -> galil.Controller:
    with simulated() as controller:
        yield controller


def test_lower_and_mixed_case_names_that_begin_like_a_command_are_variables(
    dmc: galil.Controller,
) -> None:
    names = LOWER_CASE + MIXED_CASE
    for i, name in enumerate(names):
        dmc.variables[name] = i
    assert dmc.variables.list() == {name: float(i) for i, name in enumerate(names)}
    assert dmc.variables["data"] == 0
    assert dmc.variables["Data"] == len(LOWER_CASE)


def test_a_lower_case_name_is_an_array_too(dmc: galil.Controller) -> None:
    dmc.arrays.define("data", 3)
    dmc.arrays.download("data", [1, 2, 3])
    assert dmc.arrays.upload("data").tolist() == [1, 2, 3]
    assert dmc.arrays.list() == {"data": 3}
    dmc.arrays.delete("data")
    assert "data" not in dmc.arrays


@pytest.mark.parametrize("name", CLASHES)
def test_an_upper_case_name_the_controller_reads_as_a_command_is_refused_before_a_byte(
    dmc: galil.Controller, name: str
) -> None:
    words = "keyword" if name in ("TIME", "ELSE") else f"clashes with the command {name[:2]}"
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=words):
        dmc.variables[name] = 1
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match=words):
        dmc.arrays.define(name, 4)


def test_the_refusal_names_the_lower_case_name_that_would_do(dmc: galil.Controller) -> None:
    with pytest.raises(galil.InvalidArgument, match="'data' is not one"):
        dmc.variables["DATA"] = 1
    dmc.variables["data"] = 1  # the advice holds


def test_the_simulator_reads_a_lower_case_name_as_a_variable_beside_the_command(
    dmc: galil.Controller,
) -> None:
    # "da" is a variable, "DA da" the command freeing it; "da" alone is no command (TC 1).
    sim = sim_of(dmc)
    assert sim.feed(b"da=5;MG da;da=;DA da;LV\r") == b": 5.0000\r\n: 5.0000\r\n:::"
    assert sim.feed(b"da\r") == b"?"


def test_variables_are_a_mutable_mapping(dmc: galil.Controller) -> None:
    v = dmc.variables
    assert isinstance(v, MutableMapping)
    v.update({"data": 1.5, "scan": -2})
    assert dict(v) == {"data": 1.5, "scan": -2.0}
    assert list(v.keys()) == ["data", "scan"]
    assert dict(v.items()) == {"data": 1.5, "scan": -2.0}
    assert list(v.values()) == [1.5, -2.0]
    assert v.get("data") == 1.5
    assert v.get("nothere") is None
    assert v.get("nothere", 7) == 7
    assert "data" in v
    assert "nothere" not in v
    assert 3 not in v
    assert v.setdefault("idx", 4) == 4
    assert v.setdefault("idx", 9) == 4
    assert v.pop("scan") == -2
    assert v.pop("scan", None) is None
    del v["idx"]
    assert v.list() == {"data": 1.5}
    v.clear()
    assert len(v) == 0
    assert dict(v) == {}


def test_a_missing_variable_is_a_key_error_and_a_command_error(dmc: galil.Controller) -> None:
    with pytest.raises(KeyError) as info:
        dmc.variables["nothere"]
    error = info.value
    assert isinstance(error, galil.UnknownVariableError)
    assert isinstance(error, galil.CommandError)
    assert error.code == 1
    assert error.name == "nothere"
    assert str(error).startswith("there is no variable 'nothere' on the controller")
    with pytest.raises(galil.UnknownVariableError, match="no variable 'nothere'"):
        del dmc.variables["nothere"]
    with pytest.raises(KeyError):
        dmc.variables.pop("nothere")


def test_deleting_a_variable_reads_it_then_frees_it_alone(dmc: galil.Controller) -> None:
    dmc.variables.update(gain=2, keep=3)
    with transcript(dmc) as sent:
        del dmc.variables["gain"]
    assert sent.lines[-1] == "DA gain"
    assert dmc.variables.list() == {"keep": 3.0}
    with transcript(dmc) as sent:
        dmc.variables.clear()
    assert [line for line in sent.lines if line.startswith("DA")] == ["DA keep"]
    assert dmc.variables.list() == {}


def test_a_bad_name_is_refused_before_a_byte_by_every_mapping_method(
    dmc: galil.Controller,
) -> None:
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        del dmc.variables["CD0"]
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument):
        dmc.variables.get("1x")
    with pytest.raises(galil.InvalidArgument):
        cmds.da_variables()


def test_async_names_and_deletion_agree_with_the_sync_ones() -> None:
    async def body() -> None:
        async with await aio.connect("sim://") as c:
            for name in LOWER_CASE:
                await c.variables.write(name, 1)
            assert sorted(await c.variables.list()) == sorted(LOWER_CASE)
            with pytest.raises(galil.InvalidArgument, match="clashes with the command DA"):
                await c.variables.write("DATA", 1)
            await c.arrays.define("scan", 2)
            assert await c.arrays.contains("scan")
            await c.variables.delete("data")
            assert not await c.variables.contains("data")
            with pytest.raises(KeyError):
                await c.variables["data"]
            with pytest.raises(galil.UnknownVariableError):
                await c.variables.delete("data")
            await c.variables.clear()
            assert await c.variables.list() == {}

    asyncio.run(asyncio.wait_for(body(), 30))


def test_clearing_the_variables_keeps_a_running_watchdog_guarding(dmc: galil.Controller) -> None:
    dog = dmc.watchdog(1.0)
    dmc.variables.update({f"v{i}": i for i in range(8)})  # two DA lines
    with transcript(dmc) as sent:
        dmc.variables.clear()
    assert [line for line in sent.lines if line.startswith("DA")] == [
        "DA v0,v1,v2,v3,v4,v5",
        "DA v6,v7",
    ]
    assert set(dmc.variables) == {"gwbeat", "gwlimit", "gwfire"}
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="library's own"):
        del dmc.variables["gwlimit"]
    dmc.sleep(0.1)
    assert dog.running
    dog.stop()


def test_the_library_variables_are_those_its_routines_use() -> None:
    # Every lower-case name beginning with "g" outside quotes in the library's routines.
    lines = [*watchdog_routine("AB").lines, *_input_routine().lines, f"{SCHEDULE_BEGIN}=TIME"]
    text = " ".join(re.sub(r'"[^"]*"', "", line) for line in lines)
    assert set(re.findall(r"\bg[a-z0-9]+\b", text)) == LIBRARY_VARIABLES
