"""Contour mode: stream a path, segment by segment, and let the controller interpolate.

    python examples/04_contour.py                       # the simulator
    python examples/04_contour.py tcp://192.168.0.42    # a real controller

In contour mode (CM) the host sends position increments (CD), each lasting 2**DT servo
samples; the controller runs them back to back from a buffer. ``controller.contour`` checks the
whole path first (CD range, DT, the speed and acceleration it implies, soft limits, whether the
link is fast enough), keeps the buffer fed, and ends with ``CD 0=0``. On hardware this MOVES
axis A by 8 mm (3 mm, then 5 mm more) and axis B by 5 mm: make sure they have room.
"""

from __future__ import annotations

import math
import sys

import numpy as np

import galil
from galil import predict
from galil.contour import increments, sample_path
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
COUNTS_PER_MM = 2000

mm = ureg.mm


def main() -> int:
    """Stream the manual's 1 - cos profile, then a quarter circle on two axes."""
    with galil.connect(ADDRESS) as dmc:
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        y = dmc.B.set_scale(counts_per=COUNTS_PER_MM / mm)
        if not (x.motor_on and dmc.B.motor_on):
            dmc.servo_here("AB")
        ts = dmc.sample_period
        dt = 2  # each segment lasts 2**2 = 4 samples (3.9 ms at the default TM 1000)

        # 1. The contour-mode example of the Galil manual: 6000 counts in 120 ms along a
        # velocity of 1 - cos, so it starts and ends at rest. Paths are functions of time in
        # counts, relative to where the axis is now; sample_path takes them at segment ends.
        a, b = 6000.0, 0.120

        def one_minus_cos(t: np.ndarray) -> np.ndarray:
            return np.asarray(
                a * t / b - a / (2 * math.pi) * np.sin(2 * math.pi * np.minimum(t, b) / b)
            )

        path = sample_path(one_minus_cos, duration=b, dt=dt, sample_period=ts)
        # What will be sent: integer increments whose running sum never drifts from the path.
        incs = increments(path)
        plan = predict.contour(incs, dt, sample_period=ts)
        print(
            f"1 - cos: {incs.size} segments, {int(incs.sum())} counts, "
            f"predicted {plan.duration * 1e3:.1f} ms, peak {plan.peak_speed:.0f} counts/s"
        )
        with dmc.motion():
            result = dmc.contour("A", path, dt=dt)
        print(
            f"  done: A at {x.reference_position:~.3f}; {result.lines} command lines, "
            f"buffer never below {result.low_water} free slots"
        )

        # 2. Two axes: a quarter circle of 5 mm radius in half a second. A path in pint units
        # goes through each axis's scale; plain numbers (as above) are counts.
        radius = 5.0  # mm

        def quarter_circle(t: np.ndarray) -> np.ndarray:
            angle = (math.pi / 2) * (1 - np.cos(math.pi * t / 0.5)) / 2  # ease in and out
            return np.column_stack([radius * np.sin(angle), radius * (1 - np.cos(angle))])

        times = np.arange(1, 129) * (1 << dt) * ts
        times = np.minimum(times, 0.5)
        path2 = quarter_circle(times) * mm  # shape (segments, 2): one column per axis
        with dmc.motion():
            arc = dmc.contour("AB", path2, dt=dt, progress=True)
        print(
            f"quarter circle: {len(arc.increments)} segments in {arc.duration:.3f} s; "
            f"A {x.reference_position:~.3f}, B {y.reference_position:~.3f}"
        )

        # 3. A path the controller cannot follow is refused before anything is sent.
        # Here: 20 mm in one 4-sample segment is beyond the CD range (±32,000 counts).
        try:
            dmc.contour("A", [0.0, 20.0] * mm, dt=dt)
        except galil.LimitError as exc:
            print(
                f"refused: {exc.name} {exc.value} beyond ±{exc.limit:.0f}, segment at sample "
                f"{exc.sample}"
            )

        # The link check: the same 1 - cos stream over a 9600-baud serial line would starve
        # the buffer. contour() runs this check with the link it has; here we ask directly.
        try:
            predict.check_contour(incs, dt, model=dmc.model, baud=9600, axis="A")
        except galil.LimitError as exc:
            print(f"a 9600-baud link is too slow: {exc.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
