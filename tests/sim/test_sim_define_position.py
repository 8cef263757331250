"""The simulator's ``DP`` and ``DE`` against the DMC-4103 command reference (decision 0058):
DP "will set both the TP and RP values", and on a stepper "the registers for TD and RP ...
but will not effect the TP register value"; DE "defines the position of the auxiliary (dual)
encoders", "When using stepper motors, the DE command defines the main encoder position", and
it is "Valid while in motion"; ``_DP`` holds ``TP``, ``_DE`` holds ``TD``."""

from __future__ import annotations

from galil.sim.controller import SimController


def _ok(sim: SimController, line: str) -> None:
    reply = sim.feed(line.encode() + b"\r")
    assert b"?" not in reply, (line, reply, sim.feed(b"TC1\r"))


def _read(sim: SimController, operands: str) -> list[float]:
    replies = [sim.feed(f"MG {name}\r".encode()).decode() for name in operands.split(",")]
    return [float(reply.split(":")[0]) for reply in replies]


def test_servo_de_sets_the_auxiliary_encoder_only_even_in_motion() -> None:
    sim = SimController()
    _ok(sim, "SH A")
    _ok(sim, "JGA=2000;BGA")
    sim.advance(0.2)
    _ok(sim, "DEA=-300")  # valid while in motion
    tp, rp, td = _read(sim, "_TPA,_RPA,_TDA")
    assert td == -300
    assert (tp, rp) != (-300, -300)
    assert sim.feed(b"DPA=0\r") == b"?"  # DP is not
    _ok(sim, "STA")
    sim.advance(1)
    tp, td = _read(sim, "_TPA,_TDA")
    _ok(sim, "DPA=1000")  # DP leaves the auxiliary encoder as it was
    assert _read(sim, "_TPA,_RPA,_TDA,_DPA,_DEA") == [1000, 1000, td, 1000, td]
    assert float(sim.feed(b"DE ?\r").decode().split(":")[0]) == td


def test_stepper_dp_sets_rp_and_td_and_de_sets_its_encoder() -> None:
    sim = SimController()
    _ok(sim, "SH A")
    _ok(sim, "PRA=1500;BGA")
    sim.advance(1)
    _ok(sim, "MO A;MTA=2;SH A")
    _ok(sim, "DPA=100")
    assert _read(sim, "_TPA,_RPA,_TDA") == [1500, 100, 100]
    _ok(sim, "DEA=7")
    assert _read(sim, "_TPA,_RPA,_TDA") == [7, 100, 100]
    _ok(sim, "PRA=50;BGA")
    sim.advance(1)
    assert _read(sim, "_TPA,_RPA,_TDA") == [57, 150, 150]  # the encoder counts the steps


def test_reset_forgets_what_de_defined() -> None:
    sim = SimController()
    _ok(sim, "DEA=123")  # (DE, not a variable named DEA)
    assert _read(sim, "_TPA,_TDA") == [0, 123]
    _ok(sim, "RS")
    assert _read(sim, "_TPA,_TDA") == [0, 0]
