"""``galil demo``: the whole job end to end on the built-in simulator, over TCP loopback.

It starts a simulated DMC behind a real TCP socket, connects as any program would, plans and runs
a move in millimetres, jogs with a speed change, streams the manual's 1 - cos contour, and
compares what the controller did with what the predictor said, sample by sample. What the
controller did is read the way it is read from hardware, through the public API only: a
capture on the controller (``controller.capture``: ``RA``/``RD``/``RC``, uploaded with ``QU``)
and a data-record stream (``controller.records``), both lined up with each prediction by the
controller sample it began on. Given a controller's address instead of the simulator, the same
code records the same things.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from galil.capture import Recording
from galil.contour import ContourResult, sample_path
from galil.controller import Controller, connect
from galil.errors import InvalidArgument
from galil.models import ModelSpec, get_model
from galil.motion import MoveHandle
from galil.notebook import compare, compare_plot
from galil.predict.profile import check_figure_path
from galil.records import RecordStream
from galil.sim.server import SimTcpServer
from galil.units import ureg

__all__ = ["record_motion", "run_demo"]

#: Samples between recorded values (the smallest ``RC`` allows; records as often), where the
#: model allows it (:func:`every_for`).
EVERY = 2


def every_for(model: ModelSpec) -> int:
    """Samples between recorded values on ``model``: the fewest both ``RC`` (a power of two)
    and ``DR`` (the model's shortest period: 8 on a DMC-21x3 or 41x3, 4 on a DMC-30010)
    allow, and no fewer than :data:`EVERY`."""
    every = max(EVERY, 1 << model.record_exponents[0])
    while every < model.dr_range[0]:
        every *= 2
    return every


def check_model(name: str) -> ModelSpec:
    """The model the demo runs on: one with axes, a binary data record and ``RC``.

    Raises:
        InvalidArgument: an unknown model, or one the demo cannot run on (said in one line).
    """
    model = get_model(name)
    if not model.axes:
        raise InvalidArgument(
            f"{model.name} is an I/O controller with no axes: the demo moves axes; pick a "
            "motion controller (e.g. --model DMC-4040)"
        )
    if model.record_size is None:
        raise InvalidArgument(
            f"{model.name} has no binary data record, which the demo compares the motion with; "
            "pick another model (e.g. --model DMC-4040)"
        )
    return model


@dataclass(frozen=True)
class Recorded:
    """One motion and what the controller recorded of it, two ways."""

    name: str
    letter: str
    handle: MoveHandle | ContourResult
    capture: Recording
    records: npt.NDArray[np.void] | None  # None: the model pushes no records (no DR)

    def worst(self) -> dict[str, int]:
        """Largest |recorded - predicted| in counts, per way of recording."""
        worst = {"capture": round(compare(self.handle, self.capture)[self.letter].worst)}
        if self.records is not None:
            worst["data records"] = round(compare(self.handle, self.records)[self.letter].worst)
        return worst


def _records_until(stream: RecordStream, sample: int) -> npt.NDArray[np.void]:
    """Every record of ``stream`` up to (and including) the first at or after ``sample``."""
    out = []
    while True:
        rec = stream.get(timeout=5.0)
        out.append(rec)
        if int(rec["time"]) >= sample:
            return np.array(out, dtype=rec.dtype)


def record_motion(
    dmc: Controller,
    name: str,
    letter: str,
    start: Callable[[], MoveHandle | ContourResult],
    seconds: float,
    every: int = EVERY,
) -> Recorded:
    """Run ``start()`` while the controller records axis ``letter``'s reference, every
    ``every`` samples (:func:`every_for`), both in arrays (a capture) and in data records
    pushed by ``DR``. A model with no Ethernet has no ``DR``: its records would be polled
    (``QR``) only as the host asks, after the motion, so it is recorded by the capture alone.

    Args:
        dmc: the controller.
        name: what the motion is called.
        letter: the axis recorded.
        start: starts the motion and returns its handle (or a finished contour's result);
            a handle is waited for here.
        seconds: how long to record at most (the capture stops once the motion is done).
        every: samples between recorded values.
    """
    with contextlib.ExitStack() as pushed:
        stream = pushed.enter_context(dmc.records(every)) if dmc.model.has_ethernet else None
        with dmc.capture([f"_RP{letter}"], every=every, seconds=seconds) as cap:
            handle = start()
            if isinstance(handle, MoveHandle):
                handle.wait()
                begin, samples = handle.begin[letter], handle.profile.samples
            else:
                begin, samples = handle.begin, handle.profiles[letter].samples
            dmc.sleep(0.02)  # a few records past the end: the axis holds still
        assert begin is not None
        assert cap.result is not None
        records = None if stream is None else _records_until(stream, begin + samples + every)
    return Recorded(name, letter, handle, cap.result, records)


def run_demo(
    png: str | None = "galil-demo.png",
    model: str = "DMC-4040",
    quiet: bool = False,
    quick: bool = False,
) -> int:
    """Run the demo; return 0 when the controller did exactly what was predicted.

    It adapts to the model: the move and the jog run on its first axis, the contour on its
    second (the first on a one-axis model), every value recorded as often as the model's
    ``RC`` and ``DR`` allow (:func:`every_for`); a model whose contour buffer holds one
    segment skips the contour (streamed over TCP, it would run dry), and says so.

    Args:
        png: where to save the plot (``None``: no plot); its extension must be a format
            matplotlib writes (checked before anything runs; without matplotlib the demo
            runs and says that there is no plot).
        model: the simulated model.
        quiet: print nothing.
        quick: a short move and jog (a smoke test of an installation, about a second).

    Raises:
        InvalidArgument: a model the demo cannot run on (a RIO, one with no binary data
            record), or a plot file of an unknown format; nothing has run.
    """
    spec = check_model(model)
    if png:
        # (no matplotlib: the demo runs, and says at plot time that there is no plot)
        with contextlib.suppress(ImportError):
            check_figure_path(png, "png")
    say: Callable[[str], None] = (lambda _s: None) if quiet else print
    began = time.monotonic()
    with SimTcpServer(model=spec.name) as server, connect(server.url) as dmc:
        ident = dmc.identity
        assert ident is not None
        say(f"simulated {ident.raw_model} (firmware {ident.firmware}) at {server.url}")
        runs = _runs(dmc, say, quick)
        # Recorded against predicted, sample by sample, both ways.
        worst = {r.name: r.worst() for r in runs}
        for name, ways in worst.items():
            say(
                f"{name}: largest |recorded - predicted| "
                + ", ".join(f"{v} counts ({k})" for k, v in ways.items())
            )
        say(
            "largest difference, recorded - predicted: "
            + ", ".join(f"{k} {max(v.values())} counts" for k, v in worst.items())
        )
        if png:
            try:
                _plot(runs, png, f"galil demo, simulated {dmc.model.name}")
                say(f"plot saved to {png}")
            except ImportError:
                say("no plot: matplotlib is missing (pip install 'galil[jupyter]')")
        say(f"demo finished in {time.monotonic() - began:.1f} s")
    return 0 if all(v == 0 for ways in worst.values() for v in ways.values()) else 1


def _runs(dmc: Controller, say: Callable[[str], None], quick: bool) -> list[Recorded]:
    """The move and the jog on the model's first axis, the contour on its second (or first)."""
    every = every_for(dmc.model)
    axes = dmc.model.axes
    if not dmc.model.has_ethernet:
        say(
            f"data records: none: the {dmc.model.name} has no Ethernet, so no DR to push them "
            "while the axes move; each motion is compared with the capture alone"
        )
    runs = [
        _demo_move(dmc, say, 2.5 if quick else 12.5, axes[0], every),
        _demo_jog(dmc, say, 0.1 if quick else 0.4, axes[0], every),
    ]
    if dmc.model.contour_buffer > 1:
        runs.append(_demo_contour(dmc, say, axes[1 if len(axes) > 1 else 0], every))
    else:
        say(
            f"contour: skipped: the {dmc.model.name}'s contour buffer holds one segment, which "
            "a stream over TCP cannot keep fed"
        )
    return runs


def _demo_move(
    dmc: Controller, say: Callable[[str], None], target: float, letter: str, every: int
) -> Recorded:
    """A position move in millimetres, planned before anything is sent."""
    mm, s = ureg.mm, ureg.s
    x = dmc.axes[letter].set_scale(counts_per=2000 / mm)
    x.speed = 20 * mm / s
    x.accel = 200 * mm / s**2
    x.decel = 200 * mm / s**2
    plan = x.plan_to(target * mm)
    say(
        f"plan: {letter} to {target:g} mm ({plan.distance} counts): {plan.shape}, "
        f"{plan.duration:.3f} s, peak {plan.peak_speed / 2000:.2f} mm/s"
    )

    def start() -> MoveHandle:
        move = x.move_to(target * mm)
        # A bar on a terminal only: piped into a log, the lines above tell the story.
        move.wait(progress=sys.stderr.isatty())
        return move

    run = record_motion(dmc, "move", letter, start, plan.duration + 0.5, every)
    say(
        f"moved: {letter} at {x.position:~.4f}, recorded {len(run.capture)} values on the "
        "controller"
    )
    return run


def _demo_jog(
    dmc: Controller, say: Callable[[str], None], hold: float, letter: str, every: int
) -> Recorded:
    """A jog with a speed change in motion, then a stop: the handle follows both."""
    mm, s = ureg.mm, ureg.s
    x = dmc.axes[letter]

    def start() -> MoveHandle:
        jog = x.jog(10 * mm / s)
        dmc.sleep(hold)
        x.jog(-5 * mm / s)
        dmc.sleep(hold + 0.1)
        x.stop()
        jog.wait()
        return jog

    run = record_motion(dmc, "jog", letter, start, 2 * hold + 1.0, every)
    say(f"jogged: +10 mm/s, then -5 mm/s in motion, stopped at {x.position:~.4f}")
    return run


def _demo_contour(dmc: Controller, say: Callable[[str], None], letter: str, every: int) -> Recorded:
    """The manual's contour: 6000 counts (3 mm) in 120 ms along a 1 - cos velocity."""
    ts = dmc.sample_period
    dmc.axes[letter].set_scale(counts_per=2000 / ureg.mm)  # (the path is in counts; plot: mm)
    a, b, dt = 6000.0, 0.120, 2
    path = sample_path(
        lambda t: a * t / b - a / (2 * math.pi) * np.sin(2 * math.pi * np.minimum(t, b) / b),
        duration=b,
        dt=dt,
        sample_period=ts,
    )
    run = record_motion(
        dmc, "contour", letter, lambda: dmc.contour(letter, path, dt=dt), b + 0.5, every
    )
    contour = run.handle
    assert isinstance(contour, ContourResult)
    incs = contour.increments
    say(
        f"contour: {incs.size} segments of {(1 << dt) * ts * 1e3:.3f} ms on {letter}, "
        f"{int(incs.sum())} counts in {contour.duration * 1e3:.1f} ms, "
        f"{contour.lines} lines, buffer never below {contour.low_water} free"
    )
    return run


def _plot(runs: list[Recorded], png: str, title: str) -> None:
    predicted = {}
    recorded = {}
    for r in runs:
        label = f"{r.letter} {r.name}"
        predicted[label] = r.handle.profiles[r.letter]
        pair = compare(r.handle, r.capture)[r.letter]
        recorded[label] = (pair.t, pair.recorded)
    fig = compare_plot(predicted, recorded, title=f"{title}: predicted vs recorded")
    fig.savefig(png, dpi=90)
