"""What happens on a fresh link before the first user command: identify, handle the echo.

``^R^V`` names the controller (``DMC4040 Rev 1.2f``) and picks its :class:`ModelSpec`. A
controller that echoes what it receives (``EO 1``, a serial setting) is found by the echo of
that very query; the echo is then switched off with ``EO 0`` (restored at close), as Galil's
own library does, or kept and stripped from every reply when the caller asks for it.
"""

from __future__ import annotations

import contextlib
import re

from galil.errors import (
    GalilConnectionError,
    GalilError,
    GalilTimeoutError,
    InvalidArgument,
    ProtocolError,
)
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
        reply = _ask(link)
        echo = False
        ident: Identity | None = None
        problem = ""
        if reply.ok:
            found = _ECHO_OF_IDENTIFY.match(reply.text)
            if found is not None and found.end():
                reply = Completed(reply.command, True, reply.text[found.end() :])
                echo = _handle_echo(link, given, keep_echo)
            ident, problem = _identity_in(reply.text)
        else:
            problem = "the controller refused ^R^V"
    if expect is not None:
        _check_same(link, ident, expect)
    _settle_model(link, ident, given, problem)
    return ident, echo


def _ask(link: Link) -> Completed:
    """``^R^V`` (lock held), asked once more if the first gets no answer, one that does not
    fit, or one that names no controller (stray bytes: a gateway's banner, a program's
    output). The link resynchronises first: its ``\\`` ends a download a host left open
    (``DL`` without its closing ``\\``: the controller is silent, taking every line as
    program text), and what came before the marker is thrown away. On a controller not
    downloading, ``\\`` is a line of its own that changes nothing (Galil's legacy library
    sends ``\\;`` to clear the link when it opens one: galil-protocol.md §3).

    Raises:
        GalilConnectionError: no answer, or none that fits, either time; the link failed.
    """
    before = link.bytes_received
    with link.wire_log.capture() as wire:  # (what came, quoted if it is no Galil answer)
        try:
            first: Completed | GalilError = link.roundtrip_locked([_IDENTIFY_ANY], link.timeout)[0]
        except (GalilTimeoutError, ProtocolError) as exc:
            first = exc
        except GalilConnectionError as exc:
            raise link.error(GalilConnectionError, _dropped(link, exc, wire.received)) from exc
    if isinstance(first, Completed) and not _names_nothing(first):
        return first
    heard, before = link.bytes_received - before, link.bytes_received
    link.note("no identity: resynchronising (its \\ ends a download left open), asking again")
    try:
        link.settle_locked([], link.timeout, echo=link.echo)
        return link.roundtrip_locked([_IDENTIFY_ANY], link.timeout)[0]
    except (GalilTimeoutError, ProtocolError, GalilConnectionError) as exc:
        silent = link.bytes_received == before
        why = _unidentified(link, (first, heard), exc, silent, bytes(wire.received))
        raise link.error(GalilConnectionError, why) from exc


def _names_nothing(reply: Completed) -> bool:
    """Whether an accepted ``^R^V`` reply holds no identity (past an echo of the query)."""
    if not reply.ok:
        return False  # (the controller refused it: an answer all the same)
    found = _ECHO_OF_IDENTIFY.match(reply.text)
    text = reply.text[found.end() :] if found is not None else reply.text
    return _identity_in(text)[0] is None


def _unidentified(
    link: Link,
    first: tuple[Completed | GalilError, int],
    then: GalilError,
    silent: bool,
    came: bytes = b"",
) -> str:
    """The message of a handshake whose ``^R^V`` failed twice (``first``, with the bytes
    heard, ``came``, then ``then``, after a resynchronisation; ``silent``: not one byte came
    to that): what arrived, and what the peer may be."""
    serial = getattr(link.transport, "kind", "") == "serial"
    where = _where(link)
    reply, heard = first
    if isinstance(reply, Completed):
        what = f"the answer to ^R^V on the {where} named no controller ({reply.text!r})"
    elif isinstance(reply, GalilTimeoutError):
        what = f"no answer to ^R^V on the {where} within {link.timeout:g} s"
        if heard:
            what += f" ({heard} byte{'s' if heard > 1 else ''} came, none ending a reply"
            what += f": {_quoted(came)})" if came else ")"
    else:
        what = f"the answer to ^R^V on the {where} did not fit ({_said(reply)})"
    if silent:
        after = f"nor a byte to the resynchronisation after it in {max(link.timeout, 0.2):g} s"
    elif isinstance(then, GalilTimeoutError):
        after = "none to a second ^R^V after the link resynchronised"
    elif isinstance(then, ProtocolError):
        after = f"after the link resynchronised, none that fits either ({_said(then)})"
    else:
        why = _said(then).removeprefix("the link is out of step and did not resynchronise ")
        after = f"then the link could not resynchronise ({why})"
    return (
        f"{what}; {after}: is a Galil controller on the other end"
        f"{' (and the baud rate right)' if serial else ''}? (The resynchronisation sent"
        " \\, which ends a download a host left open with DL.)"
    )


def _said(exc: GalilError) -> str:
    """An error's message without the link's advice or what it says happens next."""
    text = str(exc.args[0] if exc.args else exc)
    for tail in (RECONNECT_ADVICE, "; the command may have executed (the link resynchronises)"):
        text = text.removesuffix(tail)
    return text.split(", so try again", 1)[0]  # (advice for a link in use, not a handshake)


def _identity_in(text: str) -> tuple[Identity | None, str]:
    """The identity in a ``^R^V`` reply and, if none, why: its last line that parses. A
    running program's output (``MG`` in ``#AUTO``) is not marked before the link sets
    ``CW 1``, so it may come in front of the identity."""
    for line in reversed(text.splitlines()):
        if line.strip():
            with contextlib.suppress(InvalidArgument):
                return parse_identity(line), ""
    try:
        return parse_identity(text), ""
    except InvalidArgument as exc:
        return None, str(exc)


def _where(link: Link) -> str:
    """The link as messages name it: its transport's label ("TCP link to 10.0.0.2:23",
    "serial port /dev/ttyUSB0"), else its repr (a plug-in transport)."""
    label = getattr(link.transport, "label", None)
    return label if isinstance(label, str) and label else repr(link.transport)


#: How many of the bytes a peer sent a message quotes.
_QUOTED = 60


def _quoted(came: bytes) -> str:
    """The first bytes a peer sent, as a message quotes them (``b'HTTP/1.1 400 ...'``)."""
    more = f" ... ({len(came)} bytes)" if len(came) > _QUOTED else ""
    return f"{came[:_QUOTED]!r}{more}"


def _dropped(link: Link, exc: GalilConnectionError, came: bytes | bytearray = b"") -> str:
    """The message of a link that failed before the controller answered ``^R^V`` (the
    handshake of a connect or a reopen: no advice to call reconnect() on an object the
    caller may never get), ``came`` the bytes that arrived first. Over Ethernet, a
    controller with all its handles taken accepts the connection and drops it at once,
    without a byte; a peer that said something and hung up is not a Galil controller (an
    HTTP server answers its 400 and closes)."""
    why = str(exc.args[0] if exc.args else exc).removesuffix(RECONNECT_ADVICE)
    if came:
        return (
            f"what answered ^R^V on the {_where(link)} was {_quoted(bytes(came))}, then it "
            f"closed the connection ({why}): that is not a Galil controller (one answers ^R^V "
            "with its model and firmware); check the address and port"
        )
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
