"""The repository itself: no merge-conflict markers left in any tracked text file."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
_MARKER = re.compile(r"^(<<<<<<<|>>>>>>>) |^=======$", re.MULTILINE)


def _tracked() -> list[Path]:
    try:
        out = subprocess.run(
            ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):  # not a git checkout (an sdist)
        return [p for p in ROOT.rglob("*") if p.is_file() and ".venv" not in p.parts]
    return [ROOT / line for line in out.splitlines() if line]


def test_no_conflict_markers_are_left_in_any_file() -> None:
    left = []
    for path in _tracked():
        if path.suffix in (".png", ".gz", ".whl", ".ipynb") or not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        starts = [m.group(1) or "=" for m in _MARKER.finditer(text)]
        if "<<<<<<<" in starts and ">>>>>>>" in starts:
            left.append(str(path.relative_to(ROOT)))
    assert left == []
