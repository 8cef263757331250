"""``axis.encoder_config`` (CE) through the public API on ``sim://``, and its typed value
:class:`galil.EncoderConfig` (decision 0048)."""

from __future__ import annotations

import asyncio

import pytest

import galil
import galil.aio as aio
from galil import EncoderConfig, EncoderType
from galil.testing import nothing_sent, transcript


def test_every_ce_value_round_trips_through_its_main_and_aux_types() -> None:
    for n in range(16):
        config = EncoderConfig.of(n)
        assert int(config) == n == config
        assert EncoderConfig(config.main, config.aux) == n
    both = EncoderConfig(main=EncoderType.QUADRATURE_REVERSED, aux=EncoderType.QUADRATURE_REVERSED)
    assert int(both) == 10  # the reference: "n = 10 implies 2 + 8"
    assert EncoderConfig.of(6).main is EncoderType.QUADRATURE_REVERSED
    assert EncoderConfig.of(6).aux is EncoderType.PULSE_DIRECTION
    assert (EncoderType.PULSE_DIRECTION_REVERSED.reversed, EncoderType.QUADRATURE.reversed) == (
        True,
        False,
    )
    assert repr(EncoderConfig()) == "EncoderConfig(main=QUADRATURE, aux=QUADRATURE)"


@pytest.mark.parametrize("bad", [4, -1, True, 1.5, "0"])
def test_an_encoder_type_that_is_not_one_is_refused(bad: object) -> None:
    with pytest.raises(galil.InvalidArgument):
        EncoderConfig(main=bad)  # type: ignore[arg-type]
    with pytest.raises(galil.InvalidArgument):
        EncoderConfig(aux=bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [16, -1, 2.5, True])
def test_a_ce_value_out_of_range_is_refused(bad: float) -> None:
    with pytest.raises(galil.InvalidArgument):
        EncoderConfig.of(bad)


def test_encoder_config_sends_ce_and_reads_the_setting_back(dmc: galil.Controller) -> None:
    with transcript(dmc) as sent:
        dmc.A.encoder_config = EncoderConfig(main=EncoderType.QUADRATURE_REVERSED)
        dmc.B.encoder_config = 13
    assert sent.lines == ["CEA=2", "CEB=13"]
    assert dmc.A.encoder_config == EncoderConfig(main=EncoderType.QUADRATURE_REVERSED)
    assert isinstance(dmc.B.encoder_config, EncoderConfig)
    assert dmc.B.encoder_config.aux is EncoderType.PULSE_DIRECTION_REVERSED
    with nothing_sent(dmc), pytest.raises(galil.InvalidArgument, match="CE"):
        dmc.A.encoder_config = 16


def test_encoder_config_is_refused_unsent_while_the_librarys_jog_runs(
    dmc: galil.Controller,
) -> None:
    # CE: "Not Valid while in motion" (the simulator: TC 7).
    handle = dmc.A.jog(10_000)
    with pytest.raises(galil.InvalidArgument, match="CE"):
        dmc.A.encoder_config = 2
    dmc.stop("A")
    handle.wait(timeout=5)
    assert dmc.A.encoder_config == 0


def test_the_async_twin_sets_and_reads_encoder_config() -> None:
    async def run() -> EncoderConfig:
        async with await aio.connect("sim://DMC4040") as dmc:
            await dmc.A.set_encoder_config(EncoderConfig(aux=EncoderType.PULSE_DIRECTION))
            return await dmc.A.encoder_config()

    assert asyncio.run(run()) == 4
