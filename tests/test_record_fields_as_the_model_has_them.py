"""A data record's axis blocks are decoded as the model has them (an 18x2's last two bytes are
reserved where a 21x3's are the analog input: both send QZ 4,24,16,28), and its velocity is the
controller's raw 64 x TV, said by RECORD_VELOCITY_SCALE, which decode_fields divides by."""

from __future__ import annotations

import numpy as np
import pytest

import galil
from galil.protocol.records import RECORD_VELOCITY_SCALE, record_to_dict
from galil.testing import sim_of, simulated


def test_a_dmc_1842_record_has_no_analog_input_in_its_axis_blocks() -> None:
    with simulated("DMC-1842") as dmc:
        sim_of(dmc).set_analog_input(1, 2.5)
        rec = dmc.record()
        assert "analog_in" not in rec["A"].dtype.names
        assert rec["A"]["reserved"] == 0
        assert "reserved" in dmc.record("A", as_dict=True)["A"]
        with dmc.records(period=8) as stream:
            records = stream.take(3)
        assert records["A"].dtype.names[-1] == "reserved"


def test_a_dmc_2143_record_keeps_the_analog_input_of_its_axis_blocks() -> None:
    with simulated("DMC-2143") as dmc:
        sim_of(dmc).set_analog_input(1, 2.5)
        assert dmc.record()["A"]["analog_in"] > 0


@pytest.mark.parametrize("model", ["DMC-4040", "DMC-1842"])
def test_a_records_velocity_is_64_times_tv_and_decode_fields_gives_counts_per_second(
    model: str,
) -> None:
    with simulated(model) as dmc:
        dmc.A.jog(20_000)
        dmc.sleep(0.3)  # at speed
        rec = dmc.record()
        tv = dmc.query_operands(["_TVA"])[0]
        assert tv != 0
        assert RECORD_VELOCITY_SCALE == 64
        assert rec["A"]["velocity"] == RECORD_VELOCITY_SCALE * tv
        assert record_to_dict(rec)["A"]["velocity"] == RECORD_VELOCITY_SCALE * tv
        assert galil.decode_fields(rec).axes["A"].velocity == tv
        with dmc.records(period=4) as stream:
            records = stream.take(3)
        np.testing.assert_array_equal(
            records["A"]["velocity"] / RECORD_VELOCITY_SCALE,
            [galil.decode_fields(r).axes["A"].velocity for r in records],
        )
        dmc.A.stop()
