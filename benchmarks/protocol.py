"""Protocol core throughput: command/reply pairs encoded and parsed per second, one core.

A pair is: build a typed command (validation included), ``Session.send`` it to bytes, feed the
controller's reply to ``Session.receive_data`` and get the ``Completed`` back. Four mixes are
timed: plain commands answered ``:``, queries answered `` 1000\\r\\n:``, a compound line of five
commands answered ``:::: 1000\\r\\n:`` (counted as five pairs), and a prebuilt command.

Each mix runs several short times; the median rate is printed, measured in CPU time of this
process ("per second on one core": other processes' load on the machine is not counted).

Target: >= 200,000 pairs/s, so the host's share stays far below the controller's ~0.5 ms per
command. Run: ``python benchmarks/protocol.py [repeats]``.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable

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


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 7
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
    for name, step in rows:
        rate = statistics.median(_rate(step) for _ in range(repeats))
        print(f"  {name:44s} {rate:12,.0f} pairs/s   ratio to target {rate / TARGET:5.2f}")


if __name__ == "__main__":
    main()
