"""A speed schedule: one move that changes speed at given distances from its start.

    python examples/05_speed_schedule.py                       # the simulator
    python examples/05_speed_schedule.py tcp://192.168.0.42    # a real controller

This is the Galil form of the manual's "distance to change" moves: each (distance, speed) pair
becomes an AD trippoint followed by SP in a small program run with XQ on thread 0. The program
is one of the library's routines: it is kept beside the program in the controller's memory,
never over it, and a schedule is refused while a program of yours runs. On hardware axis A
MOVES 30 mm forward.
"""

from __future__ import annotations

import sys

import galil
from galil import predict
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
COUNTS_PER_MM = 2000

mm, s = ureg.mm, ureg.s


def main() -> int:
    """Validate a schedule, preview it, run it; return a process exit code."""
    with galil.connect(ADDRESS) as dmc:
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        if not x.motor_on:
            dmc.servo_here("A")
        x.accel = 200 * mm / s**2
        x.decel = 200 * mm / s**2

        # Start at 20 mm/s; slow to 10 mm/s after 10 mm and to 5 mm/s after 20 mm.
        distance = 30 * mm
        changes = [(10 * mm, 10 * mm / s), (20 * mm, 5 * mm / s)]

        # A change point is valid only once the ramp before it has finished. An invalid one
        # is refused before anything is sent, and the error names the earliest valid point.
        try:
            x.speed_schedule(distance, [(0.5 * mm, 10 * mm / s)], speed=20 * mm / s)
        except predict.ScheduleError as exc:
            earliest = exc.earliest / COUNTS_PER_MM
            print(f"refused: change {exc.index} at 0.5 mm; the earliest valid is {earliest} mm")

        # Preview in counts with the predictor (what speed_schedule() will check and run).
        ac, dc = dmc.query_operands(["_ACA", "_DCA"])  # the controller's quantised values
        preview = predict.speed_schedule(
            30 * COUNTS_PER_MM,
            20 * COUNTS_PER_MM,
            [(10 * COUNTS_PER_MM, 10 * COUNTS_PER_MM), (20 * COUNTS_PER_MM, 5 * COUNTS_PER_MM)],
            ac,
            dc,
            sample_period=dmc.sample_period,
        )
        plan = preview.profile
        print(
            f"plan: {plan.distance / COUNTS_PER_MM:.1f} mm in {plan.duration:.3f} s, "
            f"trippoints at {[t / COUNTS_PER_MM for t in preview.triggers]} mm"
        )
        # The speed in each third of the move, from the predicted profile. Positions are whole
        # counts per sample, so average the per-sample velocity over ~50 ms.
        for at in (5, 15, 25):
            k = int(abs(plan.position - plan.start - at * COUNTS_PER_MM).argmin())
            v = plan.velocity[k - 25 : k + 25].mean() / COUNTS_PER_MM
            print(f"  at {at:>2} mm: {v:5.1f} mm/s")

        with dmc.motion("A"):
            move = x.speed_schedule(distance, changes, speed=20 * mm / s)
            result = move.wait(progress=True)
        print(f"done at {x.position:~.3f}; end vs prediction {result.deviation} counts")
    return 0


if __name__ == "__main__":
    sys.exit(main())
