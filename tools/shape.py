"""Functions over 60 lines and classes over 500 lines in galil/ (AST based).

A function's length counts its code, not its docstring: the rule is about logic that wants
cutting, and a long ``Args:`` section is documentation, not logic.

Run: ``python tools/shape.py [package_dir]``; ``tests/test_code_shape.py`` runs it too.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

FUNC, CLASS = 60, 500


def _docstring_lines(node: ast.AST) -> int:
    body = getattr(node, "body", [])
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        first = body[0]
        if isinstance(first.value.value, str) and first.end_lineno is not None:
            return first.end_lineno - first.lineno + 1
    return 0


def offenders(root: Path) -> list[str]:
    """``path:line kind name length`` for every function or class over its limit."""
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                assert node.end_lineno is not None
                n = node.end_lineno - node.lineno + 1 - _docstring_lines(node)
                if n > FUNC:
                    out.append(f"{path}:{node.lineno} def {node.name} {n}")
            elif isinstance(node, ast.ClassDef):
                assert node.end_lineno is not None
                n = node.end_lineno - node.lineno + 1
                if n > CLASS:
                    out.append(f"{path}:{node.lineno} class {node.name} {n}")
    return out


if __name__ == "__main__":
    found = offenders(Path(sys.argv[1] if len(sys.argv) > 1 else "galil"))
    print("\n".join(found) or "none")
