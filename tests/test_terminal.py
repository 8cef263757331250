"""``galil terminal``: what a person types, through a real pseudo-terminal and in-process."""

from __future__ import annotations

import math
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from program_helpers import wait_for_motion

import galil
from galil import cli
from galil.errors import InvalidArgument
from galil.sim.clock import RealTimeClock
from galil.sim.server import SimPtyServer, SimTcpServer
from galil.terminal import _PROGRAM_ONLY_HINT, Terminal, program_lines
from galil.testing import nothing_sent, simulated

Spawn = Callable[..., subprocess.Popen[str]]

PROGRAM = ["#A", "WT 100", 'MG "hello"', "EN"]


# ----------------------------------------------------------------------------------- in-process


@pytest.fixture
def term() -> Iterator[tuple[Terminal, list[str]]]:
    with galil.connect("sim://DMC-4040") as dmc:
        out: list[str] = []
        dmc.subscribe(out.append)
        yield Terminal(dmc, write=out.append, timeout=1.0), out


def test_compound_lines_pass_through_and_replies_print(term: tuple[Terminal, list[str]]) -> None:
    t, out = term
    t.feed("PRA=1000;BGA")
    wait_for_motion(t.controller)
    t.feed("MG _RPA;MG 6*7")
    assert out == [" 1000.0000", " 42.0000"]


def test_a_rejected_line_is_explained_and_the_session_goes_on(
    term: tuple[Terminal, list[str]],
) -> None:
    t, out = term
    t.feed("bg")
    t.feed("PRA=10;BGX")
    t.feed("MG 1+2")
    assert out[:2] == [
        "? 1 Unrecognized command",
        "  (Galil commands and operands are upper case: did you mean 'BG'?)",
    ]
    assert out[2].startswith("? ")
    assert out[3] == "  (refused: 'BGX')"
    assert out[-1] == " 3.0000"


def test_a_typed_download_is_sent_as_one_dl_and_its_program_runs(
    term: tuple[Terminal, list[str]],
) -> None:
    t, out = term
    t.feed("DL")
    assert t.downloading
    assert t.prompt == "DL> "
    t.feed("\n".join(PROGRAM))  # pasted: several lines at once
    t.feed("\\")
    assert not t.downloading
    assert out[-1] == "downloaded 4 lines"
    t.feed("XQ #A")
    t.controller.sleep(0.2)
    t.feed("MG 0")  # on this link the message comes with the next reply
    assert "hello" in out[-2:]
    t.feed("UL")
    assert out[-4:] == PROGRAM


def test_a_timeout_says_so_and_the_next_command_works(term: tuple[Terminal, list[str]]) -> None:
    t, out = term
    t.timeout = 0.1
    t.feed("BV")  # BV answers when the burn ends (0.25 s), after the timeout
    assert out[-1].startswith("timeout: ")
    t.feed("MG 1")  # resynchronises first (once BV has answered), then sends
    assert out[-1] == " 1.0000"
    t.feed("JGA=1000;BGA")
    t.interrupt()
    assert out[-1].startswith("Ctrl-C: sent ST")
    t.controller.sleep(0.5)
    t.feed("MG _BGA")
    assert out[-1] == " 0.0000"


def test_a_program_only_command_is_refused_with_a_hint(term: tuple[Terminal, list[str]]) -> None:
    # AM, MC and WT are "Not Valid in terminal" (DMC-4103 command reference; decision 0044).
    t, out = term
    t.feed("AMA")
    t.feed("PRA=5;WT 2000")
    assert out == [
        "? 2 Command only valid from program",
        _PROGRAM_ONLY_HINT,
        "? 2 Command only valid from program",
        "  (refused: 'WT 2000')",
        _PROGRAM_ONLY_HINT,
    ]


def test_ctrl_c_cancels_a_download_being_typed(term: tuple[Terminal, list[str]]) -> None:
    t, out = term
    t.feed("DL")
    t.feed("#A")
    t.interrupt()
    assert not t.downloading
    assert "download cancelled" in out


@pytest.mark.parametrize("timeout", [math.inf, math.nan, -1, "5", True, 0, None], ids=repr)
def test_a_bad_reply_timeout_is_refused_before_the_terminal_starts(timeout: object) -> None:
    # A reply's timeout, checked as every timeout is (galil.link.check_seconds, more than 0):
    # before, "5" and None failed with a TypeError at the first command, and True was 1 s.
    with simulated() as dmc, nothing_sent(dmc), pytest.raises(InvalidArgument, match="timeout"):
        Terminal(dmc, timeout=timeout)  # type: ignore[arg-type]


def test_program_files_lose_blank_lines_and_indentation() -> None:
    text = "#A\n\n\tMG 1\n  EN  \r\n\\\nignored\n"
    assert program_lines(text) == ["#A", "MG 1", "EN"]
    with pytest.raises(InvalidArgument):
        program_lines("\n \n")


def test_dl_and_ul_commands_round_trip_a_program_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "prog.dmc"
    source.write_text("#A\n  MG 1\n\nEN\n")
    saved = tmp_path / "back.dmc"
    with SimTcpServer() as srv:
        assert cli.main(["dl", str(source), srv.url]) == 0
        assert cli.main(["ul", srv.url, str(saved)]) == 0
        assert cli.main(["ul", srv.url]) == 0
    assert saved.read_text().splitlines() == ["#A", "MG 1", "EN"]
    assert capsys.readouterr().out.splitlines()[-3:] == ["#A", "MG 1", "EN"]


def test_the_terminal_runs_the_simulator_in_real_time() -> None:
    with cli._connect("sim://DMC-4040", 1.0) as dmc:
        assert isinstance(dmc.transport.controller.clock, RealTimeClock)  # type: ignore[attr-defined]


# ----------------------------------------------------------------------------------- pty


_ANSI = re.compile(rb"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\x1b[=>]|\r")


class PtyScreen:
    """A child process on a real pseudo-terminal, read as plain text."""

    def __init__(self, fd: int, proc: subprocess.Popen[str]) -> None:
        self.fd = fd
        self.proc = proc
        self.status = 0  # how the child is to end (checked at teardown)
        self.text = ""

    def send(self, data: str) -> None:
        os.write(self.fd, data.encode())

    def expect(self, pattern: str, timeout: float = 15.0) -> re.Match[str]:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while True:
            found = rx.search(self.text)
            if found:
                self.text = self.text[found.end() :]
                return found
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{pattern!r} not seen; screen: {self.text[-800:]!r}")
            ready, _, _ = select.select([self.fd], [], [], left)
            if ready:
                try:
                    chunk = os.read(self.fd, 4096)
                except OSError:
                    chunk = b""
                if not chunk:
                    raise AssertionError(f"the terminal ended before {pattern!r}: {self.text!r}")
                self.text += _ANSI.sub(b"", chunk).decode("utf-8", "replace")

    def wait_closed(self, timeout: float = 15.0) -> None:
        """Read until the child closes the terminal (it left)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.fd], [], [], 0.1)
            if ready:
                try:
                    if not os.read(self.fd, 4096):
                        return
                except OSError:
                    return  # EIO: the other side is closed
        raise AssertionError(f"the terminal did not end; screen: {self.text[-400:]!r}")


@pytest.fixture
def pty_terminal(spawn: Spawn, tmp_path: Path) -> Iterator[Callable[..., PtyScreen]]:
    started: list[PtyScreen] = []

    def start(*args: str) -> PtyScreen:
        master, slave = os.openpty()
        env = dict(os.environ, TERM="xterm", PROMPT_TOOLKIT_NO_CPR="1")
        env["XDG_STATE_HOME"] = str(tmp_path)  # the history file goes here
        proc = spawn(
            [sys.executable, "-m", "galil", "terminal", *args],
            stdin=slave,
            stdout=slave,
            stderr=slave,
            env=env,
            start_new_session=True,
            preexec_fn=_ctty,  # the pty is its controlling terminal: ^C in a wait is SIGINT
        )
        os.close(slave)
        started.append(PtyScreen(master, proc))
        return started[-1]

    yield start
    for screen in started:
        if screen.proc.poll() is None:
            screen.proc.kill()
        screen.proc.wait(timeout=30)
        os.close(screen.fd)
    for screen in started:
        assert screen.proc.returncode == screen.status


def _ctty() -> None:
    import fcntl
    import termios

    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


class HoldNextReply:
    """A fault hook for the simulator's servers (:mod:`galil.sim.faults`): once armed, the
    next reply's terminator and what follows it come ``seconds`` late, as if the controller
    held the ``:`` (what a host's AM did before decision 0044)."""

    def __init__(self) -> None:
        self.seconds = 0.0

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        ends = [i for i in (data.find(b":"), data.find(b"?")) if i >= 0]
        if not self.seconds or not ends:
            return [(0.0, data)]
        seconds, self.seconds = self.seconds, 0.0
        return [(0.0, data[: min(ends)]), (seconds, data[min(ends) :])]


def until_still(screen: PtyScreen) -> None:
    """Poll ``MG _BGA`` at the terminal until the A axis stands still (real time passes)."""
    for _ in range(500):
        screen.send("MG _BGA\r")
        if screen.expect(r" ([01])\.0000\n").group(1) == "0":
            return
    raise AssertionError("the A axis never stopped")


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_a_session_against_a_serial_simulator_through_a_real_pty(
    pty_terminal: Callable[..., PtyScreen],
) -> None:
    hold = HoldNextReply()
    with SimPtyServer(model="DMC-4040", faults=hold) as sim:
        screen = pty_terminal(sim.path, "--timeout", "1")
        screen.expect(r"Ctrl-D leaves")
        screen.send("PRA=1000;BGA\r")
        screen.send("AMA\r")  # "Not Valid in terminal" (decision 0044): refused, with a hint
        screen.expect(r"\? 2 Command only valid from program\n *\(program only: ")
        until_still(screen)
        screen.send("MG _RPA\r")
        screen.expect(r" 1000\.0000")
        screen.send("bg\r")
        screen.expect(r"\? 1 Unrecognized command")
        screen.send("MG 2*3\r")  # the session goes on
        screen.expect(r" 6\.0000")
        screen.send("DL\r")
        screen.expect(r"download: ")
        for line in PROGRAM:
            screen.send(line + "\r")
        screen.send("\\\r")
        screen.expect(r"downloaded 4 lines")
        screen.send("XQ #A\r")
        screen.expect(r"hello")  # program output shows as it arrives, with no Enter
        screen.send("\x1b[A\r")  # Up arrow: the last line again
        screen.expect(r"XQ #A.*\n.*hello")
        screen.send("JGA=5000;BGA\r")
        screen.send("MG _BGA\r")
        screen.expect(r" 1\.0000")
        screen.send("\x03")  # Ctrl-C
        screen.expect(r"Ctrl-C: sent ST")
        until_still(screen)
        hold.seconds = 1.5  # the next ':' comes 1.5 s late: a timeout, the session goes on
        screen.send("a=1\r")
        screen.expect(r"timeout: ")
        for _ in range(5):  # once the ':' has come (on a loaded machine, after a retry or two)
            screen.send("MG 7\r")
            if screen.expect(r" 7\.0000\n:|not sent: [^\n]*\n:").group(0)[0] == " ":
                break
        else:
            raise AssertionError("MG 7 never answered after the held reply's timeout")
        screen.send("\x04")  # Ctrl-D, at the prompt, leaves
        screen.wait_closed()


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_a_session_on_the_in_process_simulator_runs_in_real_time(
    pty_terminal: Callable[..., PtyScreen],
) -> None:
    screen = pty_terminal("sim://DMC-4040")
    screen.expect(r"Ctrl-D leaves")
    screen.send("JGA=1000;BGA\r")
    for _ in range(500):  # the clock runs while nobody waits on a reply
        screen.send("MG _TPA>100\r")
        if screen.expect(r" ([01])\.0000\n").group(1) == "1":
            break
    else:
        raise AssertionError("the jog never passed 100 counts")
    screen.send("\x03")
    screen.expect(r"sent ST.*\n:")
    screen.send("\x04")
    screen.wait_closed()


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP"])
def test_sigterm_or_sighup_at_the_prompt_puts_the_tty_back_and_exits_128_plus_the_signal(
    pty_terminal: Callable[..., PtyScreen], name: str
) -> None:
    # Before, the signal killed the terminal where it stood: the tty stayed in raw mode (no
    # echo, no line editing, no Ctrl-C) and the controller was never closed.
    import termios

    signum = int(getattr(signal, name))
    screen = pty_terminal("sim://DMC-4040")
    screen.expect(r"Ctrl-D leaves")
    screen.send("MG 1\r")
    screen.expect(r" 1\.0000\n:")
    screen.status = 128 + signum
    screen.proc.send_signal(signum)
    assert screen.proc.wait(timeout=30) == 128 + signum
    flags = termios.tcgetattr(screen.fd)[3]  # the line settings of the pty, as left
    for flag in (termios.ECHO, termios.ICANON, termios.ISIG):  # echo, lines, Ctrl-C
        assert flags & flag
