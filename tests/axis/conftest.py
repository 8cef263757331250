"""Fixtures for the axis layer: controllers on simulators, reached only through the public API."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import galil
from galil.testing import simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    """A DMC-4040 on an in-process simulator with a manual clock."""
    with simulated("DMC-4040") as controller:
        yield controller
