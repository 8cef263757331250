"""Electronic gearing (``GA``, ``GR``): a follower's reference from its master's motion.

``GR`` ratios lie within ±127 with a resolution of 1/65536 (40x0 and 18x6 command references).
Assumptions until a controller log pins them (ADR 0009):

- A ratio is stored truncated towards zero to a multiple of 1/65536 (a GR page of Galil's
  SMC-4000 OEM manual: "only the integer portion is stored").
- The follower's reference is its position when gearing engaged plus ratio × the master's
  displacement since then, carried exactly at 1/65536 count and rounded half up (the engine's
  rule), so nothing drifts however long it runs. A ratio change (``GR`` while geared) carries
  on from the exact follower position at that sample.
- The prediction follows the master's predicted *reference*: exact for a commanded-position
  master (``GA CA``) or the vector distance of a sequence (``GA S``: pass
  :attr:`VectorProfile.path`); an encoder master (``GA A``) adds the master's following error.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from galil.errors import InvalidArgument, LimitError
from galil.models import ModelSpec
from galil.predict.checks import resolve_model
from galil.predict.counts import whole_counts
from galil.predict.profile import Profile

__all__ = ["GearFollower", "gear", "gear_profile", "quantise_ratio"]

Int64Array = npt.NDArray[np.int64]
_ONE = 65536  # fixed-point scale of positions (1/65536 count)


def quantise_ratio(ratio: float, model: str | ModelSpec = "DMC-4040") -> float:
    """A GR ratio as the controller stores it: truncated to the model's resolution.

    Raises:
        LimitError: not finite, or beyond the model's ±``gr_max``.
    """
    spec = resolve_model(model)
    if not (isinstance(ratio, (int, float)) and math.isfinite(ratio)):
        raise LimitError(
            f"GR must be a finite number, got {ratio!r}",
            name="GR",
            value=None,
            limit=spec.gr_max,
            model=spec.name,
        )
    if abs(ratio) > spec.gr_max:
        raise LimitError(
            f"GR {ratio:g} is beyond ±{spec.gr_max:g} on {spec.name}",
            name="GR",
            value=float(ratio),
            limit=spec.gr_max,
            model=spec.name,
        )
    steps = math.trunc(ratio / spec.gr_resolution)
    return steps * spec.gr_resolution


def _fixed_ratio(ratio: float, resolution: float) -> int:
    """The ratio in 1/65536 units (the resolution must divide 1/65536 evenly)."""
    steps = ratio / resolution
    per_step = resolution * _ONE
    if not (steps.is_integer() and per_step.is_integer()):
        raise InvalidArgument(f"ratio {ratio!r} is not a multiple of {resolution!r}")
    return int(steps) * int(per_step)


def _masters(master: npt.ArrayLike) -> Int64Array:
    m = np.asarray(master)
    if m.ndim != 1:
        raise InvalidArgument("master positions must be a 1-D sequence of counts")
    if not (np.issubdtype(m.dtype, np.integer) or np.all(m == np.round(m))):
        raise InvalidArgument("master positions must be whole counts")
    out: Int64Array = m.astype(np.int64)
    return out


class GearFollower:
    """The follower side of ``GA``/``GR``, stepped with its master's samples.

    The simulator feeds it the master's reference sample by sample; :func:`gear` feeds it a
    whole prediction. The positions are a pure function of the master values since the last
    ratio change, so any chunking gives the same result.

    Args:
        ratio: GR, already quantised (:func:`quantise_ratio`).
        master: the master's position when gearing engages, counts.
        position: the follower's position then, counts.
        resolution: GR step (:attr:`ModelSpec.gr_resolution`).

    Attributes:
        ratio: the ratio in force.
        position: the follower's reference after the last sample, counts.
    """

    def __init__(
        self, ratio: float, *, master: int, position: int, resolution: float = 1 / 65536
    ) -> None:
        self.resolution = float(resolution)
        self.ratio = float(ratio)
        self._q = _fixed_ratio(self.ratio, self.resolution)
        self._m0 = int(master)
        self._base = int(position) * _ONE  # follower at the anchor, 1/65536 count
        self._last_master = int(master)
        self.position = int(position)

    def _fixed(self, m: Int64Array) -> Int64Array:
        out: Int64Array = self._base + self._q * (m - self._m0)
        return out

    def follow(self, master: npt.ArrayLike) -> Int64Array:
        """Commit the next samples, given the master's position at each; return the follower's."""
        m = _masters(master)
        out = (self._fixed(m) + _ONE // 2) >> 16
        if m.size:
            self._last_master = int(m[-1])
            self.position = int(out[-1])
        return out

    def set_ratio(self, ratio: float) -> None:
        """``GR`` while geared: the new ratio applies from the next sample on."""
        q = _fixed_ratio(float(ratio), self.resolution)
        self._base = int(self._fixed(np.array([self._last_master], dtype=np.int64))[0])
        self._m0 = self._last_master
        self._q = q
        self.ratio = float(ratio)


def gear(
    master: npt.ArrayLike,
    ratio: float,
    *,
    start: int = 0,
    model: str | ModelSpec = "DMC-4040",
) -> Int64Array:
    """Predict a follower geared to ``master`` from sample 0 (gearing engaged there).

    Args:
        master: the master's predicted positions, counts, one per sample (e.g.
            ``Profile.position``, or ``VectorProfile.path`` for ``GA S``).
        ratio: GR; quantised for ``model`` first.
        start: the follower's position at sample 0.
        model: model name or spec (GR range and resolution).

    Returns:
        The follower's reference at each sample (int64): ``start + ratio·(master - master[0])``
        at 1/65536 count, rounded half up.

    Raises:
        LimitError: a ratio beyond the model's range. InvalidArgument: bad master positions.
    """
    spec = resolve_model(model)
    q = quantise_ratio(ratio, spec)
    m = _masters(master)
    if m.size == 0:
        return np.empty(0, dtype=np.int64)
    position = whole_counts(start, "start")
    follower = GearFollower(q, master=int(m[0]), position=position, resolution=spec.gr_resolution)
    return follower.follow(m)


def gear_profile(
    master: Profile,
    ratio: float,
    *,
    start: int = 0,
    model: str | ModelSpec = "DMC-4040",
) -> Profile:
    """:func:`gear` for a master :class:`Profile`; the follower's own :class:`Profile`."""
    q = quantise_ratio(ratio, model)
    pos = gear(master.position, q, start=start, model=model)
    return Profile.from_samples(
        pos,
        sample_period=master.sample_period,
        shape="geared",
        peak_speed=abs(q) * master.peak_speed,
        stop_code=master.stop_code,
    )
