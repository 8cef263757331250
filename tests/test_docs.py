"""The user guide's code runs as written.

Every ```python block of a page runs, in order, in one namespace per page (a block may use what
an earlier block of the same page made). A block fenced ```python no-run is skipped: it needs
hardware or a process the page cannot start. What a block shows it prints (a ``# -> ...``
comment, see ``doc_outputs``) it must print. Relative links between pages must resolve.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from doc_outputs import missing_outputs, shown_outputs, shown_runs

import galil

DOCS = Path(__file__).resolve().parent.parent / "docs"
PAGES = sorted(p for p in DOCS.glob("*.md"))
GUIDE = [
    "index.md",
    "getting-started.md",
    "jog.md",
    "position.md",
    "contour.md",
    "speed-schedule.md",
    "homing.md",
    "io.md",
    "tuning.md",
    "vector.md",
    "units.md",
    "safety.md",
    "reliability.md",
    "predictor.md",
    "transports.md",
    "testing.md",
    "raw.md",
    "setup.md",
    "programs.md",
    "capture.md",
    "performance.md",
]

# Pages of the site that are not guide pages: an overview, and two generated ones.
NOT_GUIDE = ("index.md", "reference.md", "changelog.md")

_FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```\s*$", re.MULTILINE | re.DOTALL)
_LINK = re.compile(r"\]\(([^)#\s]+\.md)(?:#[^)]*)?\)")


def python_blocks(text: str) -> list[tuple[int, str, bool]]:
    """``(line, code, runnable)`` for each python block of a Markdown page."""
    out = []
    for m in _FENCE.finditer(text):
        info = m.group(1).strip().split()
        if not info or info[0] != "python":
            continue
        line = text.count("\n", 0, m.start()) + 2
        out.append((line, m.group(2), "no-run" not in info[1:]))
    return out


def test_the_guide_has_its_pages() -> None:
    assert sorted(p.name for p in PAGES if p.name in GUIDE) == sorted(GUIDE)


def test_block_extraction() -> None:
    page = "x\n```python\na = 1\n```\n```bash\nmake\n```\n```python no-run\nb = 2\n```\n"
    assert python_blocks(page) == [(3, "a = 1\n", True), (9, "b = 2\n", False)]


def test_shown_outputs_are_the_arrow_comments_matched_in_order() -> None:
    code = (
        'print("a -> b")  # prose -> not checked\n'
        "print(1, 2)  # -> 1 2\n"
        "# -> tcp://127.0.0.1:...\n"
        "x = '# -> in a string'\n"
    )
    shown = shown_outputs(code)
    assert shown == ["1 2", "tcp://127.0.0.1:..."]
    assert missing_outputs(shown, "a -> b\n1 2\nnoise\n  tcp://127.0.0.1:4012\n") == []
    assert missing_outputs(shown, "tcp://127.0.0.1:4012\n1 2\n") == ["tcp://127.0.0.1:..."]
    assert missing_outputs(["1 2"], "1 2 3\n") == ["1 2"]  # a whole line, not a prefix


def test_a_run_of_shown_lines_is_printed_with_none_left_out() -> None:
    code = 'print("\\n".join(sent))\n# -> MG _BGS\n# -> BG S\nprint(2)  # -> 2\nprint(3)  # -> 3\n'
    runs = shown_runs(code)
    assert runs == [("MG _BGS", "BG S"), ("2",), ("3",)]
    assert missing_outputs(runs, "MG _BGS\nBG S\nnoise\n2\n3\n") == []
    # a line printed twice where the page shows it once (a query sent twice) is caught
    assert missing_outputs(runs, "MG _BGS\nMG _BGS\nBG S\n2\n3\n") == ["MG _BGS", "BG S", "2", "3"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_resolve(page: Path) -> None:
    for target in _LINK.findall(page.read_text(encoding="utf-8")):
        if "://" in target:
            continue
        assert (page.parent / target).is_file(), f"{page.name} links to missing {target}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_page_code_runs(
    page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    if page.name == "bluesky.md":
        pytest.importorskip("ophyd_async")  # the optional extra galil[bluesky]
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.chdir(tmp_path)  # a block that saves a file saves it here
    blocks = python_blocks(page.read_text(encoding="utf-8"))
    if page.name not in NOT_GUIDE:
        assert any(run for _, _, run in blocks), f"{page.name} has no runnable python block"
    namespace: dict[str, Any] = {"__name__": f"docs_{page.stem.replace('-', '_')}"}
    try:
        for line, code, runnable in blocks:
            if not runnable:
                compile(code, f"{page.name}:{line}", "exec")  # it must still be valid Python
                continue
            capsys.readouterr()
            try:
                exec(compile(code, f"{page.name}:{line}", "exec"), namespace)
            except Exception as exc:
                pytest.fail(f"{page.name}, block at line {line}: {type(exc).__name__}: {exc}")
            printed = capsys.readouterr().out
            missing = missing_outputs(shown_runs(code), printed)
            if missing:
                pytest.fail(
                    f"{page.name}, block at line {line} shows {missing[0]!r} but printed:\n"
                    f"{printed}"
                )
    finally:
        # Pages connect to simulators (some behind a socket); close whatever they left open.
        from galil.sim.server import SimTcpServer

        for value in namespace.values():
            if isinstance(value, galil.Controller) and not value.closed:
                value.close()
            elif isinstance(value, SimTcpServer):
                value.stop()  # idempotent
            elif type(value).__name__ == "RunEngine":
                # A RunEngine runs its loop on a thread of its own for the whole session.
                value.loop.call_soon_threadsafe(value.loop.stop)
                value._th.join(5)
        capsys.readouterr()
