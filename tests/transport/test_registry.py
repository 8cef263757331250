"""Address parsing, the scheme registry and entry-point discovery."""

from __future__ import annotations

from collections.abc import Iterator
from importlib.metadata import EntryPoint
from typing import Any
from urllib.parse import SplitResult

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import galil.transport as transport
from galil.errors import GalilConnectionError, InvalidArgument
from galil.transport import (
    open_transport,
    parse_options,
    register_scheme,
    registered_schemes,
    split_address,
    timeout_grid,
)


class RecordingTransport:
    """A Transport that records what it was opened with."""

    secondary = None

    def __init__(self, url: SplitResult, options: dict[str, Any]) -> None:
        self.url = url
        self.options = options
        self.written = b""

    @property
    def kind(self) -> str:
        return "sim"

    def write(self, data: bytes) -> None:
        self.written += data

    def read(self, timeout: float) -> bytes:
        return b""

    def close(self) -> None:
        pass


@pytest.fixture
def clean_registry() -> Iterator[None]:
    saved = dict(transport._registry)
    loaded = transport._entry_points_loaded
    yield
    transport._registry.clear()
    transport._registry.update(saved)
    transport._entry_points_loaded = loaded


@pytest.mark.parametrize(
    ("address", "scheme", "where"),
    [
        ("/dev/ttyUSB0", "serial", "/dev/ttyUSB0"),
        ("COM3", "serial", "COM3"),
        ("com12", "serial", "com12"),
        ("\\\\.\\COM10", "serial", "\\\\.\\COM10"),
        ("/dev/galilpci0", "pci", "/dev/galilpci0"),
        ("serial:///dev/ttyS0?baudrate=19200", "serial", "/dev/ttyS0"),
        ("tcp://10.0.0.5", "tcp", "10.0.0.5"),
        ("10.0.0.5", "tcp", "10.0.0.5"),
        ("10.0.0.5:1023", "tcp", "10.0.0.5:1023"),
        ("usb://1079:4040?serial=123", "usb", "1079:4040"),
        ("sim://DMC-4040", "sim", "DMC-4040"),
        ("socket://localhost:7777", "socket", "localhost:7777"),
        ("loop://", "loop", ""),
    ],
)
def test_split_address(address: str, scheme: str, where: str) -> None:
    url = split_address(address)
    assert url.scheme == scheme
    assert where in (url.netloc + url.path)


@pytest.mark.parametrize("address", ["", "   ", "localhost", "ttyUSB0", "1:2://x"])
def test_split_address_refuses_ambiguous(address: str) -> None:
    with pytest.raises(InvalidArgument):
        split_address(address)


def test_parse_options_converts_and_keywords_win() -> None:
    url = split_address("serial:///dev/x?baudrate=19200&rtscts=0&parity=N&xonxoff=false&t=0.5")
    opts = parse_options(url, {"parity": "E"})
    assert opts == {"baudrate": 19200, "rtscts": 0, "parity": "E", "xonxoff": False, "t": 0.5}


@settings(max_examples=150, deadline=None)
@given(st.floats(min_value=-10, max_value=1000, allow_nan=False))
def test_timeout_grid_rounds_up_to_10_ms(t: float) -> None:
    g = timeout_grid(t)
    if t <= 0:
        assert g == 0
    else:
        assert g >= t - 1e-9
        assert g - t < 0.01 + 1e-9
        assert abs(g * 100 - round(g * 100)) < 1e-6


def test_builtin_schemes_and_sim_entry_point_are_listed() -> None:
    names = registered_schemes()
    for scheme in ("tcp", "serial", "usb", "pci", "socket", "loop", "spy", "sim"):
        assert scheme in names


def test_register_scheme_round_trip(clean_registry: None) -> None:
    def opener(url: SplitResult, **options: Any) -> RecordingTransport:
        return RecordingTransport(url, options)

    register_scheme("fake", opener)
    t = open_transport("FAKE://box?x=1", answer=42)
    assert isinstance(t, RecordingTransport)
    assert t.url.netloc == "box"
    assert t.options == {"answer": 42}
    assert "fake" in registered_schemes()
    with pytest.raises(InvalidArgument, match="already registered"):
        register_scheme("fake", lambda url, **o: RecordingTransport(url, o))
    register_scheme("fake", lambda url, **o: RecordingTransport(url, {"new": True}), replace=True)
    t2 = open_transport("fake://box")
    assert isinstance(t2, RecordingTransport)
    assert t2.options == {"new": True}


@pytest.mark.parametrize("scheme", ["", "1abc", "a b", "a:b"])
def test_register_scheme_validates(scheme: str, clean_registry: None) -> None:
    with pytest.raises(InvalidArgument):
        register_scheme(scheme, lambda url, **o: RecordingTransport(url, o))


def test_register_scheme_needs_callable(clean_registry: None) -> None:
    with pytest.raises(InvalidArgument, match="callable"):
        register_scheme("x", "not callable")  # type: ignore[arg-type]


def test_unknown_scheme_lists_known() -> None:
    with pytest.raises(InvalidArgument, match=r"no transport for scheme 'nope'.*tcp"):
        open_transport("nope://x")


def test_opener_must_return_a_transport(clean_registry: None) -> None:
    register_scheme("bogus", lambda url, **o: object())
    with pytest.raises(GalilConnectionError, match="not a Transport"):
        open_transport("bogus://x")


def test_entry_points_are_discovered_and_broken_plugins_reported(
    clean_registry: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    good = EntryPoint(
        name="viaplugin", value="test_registry:plugin_opener", group=transport.ENTRY_POINT_GROUP
    )
    broken = EntryPoint(
        name="broken", value="no_such_module_xyz:opener", group=transport.ENTRY_POINT_GROUP
    )
    monkeypatch.setattr(transport, "entry_points", lambda group: [good, broken])
    transport._entry_points_loaded = False
    transport._registry.pop("viaplugin", None)
    t = open_transport("viaplugin://dev", flag=True)
    assert isinstance(t, RecordingTransport)
    assert t.options == {"flag": True}
    with pytest.raises(GalilConnectionError, match=r"plugin 'broken'.*failed to load"):
        open_transport("broken://x")


def test_explicit_registration_wins_over_entry_point(
    clean_registry: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    ep = EntryPoint(name="dup", value="no_such_module_xyz:o", group=transport.ENTRY_POINT_GROUP)
    monkeypatch.setattr(transport, "entry_points", lambda group: [ep])
    transport._entry_points_loaded = False
    register_scheme("dup", lambda url, **o: RecordingTransport(url, o))
    assert isinstance(open_transport("dup://x"), RecordingTransport)


def plugin_opener(url: SplitResult, **options: Any) -> RecordingTransport:
    """Target of the fake entry point above."""
    return RecordingTransport(url, options)
