"""Run every benchmark, print each figure against its target and anchor, write the JSON.

Each script runs in a process of its own (its threads, simulators and allocations do not
disturb the next) with ``--json``; the figures are gathered into one table, a one-line
summary, and ``benchmarks/results/bench.json`` (the figures, the machine, the date).

Run: ``.venv/bin/python benchmarks/run.py [--quick] [name ...]`` (``make bench``); names pick
scripts (``predict``, ``host``, ...), default all. ``--quick`` shortens the long runs (the
60 s data-record streams become 10 s): for trying things, not for the figures of record.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from harness import Figure, table

HERE = Path(__file__).resolve().parent
#: The scripts, in the order they run (cheap and in-process first, streams last).
SCRIPTS = (
    "protocol",
    "predict",
    "host",
    "roundtrip",
    "records",
    "sim",
    "transfer",
    "contour_stream",
)


def run_script(name: str, quick: bool) -> tuple[list[Figure], float, int]:
    """Run one script; return its figures, its wall time and its exit code."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "figures.json"
        cmd = [sys.executable, str(HERE / f"{name}.py"), "--json", str(out)]
        if quick:
            cmd.append("--quick")
        print(f"\n=== {name} ===", flush=True)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, check=False)
        spent = time.perf_counter() - t0
        if not out.exists():
            return [], spent, proc.returncode or 1
        data = json.loads(out.read_text())
    return [Figure.from_json(d) for d in data], spent, proc.returncode


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (noisier figures)")
    parser.add_argument("names", nargs="*", help=f"scripts to run (default all: {SCRIPTS})")
    parser.add_argument(
        "--out", type=Path, default=HERE / "results" / "bench.json", help="the JSON written"
    )
    args = parser.parse_args()
    names = args.names or list(SCRIPTS)
    unknown = [n for n in names if n not in SCRIPTS]
    if unknown:
        parser.error(f"unknown benchmark(s) {unknown}; choose from {SCRIPTS}")
    figures: list[Figure] = []
    runs: dict[str, dict[str, float]] = {}
    failed: list[str] = []
    load0 = os.getloadavg()
    for name in names:
        got, spent, code = run_script(name, args.quick)
        figures += got
        runs[name] = {"seconds": round(spent, 1), "exit_code": code}
        if code != 0 and not got:
            failed.append(name)
    print("\n=== all figures (" + ("quick runs" if args.quick else "full runs") + ") ===")
    print(table(figures))
    if failed:
        print(f"scripts that failed: {', '.join(failed)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "quick": args.quick,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "platform": platform.platform(),
            "load_average_before": load0,
            "load_average_after": os.getloadavg(),
        },
        "scripts": runs,
        "met": sum(f.ok for f in figures),
        "figures": [f.to_json() for f in figures],
    }
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"written: {args.out}")
    return 0 if not failed and all(f.ok for f in figures) else 1


if __name__ == "__main__":
    sys.exit(main())
