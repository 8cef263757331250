"""AS, MF and MR on ``sim://``, and the units of WT and TW (decision 0042).

Programs are downloaded and run with ``dmc.programs``; the simulated clock passes only while
the test waits, so a ``TIME`` a program records is the exact servo sample. At TM 1000 a sample
is 1/1024 s; the default AC and DC are 256,000 counts/s², so a ramp to 10,000 counts/s takes
10000 / 256000 s = 40 samples.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from program_helpers import drain_messages, run_program

import galil
from galil.testing import sim_of, simulated


@pytest.fixture
def dmc() -> Iterator[galil.Controller]:
    with simulated() as controller:
        yield controller


# ---- AS ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("tm", "samples"), [(1000, 40), (500, 80)])
def test_as_goes_on_at_the_sample_the_trapezoid_reaches_its_slew_speed(
    dmc: galil.Controller, tm: int, samples: int
) -> None:
    # AS is "Scaled By TM": SP and AC stay in counts/s and counts/s², so the ramp lasts
    # 0.039 s at any TM, twice as many samples at TM 500. _RPA is the ramp's 1/2 a t².
    program = f"#M\nTM {tm}\nSP 10000;PR 100000\nt0=TIME\nBG A\nAS A\nMG TIME-t0,_RPA\nST A\nEN"
    assert run_program(dmc, program) == [f"{samples}.0000 195.0000"]


def test_as_in_a_triangle_goes_on_where_the_speed_begins_to_fall(
    dmc: galil.Controller,
) -> None:
    # "If the speed is not reached, the trippoint will be triggered after the speed begins
    # diverging from the AS value": a 1000-count move never reaches SP 100000; it peaks
    # half-way, at 500 counts.
    program = "#M\nSP 100000;PR 1000\nt0=TIME\nBG A\nAS A\nMG TIME-t0,_RPA\nAM A\nMG TIME-t0\nEN"
    assert run_program(dmc, program) == ["64.0000 500.0000", "128.0000"]


def test_as_goes_on_once_a_jog_has_slowed_to_its_new_speed(dmc: galil.Controller) -> None:
    # "The AS command will operate after either accelerating or decelerating."
    program = "#M\nJG 20000;BG A\nAS A\nt0=TIME\nJG 10000\nAS A\nMG TIME-t0\nST A\nEN"
    assert run_program(dmc, program) == ["40.0000"]


def test_as_s_waits_for_the_path_speed_and_as_of_axes_at_rest_goes_on_at_once(
    dmc: galil.Controller,
) -> None:
    program = (
        "#M\nt0=TIME\nAS\nAS BC\nMG TIME-t0\n"
        "VM AB;VP 100000,0;VE;VS 10000\nt0=TIME;BG S\nAS S\nMG TIME-t0\nST S\nEN"
    )
    assert run_program(dmc, program) == ["0.0000", "40.0000"]


def test_as_of_an_axis_and_a_plane_waits_for_both(dmc: galil.Controller) -> None:
    # A reaches SP 20000 in 80 samples, the S path VS 10000 in 40.
    program = (
        "#M\nVM BC;VP 100000,0;VE;VS 10000;SP 20000;PR 100000\n"
        "t0=TIME;BG S;BG A\nAS SA\nMG TIME-t0\nST S;ST A\nEN"
    )
    assert run_program(dmc, program) == ["80.0000"]


# ---- MF and MR --------------------------------------------------------------------------
# JG 1000 is under one count a sample: the encoder passes every count, so the one it shows
# when the trippoint goes on tells the sample (one earlier shows 199, one later 201).
def test_mf_goes_on_at_the_sample_the_encoder_gets_to_the_position_moving_forward(
    dmc: galil.Controller,
) -> None:
    assert run_program(dmc, "#M\nJG 1000;BG A\nMF 200\nMG _TPA\nST A\nEN") == ["200.0000"]


def test_mr_goes_on_at_the_sample_the_encoder_gets_to_the_position_moving_back(
    dmc: galil.Controller,
) -> None:
    program = "#M\nJG ,-1000;BG B\nMRB=-200\nMG _TPB\nST B\nEN"
    assert run_program(dmc, program) == ["-200.0000"]


@pytest.mark.parametrize(
    ("wait", "turn", "start", "speed"),
    [("MF 200", "MR 0", 500, -2000), ("MR -200", "MF 0", -500, 2000)],
    ids=["MF", "MR"],
)
def test_a_crossing_the_other_way_does_not_count_only_the_one_back(
    dmc: galil.Controller, wait: str, turn: str, start: int, speed: int
) -> None:
    # The axis passes the position the wrong way first; thread 1 turns it round once it is
    # well past (at 0), and the trippoint goes on when it comes back across.
    program = (
        f"#M\nDP {start};JG {speed};BG A\nt1=-1\nXQ #B,1\n{wait}\nMG _TPA,t1>0,TIME>t1\n"
        f"ST A\nEN\n#B\n{turn}\nt1=TIME\nJG {-speed}\nEN"
    )
    assert run_program(dmc, program) == [f"{-200 * speed // abs(speed)}.0000 1.0000 1.0000"]


def test_mf_on_several_axes_goes_on_when_the_first_crosses(dmc: galil.Controller) -> None:
    # "Although multiple positions can be specified, only one of the MF conditions must be
    # satisfied": A does not move, B crosses.
    program = "#M\nJG ,1000;BG B\nMF 200,200\nMG _TPA,_TPB\nST B\nEN"
    assert run_program(dmc, program) == ["0.0000 200.0000"]


def test_mf_waits_on_after_a_move_that_ends_short_of_the_position(
    dmc: galil.Controller,
) -> None:
    # MF watches the encoder only (no "profiling complete" clause, unlike AP).
    dmc.programs.download('#M\nPR 100;BG A\nMF 200\nMG "crossed"\nEN')
    dmc.programs.run("#M", thread=0)
    dmc.sleep(0.5)
    assert 0 in dmc.programs.threads
    assert dmc.query_number("MG _TPA") == 100
    dmc.programs.halt()
    assert drain_messages(dmc) == []


@pytest.mark.parametrize(
    ("line", "code"),
    [("MF 2147483648", 6), ("MR ,-2147483649", 6), ("MF", 4), ("AS E", 4)],
)
def test_a_bad_argument_halts_the_thread_with_its_tc(
    dmc: galil.Controller, line: str, code: int
) -> None:
    lines = run_program(dmc, f'#M\nJG 1000;BG A\n{line}\nMG "after"\nEN')
    assert lines == []
    assert dmc.query_numbers("MG _TC,_ED") == [float(code), 2.0]
    dmc.command("ST A")


# ---- the units of WT and TW -------------------------------------------------------------
@pytest.mark.parametrize(("tm", "samples"), [(1000, 103), (500, 205), (250, 410)])
def test_wt_counts_milliseconds_of_real_time_at_any_tm(
    dmc: galil.Controller, tm: int, samples: int
) -> None:
    """WT is "Scaled By TM" (WT's entry; TM's list of automatically scaled commands), and
    Galil's "Time based commands on Accelera motion controllers" (2009): "With the default
    TM1000, a WT100 will give a wait time of 100msec. Changing to a TM500, the WT100 will
    still give a wait time of 100msec." A sample is TM / 1,024,000 s ("TM 1000 will actually
    set an update rate of 976 microseconds"): 100 ms is 102.4 samples at TM 1000, rounded up.
    """
    program = f"#M\nTM {tm}\nt0=TIME\nWT 100\nMG TIME-t0\nEN"
    assert run_program(dmc, program) == [f"{samples}.0000"]


@pytest.mark.parametrize("tm", [1000, 500])
def test_tw_counts_servo_samples_at_any_tm(dmc: galil.Controller, tm: int) -> None:
    """TW is on TM's list of commands "NOT automatically scaled", and the same 2009 note
    says: "With the default TM1000, a TW100 will wait 100 samples (roughly 100msec) after
    motion before calling #MCTIME. Changing to a TM500, a TW100 will still wait 100
    samples (roughly 50msec)"."""
    sim_of(dmc).set_servo_lag(0.05, "A")  # the motor is far behind when the profile ends
    program = (
        f"#M\nTM {tm}\nTW 20\nPR 1000;BG A\nAM A\na=TIME\nMC A\nEN\n#MCTIME\nMG TIME-a,_SCA\nEN"
    )
    assert run_program(dmc, program) == ["20.0000 99.0000"]
