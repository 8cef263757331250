"""``galil terminal`` in this process: what its pty tests do in a child (which coverage does not
see), plus the failures a person meets: a blank line, an empty or refused download, a failed
reset, a Ctrl-C that cannot reach the controller, piped and line-edited input.
"""

from __future__ import annotations

import asyncio
import errno
import io
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import pytest
from prompt_toolkit import PromptSession
from prompt_toolkit.application import create_app_session
from prompt_toolkit.history import FileHistory
from prompt_toolkit.input import create_pipe_input
from prompt_toolkit.output.plain_text import PlainTextOutput
from prompt_toolkit.patch_stdout import StdoutProxy

import galil
from galil import cli, terminal
from galil.protocol import commands
from galil.sim.server import SimTcpServer
from galil.terminal import Terminal, _Screen, default_history_path, run_terminal
from galil.testing import nothing_sent, sim_of


class Faults:
    """A fault hook for ``sim://``: drops every reply while ``drop`` but those holding
    ``keep``; raises SIGINT (Ctrl-C) when a reply holds ``interrupt_on``."""

    def __init__(self) -> None:
        self.drop = False
        self.keep: bytes | None = None
        self.interrupt_on: bytes | None = None

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if self.interrupt_on is not None and self.interrupt_on in data:
            self.interrupt_on = None
            signal.raise_signal(signal.SIGINT)
        if self.drop and (self.keep is None or self.keep not in data):
            return []
        return [(0.0, data)]


@pytest.fixture
def faults() -> Faults:
    return Faults()


@pytest.fixture
def dmc(faults: Faults) -> Iterator[galil.Controller]:
    with galil.connect("sim://DMC-4040", faults=faults) as controller:
        yield controller


@pytest.fixture
def out() -> list[str]:
    return []


@pytest.fixture
def term(dmc: galil.Controller, out: list[str]) -> Terminal:
    return Terminal(dmc, write=out.append, timeout=1.0)


def test_a_blank_line_sends_nothing_and_prints_nothing(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    with nothing_sent(dmc):
        term.feed("")
        term.feed("   \t")
    assert out == []


def test_a_download_with_no_lines_is_cancelled_without_sending(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    term.feed("DL")
    with nothing_sent(dmc):
        term.feed("")
        term.feed("\\")
    assert out[-1] == "download cancelled: no program lines"
    assert not term.downloading
    assert term.prompt == ":"


def test_a_program_line_the_controller_cannot_take_is_not_sent(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    with nothing_sent(dmc):
        assert not term.download(["#A", "MG " + "1+" * 60 + "1", "EN"])
    assert out[-1].startswith("not sent: DL line 2: ")
    assert "the limit is" in out[-1]


def test_a_failed_reset_is_reported_and_the_session_goes_on(
    faults: Faults, term: Terminal, out: list[str]
) -> None:
    # ST (before RS) is never answered, nor anything else but the resync marker: the link is
    # alive (one that hears nothing at all is dead and ends the terminal: decision 0089).
    faults.drop, faults.keep = True, b"SYNC"
    term.feed("RS")
    assert out[-1].startswith("error: ")
    assert "could not be stopped" in out[-1]
    faults.drop = False
    term.feed("MG 1")
    assert out[-1] == " 1.0000"
    term.feed("RS")
    assert out[-1].startswith("reset (RS): the controller restarted")


def test_ctrl_c_that_cannot_send_st_says_so(faults: Faults, term: Terminal, out: list[str]) -> None:
    faults.drop, faults.keep = True, b"SYNC"  # (alive: the resync marker is answered)
    term.interrupt()
    assert out[-1].startswith("Ctrl-C: ST not sent: ")
    faults.drop = False
    term.feed("MG 2")
    assert out[-1] == " 2.0000"


def test_a_dead_link_ends_the_terminal_rather_than_being_reported(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    dmc.transport.close()
    with pytest.raises(galil.GalilConnectionError, match="link is closed"):
        term.feed("MG 1")
    assert out == []


def test_piped_input_runs_as_a_script_and_prints_program_output(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    script = 'MG 1+2\nbg\nDL\n#A\nMG "hello"\nEN\n\\\nXQ #A\nMG 4\n'
    monkeypatch.setattr(sys, "stdin", io.StringIO(script))
    assert run_terminal(dmc) == 1  # stdin is no terminal: read line by line; bg is refused
    lines = capsys.readouterr().out.splitlines()
    assert lines[:2] == [" 3.0000", "? 1 Unrecognized command"]
    assert "downloaded 3 lines" in lines
    assert lines.index("hello") > lines.index("downloaded 3 lines")
    assert lines[-1] == " 4.0000"
    dmc.command("MG 5")  # the terminal no longer listens once it has ended
    assert capsys.readouterr().out == ""


class HoldReply:
    """A fault hook for the simulator's servers: the next reply holding ``mark`` comes
    ``seconds`` late (and what follows it, in order)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.mark = b"7777"

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        if self.seconds and self.mark in data:
            seconds, self.seconds = self.seconds, 0.0
            return [(seconds, data)]
        return [(0.0, data)]


def test_a_command_while_a_late_reply_is_due_is_not_sent_and_says_why() -> None:
    hold = HoldReply()
    with SimTcpServer(model="DMC-4040", faults=hold) as srv, galil.connect(srv.url) as dmc:
        out: list[str] = []
        term = Terminal(dmc, write=out.append, timeout=0.05)
        hold.seconds, hold.mark = 0.3, b":"  # a burn holds its reply while flash is written
        term.feed("BV")
        assert out[-1].startswith("timeout: no reply to 'BV'")
        term.feed("MG 1")  # the link cannot resynchronise while the burn's reply is due
        assert out[-1].startswith("not sent: the link is out of step")
        assert "busy with BV" in out[-1]
        assert out[-1].endswith("(an earlier reply may still be due, e.g. a burn's)")
        for _ in range(100):  # once the late reply has come, the session goes on
            term.feed("MG 2")
            if out[-1] == " 2.0000":
                break
        else:
            raise AssertionError(f"MG 2 never answered: {out[-3:]}")


class CtrlCOnce(io.StringIO):
    """Piped input whose second read is interrupted by Ctrl-C."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.reads = 0

    def readline(self, size: int = -1) -> str:  # type: ignore[override]
        self.reads += 1
        if self.reads == 2:
            raise KeyboardInterrupt
        return super().readline(size)


def test_ctrl_c_while_reading_piped_input_sends_st_and_reading_goes_on(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sys, "stdin", CtrlCOnce("JGA=1000;BGA\nMG 6\n"))
    assert run_terminal(dmc, interactive=False) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Ctrl-C: sent ST")
    assert lines[1] == " 6.0000"
    # (the simulator's clock has not run: A is still decelerating when the input ends)
    assert lines[2:] == [
        "warning: leaving while axis A moves: the end of the terminal stops nothing (ST stops "
        "the motion, HX n halts thread n)"
    ]
    assert "ST" in [text for _, text in sim_of(dmc).command_log]


def _session(dmc: galil.Controller, keys: str, history: Path | None) -> str:
    """Type ``keys`` at the line-edited terminal; what it showed (prompts included)."""
    screen = io.StringIO()
    before = signal.getsignal(signal.SIGINT)
    with create_pipe_input() as typed:
        typed.send_text(keys)
        with create_app_session(input=typed, output=PlainTextOutput(screen)):
            assert run_terminal(dmc, interactive=True, history=history) == 0
    assert signal.getsignal(signal.SIGINT) is before  # put back as it was
    return screen.getvalue()


def test_a_line_edited_session_sends_lines_keeps_history_and_handles_ctrl_c_and_ctrl_d(
    dmc: galil.Controller, tmp_path: Path
) -> None:
    history = tmp_path / "state" / "galil" / "terminal-history"
    keys = (
        "MG 1+2\r"
        "DL\r#A\r\x04"  # Ctrl-D while a program is typed: the download is cancelled
        "\x03"  # Ctrl-C at the prompt: ST
        "MG 4\r"
        "\x04"  # Ctrl-D at the prompt leaves
    )
    shown = _session(dmc, keys, history)
    events = [
        " 3.0000",
        "download cancelled",
        "Ctrl-C: sent ST",
        " 4.0000",
    ]
    at = 0
    for event in events:
        at = shown.index(event, at) + len(event)
    kept = [line for line in history.read_text().splitlines() if line.startswith("+")]
    assert kept == ["+MG 1+2", "+DL", "+#A", "+MG 4"]


def test_lines_printed_while_the_next_prompt_comes_and_goes_are_all_shown(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch
) -> None:
    # prompt-toolkit's patch_stdout proxy hands a printed line to the running prompt's event
    # loop from its own thread. Here that thread is always late (as a busy machine may make
    # it): it looks for a prompt when the next one is already shown and hands the line over
    # only once that prompt has ended. The terminal's lines must not depend on it.
    original = StdoutProxy._get_app_loop

    def late(proxy: StdoutProxy) -> asyncio.AbstractEventLoop | None:
        deadline = time.monotonic() + 5.0
        while proxy.app_session.app is None and time.monotonic() < deadline:
            time.sleep(0.001)
        loop = original(proxy)
        while loop is not None and not loop.is_closed() and time.monotonic() < deadline:
            time.sleep(0.001)
        return loop

    monkeypatch.setattr(StdoutProxy, "_get_app_loop", late)
    shown = _session(dmc, "MG 1+2\rMG 4\r\x04", None)
    assert shown.index(" 3.0000") < shown.index(" 4.0000")


def test_lines_from_another_thread_are_shown_above_the_prompt_or_after_it_ends() -> None:
    screen = io.StringIO()
    with create_pipe_input() as typed, create_app_session(typed, PlainTextOutput(screen)):
        lines = _Screen()
        session: PromptSession[str] = PromptSession()

        def from_a_thread(text: str) -> None:
            thread = threading.Thread(target=lines.write, args=(text,))
            thread.start()
            thread.join()

        def start() -> None:
            lines.prompt_shown(session.app)
            # while the prompt is shown; the line is typed only then
            from_a_thread("above the prompt")
            typed.send_text("typed\r")
            # once the prompt has its answer, while its event loop ends
            answered = session.app.future
            assert answered is not None
            answered.add_done_callback(lambda _: from_a_thread("as it ends"))

        lines.write("before")
        try:
            assert session.prompt(":", pre_run=start) == "typed"
        finally:
            lines.prompt_gone()
        lines.write("after")
    text = screen.getvalue()
    at = 0
    for line in ["before", "above the prompt", "typed", "as it ends", "after"]:
        at = text.index(line, at) + len(line)


def test_ctrl_c_during_a_command_sends_st_and_the_session_goes_on(
    dmc: galil.Controller, faults: Faults
) -> None:
    faults.interrupt_on = b"7777"  # Ctrl-C while the reply to MG 7777 comes in
    shown = _session(dmc, "JGA=1000;BGA\rMG 7777\rMG 8\r\x04", None)
    assert shown.index("Ctrl-C: sent ST") < shown.index(" 8.0000")
    log = [text for _, text in sim_of(dmc).command_log]
    assert log.index("ST") > log.index("MG 7777")


class CtrlCAfterAReply:
    """A tracer for the terminal's thread: a SIGINT, as a Ctrl-C typed between two prompts
    raises (the tty is then in cooked mode), at the ``at``-th line the prompt loop runs once
    the first typed line has been handled (``Terminal.feed`` returned, its reply shown).
    ``lines`` counts the loop's lines from there to the next prompt."""

    def __init__(self, at: int | None) -> None:
        self.at = at
        self.fed = False
        self.prompted = False
        self.lines = 0

    def __call__(self, frame: FrameType, event: str, arg: object) -> Any:
        if frame.f_code is Terminal.feed.__code__:
            return self._feed
        if frame.f_code is terminal._prompt_loop.__code__:
            return self._loop
        if frame.f_code is PromptSession.prompt.__code__ and self.fed:
            self.prompted = True
        return None

    def _feed(self, frame: FrameType, event: str, arg: object) -> Any:
        if event == "return":
            self.fed = True
        return self._feed

    def _loop(self, frame: FrameType, event: str, arg: object) -> Any:
        if event == "line" and self.fed and not self.prompted:
            self.lines += 1
            if self.lines == self.at:
                signal.raise_signal(signal.SIGINT)
        return self._loop


def test_a_ctrl_c_anywhere_between_a_reply_and_the_next_prompt_sends_st(
    dmc: galil.Controller,
) -> None:
    def session(tracer: CtrlCAfterAReply) -> str:
        previous = sys.gettrace()
        sys.settrace(tracer)
        try:
            return _session(dmc, "MG 1\rMG 8\r\x04", None)
        except KeyboardInterrupt:
            raise AssertionError(f"a Ctrl-C at loop line {tracer.at} ended it") from None
        finally:
            sys.settrace(previous)

    count = CtrlCAfterAReply(None)
    session(count)
    assert count.lines > 3
    for at in range(1, count.lines + 1):
        shown = session(CtrlCAfterAReply(at))
        assert shown.index(" 1.0000") < shown.index("Ctrl-C: sent ST") < shown.index(" 8.0000")


def test_an_unwritable_history_keeps_it_for_the_session_only(
    dmc: galil.Controller, tmp_path: Path
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    shown = _session(dmc, "MG 9\r\x04", blocker / "galil" / "terminal-history")
    assert " 9.0000" in shown


def test_the_history_lives_in_the_xdg_state_directory(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", "/var/state")
    assert default_history_path() == Path("/var/state/galil/terminal-history")
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", "/home/someone")
    assert default_history_path() == Path("/home/someone/.local/state/galil/terminal-history")


def test_a_history_file_that_cannot_be_written_is_kept_for_the_session_and_says_so(
    dmc: galil.Controller, tmp_path: Path
) -> None:
    # A directory, or a file not ours (left by `sudo galil terminal`): before, a directory
    # printed prompt-toolkit's traceback, and a file it could not append to hung the terminal
    # at the first line typed.
    shown = _session(dmc, "MG 9\rMG 8\r\x04", tmp_path)
    assert shown.count(f"history: cannot use {tmp_path} (Is a directory)") == 1
    assert "the history is kept for this session only" in shown
    assert shown.index(" 9.0000") < shown.index(" 8.0000")
    assert "Traceback" not in shown


def test_a_history_file_that_fails_during_the_session_goes_on_in_memory(
    dmc: galil.Controller, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(self: FileHistory, string: str) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(FileHistory, "store_string", full)  # the disk fills up
    history = tmp_path / "terminal-history"
    shown = _session(dmc, "MG 1\rMG 2\rMG 3\r\x04", history)  # before, MG 1 hung it
    assert shown.count("(No space left on device); the history is kept for this session") == 1
    assert shown.index(" 1.0000") < shown.index(" 2.0000") < shown.index(" 3.0000")


def test_a_typed_ul_or_ls_has_the_timeout_of_a_whole_program_memory() -> None:
    # At 9600 baud, the 200 lines take about 2 s: more than the terminal's 1 s reply timeout,
    # which a typed UL had before ("timeout: no reply to 'UL'"), while `galil ul` worked.
    program = "\n".join(["#A", *(f"MG {n}" for n in range(200)), "EN"])
    with galil.connect("sim://DMC-4040?baud=9600") as slow:
        slow.programs.download(program)
        out: list[str] = []
        term = Terminal(slow, write=out.append, timeout=1.0)
        term.feed("UL")
        assert out == program.splitlines()
        out.clear()
        term.feed("LS")
        assert out[:2] == ["0 #A", "1 MG 0"]
        assert out[-2:] == ["201 EN", "202 "]
        assert term.failures == 0


def test_qr_says_what_came_back(term: Terminal, out: list[str]) -> None:
    term.feed("QR")  # before, nothing at all was printed
    assert out == [
        "(QR: a 226-byte binary data record, not shown; MG reads its values as text: MG _TPA, _RPA)"
    ]


def test_a_compound_line_with_a_rejected_part_prints_the_replies_of_the_others(
    term: Terminal, out: list[str]
) -> None:
    term.feed("MG 1;XYZ;MG 2")  # before, only the rejection was printed
    assert out == [" 1.0000", "? 1 Unrecognized command", "  (refused: 'XYZ')", " 2.0000"]


@pytest.mark.parametrize(
    ("line", "advice"),
    [
        ("RS;MG 1", "not sent: RS in a line with other commands would reset the controller"),
        # (before, these two alone got "RS in a line with other commands ...: type RS alone")
        ("RS 0", "not sent: 'RS 0': RS with an argument is not sent from here. Type RS alone"),
        ("RS -1", "not sent: 'RS -1': RS with an argument is not sent from here. Type RS alone"),
        ("MG 1;BN", "not sent: BN in a line with other commands would burn"),
        ("DL #A", "not sent: 'DL #A': a program download starts with DL typed alone"),
        ("QD x[]", "not sent: 'QD x[]': QD takes an array's values from the lines after it"),
        ("CW 2", "not sent: 'CW 2' changes how program output is marked"),
        ("EO 1", "not sent: 'EO 1' switches the echo the link handles"),
        ("CF A", "not sent: 'CF A' would send program output away from this terminal"),
        ("IHS=>-1", "not sent: 'IHS=>-1' would close the handle this terminal talks on"),
    ],
)
def test_a_line_the_library_will_not_send_says_what_to_type_instead(
    dmc: galil.Controller, term: Terminal, out: list[str], line: str, advice: str
) -> None:
    # Before: "not sent: not sent: ...", with the Python call to use (controller.reset(),
    # commands.dl(), connect(..., echo=True)).
    with nothing_sent(dmc):
        term.feed(line)
    assert len(out) == 1
    assert out[0].startswith(advice)
    for python in ("reset()", "commands.", "connect("):
        assert python not in out[0]
    assert term.failures == 1


def test_a_downloaded_program_is_checked_as_programs_download_checks_it(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    lines = ["#A", *(["MG 1"] * dmc.model.program_lines), "EN"]
    with nothing_sent(dmc):
        assert not term.download(lines)
    assert out[-1] == "not sent: the program has 2002 lines; DMC-4040 holds 2000"


def test_a_typed_download_refused_says_what_to_change_in_its_lines_not_a_python_keyword(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    term.feed("DL")
    with nothing_sent(dmc):
        for line in ("#A", "PR 1000;REM the first move", "EN", "\\"):
            term.feed(line)
    assert out[-1].startswith("not sent: program line 2: REM after a label or a command")
    assert out[-1].endswith("write ' for a comment after a command, or drop the comment")
    assert "strip_comments" not in out[-1]
    with pytest.raises(galil.InvalidArgument, match=r"or pass strip_comments=True \[DMC-4040\]$"):
        dmc.programs.download("#A\nPR 1000;REM the first move\nEN")  # (the API's own advice)


@pytest.mark.parametrize(
    ("script", "status"),
    [
        ("MG 1\nMG 2\n", 0),
        ("MG 1\nXYZ\nMG 2\n", 1),  # refused by the controller
        ("RS;MG 1\nMG 2\n", 1),  # not sent
        ("DL\n#A\nMG " + "1+" * 60 + "1\n\\\n", 1),  # a download refused
    ],
)
def test_a_piped_script_ends_with_status_1_when_a_line_failed(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, script: str, status: int
) -> None:
    # Before, `galil terminal ADDRESS < setup.txt` ended with 0 whatever happened.
    monkeypatch.setattr(sys, "stdin", io.StringIO(script))
    assert run_terminal(dmc, interactive=False) == status


def test_a_line_edited_session_ends_with_status_0_after_a_refused_line(
    dmc: galil.Controller,
) -> None:
    assert "? 1 Unrecognized command" in _session(dmc, "XYZ\r\x04", None)  # (status 0 there)


class SignalOnRead(io.StringIO):
    """Piped input during whose second read the process gets ``signum``."""

    def __init__(self, text: str, signum: int) -> None:
        super().__init__(text)
        self.signum = signum
        self.reads = 0

    def readline(self, size: int = -1) -> str:  # type: ignore[override]
        self.reads += 1
        if self.reads == 2:
            signal.raise_signal(self.signum)
        return super().readline(size)


def test_sigterm_ends_the_galil_terminal_command_which_closes_the_controller(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    noted: list[int] = []

    def handler(signum: int, frame: object) -> None:
        noted.append(signum)

    before = signal.signal(signal.SIGTERM, handler)
    try:
        monkeypatch.setattr(sys, "stdin", SignalOnRead("MG 1\nMG 2\n", signal.SIGTERM))
        monkeypatch.setattr("galil.cli._connect", lambda address, timeout: dmc)
        assert cli.main(["terminal", "sim://DMC-4040"]) == 128 + signal.SIGTERM
        assert dmc.closed
        assert capsys.readouterr().out.splitlines() == [" 1.0000"]
        assert noted == []  # the terminal's own handler had it, and then put this one back
        assert signal.getsignal(signal.SIGTERM) is handler
    finally:
        signal.signal(signal.SIGTERM, before)


def test_sigterm_at_the_line_edited_prompt_ends_the_terminal_with_128_plus_15(
    dmc: galil.Controller,
) -> None:
    noted: list[int] = []

    def handler(signum: int, frame: object) -> None:
        noted.append(signum)

    before = signal.signal(signal.SIGTERM, handler)
    screen = io.StringIO()
    try:
        with create_pipe_input() as typed:

            def at_the_prompt() -> None:  # once the reply to MG 1 is shown, and the prompt
                deadline = time.monotonic() + 30
                while not re.search(r" 1\.0000\n.*:", screen.getvalue(), re.S):
                    if time.monotonic() > deadline:
                        break
                    time.sleep(0.01)
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(2)
                typed.send_text("\x04")  # (ends a terminal that did not end on the signal)

            typed.send_text("MG 1\r")
            killer = threading.Thread(target=at_the_prompt, daemon=True)
            killer.start()
            with create_app_session(input=typed, output=PlainTextOutput(screen)):
                status = run_terminal(dmc, interactive=True)
            killer.join()
        assert status == 128 + signal.SIGTERM
        assert noted == []  # the terminal's own handler had it, and then put this one back
        assert signal.getsignal(signal.SIGTERM) is handler
    finally:
        signal.signal(signal.SIGTERM, before)


def test_a_link_lost_under_the_terminal_says_to_start_it_again(
    dmc: galil.Controller, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("MG 1\n"))
    monkeypatch.setattr("galil.cli._connect", lambda address, timeout: dmc)
    dmc.transport.close()  # the cable is pulled
    assert cli.main(["terminal", "sim://DMC-4040"]) == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith("galil: ")
    assert "link is closed" in err
    assert err.endswith("; start galil terminal sim://DMC-4040 again")
    assert "reconnect()" not in err  # (Python advice: before, the terminal's own)


def test_a_typed_download_makes_the_library_forget_the_routines_it_replaced(
    dmc: galil.Controller, term: Terminal
) -> None:
    with pytest.raises(galil.GalilTimeoutError):  # (input 2 is high: the routine installed)
        dmc.io.wait_for_input(2, high=False, timeout=0.1, thread=3)
    assert term.download(["#A", "MG 5", "EN"])
    assert dmc.routines.upload() == ["#A", "MG 5", "EN"]  # (the library's block is gone)
    assert dmc.routines.threads == {}
    dmc.programs.run("#A", thread=3)  # (before: "thread 3 runs the library's #GINWAIT")
    dmc.programs.wait(3)
    with pytest.raises(galil.GalilTimeoutError):  # installed again, beside it
        dmc.io.wait_for_input(2, high=False, timeout=0.1, thread=3)
    assert dmc.programs.upload() == "#A\nMG 5\nEN"
    assert "#GINWAIT" in dmc.routines.upload()


def test_a_typed_download_while_the_watchdog_runs_is_not_sent_nor_its_lines_run(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    dog = dmc.watchdog(5.0)
    term.feed("DL")
    with nothing_sent(dmc, allow_queries=True):
        for line in ("#A", "PR 1000", "BG A", "EN", "\\"):
            term.feed(line)
    assert out[-1].startswith("not sent: thread 7 (the library's #GWDOG: the watchdog) is ")
    assert "refuses DL while a program runs (TC 17)" in out[-1]
    dmc.sleep(1.0)  # (before: the controller refused the DL and ran PR 1000 and BG A)
    assert dmc.A.reference_position == 0
    assert dog.running
    assert dmc.routines.threads == {7: "#GWDOG"}
    dog.stop()


def test_a_download_sent_raw_makes_the_library_forget_the_routines_it_replaced(
    dmc: galil.Controller,
) -> None:
    dog = dmc.watchdog(5.0)
    with (
        nothing_sent(dmc, allow_queries=True),
        pytest.raises(galil.InvalidArgument, match=r"thread 7 .* is running"),
    ):
        dmc.send(commands.dl(["#A", "EN"]))
    dog.stop()
    dog = dmc.watchdog(0.5, thread=3)
    sim_of(dmc).advance(1.0)  # the host silent: it fires, and its routine ends at EN
    assert dog.fired
    assert dmc.routines.threads == {3: "#GWDOG"}  # (held, its routine ended: no thread runs)
    assert dmc.exchange(commands.dl(["#A", "EN"])).ok
    assert dmc.routines.threads == {}
    dog.stop()
    dmc.programs.run("#A", thread=3)


def test_a_backslash_inside_a_downloaded_line_refuses_the_download_and_runs_none_of_its_lines(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    pasted = "DL\n#SCAN\n' data goes to C:\\scans\nPRA=5000\nBGA\nEN\n\\\n"
    term.feed("DL")
    with nothing_sent(dmc):  # (before: the line was cut at the \, the rest ran as commands)
        term.feed(pasted.removeprefix("DL\n"))
    assert out[-2].startswith("DL line 2: character '\\\\' cannot be downloaded")
    assert out[-1] == "not sent: DL line 2: character '\\\\' cannot be downloaded"
    assert not term.downloading
    assert term.failures == 1
    dmc.sleep(0.5)
    assert dmc.A.reference_position == 0
    assert not dmc.A.moving
    term.feed("MG 7")  # the line after the end of the download runs
    assert out[-1] == " 7.0000"


def test_a_line_with_two_refused_parts_explains_the_last_and_says_the_first_is_unexplained(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    term.feed("JGA=5000;BGA")
    term.feed("MG 1;PRA=1000;MG 2;BGA;MG 3")  # (before: "? 21 ... (refused: 'PRA=1000')")
    assert out[-6:] == [
        " 1.0000",
        "? (refused: 'PRA=1000'; why is not known: TC1 tells only the last error)",
        " 2.0000",
        "? 21 Begin not valid while running",
        "  (refused: 'BGA')",
        " 3.0000",
    ]
    dmc.stop()


def test_ctrl_c_halts_a_program_that_would_start_motion_again_and_says_so(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    assert term.download(["#L", "PRA=2000", "BGA", "AMA", "JP #L", "EN"])
    term.feed("XQ #L")
    dmc.sleep(0.05)
    assert dmc.A.moving
    term.interrupt()  # (before: ST only, and "motion stopped on every axis" while #L ran on)
    assert out[-1] == (
        "Ctrl-C: sent ST to every axis and halted the program threads (HX0) (Ctrl-D leaves)"
    )
    dmc.sleep(0.5)
    assert not dmc.A.moving
    assert dmc.programs.threads == {}


def test_ctrl_c_leaves_the_librarys_routines_running_and_names_them(
    dmc: galil.Controller, term: Terminal, out: list[str]
) -> None:
    dog = dmc.watchdog(5.0)
    term.feed("JGA=5000;BGA")
    term.interrupt()
    assert out[-1] == (
        "Ctrl-C: sent ST, motion stopped on every axis; thread 7 runs the library's #GWDOG "
        "(the watchdog): left running (Ctrl-D leaves)"
    )
    assert dog.running
    assert dmc.routines.running().keys() == {7}
    dog.stop()


def test_ctrl_c_tells_another_sessions_watchdog_by_its_label_and_leaves_it_running() -> None:
    with (
        SimTcpServer(model="DMC-4040") as server,
        galil.connect(server.url) as other,
        galil.connect(server.url) as dmc,
    ):
        dog = other.watchdog(5.0)
        out: list[str] = []
        Terminal(dmc, write=out.append).interrupt()
        assert out == [
            "Ctrl-C: sent ST, motion stopped on every axis; thread 7 runs the library's #GWDOG "
            "(the watchdog): left running (Ctrl-D leaves)"
        ]
        assert dog.running
        dog.stop()


def test_leaving_the_terminal_while_an_axis_moves_or_a_program_runs_warns(
    dmc: galil.Controller,
) -> None:
    shown = _session(dmc, "JGA=5000;BGA\r\x04", None)  # before: it left without a word
    assert "warning: leaving while axis A moves: the end of the terminal stops nothing" in shown
    dmc.stop()
    dmc.sleep(0.1)
    dmc.programs.download("#W\nWT 10000\nEN")
    dmc.programs.run("#W", thread=2)
    shown = _session(dmc, "MG 1\r\x04", None)
    assert "warning: leaving while thread 2 runs: the end of the terminal" in shown
    assert "axis" not in shown.partition("warning:")[2]


@pytest.mark.parametrize(("line", "size"), [("QRA", 118), ("QRAB", 154), ("QR A", 118)])
def test_qr_with_its_axes_written_after_it_says_what_came_back(
    term: Terminal, out: list[str], line: str, size: int
) -> None:
    term.feed(line)  # (before: QRA and QRAB printed nothing)
    assert len(out) == 1
    assert out[0].startswith(f"(QR: a {size}-byte binary data record")
    assert term.failures == 0


class CutReply:
    """A fault hook for ``sim://``: a reply holding ``mark`` comes only in part."""

    def __init__(self, mark: bytes) -> None:
        self.mark = mark

    def __call__(self, data: bytes) -> list[tuple[float, bytes]]:
        return [(0.0, data[:4] if self.mark in data else data)]


def test_a_reply_cut_part_way_says_which_option_gives_a_longer_timeout() -> None:
    with galil.connect("sim://DMC-4040", faults=CutReply(b"7777")) as dmc:
        out: list[str] = []
        Terminal(dmc, write=out.append, timeout=0.05).feed("MG 7777")
    assert out[-1].startswith("timeout: the reply to 'MG 7777' was cut part way: 4 bytes")
    assert "a long reply needs a longer timeout (give a longer --timeout)" in out[-1]
    assert "pass timeout=" not in out[-1]  # (the Python keyword, before)
