"""Golden bytes for the coordinated-motion and gearing builders, and their refusals."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from galil.errors import InvalidArgument, LimitError
from galil.models import get_model
from galil.protocol import commands as c
from galil.protocol.commands import Command

M4040 = get_model("DMC-4040")
M2183 = get_model("DMC-2183")

GOLDEN: list[tuple[Callable[[], Command], bytes]] = [
    (lambda: c.ca(), b"CA S\r"),
    (lambda: c.ca("T"), b"CA T\r"),
    (lambda: c.cs("S"), b"CS S\r"),
    (lambda: c.vm("AB", model=M4040), b"VM AB\r"),
    (lambda: c.vm("DA"), b"VM DA\r"),
    (lambda: c.lm("ABC", model=M4040), b"LM ABC\r"),
    (lambda: c.vp(8000, -2000), b"VP 8000,-2000\r"),
    (lambda: c.cr(1000, 270, 90, model=M4040), b"CR 1000,270,90\r"),
    (lambda: c.cr(1234.56786, -0.00390625, 360.5), b"CR 1234.5679,-0.0039,360.5\r"),
    (lambda: c.ve(), b"VE\r"),
    (lambda: c.le(), b"LE\r"),
    (lambda: c.li(100, None, -5, model=M4040), b"LI 100,,-5\r"),
    (lambda: c.li(B=3), b"LI ,3\r"),
    (lambda: c.li(A=0, B=-8388607, model=M4040), b"LI 0,-8388607\r"),
    (lambda: c.vs(20000, model=M4040), b"VSS=20000\r"),
    (lambda: c.va(256000, "T", model=M4040), b"VAT=256000\r"),
    (lambda: c.vd(1024), b"VDS=1024\r"),
    (lambda: c.vt(0.5, model=M2183), b"VTS=0.5\r"),
    (lambda: c.ga(None, "CA", model=M4040), b"GA ,CA\r"),
    (lambda: c.ga(C="S"), b"GA ,,S\r"),
    (lambda: c.ga("DB", "A"), b"GA DB,A\r"),
    (lambda: c.gr(B=0.5), b"GR ,0.5\r"),
    (lambda: c.gr(0, -127, model=M4040), b"GR 0,-127\r"),
]


@pytest.mark.parametrize(("build", "wire"), GOLDEN, ids=[g[1].decode()[:-1] for g in GOLDEN])
def test_builders_give_the_golden_bytes(build: Callable[[], Command], wire: bytes) -> None:
    assert build().wire == wire


REFUSED: list[tuple[Callable[[], Command], type[Exception], str]] = [
    (lambda: c.ca("U"), InvalidArgument, "S or T"),
    (lambda: c.vm("A", model=M4040), InvalidArgument, "two axes"),
    (lambda: c.vm("ABC"), InvalidArgument, "two axes"),
    (lambda: c.vm("AE", model=M4040), InvalidArgument, "unknown axis"),
    (lambda: c.lm("", model=M4040), InvalidArgument, "at least one"),
    (lambda: c.lm("AA"), InvalidArgument, "twice"),
    (lambda: c.vp(1.5, 0), InvalidArgument, "whole number"),
    (lambda: c.vp(2**31, 0), LimitError, "32-bit"),
    (lambda: c.cr(5, 0, 90, model=M4040), LimitError, "CR radius"),
    (lambda: c.cr(1000, 0, 0), InvalidArgument, "must not be 0"),
    (lambda: c.cr(1000, 40000, 90), LimitError, "CR start angle"),
    (lambda: c.cr(6_000_000, 0, 90), LimitError, "radius × sweep"),
    (lambda: c.li(8_388_608, model=M4040), LimitError, "LI"),
    (lambda: c.li(1.5), InvalidArgument, "whole number"),
    (lambda: c.vs(0, model=M4040), LimitError, "VS"),
    (lambda: c.vs(30_000_000, model=M4040), LimitError, "VS"),
    (lambda: c.va(2, model=M4040), LimitError, "VA"),  # (the smallest: 2.56, at TM 20000)
    (lambda: c.vd(2e9), LimitError, "VD"),
    (lambda: c.vs(1000, "X"), InvalidArgument, "S or T"),
    (lambda: c.vt(0.5, model=M4040), InvalidArgument, "no VT"),
    (lambda: c.vt(2, model=M2183), LimitError, "VT"),
    (lambda: c.ga(A="CA"), InvalidArgument, "cannot follow itself"),
    (lambda: c.ga(B="Q"), InvalidArgument, "not a master"),
    (lambda: c.ga(B="CE", model=M4040), InvalidArgument, "not a master"),
    (lambda: c.ga(B="S;BG"), InvalidArgument, "not a master"),
    (lambda: c.ga(model=M4040), InvalidArgument, "no master"),
    (lambda: c.gr(B=128, model=M4040), LimitError, "GR"),
]


@pytest.mark.parametrize(("build", "error", "match"), REFUSED, ids=[r[2] for r in REFUSED])
def test_bad_coordinated_commands_are_refused_before_any_bytes(
    build: Callable[[], Command], error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        build()
