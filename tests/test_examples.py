"""Every example runs: the scripts as subprocesses, the notebook through a Jupyter kernel.

The scripts run against the in-process simulator by default (simulated time, so they are fast),
and one of them against the simulator served over TCP, given an address as hardware would be.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SCRIPTS = sorted(EXAMPLES.glob("[0-9][0-9]_*.py"))

# A line (or part of one) each script must print: the point of the example happened.
EXPECTED = {
    "01_connect.py": [
        "connected to DMC4040",
        "data record at sample",
        "refused as expected: TC 10",
    ],
    "02_jog.py": [
        "velocity -5.00 mm / s",
        "stop code 4",
        "jog into the forward soft limit: stop code 2",
    ],
    "03_move_with_units.py": [
        "plan A -> 12.5 mm: trapezoid",
        "peak 20.00 mm/s",
        "plot in mm saved",
        "end vs prediction: {'A': 0} counts",
        "refused: FL would be crossed",
        "wrong dimension",
        "back at A 0.00",
    ],
    "04_contour.py": [
        "1 - cos: 31 segments, 6000 counts",
        "B 5.000 mm",
        "refused: CD 40000",
        "too slow",
    ],
    "05_speed_schedule.py": [
        "earliest valid is",
        "trippoints at [10.0, 20.0] mm",
        "end vs prediction {'A': 0} counts",
    ],
    "06_lab_day_one.py": [
        "homed? False",
        "homed with stop code 10, position 0",
        "homed? True: HM started by this Controller ended with stop code 10",
        "gains KP 8.0 KI 0.25 KD 64.0, motor SERVO",
        "refused before sending: KP",
        "output 1 is True",
        "parameters saved",
    ],
    "07_capture.py": [
        "plan A -> 10 mm: trapezoid",
        "reference vs prediction: largest difference 0 counts",
        f"plot saved to {Path(tempfile.gettempdir()) / 'capture_A.png'}",
        "data records at samples",
    ],
    "08_draw_a_shape.py": [
        "plan: 151.416 mm of path in 3.886 s, top speed 40.0 mm/s",
        "drawn: stop codes {'A': 101, 'B': 101}, end vs prediction {'A': 0, 'B': 0}",
        "back at A 0.00 mm, B 0.00 mm",
        "refused: segment 1: axis B speed",
        "C follows A at 0.5: predicted 10.000 mm, at 10.000 mm",
    ],
}


def _run(args: list[str], cwd: Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONWARNINGS="error::RuntimeWarning")
    return subprocess.run(
        [sys.executable, *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_every_script_is_covered() -> None:
    assert [p.name for p in SCRIPTS] == sorted(EXPECTED)


@dataclass(frozen=True)
class Ran:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Ran]:
    """Every script, run at once (each in its own process and folder, as a user runs it):
    the suite waits for the slowest instead of for their sum."""
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONWARNINGS="error::RuntimeWarning")
    procs = {
        script.name: subprocess.Popen(
            [sys.executable, str(script)],
            cwd=tmp_path_factory.mktemp(script.stem),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for script in SCRIPTS
    }
    out = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=120)
        out[name] = Ran(proc.returncode, stdout, stderr)
    return out


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_script_runs_on_the_simulator(script: Path, ran: dict[str, Ran]) -> None:
    proc = ran[script.name]
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    for text in EXPECTED[script.name]:
        assert text in proc.stdout, f"{text!r} not in:\n{proc.stdout}"


def test_script_takes_an_address(tmp_path: Path) -> None:
    # The simulator behind a real TCP socket stands in for a controller on the network.
    from galil.sim.server import SimTcpServer

    # No message port, as on a controller: the client claims messages with CF on a handle.
    with SimTcpServer(model="DMC-4040", message_port=None) as server:
        proc = _run([str(EXAMPLES / "03_move_with_units.py"), server.url], tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for text in EXPECTED["03_move_with_units.py"]:
        assert text in proc.stdout, f"{text!r} not in:\n{proc.stdout}"
    assert (tmp_path / "plan_A.png").stat().st_size > 0


@pytest.mark.parametrize(
    "address",
    [
        "tcp://127.0.0.1:1",
        "tcp://127.0.0.1:99999",  # (before: an InvalidArgument traceback)
        "nonsense",
    ],
)
def test_script_reports_a_bad_address(tmp_path: Path, address: str) -> None:
    proc = _run([str(EXAMPLES / "01_connect.py"), address], tmp_path)
    assert proc.returncode == 1
    assert proc.stderr.startswith(f"could not connect to {address}: ")
    assert proc.stderr.count("\n") == 1
    assert "Traceback" not in proc.stderr


def test_the_capture_example_writes_its_plot_where_it_says_not_into_the_cwd(
    tmp_path: Path,
) -> None:
    plot = tmp_path / "plots" / "out.png"
    plot.parent.mkdir()
    here = tmp_path / "cwd"
    here.mkdir()
    proc = _run([str(EXAMPLES / "07_capture.py"), "sim://DMC-4040", str(plot)], here)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"plot saved to {plot}" in proc.stdout
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(here.iterdir()) == []  # (before: capture_A.png in the folder it ran in)


def test_notebook_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    monkeypatch.setenv("MPLBACKEND", "Agg")  # the kernel inherits it: no display needed
    copy = tmp_path / "lab.ipynb"
    shutil.copy(EXAMPLES / "lab.ipynb", copy)
    nb = nbformat.read(copy, as_version=4)
    # Committed without outputs, so a diff shows only what a person changed.
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not cell.outputs
            assert cell.execution_count is None
    client = nbclient.NotebookClient(
        nb, timeout=60, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError on the first failing cell
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "A move: largest |recorded - predicted| = 0 counts" in text
    assert "B contour: largest |recorded - predicted| = 0 counts" in text
    assert "refused:" in text
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 2  # the planned profile and the comparison
