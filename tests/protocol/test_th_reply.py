"""The ``TH`` reply read into the handles in use (``galil.protocol.handles``)."""

from __future__ import annotations

from galil.protocol.handles import OpenHandle, parse_th

_TH = (
    "CONTROLLER IP ADDRESS 10,0,51,82 ETHERNET ADDRESS 00-50-4C-20-01-0F\r\n"
    "IHA TCP PORT 23 TO IP ADDRESS 10,0,51,81 PORT 3297\r\n"
    "IHB UDP PORT 23 TO IP ADDRESS 10,0,51,081 PORT 3298\r\n"
    "IHC AVAILABLE\r\n"
    "IHD ESTABLISHING SOMETHING\r\n"
)


def test_th_lists_each_handle_in_use_with_its_peer_and_leaves_the_rest_out() -> None:
    handles = parse_th(_TH)
    assert handles == {
        "A": OpenHandle("A", "TCP", 23, ("10.0.51.81", 3297)),
        "B": OpenHandle("B", "UDP", 23, ("10.0.51.81", 3298)),
    }
    assert parse_th("") == {}
