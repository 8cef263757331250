"""Outputs shown in the documentation's code are checked, not just shown.

A comment whose text starts with ``->`` shows one line that the code prints::

    print(plan.shape, f"{plan.duration:.3f} s")  # -> trapezoid 0.726 s
    print(dmc.command("UL"))  # -> #HELLO
    # -> MG "hello"

The rest of the comment is the whole line (surrounding blanks aside); ``...`` stands for
anything (a port number, a time that varies). The lines a block prints must contain the shown
ones in the order they are shown; other printed lines may come between them, except within a
run: the ``# ->`` lines that stand alone right below a shown line (a transcript, a listing)
show the lines printed right after it, none left out (:func:`shown_runs`: a line printed
twice where the page shows it once is caught). A comment that does not start with ``->`` is
prose and is not checked.
"""

from __future__ import annotations

import io
import re
import tokenize
from collections.abc import Sequence

__all__ = ["missing_outputs", "shown_outputs", "shown_runs"]

_SHOWN = re.compile(r"#\s*->(.*)$")


def shown_outputs(code: str) -> list[str]:
    """The output lines a block's ``# -> ...`` comments show, in source order."""
    shown = []
    for token in tokenize.generate_tokens(io.StringIO(code).readline):
        if token.type == tokenize.COMMENT:
            m = _SHOWN.match(token.string)
            if m:
                shown.append(m.group(1).strip())
    return shown


def shown_runs(code: str) -> list[tuple[str, ...]]:
    """The output lines a block's ``# -> ...`` comments show, in source order, in runs: a
    shown line and the comment-only ``# ->`` lines right below it, which show the lines
    printed right after it."""
    runs: list[list[str]] = []
    last = -2
    for token in tokenize.generate_tokens(io.StringIO(code).readline):
        if token.type != tokenize.COMMENT:
            continue
        m = _SHOWN.match(token.string)
        if not m:
            continue
        row = token.start[0]
        alone = token.line.lstrip().startswith("#")
        if runs and alone and row == last + 1:
            runs[-1].append(m.group(1).strip())
        else:
            runs.append([m.group(1).strip()])
        last = row
    return [tuple(run) for run in runs]


def _matches(shown: str, line: str) -> bool:
    pattern = ".*".join(re.escape(part) for part in shown.split("..."))
    return re.fullmatch(pattern, line.strip()) is not None


def missing_outputs(shown: Sequence[str | tuple[str, ...]], printed: str) -> list[str]:
    """The shown lines that ``printed`` lacks (in order: the first unmatched and every one
    after it). A tuple is a run (:func:`shown_runs`): lines printed one right after another."""
    lines = printed.splitlines()
    runs = [(want,) if isinstance(want, str) else want for want in shown]
    at = 0
    for k, run in enumerate(runs):
        # (the first line that matches a run's first begins it: the rest follow it directly)
        while at < len(lines) and not _matches(run[0], lines[at]):
            at += 1
        follows = lines[at : at + len(run)]
        if len(follows) < len(run) or not all(map(_matches, run, follows)):
            return [line for rest in runs[k:] for line in rest]
        at += len(run)
    return []
