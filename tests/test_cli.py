"""The ``galil`` console command, run as a user would."""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

import galil
from galil import cli
from galil.errors import GalilConnectionError, InvalidArgument
from galil.sim import server as sim_server
from galil.sim.server import SimTcpServer

GALIL = [sys.executable, "-m", "galil.cli"]

Spawn = Callable[..., subprocess.Popen[str]]  # the `spawn` fixture of tests/conftest.py


def test_plan_prints_the_profile_and_saves_a_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "plan.png"
    assert (
        cli.main(["plan", "10000", "--speed", "25000", "--accel", "256000", "--png", str(png)]) == 0
    )
    out = capsys.readouterr().out
    assert "trapezoid" in out
    assert "0 → 10000 counts" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plan_refuses_an_out_of_range_speed(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["plan", "10000", "--speed", "1e12"]) == 2
    assert "SP" in capsys.readouterr().err


def test_info_describes_a_simulated_controller(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["info", "sim://DMC-4040"]) == 0
    out = capsys.readouterr().out
    assert "DMC4040" in out
    assert "axes: A, B, C, D" in out


def test_output_into_a_closed_pipe_ends_quietly_with_the_shells_status() -> None:
    # `galil info ... | head -1`: the reader has gone before the output is written.
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        run = subprocess.run(
            [*GALIL, "info", "sim://DMC-4040"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write_end)
    assert run.returncode == 141
    assert run.stderr == ""


def test_terminal_sends_lines_and_explains_rejections() -> None:
    run = subprocess.run(
        [*GALIL, "terminal", "sim://DMC-4040"],
        input="MG 1+2\nbg\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 1, run.stderr  # piped: a refused line makes the status 1
    assert "3.0000" in run.stdout
    assert "? 1 Unrecognized command" in run.stdout


def test_sim_serves_tcp_until_interrupted(spawn: Spawn) -> None:
    proc = spawn(
        [*GALIL, "sim", "--model", "DMC-4040", "--tcp", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        match = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
        assert match, line
        with socket.create_connection(("127.0.0.1", int(match.group(1))), timeout=10) as s:
            s.sendall(b"MG 6*7\r")
            reply = b""
            while not reply.endswith(b":"):
                chunk = s.recv(64)
                assert chunk
                reply += chunk
        assert reply.strip() == b"42.0000\r\n:".strip()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    assert proc.returncode in (0, 130, -signal.SIGINT)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty")
def test_sim_serves_a_pty_until_interrupted(spawn: Spawn) -> None:
    import serial

    proc = spawn(
        [*GALIL, "sim", "--pty"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        match = re.search(r"(/dev/\S+)", line)
        assert match, line
        port = serial.Serial(match.group(1), timeout=10)
        try:
            port.write(b"MG 6*7\r")
            assert port.read_until(b":").strip() == b"42.0000\r\n:".strip()
        finally:
            port.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty")
def test_sim_on_a_pty_at_a_baud_rate_carries_bytes_no_faster_than_that_line(
    spawn: Spawn,
) -> None:
    import time

    import serial

    proc = spawn(
        [*GALIL, "sim", "--pty", "--baud", "9600"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        match = re.search(r"(/dev/\S+)", proc.stdout.readline())
        assert match
        port = serial.Serial(match.group(1), timeout=10)
        try:
            port.write(b"MG 1\r")  # the line is up
            assert port.read_until(b":").strip().endswith(b":")
            lines = b"MG 2\r" * 20  # 100 bytes out, 20 replies of 10 bytes back
            start = time.monotonic()
            port.write(lines)
            replies = b"".join(port.read_until(b":") for _ in range(20))
            took = time.monotonic() - start
        finally:
            port.close()
        assert replies.count(b"2.0000") == 20
        # 9600 baud is 960 bytes a second each way (full duplex): the replies alone take that
        assert took >= 0.9 * len(replies) / 960
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)


def test_sim_stops_cleanly_on_sigterm(spawn: Spawn) -> None:
    proc = spawn(
        [*GALIL, "sim", "--tcp", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert "tcp://127.0.0.1:" in proc.stdout.readline()
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err


def test_python_m_galil_is_the_galil_command() -> None:
    run = subprocess.run(
        [sys.executable, "-m", "galil", "--version"], capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == f"galil {galil.__version__}"


def _parsers() -> list[argparse.ArgumentParser]:
    parser = cli.build_parser()
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return [parser, *subs[0].choices.values()]


def test_every_option_has_help_and_no_markup_shows() -> None:
    for parser in _parsers():
        for action in parser._actions:
            assert action.help, f"{parser.prog}: {action.option_strings or action.dest} has no help"
        text = parser.format_help()
        for markup in ("``", ":class:", ":meth:", ":func:", ".. "):
            assert markup not in text, f"{parser.prog} --help shows {markup!r}"


def test_plan_takes_units_with_a_scale(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["plan", "12.5mm", "--speed", "20mm/s", "--accel", "200mm/s^2", "--scale", "2000/mm"]
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "0 → 12.5 mm (0 → 25000 counts)" in out
    assert "peak speed 20 mm/s" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["-12.5mm", "--scale", "2000/mm"],
        ["--scale", "2000/mm", "-12.5mm"],
        ["--scale", "2000/mm", "--speed", "20mm/s", "-12.5mm"],
    ],
)
def test_plan_takes_a_negative_distance_with_units(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: "the following arguments are required: distance" (argparse took -12.5mm for an
    # option), with or without `--` before it.
    assert cli.main(["plan", *argv]) == 0
    assert "0 → -12.5 mm (0 → -25000 counts)" in capsys.readouterr().out
    (plan,) = [p for p in _parsers() if p.prog == "galil plan"]
    assert "galil plan -12.5mm --scale 2000/mm" in " ".join(plan.format_help().split())


def test_plan_refuses_units_without_a_scale(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["plan", "12.5mm"]) == 2
    assert "scale" in capsys.readouterr().err
    assert cli.main(["plan", "1.5", "--scale", "2000/mm"]) == 2
    assert "not a whole number" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["12.5mm"], "the distance 12.5mm has units but there is no --scale"),
        (["100", "--speed", "20mm/s"], "--speed 20mm/s has units but there is no --scale"),
        (["100", "--decel", "2mm/s^2"], "--decel 2mm/s^2 has units but there is no --scale"),
        (["1.5", "--scale", "2000/mm"], "(plain numbers are counts: write 1.5mm)"),
    ],
)
def test_plan_says_which_option_to_give_not_a_python_call(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # A person at a shell has no axis to call set_scale on: the message names --scale.
    assert cli.main(["plan", *argv]) == 2
    err = capsys.readouterr().err
    assert says in err, err
    assert "set_scale" not in err


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "--tcp", "127.0.0.1:70000"],
        ["sim", "--tcp", "127.0.0.1:port"],
        ["sim", "--message-port", "70000"],
        ["sim", "--message-port", "-2"],
    ],
)
def test_sim_refuses_a_port_out_of_range_in_one_line(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("galil: ")
    assert "port" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv",
    [
        ["--tcp", "127.0.0.1:70000"],
        ["--tcp", "127.0.0.1:port"],
        ["--message-port", "70000"],
        ["--message-port", "-2"],
    ],
)
def test_the_sim_modules_entry_point_checks_ports_as_the_cli_does(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    # `python -m galil.sim.server`: a usage error (exit 2), not an OverflowError from bind().
    with pytest.raises(SystemExit) as exit_:
        sim_server.main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "galil sim: error: --" in err
    assert "port" in err
    with pytest.raises(InvalidArgument, match=r"must be 0\.\.65535"):
        sim_server.SimTcpServer(port=70000)


@pytest.mark.parametrize("option", ["--tcp", "--message-port"])
@pytest.mark.parametrize("entry", ["module", "cli"])
def test_sim_on_a_port_in_use_is_one_line_and_status_2(
    option: str, entry: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # `python -m galil.sim.server` and `galil sim` on a taken port: no OSError traceback.
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        argv = [f"--tcp=127.0.0.1:{port}"] if option == "--tcp" else [f"--message-port={port}"]
        status = sim_server.main(argv) if entry == "module" else cli.main(["sim", *argv])
    assert status == 2
    err = capsys.readouterr().err
    which = "command" if option == "--tcp" else "message"
    assert err.startswith(f"galil sim: error: cannot serve the {which} port on 127.0.0.1:{port}: ")
    assert "(port 0 picks a free one)" in err
    assert err.count("\n") == 1
    assert "Traceback" not in err


def test_a_sim_server_that_cannot_have_its_port_says_which_and_closes_the_rest() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        free = probe.getsockname()[1]
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        server = sim_server.SimTcpServer(port=free, message_port=port)
        with pytest.raises(GalilConnectionError, match=f"message port on 127.0.0.1:{port}"):
            server.start()
    # The command port (TCP and UDP), bound before the message port failed, was let go.
    with sim_server.SimTcpServer(port=free) as again:
        assert again.address == ("127.0.0.1", free)


@pytest.mark.parametrize(
    "address",
    [
        "tcp://[::1",
        "tcp://127.0.0.1:1?connect_timeout=abc",
        "usb://1079:4040?interface=abc",
        "pci:///dev/null?write_timeout=abc",
        "loop://?bogus=1",
        "300.300.300.300:23",
    ],
)
def test_info_reports_a_bad_address_in_one_line(
    address: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["info", address]) == 2
    err = capsys.readouterr().err
    assert err.startswith("galil: ")
    assert err.count("\n") == 1


def test_ul_of_an_empty_program_saves_an_empty_file_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saved = tmp_path / "saved.dmc"
    assert cli.main(["ul", "sim://DMC-4040", str(saved)]) == 0  # a new controller: no program
    assert saved.read_text() == ""  # before: one empty line, "1 lines saved"
    assert capsys.readouterr().err == f"no program saved to {saved}\n"
    assert cli.main(["ul", "sim://DMC-4040"]) == 0
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == "no program in the controller's memory\n"


def test_dl_refuses_a_program_bigger_than_the_models_memory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "big.dmc"
    source.write_text("#A\n" + "MG 1\n" * 2000 + "EN\n")  # a DMC-4040 holds 2000 lines
    assert cli.main(["dl", str(source), "sim://DMC-4040"]) == 2  # before: "downloaded"
    assert capsys.readouterr().out == (
        "not sent: the program has 2002 lines; DMC-4040 holds 2000\n"
    )


def _usage(text: str) -> str:
    """The usage block at the top of an argparse help or error text."""
    return text.split("\n\n")[0].split("\ngalil sim: error:")[0].strip()


def test_sim_help_and_its_errors_show_one_usage_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as helped:
        cli.main(["sim", "--help"])
    assert helped.value.code == 0
    help_text = capsys.readouterr().out
    with pytest.raises(SystemExit) as refused:
        cli.main(["sim", "--bogus"])
    assert refused.value.code == 2
    error = capsys.readouterr().err
    assert "galil sim: error: unrecognized arguments: --bogus" in error
    assert _usage(help_text) == _usage(error)
    assert "[--tcp HOST:PORT | --pty]" in _usage(help_text)  # one or the other


def test_sim_help_says_where_it_serves_without_tcp_or_pty(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        cli.main(["sim", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "With neither --tcp nor --pty it serves TCP on 127.0.0.1 on a free port" in text
    for action in sim_server.options()._actions:
        assert action.help, f"galil sim: {action.option_strings} has no help"


def test_plan_refuses_a_model_with_no_axes(capsys: pytest.CaptureFixture[str]) -> None:
    # As the library's RIO refuses a move: an I/O unit has no profile to print.
    assert cli.main(["plan", "1000", "--model", "RIO-47100"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == "galil: RIO-47100 is an I/O controller with no axes: it has no motion to plan\n"


@pytest.mark.parametrize("command", [["plan", "10000"], ["demo"]])
@pytest.mark.parametrize(
    ("name", "what"), [("plot.xyz", "an unknown format 'xyz'"), ("plot", "no extension")]
)
def test_a_plot_file_of_no_known_format_is_refused_in_one_line_before_anything_runs(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: list[str],
    name: str,
    what: str,
) -> None:
    # Before: the plan was printed (the demo run) and then matplotlib's traceback came.
    png = tmp_path / name
    assert cli.main([*command, "--png", str(png)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith(f"galil: --png {str(png)!r} has {what}: name the file with one of ")
    assert ".png, " in err
    assert err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ["10000", "--speed", "1"],
            "galil: SP 1 counts/s is less than one step, the smallest speed above 0 (2 counts/s "
            "at TM 1000): it would be SP 0, and a move at SP 0 is refused\n",
        ),
        (
            ["1mm", "--scale", "2000/mm", "--speed", "0.0004mm/s"],
            "galil: SP 0.8 counts/s is less than one step, the smallest speed above 0 (2 "
            "counts/s at TM 1000): it would be SP 0, and a move at SP 0 is refused (in user "
            "units: the smallest is 0.001 mm / s, you gave 0.0004 mm / s)\n",
        ),
    ],
)
def test_plan_refuses_a_speed_under_one_step_as_the_python_api_does(
    capsys: pytest.CaptureFixture[str], argv: list[str], said: str
) -> None:
    # (before: "speed must be a positive number, got 0.0")
    assert cli.main(["plan", *argv]) == 2
    assert capsys.readouterr().err == said
    with (  # (the Python API's refusal, which the CLI's now is)
        galil.connect("sim://DMC-4040") as dmc,
        pytest.raises(galil.LimitError, match="less than one step") as info,
    ):
        dmc.A.speed = 1
    assert info.value.floor


@pytest.mark.parametrize(
    ("argv", "note"),
    [
        (
            ["10000", "--accel", "100"],
            "note: --accel 100 counts/s^2: the controller stores AC and DC 1024 counts/s^2 (in "
            "its steps, and its range, on DMC-4040); the plan uses that",
        ),
        (
            ["10000", "--speed", "2001"],
            "note: --speed 2001 counts/s: the controller stores SP 2000 counts/s (in its steps, "
            "and its range, on DMC-4040); the plan uses that",
        ),
        (
            ["12.5mm", "--scale", "2000/mm", "--speed", "20mm/s", "--accel", "200mm/s^2"],
            "note: --accel 200mm/s^2 (400000 counts/s^2): the controller stores AC and DC "
            "399360 counts/s^2 (in its steps, and its range, on DMC-4040); the plan uses that",
        ),
    ],
)
def test_plan_says_a_value_the_controller_stores_otherwise_and_plans_with_it(
    capsys: pytest.CaptureFixture[str], argv: list[str], note: str
) -> None:
    # (before: --accel 100 became AC 1024 without a word)
    assert cli.main(["plan", *argv]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == note
    assert lines[1].startswith("Profile: ")


def test_plan_says_nothing_more_when_every_value_is_stored_as_given(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert cli.main(["plan", "10000", "--speed", "25000", "--accel", "256000"]) == 0
    assert capsys.readouterr().out.startswith("Profile: ")


@pytest.mark.parametrize(
    ("scale", "said"),
    [
        ("2000", "galil: --scale 2000: give counts per unit, e.g. --scale 2000/mm or --scale "
         "4096/deg\n"),
        ("-2000/mm", "galil: --scale -2000/mm: the counts per unit must be positive and finite, "
         "e.g. --scale 2000/mm or --scale 4096/deg (for an axis whose positive direction is the "
         "motor's negative one, give the distance with the opposite sign)\n"),
        ("2000/s", "galil: --scale 2000/s: give counts per a length or an angle, e.g. --scale "
         "2000/mm or --scale 4096/deg\n"),
    ],
)  # fmt: skip
def test_plan_says_what_scale_takes_in_the_clis_words(
    capsys: pytest.CaptureFixture[str], scale: str, said: str
) -> None:
    # (before: "counts_per must be a Quantity such as 2000 / ureg.mm", "sign=-1", "<Quantity")
    assert cli.main(["plan", "1mm", "--scale", scale]) == 2
    assert capsys.readouterr().err == said


def test_plan_shows_the_unit_the_distance_was_given_in(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["plan", "1in", "--scale", "2000/mm", "--speed", "1in/s", "--accel", "8in/s^2"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out  # (before: "0 → 25.4 mm", "peak speed 25.4 mm/s")
    assert "start → end 0 → 1 in (0 → 50800 counts)" in out
    assert "peak speed 1 in/s (50800 counts/s)" in out


def test_dl_names_another_sessions_watchdog_and_says_what_a_cli_user_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "p.dmc"
    source.write_text("#B\nMG 2\nEN\n")
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as other:
        other.programs.download("#A\nWT 60000\nEN")
        dog = other.watchdog(5.0)  # thread 7, in another session than galil dl's
        other.programs.run("#A", thread=0)
        assert cli.main(["dl", str(source), server.url]) == 2
        out = capsys.readouterr().out
        dog.stop()
        other.programs.halt(0)
    # Before: "thread 0, thread 7 are running ...; halt thread(s) [0, 7]
    # (controller.programs.halt(n), or HX n) first": thread 7 is the other session's watchdog.
    assert out == (
        "not sent: thread 0, thread 7 (the library's #GWDOG: the watchdog) are running: the "
        "controller refuses DL while a program runs (TC 17) and would then run the program's "
        "lines as commands; halt it first (HX0); stop the watchdog in the program that started "
        "it (HX7 would end it unseen, and leave its motion unguarded)\n"
    )


def test_ul_leaves_out_the_librarys_routines_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    saved = tmp_path / "saved.dmc"
    with SimTcpServer(model="DMC-4040") as server, galil.connect(server.url) as other:
        other.programs.download("#A\nMG 1\nEN")
        dog = other.watchdog(5.0)  # (its routine goes into program memory, after #A)
        assert cli.main(["ul", server.url, str(saved)]) == 0
        dog.stop()
    # Before: the file held the library's block too, which a galil dl would send as yours.
    assert saved.read_text() == "#A\nMG 1\nEN\n"
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("(left out: the library's routines #GWDOG, the ")
    assert err[0].endswith(
        ' lines from its marker line "\'galil library" on; they are not part of your program)'
    )
    assert err[1] == f"3 lines saved to {saved}"


@pytest.mark.parametrize(
    ("data", "said"),
    [
        (b'#A\nMG "caf\xc3\xa9"\nEN\n', "line 2: character 'é' (U+00E9) cannot be downloaded"),
        (b'#A\n\nMG "caf\xe9"\nEN\n', "line 3: byte 0xe9 is not text"),  # (latin-1, blank line 2)
    ],
)
def test_dl_names_the_character_or_byte_it_cannot_download_and_its_line_in_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: bytes, said: str
) -> None:
    source = tmp_path / "p.dmc"
    source.write_bytes(data)
    assert cli.main(["dl", str(source), "sim://DMC-4040"]) == 2
    out, err = capsys.readouterr()
    # (before: "DL line 2: character '\ufffd' cannot be downloaded", the replacement character)
    assert err == f"galil: {source} {said}; a program is ASCII\n"
    assert out == ""
