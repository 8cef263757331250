"""Benchmark the profile predictor against ruckig, and contour prediction against bare numpy.

Prints: samples per second for a 10 s, 4-axis move at 1024 Hz; planning latency per move
without sampling; ruckig's ``Trajectory.at_time`` sampling the same motion in a loop; ratios and
targets (>= 20 M samples/s, >= 5x ruckig, <= 50 us planning). Then ``predict.contour`` on a
1 M-segment DT 1 path (>= 50 M samples/s, within 2x of the floor-interpolation formula written
directly in numpy, measured in the same run; peak memory no more than the output arrays), and
how its cost grows from 1 k to 1 M segments; and how a move's prediction grows from 1 s to 1 h.

Run: ``.venv/bin/python benchmarks/predict.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import importlib
import tracemalloc

import numpy as np
import numpy.typing as npt
from harness import Figure, Scaling, best, finish, interleaved, options

from galil import predict

TS = 1 / 1024
SPEED = 100_000.0
ACCEL = 1_024_000.0
# Each axis lasts about 10 s: distance = SPEED * (10 s - SPEED/ACCEL).
AXES = {
    "A": (SPEED * (10 - SPEED / ACCEL), SPEED, ACCEL, ACCEL),
    "B": (-SPEED * (10 - SPEED / ACCEL), SPEED, ACCEL, ACCEL),
    "C": (0.5 * SPEED * (10 - 0.5 * SPEED / ACCEL), 0.5 * SPEED, ACCEL, ACCEL),
    "D": (0.25 * SPEED * (10 - 0.25 * SPEED / ACCEL), 0.25 * SPEED, ACCEL, ACCEL),
}


def predict_all() -> predict.MultiProfile:
    return predict.together(
        {
            k: predict.move(int(d), sp, ac, dc, sample_period=TS)
            for k, (d, sp, ac, dc) in AXES.items()
        }
    )


def bare_contour(c: npt.NDArray[np.int64], n: int, start: int = 0) -> npt.NDArray[np.int64]:
    """The anchor: ``r0 + floor(c*j / 2**n)`` written directly in numpy, into the output."""
    length = 1 << n
    out = np.empty(c.size * length + 1, np.int64)
    out[0] = start
    rows = out[1:].reshape(c.size, length)
    np.multiply(c[:, None], np.arange(1, length + 1), out=rows)
    np.right_shift(rows, n, out=rows)
    base = np.cumsum(c) - c + start
    rows += base[:, None]
    return out


def contour_bench() -> Figure:
    """predict.contour on DT 1 paths against the bare kernel, with its scaling."""
    rng = np.random.default_rng(15)
    c = rng.integers(-3000, 3001, 1_000_000)
    samples = 2 * c.size
    assert np.array_equal(predict.contour(c, 1).position, bare_contour(c, 1))
    t_bare = best(lambda: bare_contour(c, 1), repeat=7)
    t_pred = best(lambda: predict.contour(c, 1), repeat=7)
    kernel = importlib.import_module("galil.predict.contour").interpolate
    t_kern = best(lambda: kernel(c, 1, 0, np.empty(samples, np.int64)), repeat=7)
    tracemalloc.start()
    p = predict.contour(c, 1)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    outputs = p.t.nbytes + p.position.nbytes + p.velocity.nbytes
    rate = samples / t_pred
    ratio = t_pred / t_bare
    print(f"contour: 1 M segments at DT 1 = {samples} samples")
    print(f"  predict   {rate / 1e6:8.2f} M samples/s   ({t_pred * 1e3:.3f} ms)  target >= 50")
    print(f"  bare      {samples / t_bare / 1e6:8.2f} M samples/s   ({t_bare * 1e3:.3f} ms)")
    print(f"  ratio predict/bare time: {ratio:5.2f}x   target <= 2")
    print(
        f"  of which positions {t_kern * 1e3:.3f} ms; the rest is the Profile's time and"
        " velocity arrays"
    )
    print(f"  peak memory / output arrays: {peak / outputs:5.2f}x   target <= 1.05")
    sizes = (1_000, 100_000, 1_000_000)
    times = [best(lambda m=m: predict.contour(c[:m], 1), repeat=7) for m in sizes]
    steps = [
        f"{b // a}x segments -> {tb / ta:.1f}x time"
        for a, b, ta, tb in zip(sizes, sizes[1:], times, times[1:], strict=False)
    ]
    cells = ", ".join(f"{m // 1000}k {t * 1e3:.3f} ms" for m, t in zip(sizes, times, strict=True))
    print(f"  scaling: {cells} ({'; '.join(steps)})")
    return Figure(
        "predict.contour (1M segments, DT 1)",
        rate / 1e6,
        "M samples/s",
        50,
        anchor="bare numpy kernel",
        anchor_value=samples / t_bare / 1e6,
        ratio=ratio,
        ratio_text="x the kernel's time",
        ratio_target=2,
        scaling=[Scaling("segments", [(float(m), t) for m, t in zip(sizes, times, strict=True)])],
        note=f"peak memory {peak / outputs:.2f}x the output arrays (target <= 1.05)"
        + ("" if peak <= 1.05 * outputs else ": MISSED"),
    )


def move_scaling() -> Scaling:
    """predict.move of one axis for moves lasting 1 s to 1 h (the whole profile sampled)."""
    points = []
    for seconds in (1.0, 10.0, 100.0, 1000.0, 3600.0):
        distance = int(SPEED * (seconds - SPEED / ACCEL))
        # .position: a move's profile is sampled when first read (Profile.planned)
        t = best(lambda d=distance: predict.move(d, SPEED, ACCEL, ACCEL).position, repeat=3)
        points.append((seconds, t))
    return Scaling("s of motion", points)


def main() -> None:
    args = options(__doc__)
    multi = predict_all()
    samples = sum(round(p.duration / TS) + 1 for p in multi.profiles.values())
    t_pred = best(predict_all, repeat=15)
    rate = samples / t_pred
    d, sp, ac, dc = AXES["A"]
    t_plan = best(lambda: predict.plan_move(int(d), sp, ac, dc), repeat=7, number=2000)

    print(f"predict: 4 axes, {multi.duration:.3f} s at 1024 Hz = {samples} samples")
    print(f"  sampling  {rate / 1e6:8.2f} M samples/s   ({t_pred * 1e3:.3f} ms)  target >= 20")
    print(f"  planning  {t_plan * 1e6:8.2f} us per move                   target <= 50")
    growth = move_scaling()
    contour = contour_bench()  # after the moves: its large arrays change the allocator's state
    sampling = Figure(
        "predict.move sampling (4 axes, 10 s)",
        rate / 1e6,
        "M samples/s",
        20,
        scaling=[growth],
    )
    planning = Figure("predict.plan_move", t_plan * 1e6, "us", 50, higher=False)
    figures = [sampling, planning, contour]
    try:
        import ruckig
    except ImportError:
        print("ruckig not installed: no comparison")
        sampling.note = "ruckig not installed: no comparison"
        finish(figures, args)
        return
    inp = ruckig.InputParameter(4)
    inp.current_position = [0.0] * 4
    inp.target_position = [a[0] for a in AXES.values()]
    inp.max_velocity = [a[1] for a in AXES.values()]
    inp.max_acceleration = [a[2] for a in AXES.values()]
    inp.max_jerk = [a[2] * 1000 for a in AXES.values()]
    inp.synchronization = ruckig.Synchronization.No
    traj = ruckig.Trajectory(4)
    otg = ruckig.Ruckig(4)
    otg.calculate(inp, traj)
    n = int(traj.duration / TS) + 1

    def sample_ruckig() -> None:
        at = traj.at_time
        for k in range(n):
            at(k * TS)

    # Interleaved with the predictor, so that load from elsewhere hits both alike.
    t_pred, t_r, _ = interleaved(
        lambda: best(predict_all, repeat=5), lambda: best(sample_ruckig, repeat=1), 7
    )
    rate = samples / t_pred
    sampling.value = rate / 1e6
    r_rate = 4 * n / t_r
    t_rplan = best(lambda: otg.calculate(inp, traj), repeat=5, number=200)
    print(f"ruckig: Trajectory.at_time over {n} samples x 4 axes")
    print(f"  sampling  {r_rate / 1e6:8.2f} M samples/s   ({t_r * 1e3:.3f} ms)")
    print(f"  planning  {t_rplan * 1e6:8.2f} us per 4-axis trajectory")
    print(f"predict, interleaved with ruckig: {rate / 1e6:8.2f} M samples/s")
    print(f"ratio predict/ruckig sampling: {rate / r_rate:6.1f}x   target >= 5")
    sampling.anchor, sampling.anchor_value = "ruckig at_time", r_rate / 1e6
    sampling.ratio, sampling.ratio_text = rate / r_rate, "x ruckig's rate"
    sampling.ratio_target, sampling.ratio_higher = 5, True
    planning.anchor, planning.anchor_value = "ruckig calculate (4 axes)", t_rplan * 1e6
    finish(figures, args)


if __name__ == "__main__":
    main()
