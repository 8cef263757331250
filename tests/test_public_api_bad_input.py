"""Every public entry point, every parameter, a table of bad values: a typed error or a value
legitimately taken; never a bare stdlib error, nothing but queries on the wire, and the link and
the axes as they were (decision 0026).

The surface is found by introspection (:func:`_surface`): the public methods and settable
properties (and ``Setting`` descriptors, and item access) of the controller, an axis, the rooms
hanging off the controller and the objects its calls return. :data:`ENTRIES` gives a valid value
for every parameter of each entry point; each case replaces one of them with one bad value.
:data:`SKIPPED` names what is left out, and why; :data:`ACCEPTS` the bad values a parameter
takes on purpose. ``test_every_entry_point_is_fuzzed_or_skipped`` fails when a new public method
is neither fuzzed nor skipped. Methods without parameters have nothing to replace and are not
called (``close``, ``reconnect``, ``abort`` ...).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import queue
import types
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import pytest

import galil
from galil.errors import ReadOnly
from galil.predict.homing import HomeSwitch
from galil.protocol.commands import Command, Expect
from galil.segments import Line
from galil.sim.server import SimTcpServer
from galil.testing import nothing_sent, simulated
from galil.tuning import MotorType, Setting
from galil.units import ureg

LONG = "x" * 2000

#: The bad values every parameter gets in turn (``None`` only where the hint refuses it).
BAD: list[tuple[str, object]] = [
    ("None", None),
    ("'x'", "x"),
    ("''", ""),
    ("nan", float("nan")),
    ("inf", float("inf")),
    ("-1", -1),
    ("10**400", 10**400),
    ("True", True),
    ("object()", object()),
    ("[]", []),
    ("{}", {}),
    ("2000 chars", LONG),
]


@dataclass(frozen=True)
class Lazy:
    """A valid value that needs the controller (a profile, a command, the polarity read)."""

    make: Callable[[galil.Controller], object]


# -- the objects whose entry points are fuzzed --------------------------------------------------


@dataclass(frozen=True)
class Group:
    """Where the entry points live: ``make`` builds the object (anything it sends is outside the
    checked block), ``after`` undoes what a case left behind (a gearing, a stream)."""

    make: Callable[[galil.Controller], Any]
    after: Callable[[galil.Controller, Any], None] = lambda dmc, obj: None


def _program(dmc: galil.Controller) -> galil.Controller:
    dmc.programs.download("#A\nWT 2\nEN\n")
    return dmc


def _array(dmc: galil.Controller) -> Any:
    dmc.arrays.define("arr", 10, replace=True)
    return dmc.arrays


def _variable(dmc: galil.Controller) -> Any:
    dmc.variables.write("v", 1.0)
    return dmc.variables


def _handle(dmc: galil.Controller) -> galil.MoveHandle:
    return dmc.A.move_by(2000)


def _vector_handle(dmc: galil.Controller) -> Any:
    return dmc.vector_move("AB", [Line(2000, 2000)], speed=10_000)


def _capture_after(dmc: galil.Controller, capture: Any) -> None:
    if capture.result is None:
        capture.stop()


GROUPS: dict[str, Group] = {
    "controller": Group(lambda dmc: dmc),
    "axis": Group(lambda dmc: dmc.A),
    "model": Group(lambda dmc: dmc.model),
    "wire_log": Group(lambda dmc: dmc.wire_log),
    "io": Group(lambda dmc: dmc.io),
    "io.inputs": Group(lambda dmc: dmc.io.inputs),
    "io.outputs": Group(lambda dmc: dmc.io.outputs),
    "io.analog_in": Group(lambda dmc: dmc.io.analog_in),
    "io.analog_out": Group(lambda dmc: dmc.io.analog_out),
    "programs": Group(lambda dmc: _program(dmc).programs),
    "arrays": Group(_array),
    "variables": Group(_variable),
    "interrupts": Group(lambda dmc: dmc.interrupts, lambda dmc, i: i.disable()),
    "messages": Group(lambda dmc: dmc.messages),
    "move handle": Group(_handle, lambda dmc, h: h.stop()),
    "vector handle": Group(_vector_handle, lambda dmc, h: h.stop()),
    "gearing": Group(lambda dmc: dmc.B.gear_to("A", 0.5), lambda dmc, g: g.off()),
    "capture": Group(lambda dmc: dmc.capture(["_TPA"], count=4), _capture_after),
    "recording": Group(lambda dmc: dmc.capture(["_TPA"], count=4).wait()),
    "record stream": Group(lambda dmc: dmc.records(8), lambda dmc, s: s.close()),
    "watchdog": Group(lambda dmc: dmc.watchdog(1.0), lambda dmc, w: w.stop()),
    "profile": Group(lambda dmc: dmc.A.plan_by(1000)),
    "multi profile": Group(lambda dmc: dmc.plan({"A": 1000, "B": 500})),
    "vector plan": Group(lambda dmc: dmc.plan_vector("AB", [Line(1000, 1000)], speed=10_000)),
    "homed": Group(lambda dmc: dmc.A.homed),
    "switches": Group(lambda dmc: dmc.A.switches),
    "switch polarity": Group(lambda dmc: dmc.switch_polarity),
    "download": Group(lambda dmc: dmc.programs.download("#A\nEN\n")),
    "contour result": Group(lambda dmc: dmc.contour("A", [10, 20], dt=2)),
}

#: Public attributes of the controller and what they are (a group above, or why not fuzzed).
ROOMS: dict[str, str] = {
    "io": "io",
    "programs": "programs",
    "arrays": "arrays",
    "variables": "variables",
    "interrupts": "interrupts",
    "messages": "messages",
    "wire_log": "wire_log",
    "model": "model",
    "switch_polarity": "switch polarity",
    "link": "skip: the controller's own methods pass their calls on to it (fuzzed there); the"
    " rest (attach, detach, transact, pause, set_keepalive ...) is the rooms' plumbing",
    "messages_room": "skip: plumbing behind `messages`/`subscribe` (restart, route, stop)",
    "records_room": "skip: plumbing behind `record`/`records` (fuzzed on the controller)",
    "tracker": "skip: the motion bookkeeping the rooms share; its callers pass its values",
    "routines": "skip: the library's own routines (watchdog, input wait); fuzzed through them",
    "transport": "skip: the simulator link's own I/O (read, write, let_time_pass)",
    "identity": "skip: a parsed ^R^V reply, no methods",
    "axes": "skip: the axes by letter, a dict (each axis's entry points are fuzzed on dmc.A;"
    " a letter the model lacks: tests/axis/test_paths_and_axes_refused_unsent.py)",
}


# -- the entry points ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Entry:
    """One entry point and a valid value for every parameter.

    kind: ``"call"``, ``"set"`` (a property or ``Setting``: the value is ``value``),
    ``"getitem"`` / ``"setitem"`` (``key``, ``value``).
    moves: a successful call may start motion.
    raw: parameters only the controller can judge: the command text itself, or the name of
    an array to free (a string goes onto the wire as it is, and the controller's ``?`` is
    the answer); any other value must still be refused unsent.
    lookup: a lookup in data already read (a recording, a plan): ``KeyError`` is its answer,
    as a mapping's, and ``TypeError`` for an unhashable key.
    """

    group: str
    name: str
    valid: Mapping[str, object] = field(default_factory=dict)
    kind: str = "call"
    moves: bool = False
    raw: tuple[str, ...] = ()
    model: str = "DMC-4040"
    tcp: bool = False  # over a simulator's TCP server (interrupts need a handle of their own)
    lookup: bool = False


def _command(dmc: galil.Controller) -> Command:
    return Command("MG 1", Expect.LINE)


def _polarity(dmc: galil.Controller) -> object:
    return dmc.switch_polarity


def _profile(dmc: galil.Controller) -> object:
    return dmc.A.plan_by(1000)


def _quiet(*args: object) -> None:
    pass


def _servo_with_the_motor_off(dmc: galil.Controller) -> MotorType:
    dmc.motor_off("A")  # (MT only with the motor off: decision 0043)
    return MotorType.SERVO


mm = ureg.mm
OFF = {"speed": 10_000, "accel": 256_000, "decel": 256_000}  # move overrides, valid
SETTINGS = {
    "brush": 0,
    "encoder_config": 0,
    "error_limit": 16_384,
    "integrator_limit": 9.998,
    "kd": 64,
    "ki": 0,
    "kp": 6,
    "limit_disable": 0,
    "motor_type": Lazy(_servo_with_the_motor_off),
    "off_on_error": 0,
    "stepper_smoothing": 1,
    "torque_limit": 9.998,
}

E = Entry
ENTRIES: list[Entry] = [
    # controller
    E("controller", "axis", {"name": "A"}),
    E("controller", "capture", {"sources": ["_TPA"], "every": 2, "count": 4, "seconds": None}),
    E(
        "controller",
        "command",
        {"text": "MG 1", "timeout": None, "allow_compound": False},
        raw=("text",),
    ),
    E("controller", "command_line", {"parts": ["MG 1"], "timeout": None}),
    E(
        "controller",
        "contour",
        {
            "axes": "AB",
            "path": [[10, 10], [20, 20]],
            "dt": 2,
            "progress": False,
            "timeout": None,
            "speed_limit": None,
            "accel_limit": None,
        },
        moves=True,
    ),
    E("controller", "exchange", {"command": Lazy(_command), "timeout": None}),
    E("controller", "motion", {"axes": None}),
    E("controller", "motor_off", {"axes": "D"}),
    E("controller", "move", {"targets": {"A": 100}, "relative": False, **OFF}, moves=True),
    E("controller", "plan", {"targets": {"A": 100}, "relative": False, **OFF}),
    E("controller", "plan_vector", {"axes": "AB", "segments": [Line(100, 100)], "speed": 10_000}),
    E("controller", "query_number", {"text": "MG 1", "timeout": None}, raw=("text",)),
    E("controller", "query_numbers", {"text": "MG 1", "timeout": None}, raw=("text",)),
    E(
        "controller",
        "query_operands",
        {"names": ["_TPA"], "timeout": None},
    ),
    E("controller", "record", {"axes": "", "as_dict": False, "timeout": None}),
    E("controller", "records", {"period": 8, "seconds": None, "method": "auto", "maxlen": 100}),
    E("controller", "reset", {"timeout": None}),
    E("controller", "save", {"timeout": None}),
    E("controller", "save_program", {"timeout": None}),
    E("controller", "save_variables", {"timeout": None}),
    E("controller", "send", {"command": Lazy(_command), "timeout": None}),
    E("controller", "send_many", {"commands": Lazy(lambda d: [_command(d)]), "timeout": None}),
    E("controller", "servo_here", {"axes": "A"}),
    E("controller", "sleep", {"seconds": 0.01}),
    E("controller", "stop", {"axes": "A"}),
    E("controller", "subscribe", {"callback": _quiet}),
    E(
        "controller",
        "vector_move",
        {
            "axes": "AB",
            "segments": [Line(100, 100)],
            "speed": 10_000,
            "accel": None,
            "decel": None,
            "smoothing": None,
            "mode": None,
            "stream": True,
            "axis_speed": None,
            "axis_accel": None,
        },
        moves=True,
    ),
    E("controller", "watchdog", {"timeout": 1.0, "thread": None, "interval": None}),
    E("controller", "timeout", {"value": 1.0}, kind="set"),
    E("controller", "switch_polarity", {"value": Lazy(_polarity)}, kind="set"),
    # axis
    E("axis", "check_parameter", {"cmd": "SP", "counts": 1000}),
    E("axis", "display", {"profile": Lazy(_profile)}),
    E("axis", "define_position", {"position": 100, "shift_limits": True}),
    E("axis", "distance_counts", {"value": 100, "what": "distance"}),
    E("axis", "position_counts", {"value": 100, "what": "position"}),
    E("axis", "rate_counts", {"value": 100, "power": 1, "what": "speed"}),
    E("axis", "signed_rate_counts", {"value": 100, "power": 1, "what": "speed"}),
    E("axis", "limit_counts", {"limit": 100, "power": 1, "what": "speed_limit"}),
    E("axis", "find_edge", {"switch": None}, moves=True),
    E("axis", "find_index", {"switch": None}, moves=True),
    E("axis", "home", {"switch": HomeSwitch(edge=500)}, moves=True),
    E("axis", "gear_to", {"master": "B", "ratio": 0.5}),
    E("axis", "increment", {"n": 100}, moves=True),
    E("axis", "jog", {"speed": 1000}, moves=True),
    E("axis", "move_by", {"distance": 100, **OFF}, moves=True),
    E("axis", "move_to", {"position": 100, **OFF}, moves=True),
    E("axis", "plan_by", {"distance": 100, **OFF}),
    E("axis", "plan_to", {"position": 100, **OFF}),
    E("axis", "set_scale", {"counts_per": 1000 / mm, "offset": None, "sign": 1}),
    E(
        "axis",
        "speed_schedule",
        {"distance": 8000, "changes": [(4000, 2000)], "speed": None, "label": "GSCHED"},
        moves=True,
    ),
    *(E("axis", name, {"value": v}, kind="set") for name, v in SETTINGS.items()),
    E("axis", "accel", {"value": 256_000}, kind="set"),
    E("axis", "decel", {"value": 256_000}, kind="set"),
    E("axis", "home_speed", {"value": 1000}, kind="set"),
    E("axis", "jog_speed", {"value": 1000}, kind="set"),
    E("axis", "smoothing", {"value": 0.5}, kind="set"),
    E("axis", "soft_limits", {"value": (-(10**6), 10**6)}, kind="set"),
    E("axis", "speed", {"value": 10_000}, kind="set"),
    # rooms
    E("model", "accel_min", {"tm": 1000}),
    E("model", "accel_resolution", {"tm": 1000}),
    E("model", "speed_resolution", {"tm": 1000}),
    E("model", "sample_period_for", {"tm": 1000}),
    E("model", "tm_setting", {"tm": 1000}),
    E("model", "axis_letter", {"name": "A"}),
    E("model", "analog_input_range", {"n": 1}),
    E("wire_log", "add", {"hook": _quiet}),
    E("io", "wait_for_input", {"n": 1, "high": True, "timeout": 0.01, "thread": None}),
    E("io.inputs", "__getitem__", {"key": 1}, kind="getitem"),
    E("io.outputs", "__getitem__", {"key": 1}, kind="getitem"),
    E("io.outputs", "__setitem__", {"key": 1, "value": True}, kind="setitem"),
    E("io.analog_in", "__getitem__", {"key": 1}, kind="getitem", model="DMC-30010"),
    E("io.analog_out", "__getitem__", {"key": 1}, kind="getitem", model="DMC-30010"),
    E("io.analog_out", "__setitem__", {"key": 1, "value": 2.0}, kind="setitem", model="DMC-30010"),
    E("programs", "download", {"source": "#A\nEN\n", "strip_comments": False, "pack": False}),
    E("programs", "run", {"label": "#A", "thread": 0}),
    E("programs", "halt", {"thread": 0}),
    E("programs", "wait", {"thread": 1, "timeout": 0.01}),
    E("programs", "burn", {"timeout": None}),
    E("arrays", "define", {"name": "arr", "size": 10, "replace": True}),
    E("arrays", "delete", {"name": "arr"}, raw=("name",)),  # no such array: the controller's ?
    E("arrays", "download", {"name": "arr", "values": [1, 2, 3], "first": 0}),
    E("arrays", "upload", {"name": "arr", "first": None, "last": None}),
    E("variables", "read", {"name": "v"}),
    E("variables", "write", {"name": "v", "value": 2.0}),
    E("variables", "delete", {"name": "v"}),
    E("variables", "__getitem__", {"key": "v"}, kind="getitem"),
    E("variables", "__setitem__", {"key": "v", "value": 2.0}, kind="setitem"),
    E("interrupts", "enable", {"axes": "", "all_done": False}, tcp=True),
    E("interrupts", "get", {"timeout": 0}),
    E("interrupts", "subscribe", {"callback": _quiet}),
    E("messages", "get", {"timeout": 0}),
    E("move handle", "wait", {"timeout": None, "progress": False}),
    E("move handle", "add_callback", {"callback": _quiet}),
    E("vector handle", "wait", {"timeout": None, "progress": False}),
    E("vector handle", "add_callback", {"callback": _quiet}),
    E("gearing", "set_ratio", {"ratio": 0.25}),
    E("gearing", "predict", {"master": Lazy(_profile)}),
    E("capture", "wait", {"timeout": None}),
    E("recording", "position", {"axis": "A"}, lookup=True),
    E("recording", "__getitem__", {"key": "_TPA"}, kind="getitem", lookup=True),
    E("record stream", "get", {"timeout": None}),
    E("record stream", "take", {"n": 2, "timeout": None}),
    E("record stream", "subscribe", {"callback": _quiet}),
    E("profile", "at", {"t": 0.01}),
    E("profile", "with_units", {"counts_per_unit": 1000, "unit": "mm", "offset": 0.0}),
    E("multi profile", "__getitem__", {"key": "A"}, kind="getitem", lookup=True),
    E("multi profile", "at", {"t": 0.01}),
    E("vector plan", "position", {"axis": "A"}, lookup=True),
    E("vector plan", "unit_of", {"axis": "A"}, lookup=True),
]

#: Public entry points with parameters left out, and why.
SKIPPED: dict[tuple[str, str], str] = {
    ("messages", "put"): "the producer side of the queue: any item is a legitimate item",
    ("messages", "close"): "the producer side: `why` is any text to show waiting readers",
    ("interrupts", "close"): "ends the interrupt queue for the controller's life; `keep_mask`"
    " is a flag",
    **{
        ("move handle", n): "a hook the library's rooms (gearing, schedules, vector streams)"
        " call with values they made; not a user's entry point"
        for n in ("track", "follow", "preset", "on_cancel", "add_event")
    },
    **{
        ("vector handle", n): "a hook the library's vector stream calls with values it made"
        for n in ("track", "follow", "preset", "on_cancel", "add_event", "record")
    },
    ("profile", "plot"): "matplotlib figures, slow; the options are passed to matplotlib",
    ("multi profile", "plot"): "matplotlib figures, slow",
    ("vector plan", "plot"): "matplotlib figures, slow",
    ("profile", "from_samples"): "a constructor of the predictor (pure; no link)",
    ("profile", "planned"): "a constructor of the predictor (pure; no link)",
    ("profile", "recast"): "a constructor of the predictor (pure; no link)",
    ("multi profile", "get"): "Mapping.get: any key is a legitimate lookup",
    **{
        ("variables", n): f"MutableMapping.{n}: the name goes through __getitem__ (fuzzed), and"
        " __delitem__ / __setitem__ (delete, write: fuzzed)"
        for n in ("get", "pop", "setdefault")
    },
    ("variables", "update"): "MutableMapping.update: each item goes through __setitem__ (fuzzed);"
    " what is not a mapping or pairs is refused as dict.update refuses it",
}


#: Bad values some parameters take on purpose: (group, entry point, parameter) -> the labels of
#: :data:`BAD` taken, and why. Any other value a call takes is a defect.
SIGNED = {"-1"}  # a signed number: -1 is a value like any other
ALL_AXES = {"''"}  # "" is the documented default: every axis
ACCEPTS: dict[tuple[str, str, str], set[str]] = {
    ("controller", "command", "text"): {"''"},  # an empty line: the controller's ':'
    ("controller", "command_line", "parts"): {"[]"},  # no parts, no line
    ("controller", "send_many", "commands"): {"[]"},  # nothing to send
    ("controller", "query_operands", "names"): {"[]"},  # nothing to read
    ("controller", "records", "maxlen"): {"10**400"},  # a bound never reached: no float in it
    ("controller", "record", "axes"): {"''", "[]"},  # no letters: every axis
    ("controller", "contour", "speed_limit"): {"{}"},  # no limit on any axis
    ("controller", "contour", "accel_limit"): {"{}"},
    ("controller", "vector_move", "axis_speed"): {"{}"},
    ("controller", "vector_move", "axis_accel"): {"{}"},
    ("controller", "motion", "axes"): ALL_AXES,
    ("controller", "motor_off", "axes"): ALL_AXES,
    ("controller", "servo_here", "axes"): ALL_AXES,
    ("controller", "stop", "axes"): ALL_AXES,
    ("interrupts", "enable", "axes"): ALL_AXES,
    ("interrupts", "enable", "all_done"): {"True"},
    ("io", "wait_for_input", "high"): {"True"},
    ("io.outputs", "__setitem__", "value"): {"True"},
    ("io.analog_out", "__setitem__", "value"): SIGNED,  # -1 V
    ("gearing", "set_ratio", "ratio"): SIGNED,  # geared the other way
    ("axis", "limit_counts", "limit"): {"{}"},  # a mapping that names no axis: no limit
    ("axis", "speed_schedule", "changes"): {"[]"},  # no change: a plain move
    ("axis", "speed_schedule", "label"): {"'x'"},  # a label of one letter
    ("programs", "download", "source"): {"'x'"},  # a program's text (one line, "x")
    ("arrays", "define", "name"): {"'x'"},
    ("variables", "write", "name"): {"'x'"},
    ("variables", "__setitem__", "key"): {"'x'"},
    ("variables", "write", "value"): SIGNED,
    ("variables", "__setitem__", "value"): SIGNED,
    ("profile", "at", "t"): {"-1", "inf", "[]"},  # before the start, after the end; no times
    ("multi profile", "at", "t"): {"-1", "inf", "[]"},  # (as Profile.at)
    ("profile", "with_units", "counts_per_unit"): SIGNED,  # a reversed axis
    ("profile", "with_units", "offset"): SIGNED,
    ("profile", "with_units", "unit"): {"'x'", "''", "2000 chars"},  # a label for plots
    **{
        ("axis", name, "what"): {label for label, _ in BAD}  # a label, only shown in messages
        for name in (
            "distance_counts",
            "position_counts",
            "rate_counts",
            "signed_rate_counts",
            "limit_counts",
        )
    },
    **{
        ("axis", name, param): SIGNED
        for name, param in [
            ("distance_counts", "value"),
            ("position_counts", "value"),
            ("signed_rate_counts", "value"),
            ("gear_to", "ratio"),
            ("increment", "n"),
            ("jog", "speed"),
            ("move_by", "distance"),
            ("move_to", "position"),
            ("define_position", "position"),
            ("plan_by", "distance"),
            ("plan_to", "position"),
            ("set_scale", "sign"),
            ("brush", "value"),
            ("jog_speed", "value"),
            ("motor_type", "value"),  # MT -1: a servo of reversed polarity
        ]
    },
}


def _accepted(entry: Entry, param: str, target: object) -> set[str]:
    """The bad labels ``param`` takes on purpose: its row in :data:`ACCEPTS`; and ``True`` for
    a flag (a parameter hinted ``bool``)."""
    out = set(ACCEPTS.get((entry.group, entry.name, param), ()))
    if entry.kind == "call":
        found = inspect.signature(getattr(target, entry.name)).parameters.get(param)
        if found is not None and found.annotation == "bool":
            out.add("True")
    return out


def _public(kind: type) -> Iterator[tuple[str, str]]:
    """(name, "call" | "set" | "getitem" | "setitem") of every public entry point of ``kind``
    that takes a value: methods with parameters, settable properties, Setting descriptors."""
    for name in dir(kind):
        if name.startswith("_") and name not in ("__getitem__", "__setitem__"):
            continue
        attr = inspect.getattr_static(kind, name)
        if isinstance(attr, property):
            if attr.fset is not None:
                yield name, "set"
        elif isinstance(attr, Setting):
            yield name, "set"
        elif name in ("__getitem__", "__setitem__"):
            if getattr(object, name, None) is not attr:
                yield name, name.strip("_")
        elif callable(attr) or isinstance(attr, (staticmethod, classmethod)):
            params = inspect.signature(getattr(kind, name)).parameters
            if [p for p in params if p not in ("self", "cls")]:
                yield name, "call"


def _surface() -> dict[tuple[str, str], str]:
    """Every public entry point that takes a value, on a simulated DMC-4040 (and a 30010 for
    analog I/O), by group."""
    found: dict[tuple[str, str], str] = {}
    analog = ("io.analog_in", "io.analog_out")
    for model, groups in (("DMC-4040", GROUPS), ("DMC-30010", analog)):
        with simulated(model) as dmc:
            for group in groups:
                spec = GROUPS[group]
                obj = spec.make(dmc)
                try:
                    for name, kind in _public(type(obj)):
                        found[(group, name)] = kind
                finally:
                    spec.after(dmc, obj)
                    _settle(dmc)
    return found


def test_every_entry_point_is_fuzzed_or_skipped() -> None:
    surface = _surface()
    listed = {(e.group, e.name) for e in ENTRIES}
    assert not listed & set(SKIPPED), "both fuzzed and skipped"
    missing = sorted(set(surface) - listed - set(SKIPPED))
    assert not missing, f"public entry points neither fuzzed nor skipped: {missing}"
    stale = sorted((listed | set(SKIPPED)) - set(surface))
    assert not stale, f"listed but not found (renamed?): {stale}"
    for e in ENTRIES:
        assert e.kind == surface[(e.group, e.name)], e


def test_every_public_attribute_of_the_controller_is_a_room_or_skipped() -> None:
    with simulated("DMC-4040") as dmc:
        names = {n for n in vars(dmc) if not n.startswith("_")}
        names |= {
            n
            for n in dir(type(dmc))
            if not n.startswith("_")
            # (the parts its own methods bind are read-only: decision 0091)
            and isinstance(inspect.getattr_static(type(dmc), n), (property, ReadOnly))
            and type(getattr(dmc, n)).__module__.startswith("galil.")
        }
        assert sorted(names - {"echo"}) == sorted(ROOMS)
    for room, what in ROOMS.items():
        assert what.startswith("skip: ") or what in GROUPS, room


# -- one case -----------------------------------------------------------------------------------


def _none_allowed(entry: Entry, param: str, target: object) -> bool:
    if entry.kind != "call":
        return False
    try:
        hint = inspect.signature(getattr(target, entry.name)).parameters[param].annotation
    except KeyError:  # a **overrides key: None keeps the axis's setting
        return entry.name in ("move_to", "move_by", "plan_to", "plan_by", "move", "plan")
    return isinstance(hint, str) and ("None" in hint or hint in ("Any", "object"))


def _resolve(value: object, dmc: galil.Controller) -> object:
    return value.make(dmc) if isinstance(value, Lazy) else value


def _invoke(entry: Entry, target: Any, args: dict[str, object]) -> object:
    if entry.kind == "set":
        setattr(target, entry.name, args["value"])
        return None
    if entry.kind == "getitem":
        return target[args["key"]]
    if entry.kind == "setitem":
        target[args["key"]] = args["value"]
        return None
    return getattr(target, entry.name)(**args)


def _dispose(result: object) -> None:
    """Undo what a successful call left running (a stream, a watchdog, a subscription)."""
    if isinstance(result, (galil.RecordStream,)):
        result.close()
    elif isinstance(result, galil.Capture):
        if result.result is None:
            result.stop()
    elif isinstance(result, galil.gearing.Gearing):
        result.off()
    elif type(result).__name__ == "Watchdog":
        result.stop()  # type: ignore[attr-defined]
    elif isinstance(result, galil.MoveHandle):
        result.stop()
    elif isinstance(result, (types.FunctionType, types.MethodType)):
        result()  # an unsubscribe


def _moving(dmc: galil.Controller) -> list[str]:
    bg = dmc.query_numbers("MG " + ",".join(f"_BG{a}" for a in dmc.axes))
    return [a for a, v in zip(dmc.axes, bg, strict=True) if v]


def _settle(dmc: galil.Controller) -> None:
    if _moving(dmc):
        dmc.stop()
    for _ in range(100):
        if not _moving(dmc):
            return
        dmc.sleep(0.05)
    raise AssertionError(f"axes still moving: {_moving(dmc)}")


def _case(
    dmc: galil.Controller, entry: Entry, param: str, label: str, bad: object, *, valid: bool = False
) -> list[str]:
    """Run one case; return what went wrong (empty when nothing did). ``valid``: the value is
    valid and the call must succeed."""
    where = f"{entry.group}.{entry.name}({param}={label})"
    group = GROUPS[entry.group]
    target = group.make(dmc)
    args = {k: _resolve(v, dmc) for k, v in entry.valid.items()}
    before = getattr(target, entry.name) if entry.kind == "set" else None
    args[param] = bad
    moving_before = _moving(dmc)  # a handle's or a gearing's own motion
    problems: list[str] = []
    raised: BaseException | None = None
    sent: AssertionError | None = None
    result: object = None
    may_send = param in entry.raw and isinstance(bad, str)
    accepted = functools.partial(_accepted, entry, param, target)
    try:
        with nothing_sent(dmc, allow_queries=True):
            try:
                result = _invoke(entry, target, args)
            except queue.Empty:  # a queue's get that timed out: the timeout was taken
                pass  # (a galil.QueueTimeoutError, so caught before GalilError)
            except galil.GalilError as exc:
                raised = exc
            except (KeyError, TypeError) as exc:
                raised = exc
                if not entry.lookup or (type(exc) is TypeError and "unhashable" not in str(exc)):
                    problems.append(f"{where}: bare {type(exc).__name__}: {str(exc)[:120]}")
            except Exception as exc:
                raised = exc
                problems.append(f"{where}: bare {type(exc).__name__}: {str(exc)[:120]}")
    except AssertionError as exc:
        sent = exc
    problems += verdict(where, raised, sent, may_send, valid, lambda: label in accepted())
    if raised is None:
        _dispose(result)
        if entry.kind == "set":
            setattr(target, entry.name, before)
    after, broken = _afterwards(dmc, where, moving_before, raised is not None or not entry.moves)
    problems += after
    if broken:
        return problems
    group.after(dmc, target)
    _settle(dmc)
    return problems


def verdict(
    where: str,
    raised: BaseException | None,
    sent: AssertionError | None,
    may_send: bool,
    valid: bool,
    accepted: Callable[[], bool],
) -> list[str]:
    """What is wrong with one call (sync or async): refused after something was sent (unless
    the value is a raw text only the controller judges), a valid call that failed, a bad
    value taken that is not ``accepted()`` on purpose. ``sent``: what ``nothing_sent`` said."""
    problems = []
    if sent is not None and raised is not None and not may_send:
        problems.append(f"{where}: refused after sending: {str(sent)[:160]}")
    if valid and raised is not None:
        problems.append(f"{where}: the valid call failed: {raised!r:.300}")
    if raised is None and not valid and not accepted():
        problems.append(f"{where}: taken, not refused")
    return problems


def _afterwards(
    dmc: galil.Controller, where: str, moving_before: Sequence[str], no_motion: bool
) -> tuple[list[str], bool]:
    """What is wrong with the link and the axes after a case (``no_motion``: the call was
    refused, or starts no motion), and whether the link is broken."""
    try:
        problems = []
        if dmc.query_number("MG 1+1") != 2:
            problems.append(f"{where}: the link answers wrongly afterwards")
        moving = _moving(dmc)
    except galil.GalilError as exc:
        return [f"{where}: the link is broken afterwards: {exc}"], True
    started = sorted(set(moving) - set(moving_before))
    if started and no_motion:
        problems.append(f"{where}: left {started} moving")
    return problems, False


def _params(entry: Entry, target: object) -> list[str]:
    if entry.kind != "call":
        return list(entry.valid)
    sig = inspect.signature(getattr(target, entry.name))
    named = [
        p.name for p in sig.parameters.values() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)
    ]
    missing = [p for p in named if p not in entry.valid]
    assert not missing, f"{entry.group}.{entry.name}: no valid value for {missing}"
    return list(entry.valid)  # the named ones and any **overrides given


@contextlib.contextmanager
def _connected(entry: Entry) -> Iterator[galil.Controller]:
    if not entry.tcp:
        with simulated(entry.model) as dmc:
            yield dmc
        return
    with SimTcpServer(model=entry.model) as server, galil.connect(server.url) as dmc:
        yield dmc


@pytest.mark.timeout(60)
@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: f"{e.group}.{e.name}")
def test_bad_values_are_refused_before_anything_is_sent(entry: Entry) -> None:
    with _connected(entry) as dmc:
        group = GROUPS[entry.group]
        probe = group.make(dmc)
        params = _params(entry, probe)
        group.after(dmc, probe)
        _settle(dmc)
        # the valid call works (or the cases would prove nothing)
        first = _resolve(entry.valid[params[0]], dmc)
        problems = _case(dmc, entry, params[0], "valid", first, valid=True)
        assert not problems, problems
        for param in params:
            for label, bad in BAD:
                if bad is None and _none_allowed(entry, param, probe):
                    continue
                problems += _case(dmc, entry, param, label, bad)
        assert not problems, "\n".join(problems)
