"""Position moves in millimetres: plan first, then move, on one axis and on two together.

    python examples/03_move_with_units.py                       # the simulator
    python examples/03_move_with_units.py tcp://192.168.0.42    # a real controller

On hardware this MOVES axes A and B within 0..25 mm of where they are now: make sure the stages
have room, and set COUNTS_PER_MM to your stages' encoder resolution.
"""

from __future__ import annotations

import sys

import galil
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
COUNTS_PER_MM = 2000

mm, s = ureg.mm, ureg.s


def main() -> int:
    """Plan and run moves with units; show the errors a script should expect."""
    with galil.connect(ADDRESS) as dmc:
        # A scale turns every position, speed and acceleration of the axis into Quantities.
        # An offset puts the user's zero where the stage is now (counts stay as they are).
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm, offset=-x.reference_position)
        y = dmc.B.set_scale(counts_per=COUNTS_PER_MM / mm)
        y = dmc.B.set_scale(counts_per=COUNTS_PER_MM / mm, offset=-y.reference_position)
        if not (x.motor_on and y.motor_on):
            dmc.servo_here("AB")

        # Setters accept any compatible unit and send the controller's quantised value.
        for axis in (x, y):
            axis.speed = 20 * mm / s
            # 0.2 m/s² = 200 mm/s²; the controller keeps a multiple of 1024 counts/s², so the
            # value read back is 199.7 mm/s².
            axis.accel = 0.2 * ureg.m / s**2
            axis.decel = 200 * mm / s**2
        # Soft limits: the controller enforces them, and every move is checked against them
        # over its whole predicted path before it is sent. Keep the stage's own to restore.
        saved = x.soft_limits  # None on a side that is off
        # Only ever tighten them: max/min keep the stage's own where they are closer.
        low, high = saved
        x.soft_limits = (
            -1 * mm if low is None else max(low, -1 * mm),
            30 * mm if high is None else min(high, 30 * mm),
        )
        low, high = x.soft_limits
        print(f"A: speed {x.speed:~.3f}, accel {x.accel:~.1f}, soft limits {low:~} to {high:~}")

        # 1. Plan: the predictor says what the profiler will do, and nothing is sent. Its
        # arrays are counts, but on a scaled axis it is shown in the axis's unit (the
        # notebook table, the plot); `display` holds that unit (None on an unscaled axis).
        plan = x.plan_to(12.5 * mm)
        counts_per, _offset, unit = plan.display
        print(
            f"plan A -> 12.5 mm: {plan.shape}, {plan.duration:.3f} s, "
            f"peak {plan.peak_speed / abs(counts_per):.2f} {unit}/s, {plan.samples} samples"
        )
        plan.plot().savefig("plan_A.png")  # position, velocity and acceleration in mm
        print("plot in mm saved to plan_A.png")

        # 2. Move: the same checks again, then PA and BG in one line. wait() polls at a rate
        # set by the predicted duration and compares the end with the prediction.
        with dmc.motion():
            move = x.move_to(12.5 * mm)
            result = move.wait(progress=True)
        print(f"A at {x.position:~.4f}; end vs prediction: {result.deviation} counts")

        # Relative moves, with per-move overrides (they stay set on the controller).
        with dmc.motion():
            x.move_by(-2.5 * mm, speed=40 * mm / s).wait()
        print(f"A after move_by(-2.5 mm): {x.reference_position:~.4f}")

        # 3. Two axes at once: planned together, sent as one line, begun in the same sample.
        targets = {"A": 20 * mm, "B": 5 * mm}
        both = dmc.plan(targets)
        print(f"plan A and B: {both!r}, done in {both.duration:.3f} s")
        with dmc.motion():
            dmc.move(targets).wait(progress=True)
        print(f"A {x.position:~.3f}, B {y.position:~.3f}")

        # 4. What a script should be ready for. Both errors are raised before any byte
        # is sent, so the stage has not moved.
        try:
            x.move_to(35 * mm)  # beyond the 30 mm forward soft limit
        except galil.LimitError as exc:
            print(f"refused: {exc.name} would be crossed at t={exc.time:.3f} s")
        try:
            x.move_to(3 * ureg.s)  # a time is not a position
        except galil.InvalidArgument as exc:
            print(f"refused: {exc}")
        try:
            x.speed = 100 * ureg.m / s  # above the model's maximum SP
        except galil.LimitError as exc:
            print(f"refused: {exc}")

        # Back to the start.
        with dmc.motion():
            dmc.move({"A": 0 * mm, "B": 0 * mm}).wait()
        x.soft_limits = saved
        print(f"back at A {x.position:~.3f}, B {y.position:~.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
