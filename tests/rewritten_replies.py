"""A simulator link whose answers to chosen command lines are rewritten (or lost), for tests
of what the library does with a controller's malformed, refused or missing replies."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from client_fakes import SimLinkWrapper

import galil
from galil.sim.clock import ManualClock
from galil.sim.controller import SimController
from galil.sim.link import SimLink

#: ``answer -> what arrives instead`` (``b""``: nothing arrives, the reply is lost).
Change = Callable[[bytes], bytes]


def lost(_answer: bytes) -> bytes:
    return b""


def answering(text: bytes) -> Change:
    """A change that puts ``text`` where the answer was."""
    return lambda _answer: text


@dataclass
class Rewrite(SimLinkWrapper):
    """The simulator's link; the answer to the next line holding a rule's mark is changed
    (the controller still runs the line). Each rule applies once, in the order given."""

    rules: list[tuple[bytes, Change]] = field(default_factory=list)
    sent: list[bytes] = field(default_factory=list)

    def once(self, mark: bytes, change: Change) -> None:
        self.rules.append((mark, change))

    def write(self, data: bytes) -> None:
        self.sent.append(bytes(data))
        for i, (mark, change) in enumerate(self.rules):
            if mark in data:
                del self.rules[i]
                self.inner.faults = lambda answer, change=change: [(0.0, change(answer))]
                try:
                    self.inner.write(data)
                finally:
                    self.inner.faults = None
                return
        self.inner.write(data)


def rewritten(model: str = "DMC-4040", timeout: float = 0.5) -> tuple[galil.Controller, Rewrite]:
    """A controller on a fresh simulator behind a :class:`Rewrite`."""
    wire = Rewrite(SimLink(SimController(model, ManualClock())))
    return galil.Controller(lambda: wire, timeout=timeout), wire
