"""Coordinated motion: draw a shape with lines and arcs, at one speed along the path.

    python examples/08_draw_a_shape.py                       # the simulator
    python examples/08_draw_a_shape.py tcp://192.168.0.42    # a real controller

A path of ``galil.Line`` and ``galil.Arc`` segments, in millimetres, runs as one vector
sequence (VM, VP, CR, VE, BG S) on axes A and B: predicted and checked as a whole before
anything is sent, then followed by a handle that knows where the axes are at every sample.
Then a third axis is geared to A and follows it. On hardware this MOVES axes A, B and C by
up to 40 mm: make sure they have room.
"""

from __future__ import annotations

import sys

import galil
from galil import Arc, Line
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
COUNTS_PER_MM = 2000

mm, s = ureg.mm, ureg.s


def rounded_square(side: float, r: float) -> list[Line | Arc]:
    """A square with rounded corners, counter-clockwise from the middle of its bottom edge."""
    straight = (side - 2 * r) * mm
    return [
        Line(straight / 2, 0),
        Arc(r * mm, 270, 90),
        Line(0, straight),
        Arc(r * mm, 0, 90),
        Line(-straight, 0),
        Arc(r * mm, 90, 90),
        Line(0, -straight),
        Arc(r * mm, 180, 90),
        Line(straight / 2, 0),
    ]


def main() -> int:
    """Plan, check and draw a rounded square; then a refusal; then gearing."""
    with galil.connect(ADDRESS) as dmc:
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        y = dmc.B.set_scale(counts_per=COUNTS_PER_MM / mm)
        z = dmc.C.set_scale(counts_per=COUNTS_PER_MM / mm)
        if not (x.motor_on and y.motor_on and z.motor_on):
            dmc.servo_here("ABC")
        square = rounded_square(40, 5)
        motion = {"speed": 40 * mm / s, "accel": 400 * mm / s**2, "decel": 400 * mm / s**2}

        # 1. The plan: the whole path predicted sample by sample; nothing is sent.
        plan = dmc.plan_vector("AB", square, **motion)
        print(
            f"plan: {plan.path[-1]:.3f} mm of path in {plan.duration:.3f} s, "
            f"top speed {plan.speed.max():.1f} mm/s"
        )
        try:
            plan.plot(title="a rounded square").savefig("square.png")
            print("plot of the path and the speed along it saved to square.png")
        except ImportError:  # matplotlib is the optional extra galil[jupyter]
            print("(no matplotlib: no plot)")

        # 2. Draw it. The handle's prediction is per axis, sample by sample.
        with dmc.motion():
            handle = dmc.vector_move("AB", square, **motion)
            result = handle.wait(progress=False)
        print(f"drawn: stop codes {result.stop_codes}, end vs prediction {result.deviation}")
        print(f"back at A {x.reference_position:~.2f}, B {y.reference_position:~.2f}")

        # 3. Refused before a byte: B may only move at 25 mm/s, and the corners turn the
        # path's 40 mm/s onto it.
        try:
            dmc.vector_move("AB", square, axis_speed={"B": 25 * mm / s}, **motion)
        except galil.LimitError as exc:
            print(f"refused: {str(exc).split(' (in user')[0]}")

        # 4. Gearing: C follows A at half its motion, predicted with A's move.
        gearing = z.gear_to(x, 0.5)
        move = x.move_by(20 * mm, speed=20 * mm / s)
        follower = move.profiles["C"]
        move.wait()
        gearing.off()
        predicted = follower.end / COUNTS_PER_MM
        print(
            f"C follows A at {gearing.ratio:g}: predicted {predicted:.3f} mm, "
            f"at {z.reference_position:~.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
