"""The documentation site: every public name has a docstring, and the site builds strictly.

The site build (``mkdocs build --strict``, the same as ``make docs``) fails on a broken link,
a missing page in the navigation or a cross-reference mkdocstrings cannot resolve; it takes a
few seconds and needs the ``docs`` dependency group (``make test`` installs it).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

import galil

ROOT = Path(__file__).resolve().parent.parent

# The modules users reach into, beyond the flat names of galil/__init__.py.
MAIN_MODULES = [
    "galil",
    "galil.controller",
    "galil.axis",
    "galil.motion",
    "galil.contour",
    "galil.segments",
    "galil.vector",
    "galil.gearing",
    "galil.link",
    "galil.messages",
    "galil.records",
    "galil.units",
    "galil.errors",
    "galil.models",
    "galil.codes",
    "galil.discovery",
    "galil.terminal",
    "galil.testing",
    "galil.notebook",
    "galil.predict",
    "galil.transport",
    "galil.sim.server",
]


def _undocumented(module: ModuleType) -> list[str]:
    missing = [] if inspect.getdoc(module) else [f"{module.__name__} (module)"]
    for name in getattr(module, "__all__", []):
        if name.startswith("__"):
            continue
        obj = getattr(module, name)
        where = f"{module.__name__}.{name}"
        callable_ = inspect.isfunction(obj) or inspect.isclass(obj)
        if callable_ and not (obj.__doc__ or "").strip():
            missing.append(where)
        if inspect.isclass(obj):
            for attr, value in vars(obj).items():
                if attr.startswith("_"):
                    continue
                func = value.fget if isinstance(value, property) else value
                func = getattr(func, "__func__", func)  # staticmethod, classmethod
                if inspect.isfunction(func) and not (func.__doc__ or "").strip():
                    missing.append(f"{where}.{attr}")
    return missing


def test_every_public_name_has_a_docstring() -> None:
    missing: list[str] = []
    for name in MAIN_MODULES:
        missing += _undocumented(importlib.import_module(name))
    assert not missing, f"public names without a docstring: {sorted(set(missing))}"


def test_the_docstring_check_names_what_lacks_one() -> None:
    module = ModuleType("fake", "A module.")

    class Thing:
        """Documented."""

        def method(self) -> None:
            pass

        @property
        def value(self) -> int:
            return 1

    def helper() -> None:
        pass

    module.Thing, module.helper = Thing, helper  # type: ignore[attr-defined]
    module.__all__ = ["Thing", "helper"]  # type: ignore[attr-defined]
    assert _undocumented(module) == ["fake.Thing.method", "fake.Thing.value", "fake.helper"]


def test_the_flat_names_are_what_galil_exports() -> None:
    assert {"connect", "find", "Found", "Controller"} <= set(galil.__all__)


@pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None, reason="the docs dependency group is not installed"
)
def test_the_site_builds_with_no_warning(tmp_path: Path) -> None:
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert run.returncode == 0, run.stderr
    assert "WARNING" not in run.stderr, run.stderr
    reference = (tmp_path / "site" / "reference" / "index.html").read_text(encoding="utf-8")
    for name in ("connect", "Controller", "find", "MoveHandle", "CommandError"):
        assert name in reference
