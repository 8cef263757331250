"""The package as users get it: the sdist and the wheel build cleanly, and the wheel installed
into a clean virtual environment runs ``galil demo --quick``.

About 10 s: the build runs without isolation (``build`` and ``hatchling`` are in the dev group)
and the new environment gets no pip of its own (this environment's pip installs into it).
Dependencies come from PyPI (or pip's cache).
"""

from __future__ import annotations

import email.parser
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

import galil

ROOT = Path(__file__).resolve().parent.parent


def _run(args: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=600, cwd=cwd)


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    run = _run([sys.executable, "-m", "build", "--no-isolation", "-o", str(out), str(ROOT)])
    assert run.returncode == 0, run.stdout + run.stderr
    assert "warning" not in (run.stdout + run.stderr).lower(), run.stdout + run.stderr
    return out


def test_the_wheel_carries_complete_metadata(dist: Path) -> None:
    (wheel,) = dist.glob("*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        meta_name = next(n for n in names if n.endswith(".dist-info/METADATA"))
        meta = email.parser.Parser().parsestr(zf.read(meta_name).decode())
    assert meta["Name"] == "galil"
    assert meta["Version"] == galil.__version__
    assert meta["Requires-Python"] == ">=3.10"
    assert meta["License-Expression"] == "MIT"
    assert meta["Summary"]
    assert sorted(meta.get_all("Provides-Extra") or []) == ["bluesky", "jupyter"]
    classifiers = meta.get_all("Classifier")
    assert "Typing :: Typed" in classifiers
    assert any(c.startswith("Development Status") for c in classifiers)
    assert "galil/py.typed" in names
    assert not any(n.startswith("tests/") for n in names)
    entry_points = _member_text(wheel, ".dist-info/entry_points.txt")
    assert "galil = galil.cli:main" in entry_points
    assert "sim = galil.sim.link:open_transport" in entry_points


def _member_text(wheel: Path, suffix: str) -> str:
    with zipfile.ZipFile(wheel) as zf:
        return zf.read(next(n for n in zf.namelist() if n.endswith(suffix))).decode()


def test_the_sdist_holds_the_sources_and_no_build_output(dist: Path) -> None:
    (sdist,) = dist.glob("*.tar.gz")
    with tarfile.open(sdist) as tf:
        names = [n.split("/", 1)[1] for n in tf.getnames() if "/" in n]
    assert "galil/__init__.py" in names
    assert "pyproject.toml" in names
    assert not any(n.startswith((".venv/", "site/", "dist/")) for n in names)


def test_the_wheel_runs_the_quick_demo_in_a_clean_environment(dist: Path, tmp_path: Path) -> None:
    (wheel,) = dist.glob("*.whl")
    env_dir = tmp_path / "env"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / ("Scripts" if sys.platform == "win32" else "bin") / "python"
    install = _run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", str(wheel)]
    )
    assert install.returncode == 0, install.stderr
    galil_cmd = python.parent / "galil"
    demo = _run([str(galil_cmd), "demo", "--quick"], cwd=tmp_path)
    assert demo.returncode == 0, demo.stdout + demo.stderr
    assert "recorded - predicted: move 0 counts, jog 0 counts, contour 0 counts" in demo.stdout
    version = _run([str(python), "-m", "galil", "--version"])
    assert version.stdout.strip() == f"galil {galil.__version__}"
