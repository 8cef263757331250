"""The README's main job, ``galil demo``, end to end (TCP loopback, a PNG), on every model
``--model`` accepts: each runs (adapted to its axes, its shortest record period and its
contour buffer) or is refused up front in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from galil import cli
from galil.demo import run_demo
from galil.models import MODELS


def test_demo_matches_its_predictions_and_writes_a_plot(tmp_path: Path) -> None:
    png = tmp_path / "demo.png"
    assert run_demo(png=str(png), quiet=True) == 0
    assert png.stat().st_size > 10_000


_REFUSED = {
    "DMC-1500": "galil: DMC-1500 has no binary data record, which the demo compares the motion "
    "with; pick another model (e.g. --model DMC-4040)\n",
    **{
        rio: f"galil: {rio} is an I/O controller with no axes: the demo moves axes; pick a "
        "motion controller (e.g. --model DMC-4040)\n"
        for rio in ("RIO-47100", "RIO-47120", "RIO-47300")
    },
}


@pytest.mark.parametrize("model", sorted({spec.name for spec in MODELS.values()}))
def test_the_quick_demo_runs_on_every_model_or_refuses_it_in_one_line(
    model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: tracebacks on one-axis models (axis B hard-coded) and RIOs, "DR period: 2 is
    # outside 8 .. 30000" on a DMC-2183, 4143 and 30010, a contour run dry on a DMC-1700.
    # (About 0.8 s each, in real time on the simulator's TCP server; little CPU.)
    status = cli.main(["demo", "--model", model, "--quick", "--quiet"])
    out, err = capsys.readouterr()
    assert out == ""
    if model in _REFUSED:
        assert (status, err) == (2, _REFUSED[model])
    else:
        assert (status, err) == (0, "")
