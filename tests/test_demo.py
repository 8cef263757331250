"""The README's main job, ``galil demo``, end to end (TCP loopback, a PNG)."""

from __future__ import annotations

from pathlib import Path

from galil.demo import run_demo


def test_demo_matches_its_predictions_and_writes_a_plot(tmp_path: Path) -> None:
    png = tmp_path / "demo.png"
    assert run_demo(png=str(png), quiet=True) == 0
    assert png.stat().st_size > 10_000
