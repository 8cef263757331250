"""The ``galil`` console command: ``demo``, ``sim``, ``plan``, ``info`` and ``terminal``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

__all__ = ["main"]


def _cmd_demo(args: argparse.Namespace) -> int:
    from galil.demo import run_demo

    return run_demo(png=args.png, model=args.model, quiet=args.quiet)


def _cmd_sim(args: argparse.Namespace) -> int:
    from galil.sim.server import main as sim_main

    argv = ["--model", args.model]
    if args.tcp:
        argv += ["--tcp", args.tcp]
    if args.pty:
        argv += ["--pty"]
    if args.message_port is not None:
        argv += ["--message-port", str(args.message_port)]
    argv += ["--lag", str(args.lag)]
    return sim_main(argv)


def _cmd_plan(args: argparse.Namespace) -> int:
    from galil import predict
    from galil.models import get_model

    model = get_model(args.model)
    speed = predict.check_parameter("SP", args.speed, model)
    accel = predict.check_parameter("AC", args.accel, model)
    decel = predict.check_parameter("DC", args.decel if args.decel else args.accel, model)
    profile = predict.move(
        args.distance,
        speed,
        accel,
        decel,
        sample_period=model.sample_period,
        smoothing=args.smoothing,
    )
    print(profile)
    if args.png:
        fig = profile.plot(title=f"PR {args.distance} on {model.name}")
        fig.savefig(args.png, dpi=100)
        print(f"plot saved to {args.png}")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    import galil

    with galil.connect(args.address) as dmc:
        ident = dmc.identity
        assert ident is not None  # connect() identifies unless told not to
        print(f"{ident.raw_model} firmware {ident.firmware} ({dmc.model.family})")
        print(f"axes: {', '.join(dmc.model.axes)}; sample period {dmc.sample_period * 1e6:.2f} us")
        for letter in dmc.model.axes:
            ax = dmc.axes[letter]
            code, text = ax.stop_code
            print(f"  {letter}: TP {ax.position:g}  moving {ax.moving}  SC {code} {text}")
    return 0


def _cmd_terminal(args: argparse.Namespace) -> int:
    import galil

    with galil.connect(args.address) as dmc:
        print(f"connected to {dmc.model.name}; Ctrl-D to leave", file=sys.stderr)
        while True:
            try:
                line = input(":")
            except EOFError:
                return 0
            if not line.strip():
                continue
            try:
                print(dmc.command(line.strip()))
            except galil.CommandError as exc:
                print(f"? {exc.code} {exc.text}")
            while True:
                try:
                    print(f"(message) {dmc.messages.get_nowait()}")
                except Exception:
                    break


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``galil`` command."""
    parser = argparse.ArgumentParser(prog="galil", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="run the end-to-end job on the built-in simulator")
    p.add_argument("--model", default="DMC-4040")
    p.add_argument("--png", default="galil-demo.png", help="where to save the plot")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("sim", help="serve a simulated controller over TCP or a pty")
    p.add_argument("--model", default="DMC-4040")
    p.add_argument("--tcp", metavar="HOST:PORT", help="e.g. 127.0.0.1:0 (0 picks a free port)")
    p.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal")
    p.add_argument(
        "--message-port",
        type=int,
        default=None,
        help="TCP port for unsolicited messages (0 picks one, -1 none: use CF on a handle)",
    )
    p.add_argument("--lag", type=float, default=0.003, help="servo lag time constant, s")
    p.set_defaults(func=_cmd_sim)

    p = sub.add_parser("plan", help="predict a position move and print (or plot) it")
    p.add_argument("distance", type=int, help="relative move, counts")
    p.add_argument("--speed", type=float, default=25_000, help="SP, counts/s")
    p.add_argument("--accel", type=float, default=256_000, help="AC, counts/s²")
    p.add_argument("--decel", type=float, default=None, help="DC, counts/s² (default: AC)")
    p.add_argument("--smoothing", type=float, default=1.0, help="IT, 0.004..1 (1: none)")
    p.add_argument("--model", default="DMC-4040")
    p.add_argument("--png", default=None)
    p.set_defaults(func=_cmd_plan)

    p = sub.add_parser("info", help="connect and describe the controller")
    p.add_argument("address", help="e.g. tcp://192.168.0.42, /dev/ttyUSB0, sim://DMC-4040")
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser("terminal", help="type commands, see replies and messages")
    p.add_argument("address")
    p.set_defaults(func=_cmd_terminal)

    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # the CLI reports errors as one line, not a traceback
        from galil.errors import GalilError

        if isinstance(exc, GalilError):
            print(f"galil: {exc}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    raise SystemExit(main())
