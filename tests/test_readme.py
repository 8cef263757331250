"""The README's usage example runs as written, against the simulator."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from doc_outputs import missing_outputs, shown_outputs

README = Path(__file__).resolve().parent.parent / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


def test_readme_has_the_two_commands() -> None:
    text = README.read_text(encoding="utf-8")
    assert "make demo" in text
    assert "make test" in text


@pytest.mark.parametrize("index", range(len(_python_blocks())))
def test_readme_python_block_runs(index: int, capsys: pytest.CaptureFixture[str]) -> None:
    code = _python_blocks()[index]
    exec(compile(code, f"README.md block {index}", "exec"), {})
    out = capsys.readouterr().out
    shown = shown_outputs(code)  # print(...)  # -> what it prints
    assert shown, "the README's example shows what it prints"
    assert not missing_outputs(shown, out), out
