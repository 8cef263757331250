"""What every benchmark shares: timing, figures against targets and anchors, scaling, JSON.

A benchmark script measures, then builds :class:`Figure` objects: the figure, its target, the
anchor it is compared with in the same run (a raw socket, numpy's own kernel, ruckig, the
link's byte rate) and how its cost grows with the work (:class:`Scaling`). ``finish()``
prints them and, with ``--json PATH``, writes them for ``benchmarks/run.py`` (``make bench``),
which gathers every script's figures into one table and ``benchmarks/results/bench.json``.

The machine is shared (two cores, other processes running tests): figures are medians or
best-of-N of short runs, and comparisons with an anchor interleave the two.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "Figure",
    "Scaling",
    "best",
    "cpu_best",
    "finish",
    "interleaved",
    "options",
    "table",
]


@dataclass
class Scaling:
    """How a cost grows with the work: ``points`` are (work, seconds) at growing work.

    ``label`` names the work (``"segments"``, ``"s of motion"``); ``growth`` gives, for each
    step, how many times the time grew for 10x the work.
    """

    label: str
    points: list[tuple[float, float]]

    def growth(self) -> list[float]:
        """Time growth per 10x work between consecutive points."""
        out = []
        for (w0, t0), (w1, t1) in zip(self.points, self.points[1:], strict=False):
            decades = math.log10(w1 / w0)
            out.append((t1 / t0) ** (1 / decades) if t0 > 0 and decades > 0 else math.nan)
        return out

    def text(self) -> str:
        cells = ", ".join(f"{_work(w)}: {_seconds(t)}" for w, t in self.points)
        growth = ", ".join(f"{g:.2g}x" for g in self.growth())
        return f"{self.label} {cells}; 10x the work -> {growth} the time"


@dataclass
class Figure:
    """One measured figure against its target, and against its anchor in the same run.

    Attributes:
        name: what is measured (``"predict.contour"``).
        value: the figure, in ``unit``.
        unit: its unit (``"M samples/s"``, ``"us"``, ``"x real time"``).
        target: the target value (``None``: reported, no target).
        higher: whether higher is better (``False`` for times, overheads, CPU shares).
        anchor: what it is compared with (``"bare numpy kernel"``, ``"raw socket"``).
        anchor_value: the anchor's figure in the same run, same unit.
        ratio: the comparison that matters (``value / anchor_value``, or a time ratio).
        ratio_text: what the ratio means (``"x the anchor's time"``).
        ratio_target: the ratio's own target, if any.
        ratio_higher: whether a higher ratio is better.
        scaling: how the cost grows with the work, if measured.
        note: anything a reader needs (the conditions, a reason for a miss).
    """

    name: str
    value: float
    unit: str
    target: float | None = None
    higher: bool = True
    anchor: str = ""
    anchor_value: float | None = None
    ratio: float | None = None
    ratio_text: str = ""
    ratio_target: float | None = None
    ratio_higher: bool = False
    scaling: list[Scaling] = field(default_factory=list)
    note: str = ""

    @property
    def ok(self) -> bool:
        """Every target met (a figure without targets is ok)."""
        good = True
        if self.target is not None:
            good = self.value >= self.target if self.higher else self.value <= self.target
        if self.ratio_target is not None and self.ratio is not None:
            r, t = self.ratio, self.ratio_target
            good = good and (r >= t if self.ratio_higher else r <= t)
        return good

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["scaling"] = [
            {"label": s.label, "points": s.points, "growth_per_10x": s.growth()}
            for s in self.scaling
        ]
        out["ok"] = self.ok
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Figure:
        data = dict(data)
        data.pop("ok", None)
        scaling = [
            Scaling(s["label"], [tuple(p) for p in s["points"]]) for s in data.pop("scaling")
        ]
        return cls(**data, scaling=scaling)

    def lines(self) -> list[str]:
        """The figure as the table prints it: one line, then its scaling and note."""
        target = "" if self.target is None else f"{'>=' if self.higher else '<='} {self.target:g}"
        head = f"{self.name:34s} {_num(self.value):>10s} {self.unit:16s} {target:11s}"
        if self.anchor:
            anchor = self.anchor
            if self.anchor_value is not None:
                anchor += f" {_num(self.anchor_value)}"
            head += f" vs {anchor}"
        if self.ratio is not None:
            head += f": {self.ratio:.3g}{self.ratio_text}"
            if self.ratio_target is not None:
                head += f" ({'>=' if self.ratio_higher else '<='} {self.ratio_target:g})"
        head += "   ok" if self.ok else "   MISSED"
        out = [head]
        out += [f"{'':36s}scaling: {s.text()}" for s in self.scaling]
        if self.note:
            out.append(f"{'':36s}{self.note}")
        return out


def _num(v: float) -> str:
    if v == 0 or not math.isfinite(v):
        return f"{v:g}"
    if abs(v) >= 1000:
        return f"{v:,.0f}"
    return f"{v:.3g}"


def _work(w: float) -> str:
    for div, suffix in ((1e6, "M"), (1e3, "k")):
        if w >= div and w % div == 0:
            return f"{w / div:g}{suffix}"
    return f"{w:g}"


def _seconds(t: float) -> str:
    if t >= 1:
        return f"{t:.3g} s"
    if t >= 1e-3:
        return f"{t * 1e3:.3g} ms"
    return f"{t * 1e6:.3g} us"


def best(fn: Callable[[], object], repeat: int = 7, number: int = 1) -> float:
    """Best wall time of ``number`` calls over ``repeat`` rounds, seconds per call."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times)


def cpu_best(fn: Callable[[], object], repeat: int = 7, number: int = 1) -> float:
    """Best CPU time of this process for ``number`` calls, seconds per call.

    Other processes' load does not count; use it for work that never waits.
    """
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(number):
            fn()
        times.append((time.process_time() - t0) / number)
    return min(times)


def interleaved(
    a: Callable[[], float], b: Callable[[], float], pairs: int
) -> tuple[float, float, float]:
    """Run ``a`` and ``b`` (each returns a time) in alternating order, ``pairs`` times.

    Returns the medians of a and b and the median of the per-pair ratios b / a: a burst of
    load from elsewhere hits both sides of a pair alike, and the median drops the rest.
    """
    ta, tb, ratios = [], [], []
    for i in range(pairs):
        if i % 2:
            y = b()
            x = a()
        else:
            x = a()
            y = b()
        ta.append(x)
        tb.append(y)
        ratios.append(y / x)
    return statistics.median(ta), statistics.median(tb), statistics.median(ratios)


def options(doc: str | None, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The options every benchmark script takes: ``--quick`` and ``--json PATH``."""
    parser = argparse.ArgumentParser(description=(doc or "").split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (figures noisier)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    return parser.parse_args(argv)


def table(figures: Sequence[Figure]) -> str:
    """The figures as lines of text, then a one-line summary."""
    lines: list[str] = []
    for f in figures:
        lines += f.lines()
    met = sum(f.ok for f in figures)
    missed = [f.name for f in figures if not f.ok]
    summary = f"{met} of {len(figures)} figures meet their targets"
    if missed:
        summary += f"; missed: {', '.join(missed)}"
    lines.append(summary)
    return "\n".join(lines)


def finish(figures: Sequence[Figure], args: argparse.Namespace) -> None:
    """Print the figures; write them as JSON when ``--json`` was given."""
    print(table(figures))
    sys.stdout.flush()
    if args.json is not None:
        args.json.write_text(json.dumps([f.to_json() for f in figures], indent=1))
