"""``Controller.reset()`` and what was burned (decision 0052): after ``RS`` the controller
runs with the burned parameters, program and variables, and the library reads them afresh."""

from __future__ import annotations

import pytest

import galil
from galil.testing import simulated
from galil.tuning import LimitDisable


def test_settings_saved_come_back_after_reset_and_unsaved_changes_do_not() -> None:
    with simulated() as dmc:
        dmc.A.limit_disable = 3
        dmc.command("TM 500")
        dmc.save()
        dmc.A.limit_disable = 0
        dmc.B.limit_disable = 1
        dmc.command("TM 250")
        dmc.reset()
        assert (dmc.A.limit_disable, dmc.B.limit_disable) == (LimitDisable(3), LimitDisable(0))
        assert dmc.sample_period == pytest.approx(500 / 1_024_000)  # the burned TM, read again
        dmc.servo_here()
        assert dmc.A.move_by(5000).wait().deviation == {"A": 0}


def test_after_reset_only_the_saved_program_and_variables_are_there() -> None:
    with simulated() as dmc:
        dmc.programs.download("#KEPT\nEN\n")
        dmc.save_program()
        dmc.programs.download("#LOST\nEN\n")
        dmc.command("kept=5")
        dmc.save_variables()
        dmc.command("lost=6")
        dmc.reset()
        assert "#KEPT" in dmc.programs.upload()
        assert dmc.query_number("MG kept") == 5.0
        with pytest.raises(galil.GalilError):
            dmc.query_number("MG lost")
