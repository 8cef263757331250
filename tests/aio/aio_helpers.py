"""Helpers for the asyncio tests: run a coroutine with a deadline, open a simulated controller,
read what reached the simulator.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TypeVar

import galil.aio as aio
from galil.testing import sim_of

T = TypeVar("T")


def run(body: Callable[[], Awaitable[T]]) -> T:
    """Run ``body()`` in a fresh event loop; fail it after 30 s rather than hang the suite."""
    return asyncio.run(asyncio.wait_for(body(), 30))  # type: ignore[arg-type]


async def sim(model: str = "DMC-4040") -> aio.AsyncController:
    """An async controller on an in-process simulator of ``model``."""
    return await aio.connect(f"sim://{model}")


def commands_of(c: aio.AsyncController) -> list[str]:
    """Every command the simulator behind ``c`` received, in order."""
    return [text for _, text in sim_of(c.sync).command_log]
