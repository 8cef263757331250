"""Outputs shown in the documentation's code are checked, not just shown.

A comment whose text starts with ``->`` shows one line that the code prints::

    print(plan.shape, f"{plan.duration:.3f} s")  # -> trapezoid 0.726 s
    print(dmc.command("UL"))  # -> #HELLO
    # -> MG "hello"

The rest of the comment is the whole line (surrounding blanks aside); ``...`` stands for
anything (a port number, a time that varies). The lines a block prints must contain the shown
ones in the order they are shown; other printed lines may come between them. A comment that
does not start with ``->`` is prose and is not checked.
"""

from __future__ import annotations

import io
import re
import tokenize

__all__ = ["missing_outputs", "shown_outputs"]

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


def _matches(shown: str, line: str) -> bool:
    pattern = ".*".join(re.escape(part) for part in shown.split("..."))
    return re.fullmatch(pattern, line.strip()) is not None


def missing_outputs(shown: list[str], printed: str) -> list[str]:
    """The shown lines that ``printed`` lacks (in order: the first unmatched and every one
    after it)."""
    lines = printed.splitlines()
    at = 0
    for k, want in enumerate(shown):
        while at < len(lines) and not _matches(want, lines[at]):
            at += 1
        if at == len(lines):
            return shown[k:]
        at += 1
    return []
