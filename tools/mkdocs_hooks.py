"""MkDocs hook: the Decisions section of the nav lists every file in docs/decisions, in order.

A new decision record then needs no edit of mkdocs.yml (and cannot be forgotten by it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def on_config(config: Any) -> Any:
    """Fill the ``Decisions`` entry of the nav from the directory."""
    docs = Path(config["docs_dir"])
    records = sorted(p.relative_to(docs).as_posix() for p in (docs / "decisions").glob("*.md"))
    for entry in config["nav"] or []:
        if isinstance(entry, dict) and "Decisions" in entry:
            entry["Decisions"] = records
    return config
