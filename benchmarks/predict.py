"""Benchmark the profile predictor against ruckig, and contour prediction against bare numpy.

Prints: samples per second for a 10 s, 4-axis move at 1024 Hz; planning latency per move
without sampling; ruckig's ``Trajectory.at_time`` sampling the same motion in a loop; ratios and
targets (>= 20 M samples/s, >= 5x ruckig, <= 50 us planning). Then ``predict.contour`` on a
1 M-segment DT 1 path (>= 50 M samples/s, within 2x of the floor-interpolation formula written
directly in numpy, measured in the same run; peak memory no more than the output arrays), and
how its cost grows from 1 k to 1 M segments.

Run: ``.venv/bin/python benchmarks/predict.py``
"""

from __future__ import annotations

import importlib
import time
import tracemalloc
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

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


def best(fn: Callable[[], object], repeat: int = 7, number: int = 1) -> float:
    """Best wall time of ``number`` calls, over ``repeat`` rounds, per call."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times)


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


def contour_bench() -> bool:
    """predict.contour on DT 1 paths; return whether its targets are met."""
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
    return rate >= 50e6 and ratio <= 2 and peak <= 1.05 * outputs


def main() -> None:
    multi = predict_all()
    samples = sum(round(p.duration / TS) + 1 for p in multi.profiles.values())
    t_pred = best(predict_all, repeat=15)
    rate = samples / t_pred
    d, sp, ac, dc = AXES["A"]
    t_plan = best(lambda: predict.plan_move(int(d), sp, ac, dc), repeat=7, number=2000)

    print(f"predict: 4 axes, {multi.duration:.3f} s at 1024 Hz = {samples} samples")
    print(f"  sampling  {rate / 1e6:8.2f} M samples/s   ({t_pred * 1e3:.3f} ms)  target >= 20")
    print(f"  planning  {t_plan * 1e6:8.2f} us per move                   target <= 50")
    contour_ok = contour_bench()  # after the moves: its large arrays change the allocator's state

    try:
        import ruckig
    except ImportError:
        print("ruckig not installed: no comparison")
        print("targets met" if contour_ok else "TARGETS MISSED")
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

    t_r = best(sample_ruckig, repeat=3)
    r_rate = 4 * n / t_r
    t_rplan = best(lambda: otg.calculate(inp, traj), repeat=5, number=200)
    print(f"ruckig: Trajectory.at_time over {n} samples x 4 axes")
    print(f"  sampling  {r_rate / 1e6:8.2f} M samples/s   ({t_r * 1e3:.3f} ms)")
    print(f"  planning  {t_rplan * 1e6:8.2f} us per 4-axis trajectory")
    print(f"ratio predict/ruckig sampling: {rate / r_rate:6.1f}x   target >= 5")
    ok = rate >= 20e6 and rate / r_rate >= 5 and t_plan <= 50e-6 and contour_ok
    print("targets met" if ok else "TARGETS MISSED")


if __name__ == "__main__":
    main()
