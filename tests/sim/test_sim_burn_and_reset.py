"""``BN``, ``BP``, ``BV`` and what ``RS``, ``RS -1`` and ``^R^S`` do with what they burned
(decision 0052), through the simulator's own port.

The DMC-4103 command reference: BN saves the parameters of its table, which "persist through
a software reset (RS command)"; RS restores "the previously saved state of the hardware, along
with parameter values and saved program"; RS -1 "restores factory default settings without
erasing the EEPROM"; a master reset restores burned parameters "to their factory defaults".
"""

from __future__ import annotations

import pytest

from galil.sim.controller import SimController

#: Settings of the BN table, each as (the command that changes it, the operand that reads
#: it, the burned value, a later value); the factory value is read from a new controller.
SETTINGS = [
    ("KPA=12", "_KPA", 12.0, "KPA=20"),
    ("LDA=3", "_LDA", 3.0, "LDA=0"),
    ("CEA=2", "_CEA", 2.0, "CEA=0"),
    ("MTA=-2", "_MTA", -2.0, "MTA=2"),
    ("OEA=1", "_OEA", 1.0, "OEA=0"),
    ("FLA=5000", "_FLA", 5000.0, "FLA=9000"),
    ("BLA=-5000", "_BLA", -5000.0, "BLA=-9000"),
    ("SPA=12000", "_SPA", 12000.0, "SPA=3000"),
    ("ACA=102400", "_ACA", 102400.0, "ACA=204800"),
    ("ITA=0.5", "_ITA", 0.5, "ITA=0.25"),
    ("HVA=1000", "_HVA", 1000.0, "HVA=2000"),
    ("VS 5000", "_VSS", 5000.0, "VS 7000"),
    ("SB 1", "@OUT[1]", 1.0, "CB 1"),
    ("AQ 1,3", "_AQ1", 3.0, "AQ 1,4"),
    ("CN 1", "_CN0", 1.0, "CN -1"),
    ("TM 500", "_TM", 500.0, "TM 250"),
    ("VF 6.2", "_VF", 6.2, "VF 8.3"),
]


def _num(sim: SimController, expression: str) -> float:
    reply = sim.feed(f"MG {expression}\r".encode())
    assert reply.endswith(b":"), reply
    return float(reply[:-1])


def _burn(sim: SimController, name: str) -> None:
    assert sim.feed(f"{name}\r".encode()) == b""  # the ':' comes when the flash is written
    assert sim.advance_until_output(1.0) == b":"


def _sent(sim: SimController, *commands: str) -> None:
    for text in commands:
        assert sim.feed(f"{text}\r".encode()) == b":", text


@pytest.fixture
def factory() -> dict[str, float]:
    sim = SimController("DMC-4040")
    return {operand: _num(sim, operand) for _, operand, _, _ in SETTINGS}


def test_rs_restores_the_burned_parameters_rs_minus_one_the_factory_ones(
    factory: dict[str, float],
) -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "MO A", *(set_ for set_, _, _, _ in SETTINGS))
    _burn(sim, "BN")
    _sent(sim, *(later for _, _, _, later in SETTINGS))
    sim.feed(b"RS\r")
    assert {op: _num(sim, op) for _, op, _, _ in SETTINGS} == {
        op: burned for _, op, burned, _ in SETTINGS
    }
    sim.feed(b"RS -1\r")  # the soft master reset: factory values, the flash kept
    assert {op: _num(sim, op) for _, op, _, _ in SETTINGS} == factory
    sim.feed(b"RS\r")
    assert _num(sim, "_KPA") == 12.0


def test_a_setting_changed_after_the_burn_is_lost_at_rs(factory: dict[str, float]) -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "KPA=12")
    sim.feed(b"RS\r")
    assert _num(sim, "_KPA") == factory["_KPA"]  # never burned: the factory value


def test_the_master_reset_erases_what_was_burned(factory: dict[str, float]) -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "KPA=12", "LDA=3", "x=5")
    _burn(sim, "BN")
    _burn(sim, "BV")
    sim.feed(b'DL\r#AUTO\rMG "auto"\rEN\r\\')
    _burn(sim, "BP")
    assert sim.feed(b"\x12\x13\r") == b":"
    assert _num(sim, "_KPA") == factory["_KPA"]
    sim.feed(b"RS\r")  # nothing burned is left to restore
    assert (_num(sim, "_KPA"), _num(sim, "_LDA")) == (factory["_KPA"], factory["_LDA"])
    assert sim.feed(b"UL\r") == b"\x1a:"
    assert sim.feed(b"x=?\r") == b"?"  # no such variable


def test_rs_brings_back_the_burned_program_and_loses_one_only_downloaded() -> None:
    sim = SimController("DMC-4040")
    sim.feed(b"DL\r#ONE\rEN\r\\")
    sim.feed(b"RS\r")
    assert sim.feed(b"UL\r") == b"\x1a:"  # never burned: gone
    sim.feed(b"DL\r#ONE\rEN\r\\")
    _burn(sim, "BP")
    sim.feed(b"DL\r#TWO\rEN\r\\")
    sim.feed(b"RS\r")
    assert sim.feed(b"UL\r") == b"#ONE\r\nEN\r\n\x1a:"


def test_rs_brings_back_the_burned_variables_and_arrays_only() -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "x=5", "DM a[3]", "a[1]=7")
    _burn(sim, "BV")
    _sent(sim, "x=9", "y=1", "a[1]=8")
    sim.feed(b"RS\r")
    assert (_num(sim, "x"), _num(sim, "a[1]")) == (5.0, 7.0)
    assert sim.feed(b"y=?\r") == b"?"  # not burned: gone


def test_a_burned_motor_off_comes_back_at_rs() -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "MO A")
    _burn(sim, "BN")
    _sent(sim, "SH A")
    sim.feed(b"RS\r")
    assert (_num(sim, "_MOA"), _num(sim, "_MOB")) == (1.0, 0.0)


def test_a_burned_gear_ratio_gears_the_follower_again_at_rs() -> None:
    sim = SimController("DMC-4040")
    _sent(sim, "GA ,CA", "GR ,0.5")
    _burn(sim, "BN")
    _sent(sim, "GR ,0")
    sim.feed(b"RS\r")
    assert sim.feed(b"GR ?,?\r") == b" 0.0000, 0.5000\r\n:"
    _sent(sim, "PR 2000", "BG A")
    sim.advance(1.0)
    assert (_num(sim, "_RPA"), _num(sim, "_RPB")) == (2000.0, 1000.0)
