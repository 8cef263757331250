"""Electronic gearing, host side: an axis that follows another at a ratio (``GA``, ``GR``).

``follower.gear_to(master, ratio)`` sends ``GA`` (the master's *commanded* position, ``CA``,
so the follower is exactly predictable: ADR 0009) and ``GR``, and returns a :class:`Gearing`.
From then on every move of the master predicts the follower too: the master's handle has the
follower in its ``profiles``, the ratio (as the controller stores it) times the master's
motion, sample by sample (:func:`galil.predict.gear`). ``master`` may also be ``"S"``, the
distance along the sequences of coordinate system S (``GA S``).

Outside gantry mode an ``ST``, a limit or ``AB`` on the follower turns its gearing off (the
manuals); the predictions follow that too. The controller superimposes a geared axis's own
moves on the gearing; the library does not predict that, so it refuses to move a geared axis.

A gearing the library did not set up (another program or host, or a burned ``GA``/``GR`` that
power-on or ``RS`` restored) is found at connect and after ``Controller.reset()`` by one read of
every axis's ratio (``_GR``: :func:`read_found`). ``GA`` has no operand and the reply of
``GA ?`` is not documented, so its master is not known: the library refuses the axis's own
motion until :func:`gear_off` (``axis.gear_off()``) turns it off (decision 0055).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Sequence

from galil import predict
from galil.errors import (
    CommandError,
    FixedAttributes,
    InvalidArgument,
    LimitError,
    ReadOnly,
    decimal_hint,
)
from galil.link import CommandLink
from galil.motion import (
    Display,
    GearLink,
    MotionTracker,
    found_text,
    refuse_dropped,
    sample_of,
    send_reopening,
)
from galil.protocol import commands as cmds
from galil.protocol.commands import Command
from galil.protocol.numbers import format_number
from galil.units import Scale

__all__ = ["Gearing", "gear_off", "gear_to", "read_found"]

_LOG = logging.getLogger("galil.gearing")


def _ratio(link: CommandLink, ratio: object) -> float:
    """GR as the controller will store it: four decimals on the wire, then its step.

    Raises:
        LimitError: beyond the model's range. InvalidArgument: not a number.
    """
    if isinstance(ratio, bool) or not isinstance(ratio, (int, float)):
        raise InvalidArgument(f"a gear ratio is a number, got {ratio!r}{decimal_hint(ratio)}")
    try:
        sent = float(format_number(float(ratio)))
    except InvalidArgument as exc:
        raise InvalidArgument(f"gear ratio {ratio!r}: {exc}") from None
    except OverflowError:  # an int too large for any float
        raise InvalidArgument(f"gear ratio {ratio!r:.40} is far out of range") from None
    return predict.quantise_ratio(sent, link.model)


class Gearing(FixedAttributes):
    """A follower geared to its master (from :meth:`galil.Axis.gear_to`).

    Attributes:
        follower: the geared axis.
        master: the master axis (its commanded position), or ``"S"``.
    """

    follower: ReadOnly[str] = ReadOnly()
    master: ReadOnly[str] = ReadOnly()

    def __init__(self, link: CommandLink, tracker: MotionTracker, gear: GearLink) -> None:
        self._link = link
        self._tracker = tracker
        self._gear = gear
        self._follower = gear.follower
        self._master = gear.master

    @property
    def ratio(self) -> float:
        """GR as the controller stores it (truncated to 1/65536)."""
        return self._gear.ratio

    @property
    def engaged(self) -> bool:
        """Whether the gearing holds (no ``GR 0``, ``ST``, limit or ``AB`` since)."""
        return self._tracker.gears.get(self.follower) is self._gear

    def predict(self, master: predict.Profile) -> predict.Profile:
        """The follower's profile for a profile of the master's commanded position (counts,
        absolute; for ``"S"``, the distance counted since the gearing engaged), with the
        fraction of a count the controller carries.

        Raises:
            InvalidArgument: the gearing is off.
        """
        if not isinstance(master, predict.Profile):
            raise InvalidArgument(f"master must be a galil.Profile, not {master!r:.60}")
        if not self.engaged:
            raise InvalidArgument(f"axis {self.follower} is not geared any more")
        return self._gear.profile(master)

    def set_ratio(self, ratio: float) -> None:
        """A new ratio (``GR``), while the master is at rest.

        Raises:
            InvalidArgument: the gearing is off, or the master is moving (the prediction of
                its move would not know when the ratio changed).
            LimitError: a ratio beyond the model's range, or of 0 (as ``gear_to``'s).
            MotionError: a limit stopped the follower since, unseen, and the controller
                turned its gearing off (:func:`~galil.motion.refuse_dropped`), or its ratio
                reads 0 on the controller (turned off by a limit, ``ST`` or ``AB`` whose stop
                code a later move overwrote); nothing is sent, and the gearing is forgotten.
        """
        q = _ratio(self._link, ratio)
        if q == 0:
            raise _zero_ratio(self._link, self.follower, ratio, "to turn it off, call off()")
        with self._tracker.lock:  # (the master at rest until the ratio is sent)
            self._set_ratio(q)

    def _set_ratio(self, q: float) -> None:
        if not self.engaged:
            raise InvalidArgument(f"axis {self.follower} is not geared any more")
        _master_at_rest(self._link, self.master)
        model = self._link.model
        name = "_AVS" if self.master == "S" else f"_RP{self.master}"
        gear = self._gear
        f = self.follower
        reads_ratios = self._tracker.reads_ratios
        now, code, *ratio = self._link.query_operands(
            [name, f"_SC{f}", *((f"_GR{f}",) if reads_ratios else ())]
        )
        # (a limit that dropped it unseen: GR would engage it again, from where it stopped;
        # a ratio of 0: the same, its stop code since overwritten by a program's move)
        refuse_dropped(
            self._link, self._tracker, {f: gear}, {f: round(code)}, {f: ratio[0]} if ratio else None
        )
        master_now = gear.travelled if self.master == "S" else round(now)

        def taken(_: list[str]) -> None:
            gear.anchor.follow([master_now])  # the controller carries on from the exact follower
            gear.anchor.set_ratio(q)
            gear.ratio = q

        line = [cmds.gr(model=model, **{f: q})]
        undo = [cmds.gr(model=model, **{f: gear.ratio})]  # (interrupted: back to the old one)
        _send_gr(self._link, self._tracker, line, taken, undo=undo)

    def off(self) -> None:
        """Turn the gearing off (``GR 0``): the follower stays where it is."""
        with self._tracker.lock:
            if self.engaged:
                self._off()

    def _off(self) -> None:
        def taken(replies: list[str]) -> None:
            self._gear.released = sample_of(replies[-1])
            self._tracker.release(self._gear)

        line = [cmds.gr(model=self._link.model, **{self.follower: 0}), cmds.time_stamp()]
        _send_gr(self._link, self._tracker, line, taken)

    def __enter__(self) -> Gearing:
        return self

    def __exit__(self, *exc: object) -> None:
        self.off()

    def __repr__(self) -> str:
        state = "engaged" if self.engaged else "off"
        return f"<Gearing {self.follower} = {self.ratio:g} x {self.master} {state}>"


def read_found(link: CommandLink, tracker: MotionTracker) -> None:
    """Read every axis's gear ratio (``_GR``, one line) and keep, as the tracker's
    :attr:`~galil.motion.MotionTracker.found`, the followers the library did not gear.

    Nothing is read on a model without axes. A controller that refuses ``_GR`` (a generic
    model, or firmware without the operand: only the DMC-4103 reference lists it) has no
    gearing found, and a warning says so on ``galil.gearing``; only a refusal is taken so, a
    dead link raises.
    """
    axes = link.model.axes
    if not axes:
        return
    try:
        ratios = link.query_operands([f"_GR{a}" for a in axes])
    except CommandError as exc:
        _LOG.warning(
            "galil: %s refused the gear ratios (%s): gearing set up elsewhere is not looked "
            "for on this link",
            link.model.name,
            exc,
        )
        tracker.found_geared(dict.fromkeys(axes, 0.0), readable=False)
        return
    tracker.found_geared(dict(zip(axes, ratios, strict=True)))


def gear_off(link: CommandLink, tracker: MotionTracker, follower: str) -> None:
    """Turn off any gearing of ``follower`` (``GR 0``; it stays where it is): one the library
    set up (as :meth:`Gearing.off`), one found on the controller (:func:`read_found`), or one
    nobody told the library of. Sent even when the library knows of none."""
    follower = link.model.axis_letter(follower)
    with tracker.lock:
        gear = tracker.gears.get(follower)
        if gear is not None:
            Gearing(link, tracker, gear)._off()
        else:
            line = [cmds.gr(model=link.model, **{follower: 0})]
            _send_gr(link, tracker, line, lambda _: _forget_found(tracker, follower))


def _forget_found(tracker: MotionTracker, follower: str) -> None:
    tracker.found.pop(follower, None)


def _send_gr(
    link: CommandLink,
    tracker: MotionTracker,
    line: Sequence[str | Command],
    taken: Callable[[list[str]], None],
    *,
    undo: Sequence[str | Command] | None = None,
) -> None:
    """Send ``line`` (a ``GR``) and call ``taken`` with its replies.

    Interrupted where it may have gone out (Ctrl-C, a timeout, a dead link: anything but the
    controller's refusal), the library would not know the ratio the controller has, the old
    or the new (decision 0069). Then ``undo`` (the old ratio) goes out, or without one (a
    gearing turned off: the safe side) the line again, ``taken`` following it; a dead link is
    reopened once for it. The exception goes on. If that fails too (the link stays dead), the
    library keeps the gearing as it knew it.
    """
    try:
        replies = link.command_line(line)
    except CommandError:
        raise  # refused: the ratio is as it was
    except BaseException:
        again: list[list[str]] = []
        back = undo or line
        went = send_reopening(lambda: again.append(link.command_line(back)), tracker.reconnect)
        if went and undo is None:
            taken(again[-1])
        raise
    taken(replies)


def _master_at_rest(link: CommandLink, master: str) -> None:
    name = "_BGS" if master == "S" else f"_BG{master}"
    if link.query_operands([name])[0]:
        raise InvalidArgument(
            f"master {master} is moving: engage or change gearing while it is at rest (the "
            "prediction of its move in progress would not include the follower)",
            model=link.model.name,
        )


def gear_to(
    link: CommandLink,
    tracker: MotionTracker,
    follower: str,
    master: str,
    ratio: object,
    *,
    display: Display | None = None,
    scale: Scale | None = None,
) -> Gearing:
    """Gear ``follower`` to ``master`` (an axis letter, or ``"S"``) at ``ratio``.

    Sends ``GA`` (commanded position ``C<master>``, or ``S``) and ``GR`` on one line.
    ``display`` and ``scale`` are the follower's (its predictions and refusals in its unit).

    Raises:
        InvalidArgument: an axis geared to itself, a master that is a follower or a follower
            that is a master (TC 46), the follower or the master moving, the follower's motor
            off; ``S`` on a controller of one axis (no path it could follow).
        LimitError: a ratio beyond the model's range (``GR``, ±127), or of 0.
    """
    model = link.model
    if master != "S":
        master = model.axis_letter(master)
    follower = model.axis_letter(follower)
    if master == "S" and not model.axes.replace(follower, ""):
        # (a path on the follower is refused while it follows: decision 0100)
        raise InvalidArgument(
            f"{model.name} has one axis, {follower}: it cannot follow S, whose paths run on "
            f"other axes (a path on {follower} itself is refused while it follows)",
            model=model.name,
        )
    q = _ratio(link, ratio)
    with tracker.lock:  # (both axes at rest until the gearing is sent and known)
        return _gear_to(link, tracker, follower, master, q, (display, scale))


def _gear_to(
    link: CommandLink,
    tracker: MotionTracker,
    follower: str,
    master: str,
    q: float,
    shown: tuple[Display | None, Scale | None],
) -> Gearing:
    model = link.model
    _check_pair(link, tracker, follower, master, q)
    m_name = "_AVS" if master == "S" else f"_RP{master}"
    bg, mo, f0, m0, sc = link.query_operands(
        [f"_BG{follower}", f"_MO{follower}", f"_RP{follower}", m_name, f"_SC{follower}"]
    )
    if not bg:  # (a move of the follower nobody saw end ends here, not in the gearing)
        tracker.ended(follower, f0, sc)
    if bg:
        raise InvalidArgument(f"axis {follower} is moving; stop it first", model=model.name)
    if mo:
        raise InvalidArgument(
            f"axis {follower} has its motor off; call controller.servo_here()", model=model.name
        )
    _master_at_rest(link, master)
    source = "S" if master == "S" else f"C{master}"
    line = [
        cmds.ga(model=model, **{follower: source}),
        cmds.gr(model=model, **{follower: q}),
        cmds.mg_operand(f"_SC{follower}"),  # (what _SC says once it follows: dropped_by)
    ]
    try:
        replies = link.command_line(line)
    except BaseException:
        _disengage(link, tracker, follower)  # a gearing the library would not know of
        raise
    anchor = predict.GearFollower(
        q, master=round(m0), position=round(f0), resolution=model.gr_resolution
    )
    code = sample_of(replies[-1])
    gear = GearLink(follower, master, q, anchor, shown[0], travelled=round(m0), scale=shown[1])
    gear.engaged_code = 0 if code is None else code
    tracker.engage(gear)
    return Gearing(link, tracker, gear)


def _disengage(link: CommandLink, tracker: MotionTracker, follower: str) -> None:
    """``GR 0`` on ``follower`` after its ``GA``/``GR`` line failed: it may have engaged, and
    the tracker would not know of it (the next move of the master would drive the follower
    unpredicted and unchecked). A dead link is reopened once for it; a failure is dropped
    (the exception that brought us here is the one to see)."""
    line = [cmds.gr(model=link.model, **{follower: 0})]
    if send_reopening(functools.partial(link.command_line, line), tracker.reconnect):
        _forget_found(tracker, follower)  # (a reopened link read it as found geared)


def _zero_ratio(link: CommandLink, follower: str, given: object, advice: str) -> LimitError:
    """The refusal of a gear ratio of 0, or ``given`` that the controller would store as 0:
    one type wherever it is met (``gear_to``, ``set_ratio``), the ratio below the model's
    smallest step."""
    model = link.model
    stored = "" if given == 0 else f" ({given!r} is stored as 0)"
    return LimitError(
        f"a gear ratio of 0 is no gearing{stored}: {advice}",
        name="GR",
        value=0.0,
        limit=model.gr_resolution,
        axis=follower,
        model=model.name,
    )


def _check_pair(
    link: CommandLink, tracker: MotionTracker, follower: str, master: str, ratio: float
) -> None:
    """Refuse a follower of itself, a ratio of 0, and a chain of gearings (TC 46)."""
    model = link.model
    if master == follower:
        raise InvalidArgument(f"axis {follower} cannot follow itself (TC 46)")
    if ratio == 0:
        raise _zero_ratio(link, follower, ratio, "give a ratio other than 0")
    found = tracker.found
    if follower in found:
        raise InvalidArgument(found_text(follower, found[follower], "gearing it"), model=model.name)
    if master in found:
        raise InvalidArgument(
            f"axis {master} is geared on the controller (ratio {found[master]:g}) and would be"
            " a master and a follower (TC 46): turn its gearing off first (gear_off)",
            model=model.name,
        )
    gears = tracker.gears
    if follower in gears:
        raise InvalidArgument(
            f"axis {follower} is already geared to {gears[follower].master}; turn that gearing"
            " off first",
            model=model.name,
        )
    if master in gears or any(g.master == follower for g in gears.values()):
        raise InvalidArgument(
            f"axis {master if master in gears else follower} would be a master and a follower"
            " (TC 46: gear axis both master and follower)",
            model=model.name,
        )
