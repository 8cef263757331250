"""The servo loop's hooks look at the axes only while something is armed: arming it mid-run.

A room's per-step hook returns at once while nothing it watches is armed (no ``OE`` 1/3 axis,
no program with ``#POSERR``, no limit stop since it last looked). Each test here arms the thing
between two stretches of time, while the axes move, and checks that the event still comes at
its exact sample: the same run with its time in one advance and one servo sample at a time
gives the same bytes, and the event did happen (a hook skipped for good would lose it in
both runs; a horizon skipped would put it late in the one advance only).
"""

from __future__ import annotations

from collections.abc import Callable

from sim_scripts import TS, Script, play

from galil.sim.controller import SimController


def one_go_and_per_sample(script: Script, lag: float = 0.003) -> bytes:
    coarse = play(script, per_sample=False, lag=lag)
    assert b"?" not in coarse
    assert play(script, per_sample=True, lag=lag) == coarse
    return coarse


def last_reply(out: bytes) -> list[bytes]:
    """The fields of the last reply in ``out`` (before its ``:``)."""
    return out.rstrip(b":").rsplit(b":", 1)[-1].split()


def download(*lines: str) -> str:
    return "DL\r" + "\r".join(lines) + "\r\\"


STATE = "MG _MOA,_SCA,_TPA,_RPA,TIME"


def test_oe_1_set_mid_jog_turns_the_motor_off_at_the_sample_the_error_passes_er() -> None:
    # A slow jog keeps the servo lag's error under ER; OE 1 comes while it runs, then a
    # faster jog makes the error pass ER inside the next stretch.
    out = one_go_and_per_sample(["ER 40;JG 2000;BG A", 300, "OE 1", 100, "JG 40000", 600, STATE])
    assert last_reply(out)[:2] == [b"1.0000", b"8.0000"]  # _MOA, _SCA


def test_a_program_with_poserr_started_mid_jog_runs_it_at_its_first_sample() -> None:
    # The error is beyond ER before any program runs (nothing to do then); XQ arms #POSERR.
    out = one_go_and_per_sample(
        [
            "ER 40;JG 40000;BG A",
            download("#M", "WT 500", "EN", "#POSERR", 'MG "E",TIME,_TEA', "RE"),
            300,
            "XQ #M",
            400,
            STATE,
        ]
    )
    assert out.count(b"E ") == 1


def test_a_second_limit_stop_runs_limswi_again() -> None:
    # The first stop is seen and the axis leaves the limit; the second must be seen too.
    out = one_go_and_per_sample(
        [
            download(
                "#M",
                "n=0;FL 1500",
                "JG 8000;BG A",
                "AM A",
                "PA 0;BG A",
                "AM A",
                "JG 8000;BG A",
                "AM A",
                "EN",
                "#LIMSWI",
                "n=n+1;t=TIME",
                'MG "L",n,t',
                "RE 1",
            ),
            "XQ #M",
            2000,
            "MG n",
            STATE,
        ]
    )
    assert out.count(b"L ") == 2


def test_mc_times_out_tw_after_the_profile_ended_while_another_axis_jogs() -> None:
    # Trippoints' service notes the sample each profile ends (MC's timeout counts from it)
    # by comparing the axes' moving flags at every step: B jogs throughout, A's move ends.
    out = one_go_and_per_sample(
        [
            download(
                "#M",
                "TW 20",
                "PR 1000;BG A",
                "AM A",
                "a=TIME",
                "MC A",
                "EN",
                "#MCTIME",
                "t=TIME;s=_SCA",
                "EN",
            ),
            "JG ,3000;BG B",
            50,
            "XQ #M",
            1000,
            "MG a,t,s,_BGB",
        ],
        lag=0.05,  # the motor is still 20 ms behind when the profile ends
    )
    ended, timed_out, stop_code, b_moving = (float(v) for v in last_reply(out))
    assert timed_out - ended == 20  # TW 20: 20 samples, TW is not scaled by TM (0042)
    assert (stop_code, b_moving) == (99, 1)


def test_er_minus_one_disables_poserr_and_off_on_error() -> None:
    # DMC-41x3 reference, ER: "n=-1 disables Error output": with ER -1 no error is beyond
    # ER, so neither #POSERR nor OE 1 acts, however large the servo lag's error.
    sim = SimController("DMC-4143", servo_lag=0.003)
    out = b""
    for line in (
        "OE 1;ER -1;JG 40000;BG A",
        download("#M", "WT 500", "EN", "#POSERR", 'MG "E",TIME,_TEA', "RE"),
        "XQ #M",
    ):
        out += sim.feed(line.encode() + b"\r")
    sim.advance(400 * TS)
    out += sim.feed(b"MG _MOA,_SCA,_TEA,_TSA\r") + sim.poll()
    assert b"E " not in out
    mo, sc, te, ts = (float(v) for v in last_reply(out))
    assert (mo, sc) == (0.0, 0.0)  # the motor on, the jog running
    assert abs(te) > 0  # a real position error, beyond any ER >= 0
    assert not int(ts) & 64  # TS bit 6 (error beyond ER) never set with ER -1


def _switches(forward: int, reverse: int) -> Callable[[SimController], None]:
    return lambda sim: sim.place_limit_switches("A", forward=forward, reverse=reverse)


def test_ld_2_leaves_the_forward_switch_watched_and_a_jog_stops_at_its_sample() -> None:
    # Only the reverse switch is disabled: the forward one must still end a step at the
    # sample the axis enters it, in one advance as sample by sample.
    out = one_go_and_per_sample(
        [_switches(3000, -3000), "LDA=2;JG 20000;BG A", 400, "MG _SCA,_RPA,TIME"]
    )
    assert last_reply(out)[0] == b"2.0000"


def test_ld_1_runs_through_a_placed_switch_to_the_soft_limit_at_its_sample() -> None:
    # The disabled forward switch is passed by (no watch ends a step there); FL, which LD
    # leaves on, stops the jog at its sample; LD 0 set mid-run then watches the switch again
    # for the jog back out and in.
    out = one_go_and_per_sample(
        [
            _switches(3000, -3000),
            "LDA=1;FLA=9000;JG 20000;BG A",
            700,
            "MG _SCA,_RPA,TIME",
            "LDA=0;PAA=0;BG A",
            700,
            "JG 20000;BG A",
            700,
            STATE,
        ]
    )
    assert b" 2.0000 " in out  # the soft limit's stop
    assert last_reply(out)[1] == b"2.0000"  # _SCA: the switch, enabled again, stopped it
    assert float(last_reply(out)[2]) < 9000
