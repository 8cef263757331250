"""The soak's checker itself: a link that gives a wrong value, hangs, or says "rejected" for a
set that ran is counted as such (the fault soak's zeros mean something only if these fire)."""

from __future__ import annotations

import itertools

import pytest

import galil.soak
from galil.errors import CommandError, ProtocolError
from galil.soak import soak


class BadLink:
    """A controller stand-in: variables in a dict, and one fault of ``kind`` on set number 3."""

    timeout = 0.1

    def __init__(self, kind: str, clock: list[float]) -> None:
        self.kind = kind
        self.clock = clock
        self.values: dict[str, float] = {}
        self.sets = itertools.count(1)

    def command(self, text: str) -> None:
        name, value = text.split("=")
        n = next(self.sets)
        self.values[name] = float(value)
        fault = n == 3 + 1  # the first set is the soak's own reset to 0
        if fault and self.kind == "rejected but ran":
            raise CommandError(1, "Unrecognized command", text)
        if fault and self.kind == "uncertain":
            raise ProtocolError(f"{text!r} may have executed")
        if fault and self.kind == "hang":
            self.clock[0] += 10.0  # ten seconds pass in this call

    def query_operands(self, names: list[str]) -> list[float]:
        (name,) = names
        value = self.values[name]
        if self.kind == "wrong" and value == 3:
            return [12345.0]  # a value never set
        return [value]


@pytest.mark.parametrize(
    ("kind", "field"),
    [
        ("wrong", "wrong"),
        ("hang", "hangs"),
        ("rejected but ran", "rejected_but_ran"),
        ("uncertain", "uncertain"),
        ("none", None),
    ],
)
def test_each_kind_of_fault_is_counted_once_and_nothing_else(
    kind: str, field: str | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    clock = [0.0]
    monkeypatch.setattr(galil.soak.time, "monotonic", lambda: clock[0])
    report = soak(BadLink(kind, clock), pairs=6, threads=1)  # type: ignore[arg-type]
    counts = {
        "wrong": report.wrong,
        "hangs": report.hangs,
        "rejected_but_ran": report.rejected_but_ran,
        "uncertain": report.uncertain,
    }
    assert report.pairs == 6
    assert counts == {k: int(k == field) for k in counts}, report.examples
