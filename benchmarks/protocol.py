"""Protocol core throughput: command/reply pairs encoded and parsed per second, one core.

A pair is: build a typed command (validation included), ``Session.send`` it to bytes, feed the
controller's reply to ``Session.receive_data`` and get the ``Completed`` back. Four mixes are
timed: plain commands answered ``:``, queries answered `` 1000\\r\\n:``, a compound line of five
commands answered ``:::: 1000\\r\\n:`` (counted as five pairs), and a prebuilt command.

Each mix runs several short times; the median rate is printed, measured in CPU time of this
process ("per second on one core": other processes' load on the machine is not counted).

Target: >= 200,000 pairs/s, so the host's share stays far below the controller's ~0.5 ms per
command. The anchor is the least work any codec must do for a pair, timed the same way: format
the command's bytes and look for the ``:`` at the end of the reply.

Run: ``python benchmarks/protocol.py [--quick] [--json PATH]``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

from harness import Figure, Scaling, cpu_best, finish, options

from galil.protocol import Session, commands, pack

TARGET = 200_000


def _rate(step: Callable[[], int], seconds: float = 0.3) -> float:
    done = 0
    start = time.process_time()
    end = start + seconds
    while True:
        for _ in range(1000):
            done += step()
        now = time.process_time()
        if now >= end:
            return done / (now - start)


def bare_pair() -> int:
    """The anchor: the bytes of ``PRA=1000`` built, and a reply's ``:`` found."""
    data = b"PRA=" + str(1000).encode() + b"\r"
    reply = b":"
    return 1 if data and reply.endswith(b":") else 0


def main() -> None:
    args = options(__doc__)
    repeats = 3 if args.quick else 7
    session = Session()

    def ack_pair() -> int:
        session.send(commands.pr(A=1000))
        session.receive_data(b":")
        return 1

    def query_pair() -> int:
        session.send(commands.tp("A"))
        session.receive_data(b" 1000\r\n:")
        return 1

    line = pack(
        [
            commands.pr(A=1000),
            commands.sp(A=25000),
            commands.bg("A"),
            commands.am("A"),
            commands.tp("A"),
        ],
        80,
    )[0]

    def compound_pairs() -> int:
        session.send(line)
        session.receive_data(b":::: 1000\r\n:")
        return 5

    prebuilt = commands.pr(A=1000)

    def prebuilt_pair() -> int:
        session.send(prebuilt)
        session.receive_data(b":")
        return 1

    rows = [
        ("PRA=1000 -> ':' (built each time)", ack_pair),
        ("TP A -> ' 1000\\r\\n:' (built each time)", query_pair),
        ("5-command line (prebuilt)", compound_pairs),
        ("prebuilt PRA=1000 -> ':'", prebuilt_pair),
    ]
    print(f"protocol core, one core (CPU time), median of {repeats}; target {TARGET:,} pairs/s")
    bare = statistics.median(_rate(bare_pair) for _ in range(repeats))
    print(f"  {'anchor: bytes built, reply end found':44s} {bare:12,.0f} pairs/s")
    figures = []
    for name, step in rows:
        rate = statistics.median(_rate(step) for _ in range(repeats))
        print(f"  {name:44s} {rate:12,.0f} pairs/s   ratio to target {rate / TARGET:5.2f}")
        figures.append(
            Figure(
                f"codec {name.split(' ->')[0].split(' (')[0]}",
                rate,
                "pairs/s",
                TARGET,
                anchor="bare bytes",
                anchor_value=bare,
                ratio=bare / rate,
                ratio_text="x the anchor's time",
            )
        )
    figures[-1].scaling.append(Scaling("pipelined commands", batch_scaling(session, prebuilt)))
    finish(figures, args)


def batch_scaling(session: Session, cmd: commands.Command) -> list[tuple[float, float]]:
    """CPU time of N prebuilt commands sent back to back and their N replies in one chunk."""
    points = []
    for n in (10, 100, 1000, 10000):
        replies = b":" * n

        def batch(n: int = n, replies: bytes = replies) -> None:
            for _ in range(n):
                session.send(cmd)
            session.receive_data(replies)

        points.append((float(n), cpu_best(batch, repeat=5, number=max(1, 1000 // n))))
    return points


if __name__ == "__main__":
    main()
