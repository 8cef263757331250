"""A lab's day one: home an axis, check its switches, tune it, drive an output, save.

    python examples/06_lab_day_one.py                       # the simulator
    python examples/06_lab_day_one.py tcp://192.168.0.42    # a real controller

On hardware this MOVES axis A: HM drives towards the home switch at SP, then slowly over it to
the next index pulse, which becomes position 0. Check the stage has room, the switches are
wired, and set the speeds below for your stage. It also sets KP/KI/KD on axis A and output 1,
and burns the parameters to flash (BN): comment those lines out if you do not want that.
"""

from __future__ import annotations

import sys

import galil

ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"


def main() -> int:
    """Home axis A, read its switches, set gains and an output; return an exit code."""
    with galil.connect(ADDRESS) as dmc:
        a = dmc.A
        if not a.motor_on:
            dmc.servo_here("A")
        a.speed = 20_000  # SP: the first stage of HM (counts/s)
        a.home_speed = 4_000  # HV: the slow stages
        print(f"switches before homing: {a.switches}")
        print(f"homed? {bool(a.homed)}: {a.homed.how}")

        with dmc.motion("A"):  # Ctrl-C or an error stops the axis
            handle = a.home()
            print(f"homing: {handle.notes.get('A', 'predicted')}")
            result = handle.wait(timeout=120)
        print(f"homed with stop code {result.stop_codes['A']}, position {a.position}")
        print(f"homed? {bool(a.homed)}: {a.homed.how}")

        a.kp, a.ki, a.kd = 8, 0.25, 64
        print(f"gains KP {a.kp} KI {a.ki} KD {a.kd}, motor {a.motor_type.name}")
        try:
            a.kp = 5000
        except galil.LimitError as exc:
            print(f"refused before sending: {exc.args[0].splitlines()[0]}")

        first = dmc.model.io_first
        dmc.io.outputs[first] = True
        print(
            f"output {first} is {dmc.io.outputs[first]}, inputs {dmc.io.inputs[first : first + 8]}"
        )
        print(f"analog input {first}: {dmc.io.analog_in[first]:.3f~}")
        dmc.save()  # BN: burn the parameters
        print("parameters saved")
    return 0


if __name__ == "__main__":
    sys.exit(main())
