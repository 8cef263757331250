"""``galil demo``: the whole job end to end on the built-in simulator, over TCP loopback.

It starts a simulated DMC behind a real TCP socket, connects as any program would, plans and runs
a move in millimetres, jogs with a speed change, streams the manual's 1 - cos contour, then
compares what the simulator's servo loop did with what the predictor says for the same commands,
sample by sample.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.contour import sample_path
from galil.controller import Controller, connect
from galil.notebook import compare_plot
from galil.predict import Profile
from galil.sim.controller import SimController
from galil.sim.server import SimTcpServer
from galil.units import ureg

__all__ = ["compare", "run_demo"]

IntArray = npt.NDArray[np.int64]


def compare(trace: IntArray, trace_start: int, predicted: IntArray, begin: int) -> int:
    """Largest |recorded - predicted| in counts over the predicted samples.

    Args:
        trace: recorded reference positions, one per sample from sample ``trace_start``.
        trace_start: sample number of ``trace[0]``.
        predicted: predicted positions, ``predicted[0]`` at sample ``begin`` (the command's
            sample: motion starts at the next one).
        begin: sample number at which the command that started the motion ran.
    """
    offset = begin - trace_start
    if offset < 0:
        raise ValueError("the trace starts after the motion began")
    recorded = trace[offset : offset + predicted.size]
    if recorded.size < predicted.size:  # the recording stopped at rest: pad with its last value
        recorded = np.concatenate((recorded, np.full(predicted.size - recorded.size, trace[-1])))
    return int(np.max(np.abs(recorded - predicted)))


def _samples_of(log: Iterable[tuple[int, str]], pattern: str, since: int) -> list[tuple[int, str]]:
    rx = re.compile(pattern)
    return [(k, text) for k, text in log if k >= since and rx.fullmatch(text.strip())]


def run_demo(
    png: str | None = "galil-demo.png",
    model: str = "DMC-4040",
    quiet: bool = False,
    quick: bool = False,
) -> int:
    """Run the demo; return 0 when the simulator matched the predictions exactly.

    Args:
        png: where to save the plot (``None``: no plot).
        model: the simulated model.
        quiet: print nothing.
        quick: a short move and jog (a smoke test of an installation, about a second).
    """

    say: Callable[[str], None] = (lambda _s: None) if quiet else print
    began = time.monotonic()
    with SimTcpServer(model=model) as server, connect(server.url) as dmc:
        ident = dmc.identity
        assert ident is not None
        say(f"simulated {ident.raw_model} (firmware {ident.firmware}) at {server.url}")
        target = 2.5 if quick else 12.5
        runs = [
            _demo_move(dmc, server.controller, say, target),
            _demo_jog(dmc, server.controller, say, 0.1 if quick else 0.4),
            _demo_contour(dmc, server.controller, say),
        ]
        # Recorded against predicted, sample by sample.
        diffs = {
            r.name: compare(r.trace, r.trace_start, r.predicted.position, r.begin) for r in runs
        }
        say(
            "largest difference, recorded - predicted: "
            + ", ".join(f"{k} {v} counts" for k, v in diffs.items())
        )
        if png:
            try:
                _plot(runs, dmc.sample_period, png, f"galil demo, simulated {dmc.model.name}")
                say(f"plot saved to {png}")
            except ImportError:
                say("no plot: matplotlib is missing (pip install 'galil[jupyter]')")
        say(f"demo finished in {time.monotonic() - began:.1f} s")
    return 0 if max(diffs.values()) == 0 else 1


@dataclass(frozen=True)
class _Run:
    name: str
    predicted: Profile
    trace: IntArray
    trace_start: int
    begin: int


def _demo_move(
    dmc: Controller, sim: SimController, say: Callable[[str], None], target: float
) -> _Run:
    """A position move in millimetres, planned before anything is sent."""
    mm, s = ureg.mm, ureg.s
    x = dmc.A.set_scale(counts_per=2000 / mm)
    x.speed = 20 * mm / s
    x.accel = 200 * mm / s**2
    x.decel = 200 * mm / s**2
    plan = x.plan_to(target * mm)
    say(
        f"plan: A to {target:g} mm ({plan.distance} counts): {plan.shape}, "
        f"{plan.duration:.3f} s, peak {plan.peak_speed / 2000:.2f} mm/s"
    )
    t0 = sim.start_trace("A")
    move = x.move_to(target * mm)
    # A bar on a terminal only: piped into a log, the lines above tell the story.
    result = move.wait(progress=sys.stderr.isatty())
    trace = sim.stop_trace("A")["A"]
    say(f"moved: A reference {result.final['A']} counts, encoder {x.position:~.4f}")
    begin = move.begin["A"]
    assert begin is not None
    return _Run("move", move.profile, trace, t0, begin)


def _demo_jog(dmc: Controller, sim: SimController, say: Callable[[str], None], hold: float) -> _Run:
    """A jog with a speed change in motion, then a stop: the handle follows both."""
    mm, s = ureg.mm, ureg.s
    x = dmc.A
    t1 = sim.start_trace("A")
    jog = x.jog(10 * mm / s)
    dmc.sleep(hold)
    x.jog(-5 * mm / s)
    dmc.sleep(hold + 0.1)
    x.stop()
    jog.wait()
    trace = sim.stop_trace("A")["A"]
    say(f"jogged: +10 mm/s, then -5 mm/s in motion, stopped at {x.position:~.4f}")
    begin = jog.begin["A"]
    assert begin is not None
    return _Run("jog", jog.profile, trace, t1, begin)


def _demo_contour(dmc: Controller, sim: SimController, say: Callable[[str], None]) -> _Run:
    """The manual's contour: 6000 counts (3 mm) in 120 ms along a 1 - cos velocity."""
    ts = dmc.sample_period
    dmc.B.set_scale(counts_per=2000 / ureg.mm)  # the path stays in counts; the plot shows mm
    a, b, dt = 6000.0, 0.120, 2
    path = sample_path(
        lambda t: a * t / b - a / (2 * math.pi) * np.sin(2 * math.pi * np.minimum(t, b) / b),
        duration=b,
        dt=dt,
        sample_period=ts,
    )
    t2 = sim.start_trace("B")
    contour = dmc.contour("B", path, dt=dt)
    trace = sim.stop_trace("B")["B"]
    first_cd = _samples_of(sim.command_log, r"CD ,?-?\d+", t2)[0][0]
    incs = contour.increments
    say(
        f"contour: {incs.size} segments of {(1 << dt) * ts * 1e3:.3f} ms on B, "
        f"{int(incs.sum())} counts in {contour.duration * 1e3:.1f} ms, "
        f"{contour.lines} lines, buffer never below {contour.low_water} free"
    )
    return _Run("contour", contour.profiles["B"], trace, t2, first_cd)


def _plot(runs: list[_Run], ts: float, png: str, title: str) -> None:
    labels = {"move": "A move", "jog": "A jog", "contour": "B contour"}
    fig = compare_plot(
        {labels[r.name]: r.predicted for r in runs},
        {
            labels[r.name]: _window(r.trace, r.trace_start, r.begin, r.predicted.position.size, ts)
            for r in runs
        },
        title=f"{title}: predicted vs recorded",
    )
    fig.savefig(png, dpi=90)


def _window(
    trace: IntArray, trace_start: int, begin: int, n: int, ts: float
) -> tuple[npt.NDArray[np.float64], IntArray]:
    offset = begin - trace_start
    rec = trace[offset : offset + n]
    t: npt.NDArray[np.float64] = np.arange(rec.size, dtype=np.float64) * ts
    return t, rec
