"""Model table lookups and ^R^V identification."""

from __future__ import annotations

import pytest

from galil import predict
from galil.errors import InvalidArgument, LimitError
from galil.models import INT32_MAX, MODELS, get_model, parse_identity
from galil.protocol import commands as cmds
from galil.testing import nothing_sent, simulated


@pytest.mark.parametrize(
    ("reply", "name", "family", "axes", "firmware"),
    [
        ("DMC1806 Rev 1.0b", "DMC-1806", "DMC-18x6", "ABCDEFGH", "1.0b"),
        ("DMC4040 Rev 1.2f", "DMC-4040", "DMC-40x0", "ABCD", "1.2f"),
        ("DMC2183 Rev 1.0o-CM", "DMC-2183", "DMC-21x3", "ABCDEFGH", "1.0o-CM"),
        (" DMC4080 Rev 1.2f\r\n", "DMC-4080", "DMC-40x0", "ABCDEFGH", "1.2f"),
        ("DMC4183 Rev 1.0a", "DMC-4183", "DMC-41x3", "ABCDEFGH", "1.0a"),
        ("DMC4123 Rev 1.0a", "DMC-4123", "DMC-41x3", "AB", "1.0a"),
        ("DMC2143 Rev 1.0", "DMC-2143", "DMC-21x3", "ABCD", "1.0"),
        ("DMC1846 Rev 1.0", "DMC-1846", "DMC-18x6", "ABCD", "1.0"),
        ("DMC1842 Rev 1.0", "DMC-1842", "DMC-18x2", "ABCD", "1.0"),
        ("DMC1822 Rev 1.0", "DMC-1822", "DMC-18x2", "AB", "1.0"),
        ("DMC30010 Rev 1.2a", "DMC-30010", "DMC-30010", "A", "1.2a"),
        ("DMC2280 Rev 1.0o-CM", "DMC-2280", "DMC-21x3", "ABCDEFGH", "1.0o-CM"),
    ],
)
def test_parse_identity(reply: str, name: str, family: str, axes: str, firmware: str) -> None:
    ident = parse_identity(reply)
    assert ident.model.name == name
    assert ident.model.family == family
    assert ident.model.axes == axes
    assert ident.firmware == firmware
    if ident.model.qz is not None:
        assert ident.model.qz[0] == len(axes)


@pytest.mark.parametrize("reply", ["", "hello", "Rev 1.0", "DMC Rev 1.0"])
def test_parse_identity_refuses(reply: str) -> None:
    with pytest.raises(InvalidArgument):
        parse_identity(reply)


def test_lookup_is_case_and_dash_insensitive() -> None:
    for spec in {s.name: s for s in MODELS.values()}.values():
        assert get_model(spec.name) is spec
        assert get_model(spec.name.lower()) is spec
        assert get_model(spec.name.replace("-", "")).name == spec.name


def test_family_names() -> None:
    assert get_model("DMC-18x2").family == "DMC-18x2"
    assert get_model("DMC-21x3").name == "DMC-2183"
    assert get_model("DMC-40x0").name == "DMC-4040"


def test_record_sizes_match_qz() -> None:
    assert get_model("DMC-4040").record_size == 82 + 4 * 36
    assert get_model("DMC-2183").record_size == 44 + 8 * 28
    assert get_model("DMC-1500").record_size is None


def test_sample_periods() -> None:
    assert get_model("DMC-1500").sample_period == 0.002
    assert get_model("DMC-1500").sample_period_for(500) == 0.002
    assert get_model("DMC-4040").sample_period == pytest.approx(1 / 1024)
    assert get_model("DMC-4040").sample_period_for(500) == pytest.approx(1 / 2048)


def test_axis_letters_and_aliases() -> None:
    m1500 = get_model("DMC-1500")
    assert m1500.axis_letter("X") == "A"
    assert m1500.axis_letter("w") == "D"
    m4040 = get_model("DMC-4040")
    assert m4040.axis_letter("c") == "C"
    with pytest.raises(InvalidArgument):
        m4040.axis_letter("E")
    with pytest.raises(InvalidArgument):
        m4040.axis_letter("X")


def test_every_models_largest_accel_is_a_number_the_controller_holds() -> None:
    for name, spec in MODELS.items():
        assert spec.ac_max <= INT32_MAX, name
        assert spec.ac_max % spec.ac_resolution == 0, name


def test_the_500x0s_largest_accel_is_accepted_and_one_step_more_refused_unsent() -> None:
    with simulated("DMC-50040") as dmc:
        top = dmc.model.ac_max
        dmc.A.accel = top
        assert dmc.A.accel == top
        with nothing_sent(dmc), pytest.raises(LimitError):
            dmc.A.accel = top + dmc.model.ac_resolution


def test_the_speed_and_accel_steps_follow_tm_in_counts_per_second() -> None:
    # DMC-4103 command reference (docs/decisions/0025), SP and JG: "resolution = 2*(1000/TM)",
    # "With TM 250 the resolution of the SP command is 8 cnts/second"; AC and DC: "Resolution =
    # Min = 1024*(1000/TM)^2", 4096 counts/s² at TM 500. SP stays in counts/s at any TM.
    m = get_model("DMC-4040")
    assert [m.speed_resolution(t) for t in (1000, 250, 500, 2000)] == [2, 8, 4, 1]
    assert m.speed_resolution() == m.sp_resolution == 2
    assert m.accel_resolution(500) == m.accel_min(500) == 4096
    assert m.accel_resolution(2000) == m.accel_min(2000) == 256
    assert m.accel_resolution() == m.ac_resolution == 1024
    fixed = get_model("DMC-1500")  # a fixed sample: no other TM to scale to
    assert fixed.speed_resolution(250) == fixed.sp_resolution
    assert fixed.accel_resolution(250) == fixed.ac_resolution


def test_the_41x3_speed_and_tm_ranges_are_its_command_references() -> None:
    # DMC-4103 reference: SP 0 ... 15,000,000 counts/s (servo); TM 125 ... 5,000 µs, the
    # minimum 125/250/375/500 for 1-2/3-4/5-6/7-8 axes (the 40x0's: 62.5 ... 187.5, 20,000).
    assert get_model("DMC-4143").sp_max == 15_000_000
    assert get_model("DMC-4143").tm_range == (250.0, 5000.0)
    assert get_model("DMC-4123").tm_range == (125.0, 5000.0)
    assert get_model("DMC-4183").tm_range == (500.0, 5000.0)
    assert get_model("DMC-4040").tm_range == (125.0, 20000.0)
    with simulated("DMC-4143") as dmc, nothing_sent(dmc), pytest.raises(LimitError):
        dmc.A.speed = 15_000_002


def test_the_accelera_gains_are_the_command_references() -> None:
    # DMC-4103 reference KP "0 1,023.875 6 1/8", KI "0 255.999 0 1/1,024", KD
    # "0 4,095.875 64 1/8"; DMC-40x0 reference pp.140-142 (KI "0 to 255 ... resolution of
    # 0.001"). None of these is an assumption any more.
    for name in ("DMC-4040", "DMC-4143"):
        m = get_model(name)
        assert (m.kp_max, m.ki_max, m.kd_max) == (1023.875, 255.999, 4095.875)
        assert (m.gain_resolution, m.ki_resolution) == (1 / 8, 1 / 1024)
        assert not [a for a in m.assumptions if "KI" in a or "KD" in a]


def test_the_41x3_cd_range_is_its_command_references() -> None:
    # DMC-4103 reference, CD: "n -32,768 32,767 0 1 Contour position segment" (round 2 of
    # docs/decisions/0025); the 40x0 keeps ±32,000 and the 18x6 ±32,762. The host's builder,
    # the simulator and the predictor all read model.cd_range.
    m = get_model("DMC-4143")
    assert m.cd_range == (-32_768, 32_767)
    assert get_model("DMC-4040").cd_range == (-32_000, 32_000)
    assert get_model("DMC-1806").cd_range == (-32_762, 32_762)
    assert cmds.cd(A=32_767, B=-32_768, model=m).text == "CD 32767,-32768"
    for bad in (32_768, -32_769):
        with pytest.raises(LimitError):
            cmds.cd(A=bad, model=m)
    with pytest.raises(LimitError):
        cmds.cd(A=32_767, model=get_model("DMC-4040"))
    predict.check_contour([32_767, -32_768], 8, model="DMC-4143")
    with pytest.raises(LimitError) as info:
        predict.check_contour([5, -32_769], 8, model="DMC-4143")
    assert (info.value.name, info.value.limit) == ("CD", -32_768)


def test_the_41x3_loop_limits_are_its_command_references() -> None:
    # DMC-4103 reference: KS "0.5 64 2 1/32"; IL "-9.9982 9.9982 9.9982" (negative freezes the
    # integrator during a move); TL "0 9.9982 9.9982"; ER "-1 2,147,483,647 16,384" (0: error
    # output on, -1: off).
    m = get_model("DMC-4143")
    assert m.ks_range == (0.5, 64.0)
    assert (m.il_min, m.il_max, m.tl_max, m.er_min) == (-9.9982, 9.9982, 9.9982, -1)
    assert cmds.il(A=-3, B=9.9982, model=m).text == "IL -3,9.9982"
    assert cmds.tl(A=9.9982, model=m).text == "TLA=9.9982"
    assert cmds.er(A=-1, B=0, model=m).text == "ER -1,0"
    with pytest.raises(LimitError):
        cmds.ks(A=0.25, model=m)
    with pytest.raises(LimitError):
        cmds.il(A=-10, model=m)
    forty = get_model("DMC-4040")  # unchanged: no 40x0 page gives these
    assert cmds.ks(A=0.25, model=forty).text == "KSA=0.25"
    for build in (lambda: cmds.il(A=-3, model=forty), lambda: cmds.er(A=0, model=forty)):
        with pytest.raises(LimitError):
            build()
    with simulated("DMC-4143") as dmc:
        dmc.A.integrator_limit = -3
        dmc.A.error_limit = -1
        assert dmc.A.integrator_limit == -3
        assert dmc.A.error_limit == -1
        with nothing_sent(dmc), pytest.raises(LimitError, match="KS"):
            dmc.A.stepper_smoothing = 0.25


def test_the_41x3_op_takes_one_field_for_all_its_outputs() -> None:
    # DMC-4103 reference, OP: "n 0 65,535 0 1 Decimal representation: General Outputs 1-16 /
    # On a 1-4 axis controller, max is 255 ($FF) for outputs 1-8 only"; "Set High Byte
    # OP65280 (OP$FF00)" sets 9-16.
    eight = get_model("DMC-4183")
    assert eight.op_bits == 16
    assert cmds.op(65_280, model=eight).text == "OP 65280"
    with pytest.raises(InvalidArgument):
        cmds.op(0, 255, model=eight)
    with pytest.raises(LimitError):
        cmds.op(256, model=get_model("DMC-4143"))
    assert cmds.op(0, 255, model=get_model("DMC-4080")).text == "OP 0,255"  # 8-bit banks


def test_no_models_speed_step_exceeds_the_planners_shortcut() -> None:
    # (planning skips the step lookup for speeds at or above this bound)
    from galil.motion import _LARGEST_SPEED_STEP

    for spec in MODELS.values():
        assert spec.speed_resolution(spec.tm_range[0]) <= _LARGEST_SPEED_STEP


def test_limit_disable_is_on_the_models_the_ld_page_lists_only() -> None:
    # DMC-4103 reference: "LD applies to DMC4000,DMC4200,DMC4103,DMC1806,DMC30010,DMC50000,
    # DMC52000,EDD37010": not the 18x2, 21x3 (nor the older 1500, 1700/1800), nor a RIO.
    having = {s.family for s in MODELS.values() if s.has_limit_disable}
    assert having == {"DMC-40x0", "DMC-41x3", "DMC-42x0", "DMC-18x6", "DMC-30010", "DMC-500x0"}
    assert get_model("DMC52040").has_limit_disable
    assert not parse_identity("DMC9940 Rev 1.0a").model.has_limit_disable  # generic
