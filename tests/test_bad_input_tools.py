"""Bad input to the CLI, discovery and the transports' options (decision 0026): one line on
stderr and exit status 2 from the CLI, never a traceback; ``InvalidArgument`` from discovery
and ``galil.connect`` before any socket or port is opened. Network tests stay on 127.0.0.1."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Callable, Iterator

import pytest
from test_public_api_bad_input import BAD

import galil
from galil import cli, discovery

ALL = {label for label, _ in BAD}

# -- the CLI --------------------------------------------------------------------------------------

CLI_CASES = [
    ["terminal"],
    ["terminal", "bogus://x"],
    ["terminal", "sim://DMC-4040", "--timeout", "x"],
    ["terminal", "sim://DMC-4040", "--timeout", "nan"],
    ["terminal", "sim://DMC-4040", "--timeout", "-1"],
    ["terminal", "sim://NOPE"],
    ["info"],
    ["info", ""],
    ["info", "x"],
    ["info", "sim://DMC-4040", "--timeout", "0"],
    ["info", "sim://DMC-4040", "--timeout", "1e400"],
    ["info", "sim://DMC-4040?lag=x"],
    ["info", "sim://DMC-4040?seed=x"],
    ["info", "sim://DMC-4040?auto_advance=maybe"],
    ["info", "sim://DMC-4040?bogus=1"],
    ["info", "tcp://127.0.0.1:0"],
    ["info", "tcp://127.0.0.1:1?connect_timeout=x"],
    ["info", "tcp://[::1"],
    ["info", "999.1.1.1"],
    ["dl"],
    ["dl", "/nonexistent/program.dmc", "sim://DMC-4040"],
    ["ul", "sim://DMC-4040", "/nonexistent/dir/program.dmc"],
    ["ul", "sim://DMC-4040", "--timeout", "nan"],
    ["list", "--timeout", "nan"],
    ["list", "--timeout", "x"],
    ["list", "--bogus"],
    *(
        ["list", "--no-serial", "--no-usb", "--no-pci", "--probe", probe]
        for probe in ("x", "", "10.0.0.0/8", "127.0.0.1:99999", "127.0.0.1:x")
    ),
    ["sim", "--tcp", "x"],
    ["sim", "--tcp", "127.0.0.1:99999"],
    ["sim", "--lag", "x"],
    ["sim", "--tcp", "127.0.0.1:0", "--baud", "9600"],
    *(["sim", "--pty", "--baud", b] for b in ("0", "-9600", "x", "nan", "inf")),
    *(
        ["sim", "--tcp", "127.0.0.1:0", *opt]
        for opt in (
            ["--model", "NOPE"],
            ["--lag", "nan"],
            ["--lag", "-1"],
            ["--message-port", "99999"],
            ["--limits", "x"],
        )
    ),
    ["plan"],
    *(["plan", d] for d in ("x", "", "nan", "inf", "1e400", "10.5", "10mm", "1e20")),
    *(
        ["plan", "10000", *opt]
        for opt in (
            ["--speed", "x"],
            ["--speed", "nan"],
            ["--speed", "-1"],
            ["--speed", "1/0"],
            ["--accel", "0"],
            ["--decel", "inf"],
            ["--scale", "x"],
            ["--scale", "0/mm"],
            ["--scale", "nan/mm"],
            ["--smoothing", "nan"],
            ["--smoothing", "x"],
            ["--model", "NOPE"],
        )
    ),
    ["plan", "10mm", "--scale", "2000/mm", "--speed", "10deg/s"],
    ["demo", "--model", "NOPE", "--quick", "--quiet"],
    [],
    ["bogus"],
]


@pytest.mark.parametrize("argv", CLI_CASES, ids=" ".join)
def test_the_cli_refuses_bad_arguments_in_one_line(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("galil"), err  # "galil: ..." or "galil plan: error: ..."


@pytest.mark.parametrize("limits", ["x", "1", "1,2,3", "1.5,9"])
def test_sim_says_what_limits_takes(limits: str, capsys: pytest.CaptureFixture[str]) -> None:
    # (it said "invalid literal for int() with base 10: 'x'")
    with pytest.raises(SystemExit) as exc:
        cli.main(["sim", "--tcp", "127.0.0.1:0", "--limits", limits])
    assert exc.value.code == 2
    assert "--limits takes two whole numbers of counts, REV,FWD" in capsys.readouterr().err


# -- discovery ------------------------------------------------------------------------------------

LOCAL = ("127.0.0.1", 0)
DISCOVERY: list[tuple[Callable[..., object], dict[str, object], dict[str, set[str]]]] = [
    (discovery.serial_ports, {"identify": False, "identify_bridges": False, "timeout": 0.05}, {}),
    (discovery.usb_devices, {"backend": None}, {}),
    (
        discovery.pci_nodes,
        {"pattern": "/nonexistent/galilpci*", "identify": False, "timeout": 0.05},
        {"pattern": {"'x'", "''", "2000 chars"}},  # any glob pattern (it finds nothing)
    ),
    (discovery.probe_hosts, {"specs": ["127.0.0.1:1"], "timeout": 0.05}, {"specs": {"[]"}}),
    (discovery.ask_group, {"group": "127.0.0.1", "port": 9, "timeout": 0.02}, {}),
    (
        discovery.listen_bootp,
        {"timeout": 0.02, "address": LOCAL, "on_request": None, "count": None},
        {"count": {"10**400"}},  # a bound never reached
    ),
    (
        discovery.find,
        {
            "serial": False,
            "usb": False,
            "pci": False,
            "network": False,
            "probe": (),
            "bootp": False,
            "identify": False,
            "identify_bridges": False,
            "timeout": 0.05,
            "group": ("127.0.0.1", 9),
            "bootp_address": LOCAL,
            "bootp_timeout": 0.02,
        },
        {"probe": {"[]"}},
    ),
]


@pytest.mark.parametrize(
    ("fn", "valid", "accepts"), DISCOVERY, ids=lambda v: getattr(v, "__name__", "")
)
def test_discovery_refuses_bad_values(
    fn: Callable[..., object], valid: dict[str, object], accepts: dict[str, set[str]]
) -> None:
    fn(**valid)
    problems = []
    for param in valid:
        for label, bad in BAD:
            if bad is None and valid[param] is None:
                continue  # the default
            try:
                fn(**{**valid, param: bad})
            except galil.InvalidArgument:
                continue
            except Exception as exc:
                problems.append(
                    f"{fn.__name__}({param}={label}): {type(exc).__name__}: {exc!s:.99}"
                )
                continue
            flag = isinstance(valid[param], bool) and label == "True"
            if not flag and label not in accepts.get(param, set()):
                problems.append(f"{fn.__name__}({param}={label}): taken")
    assert not problems, "\n".join(problems)


# -- transport options --------------------------------------------------------------------------


@pytest.fixture
def listener() -> Iterator[tuple[int, Callable[[], int]]]:
    """A TCP port on 127.0.0.1, and how many connections were made to it (the kernel
    completes them into the backlog; nothing accepts them until the count)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(64)
    server.setblocking(False)

    def opened() -> int:
        n = 0
        with contextlib.suppress(BlockingIOError):
            while True:
                server.accept()[0].close()
                n += 1
        return n

    yield server.getsockname()[1], opened
    server.close()


TCP_OPTIONS = ["connect_timeout", "write_timeout", "port", "message_port", "timeout", "history"]
QUERY_BAD = ["x", "", "nan", "inf", "-1", "1e400", "0", "x" * 200]


@pytest.mark.parametrize("option", TCP_OPTIONS)
def test_tcp_options_are_refused_before_a_socket_opens(
    option: str, listener: tuple[int, Callable[[], int]]
) -> None:
    port, opened = listener
    url = f"tcp://127.0.0.1:{port}"
    problems = []
    for label, bad in BAD:
        if bad is None and option in ("message_port", "timeout"):
            continue  # none / the default
        try:
            galil.connect(url, **{"timeout": 0.05, option: bad}).close()
        except galil.InvalidArgument:
            continue
        except Exception as exc:
            problems.append(f"{option}={label}: {type(exc).__name__}: {exc!s:.99}")
            continue
        problems.append(f"{option}={label}: taken")
    if option not in ("timeout", "history"):  # client options: keywords only
        for text in QUERY_BAD + (["99999"] if option.endswith("port") else []):
            try:
                galil.connect(f"{url}?{option}={text}", timeout=0.05).close()
            except galil.InvalidArgument:
                continue
            except Exception as exc:
                problems.append(f"?{option}={text:.20}: {type(exc).__name__}: {exc!s:.99}")
                continue
            problems.append(f"?{option}={text:.20}: taken")
    assert not problems, "\n".join(problems)
    assert not opened(), "a connection was opened before the option was refused"


#: Options of sim:// and the bad values each takes on purpose.
SIM_OPTIONS: dict[str, set[str]] = {
    "lag": set(),
    "seed": {"-1", "10**400"},  # any integer seeds the random faults
    "auto_advance": {"True"},
    "faults": set(),
    "clock": set(),
    "messages": set(),
}


@pytest.mark.parametrize("option", list(SIM_OPTIONS))
def test_sim_options_are_refused(option: str) -> None:
    problems = []
    for label, bad in BAD:
        if bad is None and option in ("seed", "faults"):
            continue  # none
        try:
            galil.connect("sim://DMC-4040", **{option: bad}).close()
        except galil.InvalidArgument:
            continue
        except Exception as exc:
            problems.append(f"{option}={label}: {type(exc).__name__}: {exc!s:.99}")
            continue
        if label not in SIM_OPTIONS[option]:
            problems.append(f"{option}={label}: taken")
    for text in ("x", "nan", "1e400", "maybe"):
        try:
            galil.connect(f"sim://DMC-4040?{option}={text}").close()
        except galil.InvalidArgument:
            continue
        except Exception as exc:
            problems.append(f"?{option}={text}: {type(exc).__name__}: {exc!s:.99}")
            continue
        problems.append(f"?{option}={text}: taken")
    assert not problems, "\n".join(problems)


def test_sim_takes_negative_limits_as_its_own_message_writes_them(
    galil_sim: Callable[..., str],
) -> None:
    # (before: "argument --limits: expected one argument", for "-50000,50000")
    address = galil_sim("--tcp", "127.0.0.1:0", "--lag", "0", "--limits", "-50000,50000")
    with galil.connect(address, timeout=5.0) as dmc:
        assert dmc.command("MG _LRA, _LFA") == " 1.0000 1.0000"  # (at 0: neither switch hit)
        dmc.A.speed, dmc.A.accel, dmc.A.decel = 2_000_000, 60_000_000, 60_000_000
        move = dmc.A.move_by(-60_000)  # (about 0.04 s, on the server's real clock)
        with pytest.raises(galil.GalilError, match="limit"):
            move.wait(timeout=5.0)
        assert dmc.A.stop_code[0] == 3  # stopped by the reverse limit switch at -50000
