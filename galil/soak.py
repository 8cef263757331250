"""A link soak: many threads set and read variables through one controller, and every reply is
checked. Run it through a fault proxy (``galil.sim.proxy``) to see what a bad link does, or
against a bench controller to trust a cable.

It counts what matters to a user: wrong replies (a value read back that was never set), hangs
(a call that outlived several timeouts), and commands reported "rejected" (``CommandError``)
that the controller nevertheless executed. Errors that say "this may have run"
(``ProtocolError``, timeouts) are counted, not blamed.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from galil.controller import Controller
from galil.errors import CommandError, GalilError

__all__ = ["SoakReport", "soak"]


@dataclass
class SoakReport:
    """What a soak saw."""

    pairs: int = 0
    wrong: int = 0
    hangs: int = 0
    rejected_but_ran: int = 0
    uncertain: int = 0  # errors that said the command may have run (timeouts, out of step)
    slowest: float = 0.0
    seconds: float = 0.0
    examples: list[str] = field(default_factory=list)

    def merge(self, other: SoakReport) -> None:
        """Add another thread's counts."""
        self.pairs += other.pairs
        self.wrong += other.wrong
        self.hangs += other.hangs
        self.rejected_but_ran += other.rejected_but_ran
        self.uncertain += other.uncertain
        self.slowest = max(self.slowest, other.slowest)
        self.examples += other.examples[: 5 - len(self.examples)]

    def __str__(self) -> str:
        return (
            f"{self.pairs} set-then-read pairs in {self.seconds:.1f} s: {self.wrong} wrong "
            f"replies, {self.hangs} hangs, {self.rejected_but_ran} reported rejected that ran, "
            f"{self.uncertain} uncertain (may have run), slowest call {self.slowest:.3f} s"
        )


def _timed(report: SoakReport, limit: float, start: float) -> None:
    took = time.monotonic() - start
    report.slowest = max(report.slowest, took)
    if took > limit:
        report.hangs += 1


def _one_thread(dmc: Controller, k: int, pairs: int, hang: float) -> SoakReport:
    report = SoakReport()
    name = f"soak{k}"
    known = {0.0}  # values the variable may hold (one once a set is confirmed)
    _reset(dmc, name)
    for i in range(1, pairs + 1):
        value = float(k * 1_000_000 + i)
        start = time.monotonic()
        try:
            dmc.command(f"{name}={value:.0f}")
            known = {value}
        except CommandError as exc:
            known = {value, *known}
            report.examples.append(f"set {value:.0f}: {exc}".splitlines()[0])
            report.rejected_but_ran += _ran(dmc, name, value)
        except GalilError:
            report.uncertain += 1
            known = {value, *known}
        _timed(report, hang, start)
        start = time.monotonic()
        try:
            got = dmc.query_operands([name])[0]
            if got not in known:
                report.wrong += 1
                report.examples.append(f"read {got} after setting {value:.0f}")
            known = {got}
        except GalilError:
            report.uncertain += 1
        _timed(report, hang, start)
        report.pairs += 1
    return report


def _reset(dmc: Controller, name: str) -> None:
    """Set the variable to 0, however many tries the faulty link needs."""
    for _ in range(100):
        try:
            dmc.command(f"{name}=0")
            if dmc.query_operands([name])[0] == 0:
                return
        except GalilError:
            continue
    raise GalilError(f"could not set {name} through the link")


def _ran(dmc: Controller, name: str, value: float) -> int:
    """1 when a 'rejected' set took effect after all (read back until the link answers)."""
    for _ in range(5):
        try:
            return int(dmc.query_operands([name])[0] == value)
        except GalilError:
            continue
    return 0


def soak(dmc: Controller, *, pairs: int = 5000, threads: int = 4) -> SoakReport:
    """Run ``pairs`` set-then-read pairs on each of ``threads`` threads; return the counts.

    A call is a hang when it takes longer than five reply timeouts.
    """
    hang = 5 * dmc.timeout + 1.0
    reports: list[SoakReport] = [SoakReport() for _ in range(threads)]

    def run(k: int) -> None:
        reports[k] = _one_thread(dmc, k, pairs, hang)

    began = time.monotonic()
    workers = [threading.Thread(target=run, args=(k,), name=f"soak-{k}") for k in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    total = SoakReport(seconds=time.monotonic() - began)
    for r in reports:
        total.merge(r)
    return total
