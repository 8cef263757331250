"""Benchmark the profile predictor against ruckig.

Prints: samples per second for a 10 s, 4-axis move at 1024 Hz; planning latency per move
without sampling; ruckig's ``Trajectory.at_time`` sampling the same motion in a loop; ratios and
targets (>= 20 M samples/s, >= 5x ruckig, <= 50 us planning).

Run: ``.venv/bin/python benchmarks/predict.py``
"""

from __future__ import annotations

import time
from collections.abc import Callable

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

    try:
        import ruckig
    except ImportError:
        print("ruckig not installed: no comparison")
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
    ok = rate >= 20e6 and rate / r_rate >= 5 and t_plan <= 50e-6
    print("targets met" if ok else "TARGETS MISSED")


if __name__ == "__main__":
    main()
