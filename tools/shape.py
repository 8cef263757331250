"""Report functions over 60 lines and classes over 500 lines in galil/ (AST based)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

FUNC, CLASS = 60, 500


def offenders(root: Path) -> list[str]:
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > FUNC:
                    out.append(f"{path}:{node.lineno} def {node.name} {n}")
            elif isinstance(node, ast.ClassDef):
                n = node.end_lineno - node.lineno + 1
                if n > CLASS:
                    out.append(f"{path}:{node.lineno} class {node.name} {n}")
    return out


if __name__ == "__main__":
    found = offenders(Path(sys.argv[1] if len(sys.argv) > 1 else "galil"))
    print("\n".join(found) or "none")
