"""The profile predictor: what the controller's profiler will do, sample by sample.

Counts and seconds throughout; numpy only (matplotlib only inside ``plot()``).
:class:`AxisProfiler` is the one motion engine, shared with the simulator; the functions drive
it with schedules of events.

>>> from galil import predict
>>> p = predict.move(10_000, speed=20_000, accel=256_000, decel=256_000)
>>> p.shape, p.position[-1]
('trapezoid', np.int64(10000))
"""

from __future__ import annotations

from galil.predict.checks import (
    Checked,
    MotionReport,
    Quantised,
    StreamReport,
    check,
    check_contour,
    check_motion,
    check_parameter,
    check_profile_motion,
    check_soft_limits,
    quantise,
    quantise_accel,
    quantise_limits,
    quantise_speed,
    quantise_value,
)
from galil.predict.contour import contour
from galil.predict.engine import AxisProfiler, KinematicPlan
from galil.predict.gearing import GearFollower, gear, gear_profile, quantise_ratio
from galil.predict.homing import (
    HomeSwitch,
    HomingParams,
    HomingPrediction,
    homing,
    stepper_output,
)
from galil.predict.jog import jog
from galil.predict.move import (
    Abort,
    Event,
    Increment,
    MovePlan,
    ScheduleError,
    SetAccel,
    SetDecel,
    SetSpeed,
    SpeedSchedule,
    Stop,
    move,
    plan_move,
    speed_schedule,
)
from galil.predict.path import Arc, Line, LinearInterp, PathSegment, VectorPath
from galil.predict.profile import MultiProfile, Profile, together
from galil.predict.smoothing import quantise_it
from galil.predict.vector import VectorProfile, VectorProfiler, vector
from galil.predict.vector_checks import (
    QuantisedVector,
    axis_rates,
    check_vector,
    quantise_vector,
    segment_deadlines,
)

__all__ = [
    "Abort",
    "Arc",
    "AxisProfiler",
    "Checked",
    "Event",
    "GearFollower",
    "HomeSwitch",
    "HomingParams",
    "HomingPrediction",
    "Increment",
    "KinematicPlan",
    "Line",
    "LinearInterp",
    "MotionReport",
    "MovePlan",
    "MultiProfile",
    "PathSegment",
    "Profile",
    "Quantised",
    "QuantisedVector",
    "ScheduleError",
    "SetAccel",
    "SetDecel",
    "SetSpeed",
    "SpeedSchedule",
    "Stop",
    "StreamReport",
    "VectorPath",
    "VectorProfile",
    "VectorProfiler",
    "axis_rates",
    "check",
    "check_contour",
    "check_motion",
    "check_parameter",
    "check_profile_motion",
    "check_soft_limits",
    "check_vector",
    "contour",
    "gear",
    "gear_profile",
    "homing",
    "jog",
    "move",
    "plan_move",
    "quantise",
    "quantise_accel",
    "quantise_it",
    "quantise_limits",
    "quantise_ratio",
    "quantise_speed",
    "quantise_value",
    "quantise_vector",
    "segment_deadlines",
    "speed_schedule",
    "stepper_output",
    "together",
    "vector",
]
