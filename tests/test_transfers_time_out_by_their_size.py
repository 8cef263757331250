"""Bulk transfers (``QU``, ``QD``, ``DL``, ``UL``, ``LV``) get a reply timeout that covers
their bytes at the link's byte rate (decision 0064): on a slow serial line they succeed where a
fixed 10 s failed, and a reply that never comes still times out, at the computed bound.

Over the simulator as a serial line in simulated time (``sim://DMC-4040?baud=...``), so a
transfer of a minute on the line takes milliseconds here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

import galil
from galil.errors import GalilTimeoutError
from galil.protocol import commands as cmds
from galil.routines import ul_reply_bytes
from galil.sim.faults import FaultHook
from galil.terminal import Terminal
from galil.testing import nothing_sent

OLD_LIMIT = 10.0  # the fixed reply timeout every transfer had


def _slow(baud: int, faults: FaultHook | None = None) -> galil.Controller:
    return galil.connect(f"sim://DMC-4040?baud={baud}", faults=faults)


@pytest.fixture
def line_9600() -> Iterator[galil.Controller]:
    with _slow(9600) as c:
        yield c


@pytest.fixture
def line_19200() -> Iterator[galil.Controller]:
    with _slow(19200) as c:
        yield c


def _program(lines: int) -> str:
    """A program of ``lines`` lines of about 70 characters each."""
    body = [f"v{i % 100}={i}*2+{'1' * 40};' filler line {i:04d}" for i in range(lines)]
    return "\n".join(["#MANY", *body[: lines - 2], "EN"])


def test_an_upload_of_1500_elements_at_9600_baud_takes_as_long_as_it_takes(
    line_9600: galil.Controller,
) -> None:
    c = line_9600
    values = -2_000_000_000 + np.arange(1500) * 7.25  # the widest numbers QU prints
    c.arrays.define("big", 1500)
    c.arrays.download("big", values)
    began = c.link.clock()
    got = c.arrays.upload("big")
    spent = c.link.clock() - began
    np.testing.assert_array_equal(got, values)
    assert spent > 2 * OLD_LIMIT  # 25 kB back at 960 B/s


def test_a_download_of_a_large_array_at_19200_baud_takes_as_long_as_it_takes(
    line_19200: galil.Controller,
) -> None:
    c = line_19200
    values = 1_234_567.5 + np.arange(3000)
    c.arrays.define("big", 3000)
    began = c.link.clock()
    c.arrays.download("big", values)
    assert c.link.clock() - began > OLD_LIMIT  # 30 kB out at 1,920 B/s
    np.testing.assert_array_equal(c.arrays.upload("big", 2990, 2999), values[2990:])


def test_a_program_of_hundreds_of_lines_goes_down_and_comes_back_at_19200_baud(
    line_19200: galil.Controller,
) -> None:
    c = line_19200
    program = _program(400)
    began = c.link.clock()
    assert c.programs.download(program).sent
    assert c.link.clock() - began > OLD_LIMIT
    began = c.link.clock()
    assert c.programs.upload() == program
    assert c.link.clock() - began > OLD_LIMIT
    assert not c.programs.download(program).sent  # read back (UL), found there already


def test_the_terminal_downloads_a_program_of_hundreds_of_lines_at_19200_baud(
    line_19200: galil.Controller,
) -> None:
    c = line_19200
    out: list[str] = []
    assert Terminal(c, write=out.append).download(_program(400).splitlines())
    assert out == ["downloaded 400 lines"]


def test_a_capture_of_thousands_of_samples_on_four_axes_uploads_at_19200_baud(
    line_19200: galil.Controller,
) -> None:
    c = line_19200
    sources = ["_RPA", "_RPB", "_RPC", "_RPD"]
    cap = c.capture(sources, every=2, count=3000)
    moves = [getattr(c, a).move_by(20_000 * (i + 1)) for i, a in enumerate("ABCD")]
    began = c.link.clock()
    rec = cap.wait()
    assert c.link.clock() - began > 4 * OLD_LIMIT  # ~6 s recording, ~18 s a source back
    assert len(rec) == 3000
    for i, (move, source) in enumerate(zip(moves, sources, strict=True)):
        move.wait()
        assert rec[source][-1] == 20_000 * (i + 1)


def test_a_list_of_hundreds_of_variables_at_9600_baud_comes_whole(
    line_9600: galil.Controller,
) -> None:
    c = line_9600
    for first in range(0, 300, 4):
        c.command(";".join(f"var{i}={i}.5" for i in range(first, first + 4)), allow_compound=True)
    began = c.link.clock()
    listed = c.variables.list()
    assert c.link.clock() - began > 5.0  # 300 lines of about 16 bytes at 960 B/s
    assert listed == {f"var{i}": i + 0.5 for i in range(300)}


def test_a_list_of_every_array_at_2400_baud_comes_whole() -> None:
    # LA had the link's ordinary timeout (1 s): 30 lines of 15 bytes take 1.9 s at 240 B/s
    with _slow(2400) as c:
        model = c.model
        size = model.array_elements // model.arrays
        names = [f"arrays{i:02d}" for i in range(model.arrays)]  # 8 letters, the longest
        for name in names:
            c.arrays.define(name, size)
        began = c.link.clock()
        listed = c.arrays.list()
        assert c.link.clock() - began > 1.5
        assert listed == dict.fromkeys(names, size)
        assert len(c.command("LA").splitlines()) == model.arrays  # as a raw command too
        assert "arrays29" in c.arrays  # (in: a listing)


def test_raw_transfers_get_the_timeout_of_their_size_as_the_rooms_do() -> None:
    # send(cmds.dl(...)) is the form docs/raw.md shows: no "no reply to 'DL' within 1 s"
    with _slow(2400) as c:
        program = ["#A", *[f"MG {i}" for i in range(200)], "EN"]
        assert c.send(cmds.dl(program)) == ""  # 1.4 kB out at 240 B/s
        assert len(c.command("UL").splitlines()) == 202  # and back
        assert len(c.exchange(cmds.ul()).text.splitlines()) == 202
        c.arrays.define("big", 300)
        c.send(cmds.qd("big", [-2_000_000_000.25] * 300))
        assert c.command("QU big[],0,299,1").count(",") >= 299  # 5 kB back
        assert c.send(cmds.qu("big")).count(",") >= 299  # (the whole array: its size unknown)
        for first in range(0, 40, 4):
            c.command(";".join(f"v{i}={i}.5" for i in range(first, first + 4)), allow_compound=True)
        assert len(c.command("LV").splitlines()) == 40
        with pytest.raises(GalilTimeoutError, match="within 1 s"):
            c.command("UL", timeout=1.0)  # a timeout given is the timeout


def test_a_raw_ls_of_a_long_program_at_9600_baud_gets_the_timeout_of_program_memory() -> None:
    # It failed with "no reply to 'LS' within 1 s" while the listing streamed in.
    with galil.connect("sim://DMC-4040?baud=9600", timeout=1.0) as c:
        c.programs.download("\n".join(["#A", *[f"v{i % 50}={i}" for i in range(300)], "EN"]))
        listing = c.command("LS").splitlines()
        assert listing[301] == "301 EN"  # numbered, to the program's last line

        assert c.command("LS #A,2").split() == ["0", "#A", "1", "v0=0", "2", "v1=1"]
        assert c.query_number("MG 3") == 3.0  # in step


def test_a_reply_cut_part_way_by_its_timeout_says_so_and_how_to_wait_longer() -> None:
    # (the link's 5 s let the resync wait out the rest of the 4 s listing)
    with galil.connect("sim://DMC-4040?baud=9600", timeout=5.0) as c:
        c.programs.download("\n".join(["#A", *[f"v{i % 50}={i}" for i in range(300)], "EN"]))
        with pytest.raises(GalilTimeoutError, match=r"'LS' was cut part way: \d+ bytes") as info:
            c.command("LS", timeout=1.0)  # (a timeout given is the timeout)
        assert "pass timeout=" in str(info.value)
        assert "no reply" not in str(info.value).splitlines()[0]
        assert c.query_number("MG 3") == 3.0  # resynchronised


class _Silence:
    """A fault hook that passes replies through until armed, then keeps ``keep`` bytes of
    what follows (0: the controller falls silent; more: a reply cut off)."""

    def __init__(self, keep: int = 0) -> None:
        self.armed = False
        self.keep = keep

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if not self.armed:
            return [(0.0, data)]
        piece, self.keep = data[: self.keep], max(0, self.keep - len(data))
        return [(0.0, piece)] if piece else []


def _armed_on(c: galil.Controller, silence: _Silence | _Trickle, prefix: bytes) -> list[float]:
    """Arm ``silence`` when a command beginning with ``prefix`` first goes out; [its time]."""
    sent: list[float] = []

    def arm(direction: str, data: bytes) -> None:
        if direction == "out" and data.startswith(prefix) and not sent:
            silence.armed = True
            sent.append(c.link.clock())

    c.wire_log.add(arm)
    return sent


def test_an_upload_never_answered_times_out_after_the_transfer_stall() -> None:
    # (not after its bound of 63 s: a transfer's reply begins as soon as its command is in)
    silence = _Silence()
    with _slow(9600, silence) as c:
        c.arrays.define("big", 1500)
        command = cmds.qu("big", 0, 1499, delim=1)
        bound = c.link.transfer_timeout(command, 17 * 1500 + 4)
        assert 2 * OLD_LIMIT < bound < 70.0  # 10 s, and twice 25 kB at 960 B/s
        assert c.link.transfer_stall == OLD_LIMIT
        sent = _armed_on(c, silence, b"QU")
        with pytest.raises(GalilTimeoutError, match="within 10 s of its bytes being on the"):
            c.arrays.upload("big")
        on_the_line = 2 * len(command.wire) / 960
        assert c.link.clock() - sent[0] == pytest.approx(OLD_LIMIT + on_the_line, abs=1e-6)
        silence.armed = False
        assert c.arrays.upload("big").size == 1500  # the link resynchronised


def test_an_upload_whose_reply_stops_part_way_times_out_after_the_transfer_stall() -> None:
    silence = _Silence(keep=5000)
    with _slow(9600, silence) as c:
        c.arrays.define("big", 1500)
        c.command("MG _VF")  # (the upload's VF check comes first: answered)
        sent = _armed_on(c, silence, b"QU")
        with pytest.raises(GalilTimeoutError, match="stopped part way: nothing for 10 s"):
            c.arrays.upload("big")
        # the 5,000 bytes take 5.2 s at 960 B/s; then 10 s of silence
        spent = c.link.clock() - sent[0]
        assert 5000 / 960 + OLD_LIMIT <= spent < 5000 / 960 + OLD_LIMIT + 0.1


def test_a_dead_controller_is_found_out_in_seconds_during_a_program_upload() -> None:
    # (UL's bound covers the whole program memory: about three minutes at 19200 baud)
    silence = _Silence()
    with _slow(19200, silence) as c:
        assert c.link.transfer_timeout(cmds.ul(), ul_reply_bytes(c.model)) > 100
        sent = _armed_on(c, silence, b"UL")
        with pytest.raises(GalilTimeoutError, match="'UL' within 10 s"):
            c.programs.upload()
        assert c.link.clock() - sent[0] < OLD_LIMIT + 0.1


class _Trickle:
    """A fault hook that, once armed, hands each reply out ``size`` bytes every ``every`` s:
    never silent for long, never done in time."""

    def __init__(self, size: int, every: float) -> None:
        self.armed = False
        self.size, self.every = size, every

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if not self.armed:
            return [(0.0, data)]
        cuts = range(0, len(data), self.size)
        return [((k + 1) * self.every, data[i : i + self.size]) for k, i in enumerate(cuts)]


def test_an_upload_that_trickles_times_out_at_its_computed_bound() -> None:
    trickle = _Trickle(size=200, every=5.0)  # 40 B/s, where the line carries 960
    with _slow(9600, trickle) as c:
        c.arrays.define("big", 1500)
        c.arrays.download("big", np.full(1500, -1e9))
        command = cmds.qu("big", 0, 1499, delim=1)
        bound = c.link.transfer_timeout(command, 17 * 1500 + 4)
        sent = _armed_on(c, trickle, b"QU")
        with pytest.raises(GalilTimeoutError, match=f"within {bound:g} s"):
            c.arrays.upload("big")
        assert c.link.clock() - sent[0] == pytest.approx(bound, abs=1e-6)


def test_a_download_that_is_never_answered_times_out_at_its_computed_bound() -> None:
    silence = _Silence()
    with _slow(19200, silence) as c:
        program = _program(400)
        download = cmds.dl(program, model=c.model)
        bound = c.link.transfer_timeout(download)
        assert OLD_LIMIT < bound < 50.0

        sent: list[float] = []

        def arm(direction: str, data: bytes) -> None:
            if direction == "out" and data.startswith(b"DL"):
                silence.armed = True
                sent.append(c.link.clock())

        c.wire_log.add(arm)
        with pytest.raises(GalilTimeoutError, match="'DL'"):
            c.programs.download(program)
        assert c.link.clock() - sent[0] == pytest.approx(bound, abs=1e-6)


def test_a_fast_link_keeps_the_least_transfer_timeout() -> None:
    with galil.connect("sim://DMC-4040") as c:  # the simulator without baud says no rate
        assert c.link.byte_rate is None
        assert c.link.transfer_timeout(cmds.ul(), 10**6) == OLD_LIMIT
    with galil.connect("sim://DMC-4040?baud=115200", timeout=30.0) as c:
        big = c.link.transfer_timeout(cmds.ul(), 11_520)
        assert big == pytest.approx(30.0 + 2 * (3 + 11_520) / 11_520)  # the link's own, on top


@pytest.mark.parametrize(
    "call",
    [
        lambda c: c.link.transfer("UL"),
        lambda c: c.link.transfer(cmds.ul(), -1),
        lambda c: c.link.transfer(cmds.ul(), 2.5),
        lambda c: c.link.transfer(cmds.ul(), True),
        lambda c: c.link.exchange(cmds.ul(), stall=0),
        lambda c: c.link.exchange(cmds.ul(), stall=float("nan")),
        lambda c: c.link.exchange(cmds.ul(), stall="10"),
    ],
)
def test_bad_transfer_arguments_are_refused_unsent(
    call: Callable[[galil.Controller], object],
) -> None:
    with (
        galil.connect("sim://DMC-4040") as c,
        nothing_sent(c),
        pytest.raises(galil.InvalidArgument),
    ):
        call(c)
