"""Record a move on the controller, sample by sample, and plot it against its prediction.

    python examples/07_capture.py                       # the simulator
    python examples/07_capture.py tcp://192.168.0.42    # a real controller
    python examples/07_capture.py sim://DMC-4040 out.png   # the plot saved to out.png

The plot goes to the file given after the address, or else to ``capture_A.png`` in the
system's temporary folder (``tempfile.gettempdir()``); the example prints where.

The controller records the reference position (what its profiler commanded) and the encoder
position of axis A every 2 servo samples into arrays of its own (``RA``, ``RD``, ``RC``); the
host uploads them afterwards (``QU``), so nothing is lost to the link. The capture knows the
controller sample of its first value and the move the sample it began on: the recording lines
up with the prediction exactly. On the simulator the reference matches it to the count.

On hardware this MOVES axis A by 10 mm and back: make sure the stage has room, and set
COUNTS_PER_MM to your stage's encoder resolution.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import galil
from galil.notebook import compare, compare_plot
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
# Where the plot goes: never into whatever folder the example was started from.
PLOT = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.gettempdir()) / "capture_A.png"
COUNTS_PER_MM = 2000

mm, s = ureg.mm, ureg.s


def main() -> int:
    """Capture a move's reference and encoder positions; compare and plot them."""
    with galil.connect(ADDRESS) as dmc:
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm, offset=-x.reference_position)
        if not x.motor_on:
            dmc.servo_here("A")
        x.speed = 20 * mm / s
        x.accel = x.decel = 200 * mm / s**2
        plan = x.plan_to(10 * mm)
        print(f"plan A -> 10 mm: {plan.shape}, {plan.duration:.3f} s")

        # Every 2 samples, for the move and a little after; the recording starts on its own
        # line just before the move (RC, then MG TIME: its first sample is known).
        with dmc.motion():
            capture = dmc.capture(["_RPA", "_TPA"], every=2, seconds=plan.duration + 0.1)
            move = x.move_to(10 * mm)
            move.wait()
            recording = capture.wait()
        print(f"recorded {len(recording)} values of {', '.join(recording.sources)}")
        print(f"capture from sample {recording.start}, the move began at {move.begin['A']}")

        # The reference is what the predictor predicts; the encoder follows it with the servo
        # loop's lag, which no prediction of the profiler includes.
        reference = compare(move, recording)["A"]
        encoder = compare(move, recording, field="position")["A"]
        print(f"reference vs prediction: largest difference {reference.worst:.0f} counts")
        print(f"encoder vs prediction: largest difference {encoder.worst:.0f} counts (lag)")

        fig = compare_plot(move, recording, title="A move: predicted vs recorded on the controller")
        fig.savefig(PLOT)
        print(f"plot saved to {PLOT}")

        # Data records carry the controller sample too, so they line up the same way.
        with dmc.records(8) as stream:
            back = x.move_to(0 * mm)
            back.wait()
            records = stream.take(4)
        print(f"data records at samples {[int(t) for t in records['time']]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
