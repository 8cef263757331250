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
from galil.predict.jog import jog
from galil.predict.move import (
    Event,
    Increment,
    MovePlan,
    ScheduleError,
    SetAccel,
    SetSpeed,
    SpeedSchedule,
    Stop,
    move,
    plan_move,
    speed_schedule,
)
from galil.predict.profile import MultiProfile, Profile, together
from galil.predict.smoothing import quantise_it

__all__ = [
    "AxisProfiler",
    "Checked",
    "Event",
    "Increment",
    "KinematicPlan",
    "MotionReport",
    "MovePlan",
    "MultiProfile",
    "Profile",
    "Quantised",
    "ScheduleError",
    "SetAccel",
    "SetSpeed",
    "SpeedSchedule",
    "Stop",
    "StreamReport",
    "check",
    "check_contour",
    "check_motion",
    "check_parameter",
    "check_profile_motion",
    "check_soft_limits",
    "contour",
    "jog",
    "move",
    "plan_move",
    "quantise",
    "quantise_accel",
    "quantise_it",
    "quantise_limits",
    "quantise_speed",
    "quantise_value",
    "speed_schedule",
    "together",
]
