"""Jog an axis: run at a speed, change speed while moving, stop.

    python examples/02_jog.py                       # the simulator
    python examples/02_jog.py tcp://192.168.0.42    # a real controller

On hardware this MOVES axis A at up to 10 mm/s for about two seconds (20 mm at most): make sure
the stage has room, and change COUNTS_PER_MM to your stage's encoder resolution.
"""

from __future__ import annotations

import sys

import galil
from galil.units import ureg

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"
COUNTS_PER_MM = 2000  # encoder counts per millimetre of this stage

mm, s = ureg.mm, ureg.s


def main() -> int:
    """Jog axis A forwards, reverse it in motion, stop; return a process exit code."""
    with galil.connect(ADDRESS) as dmc:
        x = dmc.A.set_scale(counts_per=COUNTS_PER_MM / mm)
        if not x.motor_on:
            dmc.servo_here("A")  # a jog needs the servo loop closed
        # Jog ramps use AC when speeding up and DC when slowing down.
        x.accel = 100 * mm / s**2
        x.decel = 100 * mm / s**2
        print(f"start at {x.position:~.3f}")

        # Inside motion(), any exception (Ctrl-C included) sends ST to the moving axes and
        # waits for them to stop before it propagates: the stage never runs on unattended.
        with dmc.motion("A"):
            jog = x.jog(10 * mm / s)
            # Every move comes back with the predictor's profile; for a jog, the ramp.
            ramp = jog.profile
            print(
                f"jogging at 10 mm/s: the ramp takes {ramp.duration * 1e3:.0f} ms "
                f"and covers {ramp.distance / COUNTS_PER_MM:.3f} mm"
            )
            # controller.sleep() waits in the controller's time: real seconds on hardware,
            # simulated ones (instantly) on the in-process simulator.
            dmc.sleep(1.0)
            print(f"after 1 s: {x.position:~.3f}, velocity {x.velocity:~.2f}")

            # A second jog() while jogging changes speed in motion (here through zero).
            # (it returns the same handle: the jog, its prediction now with the new ramp)
            x.jog(-5 * mm / s)
            dmc.sleep(1.0)
            print(f"reversed: {x.position:~.3f}, velocity {x.velocity:~.2f}")

            x.stop()  # decelerates at DC
            jog.wait()  # until the ramp down is over

        code, text = x.stop_code
        print(f"stopped at {x.position:~.3f}: stop code {code} ({text})")

        # A jog cannot be checked ahead; the controller stops it at a soft limit itself
        # (stop code 2): set limits around where we are and watch the axis stop on its own.
        saved = x.soft_limits  # put the stage's own limits back afterwards (None: off)
        here = x.position
        # Only ever tighten limits: max/min keep the stage's own where they are closer.
        low, high = here - 20 * mm, here + 1 * mm
        x.soft_limits = (
            low if saved[0] is None else max(saved[0], low),
            high if saved[1] is None else min(saved[1], high),
        )
        try:
            with dmc.motion("A"):
                x.jog(5 * mm / s)
                dmc.sleep(1.0)
                code, text = x.stop_code
                print(f"jog into the forward soft limit: stop code {code} ({text})")
        finally:
            x.soft_limits = saved
    return 0


if __name__ == "__main__":
    sys.exit(main())
