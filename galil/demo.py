"""``galil demo``: the whole job end to end on the built-in simulator, over TCP loopback.

It starts a simulated DMC behind a real TCP socket, connects as any program would, plans and runs
a move in millimetres, jogs with a speed change, streams the manual's 1 - cos contour, then
compares what the simulator's servo loop did with what the predictor says for the same commands,
sample by sample.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Iterable

import numpy as np
import numpy.typing as npt

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
    png: str | None = "galil-demo.png", model: str = "DMC-4040", quiet: bool = False
) -> int:
    """Run the demo; return 0 when the simulator matched the predictions exactly."""
    import galil
    from galil import predict
    from galil.contour import increments, sample_path
    from galil.sim.server import SimTcpServer
    from galil.units import ureg

    say: Callable[[str], None] = (lambda _s: None) if quiet else print
    began = time.monotonic()
    mm, s = ureg.mm, ureg.s
    with SimTcpServer(model=model) as server, galil.connect(server.url) as dmc:
        sim = server.controller
        ident = dmc.identity
        assert ident is not None
        ts = dmc.sample_period
        say(f"simulated {ident.raw_model} (firmware {ident.firmware}) at {server.url}")

        # 1. A position move in millimetres, planned before anything is sent.
        x = dmc.A.set_scale(counts_per=2000 / mm)
        x.speed = 20 * mm / s
        x.accel = 200 * mm / s**2
        x.decel = 200 * mm / s**2
        plan = x.plan_to(12.5 * mm)
        say(
            f"plan: A to 12.5 mm ({plan.distance} counts): {plan.shape}, "
            f"{plan.duration:.3f} s, peak {plan.peak_speed / 2000:.2f} mm/s"
        )
        t0 = sim.start_trace("A")
        move = x.move_to(12.5 * mm)
        result = move.wait(progress=not quiet)
        trace_move = sim.stop_trace("A")["A"]
        bg = _samples_of(sim.command_log, r"BG ?A", t0)[0][0]
        say(f"moved: A reference {result.final['A']} counts, encoder {x.position:~.4f}")

        # 2. A jog with a speed change in motion, then a stop.
        ac, dc = (float(v) for v in dmc.query_operands(["_ACA", "_DCA"]))
        start = int(dmc.query_number("MG _RPA"))
        t1 = sim.start_trace("A")
        x.jog(10 * mm / s)
        dmc.sleep(0.4)
        x.jog(-5 * mm / s)
        dmc.sleep(0.5)
        x.stop()
        while x.moving:
            dmc.sleep(0.02)
        trace_jog = sim.stop_trace("A")["A"]
        jg = _samples_of(sim.command_log, r"JGA=-?\d+", t1)
        jog_bg = _samples_of(sim.command_log, r"BGA", t1)[0][0]
        st = _samples_of(sim.command_log, r"ST A", t1)[0][0]
        speeds = [float(text.partition("=")[2]) for _, text in jg]
        jog_prediction = predict.jog(
            speeds[0],
            ac,
            dc,
            changes=[((jg[1][0] - jog_bg) * ts, speeds[1])],
            stop_at=(st - jog_bg) * ts,
            start=start,
            sample_period=ts,
        )
        say(f"jogged: +10 mm/s, then -5 mm/s in motion, stopped at {x.position:~.4f}")

        # 3. The manual's contour: 6000 counts in 120 ms along a 1 - cos velocity.
        a, b, dt = 6000.0, 0.120, 2
        path = sample_path(
            lambda t: a * t / b - a / (2 * math.pi) * np.sin(2 * math.pi * np.minimum(t, b) / b),
            duration=b,
            dt=dt,
            sample_period=ts,
        )
        incs = increments(path)
        start_b = int(dmc.query_number("MG _RPB"))
        t2 = sim.start_trace("B")
        contour = dmc.contour("B", path, dt=dt)
        trace_contour = sim.stop_trace("B")["B"]
        first_cd = _samples_of(sim.command_log, r"CD ,?-?\d+", t2)[0][0]
        contour_prediction = predict.contour(incs, dt, start=start_b, sample_period=ts)
        say(
            f"contour: {incs.size} segments of {(1 << dt) * ts * 1e3:.3f} ms on B, "
            f"{int(incs.sum())} counts in {contour.duration * 1e3:.1f} ms, "
            f"{contour.lines} lines, buffer never below {contour.low_water} free"
        )

        # 4. Recorded against predicted, sample by sample.
        diffs = {
            "move": compare(trace_move, t0, move.profile.position, bg),
            "jog": compare(trace_jog, t1, jog_prediction.position, jog_bg),
            "contour": compare(trace_contour, t2, contour_prediction.position, first_cd),
        }
        worst = max(diffs.values())
        say(
            "largest difference, recorded - predicted: "
            + ", ".join(f"{k} {v} counts" for k, v in diffs.items())
        )
        if png:
            from galil.notebook import compare_plot

            fig = compare_plot(
                {"A move": move.profile, "A jog": jog_prediction, "B contour": contour_prediction},
                {
                    "A move": _window(trace_move, t0, bg, move.profile.position.size, ts),
                    "A jog": _window(trace_jog, t1, jog_bg, jog_prediction.position.size, ts),
                    "B contour": _window(
                        trace_contour, t2, first_cd, contour_prediction.position.size, ts
                    ),
                },
                title=f"galil demo, simulated {dmc.model.name}: predicted vs recorded",
            )
            fig.savefig(png, dpi=90)
            say(f"plot saved to {png}")
        say(f"demo finished in {time.monotonic() - began:.1f} s")
    return 0 if worst == 0 else 1


def _window(
    trace: IntArray, trace_start: int, begin: int, n: int, ts: float
) -> tuple[npt.NDArray[np.float64], IntArray]:
    offset = begin - trace_start
    rec = trace[offset : offset + n]
    t: npt.NDArray[np.float64] = np.arange(rec.size, dtype=np.float64) * ts
    return t, rec
