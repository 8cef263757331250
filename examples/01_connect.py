"""Connect to a controller, say what it is, and read each axis's state.

Run it against the built-in simulator (no hardware needed)::

    python examples/01_connect.py

or against a real controller by giving its address::

    python examples/01_connect.py tcp://192.168.0.42
    python examples/01_connect.py /dev/ttyUSB0

Nothing here moves a motor: it only reads.
"""

from __future__ import annotations

import sys

import galil

# The simulator is the default so the script runs anywhere; any address galil.connect()
# understands works instead (tcp://, serial ports, usb://, /dev/galilpci0, sim://MODEL).
ADDRESS = sys.argv[1] if len(sys.argv) > 1 else "sim://DMC-4040"


def main() -> int:
    """Connect, describe the controller, read the axes; return a process exit code."""
    try:
        dmc = galil.connect(ADDRESS, timeout=2.0)
    except (galil.GalilConnectionError, galil.InvalidArgument) as exc:
        # An address that cannot be read (InvalidArgument), a cable out, a controller off
        # (GalilConnectionError): say so plainly rather than a traceback.
        print(f"could not connect to {ADDRESS}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1

    # `with` closes the link (and restores what connect changed) however the block ends.
    with dmc:
        ident = dmc.identity
        if ident is not None:
            print(f"connected to {ident.raw_model}, firmware {ident.firmware}")
        print(
            f"model {dmc.model.name}: axes {dmc.model.axes}, "
            f"one servo sample every {dmc.sample_period * 1e6:.1f} µs"
        )

        # Each axis reads the controller's operands (_TP, _SC, _MO, ...) as typed values.
        # Without a scale they are plain counts; see 03_move_with_units.py for millimetres.
        for letter, axis in dmc.axes.items():
            code, text = axis.stop_code
            state = "on" if axis.motor_on else "OFF"
            print(
                f"  {letter}: position {axis.position:>10.0f} counts, motor {state}, "
                f"speed {axis.speed:.0f} c/s, stop code {code} ({text})"
            )

        # A data record (QR) has the state of every axis taken in the same servo sample.
        try:
            rec = dmc.record()
            positions = {a: int(rec[a]["position"]) for a in dmc.model.axes}
            print(f"data record at sample {rec['sample']}: positions {positions}")
        except (galil.InvalidArgument, galil.CommandError) as exc:  # not on every model
            print(f"no data record: {str(exc).splitlines()[0]}")

        # Raw commands are there when you need one; a query returns the reply text.
        print("raw MG _TPA ->", dmc.command("MG _TPA").strip())
        # Several operands in as few round trips as fit on a line.
        tp_a, sc_a = dmc.query_operands(["_TPA", "_SCA"])
        print(f"_TPA = {tp_a:.0f}, _SCA = {sc_a:.0f}")

        # A command the controller refuses raises CommandError, already explained with TC1.
        try:
            dmc.command("XQ #NOLABEL")
        except galil.CommandError as exc:
            print(f"refused as expected: TC {exc.code} ({exc.text})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
