"""``pip install galil`` without the ``jupyter`` extra: the demo runs without its plot, the
plot calls and the jog widget raise an ImportError naming the extra, ``galil plan --png``
says so in one line, and ``wait(progress=True)`` warns once that it shows no bar. The
optional packages are hidden from the import system by the ``missing`` fixture."""

from __future__ import annotations

import builtins
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import galil
from galil import cli, motion
from galil.demo import run_demo
from galil.notebook import compare_plot, jog_widget
from galil.testing import simulated

_HIDDEN = ("matplotlib", "tqdm", "ipywidgets")


@pytest.fixture
def missing(monkeypatch: pytest.MonkeyPatch) -> None:
    """matplotlib, tqdm and ipywidgets are not installed (as after ``pip install galil``)."""
    real: Callable[..., Any] = builtins.__import__

    def fake(name: str, *args: Any, **kwargs: Any) -> Any:
        top = name.partition(".")[0]
        if top in _HIDDEN:
            raise ModuleNotFoundError(f"No module named {top!r}", name=top)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake)
    # (each test starts with nothing said: the warning comes once per process)
    monkeypatch.setattr(motion.WaitBar, "_said_missing", False, raising=False)


def test_the_demo_runs_without_matplotlib_and_says_there_is_no_plot(
    missing: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "demo.png"
    assert run_demo(png=str(png), quick=True) == 0
    said = capsys.readouterr().out
    assert "no plot: matplotlib is missing (pip install 'galil[jupyter]')" in said
    assert "demo finished" in said
    assert not png.exists()


def test_plan_png_without_matplotlib_is_one_line_naming_the_extra(
    missing: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "plan.png"
    assert cli.main(["plan", "10000", "--speed", "25000", "--png", str(png)]) == 2
    err = capsys.readouterr().err
    assert (
        err
        == "galil: --png needs matplotlib, which is not installed: pip install 'galil[jupyter]'\n"
    )


def test_plots_without_matplotlib_raise_an_import_error_naming_the_extra(missing: None) -> None:
    with simulated("DMC-4040") as dmc:
        plan = dmc.A.plan_to(1000)
        with pytest.raises(
            ImportError, match=r"^Profile\.plot\(\) needs matplotlib, .*galil\[jupyter\]"
        ):
            plan.plot()
        with pytest.raises(
            ModuleNotFoundError, match=r"^compare_plot\(\) needs matplotlib"
        ) as info:
            compare_plot({"A": plan}, {"A": (plan.t, plan.position)})
        assert info.value.name == "matplotlib"


def test_the_jog_widget_without_ipywidgets_names_the_extra(missing: None) -> None:
    with (
        simulated("DMC-4040") as dmc,
        pytest.raises(ImportError, match=r"^jog_widget\(\) needs ipywidgets, .*galil\[jupyter\]"),
    ):
        jog_widget(dmc.A)


def test_progress_without_tqdm_warns_once_and_the_wait_goes_on(missing: None) -> None:
    with simulated("DMC-4040") as dmc:
        with pytest.warns(RuntimeWarning, match=r"progress=True shows no bar: tqdm") as said:
            dmc.A.move_to(1000).wait(progress=True)
        assert said[0].filename == __file__
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            result = dmc.A.move_to(0).wait(progress=True)  # (said once)
        assert result.final == {"A": 0}
        assert isinstance(dmc, galil.Controller)
