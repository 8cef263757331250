"""The reprs a user sees at a prompt are short and say what the object is: a plan of a scaled
axis in its unit (not its arrays), the interrupts' state, a model's name and key numbers (not
its 80 fields and the prose of its assumptions), a contour's result (not every increment), a
recording with how many values it holds.
"""

from __future__ import annotations

import math

import numpy as np

import galil
from galil.contour import sample_path
from galil.testing import simulated
from galil.units import ureg

mm, s = ureg.mm, ureg.s


def test_a_plan_of_a_scaled_axis_shows_its_unit_not_its_arrays() -> None:
    with simulated("DMC-4040") as dmc:
        x = dmc.A.set_scale(counts_per=2000 / mm)
        text = repr(x.plan_to(12.5 * mm))
    assert "array" not in text
    assert len(text) < 200
    assert text.startswith("UnitProfile(shape='trapezoid', duration=1.09766, samples=1124,")
    assert "end=12.5 mm" in text
    assert "peak_speed=12.5 mm / s" in text
    assert "counts 0 -> 25000" in text


def test_the_interrupts_say_their_state() -> None:
    with simulated("DMC-4040") as dmc:
        text = repr(dmc.interrupts)
    assert text == "<Interrupts of DMC-4040: not enabled, 0 waiting, 0 dropped>"


def test_a_model_and_an_identity_are_one_line_of_key_numbers() -> None:
    with simulated("DMC-4040") as dmc:
        model, identity = repr(dmc.model), repr(dmc.identity)
    assert model.startswith("<ModelSpec DMC-4040 (DMC-40x0): axes ABCD, SP max 22000000,")
    assert "8 threads" in model
    assert len(model) < 200
    assert "assumptions" not in identity
    assert len(identity) < 300
    assert model in identity
    rio = repr(galil.get_model("RIO-47100"))
    assert "no axes" in rio
    assert "SP max" not in rio


def test_a_contour_result_says_its_size_not_every_increment() -> None:
    with simulated() as dmc:
        ts = dmc.sample_period

        def path(t: np.ndarray) -> np.ndarray:
            return 6000 * t / 0.12 - 6000 / (2 * math.pi) * np.sin(2 * math.pi * t / 0.12)

        result = dmc.contour("A", sample_path(path, duration=0.12, dt=2, sample_period=ts), dt=2)
    text = repr(result)
    assert "array" not in text
    assert len(text) < 200
    assert text.startswith("ContourResult(axes='A', segments=31, dt=2, duration=0.121094 s,")
    assert "ends={'A': 6000}" in text


def test_a_recording_says_how_many_values_it_holds() -> None:
    with simulated() as dmc:
        recording = dmc.capture(["_RPA", "_TPA"], seconds=0.1).wait()
    assert len(recording) == 53
    text = repr(recording)
    assert text.startswith("Recording(sources=('_RPA', '_TPA'), 53 values each, every=2,")
