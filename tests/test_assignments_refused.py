"""A misspelt setting is refused, with the name meant, instead of binding an attribute that
nothing reads (decision 0091); the settings themselves are assigned as before."""

from __future__ import annotations

from typing import Any

import pytest

import galil
from galil.testing import sim_of, simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


@pytest.mark.parametrize(
    ("name", "meant"),
    [
        ("soft_limit", "soft_limits"),
        ("acceleration", "accel"),
        ("deceleration", "decel"),
        ("Kp", "kp"),
        ("max_speed", "speed"),
    ],
)
def test_a_misspelt_axis_setting_is_refused_with_the_name_meant(name: str, meant: str) -> None:
    with simulated() as dmc:
        x = dmc.A.set_scale(2000 / mm)
        sent = len(sim_of(dmc).command_log)
        with pytest.raises(galil.GalilAttributeError) as info:
            setattr(x, name, 3 * mm)
        assert isinstance(info.value, AttributeError)
        assert meant in info.value.suggestions
        assert f"{meant!r}" in str(info.value)
        assert name not in vars(x)
        assert len(sim_of(dmc).command_log) == sent


def test_a_misspelt_controller_setting_is_refused_with_the_name_meant() -> None:
    with simulated() as dmc:
        with pytest.raises(galil.GalilAttributeError, match="'switch_polarity'"):
            dmc.switch_polarity2 = galil.SwitchPolarity(limit=1)  # type: ignore[attr-defined]
        with pytest.raises(galil.GalilAttributeError):
            dmc.A = dmc.B  # type: ignore[misc]
        assert dmc.A.letter == "A"


def test_the_settings_are_still_assigned_and_sent() -> None:
    with simulated() as dmc:
        x = dmc.A.set_scale(2000 / mm)
        x.soft_limits = (-5 * mm, 5 * mm)
        x.speed = 10 * mm / s
        x.kp = 8
        dmc.switch_polarity = galil.SwitchPolarity(limit=-1)
        dmc.timeout = 2.0
        assert float(dmc.command("MG _FLA")) == 10000
        assert float(dmc.command("MG _BLA")) == -10000
        assert x.speed.m_as(mm / s) == pytest.approx(10)
        assert x.kp == 8
        assert dmc.switch_polarity.limit == -1
        assert dmc.link.timeout == 2.0
        with pytest.raises(galil.LimitError):
            x.move_to(20 * mm)


def test_a_read_only_property_or_a_method_is_refused_as_no_setting() -> None:
    with simulated() as dmc:
        x = dmc.A
        with pytest.raises(galil.GalilAttributeError, match="read-only"):
            x.velocity = 3  # type: ignore[misc]
        with pytest.raises(galil.GalilAttributeError, match="not a setting"):
            x.move_to = None  # type: ignore[assignment,method-assign]
        assert callable(x.move_to)


def test_the_rooms_and_handles_refuse_a_new_public_name() -> None:
    with simulated() as dmc:
        move = dmc.A.move_by(1000)
        move.wait()
        with dmc.records(32) as stream:
            objects: list[Any] = [
                dmc.io, dmc.io.outputs, dmc.programs, dmc.arrays, dmc.variables,
                dmc.interrupts, move, stream,
            ]  # fmt: skip
            for obj in objects:
                with pytest.raises(galil.GalilAttributeError):
                    obj.timout = 5
                assert "timout" not in vars(obj)
        # Private names stay the objects' own business.
        move._note = 1  # type: ignore[attr-defined]


def test_the_attributes_the_library_binds_are_read_only_to_the_user() -> None:
    """Before: ``dog.thread = 3`` changed the repr but not the controller (the stop then left
    the routine running on thread 7, with no heartbeat), and ``cap.count = 5000`` made
    ``wait()`` read past its arrays."""
    with simulated() as dmc:
        dog = dmc.watchdog(0.5)
        cap = dmc.capture(["_RPA"], count=10)
        gear = dmc.B.gear_to(dmc.A, 1.0)
        move = dmc.A.move_by(1000)
        with dmc.records(32) as stream:
            bound: list[tuple[Any, str]] = [
                (dog, "timeout"), (dog, "interval"), (dog, "thread"),
                (cap, "count"), (cap, "every"), (cap, "sources"), (cap, "arrays"),
                (cap, "link"), (cap, "start_sample"), (cap, "result"),
                (dmc, "link"), (dmc, "io"), (dmc, "programs"), (dmc, "arrays"),
                (dmc, "variables"), (dmc, "interrupts"), (dmc, "routines"), (dmc, "tracker"),
                (dmc, "messages_room"), (dmc, "records_room"), (dmc, "identity"), (dmc, "echo"),
                (dmc.A, "letter"), (dmc.programs, "link"), (dmc.programs, "routines"),
                (dmc.arrays, "link"), (dmc.variables, "link"), (dmc.io.inputs, "first"),
                (dmc.io.inputs, "count"), (dmc.interrupts, "link"), (dmc.interrupts, "queue"),
                (dmc.interrupts, "mask"), (stream, "period"), (stream, "method"),
                (stream, "dropped"), (stream, "missed"), (stream, "gaps"), (stream, "gap_count"),
                (move, "kind"),
                (move, "started_at"), (gear, "follower"), (gear, "master"),
            ]  # fmt: skip
            sent = len(sim_of(dmc).command_log)
            for obj, name in bound:
                before = getattr(obj, name)
                with pytest.raises(galil.GalilAttributeError, match="is read-only") as info:
                    setattr(obj, name, 3)
                assert info.value.attribute == name
                after = getattr(obj, name)
                copy = isinstance(before, list) and after == before  # (stream.gaps: a copy)
                assert after is before or copy, (type(obj).__name__, name)
                assert name not in vars(obj)
            assert len(sim_of(dmc).command_log) == sent  # nothing sent
        move.wait()
        gear.off()
        assert len(cap.wait()) == 10  # its own count
        dog.stop()
        assert dmc.query_operands(["_XQ7"]) == [-1]  # the routine halted where it ran
