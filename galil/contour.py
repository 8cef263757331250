"""Contour mode, host side: turn an ideal path into the integer increments CD sends.

The planner keeps the commanded path within half a count of the ideal one: increment i is
``round(path[i]) - round(path[i-1])``, so the running sum is the rounded ideal position at every
segment end (no drift) and the total is exact.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from galil.client import Controller
    from galil.predict import Profile

from galil.errors import ContourUnderrunError, GalilError, InvalidArgument

__all__ = ["ContourResult", "ContourUnderrunError", "increments", "sample_path", "stream"]


def _round(x: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    # Half-way values round up (floor(x + 0.5)) so the rule does not depend on parity.
    out: npt.NDArray[np.int64] = np.floor(x + 0.5).astype(np.int64)
    return out


def increments(path: npt.ArrayLike, *, start: int = 0) -> npt.NDArray[np.int64]:
    """Integer CD increments that follow ``path`` (ideal absolute positions at segment ends).

    Args:
        path: ideal positions in counts at the end of each segment (floats allowed).
        start: the (integer) position before the first segment.

    Returns:
        int64 increments; ``start + cumsum(increments) == round(path)`` element by element.

    Raises:
        InvalidArgument: the path is not 1-D and finite, or ``start`` is not a whole count.
    """
    x = np.asarray(path, dtype=np.float64)
    if x.ndim != 1:
        raise InvalidArgument(f"path must be 1-D, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InvalidArgument("path holds NaN or infinity")
    if int(start) != start:
        raise InvalidArgument(f"start must be a whole count, got {start!r}")
    ends = _round(x)
    out: npt.NDArray[np.int64] = np.diff(ends, prepend=np.int64(int(start)))
    return out


def sample_path(
    func: Callable[[npt.NDArray[np.float64]], npt.ArrayLike],
    duration: float,
    dt: int,
    sample_period: float = 1 / 1024,
) -> npt.NDArray[np.float64]:
    """Sample ``func(t)`` (t in seconds) at the end of each ``2**dt``-sample segment.

    The last segment end is clipped to ``duration`` so the path ends on ``func(duration)``
    (that segment then moves its whole remainder in ``2**dt`` samples).

    Args:
        func: position in counts as a function of time; called once with an array of times.
        duration: seconds covered.
        dt: the DT exponent (1..8).
        sample_period: seconds per servo sample.

    Returns:
        Ideal absolute positions at the segment ends (floats), ready for :func:`increments`.

    Raises:
        InvalidArgument: bad duration, DT or sample period, or ``func`` returns a wrong shape.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise InvalidArgument(f"duration must be positive, got {duration!r}")
    if not 1 <= int(dt) <= 8 or int(dt) != dt:
        raise InvalidArgument(f"DT must be an integer in 1..8, got {dt!r}")
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise InvalidArgument(f"sample_period must be positive, got {sample_period!r}")
    seg = (1 << int(dt)) * sample_period
    count = max(1, math.ceil(duration / seg - 1e-9))
    t = np.minimum(np.arange(1, count + 1, dtype=np.float64) * seg, duration)
    x = np.asarray(func(t), dtype=np.float64)
    if x.shape != t.shape:
        raise InvalidArgument(f"func returned shape {x.shape}, expected {t.shape}")
    return x


@dataclass(frozen=True)
class ContourResult:
    """A finished contour stream.

    Attributes:
        axes: the contour axes.
        increments: the CD increments sent, shape (segments, axes).
        dt: the DT exponent used.
        profiles: predicted profile per axis.
        low_water: fewest free buffer slots seen while streaming (``_CM``).
        lines: command lines sent for the segments.
    """

    axes: str
    increments: npt.NDArray[np.int64]
    dt: int
    profiles: dict[str, Profile]
    low_water: int
    lines: int

    @property
    def duration(self) -> float:
        """Predicted duration in seconds."""
        return max(p.duration for p in self.profiles.values())


def _link_options(controller: Controller) -> dict[str, Any]:
    transport = controller.transport
    kind = getattr(transport, "kind", "")
    if kind == "serial":
        # The serial transport keeps its pyserial object on ``port``; a plug-in may carry
        # ``baudrate`` itself. An unknown rate is taken as the slowest common one.
        baud = getattr(transport, "baudrate", None)
        if baud is None:
            baud = getattr(getattr(transport, "port", None), "baudrate", None)
        return {"baud": float(baud) if baud else 9600.0}
    if kind == "ethernet":
        return {"ethernet": True}
    return {}  # in-process, USB and PCI links are far faster than any contour needs


def _cd_text(letters: str, all_axes: str, row: Sequence[int]) -> str:
    # CD takes one field per controller axis, in axis order; non-contour fields stay empty.
    fields = [""] * (max(all_axes.index(a) for a in letters) + 1)
    for a, v in zip(letters, row, strict=True):
        fields[all_axes.index(a)] = str(int(v))
    return "CD " + ",".join(fields)


def stream(
    controller: Controller,
    axes: str | Sequence[str],
    path: npt.ArrayLike,
    *,
    dt: int,
    progress: bool = False,
    timeout: float | None = None,
) -> ContourResult:
    """Run a contour: check it, enter CM, keep the buffer fed, end with ``CD 0=0``, wait.

    Args:
        controller: the connected controller.
        axes: contour axes, e.g. ``"B"`` or ``"AB"``.
        path: ideal positions *relative to where each axis is now*, at the end of each
            ``2**dt``-sample segment; shape (segments,) or (segments, axes). Plain numbers are
            counts; a pint Quantity array is converted through each axis's scale.
        dt: DT exponent (segments last ``2**dt`` samples).
        progress: show a ``tqdm.auto`` bar over segments.
        timeout: seconds to wait for the contour to finish after the last segment (default:
            its predicted duration plus a margin).

    Raises:
        LimitError: an increment outside the CD range, a DT outside the model's range, or a
            link too slow for the stream (nothing is sent then).
        InvalidArgument: a bad path or axis, or an axis already moving (nothing is sent).
        ContourUnderrunError: the buffer ran dry while streaming (the contour is ended).
    """
    from galil import predict
    from galil.predict.checks import check_contour

    model = controller.model
    names = list(axes) if isinstance(axes, str) else [str(a) for a in axes]
    letters = "".join(model.axis_letter(a) for a in names)
    if not letters or len(set(letters)) != len(letters):
        raise InvalidArgument(f"contour axes must be distinct and non-empty, got {axes!r}")
    if isinstance(dt, bool) or not isinstance(dt, int):
        raise InvalidArgument(f"dt must be an integer exponent, got {dt!r}")
    ideal = _path_counts(controller, letters, path)
    if ideal.ndim == 1:
        ideal = ideal[:, None]
    if ideal.ndim != 2 or ideal.shape[1] != len(letters) or ideal.shape[0] == 0:
        raise InvalidArgument(
            f"path must have shape (segments,) or (segments, {len(letters)}), got "
            f"{np.asarray(path).shape}"
        )
    incs = np.stack([increments(ideal[:, j]) for j in range(len(letters))], axis=1)
    link = _link_options(controller)
    for j, a in enumerate(letters):
        check_contour(
            incs[:, j],
            dt,
            model=model,
            axis=a,
            sample_period=controller.sample_period,
            bytes_per_segment=len(_cd_text(letters, model.axes, incs[0])) + 1,
            **link,
        )
    ops = ("RP", "BG", "BL", "FL")
    state = controller.query_operands([f"_{op}{a}" for a in letters for op in ops])
    axis_state = {a: state[j * len(ops) : (j + 1) * len(ops)] for j, a in enumerate(letters)}
    for a, (_, bg, _, _) in axis_state.items():
        if bg:
            raise InvalidArgument(f"axis {a} is moving; stop it before a contour", model=model.name)
    starts = {a: round(axis_state[a][0]) for a in letters}
    profiles = {
        a: predict.contour(incs[:, j], dt, start=starts[a], sample_period=controller.sample_period)
        for j, a in enumerate(letters)
    }
    for a, prof in profiles.items():
        # The whole path against FL/BL, as for any move, before CM goes out.
        predict.check_soft_limits(prof, low=axis_state[a][2], high=axis_state[a][3], axis=a)
    texts = [_cd_text(letters, model.axes, row) for row in incs.tolist()]
    depth = model.contour_buffer
    seg_time = (1 << dt) * controller.sample_period
    # Refill when a quarter of the buffer is free: few long lines, and most of the buffer
    # still queued (a quarter of 511 segments is 0.25 s even at DT 1).
    refill = max(1, depth // 4)
    bar = _bar(len(texts), letters) if progress else None
    if round(controller.query_operands(["_TC"])[0]) == 42:
        controller.command("TC 0")  # a previous stream's code; ours must be seen afresh
    controller.command_line([f"CM {letters}", f"DT {dt}"])
    sent = 0
    lines = 0
    low_water = depth
    try:
        while sent < len(texts):
            free_f, tc = controller.query_operands(["_CM", "_TC"])
            free = round(free_f)
            if sent and round(tc) == 42:
                raise ContourUnderrunError(
                    f"contour buffer ran dry after {sent} of {len(texts)} segments "
                    "(TC 42: contour data sent too slowly)",
                    segment=sent,
                    model=model.name,
                )
            low_water = min(low_water, free)
            room = free - 1  # one spare: models differ in whether _CM counts the running one
            if depth <= 2:
                # A one-deep buffer: WC holds its ':' until the segment before is running.
                controller.command_line([texts[sent], "WC"], timeout=seg_time * 4 + 1.0)
                sent += 1
                lines += 1
            elif room >= min(refill, len(texts) - sent):
                batch = texts[sent : sent + room]
                controller.command_line(batch)
                sent += len(batch)
                lines += _line_count(batch, model.line_length)
            else:
                # Wait for the room one refill needs, but poll at least every 50 ms and well
                # within what is queued: a late look costs more than an early one.
                queued = (depth - free) * seg_time
                need = (refill - max(room, 0)) * seg_time
                controller._pause(max(seg_time, min(need, queued / 4, 0.05)))
            if bar is not None:
                bar.update(sent - bar.n)
        # How full the buffer got: the last batch is the fullest moment of a short path.
        low_water = min(low_water, round(controller.query_operands(["_CM"])[0]))
    except BaseException:
        # Leave the controller out of contour mode whatever happened; report the first error.
        with contextlib.suppress(GalilError):
            controller.command("CD 0=0")
        raise
    finally:
        if bar is not None:
            bar.close()
    controller.command("CD 0=0")
    wait = timeout if timeout is not None else max(p.duration for p in profiles.values()) + 2.0
    deadline = controller._clock() + wait
    while any(controller._query_ints([f"_BG{a}" for a in letters])):
        now = controller._clock()
        if now > deadline:
            from galil.errors import GalilTimeoutError

            raise GalilTimeoutError(
                f"contour on {letters} not finished after {wait:.3g} s", model=model.name
            )
        controller._pause(min(0.05, max(seg_time, 0.005), max(deadline - now, 0.001)))
    return ContourResult(letters, incs, dt, profiles, low_water, lines)


def _path_counts(controller: Controller, letters: str, path: Any) -> npt.NDArray[np.float64]:
    """The path in counts: plain numbers as they are, a Quantity through each axis's scale."""
    from galil.units import counts_or_plain, is_quantity

    if not is_quantity(path):
        return np.asarray(path, dtype=np.float64)
    magnitude = np.asarray(path.magnitude, dtype=np.float64)
    columns = magnitude[:, None] if magnitude.ndim == 1 else magnitude
    if columns.ndim != 2 or columns.shape[1] != len(letters):
        return magnitude  # the shape check after this call reports it
    out = np.empty_like(columns)
    for j, a in enumerate(letters):
        scale = controller.axes[a].scale
        unit_of = path.units
        if scale is None:
            out[:, j] = [
                counts_or_plain(v * unit_of, f"contour path on {a}") for v in columns[:, j]
            ]
        else:
            # One conversion factor per axis: the path is relative, so no offset applies.
            factor = scale.distance_to_counts(1.0 * unit_of, f"contour path on {a}")
            out[:, j] = columns[:, j] * factor
    return out.ravel() if magnitude.ndim == 1 else out


def _line_count(parts: Sequence[str], limit: int) -> int:
    count, length = 1, 0
    for p in parts:
        if length and length + 1 + len(p) + 1 > limit:
            count += 1
            length = 0
        length += len(p) + (1 if length else 0)
    return count


def _bar(total: int, letters: str) -> Any:
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=f"contour {letters}", unit="seg")
