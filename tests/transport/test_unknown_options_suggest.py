"""An option ``connect()`` does not know is refused, before anything is opened, with the
closest spelling among the client's and the transport's options (``reconect``: did you mean
'reconnect'?); one close to none is named alone."""

from __future__ import annotations

import pytest

import galil
from galil.errors import InvalidArgument


@pytest.mark.parametrize(
    ("address", "options", "meant"),
    [
        ("sim://DMC-4040", {"reconect": True}, "'reconect': did you mean 'reconnect'?"),
        ("sim://DMC-4040?clok=real", {}, "'clok': did you mean 'clock'?"),
        ("tcp://127.0.0.1:1", {"reconect": True}, "'reconect': did you mean 'reconnect'?"),
        ("tcp://127.0.0.1:1", {"conect_timeout": 1}, "did you mean 'connect_timeout'?"),
        ("tcp://127.0.0.1:1", {"tiemout": 1}, "'tiemout': did you mean 'timeout'?"),
    ],
)
def test_a_misspelt_option_suggests_the_one_meant(
    address: str, options: dict[str, object], meant: str
) -> None:
    with pytest.raises(InvalidArgument, match=r"^unknown (sim://|TCP) option\(s\)") as info:
        galil.connect(address, **options)
    assert meant in str(info.value)


def test_an_option_close_to_none_is_named_alone() -> None:
    with pytest.raises(InvalidArgument) as info:
        galil.connect("sim://DMC-4040", frobnicate=1)
    assert str(info.value).startswith("unknown sim:// option(s): frobnicate")
    assert "did you mean" not in str(info.value)
