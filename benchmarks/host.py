"""Host-side cost of planning and moving: what the library adds to the round trips it needs.

Two parts:

1. ``plan_by`` / ``plan_to`` over a transport that answers at once (a dictionary of canned
   replies: no controller, no simulator, no socket), against the one state query they make
   (``MG _RPA,_BGA,_SPA,...``, through the same link). The difference is the host overhead:
   units, prediction, checks, the handle. Target: <= 30 us beyond the query, on an axis in
   counts and on a scaled axis (mm). Distances change from call to call (no repeated plan).
2. ``move_to`` + ``wait()`` on the in-process simulator (``sim://``, manual clock) against one
   state query on the same link. Target: <= 3x the query. Moves of 1 s to 1 h show how the
   cost grows with the length of the move.

Times are the median of interleaved pairs of short runs (each the best of a few blocks), so
load from other processes hits both sides of a pair alike; planning, which never waits, is
timed in this process's CPU time.

Run: ``.venv/bin/python benchmarks/host.py [--quick] [--json PATH]``
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable

from harness import Figure, Scaling, best, cpu_best, finish, interleaved, options

import galil
from galil.controller import Controller
from galil.units import get_registry

#: Canned operand values of the instant transport (axis A of a DMC-4040 at power-on).
VALUES = {
    "RP": 0.0,
    "TP": 0.0,
    "BG": 0.0,
    "SP": 25000.0,
    "AC": 256000.0,
    "DC": 256000.0,
    "IT": 1.0,
    "BL": -2147483648.0,
    "FL": 2147483647.0,
    "MO": 0.0,
    "SC": 1.0,
    "TS": 15.0,  # (bits 3 and 2 set: neither limit switch active, as the simulator reads)
}


class InstantTransport:
    """A transport whose controller answers every command at once from canned values.

    ``MG`` of operands answers their values from :data:`VALUES` (``TIME`` 1000), anything
    else ``:``. Replies are computed once per command text and kept.
    """

    secondary = None
    kind = "ethernet"

    def __init__(self) -> None:
        self._out = b""
        self._replies: dict[bytes, bytes] = {}
        self.last = b""  # the last line written

    def _reply(self, line: bytes) -> bytes:
        out = []
        for part in line.split(b";"):
            text = part.decode()
            if text.startswith("MG "):
                names = [n.split("{")[0].strip() for n in text[3:].split(",")]
                nums = [1000.0 if n == "TIME" else VALUES.get(n[1:3], 0.0) for n in names]
                out.append((" " + " ".join(f"{v:.4f}" for v in nums) + "\r\n:").encode())
            else:
                out.append(b":")
        return b"".join(out)

    def write(self, data: bytes) -> None:
        replies = self._replies
        for line in data.split(b"\r")[:-1]:
            self.last = line
            reply = replies.get(line)
            if reply is None:
                reply = replies[line] = self._reply(line)
            self._out += reply

    def read(self, timeout: float) -> bytes:
        out, self._out = self._out, b""
        return out

    def close(self) -> None:
        pass


def _per_call(fn: Callable[[], object], number: int, cpu: bool = False) -> Callable[[], float]:
    timer = cpu_best if cpu else best

    def run() -> float:
        return timer(fn, repeat=3, number=number)

    return run


def state_query(c: Controller) -> list[str]:
    """The operands of the one state query a plan on axis A sends (the anchor is that very
    query, read off the wire, so it follows whatever the library asks)."""
    transport = InstantTransport()
    probe = galil.connect(transport, handshake=False, model=c.link.model.name)
    probe.A.plan_by(1000)
    line = transport.last.decode()
    probe.close()
    if not line.startswith("MG ") or ";" in line:
        raise RuntimeError(f"a plan's state query is not one MG line: {line!r}")
    return [n.split("{")[0].strip() for n in line[3:].split(",")]


def planning(quick: bool) -> list[Figure]:
    """plan_by and plan_to against the state query, over the instant transport."""
    c = galil.connect(InstantTransport(), handshake=False, model="DMC-4040")
    link = c.link
    names = state_query(c)
    number, pairs = (300, 7) if quick else (1000, 15)
    distances = itertools.cycle(range(1000, 2000, 7))
    axis = c.A

    def query() -> None:
        link.query_operands(names)

    figures = []
    ureg = get_registry()
    cases: list[tuple[str, Callable[[], object]]] = [
        ("plan_by, counts", lambda: axis.plan_by(next(distances))),
        ("plan_to, counts", lambda: axis.plan_to(next(distances))),
    ]
    mm = [d / 1000 * ureg.mm for d in range(1000, 2000, 7)]
    scaled_values = itertools.cycle(mm)
    scaled = [
        ("plan_by, mm", lambda: axis.plan_by(next(scaled_values))),
        ("plan_to, mm", lambda: axis.plan_to(next(scaled_values))),
    ]
    for label, fn in cases + scaled:
        if label.endswith("mm") and axis.scale is None:
            axis.set_scale(1000 / ureg.mm)
        fn()  # warm up (imports, caches of the first call)
        t_query, t_plan, _ = interleaved(
            _per_call(query, number, cpu=True), _per_call(fn, number, cpu=True), pairs
        )
        overhead = (t_plan - t_query) * 1e6
        print(
            f"  {label:16s} {t_plan * 1e6:7.1f} us; state query {t_query * 1e6:6.1f} us;"
            f" overhead {overhead:6.1f} us"
        )
        figures.append(
            Figure(
                f"host {label} (overhead)",
                overhead,
                "us",
                30,
                higher=False,
                anchor="state query",
                anchor_value=t_query * 1e6,
                ratio=t_plan / t_query,
                ratio_text="x the query",
                note="instant transport: no controller, no socket",
            )
        )
    c.close()
    return figures


def _move_wait(c: Controller, distance: int) -> None:
    handle = c.A.move_by(distance)
    handle.wait()


def _by_hand(c: Controller, names: list[str], pause: float) -> Callable[[int], None]:
    """The move's exchanges without the library: what any client of this simulator pays.

    The state query, the move line, the predicted time passing, one poll; no units, no
    prediction, no checks, no handle (``pause`` is the move's predicted time plus a sample).
    """
    link = c.link
    poll = ["_BGA", "_RPA", "_SCA"]

    def move(distance: int) -> None:
        link.query_operands(names)
        link.command_line([f"PRA={distance}", "BG A", "MG TIME"])
        link.pause(pause)
        if link.query_operands(poll)[0]:
            raise RuntimeError("the move by hand is still running after its predicted time")

    return move


def moving(quick: bool) -> list[Figure]:
    """move_by + wait on sim:// against one state query on the same link, and by hand."""
    c = galil.connect("sim://DMC-4040")
    link = c.link
    names = state_query(c)
    number, pairs = (30, 7) if quick else (100, 15)
    sign = itertools.cycle((1, -1))

    def query() -> None:
        link.query_operands(names)

    def move() -> None:
        _move_wait(c, next(sign) * 1000)

    pause = c.A.plan_by(1000).duration + link.sample_period
    by_hand = _by_hand(c, names, pause)

    def raw() -> None:
        by_hand(next(sign) * 1000)

    move()
    raw()
    t_query, t_move, ratio = interleaved(_per_call(query, number), _per_call(move, number), pairs)
    t_query2, t_raw, raw_ratio = interleaved(
        _per_call(query, number), _per_call(raw, number), pairs
    )
    _, _, lib_ratio = interleaved(_per_call(raw, number), _per_call(move, number), pairs)
    print(
        f"  move_by(1000) + wait {t_move * 1e6:7.1f} us; state query {t_query * 1e6:6.1f} us;"
        f" {ratio:.2f}x\n  the same exchanges by hand {t_raw * 1e6:7.1f} us;"
        f" {raw_ratio:.2f}x the query; the library's move is {lib_ratio:.2f}x them"
    )
    points = []
    c.A.speed = 100_000
    for seconds in (1.0, 10.0, 100.0, 1000.0, 3600.0):
        distance = round(100_000 * (seconds - 100_000 / 256_000))
        if quick and seconds > 100:
            break
        t0 = time.perf_counter()
        _move_wait(c, next(sign) * distance)
        points.append((seconds, time.perf_counter() - t0))
    c.close()
    return [
        Figure(
            "host move_by + wait (sim://)",
            ratio,
            "x one query",
            3,
            higher=False,
            anchor="state query (us)",
            anchor_value=t_query * 1e6,
            scaling=[Scaling("s of motion", points)],
            note=f"{t_move * 1e6:.0f} us per move of 0.14 s; in-process simulator, manual clock:"
            f" the same exchanges by hand cost {raw_ratio:.2f}x the query (next line)",
        ),
        Figure(
            "sim:// move exchanged by hand (floor)",
            raw_ratio,
            "x one query",
            None,
            higher=False,
            anchor="state query (us)",
            anchor_value=t_query2 * 1e6,
            ratio=lib_ratio,
            ratio_text="x: the library's move_by + wait against it",
            note="state query, PR/BG/MG TIME, the predicted time, one poll: no library work;"
            " the simulator's command handling and servo stepping",
        ),
    ]


def main() -> None:
    args = options(__doc__)
    print("planning over a transport that answers at once (DMC-4040, axis A):")
    figures = planning(args.quick)
    print("moving on the in-process simulator (DMC-4040, axis A):")
    figures.extend(moving(args.quick))
    finish(figures, args)


if __name__ == "__main__":
    main()
