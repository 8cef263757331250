"""Programs, arrays and variables, awaited: twins of ``controller.programs``,
``controller.arrays`` and ``controller.variables`` (:mod:`galil.programs`, :mod:`galil.arrays`).

::

    await dmc.programs.download(SQUARES)
    await dmc.programs.run("#SQUARES", thread=1)
    await dmc.programs.wait(1)
    await dmc.arrays.upload("sq")           # a numpy array
    await dmc.variables.write("gain", 2.5)  # sync: dmc.variables["gain"] = 2.5
    await dmc.variables["gain"]             # 2.5
"""

from __future__ import annotations

import operator
from collections.abc import Awaitable

from galil.aio._waits import in_slices
from galil.aio._worker import Backed, Room, Worker, twin
from galil.arrays import Arrays, Variables
from galil.link import Link
from galil.programs import Programs, check_thread_timeout

__all__ = ["AsyncArrays", "AsyncPrograms", "AsyncVariables"]


def _threads(programs: Programs) -> dict[int, int]:
    return programs.threads


class AsyncPrograms(Backed[Programs]):
    """The user's program, its threads, and burning it to flash, awaited."""

    def __init__(self, sync: Programs, worker: Worker, link: Link) -> None:
        super().__init__(sync, worker)
        self._link = link

    download = twin(Programs.download)
    upload = twin(Programs.upload)
    run = twin(Programs.run)
    halt = twin(Programs.halt)
    burn = twin(Programs.burn)

    async def threads(self) -> dict[int, int]:
        """The user's running threads and the line each is on (``_XQn``); the library's own
        threads are left out. One round trip."""
        return await self._worker.run(_threads, self.sync)

    async def wait(self, thread: int = 0, timeout: float = 10.0) -> None:
        """Wait until ``thread`` has finished (its ``_XQn`` reads -1), in controller time
        (see :meth:`galil.programs.Programs.wait`; run in slices so a cancelled task frees
        its worker thread soon).

        Raises:
            InvalidArgument: a bad thread or timeout.
            GalilTimeoutError: it still runs after ``timeout`` seconds (it is not halted).
            ProgramError: it stopped on an error, its own or another thread's (decision 0059).
        """
        total = check_thread_timeout(timeout)  # as the sync wait: None and inf refused
        programs = self.sync

        def wait(seconds: float) -> None:
            programs.wait(thread, seconds)

        expired = f"thread {thread} still runs after {total} s"  # (seconds: not a Quantity)
        await in_slices(self._worker, self._link, wait, total, expired)

    def __repr__(self) -> str:
        return f"<AsyncPrograms of {self.sync!r}>"


class AsyncArrays(Room[Arrays]):
    """The controller's arrays, awaited (``await dmc.arrays.upload("sq")``)."""

    list = twin(Arrays.list)
    define = twin(Arrays.define)
    delete = twin(Arrays.delete)
    download = twin(Arrays.download)
    upload = twin(Arrays.upload)

    async def contains(self, name: object) -> bool:
        """Whether array ``name`` exists (sync: ``name in dmc.arrays``; ``LA``)."""
        return await self._worker.run(operator.contains, self.sync, name)

    def __repr__(self) -> str:
        return f"<AsyncArrays of {self.sync!r}>"


class AsyncVariables(Room[Variables]):
    """The controller's variables, awaited: ``await variables["x"]`` reads one (``MG x``),
    ``await variables.write("x", 2)`` sets it (sync: ``variables["x"] = 2``),
    ``await variables.delete("x")`` frees it (sync: ``del variables["x"]``). A missing name
    raises :class:`~galil.errors.UnknownVariableError` (a ``KeyError`` too). Not a mapping:
    its reads are awaited; ``await variables.list()`` is the dict."""

    read = twin(Variables.read)
    write = twin(Variables.write)
    delete = twin(Variables.delete)
    clear = twin(Variables.clear)
    list = twin(Variables.list)

    def __getitem__(self, name: str) -> Awaitable[float]:
        return self._worker.run(self.sync.read, name)

    async def contains(self, name: object) -> bool:
        """Whether variable ``name`` exists (sync: ``name in dmc.variables``; ``LV``)."""
        return await self._worker.run(operator.contains, self.sync, name)

    def __repr__(self) -> str:
        return f"<AsyncVariables of {self.sync!r}>"
