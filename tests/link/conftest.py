"""Fixtures for the link tests: a scriptable firmware stand-in (tests/client_fakes.py) reached
through a ``fakegalil://`` scheme, and a controller connected to it.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any
from urllib.parse import SplitResult

import pytest
from client_fakes import FakeGalil, FakeLink

import galil.transport as transport_registry
from galil.controller import Controller, connect
from galil.errors import InvalidArgument


@pytest.fixture
def peer() -> Iterator[FakeGalil]:
    """The firmware stand-in, registered as ``fakegalil://`` for the test's length."""
    fake = FakeGalil()

    def opener(url: SplitResult, **options: Any) -> FakeLink:
        if options:
            raise InvalidArgument(f"unknown option(s) {sorted(options)}")
        return fake.open()

    transport_registry.register_scheme("fakegalil", opener, replace=True)
    yield fake
    transport_registry._registry.pop("fakegalil", None)


@pytest.fixture
def c(peer: FakeGalil) -> Iterator[Controller]:
    """A controller connected to ``peer`` with a short timeout."""
    ctl = connect("fakegalil://x", timeout=0.2)
    yield ctl
    ctl.close()
