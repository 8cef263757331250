"""Golden bytes for every builder, and every refusal (raised before any bytes exist)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from galil.errors import InvalidArgument, LimitError
from galil.models import get_model
from galil.protocol import commands as c
from galil.protocol.commands import Command, Expect, ReplyKind, pack, parse_line

M4040 = get_model("DMC-4040")
M1500 = get_model("DMC-1500")
M2183 = get_model("DMC-2183")

GOLDEN: list[tuple[Callable[[], Command], bytes, ReplyKind]] = [
    (lambda: c.pr(1000, None, -200), b"PR 1000,,-200\r", ReplyKind.ACK),
    (lambda: c.pr(B=500), b"PRB=500\r", ReplyKind.ACK),
    (lambda: c.pr(A=1, C=-2), b"PR 1,,-2\r", ReplyKind.ACK),
    (lambda: c.pr(X=5, model=M1500), b"PRX=5\r", ReplyKind.ACK),
    (lambda: c.pr(1.0, 2), b"PR 1,2\r", ReplyKind.ACK),
    (lambda: c.pa(H=-2147483648), b"PAH=-2147483648\r", ReplyKind.ACK),
    (lambda: c.pa(0, 0, 0, 0, model=M4040), b"PA 0,0,0,0\r", ReplyKind.ACK),
    (lambda: c.sp(A=25000.5, model=M4040), b"SPA=25000.5\r", ReplyKind.ACK),
    (lambda: c.sp(1000, 2000), b"SP 1000,2000\r", ReplyKind.ACK),
    (lambda: c.ac(A=256000), b"ACA=256000\r", ReplyKind.ACK),
    (lambda: c.dc(256000, None, 1024, model=M4040), b"DC 256000,,1024\r", ReplyKind.ACK),
    (lambda: c.jg(A=-5000), b"JGA=-5000\r", ReplyKind.ACK),
    (lambda: c.ip(B=100), b"IPB=100\r", ReplyKind.ACK),
    (lambda: c.it(A=0.5), b"ITA=0.5\r", ReplyKind.ACK),
    (lambda: c.dp(0, 0), b"DP 0,0\r", ReplyKind.ACK),
    (lambda: c.fl(A=2147483647), b"FLA=2147483647\r", ReplyKind.ACK),
    (lambda: c.bl(A=-2147483648), b"BLA=-2147483648\r", ReplyKind.ACK),
    (lambda: c.bg("AC"), b"BG AC\r", ReplyKind.ACK),
    (lambda: c.bg(), b"BG\r", ReplyKind.ACK),
    (lambda: c.bg("S"), b"BG S\r", ReplyKind.ACK),
    (lambda: c.st("AB"), b"ST AB\r", ReplyKind.ACK),
    (lambda: c.st(), b"ST\r", ReplyKind.ACK),
    (lambda: c.ab(), b"AB\r", ReplyKind.ACK),
    (lambda: c.ab(motion_only=True), b"AB 1\r", ReplyKind.ACK),
    (lambda: c.am("A"), b"AM A\r", ReplyKind.ACK),
    (lambda: c.mc(["A", "B"]), b"MC AB\r", ReplyKind.ACK),
    (lambda: c.sh("ABCD", model=M4040), b"SH ABCD\r", ReplyKind.ACK),
    (lambda: c.mo(), b"MO\r", ReplyKind.ACK),
    (lambda: c.tp(), b"TP\r", ReplyKind.DATA),
    (lambda: c.tp("AB"), b"TP AB\r", ReplyKind.DATA),
    (lambda: c.tv("A"), b"TV A\r", ReplyKind.DATA),
    (lambda: c.te("A"), b"TE A\r", ReplyKind.DATA),
    (lambda: c.rp("B"), b"RP B\r", ReplyKind.DATA),
    (lambda: c.td("A"), b"TD A\r", ReplyKind.DATA),
    (lambda: c.ts("A"), b"TS A\r", ReplyKind.DATA),
    (lambda: c.sc("A"), b"SC A\r", ReplyKind.DATA),
    (lambda: c.cm("AB"), b"CM AB\r", ReplyKind.ACK),
    (lambda: c.cd(100, 200), b"CD 100,200\r", ReplyKind.ACK),
    (lambda: c.cd(100, 200, dt=3), b"CD 100,200=3\r", ReplyKind.ACK),
    (lambda: c.cd(A=5), b"CD 5\r", ReplyKind.ACK),
    (lambda: c.cd(B=5, dt=2), b"CD ,5=2\r", ReplyKind.ACK),
    (lambda: c.cd_end(), b"CD 0=0\r", ReplyKind.ACK),
    (lambda: c.cd_end("AB"), b"CD 0,0=0\r", ReplyKind.ACK),
    (lambda: c.dt(3), b"DT 3\r", ReplyKind.ACK),
    (lambda: c.dt(-1, model=M4040), b"DT -1\r", ReplyKind.ACK),
    (lambda: c.dt(0), b"DT 0\r", ReplyKind.ACK),
    (lambda: c.wc(), b"WC\r", ReplyKind.ACK),
    (lambda: c.tc(), b"TC1\r", ReplyKind.DATA),
    (lambda: c.tc(0), b"TC0\r", ReplyKind.DATA),
    (lambda: c.mg("Hello world"), b'MG "Hello world"\r', ReplyKind.DATA),
    (lambda: c.mg_operand("_TPA"), b"MG _TPA{Z10.4}\r", ReplyKind.DATA),
    (
        lambda: c.mg_operand("_TPA", "_BGB", "var1", "arr[3]", "@IN[1]"),
        b"MG _TPA{Z10.4},_BGB{Z10.4},var1{Z10.4},arr[3]{Z10.4},@IN[1]{Z10.4}\r",
        ReplyKind.DATA,
    ),
    (lambda: c.tm(1000), b"TM 1000\r", ReplyKind.ACK),
    (lambda: c.tm(250, model=M4040), b"TM 250\r", ReplyKind.ACK),
    (lambda: c.cw(1), b"CW 1\r", ReplyKind.ACK),
    (lambda: c.cw(2, 1), b"CW 2,1\r", ReplyKind.ACK),
    (lambda: c.cw(drop=0), b"CW ,0\r", ReplyKind.ACK),
    (lambda: c.eo(0), b"EO 0\r", ReplyKind.ACK),
    (lambda: c.lz(1), b"LZ 1\r", ReplyKind.ACK),
    (lambda: c.qz(), b"QZ\r", ReplyKind.DATA),
    (lambda: c.qr(), b"QR\r", ReplyKind.RECORD),
    (lambda: c.qr("A"), b"QR A\r", ReplyKind.RECORD),
    (lambda: c.th(), b"TH\r", ReplyKind.DATA),
    (lambda: c.identify(), b"\x12\x16\r", ReplyKind.DATA),
    (lambda: c.dl(["#A", 'MG "hi"', "EN"]), b'DL\r#A\rMG "hi"\rEN\r\\', ReplyKind.DOUBLE_ACK),
    (lambda: c.dl("#A\nEN\n"), b"DL\r#A\rEN\r\\", ReplyKind.DOUBLE_ACK),
    (lambda: c.ul(), b"UL\r", ReplyKind.CTRL_Z),
    (lambda: c.qu("arr"), b"QU arr[],,,1\r", ReplyKind.CTRL_Z),
    (lambda: c.qu("arr", 0, 9, delim=0), b"QU arr[],0,9,0\r", ReplyKind.CTRL_Z),
    (lambda: c.qd("arr", [1, 2.5, -3]), b"QD arr[],0,2\r1,2.5,-3\\", ReplyKind.ACK),
    (lambda: c.qd("arr", [7], first=4), b"QD arr[],4,4\r7\\", ReplyKind.ACK),
    (lambda: c.xq("#MAIN"), b"XQ #MAIN\r", ReplyKind.ACK),
    (lambda: c.xq("#A", 3), b"XQ #A,3\r", ReplyKind.ACK),
    (lambda: c.xq(), b"XQ\r", ReplyKind.ACK),
    (lambda: c.hx(), b"HX\r", ReplyKind.ACK),
    (lambda: c.hx(2), b"HX2\r", ReplyKind.ACK),
    (lambda: c.assign("speed2", 1.5), b"speed2=1.5\r", ReplyKind.ACK),
    (lambda: c.assign("SPEEDZ", -3), b"SPEEDZ=-3\r", ReplyKind.ACK),
    (lambda: c.assign("posx", 0), b"posx=0\r", ReplyKind.ACK),
    # lower case is never a command (decision 0060): the reference's own "date", "ta0"
    (lambda: c.assign("date", 8), b"date=8\r", ReplyKind.ACK),
    (lambda: c.assign("ta0", 0), b"ta0=0\r", ReplyKind.ACK),
    (lambda: c.assign("pr", 1), b"pr=1\r", ReplyKind.ACK),
    (lambda: c.da_variables("gain", "data"), b"DA gain,data\r", ReplyKind.ACK),
]


@pytest.mark.parametrize(
    ("build", "wire", "kind"), GOLDEN, ids=[g[1].decode("latin-1") for g in GOLDEN]
)
def test_golden_bytes(build: Callable[[], Command], wire: bytes, kind: ReplyKind) -> None:
    cmd = build()
    assert cmd.wire == wire
    assert cmd.expect.kind is kind
    assert cmd.returns_data is (kind not in (ReplyKind.ACK, ReplyKind.DOUBLE_ACK))


def test_qr_record_size_from_model() -> None:
    assert c.qr(model=M4040).expect == Expect.record(M4040.record_size)
    assert c.qr("A", model=M4040).expect == Expect.record(None)
    assert c.tp("A").expect == Expect.data(1)


REFUSALS: list[tuple[Callable[[], object], type[Exception]]] = [
    # unknown axes
    (lambda: c.pr(I=5), InvalidArgument),
    (lambda: c.pr(E=5, model=M4040), InvalidArgument),
    (lambda: c.pr(X=5, model=M4040), InvalidArgument),
    (lambda: c.bg("AE", model=M4040), InvalidArgument),
    (lambda: c.bg("AA"), InvalidArgument),
    (lambda: c.bg("A;B"), InvalidArgument),
    (lambda: c.tp("a"), InvalidArgument),
    (lambda: c.pr(1, 2, 3, 4, 5, model=M4040), InvalidArgument),
    (lambda: c.pr(), InvalidArgument),
    (lambda: c.pr(None, None), InvalidArgument),
    (lambda: c.pr(5, A=5), InvalidArgument),
    (lambda: c.cm(""), InvalidArgument),
    # NaN, infinity, non-numbers, fractions of counts
    (lambda: c.pr(A=math.nan), InvalidArgument),
    (lambda: c.sp(A=math.inf), InvalidArgument),
    (lambda: c.ac(A=-math.inf), InvalidArgument),
    (lambda: c.pr(A="1000"), InvalidArgument),
    (lambda: c.pr(A=True), InvalidArgument),
    (lambda: c.pr(A=1.5), InvalidArgument),
    (lambda: c.assign("x", math.nan), InvalidArgument),
    # ranges
    (lambda: c.pr(A=2**31), LimitError),
    (lambda: c.pa(A=-(2**31) - 1), LimitError),
    (lambda: c.ip(A=2.0**40), LimitError),
    (lambda: c.sp(A=-1), LimitError),
    (lambda: c.sp(A=22_000_001, model=M4040), LimitError),
    (lambda: c.jg(A=-22_000_001, model=M4040), LimitError),
    (lambda: c.ac(A=1000), LimitError),
    (lambda: c.ac(A=1_073_740_801, model=M4040), LimitError),
    (lambda: c.dc(A=67_107_841, model=M2183), LimitError),
    (lambda: c.it(A=0.003), LimitError),
    (lambda: c.it(A=1.01), LimitError),
    (lambda: c.cd(32_001, model=M4040), LimitError),
    (lambda: c.cd(100, dt=9), LimitError),
    (lambda: c.cd(0.5), InvalidArgument),
    (lambda: c.dt(9), LimitError),
    (lambda: c.dt(-2), LimitError),
    (lambda: c.dt(-1, model=M1500), LimitError),
    (lambda: c.tm(20), LimitError),
    (lambda: c.tm(1000, model=M1500), InvalidArgument),
    (lambda: c.tc(2), InvalidArgument),
    (lambda: c.cw(3), InvalidArgument),
    (lambda: c.cw(), InvalidArgument),
    (lambda: c.cw(1, 2), InvalidArgument),
    (lambda: c.eo(2), InvalidArgument),
    (lambda: c.lz(True), InvalidArgument),
    (lambda: c.hx(8), LimitError),
    (lambda: c.xq("#A", -1), LimitError),
    # strings that could smuggle a second command or break the framing
    (lambda: c.mg('a";BG'), InvalidArgument),
    (lambda: c.mg("a;BG"), InvalidArgument),
    (lambda: c.mg("a\rBG"), InvalidArgument),
    (lambda: c.mg("a\nBG"), InvalidArgument),
    (lambda: c.mg("back\\slash"), InvalidArgument),
    (lambda: c.mg("café"), InvalidArgument),
    (lambda: c.mg("why?"), InvalidArgument),
    (lambda: c.mg("{N}"), InvalidArgument),
    (lambda: c.mg(":colon first"), InvalidArgument),
    (lambda: c.mg("x" * 73), InvalidArgument),
    (lambda: c.mg("x" * 32, model=M1500), InvalidArgument),
    (lambda: c.mg(5), InvalidArgument),  # type: ignore[arg-type]
    (lambda: c.mg_operand(), InvalidArgument),
    (lambda: c.mg_operand("_TPA;BG"), InvalidArgument),
    (lambda: c.mg_operand('"x"'), InvalidArgument),
    # names and labels
    (lambda: c.assign("1abc", 1), InvalidArgument),
    (lambda: c.assign("toolongname", 1), InvalidArgument),
    (lambda: c.assign("a;BG", 1), InvalidArgument),
    (lambda: c.assign("_TPA", 1), InvalidArgument),
    (lambda: c.assign("CD0", 1), InvalidArgument),
    (lambda: c.assign("SPA", 1), InvalidArgument),
    (lambda: c.assign("PR", 1), InvalidArgument),
    (lambda: c.assign("DATA", 1), InvalidArgument),
    (lambda: c.da_variables(), InvalidArgument),
    (lambda: c.da_variables("CD0"), InvalidArgument),
    (lambda: c.assign("BGAB", 1), InvalidArgument),
    (lambda: c.assign("ELSE", 1), InvalidArgument),
    (lambda: c.assign("vär", 1), InvalidArgument),
    (lambda: c.xq("A"), InvalidArgument),
    (lambda: c.xq("#A;BG"), InvalidArgument),
    (lambda: c.xq("#TOOLONGX"), InvalidArgument),
    (lambda: c.qu("a b"), InvalidArgument),
    (lambda: c.qu("arr", delim=2), InvalidArgument),
    (lambda: c.qu("arr", 5, 2), LimitError),
    (lambda: c.qd("arr", []), InvalidArgument),
    (lambda: c.qd("arr", [math.nan]), InvalidArgument),
    (lambda: c.qd("CD0", [1]), InvalidArgument),
    # programs
    (lambda: c.dl([]), InvalidArgument),
    (lambda: c.dl(["#A", "", "EN"]), InvalidArgument),
    (lambda: c.dl(["#A", "MG \\"]), InvalidArgument),
    (lambda: c.dl(["#A", "\x1a"]), InvalidArgument),
    (lambda: c.dl(["#A", "é"]), InvalidArgument),
    (lambda: c.dl(["x" * 81]), InvalidArgument),
    (lambda: c.dl([5]), InvalidArgument),  # type: ignore[list-item]
    # raw lines
    (lambda: parse_line("PR 1\rBG"), InvalidArgument),
    (lambda: parse_line("MG é"), InvalidArgument),
    (lambda: parse_line("DL"), InvalidArgument),
    (lambda: pack([c.mg("x" * 70)], 40), InvalidArgument),
    (lambda: pack([parse_line("a=1;b=2")]), InvalidArgument),
]


@pytest.mark.parametrize(("build", "error"), REFUSALS)
def test_refusals_happen_in_the_builder(
    build: Callable[[], object], error: type[Exception]
) -> None:
    with pytest.raises(error):
        build()


def test_limit_error_says_what_and_where() -> None:
    with pytest.raises(LimitError) as info:
        c.sp(A=30_000_000, model=M4040)
    assert info.value.name == "SP"
    assert info.value.axis == "A"
    assert info.value.limit == M4040.sp_max
    assert info.value.value == 30_000_000


def test_pack_respects_line_length_and_order() -> None:
    cmds = [c.pr(A=1000), c.sp(A=25000), c.bg("A"), c.am("A"), c.tp("A")] * 6
    for limit in (40, 80):
        lines = pack(cmds, limit)
        assert all(len(line.text) + 1 <= limit for line in lines)
        flat = [p for line in lines for p in (line.parts or (line,))]
        assert flat == cmds
        assert all(
            line.text == ";".join(p.text for p in line.parts) for line in lines if line.parts
        )
    assert len(pack(cmds, 40)) > len(pack(cmds, M4040))


def test_pack_puts_special_replies_alone() -> None:
    cmds = [c.pr(A=1), c.qr(), c.bg("A"), c.dl(["#A", "EN"]), c.ul(), c.identify(), c.qd("a", [1])]
    lines = pack(cmds)
    assert [line.text for line in lines] == [
        "PRA=1",
        "QR",
        "BG A",
        "DL",
        "UL",
        "\x12\x16",
        "QD a[],0,0",
    ]


def test_parse_line_infers_reply_shapes() -> None:
    line = parse_line('a=1;MG "x;y";TP A;QR;UL;QU a[]')
    assert [p.text for p in line.parts] == ["a=1", 'MG "x;y"', "TP A", "QR", "UL", "QU a[]"]
    kinds = [p.expect.kind for p in line.parts]
    assert kinds == [
        ReplyKind.ANY,
        ReplyKind.DATA,
        ReplyKind.DATA,
        ReplyKind.RECORD,
        ReplyKind.CTRL_Z,
        ReplyKind.CTRL_Z,
    ]
    assert parse_line("BG A") == Command("BG A", Expect.ANY)


@settings(max_examples=150, deadline=None)
@given(st.text(max_size=20))
def test_mg_text_is_sent_verbatim_or_refused(text: str) -> None:
    try:
        cmd = c.mg(text)
    except InvalidArgument:
        return
    assert cmd.text == f'MG "{text}"'
    assert not set(text) & set(';"\\\r\n?{}')
    assert text.isascii()
    assert text.isprintable()


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(st.sampled_from("ABCDEFGH"), st.integers(-(2**31), 2**31 - 1), min_size=1))
def test_axis_forms_round_trip(values: dict[str, int]) -> None:
    text = c.pr(**values).text
    if len(values) == 1:
        ((letter, v),) = values.items()
        assert text == f"PR{letter}={v}"
    else:
        fields = text.removeprefix("PR ").split(",")
        for letter, v in values.items():
            assert fields["ABCDEFGH".index(letter)] == str(v)
        assert sum(1 for f in fields if f) == len(values)


@settings(max_examples=150, deadline=None)
@given(
    letters=st.sampled_from(["A", "C", "AB", "BA", "ABD", "DCBA", "XZ", "H"]),
    rows=st.lists(
        st.lists(st.integers(-40_000, 40_000), min_size=4, max_size=4), min_size=1, max_size=8
    ),
    model=st.sampled_from([None, "DMC-4040", "DMC-4080"]),
)
def test_cd_rows_are_the_cd_commands_of_each_row(
    letters: str, rows: list[list[int]], model: str | None
) -> None:
    spec = None if model is None else get_model(model)
    inc = np.array([r[: len(letters)] for r in rows], dtype=np.int64).reshape(-1, len(letters))

    def outcome(build: object) -> object:
        try:
            return build()  # type: ignore[operator]
        except (InvalidArgument, LimitError) as exc:
            return type(exc)

    one_by_one = outcome(
        lambda: [c.cd(model=spec, **dict(zip(letters, r, strict=True))) for r in inc.tolist()]
    )
    assert outcome(lambda: c.cd_rows(inc, letters, model=spec)) == one_by_one


def test_cd_rows_take_one_column_flat_and_refuse_fractions() -> None:
    assert [k.text for k in c.cd_rows(np.array([3, -4]), "B")] == ["CD ,3", "CD ,-4"]
    assert [k.text for k in c.cd_rows(np.array([[2.0], [5.0]]), "A")] == ["CD 2", "CD 5"]
    with pytest.raises(InvalidArgument):
        c.cd_rows(np.array([0.5]), "A")
    with pytest.raises(InvalidArgument):
        c.cd_rows(np.zeros((3, 2)), "A")
    with pytest.raises(InvalidArgument):
        c.cd_rows(np.zeros((3, 2)), "AX")


def test_models_whose_cd_takes_no_dt_end_contour_with_dt_0_then_cd_0() -> None:
    old = get_model("DMC-18x2")
    assert [x.text for x in c.contour_end("AB", model=old)] == ["DT 0", "CD 0,0"]
    assert [x.text for x in c.contour_end("AB", model=M4040)] == ["CD 0,0=0"]
    assert c.cd_end("A", model=old).text == "CD 0"
    with pytest.raises(InvalidArgument, match="DT 3"):
        c.cd(100, dt=3, model=old)
    assert c.cd(100, model=old).text == "CD 100"


def test_a_stepped_speed_goes_out_at_or_just_beyond_its_step() -> None:
    # (rounded to four decimals, 4/3 * 83494 = 111325.33333... went out as 111325.3333: a
    # controller rounding down to its step stores the step below)
    assert c.jg(A=4 / 3 * 83_494).text == "JGA=111325.3334"
    assert c.jg(A=-4 / 3 * 83_494).text == "JGA=-111325.3334"
    assert c.sp(A=4 / 3 * 83_494).text == "SPA=111325.3334"
    assert c.ac(A=1024 * (1000 / 1500) ** 2 * 1001).text == "ACA=455566.2223"
    assert c.sp(A=25_000.5).text == "SPA=25000.5"  # four decimals hold it: as it is
    assert c.hv(A=4 / 3 * 83_494).text == "HVA=111325.3334"  # HV steps as SP does
    assert c.vs(4 / 3 * 83_494).text == "VSS=111325.3334"  # and VS, VA, VD (assumed)
    assert c.va(1024 * (1000 / 1500) ** 2 * 1001).text == "VAS=455566.2223"
    assert c.sp(A=25_000).text == "SPA=25000"
    assert c.pr(A=1000).text == "PRA=1000"


@pytest.mark.parametrize(
    ("line", "kind"),
    [
        ("ULIM=5", ReplyKind.ANY),
        ("ULIM", ReplyKind.ANY),
        ("DLY=3", ReplyKind.ANY),
        ("QDX=1", ReplyKind.ANY),
        ("QRX=2", ReplyKind.ANY),
        ("TPOS=1", ReplyKind.ANY),
        ("TP2[3]=0", ReplyKind.ANY),
        ("UL", ReplyKind.CTRL_Z),
        ("QU a[],0,3,1", ReplyKind.CTRL_Z),
        ("QR", ReplyKind.RECORD),
        ("QR ABC", ReplyKind.RECORD),
        ("TPA", ReplyKind.DATA),
        ("TPA=?", ReplyKind.DATA),
    ],
)
def test_a_variable_whose_name_begins_like_a_transfer_or_query_is_a_plain_command(
    line: str, kind: ReplyKind
) -> None:
    """``ULIM=5`` is an assignment, not ``UL`` (it waited for a ^Z that never came), and
    ``QRX=2`` no ``QR`` (a data record); ``DLY=3`` is not refused as a ``DL``."""
    assert parse_line(line).expect.kind is kind
