"""Per-model capabilities of Galil DMC controllers.

Values come from ``shared/reference/galil-protocol.md``. Where the sources are unsure the entry
says which assumption we make (``assumptions``) so a reader can see what is measured and what is
a guess; change the table, not the code, when a manual or a hardware log pins a value down.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
from dataclasses import dataclass, field

from galil.errors import InvalidArgument, decimal_hint

__all__ = [
    "ETHERNET_BYTES_PER_S",
    "INT32_MAX",
    "INT32_MIN",
    "IT_RANGE",
    "MODELS",
    "MOTOR_TYPES",
    "ModelSpec",
    "for_firmware",
    "generic_model",
    "get_model",
    "parse_identity",
    "tm_of",
]

_ALL_AXES = "ABCDEFGH"

#: The controller's 32-bit integer registers (positions, PR/PA/IP, FL/BL, CD sums).
INT32_MIN = -2_147_483_648
INT32_MAX = 2_147_483_647
#: Sustained command bytes per second assumed for an Ethernet link. Each command line waits for
#: its ':' before the next goes out, so the round trip (about 1 ms on a LAN) limits the rate far
#: below the wire speed; 64 kB/s is a conservative guess, not a measurement.
ETHERNET_BYTES_PER_S = 64_000.0
#: IT (independent smoothing) range on every model found; resolution 1/256.
IT_RANGE = (0.004, 1.0)
#: MT values and what they mean (EPICS writeInt32 MT table; BLISS constants agree).
MOTOR_TYPES: dict[float, str] = {
    1.0: "servo",
    -1.0: "servo, reversed",
    1.5: "PWM servo",
    -1.5: "PWM servo, reversed",
    -2.0: "stepper, active-high step pulses",
    2.0: "stepper, active-low step pulses",
    -2.5: "stepper, active-high step pulses, reversed direction",
    2.5: "stepper, active-low step pulses, reversed direction",
    4.0: "servo 2PB",
    -4.0: "servo 2PB, reversed",
    10.0: "EtherCAT position",
    11.0: "EtherCAT torque",
    -11.0: "EtherCAT torque, reversed",
}
_MT_STANDARD = frozenset({1.0, -1.0, 1.5, -1.5, 2.0, -2.0, 2.5, -2.5})
#: MT 4 / -4 "Servo 2PB" (EPICS writeInt32's MT table, which drives every model it knows):
#: taken on the Accelera-class families (40x0, 41x3, 42x0, 500x0, 18x6, 30010); the Optima-era
#: cards (1500, 1700/1800, 18x2) and the 21x3 keep the standard set (see their assumptions).
_MT_2PB = _MT_STANDARD | {4.0, -4.0}
_MT_2PB_ASSUMPTION = (
    "MT 4 / -4 ('Servo 2PB', EPICS's MT table) taken: EPICS names no model for it, and no"
    " command reference page of this family was seen"
)
_MT_NO_2PB_ASSUMPTION = (
    "MT 4 / -4 ('Servo 2PB', EPICS's MT table) refused: EPICS names no model for it and no"
    " source gives it for this (pre-Accelera) family; refused as the narrower choice"
)
#: Interrogation reply formats (``KP ?``, ``TM ?``): the command references' "Default Format",
#: m.n = digits before and after the point. KP and KD 4.2 (DMC-40x0 command reference KP p.142,
#: KD p.140; DMC-18x6 manc18x6-127, -125; Optima DMC-1xxx/18x2 optcom-125; DMC-1000/1500 KP
#: p.79), KI 4.4 (DMC-40x0 p.141; DMC-18x6 manc18x6-126), TM 1.0 (DMC-40x0 p.236; DMC-18x6
#: manc18x6-206). ``MG _KPA`` prints in the variable format (VF) instead.
_REPLY_FORMATS = {"KP": "4.2", "KI": "4.4", "KD": "4.2", "TM": "1.0"}
#: The Optima DMC-1xxx/18x2 reference gives KI format 4.0 (optcom-126; DMC-1400 reference too).
_OPTIMA_REPLY_FORMATS = {**_REPLY_FORMATS, "KI": "4.0"}
#: KI on the Optima DMC-1xxx/18x2: "0 to 2047.875 with a resolution of 1/128" (optcom-126; the
#: DMC-1400 reference's KI page says the same, manualsdump galil-dmc-1400/152344/128). EPICS
#: (GalilAxis.cpp setIGain) caps every model but the 2xxx at 255.999, the 40x0/41x3 maximum;
#: its comment names only the 21x3, 41x3 and 40x0, so the vendor page is taken for the Optima.
_OPTIMA_KI_MAX = 2047.875
_OPTIMA_KI_RESOLUTION = 1 / 128
#: SP, JG, AC and DC under another TM (docs/decisions/0025). The DMC-4103 command reference's
#: TM page: "The following commands are automatically scaled to adjust for changes in sample
#: time" (AC, DC, JG, SP among them); its SP page: "The resolution of the SP command is
#: dependent upon the update rate setting (TM). With the default rate of TM 1000 the
#: resolution is 2 cnts/second. ... resolution = 2*(1000/TM)" (JG: the same words); its AC and
#: DC pages: "Resolution = Min = 1024*(1000/TM)^2" (TM 500: 4096 counts/s²). The units stay
#: counts/s and counts/s²; only the step (and AC/DC's minimum) follows TM.
_TM_REFERENCE = 1000.0
#: OP's fields per model, where the sources stop (documented, not settled; see ``assumptions``).
_OP_ASSUMPTION = (
    "OP fields: 8-bit banks (OP n0,n1: outputs 1-8, 9-16). Sourced only for outputs 1-8 (DMC-3425"
    " user manual p.180: 'OP m,a,b,c,d', m = outputs 1-8, a-d = extended I/O 17-80 in 16-bit"
    " groups) and for the RIO (IRTF notes: 'OP $00,$01' sets DO8); how a DMC with 16 general"
    " outputs takes outputs 9-16 is not found for this family (the DMC-4103 reference's OP"
    " takes one 16-bit field, 'General Outputs 1-16'; its page lists other families, but"
    " its table is the 4103's), and extended I/O (CO) is not modelled"
)

#: Program memory taken from the DMC-40x0 defaults (ModelSpec.program_lines ...).
_MEMORY_ASSUMPTION = (
    "program memory as the DMC-40x0 as remembered from its user manual (2000 lines, 510"
    " labels, 510 variables, 30 arrays of 24,000 elements together): no source for this"
    " family"
)
#: SP maxima no page gives (the 18x2, 18x6, 30010 and 500x0 entries).
_SP_ASSUMPTION = "SP maximum {} counts/s: not sourced for this family"

_NO_HV_ASSUMPTION = (
    "no HV: the Optima HM page names none (stage 2 runs 'slowly', a stepper's at 256"
    " counts/s); a servo's slow stages are assumed to run at 256 counts/s too"
)

#: VS, VA and VD under another TM (docs/decisions/0025, "Predictions at any TM").
_VECTOR_TM_ASSUMPTION = (
    "VS steps by 2*(1000/TM) counts/s and VA/VD by 1024*(1000/TM)^2 counts/s² (VA/VD's"
    " minimum too), as SP and AC do: the 4103 reference marks VS, VA and VD 'Scaled By TM'"
    " (its TM page lists them among the scaled commands) and gives them SP's and AC's"
    " resolution at TM 1000 (2, 1024), but states the formula only on the SP/JG and AC/DC"
    " pages"
)


def _check_tm(tm: object) -> float:
    """A TM in microseconds: a positive, finite real number (not a bool).

    Raises:
        InvalidArgument: anything else.
    """
    if type(tm) is float and 0 < tm < math.inf:  # the usual case, at once (NaN fails too)
        return tm
    if isinstance(tm, bool) or not isinstance(tm, numbers.Real):
        raise InvalidArgument(
            f"tm must be a number of microseconds, not {tm!r:.60}{decimal_hint(tm)}"
        )
    try:
        value = float(tm)
    except OverflowError:  # 10**400
        value = math.inf
    ok = math.isfinite(value) and value > 0
    if not ok:
        raise InvalidArgument(
            f"tm must be a positive, finite number of microseconds, not {tm!r:.60}"
        )
    return value


@dataclass(frozen=True)
class ModelSpec:
    """What one controller family can do.

    Attributes:
        name: canonical name, e.g. ``"DMC-4040"``.
        family: family name, e.g. ``"DMC-40x0"``.
        axes: axis letters in order (``"ABCD"``; ``"XYZW"`` on families that name them so).
        aliases: other letters the firmware accepts for the same axes (X=A, Y=B, Z=C, W=D).
        tm_default: TM at power-on in microseconds (1000 gives 1024 Hz: a sample lasts
            TM / 1,024,000 s). Where TM cannot be changed, the TM of the fixed sample, which
            ``TM ?`` and ``_TM`` answer (DMC-1500: 2048, its 2 ms).
        tm_adjustable: whether TM may be changed (the DMC-1500 has a fixed 2 ms sample); see
            :attr:`sample_period_fixed`.
        ac_min, ac_max, ac_resolution: AC/DC range in counts/s² at TM 1000; values round
            down to the resolution. AC and DC stay in counts/s² at any TM, but their step and
            minimum scale with it (:meth:`accel_resolution`, :meth:`accel_min`).
        sp_max, sp_resolution: SP/JG maximum and step in counts/s at TM 1000. SP and JG stay
            in counts/s at any TM; the step scales with it (:meth:`speed_resolution`).
        cd_max: largest CD increment per segment.
        cd_min: smallest (most negative) CD increment; ``None`` means ``-cd_max``. See
            :attr:`cd_range`.
        dt_range: allowed DT exponents (segment = 2**n samples).
        contour_buffer: contour segments the controller can queue (``_CM`` when empty).
        contour_dt_suffix: ``CD`` takes a segment's own DT as ``=n`` and ``CD 0=0`` ends
            contour mode. Without it (the DMC-1500/1700/18x2 manuals show only that form)
            ``DT 0`` then ``CD 0`` ends it, and a segment cannot carry its own DT.
        line_length: longest command line the controller accepts, in characters.
        mg_max: longest MG text.
        transports: buses the family offers.
        qz: the ``QZ`` reply (axes, general block, coordinated block, axis block bytes), or
            ``None`` when the family has no binary data record we know of.
        record_axis_analog: the last two bytes of a 28-byte axis block are the axis's
            analog input (gclib ``GDataRecord2103``); without it they are reserved (gclib
            ``GDataRecord1802``: "no analog in axis data").
        it_range: smoothing (IT) range.
        tm_min_by_axes: smallest TM (µs) of the normal firmware for 1-2, 3-4, 5-6 and 7-8
            axes (M40-CR p246); see :attr:`tm_range`.
        tm_max: largest TM (µs).
        tm_resolution: TM's step (µs). What the controller does with a TM off the step is
            not documented: the library refuses one before sending (docs/decisions/0102).
        dr_range: data-record period (``DR``) in samples, smallest and largest.
        dr_exponent: ``DR n`` takes an exponent, a period of ``2**n`` samples (the PCI
            18xx cards: GCLIBO, protocol §7); :func:`galil.protocol.commands.dr` is refused
            there (no exponent form is built).
        label_length: characters of a program label after ``#``.
        variable_length: characters of a variable or array name.
        threads: program threads (``XQ``).
        program_lines: lines of program memory (``DL``).
        labels: labels a program may hold (TC 62 "too many labels" beyond).
        variables: variables the controller holds (TC 67 beyond).
        arrays: arrays the controller holds (``DM``; TC 67 beyond).
        array_elements: array elements of all arrays together (``DM``; TC 66 beyond).
        record_exponents: ``RC n``: ``2**n`` samples between captured values, n in this
            range (DMC-1600/1700/1800 manuals: 1 to 8; ``RC 0`` stops; Galil's own
            record_position example: ``RC 1`` records at 512 Hz at TM 1000).
        record_arrays: arrays ``RA``/``RD`` record at once (DMC-1700/1800: eight).
        user_interrupts: ``UI n``: n from 0 to this value minus one (40x0 reference: 0-15).
        default_speed: SP and JG at power-on, counts/s.
        default_accel: AC and DC at power-on, counts/s².
        vector_buffer: LM/VM segments the coordinated-motion buffer holds (``_LMS`` when
            empty): 511 (EPICS ``GalilController.h``; Galil 2004 catalogue "up to 511 LI
            segments"); assumed the same on every family.
        vs_max: largest VS in counts/s; ``None`` means ``sp_max`` (assumption). VS has SP's
            resolution (QCoDeS 41x3: 2 ... 15,000,000 in steps of 2).
        va_max: largest VA/VD in counts/s²; ``None`` means ``ac_max``. VA/VD round down to
            ``ac_resolution`` like AC/DC (QCoDeS 41x3: 1024 ... 1,073,740,800 step 1024).
        li_max: largest |LI| increment per axis and segment (EPICS: 8,388,607 = 2**23 - 1).
        cr_radius: CR radius range in counts (DMC-1400 command reference: 10 ... 6,000,000).
        cr_angle_max: largest |θ| and |Δθ| of CR in degrees (DMC-1400 reference: 32,000).
        cr_angle_resolution: CR angle step in degrees (user manuals: 1/256 degree).
        cr_arc_max: largest |r·Δθ| of one CR, Δθ in degrees (DMC-1400 reference: 4.5e8).
        vector_distance_max: longest total sequence in counts (TC 31: "> 2 billion").
        vector_segment_min: shortest segment in counts before TC 30 "sequence segment too
            short"; 1 count is an assumption (no source gives the threshold).
        vt: whether the family has VT (vector smoothing). Sourced for the DMC-2x00 series
            (BLISS) and listed beside IT on the DMC-1000 and Optima references; the 40x0 user
            manual says IT smooths VM/LM moves instead, assumed for the Accelera families.
        gr_max: largest |GR| gear ratio (40x0 and 18x6 references: ±127).
        gr_resolution: GR step (40x0 reference: 1/65536).
        io_first: number of the first digital input, output and analog channel: 1 on DMC
            controllers (``@IN[1]``), 0 on the RIO (``@IN[0]``) (gclib field comments; EPICS).
        digital_inputs, digital_outputs: general-purpose digital inputs and outputs.
        op_bits: outputs one ``OP`` field sets: 8 (``OP n0,n1``, 8-bit banks) or 16 (one
            field for outputs 1-16, as the DMC-4103 reference's ``OP n``).
        analog_inputs: analog inputs (``@AN[n]``).
        analog_outputs: analog outputs (``AO n,v``); 0 where the model has none we know of.
        analog_in_range, analog_out_range: volts at the default AQ/DQ setting.
        dq_ranges: ``DQ n`` codes and the volts each sets on the analog outputs, where the
            model has ``DQ`` (the RIO-47120: 1 = 0-5 V, 2 = 0-10 V, 3 = ±5 V, 4 = ±10 V,
            RIO-UM p44); empty where it has none.
        analog_in_ranges: the inputs (by number) whose range differs from
            ``analog_in_range``, at the default AQ; :meth:`analog_input_range` reads them.
        reply_formats: format (``"4.2"``) of the interrogation replies ``KP ?``, ``KI ?``,
            ``KD ?`` and ``TM ?``, by command: the command reference's "Default Format"
            (sources at ``_REPLY_FORMATS``; families without a page of their own are assumed
            to share the DMC-40x0's). A whole part wider than m prints in full, so TM 1.0
            gives ``1000``: an assumption (the TM page's own default, 1000, does not fit one
            digit, so m cannot be a cap there as it is for PF/VF).
        motor_types: the MT values the model accepts (:data:`MOTOR_TYPES` says what each is).
        kp_max, ki_max, kd_max: gain maxima; gain_resolution the step of KP and KD (1/8);
            ki_resolution KI's (1/1024); sources at the fields. The Optima-era cards
            (DMC-1700/1800, 18x2) take KI up to 2047.875 in steps of 1/128
            (``_OPTIMA_KI_MAX``); the DMC-1500 is assumed to.
        ks_range: stepper smoothing KS (40x0 user manual: 0.25 ... 64).
        il_min, il_max: integrator limit (IL) range in volts; a negative IL freezes the
            integrator during a move where the model takes one (4103 reference).
        tl_max: torque limit (TL) in volts, from 0.
        er_min, er_max: position-error limit (ER) range in counts (4103 reference: ER 0
            turns the error output on, ER -1 off).
        hv_default: HV (homing speed) at power-on, counts/s.
        has_hv: the model has ``HV`` (the speed of HM's slow stages). The Optima-era cards'
            HM page names no HV: their stage 2 runs "slowly" at a speed of the firmware's,
            :attr:`home_slow_speed`, and ``home_speed`` is refused there.
        home_slow_speed: the speed (counts/s) of HM's slow stages where the model has no HV
            (the Optima HM page: a stepper's stage 2 at 256 counts/s; a servo's is assumed
            the same).
        homing_stages: stages of HM on a servo axis (3: find the index last).
        has_limit_disable: the model has ``LD`` (limit disable, per axis: 0 both switches
            on, 1 the forward one off, 2 the reverse one off, 3 both off). The DMC-4103
            command reference: "LD applies to DMC4000,DMC4200,DMC4103,DMC1806,DMC30010,
            DMC50000,DMC52000,EDD37010"; not the DMC-18x2, 21x3, 1500 or 1700/1800, nor a
            RIO (no axes) or a generic model (decision 0046).
        burn_timeout: seconds to wait for BN/BP/BV (flash writes; EPICS waits up to 3 s).
        generic: the spec was made for an identity no table entry matches (conservative).
        assumptions: plain-language list of values that are guesses, and why.
    """

    name: str
    family: str
    axes: str
    aliases: dict[str, str] = field(default_factory=dict)
    tm_default: float = 1000.0
    tm_adjustable: bool = True
    ac_min: int = 1024
    ac_max: int = 1_073_740_800
    ac_resolution: int = 1024
    sp_max: int = 22_000_000
    sp_resolution: int = 2
    cd_max: int = 32_000
    cd_min: int | None = None
    dt_range: tuple[int, int] = (1, 8)
    contour_buffer: int = 511
    contour_dt_suffix: bool = True
    line_length: int = 80
    mg_max: int = 72
    transports: frozenset[str] = frozenset({"serial"})
    qz: tuple[int, int, int, int] | None = None
    record_axis_analog: bool = True
    it_range: tuple[float, float] = IT_RANGE
    # Sourced for the 40x0 (M40-CR p246) and, different, for the 41x3 (its entry); other
    # adjustable families are assumed to share the 40x0's.
    tm_min_by_axes: tuple[float, float, float, float] = (62.5, 125.0, 156.25, 187.5)
    tm_max: float = 20000.0
    # The 41x3's TM resolution, 31.25 µs (its entry); the 40x0's TM page: "31.25-20000 in
    # 31.25 µs steps" (M40-CR p246). Assumed for the other adjustable families.
    tm_resolution: float = 31.25
    # gclib gclibo.c GRecordRate: "if (period_arg < 2) period_arg = 2; //lowest non-zero DR"
    # for the DMC40, DMC500 and RIO (8 for the DMC41/DMC21, 4 for the DMC3). The 30,000 top
    # is the 4103 reference's; for the others it is assumed.
    dr_range: tuple[int, int] = (2, 30000)
    dr_exponent: bool = False
    label_length: int = 7  # "#" and up to seven characters (40x0 user manual)
    variable_length: int = 8  # up to eight characters, the first a letter
    threads: int = 8  # EPICS: 8 by default, DMC-1xxx 2, DMC-3xxxx 6, RIO 4
    # Program memory: the DMC-40x0 figures as remembered from its user manual (2000 lines,
    # 510 labels, 510 variables, 30 arrays of 24000 elements together), unsourced; every
    # family that takes them lists _MEMORY_ASSUMPTION, and the 21x3 has its own variables.
    program_lines: int = 2000
    labels: int = 510
    variables: int = 510
    arrays: int = 30
    array_elements: int = 24_000
    record_exponents: tuple[int, int] = (1, 8)
    record_arrays: int = 8
    user_interrupts: int = 16
    # Power-on values of SP, JG, AC and DC (the command references' defaults: 25,000 counts/s
    # and 256,000 counts/s²; assumed the same on every family).
    default_speed: float = 25_000.0
    default_accel: float = 256_000.0
    # Coordinated motion (LM/LI, VM/VP/CR) and gearing (GA/GR); sources in the docstring.
    vector_buffer: int = 511
    vs_max: int | None = None
    va_max: int | None = None
    li_max: int = 8_388_607
    cr_radius: tuple[float, float] = (10.0, 6_000_000.0)
    cr_angle_max: float = 32_000.0
    cr_angle_resolution: float = 1 / 256
    cr_arc_max: float = 4.5e8
    vector_distance_max: int = 2_000_000_000
    vector_segment_min: float = 1.0
    vt: bool = False
    gr_max: float = 127.0
    gr_resolution: float = 1 / 65536
    # I/O (facts section 3); the defaults are a 1-4 axis DMC-40x0.
    io_first: int = 1
    digital_inputs: int = 8
    digital_outputs: int = 8
    op_bits: int = 8
    analog_inputs: int = 8
    analog_outputs: int = 0
    analog_in_range: tuple[float, float] = (-10.0, 10.0)
    analog_out_range: tuple[float, float] = (-10.0, 10.0)
    analog_in_ranges: dict[int, tuple[float, float]] = field(default_factory=dict)
    dq_ranges: dict[int, tuple[float, float]] = field(default_factory=dict)
    # Motor and loop settings (facts section 4).
    reply_formats: dict[str, str] = field(default_factory=lambda: dict(_REPLY_FORMATS))
    motor_types: frozenset[float] = _MT_STANDARD
    # Gains of the Accelera-era cards (docs/decisions/0025). Galil's DMC-4103 command reference
    # gives, in its argument tables (min, max, default, resolution), KP "0 1,023.875 6 1/8", KI
    # "0 255.999 0 1/1,024" and KD "0 4,095.875 64 1/8". The printed DMC-40x0 reference says KP
    # "0 to 1023.875 with a resolution of 1/8" (p.142), KD "0 to 4095.875 with a resolution of
    # 1/8" (p.140) and KI "0 to 255 with a resolution of 0.001" (p.141): the same range in
    # rounder words (EPICS, GalilAxis.cpp setIGain, caps KI at 255.999 on the 40x0 and 41x3).
    kp_max: float = 1023.875
    ki_max: float = 255.999
    ki_resolution: float = 1 / 1024
    kd_max: float = 4095.875
    gain_resolution: float = 1 / 8
    ks_range: tuple[float, float] = (0.25, 64.0)
    il_min: float = 0.0
    il_max: float = 9.998
    tl_max: float = 9.998
    er_min: int = 1
    er_max: int = INT32_MAX
    hv_default: float = 256.0
    has_hv: bool = True
    home_slow_speed: float = 256.0
    homing_stages: int = 3
    has_limit_disable: bool = False
    burn_timeout: float = 3.0
    generic: bool = False
    assumptions: tuple[str, ...] = ()

    def __repr__(self) -> str:
        # Short: the generated one printed all 80 fields and the assumptions' prose (about
        # 3 KB in every Identity); dataclasses.asdict(spec) gives them all.
        motion = "no axes"
        if self.axes:
            motion = f"axes {self.axes}, SP max {self.sp_max}, AC {self.ac_min}..{self.ac_max}"
        note = ", generic" if self.generic else ""
        return (
            f"<ModelSpec {self.name} ({self.family}): {motion}, TM {self.tm_default:g} µs,"
            f" {self.threads} threads, {self.digital_inputs} in / {self.digital_outputs} out"
            f"{note}>"
        )

    @property
    def has_axes(self) -> bool:
        """Whether the model drives motors (a RIO has none)."""
        return bool(self.axes)

    @property
    def has_ethernet(self) -> bool:
        """Whether the model has an Ethernet port: the only way to the second handles that
        ``DR`` records, interrupts and unsolicited messages come on (the one place that says
        so; a serial or PCI model reached over TCP, through a device server, has none)."""
        return "ethernet" in self.transports

    @property
    def tm_range(self) -> tuple[float, float]:
        """Smallest and largest TM (µs) for this model's axis count (normal firmware)."""
        index = min(max(len(self.axes) - 1, 0) // 2, 3)
        return self.tm_min_by_axes[index], self.tm_max

    @property
    def cd_range(self) -> tuple[int, int]:
        """Smallest and largest CD increment per axis and segment."""
        return (-self.cd_max if self.cd_min is None else self.cd_min), self.cd_max

    @property
    def contour_preload(self) -> bool:
        """``DT -1`` holds ``CD`` segments in the contour buffer until a positive ``DT``
        starts them: a stream can fill the buffer before it moves. The buffered models
        (DMC-4103 reference, DT: "n = -1 allows a pre-load of the contour buffer ... A
        positive DT will resume contour mode"; the models with a one-deep buffer have no
        ``DT -1``)."""
        return self.contour_buffer > 1

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample at the default TM."""
        return self.tm_default / 1_024_000.0

    @property
    def sample_period_fixed(self) -> float | None:
        """Seconds per sample where TM cannot be changed (``None`` where it can)."""
        return None if self.tm_adjustable else self.sample_period

    def sample_period_for(self, tm: float) -> float:
        """Seconds per sample for a given TM (µs), honouring fixed-rate models."""
        tm = _check_tm(tm)
        if not self.tm_adjustable:
            return self.sample_period
        return tm / 1_024_000.0

    def tm_setting(self, tm: object) -> float:
        """``tm`` (µs) as a ``TM`` this model may be sent (the range is the controller's to
        judge, and :func:`galil.protocol.commands.tm`'s).

        Raises:
            InvalidArgument: ``tm`` is not a finite real number (a bool is not); the model's
                sample period is fixed (no TM, or a TM that cannot change); ``TM <= 0``,
                which "turns the servo loop off" (M40-CR p246), a state the library's
                predictions and guards cannot follow; a value off :attr:`tm_resolution`,
                whose fate is not documented (docs/decisions/0102).
        """
        if isinstance(tm, bool) or not isinstance(tm, numbers.Real):
            raise InvalidArgument(f"tm must be a number of microseconds, not {tm!r:.60}")
        try:
            value = float(tm)
        except OverflowError:  # 10**400
            value = math.inf
        why = None
        if not math.isfinite(value):
            why = f"tm must be a finite number of microseconds, not {tm!r:.60}"
        elif not self.tm_adjustable:
            why = f"{self.name} has a fixed sample period: TM cannot be set"
        elif value <= 0:
            why = (
                f"TM {value:g} would turn the servo loop off (TM <= 0 does): the motors would"
                " no longer be controlled, which the library's predictions and guards cannot"
                " follow; turn the motors off with MO (controller.motor_off) instead"
            )
        else:
            step = self.tm_resolution
            below = math.floor(value / step + 1e-9) * step
            if min(value - below, below + step - value) > 1e-9 * step:
                why = (
                    f"TM {value:g} is not a multiple of {step:g} µs, TM's step on {self.name}:"
                    f" what the controller makes of it is not documented; use {below:g} or"
                    f" {below + step:g}"
                )
        if why is not None:
            raise InvalidArgument(why, model=self.name)
        return value

    def _tm_scale(self, tm: float | None) -> float:
        """1000 / TM for ``tm`` (default: the power-on TM); 1 where TM is fixed."""
        if tm is not None:
            tm = _check_tm(tm)
        if not self.tm_adjustable:
            return 1.0
        return _TM_REFERENCE / (self.tm_default if tm is None else tm)

    def speed_resolution(self, tm: float | None = None) -> float:
        """SP/JG step in counts/s at ``tm`` µs (default: the power-on TM).

        ``sp_resolution * 1000 / TM``: 2 counts/s at TM 1000, 8 at TM 250 (the command
        reference's "resolution = 2*(1000/TM)"). A model whose TM is fixed keeps
        ``sp_resolution``.
        """
        return self.sp_resolution * self._tm_scale(tm)

    def accel_resolution(self, tm: float | None = None) -> float:
        """AC/DC step in counts/s² at ``tm`` µs: ``ac_resolution * (1000 / TM)**2``."""
        return self.ac_resolution * self._tm_scale(tm) ** 2

    def accel_min(self, tm: float | None = None) -> float:
        """Smallest AC/DC in counts/s² at ``tm`` µs: ``ac_min * (1000 / TM)**2``."""
        return self.ac_min * self._tm_scale(tm) ** 2

    def analog_input_range(self, n: int) -> tuple[float, float]:
        """The volts analog input ``n`` (the model's numbering, from :attr:`io_first`) reads,
        lowest and highest, at the default AQ: :attr:`analog_in_range` unless
        :attr:`analog_in_ranges` says otherwise (the DMC-30010's input 2 reads 0 ... 5 V).

        Raises:
            InvalidArgument: ``n`` is not an integer (numpy's are taken; a bool is not), or
                the model has no such input.
        """
        given: object = n  # (checked: a caller may pass anything)
        if isinstance(given, bool) or not isinstance(given, numbers.Integral):
            raise InvalidArgument(f"analog input number must be an integer, not {n!r:.60}")
        first, count = self.io_first, self.analog_inputs
        if not first <= int(given) < first + count:
            raise InvalidArgument(
                f"analog input {n!r:.60} does not exist on {self.name} "
                f"({first} .. {first + count - 1})",
                model=self.name,
            )
        return self.analog_in_ranges.get(int(given), self.analog_in_range)

    @property
    def record_size(self) -> int | None:
        """Size in bytes of a QR record with every block present (header included)."""
        if self.qz is None:
            return None
        n, general, coord, per_axis = self.qz
        return 4 + general + coord + n * per_axis

    def axis_letter(self, name: str) -> str:
        """Return the canonical letter for ``name`` (``"X"`` -> ``"A"`` where aliased).

        Raises:
            InvalidArgument: the model has no such axis.
        """
        if not self.axes:
            raise InvalidArgument(
                f"{self.name} is an I/O controller with no axes (axis {name!r}): it cannot "
                "move; use controller.io",
                model=self.name,
            )
        letter = name.upper() if isinstance(name, str) else ""
        letter = self.aliases.get(letter, letter)
        if len(letter) != 1 or letter not in self.axes:
            raise InvalidArgument(
                f"axis {name!r} does not exist on {self.name} (axes: {', '.join(self.axes)})",
                model=self.name,
            )
        return letter


_XYZW = {"X": "A", "Y": "B", "Z": "C", "W": "D"}
_ETH_USB = frozenset({"serial", "usb", "ethernet"})

MODELS: dict[str, ModelSpec] = {}


#: Families whose general I/O comes in banks of 8 inputs and 8 outputs per four axes: inputs
#: and outputs 9-16 exist on boards with more than 4 axes (EPICS Init4000/Init2103: ``_TI1``
#: and outputs 9-16 "only meaningful with >4 axes"). The one place the rule is applied
#: (:func:`_with_io`), by every entry and by :func:`get_model`'s part numbers.
_BANKED_IO = frozenset(
    {"DMC-1700/1800", "DMC-18x2", "DMC-18x6", "DMC-21x3", "DMC-40x0", "DMC-41x3", "DMC-42x0"}
    | {"DMC-500x0"}
)


def _with_io(spec: ModelSpec) -> ModelSpec:
    """``spec`` with the general digital I/O of its axis count, where its family's comes in
    banks (:data:`_BANKED_IO`): 8 in / 8 out up to 4 axes, 16 / 16 above."""
    if spec.family not in _BANKED_IO:
        return spec
    n = 8 if len(spec.axes) <= 4 else 16
    if (spec.digital_inputs, spec.digital_outputs) == (n, n):
        return spec
    return dataclasses.replace(spec, digital_inputs=n, digital_outputs=n)


def _add(spec: ModelSpec, *names: str) -> None:
    spec = _with_io(spec)
    MODELS[spec.name] = spec
    for n in names:
        MODELS[n] = spec


_add(
    ModelSpec(
        name="DMC-1500",
        family="DMC-1500",
        axes="ABCD",
        aliases=_XYZW,
        # The 2 ms fixed sample (AN3312 p.4) as TM counts it (TM / 1,024,000 s), one fact: the
        # sample period and what TM ? answers both come from it.
        tm_default=2048.0,
        tm_adjustable=False,
        ac_max=67_107_840,
        sp_max=8_000_000,
        cd_max=32_000,
        contour_buffer=1,
        contour_dt_suffix=False,
        line_length=80,
        mg_max=31,
        transports=frozenset({"serial"}),
        qz=None,
        threads=2,
        vt=True,
        reply_formats=_OPTIMA_REPLY_FORMATS,
        ki_max=_OPTIMA_KI_MAX,  # assumed (see assumptions)
        ki_resolution=_OPTIMA_KI_RESOLUTION,
        has_hv=False,
        assumptions=(
            _NO_HV_ASSUMPTION + " (the DMC-1000/1500 HM page was not found: the Optima's taken)",
            _MT_NO_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "4 axes: the DMC-1500 manual excerpt names X Y Z W; the axis count is not sourced",
            "serial only: the DMC-1500 is a stand-alone RS-232 controller in the sources",
            "contour buffer of 1: pre-Accelera controllers had a 1-deep contour queue",
            "SP maximum 8,000,000 c/s: no primary source; picked below the 2xxx recollection",
            "no binary data record: no layout found for this family",
            "TM ? (and _TM) answer 2048, the fixed 2 ms sample in TM's units as on later"
            " models (TM 1000 = 1/1024 s), and TM n is refused (TC 6) whatever n: the"
            " DMC-1000/1500 reference's TM page, if it has one, was not found",
            "KI ? in format 4.0, and KI 0 ... 2047.875 in steps of 1/128, as on the Optima and"
            " DMC-1400 references; the DMC-1000/1500 reference's KI page was not found (its KP"
            " page gives 4.2)",
            _OP_ASSUMPTION,
        ),
    ),
    "DMC1500",
)
_add(
    ModelSpec(
        name="DMC-1700",
        family="DMC-1700/1800",
        axes="ABCDEFGH",
        aliases=_XYZW,
        ac_max=67_107_840,
        sp_max=12_000_000,
        contour_buffer=1,
        contour_dt_suffix=False,
        line_length=80,
        transports=frozenset({"pci"}),
        qz=(8, 24, 16, 28),
        threads=2,
        vt=True,
        reply_formats=_OPTIMA_REPLY_FORMATS,
        ki_max=_OPTIMA_KI_MAX,  # optcom-126
        ki_resolution=_OPTIMA_KI_RESOLUTION,
        has_hv=False,
        dr_exponent=True,  # the DMC-1800 is a PCI 18xx (protocol §7); the 1700 assumed alike
        assumptions=(
            "ISA/PCI bus card: reached through a Galil driver device node",
            _NO_HV_ASSUMPTION,
            _MT_NO_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "DR n takes an exponent (2**n samples) as on the PCI 18xx: sourced for the PCI"
            " DMC-1800, assumed for the ISA DMC-1700 this entry also stands for",
            "data record like the 2x00 (QZ 8,24,16,28): the 1700 manual shares that layout",
            "contour buffer of 1: pre-Accelera firmware",
            "SP maximum 12,000,000 c/s: recollection, not a primary page",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC-1800",
    "DMC1700",
    "DMC1800",
)
_add(
    ModelSpec(
        name="DMC-18x2",
        family="DMC-18x2",
        axes="ABCD",
        aliases=_XYZW,
        ac_max=67_107_840,
        sp_max=12_000_000,
        cd_max=32_000,
        contour_buffer=1,
        transports=frozenset({"pci"}),
        contour_dt_suffix=False,
        # gclib gclib_record.h, GDataRecord1802 (current revision): "The 18x2 Data record is
        # the Same as 2103 except the following. No header bytes. Software removes it from QR.
        # No analog in axis data." Its axis blocks are 28 bytes, the last two reserved (A at
        # 40-67, B at 68-95 of the record without the header), 152 bytes for 4 axes; an older
        # revision (26-byte blocks, header kept) is where the 26 of some notes comes from. The
        # QR reply carries the 4-byte header, as on the 21x3 and 40x0 (docs/decisions/0025).
        qz=(4, 24, 16, 28),
        record_axis_analog=False,
        threads=2,
        vt=True,
        reply_formats=_OPTIMA_REPLY_FORMATS,
        ki_max=_OPTIMA_KI_MAX,  # optcom-126
        ki_resolution=_OPTIMA_KI_RESOLUTION,
        has_hv=False,
        dr_exponent=True,  # PCI DMC-18xx: DR n is 2**n samples (GCLIBO; protocol §7)
        assumptions=(
            "CD range ±32,000 from the seed manual excerpt",
            _SP_ASSUMPTION.format("12,000,000"),
            _NO_HV_ASSUMPTION,
            _MT_NO_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "contour buffer of 1: the seed shows WC pacing one segment at a time",
            "QZ answers 4, 24, 16, 28: the sizes of gclib's GDataRecord1802 (28-byte axis"
            " blocks, header on the wire); the QZ reply itself not seen from an 18x2",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC-1842",
    "DMC1842",
    "DMC1832",
    "DMC1822",
    "DMC1812",
)
_add(
    ModelSpec(
        name="DMC-1806",
        family="DMC-18x6",
        axes="ABCDEFGH",
        ac_max=1_073_740_800,
        sp_max=22_000_000,
        cd_max=32_762,
        contour_buffer=511,
        transports=frozenset({"pci"}),
        qz=(8, 52, 26, 36),
        has_limit_disable=True,  # the LD page lists the DMC1806 (EPICS: no LD on any 1xxx)
        motor_types=_MT_2PB,
        dr_exponent=True,  # PCI DMC-18xx: DR n is 2**n samples (GCLIBO; protocol §7)
        assumptions=(
            "CD range ±32,762 as printed on the 18x6 CD page (sic)",
            _SP_ASSUMPTION.format("22,000,000"),
            _MT_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "record laid out like the 40x0 one (gclib GDataRecord1806); sizes assumed equal",
            "8 threads as on the 40x0 (the 18x6 is an Accelera card like it): no 18x6 page gives"
            " the count, and EPICS (GalilController.cpp, model_[3] == '1') gives every DMC-1xxx,"
            " the 18x6 included, 2 threads; gclib's GDataRecord1806 carries the 40x0's thread"
            " status byte (bit n = thread n) where the 18x2's GDataRecord1802 has a general"
            " status byte, which fits 8 but does not count them",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC-18x6",
    "DMC1806",
    "DMC1846",
    "DMC1886",
)
_add(
    ModelSpec(
        name="DMC-2183",
        family="DMC-21x3",
        axes="ABCDEFGH",
        ac_max=67_107_840,
        sp_max=12_000_000,
        cd_max=32_000,
        contour_buffer=511,
        transports=_ETH_USB,
        qz=(8, 24, 16, 28),
        dr_range=(8, 30000),
        vt=True,
        ki_max=2047.992,  # EPICS GalilAxis.h
        # "up to 254 variables" (DMC-2x00 user manual, manualsdump galil-dmc-2x00), which
        # this entry also stands for; the 21x3's own figure is not found.
        variables=254,
        assumptions=(
            "contour buffer 511 as on Accelera-class firmware: not confirmed for 21x3",
            "254 variables as the DMC-2x00 manual says; other program memory (2000 lines, 510"
            " labels, 30 arrays of 24,000 elements) as the DMC-40x0: no source for this family",
            _MT_NO_2PB_ASSUMPTION,
            "DR minimum 8 samples on the Econo 21x3 (EPICS: 8 ms minimum update period)",
            "SP maximum 12,000,000 c/s: recollection, not a primary page",
            "KI ? in format 4.4 as on the 40x0: no 21x3 page found (its KI maximum, 2047.992,"
            " is the older range, whose Optima page gives 4.0)",
            "KI in steps of 1/1024 (the default): 2047.992 (EPICS) is 2048 - 1/128, the Optima"
            " page's step, but no 21x3 page gives the step",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC-21x3",
    "DMC2183",
    "DMC2143",
    "DMC2163",
    "DMC2123",
    "DMC2113",
    "DMC-2143",
)
_add(
    ModelSpec(
        name="DMC-4040",
        family="DMC-40x0",
        axes="ABCD",
        ac_max=1_073_740_800,
        sp_max=22_000_000,
        cd_max=32_000,
        contour_buffer=511,
        transports=_ETH_USB,
        qz=(4, 52, 26, 36),
        has_limit_disable=True,  # and so the 41x3, 42x0 and 500x0 built on it
        motor_types=_MT_2PB,
        assumptions=(
            _MT_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "CD range ±32,000 from the 40x0 manual summary; the 18x6 page says ±32,762, and the"
            " 4103 reference's CD page (which lists the DMC4000) -32,768 ... 32,767",
            "DR at most 30,000 samples between records: not sourced",
            "SP maximum 22,000,000 c/s: BLISS's GalilDMC.set_velocity docstring (servo; 6,000,000"
            " for steppers, not modelled), no 40x0 reference page seen",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC-40x0",
    "DMC4040",
)
for _n in (1, 2, 3, 5, 6, 7, 8):
    _base = MODELS["DMC-4040"]
    _add(
        ModelSpec(
            **{
                **_base.__dict__,
                "name": f"DMC-40{_n}0",
                "axes": _ALL_AXES[:_n],
                "qz": (_n, 52, 26, 36),
            }
        ),
        f"DMC40{_n}0",
    )
_add(
    ModelSpec(
        **{
            **MODELS["DMC-4040"].__dict__,
            "name": "DMC-4143",
            "family": "DMC-41x3",
            "axes": "ABCD",
            "qz": (4, 52, 26, 36),
            "dr_range": (8, 30000),  # DMC-4103 reference DR: n0 8 ... 30,000
            "vs_max": 15_000_000,  # QCoDeS dmc_41x3.py: VS 2 ... 15,000,000 step 2
            # DMC-4103 command reference (docs/decisions/0025): SP "0 15,000,000 25,000 2 ...
            # (Servos)", "0 3,000,000" for steppers; JG ±15,000,000. TM "125 5,000 1,000 31.25"
            # with the minimum by axis count 125, 250, 375, 500 (1-2, 3-4, 5-6, 7-8 axes).
            "sp_max": 15_000_000,
            "tm_min_by_axes": (125.0, 250.0, 375.0, 500.0),
            "tm_max": 5000.0,
            # DMC-4103 command reference, argument tables (min, max, default, resolution;
            # docs/decisions/0025, round 2). CD: "n -32,768 32,767 0 1 Contour position
            # segment". OP: "n 0 65,535 0 1 Decimal representation: General Outputs 1-16 / On
            # a 1-4 axis controller, max is 255 ($FF) for outputs 1-8 only" (one field; "Set
            # High Byte OP65280 (OP$FF00) 9-16"). KS: "n 0.5 64 2 1/32". IL: "n -9.9982
            # 9.9982 9.9982 20/65,536 ... n< 0 (negative value) freezes the effect of the
            # integrator during the move". TL: "n 0 9.9982 9.9982 20/65,536". ER: "n -1
            # 2,147,483,647 16,384 1 ... n=0 enables Error output. n=-1 disables Error
            # output". HV: "n 0 15,000,000 256 2" (servos), as SP, 256 at power-on.
            "cd_max": 32_767,
            "cd_min": -32_768,
            "op_bits": 16,
            "ks_range": (0.5, 64.0),
            "il_min": -9.9982,
            "il_max": 9.9982,
            "tl_max": 9.9982,
            "er_min": -1,
            "assumptions": (
                "one SP/JG/HV maximum for every axis: the 4103 reference's 3,000,000 counts/s"
                " for stepper axes (MT ±2, ±2.5) is not enforced, because the range checks"
                " know the model, not the motor type each axis has at that moment",
                "TM off its 31.25 µs step refused (what the controller does with one is not"
                " documented)",
                _MT_2PB_ASSUMPTION,
                _MEMORY_ASSUMPTION,
                _VECTOR_TM_ASSUMPTION,
            ),
        }
    ),
    "DMC-41x3",
    "DMC4143",
    "DMC4183",
    "DMC4123",
    "DMC4113",
)
_add(
    ModelSpec(
        name="DMC-30010",
        family="DMC-30010",
        axes="A",
        ac_max=1_073_740_800,
        sp_max=22_000_000,
        cd_max=32_000,
        contour_buffer=511,
        transports=_ETH_USB,
        qz=(1, 18, 16, 36),
        dr_range=(4, 30000),  # gclib GRecordRate: 4 on the 30010/31010
        # 6 threads; 4 on firmware before 1.2a ("Firmware prior to 1.2a has only 4 threads",
        # EPICS Init30010): parse_identity gives the spec of the firmware (for_firmware).
        threads=6,
        has_limit_disable=True,
        motor_types=_MT_2PB,
        # EPICS maps 8 inputs (record byte 6) and 4 outputs (byte 8) on the 30000 (wave-2
        # facts §1.3); gclib's record has two bytes of each, which does not count them.
        digital_outputs=4,
        # gclib GDataRecord30000: analog input 1 in the axis block, input 2 and outputs 1-2
        # in the general block; EPICS drives AO ±10 V (3276.8 counts/V) on the 30010 and
        # reads @AN[2] as 0-5 V (13107.2 counts/V, unsigned; wave-2 facts, DMC-30010/31010).
        analog_inputs=2,
        analog_outputs=2,
        analog_in_ranges={2: (0.0, 5.0)},
        assumptions=(
            "contour buffer 511 as on Accelera-class firmware: not confirmed",
            "8 digital inputs and 4 outputs as EPICS maps them: the 30010 manual's count was"
            " not seen",
            _SP_ASSUMPTION.format("22,000,000"),
            _MT_2PB_ASSUMPTION,
            _MEMORY_ASSUMPTION,
            "analog input 1 at ±10 V as the other DMC controllers' (input 2's 0-5 V is"
            " EPICS's); a DMC-31010, which takes this table, decodes its inputs per AQ"
            " (EPICS), which is not modelled",
            _VECTOR_TM_ASSUMPTION,
            _OP_ASSUMPTION,
        ),
    ),
    "DMC30010",
    "DMC-30000",
)

#: Unconfirmed facts the families added for issue 11 share (see docs/decisions/0015).
_LAB_ASSUMPTIONS = (
    "KP, KI and KD ranges and steps as the DMC-40x0/41x3 (KI 0 ... 255.999 in 1/1024ths, KP"
    " and KD in 1/8ths): Galil's KI/KP/KD pages list this family among the models they apply"
    " to, but the tables seen are the 4103's",
    "IL and TL 0 ... 9.998 V, ER 1 ... 2**31-1 counts as the 40x0: the 4103 reference's IL,"
    " TL and ER pages list this family, but their tables (IL ±9.9982, TL 0 ... 9.9982, ER"
    " -1 ... 2**31-1) are the 4103's",
    "HV 256 counts/s at power-on, HV range as SP: the 4103 reference's HV table says so"
    " (0 ... 15,000,000, default 256) and its page lists this family, but the table is the"
    " 4103's",
    "KS 0.25 ... 64 (40x0 manual) in steps of 1/32, default 2: the 4103 reference's KS table"
    " gives that step and default (and a 0.5 minimum) and its page lists this family, but"
    " the table is the 4103's",
    "BN/BP/BV finish within 3 s (EPICS's timeout for them); real durations unknown",
    "no analog outputs on DMC motion controllers (the 40x0 command reference has no @AO)",
    _MT_2PB_ASSUMPTION,
    _VECTOR_TM_ASSUMPTION,
    _OP_ASSUMPTION,
)


def _family(base: str, name: str, prefix: str, **changes: object) -> None:
    """Add ``name`` (a 4-axis entry built on ``base``) and its 1-8 axis siblings."""
    spec = ModelSpec(**{**MODELS[base].__dict__, "name": name, **changes})
    _add(spec, name.replace("-", ""))
    for n in range(1, 9):
        sibling = f"{prefix}{n}0"
        if sibling.replace("DMC", "DMC-") == name:
            continue
        _add(
            ModelSpec(
                **{
                    **spec.__dict__,
                    "name": sibling.replace("DMC", "DMC-"),
                    "axes": _ALL_AXES[:n],
                    "qz": (n, 52, 26, 36),
                }
            ),
            sibling,
        )


_family(
    "DMC-4040",
    "DMC-4240",
    "DMC42",
    family="DMC-42x0",
    assumptions=(
        "ranges, buffers, TM and record as the DMC-40x0: the 42x0 shares the 4000 record "
        "(gclib GDataRecord4000) and BLISS's MODEL_4000 tables",
        "the 42x0 may not retain its IP address (ISIS): burn it with BN",
        _MEMORY_ASSUMPTION,
        *_LAB_ASSUMPTIONS,
    ),
)
_family(
    "DMC-4040",
    "DMC-50040",
    "DMC500",
    family="DMC-500x0",
    aliases=_XYZW,  # "A-D interchangeable with X,Y,Z,W" (M500)
    # EPICS gives 2,147,483,648 as the 50000 series' maximum acceleration; one past the
    # controller's 32-bit number range, so the largest multiple of AC's 1024 within it.
    ac_max=2_147_482_624,
    motor_types=_MT_2PB | {10.0, 11.0, -11.0},  # EtherCAT types (EPICS MT table)
    assumptions=(
        "TM range, program memory, contour and vector buffers as the DMC-40x0 (not found "
        "for the 500x0)",
        "record as the 4000 (gclib uses GDataRecord4000 for 500x0): QZ n,52,26,36",
        "SP maximum 22,000,000 c/s as the 40x0: not sourced",
        *_LAB_ASSUMPTIONS,
    ),
)
MODELS["DMC-42x0"] = MODELS["DMC-4240"]
MODELS["DMC-500x0"] = MODELS["DMC-50040"]

_RIO_ASSUMPTIONS = (
    "no motion: a RIO has no axes; motion commands are refused before sending",
    "QZ 0,4,48,0 (general block at 4-7, I/O block at 8-55): inferred from gclib's RIO "
    "layout and EPICS's 'I/O block 48' for the RIO-471xx",
    "no TM: a fixed sample of 1/1024 s (gclib: 'RIO doesn't have TM'); TM is refused before"
    " sending, and the simulator answers TM with TC 1 (unrecognised command): the code a"
    " RIO gives is not sourced",
    _MEMORY_ASSUMPTION,
    "BN/BP/BV finish within 3 s (EPICS's timeout for them); real durations unknown",
)
_add(
    ModelSpec(
        name="RIO-47120",
        family="RIO-47xxx",
        axes="",
        transports=frozenset({"ethernet"}),
        qz=(0, 4, 48, 0),
        line_length=40,  # "under 40 chars max" (IRTF field notes)
        threads=4,  # EPICS
        io_first=0,
        digital_inputs=16,
        digital_outputs=16,
        analog_inputs=8,
        analog_outputs=8,
        # RIO-47120: "1 = 0-5 V, 2 = 0-10 V, 3 = ±5 V, 4 = ±10 V" (RIO-UM p44)
        dq_ranges={1: (0.0, 5.0), 2: (0.0, 10.0), 3: (-5.0, 5.0), 4: (-10.0, 10.0)},
        # gclib: "dt = 0.9765625; //RIO doesn't have TM": a fixed 1/1024 s sample
        tm_adjustable=False,
        motor_types=frozenset(),
        homing_stages=0,
        assumptions=(
            "16 inputs, 16 outputs, 8 analog inputs and outputs at ±10 V (IRTF's "
            "RIO-47120-16bit); AQ 2 and DQ 4 (±10 V) assumed at power-on",
            *_RIO_ASSUMPTIONS,
        ),
    ),
    "RIO-47xxx",
    "RIO47120",
    "RIO47122",
    "RIO-47122",
)
_add(
    ModelSpec(
        **{
            **MODELS["RIO-47120"].__dict__,
            "name": "RIO-47100",
            "analog_in_range": (0.0, 5.0),
            "analog_out_range": (0.0, 5.0),
            "dq_ranges": {},  # AO fixed at 0-5 V: no DQ
            "assumptions": (
                "AQ 0 (0-5 V) at power-on and AO fixed at 0-5 V (RIO-47100 user manual p.44)",
                *_RIO_ASSUMPTIONS,
            ),
        }
    ),
    "RIO47100",
    "RIO47102",
    "RIO-47102",
)
_add(
    ModelSpec(
        **{
            **MODELS["RIO-47120"].__dict__,
            "name": "RIO-47300",
            "digital_inputs": 24,
            "digital_outputs": 24,
            "qz": (0, 4, 52, 0),  # EPICS: I/O block 52 on the RIO-47300
            "assumptions": (
                "24 inputs and 24 outputs (gclib's 47300 record: 0-23 each)",
                "8 analog inputs and outputs at ±10 V as the RIO-47120 (the record's fields"
                " are the 47100's; no source gives the 47300's ranges)",
                *_RIO_ASSUMPTIONS,
            ),
        }
    ),
    "RIO47300",
)

_IDENT = re.compile(r"^\s*(?P<model>[A-Z]{2,4}-?\d+\w*?)\s+Rev\.?\s+(?P<rev>\S+)", re.IGNORECASE)


# Four-digit part numbers are <family digits><axis count><family suffix>: DMC-4040 is a
# 40x0 with 4 axes, DMC-2183 a 21x3 with 8, DMC-1846 an 18x6 with 4 (EPICS reads the axis
# count from the same digit). Keys: (first two digits, last digit) -> family's table entry.
_FAMILY_BY_DIGITS = {
    ("17", "0"): "DMC-1700",
    ("18", "0"): "DMC-1700",
    ("18", "2"): "DMC-18x2",
    ("18", "6"): "DMC-1806",
    ("21", "3"): "DMC-2183",
    # Assumption: the DMC-2x00 (2100/2200, e.g. "DMC2280 Rev 1.0o-CM") shares the 21x3
    # ranges and its 24/16/28 data record (M2x00 p.67-69); no separate table entry yet.
    ("21", "0"): "DMC-2183",
    ("22", "0"): "DMC-2183",
    ("40", "0"): "DMC-4040",
    ("41", "3"): "DMC-4143",
    ("42", "0"): "DMC-4240",
}
_PART = re.compile(r"DMC-?(\d{4,5})")


def _with_axes(base: ModelSpec, name: str, n: int) -> ModelSpec:
    return _with_io(
        dataclasses.replace(
            base, name=name, axes=_ALL_AXES[:n], qz=None if base.qz is None else (n, *base.qz[1:])
        )
    )


def tm_of(sample_period: float) -> float:
    """The TM (µs) of a sample period in seconds, as :meth:`ModelSpec.sample_period_for` made
    it (TM / 1,024,000), rounded to a millionth of a µs so that TM 1500 is 1500, not
    1499.9999999999998: the steps of SP, AC and the rest follow it."""
    return round(sample_period * 1_024_000, 6)


def get_model(name: str) -> ModelSpec:
    """Return the spec for a model name such as ``"DMC-4040"``, ``"DMC4040"`` or ``"dmc-1806"``.

    A part number that is not in the table maps to its family with the axis count read from
    the third digit (``DMC4183`` -> DMC-41x3 with 8 axes, ``DMC1846`` -> DMC-18x6 with 4).

    Raises:
        InvalidArgument: no family matches.
    """
    key = name.strip().upper() if isinstance(name, str) else ""
    compact = key.replace("-", "")
    for spec in MODELS.values():
        if spec.name.upper().replace("-", "") == compact:
            return spec
    part = _PART.fullmatch(key)
    if part is not None:
        digits = part.group(1)
        if len(digits) == 4 and (digits[:2], digits[3]) in _FAMILY_BY_DIGITS:
            base = MODELS[_FAMILY_BY_DIGITS[digits[:2], digits[3]]]
            n = int(digits[2]) if digits[2] in "12345678" else len(base.axes)
            return _with_axes(base, f"DMC-{digits}", n)
        if len(digits) == 4 and digits.startswith("15"):
            return MODELS["DMC-1500"]
        if len(digits) == 5 and digits[:2] in ("30", "31"):
            return MODELS["DMC-30010"]
        if len(digits) == 5 and digits[:3] in ("500", "520") and digits[3] in "12345678":
            return _with_axes(MODELS["DMC-50040"], f"DMC-{digits}", int(digits[3]))
    for known, spec in MODELS.items():
        if known.upper().replace("-", "") == compact:
            return spec
    known = ", ".join(sorted({s.name for s in MODELS.values()}))
    raise InvalidArgument(f"unknown controller model {name!r}; known: {known}")


def _generic_axes(compact: str) -> int:
    """Axes of an unknown DMC part number, read as EPICS does (``GalilController::connected``).

    ``DMC5xxxx`` has the count at index 6, ``DMC3xxxx`` one axis, others at index 5.
    """
    digit = compact[6:7] if compact[3:4] == "5" else compact[5:6]
    if compact[3:4] == "3":
        return 1
    return int(digit) if digit in tuple("12345678") else 1


def generic_model(raw_model: str) -> ModelSpec:
    """A conservative spec for a genuine Galil identity that no table entry matches.

    Motion controllers get their axis count the way EPICS reads it from the part number,
    the narrowest ranges of the known families, a one-deep contour buffer, no data record and
    no analog outputs; a ``RIO...`` gets the I/O of the smallest RIO. ``generic`` is set so
    the caller can warn.
    """
    compact = raw_model.strip().upper().replace("-", "")
    note = (
        f"{compact} matches no table entry: conservative limits (narrowest known ranges, "
        "no data record, no analog outputs); pass model= to pick a family's tables"
    )
    if compact.startswith("RIO"):
        return ModelSpec(
            **{
                **MODELS["RIO-47120"].__dict__,
                "name": compact,
                "family": "RIO (generic)",
                "qz": None,
                "digital_inputs": 8,
                "digital_outputs": 8,
                "analog_in_range": (0.0, 5.0),
                "analog_out_range": (0.0, 5.0),
                "generic": True,
                "assumptions": (note,),
            }
        )
    n = _generic_axes(compact) if compact.startswith("DMC") else 1
    return ModelSpec(
        name=compact,
        family="generic",
        axes=_ALL_AXES[:n],
        ac_max=67_107_840,
        sp_max=3_000_000,
        contour_buffer=1,
        transports=_ETH_USB,
        qz=None,
        threads=2,
        ki_max=255.999,
        generic=True,
        assumptions=(note,),
    )


_REVISION = re.compile(r"(\d+)\.(\d+)([a-z]?)", re.IGNORECASE)


def for_firmware(spec: ModelSpec, firmware: str) -> ModelSpec:
    """``spec`` as a controller running ``firmware`` (the ``^R^V`` revision, ``"1.2a"``) has
    it: a DMC-30010 (and the 31010 its entry stands for) before 1.2a has 4 threads, not 6
    ("Firmware prior to 1.2a has only 4 threads", EPICS Init30010). A revision that does not
    read as ``<major>.<minor><letter>`` gets the fewer threads (assumption: the safe side).
    Other models are returned unchanged."""
    if spec.family != "DMC-30010":
        return spec
    found = _REVISION.match(firmware.strip()) if isinstance(firmware, str) else None
    old = found is None or (int(found[1]), int(found[2]), found[3].lower()) < (1, 2, "a")
    return dataclasses.replace(spec, threads=4) if old and spec.threads > 4 else spec


@dataclass(frozen=True)
class Identity:
    """A parsed ``^R^V`` reply."""

    model: ModelSpec
    raw_model: str
    firmware: str


def parse_identity(reply: str) -> Identity:
    """Parse a ``^R^V`` reply like ``"DMC4040 Rev 1.2f"`` into an :class:`Identity`.

    A well-formed identity of a model the tables do not know gets :func:`generic_model`
    (``identity.model.generic`` is then true).

    Raises:
        InvalidArgument: the text is not a Galil identification string.
    """
    m = _IDENT.match(reply)
    if m is None:
        raise InvalidArgument(f"not a Galil identification string: {reply!r}")
    raw = m.group("model").upper()
    try:
        model = get_model(raw)
    except InvalidArgument:
        model = generic_model(raw)  # a genuine identity: connect, conservatively (the caller warns)
    firmware = m.group("rev")
    return Identity(model=for_firmware(model, firmware), raw_model=raw, firmware=firmware)
