"""What happens on a fresh link before the first user command: identify, handle the echo.

``^R^V`` names the controller (``DMC4040 Rev 1.2f``) and picks its :class:`ModelSpec`. A
controller that echoes what it receives (``EO 1``, a serial setting) is found by the echo of
that very query; the echo is then switched off with ``EO 0`` (restored at close), as Galil's
own library does, or kept and stripped from every reply when the caller asks for it.
"""

from __future__ import annotations

import re

from galil.errors import GalilConnectionError, GalilTimeoutError, InvalidArgument, ProtocolError
from galil.link import RECONNECT_ADVICE, Link, warn_caller
from galil.models import Identity, ModelSpec, parse_identity
from galil.protocol import commands as cmds
from galil.protocol.commands import Command, Expect
from galil.protocol.session import Completed

__all__ = ["identify"]

# ^R^V with any reply shape, and what its echo looks like in front of the identity (the
# controller may or may not echo the control characters; an echoed CR may gain an LF).
_IDENTIFY_ANY = Command("\x12\x16", Expect.ANY)
_ECHO_OF_IDENTIFY = re.compile(r"[\x12\x16]*\r\n?")


def identify(
    link: Link, given: ModelSpec | None, *, keep_echo: bool, expect: Identity | None = None
) -> tuple[Identity | None, bool]:
    """Ask ``^R^V``, set ``link.model``, and deal with an echo (lock taken here).

    Args:
        expect: the identity the link found before (a reopen): another one is refused, and
            ``link.model`` is left as it was.

    Returns:
        The parsed identity (``None`` when only ``given`` names the model) and whether the
        controller still echoes (only with ``keep_echo``, or if it refused ``EO 0``).

    Raises:
        GalilConnectionError: no answer, an answer that names no model and none was given,
            or (``expect``) another controller than before.
    """
    with link.locked():
        try:
            # Any reply shape: with echo on, the echo of ^R^V comes first (maybe a line of
            # its own), and that is how the echo is found.
            reply = link.roundtrip_locked([_IDENTIFY_ANY], link.timeout)[0]
        except GalilTimeoutError as exc:
            serial = getattr(link.transport, "kind", "") == "serial"
            raise link.error(
                GalilConnectionError,
                f"no answer to ^R^V on the {_where(link)} within {link.timeout:g} s: is a Galil"
                f" controller on the other end{' (and the baud rate right)' if serial else ''}?",
            ) from exc
        except GalilConnectionError as exc:
            raise link.error(GalilConnectionError, _dropped(link, exc)) from exc
        echo = False
        ident: Identity | None = None
        problem = ""
        if reply.ok:
            found = _ECHO_OF_IDENTIFY.match(reply.text)
            if found is not None and found.end():
                reply = Completed(reply.command, True, reply.text[found.end() :])
                echo = _handle_echo(link, given, keep_echo)
            try:
                ident = parse_identity(reply.text)
            except InvalidArgument as exc:
                problem = str(exc)
        else:
            problem = "the controller refused ^R^V"
    if expect is not None:
        _check_same(link, ident, expect)
    _settle_model(link, ident, given, problem)
    return ident, echo


def _where(link: Link) -> str:
    """The link as messages name it: its transport's label ("TCP link to 10.0.0.2:23",
    "serial port /dev/ttyUSB0"), else its repr (a plug-in transport)."""
    label = getattr(link.transport, "label", None)
    return label if isinstance(label, str) and label else repr(link.transport)


def _dropped(link: Link, exc: GalilConnectionError) -> str:
    """The message of a link that failed before the controller answered ``^R^V`` (the
    handshake of a connect or a reopen: no advice to call reconnect() on an object the
    caller may never get). Over Ethernet, a controller with all its handles taken accepts
    the connection and drops it at once."""
    why = str(exc.args[0] if exc.args else exc).removesuffix(RECONNECT_ADVICE)
    if getattr(link.transport, "kind", "") == "ethernet":
        return (
            f"the controller dropped the connection before it answered ^R^V ({why}): it may"
            " have no free Ethernet handle (it has eight; TH on another connection lists them:"
            " close one, or free a stale one with IHm=>-1)"
        )
    return f"the link failed before the controller answered ^R^V ({why})"


def _check_same(link: Link, ident: Identity | None, expect: Identity) -> None:
    """A link reopened (a reconnect, automatic or not) must reach the controller it reached
    before: another model at the same address (a controller swapped, an address reused)
    would take commands meant for the first one (its axes, its ranges, its program).

    Raises:
        GalilConnectionError: ``^R^V`` names another model (or none at all).
    """
    if ident is not None and ident.raw_model == expect.raw_model:
        return  # (the firmware may have changed: an update between the two links)
    found = (
        "a controller whose ^R^V names no model"
        if ident is None
        else f"a {ident.raw_model} (firmware {ident.firmware})"
    )
    raise link.error(
        GalilConnectionError,
        f"the link was reopened to {found}, not the {expect.raw_model} (firmware"
        f" {expect.firmware}) it reached before: refused, since commands meant for one would"
        " go to the other; galil.connect() opens a link to the new one",
    )


def _settle_model(
    link: Link, ident: Identity | None, given: ModelSpec | None, problem: str
) -> None:
    if ident is None:
        if given is None:
            raise link.error(
                GalilConnectionError,
                f"cannot identify the controller ({problem}); pass model='DMC-....'",
            )
        warn_caller(f"{problem}; using model={given.name} as given")
        link.model = given
        return
    if ident.model.generic and given is not None:
        link.model = given  # the caller named the family: use its tables
        return
    link.model = ident.model
    if ident.model.generic:
        warn_caller(
            f"{ident.raw_model} (firmware {ident.firmware}) is a Galil controller the tables "
            f"do not know; connected as a generic model with conservative limits "
            f"({len(ident.model.axes)} axes, no data record); pass model= to choose tables",
        )
        return
    if given is not None and given.name != ident.model.name:
        warn_caller(
            f"model={given.name} was given but the controller says {ident.raw_model}; "
            f"using {ident.model.name}",
        )


def _handle_echo(link: Link, given: ModelSpec | None, keep_echo: bool) -> bool:
    """The controller echoes: strip it from now on; unless kept, switch it off (lock held)."""
    link.set_echo(True)
    link.note("the controller echoes (EO 1)")
    if keep_echo:
        return True
    try:
        done = link.roundtrip_locked([cmds.eo(0)], link.timeout)[0]
    except (GalilTimeoutError, ProtocolError):
        done = Completed(cmds.eo(0), False)  # the session resynchronises before the next
    if done.ok:
        link.set_echo(False)
        link.restore_on_close(cmds.eo(1), own=cmds.eo(0))
        return False
    name = given.name if given is not None else "the controller"
    warn_caller(
        f"{name} echoes and refused EO 0; the echo is stripped from every reply",
    )
    return True
