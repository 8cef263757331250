"""The ``galil`` console command (also ``python -m galil``).

Subcommands: ``terminal``, ``list``, ``info``, ``dl``, ``ul``, ``plan``, ``sim`` and ``demo``.
Errors from the library are reported as one line (``galil: ...``) with exit status 2.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["build_parser", "main"]

DESCRIPTION = """\
Talk to Galil DMC motion controllers, find them, and simulate one.

Addresses: tcp://192.168.0.42 (or just 192.168.0.42), /dev/ttyUSB0, COM3,
usb://, /dev/galilpci0, sim://DMC-4040 (the built-in simulator).
"""

EPILOG = """\
examples:
  galil list                         serial, USB and PCI controllers on this computer
  galil terminal sim://DMC-4040      a terminal on the simulator (Ctrl-D leaves)
  galil dl program.dmc 192.168.0.42  download a program
  galil plan 12.5mm --speed 20mm/s --accel 200mm/s^2 --scale 2000/mm
  galil demo --quick                 the end-to-end job on the simulator, in a few seconds
"""


def _version() -> str:
    from galil import __version__

    return __version__


# ----------------------------------------------------------------------------------- commands


def _cmd_demo(args: argparse.Namespace) -> int:
    from galil.demo import run_demo

    png = None if args.no_png or args.quick else args.png
    return run_demo(png=png, model=args.model, quiet=args.quiet, quick=args.quick)


def _cmd_sim(argv: Sequence[str]) -> int:
    """``galil sim``: the server's own parser reads the options (one usage line, in the help
    and in every error), then the ports are checked (refused in one line) and it serves."""
    from galil.sim.server import check_ports, options, serve

    parser = options()
    args = parser.parse_args(argv)
    check_ports(args.tcp, args.message_port)
    return serve(parser, args)


def _quantity(text: str, what: str) -> Any:
    """``"12.5mm"`` as a pint Quantity, ``"10000"`` as a plain number."""
    from galil.errors import InvalidArgument
    from galil.units import ureg

    try:
        return float(text)
    except ValueError:
        pass
    try:
        return ureg.Quantity(text.replace("^", "**"))
    except Exception as exc:  # pint raises several kinds for text it cannot read
        raise InvalidArgument(f"{what}: cannot read {text!r} as a number or a quantity") from exc


def _model_with_axes(name: str) -> Any:
    """The model ``galil plan`` plans for; one with no axes (a RIO) is refused, as the library
    refuses a move on it."""
    from galil.errors import InvalidArgument
    from galil.models import get_model

    model = get_model(name)
    if not model.axes:
        raise InvalidArgument(
            f"{model.name} is an I/O controller with no axes: it has no motion to plan"
        )
    return model


def plan_profile(args: argparse.Namespace, note: Callable[[str], None] | None = None) -> Any:
    """The profile ``galil plan`` prints: counts, or the unit the distance was given in (with
    ``--scale``). A value the controller would store otherwise (SP and AC go in steps) is
    said through ``note(text)``, with the value the plan uses; a speed above 0 but under one
    step is refused, as the Python API refuses it."""
    from galil.errors import InvalidArgument
    from galil.units import counts_or_plain

    model = _model_with_axes(args.model)
    given = {  # what was typed, under the option's name
        "distance": ("the distance", args.distance),
        "SP": ("--speed", args.speed),
        "AC": ("--accel", args.accel),
        "DC": ("--decel", args.decel if args.decel else args.accel),
    }
    values = {name: _quantity(text, option) for name, (option, text) in given.items()}
    scale = _plan_scale(args.scale) if args.scale else None
    for name, value in values.items():
        if scale is None and not isinstance(value, float):
            option, text = given[name]
            raise InvalidArgument(
                f"{option} {text} has units but there is no --scale: give one (counts per "
                "unit, e.g. --scale 2000/mm), or plain counts"
            )
    counts: dict[str, float] = {}
    for name, value in values.items():
        if scale is None or isinstance(value, float):
            counts[name] = counts_or_plain(value, name)
        elif name == "distance":
            counts[name] = scale.distance_to_counts(value)
        else:
            counts[name] = abs(scale.rate_to_counts(value, 1 if name == "SP" else 2, name))
    distance = _plan_distance(args.distance, values["distance"], counts["distance"], scale)
    return _planned(model, distance, counts, args, scale, values["distance"], note)


def _planned(
    model: Any,
    distance: int,
    counts: dict[str, float],
    args: Any,
    scale: Any,
    shown: Any,
    note: Any,
) -> Any:
    """The profile of ``distance`` counts at the stored SP, AC, DC and IT, in the unit of
    ``shown`` (the distance as given) when there is a scale."""
    from galil import predict
    from galil.errors import LimitError
    from galil.models import tm_of
    from galil.moves import check_int32
    from galil.units import state_in_units

    try:  # (refused as Axis.plan_by refuses it: in counts, and in the scale's unit)
        check_int32("PR", distance, "the axis", model.name)
        stored = {n: predict.check_parameter(n, counts[n], model) for n in ("SP", "AC", "DC")}
        if stored["SP"] == 0 and counts["SP"] != 0:
            from galil.axis import _under_one_step  # (the Python API's refusal, word for word)

            raise _under_one_step("SP", counts["SP"], model, tm_of(model.sample_period), "")
    except LimitError as exc:
        state_in_units(exc, scale)
        raise
    smoothing = predict.check_parameter("IT", args.smoothing, model)  # stored in 1/256ths
    _say_stored(note, model, args, counts, {**stored, "IT": smoothing})
    profile = predict.move(
        distance, stored["SP"], stored["AC"], stored["DC"],
        sample_period=model.sample_period, smoothing=smoothing,
    )  # fmt: skip
    if scale is None:
        return profile
    unit = shown.units if not isinstance(shown, float) else scale.unit
    per = abs(scale.distance_to_counts(1.0 * unit))  # (counts in one of the distance's units)
    return profile.with_units(per, f"{unit:~}")


def _say_stored(
    note: Any, model: Any, args: Any, counts: dict[str, float], stored: dict[str, float]
) -> None:
    """Say each value the controller stores otherwise than given (SP, AC and DC go in steps,
    IT in 1/256ths; AC has a smallest value), and that the plan uses what it stores."""
    if note is None:
        return
    given = {"SP": args.speed, "AC": args.accel, "DC": args.decel or args.accel}
    options = {"SP": "--speed", "AC": "--accel", "DC": "--decel" if args.decel else "--accel"}
    units = {"SP": " counts/s", "AC": " counts/s^2", "DC": " counts/s^2", "IT": ""}
    said: dict[tuple[str, float], list[str]] = {}
    for name, used in stored.items():
        asked = args.smoothing if name == "IT" else counts[name]
        if not math.isclose(used, asked, rel_tol=1e-9, abs_tol=1e-9):
            said.setdefault((options.get(name, "--smoothing"), used), []).append(name)
    for (option, used), names in said.items():
        name = names[0]
        asked = args.smoothing if name == "IT" else counts[name]
        text = f"{option} {asked:.10g}{units[name]}"
        if name != "IT" and not _plain(given[name]):  # (a quantity: its counts beside it)
            text = f"{option} {given[name]} ({asked:.10g}{units[name]})"
        note(
            f"note: {text}: the controller stores {' and '.join(names)} {used:.10g}"
            f"{units[name]} (in its steps, and its range, on {model.name}); the plan uses that"
        )


def _plain(text: object) -> bool:
    """Whether ``text`` is a plain number (counts) rather than a quantity with units."""
    try:
        float(str(text))
    except ValueError:
        return False
    return True


def _plan_scale(text: str) -> Any:
    """``--scale`` as a :class:`~galil.units.Scale`, refused in the CLI's words."""
    from galil.errors import InvalidArgument
    from galil.units import Scale

    value = _quantity(text, "--scale")
    example = "e.g. --scale 2000/mm or --scale 4096/deg"
    if isinstance(value, float):
        raise InvalidArgument(f"--scale {text}: give counts per unit, {example}")
    try:
        return Scale(counts_per=value)
    except InvalidArgument:
        magnitude = float(value.magnitude)
        if not (math.isfinite(magnitude) and magnitude > 0):
            raise InvalidArgument(
                f"--scale {text}: the counts per unit must be positive and finite, {example} "
                "(for an axis whose positive direction is the motor's negative one, give the "
                "distance with the opposite sign)"
            ) from None
        raise InvalidArgument(
            f"--scale {text}: give counts per a length or an angle, {example}"
        ) from None


def _plan_distance(text: str, value: Any, counts: float, scale: Any) -> int:
    """The distance in whole counts, by the predictor's rule (decision 0092): a plain number
    is counts and must be whole; a distance in the units of ``--scale`` is rounded to the
    nearest count, as an axis with a scale rounds it."""
    from galil.predict.counts import ROUND_IT, whole_counts

    if scale is not None and not isinstance(value, float):
        return round(counts)
    # (a plain number with a scale: the unit was left out)
    hint = f" (plain numbers are counts: write {text}{scale.unit:~})" if scale else ROUND_IT
    return whole_counts(counts, "the distance", hint)


def _cmd_plan(args: argparse.Namespace) -> int:
    if args.png:
        from galil.predict.profile import check_figure_path

        check_figure_path(args.png)  # (before: a traceback from matplotlib after the plan)
    profile = plan_profile(args, note=print)
    print(profile)
    if args.png:
        fig = profile.plot(title=f"PR {args.distance} on {args.model}")
        fig.savefig(args.png, dpi=100)
        print(f"plot saved to {args.png}")
    return 0


def _connect(address: str, timeout: float) -> Any:
    import galil

    options: dict[str, Any] = {"timeout": timeout}
    if address.startswith("sim:") and "clock=" not in address:
        options["clock"] = "real"  # a person is typing: the simulator runs in real time
    return galil.connect(address, **options)


def _cmd_info(args: argparse.Namespace) -> int:
    with _connect(args.address, args.timeout) as dmc:
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
    from galil.errors import GalilConnectionError
    from galil.link import RECONNECT_ADVICE
    from galil.terminal import default_history_path, run_terminal

    history = None if args.no_history else (args.history or default_history_path())
    with _connect(args.address, args.timeout) as dmc:
        ident = dmc.identity
        name = ident.raw_model if ident is not None else dmc.model.name
        print(
            f"connected to {name} at {args.address}; Ctrl-C stops (ST, HX), Ctrl-D leaves",
            file=sys.stderr,
            flush=True,
        )
        try:
            return run_terminal(dmc, timeout=args.timeout, history=history)
        except GalilConnectionError as exc:  # the link died: the terminal has ended
            why = str(exc.args[0] if exc.args else exc).replace(RECONNECT_ADVICE, "")
            print(f"galil: {why}; start galil terminal {args.address} again", file=sys.stderr)
            return 2


def _cmd_dl(args: argparse.Namespace) -> int:
    from galil.terminal import Terminal, program_lines

    lines = program_lines(_program_text(args.file))
    with _connect(args.address, args.timeout) as dmc:  # (checked as programs.download checks)
        return 0 if Terminal(dmc, timeout=args.timeout).download(lines) else 2


def _program_text(file: str) -> str:
    """A program file's text: ASCII, as a controller holds it. A character that is not (an
    ``é``, read as UTF-8) or a byte that is not text is named, with its line in the file.

    Raises:
        InvalidArgument: a character or byte a program cannot hold.
    """
    from galil.errors import InvalidArgument

    data = Path(file).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        at = data.count(b"\n", 0, exc.start) + 1
        raise InvalidArgument(
            f"{file} line {at}: byte 0x{data[exc.start]:02x} is not text; a program is ASCII"
        ) from None
    for n, line in enumerate(text.splitlines(), 1):
        bad = next((c for c in line if ord(c) > 0x7E), None)
        if bad is not None:
            raise InvalidArgument(
                f"{file} line {n}: character {bad!r} (U+{ord(bad):04X}) cannot be downloaded; "
                "a program is ASCII"
            )
    return text


def _cmd_ul(args: argparse.Namespace) -> int:
    """``galil ul``: the user's program, as ``programs.upload()`` gives it: the library's
    routines after it (a watchdog's, an input wait's) are left out, and said, so that a
    ``galil dl`` of the file downloads the user's program only."""
    from galil.protocol import commands as cmds
    from galil.routines import MARKER, split_program, ul_reply_bytes

    command = cmds.ul()
    with _connect(args.address, args.timeout) as dmc:
        text = dmc.link.transfer(command, ul_reply_bytes(dmc.model)).text
    everything = text.splitlines()
    lines, routines = split_program([line for line in everything if line.strip()])
    if routines:
        left = len(everything) - len(lines)
        print(
            f"(left out: the library's routines {', '.join(routines)}, the {left} lines from "
            f"its marker line {MARKER!r} on; they are not part of your program)",
            file=sys.stderr,
        )
    program = "".join(f"{line}\n" for line in lines)  # (no program: an empty file)
    if args.file:
        Path(args.file).write_text(program, encoding="ascii")
        count = f"{len(lines)} line{'s' if len(lines) != 1 else ''}" if lines else "no program"
        print(f"{count} saved to {args.file}", file=sys.stderr)
    else:
        sys.stdout.write(program)
        if not lines:
            print("no program in the controller's memory", file=sys.stderr)
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from galil.discovery import find

    found = find(
        serial=not args.no_serial,
        usb=not args.no_usb,
        pci=not args.no_pci,
        network=args.network,
        probe=args.probe,
        bootp=args.bootp,
        identify=not args.no_identify,
        timeout=args.timeout,
    )
    for item in found:
        print(item)
    if not found:
        print("no controller found", file=sys.stderr)
    if not (args.network or args.probe or args.bootp):
        print(
            "(Ethernet not searched: --network asks the LAN, --probe 192.168.0.0/24 asks "
            "given addresses)",
            file=sys.stderr,
        )
    return 0 if found else 1


# ----------------------------------------------------------------------------------- parser


def _timeout(p: argparse.ArgumentParser, default: float) -> None:
    p.add_argument(
        "--timeout",
        type=float,
        default=default,
        metavar="S",
        help=f"seconds to wait for each reply (default {default:g})",
    )


def _add_connection_commands(sub: Any) -> None:
    p = sub.add_parser(
        "terminal",
        help="type commands, see replies and program output as it arrives",
        description="A Galil terminal: lines go to the controller as typed (PRA=1000;BGA); "
        "a rejected line is explained with TC1; DL alone starts a program download ending "
        "with a line holding a backslash alone; Ctrl-C stops the motion (ST) and the "
        "programs (HX); Ctrl-D leaves. Piped input "
        "(galil terminal ADDRESS < setup.txt) runs line by line; the exit status is then 1 "
        "if any line was refused or failed.",
    )
    p.add_argument("address", help="controller address, e.g. 192.168.0.42 or sim://DMC-4040")
    _timeout(p, 5.0)
    p.add_argument(
        "--history", type=Path, metavar="FILE", help="history file (default: in ~/.local/state)"
    )
    p.add_argument("--no-history", action="store_true", help="keep no history file")
    p.set_defaults(func=_cmd_terminal)

    p = sub.add_parser("info", help="connect and describe the controller and its axes")
    p.add_argument("address", help="e.g. tcp://192.168.0.42, /dev/ttyUSB0, sim://DMC-4040")
    _timeout(p, 1.0)
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser("dl", help="download a program file (DL)")
    p.add_argument("file", help="program text; blank lines and indentation are dropped")
    p.add_argument("address", help="controller address")
    _timeout(p, 5.0)
    p.set_defaults(func=_cmd_dl)

    p = sub.add_parser("ul", help="upload the program (UL) to standard output or a file")
    p.add_argument("address", help="controller address")
    p.add_argument("file", nargs="?", help="where to save it (default: standard output)")
    _timeout(p, 5.0)
    p.set_defaults(func=_cmd_ul)
    _add_list_command(sub)


def _add_list_command(sub: Any) -> None:
    p = sub.add_parser(
        "list",
        aliases=["find"],  # as galil.find() in Python
        help="find controllers: serial ports, USB, PCI, and Ethernet when asked",
        description="Lists serial ports whose USB IDs are Galil's or a USB-serial bridge's, "
        "Galil USB devices, Galil PCI nodes, and Ethernet controllers when asked.",
    )
    p.add_argument(
        "--network",
        action="store_true",
        help="also ask the LAN: ^R^V to Galil's multicast group 239.255.19.56",
    )
    p.add_argument(
        "--probe",
        action="append",
        default=[],
        metavar="ADDR",
        help="ask these hosts over TCP: 192.168.0.42, 192.168.0.42:23 or 192.168.0.0/24 "
        "(repeatable)",
    )
    p.add_argument(
        "--bootp",
        action="store_true",
        help="listen 5 s for controllers asking for an IP address (UDP 67: needs root)",
    )
    p.add_argument("--no-serial", action="store_true", help="skip serial ports")
    p.add_argument("--no-usb", action="store_true", help="skip USB devices")
    p.add_argument("--no-pci", action="store_true", help="skip PCI nodes")
    p.add_argument(
        "--no-identify", action="store_true", help="do not open what is found to ask ^R^V"
    )
    _timeout(p, 1.0)
    p.set_defaults(func=_cmd_list)


def _add_offline_commands(sub: Any) -> None:
    p = sub.add_parser("demo", help="run the end-to-end job on the built-in simulator")
    p.add_argument("--model", default="DMC-4040", help="simulated model (default DMC-4040)")
    p.add_argument("--png", default="galil-demo.png", help="where to save the plot")
    p.add_argument("--no-png", action="store_true", help="do not draw the plot")
    p.add_argument("--quick", action="store_true", help="short moves, no plot: a smoke test")
    p.add_argument("--quiet", action="store_true", help="print nothing; the status tells")
    p.set_defaults(func=_cmd_demo)

    # Listed here; its options are the server's parser's (galil.sim.server.options), which
    # main() hands the arguments after "sim" to.
    sub.add_parser(
        "sim",
        help="serve a simulated controller over TCP (default: 127.0.0.1, a free port) or a pty",
        add_help=False,
    )

    p = sub.add_parser(
        "plan",
        help="predict a position move and print (or plot) it",
        description="Predict a relative move as the controller's profiler will run it. "
        "Plain numbers are counts; with --scale, values take units (12.5mm, 20mm/s). "
        "A negative distance is given as it is written: galil plan -12.5mm --scale 2000/mm.",
    )
    # A value that begins with a minus and a digit is a value, units or not (-12.5mm, as
    # Python 3.13's argparse reads it): argparse before took it for an unknown option.
    p._negative_number_matcher = re.compile(r"-\.?\d")
    p.add_argument(
        "distance", help="relative move: counts, or a length with --scale (12.5mm, -12.5mm)"
    )
    p.add_argument("--speed", default="25000", help="SP: counts/s, or e.g. 20mm/s")
    p.add_argument("--accel", default="256000", help="AC: counts/s^2, or e.g. 200mm/s^2")
    p.add_argument("--decel", default=None, help="DC (default: the acceleration)")
    p.add_argument("--scale", default=None, help="counts per unit, e.g. 2000/mm or 4096/deg")
    p.add_argument("--smoothing", type=float, default=1.0, help="IT, 0.004..1 (1: none)")
    p.add_argument("--model", default="DMC-4040", help="model whose ranges apply")
    p.add_argument("--png", default=None, help="save a plot of the profile here")
    p.set_defaults(func=_cmd_plan)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``galil`` command."""
    parser = argparse.ArgumentParser(
        prog="galil",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"galil {_version()}")
    sub = parser.add_subparsers(
        dest="command",
        required=True,
        metavar="COMMAND",
        help="what to do (COMMAND -h: its options)",
    )
    _add_connection_commands(sub)
    _add_offline_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``galil`` command; returns the exit status."""
    given = list(sys.argv[1:] if argv is None else argv)
    if given[:1] == ["sim"]:
        run: Any = functools.partial(_cmd_sim, given[1:])
    else:
        args = build_parser().parse_args(given)
        run = functools.partial(args.func, args)
    try:
        return int(run())
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `galil info ... | head`: the reader has gone, quietly
        _quiet_stdout()
        return 141  # (128 + SIGPIPE, as a shell reports a command its pipe ended)
    except Exception as exc:  # the CLI reports errors as one line, not a traceback
        from galil.errors import GalilError

        if isinstance(exc, GalilError):
            print(f"galil: {exc.args[0] if exc.args else exc}", file=sys.stderr)
            return 2
        # A file or a device that cannot be opened; an optional package missing (its
        # message names the extra that installs it: --png without matplotlib).
        if isinstance(exc, (OSError, ModuleNotFoundError)):
            print(f"galil: {exc}", file=sys.stderr)
            return 2
        raise


def _quiet_stdout() -> None:
    """Point stdout at the null device: Python's own flush at exit would meet the broken
    pipe again and print a second error."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # (a stdout with no file descriptor: nothing to flush)
        pass


if __name__ == "__main__":
    raise SystemExit(main())
