"""No ``Any`` in a public signature (decision 0099): every parameter and return of the public
functions, methods (inherited ones too), properties (getters and setters), ``__init__`` and
protocol methods of the public classes, sync and async, is typed with what the library takes
and returns. ``Any`` there tells a type checker nothing: ``x.position.to("mm")`` passed mypy
and failed at run time on an axis without a scale, and a str position passed mypy.

The annotations are evaluated (``typing.get_type_hints``; names a module imports for type
checking only are imported for it), so an annotation that does not resolve fails too, and the
aliases are looked through: ``Any`` hidden in an alias, a ``Mapping``'s values, a
``Callable``'s return, a ``**kwargs`` TypedDict or an overload is found. numpy's own ``Any``
(an array's shape, ``npt.ArrayLike``'s internals) is numpy's, not the library's, and is not.

An ``Any`` that is right stays only in :data:`ALLOWED`, with its reason.
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import pkgutil
import re
import sys
import types
import typing
from collections.abc import Callable, Iterator
from typing import Any, TypedDict

import numpy as np
import pytest

import galil

#: The Anys that are right, and why: ``"<where>: <parameter>"`` (``return`` for the return).
ALLOWED: dict[str, str] = {
    "galil.transport.usb.UsbTransport.__init__: device": "a pyusb device: pyusb is untyped",
    "galil.bluesky.GalilMotor.connect: mock": "ophyd-async's Device.connect takes a bare"
    " DeviceMock (DeviceMock[Any]); an override may not take less",
    "galil.bluesky.GalilContourFlyer.connect: mock": "as GalilMotor.connect: ophyd-async's"
    " Device.connect signature",
    "galil.bluesky.GalilContourFlyer.collect: return": "event_model's PartialEvent, the"
    " document bluesky's Flyable.collect yields, holds Any values",
}

#: Anys in files that were being changed elsewhere when this test came (bluesky, records,
#: queues, capture, arrays, moves): the lead types them after merging, and empties this list.

#: The protocol methods looked at besides the public names (the ones a user reaches by syntax).
DUNDERS = frozenset(
    {
        "__init__", "__call__", "__getitem__", "__setitem__", "__delitem__", "__contains__",
        "__iter__", "__aiter__", "__next__", "__anext__", "__len__", "__await__",
        "__enter__", "__exit__", "__aenter__", "__aexit__",
    }
)  # fmt: skip

_ANY_WORD = re.compile(r"\bAny\b")


def _public_modules() -> list[types.ModuleType]:
    """``galil``, its public modules and packages, and the public modules of those packages."""
    names = ["galil"]
    for info in pkgutil.iter_modules(galil.__path__):
        if info.name.startswith("_") or info.name == "__main__":
            continue
        names.append(f"galil.{info.name}")
        if info.ispkg:
            package = importlib.import_module(f"galil.{info.name}")
            names += [
                f"galil.{info.name}.{sub.name}"
                for sub in pkgutil.iter_modules(package.__path__)
                if not sub.name.startswith("_")
            ]
    modules = []
    for name in names:
        try:
            modules.append(importlib.import_module(name))
        except ImportError:  # an optional dependency (ophyd-async on Python 3.10)
            continue
    return modules


@functools.cache
def _type_checking_names(module_name: str) -> dict[str, object]:
    """What ``module_name`` imports under ``if TYPE_CHECKING:`` (matplotlib's Figure ...),
    imported here so that its annotations resolve."""
    module = sys.modules[module_name]
    try:
        tree = ast.parse(inspect.getsource(module))
    except (OSError, TypeError):
        return {}
    found: dict[str, object] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            code = compile(ast.Module(body=node.body, type_ignores=[]), module_name, "exec")
            space: dict[str, object] = {"__name__": module_name}
            try:
                exec(code, space)
            except ImportError:  # an optional dependency: left unresolved, and reported
                continue
            found.update({k: v for k, v in space.items() if not k.startswith("__")})
    return found


def _namespace(func: Callable[..., object]) -> dict[str, object]:
    module_name = getattr(func, "__module__", None) or "galil"
    module = sys.modules.get(module_name)
    space = dict(vars(module)) if module is not None else {}
    space.update(getattr(func, "__globals__", {}))
    for name, value in _type_checking_names(module_name).items():
        space.setdefault(name, value)
    return space


def _hides_any(tp: object) -> bool:
    """Whether the evaluated annotation ``tp`` is or holds ``Any`` (numpy's own excepted)."""
    if tp is Any:
        return True
    if isinstance(tp, typing.ForwardRef):
        return bool(_ANY_WORD.search(tp.__forward_arg__))
    if isinstance(tp, str):
        return bool(_ANY_WORD.search(tp))
    if isinstance(tp, (list, tuple)):  # a Callable's parameters
        return any(_hides_any(t) for t in tp)
    if typing.is_typeddict(tp):
        return any(_hides_any(t) for t in typing.get_type_hints(tp).values())
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is None or origin is typing.Literal:
        return False
    if origin is np.ndarray:  # (its shape is numpy's; its dtype is the library's)
        return _hides_any(args[1]) if len(args) > 1 else False
    if origin is np.dtype:
        return any(_hides_any(t) for t in args)
    if getattr(origin, "__module__", "").startswith("numpy"):
        return False  # numpy's own protocols (npt.ArrayLike's internals)
    return any(_hides_any(t) for t in args)


def _evaluated(raw: object, space: dict[str, object]) -> object:
    """The annotation ``raw`` evaluated in ``space``; ``raw`` itself (looked at as text) when
    it does not evaluate at run time (``array.array[float]`` before Python 3.12)."""
    if not isinstance(raw, str):
        return raw
    try:
        return typing.get_type_hints(_Holder(raw), globalns=space)["value"]
    except Exception:
        return raw


class _Holder:
    """An object whose one annotation is a given string (for ``typing.get_type_hints``)."""

    def __init__(self, annotation: str) -> None:
        self.__annotations__ = {"value": annotation}


def _found_in(func: Callable[..., object], where: str) -> Iterator[str]:
    """``"<where>: <parameter>"`` for each parameter (and ``return``) whose annotation is or
    holds ``Any``, in ``func`` and its overloads: as written, and evaluated."""
    get_overloads: Callable[[object], list[Callable[..., object]]] = getattr(
        typing, "get_overloads", lambda f: []
    )  # (Python 3.11+)
    for variant in [func, *get_overloads(func)]:
        space = _namespace(variant)
        for name, raw in getattr(variant, "__annotations__", {}).items():
            if _hides_any(raw) or _hides_any(_evaluated(raw, space)):
                yield f"{where}: {name}"


def _functions_of(cls: type) -> Iterator[tuple[str, Callable[..., object]]]:
    """The public methods, properties (getter and setter) and protocol methods of ``cls``,
    inherited ones too (from the library's classes), each as (name, function)."""
    names: set[str] = set()
    for base in cls.__mro__:
        if base.__module__.startswith("galil"):
            names |= {n for n in vars(base) if not n.startswith("_") or n in DUNDERS}
    for name in sorted(names):
        attr = inspect.getattr_static(cls, name)
        if isinstance(attr, property):
            if attr.fget is not None:
                yield name, attr.fget
            if attr.fset is not None:
                yield f"{name}=", attr.fset
            continue
        if isinstance(attr, (staticmethod, classmethod)):
            attr = attr.__func__
        if inspect.isfunction(attr):
            yield name, attr


def _defined_here(obj: object) -> bool:
    return str(getattr(obj, "__module__", "")).startswith("galil")


def _anys_in(modules: list[types.ModuleType]) -> set[str]:
    found: set[str] = set()
    seen: set[int] = set()
    for module in modules:
        names = getattr(module, "__all__", None) or [n for n in dir(module) if n[:1] != "_"]
        for name in names:
            obj = getattr(module, name, None)
            if obj is None or id(obj) in seen:
                continue
            seen.add(id(obj))
            if inspect.isclass(obj):
                if not _defined_here(obj) or typing.is_typeddict(obj):
                    continue
                where = f"{obj.__module__}.{obj.__qualname__}"
                for attr, func in _functions_of(obj):
                    found.update(_found_in(func, f"{where}.{attr}"))
            elif inspect.isfunction(obj):
                if _defined_here(obj):
                    found.update(_found_in(obj, f"{obj.__module__}.{obj.__qualname__}"))
            elif callable(obj) and _defined_here(type(obj)):  # (an instance: galil.units.ureg)
                call = type(obj).__call__
                found.update(_found_in(call, f"{module.__name__}.{name}"))
    return found


@pytest.fixture(scope="module")
def anys() -> set[str]:
    return _anys_in(_public_modules())


def test_no_public_signature_has_any(anys: set[str]) -> None:
    unexplained = sorted(anys - set(ALLOWED))
    assert not unexplained, (
        f"Any in public signatures (type them; an Any that is right goes in ALLOWED with its "
        f"reason): {unexplained}"
    )


def test_every_allowed_any_is_still_there(anys: set[str]) -> None:
    stale = sorted(set(ALLOWED) - anys)
    assert not stale, f"allowed Anys that are no more (remove them from the lists): {stale}"
    assert all(reason.strip() for reason in ALLOWED.values())


# -- the walker itself: Any is found wherever it hides, numpy's own is not -----------------


class _Options(TypedDict, total=False):
    speed: Any


class _Clean(TypedDict, total=False):
    speed: float


if sys.version_info >= (3, 11):
    from typing import Unpack
else:
    from typing_extensions import Unpack


def _fake_module() -> types.ModuleType:
    """A module of the library (by its name) with Any in each place a walk must look."""
    module = types.ModuleType("galil._fake_for_the_walk")
    source = """
from __future__ import annotations
from collections.abc import Callable, Mapping
from typing import Any, overload
import numpy as np
import numpy.typing as npt

def returns_any() -> Any: ...
def mapping_of_any(x: Mapping[str, Any]) -> None: ...
def callable_to_any(f: Callable[..., Any]) -> None: ...
def kwargs_any(**options: Any) -> None: ...
def kwargs_typed_dict(**options: Unpack[_Options]) -> None: ...
def array_of_any(a: npt.NDArray[Any]) -> None: ...
def numpy_own(a: npt.ArrayLike, b: npt.NDArray[np.float64], c: np.integer) -> float: ...
def clean_kwargs(**options: Unpack[_Clean]) -> None: ...
@overload
def overloaded(x: int) -> Any: ...
@overload
def overloaded(x: str) -> str: ...
def overloaded(x: int | str) -> object: ...

class Base:
    def inherited(self, x: Any) -> None: ...

class Room(Base):
    def __init__(self, value: Any) -> None: ...
    @property
    def reading(self) -> Any: ...
    @reading.setter
    def reading(self, value: Any) -> None: ...
    def __getitem__(self, key: int) -> float: ...
    def _private(self, x: Any) -> None: ...
"""
    space = vars(module)
    space.update(_Options=_Options, _Clean=_Clean, Unpack=Unpack)
    sys.modules[module.__name__] = module
    exec(compile(source, "<fake>", "exec"), space)
    return module


def test_the_walk_finds_any_wherever_it_hides_and_not_numpys_own() -> None:
    module = _fake_module()
    try:
        found = _anys_in([module])
    finally:
        del sys.modules[module.__name__]
    fake = "galil._fake_for_the_walk"
    assert found == {
        f"{fake}.returns_any: return",
        f"{fake}.mapping_of_any: x",
        f"{fake}.callable_to_any: f",
        f"{fake}.kwargs_any: options",
        f"{fake}.kwargs_typed_dict: options",
        f"{fake}.array_of_any: a",
        f"{fake}.overloaded: return",
        f"{fake}.Base.inherited: x",
        f"{fake}.Room.__init__: value",
        f"{fake}.Room.inherited: x",
        f"{fake}.Room.reading: return",
        f"{fake}.Room.reading=: value",
    }


def test_the_public_types_resolve_at_run_time() -> None:
    # What the signatures name is there at run time (the sync/async twin test evaluates them).
    move_to = typing.get_type_hints(galil.Axis.move_to)
    assert move_to["position"] == galil.Amount
    assert typing.get_args(move_to["overrides"]) == (galil.MoveOverrides,)
    assert set(typing.get_type_hints(galil.MoveOverrides)) == {"speed", "accel", "decel"}
    position = inspect.getattr_static(galil.Axis, "position").fget
    assert typing.get_type_hints(position)["return"] == galil.Reading
