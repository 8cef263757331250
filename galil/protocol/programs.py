"""Program text, sans-I/O: normalise, strip comments, pack lines, and check them for a model.

A program is downloaded line by line (``DL``); the controller refuses a line that is empty,
too long, or that holds a backslash (it ends the download), and a program with too many lines
or labels, or a label twice. Everything here is checked before a byte is sent, each refusal
naming the line (1-based, in the text as given) and the rule::

    lines = program_lines('#A\\n  PR 1000 \\' a comment\\n  BG A\\nEN', strip_comments=True)
    # ['#A', 'PR 1000', 'BG A', 'EN']
    check_program(lines, model)

Lines are stored without surrounding blanks (Galil's own tools remove them too), so the text
uploaded afterwards can be compared with what was sent. ``REM`` lines are never sent: the
DMC-4103 command reference calls ``REM`` "NOT a controller command" that Galil's PC software
strips before a download; a ``'`` comment is a command and stays unless ``strip_comments``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from galil.errors import InvalidArgument
from galil.models import ModelSpec

__all__ = ["ProgramLine", "check_program", "labels_of", "pack_lines", "program_lines"]

_LABEL_START = re.compile(r"#([A-Za-z0-9_]*)")
_BAD_CHAR = re.compile(r"[^\x20-\x7e]|\\")
#: ``REM`` as a word (``REMAIN=5`` is an assignment, not a remark).
_REMARK = re.compile(r"REM(?:\s|$)")


@dataclass(frozen=True)
class ProgramLine:
    """One line to download, and the line of the source text it came from (1-based)."""

    text: str
    source: int


def _comment_start(line: str) -> int:
    """Index where a comment begins (``'`` or ``REM`` at the start of a command), or -1."""
    quoted = False
    command_start = True
    label = _LABEL_START.match(line)
    i = label.end() if label is not None else 0  # a label is followed by a command or a comment
    while i < len(line):
        ch = line[i]
        if ch == '"':
            quoted = not quoted
            command_start = False
        elif not quoted:
            if command_start and ch == " ":
                pass
            elif command_start and (ch == "'" or _REMARK.match(line, i)):
                return i
            elif ch == ";":
                command_start = True
                i += 1
                continue
            else:
                command_start = False
        i += 1
    return -1


def _without_comment(line: str) -> str:
    cut = _comment_start(line)
    code = line if cut < 0 else line[:cut]
    return code.strip().rstrip(";").strip()


def program_lines(
    text: str | Sequence[str], *, strip_comments: bool = False, pack: int | None = None
) -> list[ProgramLine]:
    """The lines of a program, each without surrounding blanks and without ``REM`` lines.

    Blank lines at the start and end of ``text`` are dropped. A blank line inside is kept
    (and refused by :func:`check_program`) unless ``strip_comments`` removes it. A line that
    begins with ``REM`` is always dropped, as Galil's software does ("REM is NOT a controller
    command": the DMC-4103 command reference); a ``REM`` anywhere else is refused by
    :func:`check_program` unless ``strip_comments`` removes it.

    Args:
        text: the program (a string, or its lines).
        strip_comments: drop comments (``'...`` and ``REM`` lines, and the ``'`` comment
            after a command) and the lines left empty.
        pack: join lines into compound lines (``PR 10;BG A``) of at most this many characters;
            a label always starts a line, and a comment ends one.

    Raises:
        InvalidArgument: ``text`` is neither a string nor a sequence of strings.
    """
    if isinstance(text, str):
        raw = text.splitlines()
    elif isinstance(text, Sequence) and all(isinstance(x, str) for x in text):
        raw = [part for x in text for part in (x.splitlines() or [""])]
    else:
        raise InvalidArgument(f"a program is a string or a list of lines, not {text!r}")
    out = [ProgramLine(line.strip(), i) for i, line in enumerate(raw, 1)]
    out = [p for p in out if not _REMARK.match(p.text)]
    while out and not out[0].text:
        out.pop(0)
    while out and not out[-1].text:
        out.pop()
    if strip_comments:
        out = [ProgramLine(_without_comment(p.text), p.source) for p in out]
        out = [p for p in out if p.text]
    if pack is not None:
        out = pack_lines(out, pack)
    return out


def pack_lines(lines: Sequence[ProgramLine], limit: int) -> list[ProgramLine]:
    """Join consecutive lines with ``;`` up to ``limit`` characters per line.

    A label line starts a new line (a label must begin its line), a line with a comment is
    never followed on the same line (the comment would swallow what follows), and a line
    already longer than ``limit`` stays as it is (:func:`check_program` refuses it).
    """
    out: list[ProgramLine] = []
    open_line: ProgramLine | None = None
    for p in lines:
        if not p.text:
            continue
        joinable = (
            open_line is not None
            and not p.text.startswith("#")
            and _comment_start(open_line.text) < 0
            and len(open_line.text) + 1 + len(p.text) <= limit
        )
        if joinable and open_line is not None:
            open_line = ProgramLine(f"{open_line.text};{p.text}", open_line.source)
            out[-1] = open_line
        else:
            open_line = p
            out.append(p)
    return out


def labels_of(lines: Sequence[str]) -> list[str]:
    """The labels lines begin with (``"#A"``), in order, repeats included."""
    found = []
    for line in lines:
        m = _LABEL_START.match(line.strip())
        if m is not None and m.group(1):
            found.append("#" + m.group(1))
    return found


def _check_label(line: ProgramLine, model: ModelSpec) -> str | None:
    m = _LABEL_START.match(line.text)
    if m is None:
        return None
    name = m.group(1)
    rest = line.text[m.end() :]
    if not name or not name[0].isalpha() or "_" in name:
        raise InvalidArgument(
            f"program line {line.source}: label {'#' + name!r} must be '#', a letter, then "
            "letters or digits",
            model=model.name,
        )
    if len(name) > model.label_length:
        raise InvalidArgument(
            f"program line {line.source}: label #{name} is {len(name)} characters long; "
            f"{model.name} allows {model.label_length} after '#'",
            model=model.name,
        )
    if rest and rest[0] not in "; '":
        raise InvalidArgument(
            f"program line {line.source}: label #{name} must end at a ';', a blank or the "
            f"end of the line, not at {rest[0]!r}",
            model=model.name,
        )
    return "#" + name


#: What to do about a line :func:`check_program` refuses, by where it ran: the library's
#: download (``programs.download``, whose keywords fix it) or a ``DL`` typed at the terminal
#: or ``galil dl`` (no keywords there: the lines themselves are changed).
_FIXES = {
    False: {
        "empty": "write ' for a blank comment line, or pass strip_comments=True",
        "long": "pass pack=False and split it, or strip_comments=True",
        "REM": "write ' for a comment after a command, or pass strip_comments=True",
    },
    True: {
        "empty": "write ' for a blank comment line",
        "long": "split it at a ';' into shorter lines, or shorten or drop its comment",
        "REM": "write ' for a comment after a command, or drop the comment",
    },
}


def _check_line(line: ProgramLine, model: ModelSpec, fixes: Mapping[str, str]) -> None:
    where = f"program line {line.source}"
    if not line.text:
        raise InvalidArgument(
            f"{where} is empty; the controller refuses empty lines ({fixes['empty']})",
            model=model.name,
        )
    bad = _BAD_CHAR.search(line.text)
    if bad is not None:
        what = "a backslash ends a download" if bad.group() == "\\" else "not printable ASCII"
        raise InvalidArgument(
            f"{where}: character {bad.group()!r} cannot be downloaded ({what})", model=model.name
        )
    if len(line.text) > model.line_length:
        raise InvalidArgument(
            f"{where}: {len(line.text)} characters; {model.name} takes {model.line_length} "
            f"({fixes['long']})",
            model=model.name,
        )
    c = _comment_start(line.text)
    if c >= 0 and _REMARK.match(line.text, c):
        raise InvalidArgument(
            f"{where}: REM after a label or a command; REM is no controller command, only a "
            "line of its own beginning with REM is a remark (dropped before the download): "
            f"{fixes['REM']}",
            model=model.name,
        )
    code = line.text if c < 0 else line.text[:c]
    if code.count('"') % 2:
        raise InvalidArgument(f"{where}: a string is not closed (odd number of quotes)")
    for text in _mg_texts(code):
        if len(text) > model.mg_max:
            raise InvalidArgument(
                f"{where}: MG text {text!r} is {len(text)} characters; {model.name} prints "
                f"{model.mg_max} at most",
                model=model.name,
            )
        if "?" in text:  # (TC 54 "Question mark part of string", galil-protocol.md §1.2)
            raise InvalidArgument(
                f"{where}: MG text {text!r} holds a '?', which the controller refuses in a "
                "string (TC 54 when the line runs); {^63} prints one",
                model=model.name,
            )


_QUOTED = re.compile(r'"([^"]*)"')
_COMMANDS = re.compile(r'(?:[^;"]|"[^"]*")+')
_MG = re.compile(r"\s*MG(?![A-Za-z0-9_])")


def _mg_texts(code: str) -> list[str]:
    """The quoted texts of the ``MG`` commands in ``code`` (a line without its comment, its
    quotes closed)."""
    label = _LABEL_START.match(code)
    rest = code[label.end() :] if label is not None else code
    if '"' not in rest:
        return []
    return [
        text
        for command in _COMMANDS.findall(rest)
        if _MG.match(command)
        for text in _QUOTED.findall(command)
    ]


def check_program(
    lines: Sequence[ProgramLine],
    model: ModelSpec,
    *,
    reserve: int = 0,
    at_terminal: bool = False,
) -> None:
    """Check every line and the whole program against ``model``; nothing to send if it fails.

    Args:
        lines: the program (from :func:`program_lines`).
        model: the controller's model (line length, program lines, labels).
        reserve: lines of program memory already taken by something else (the library's
            routines), so the program must fit in what is left.
        at_terminal: the program was typed after a ``DL`` (or read by ``galil dl``): a
            refusal says what to change in its lines, not which keyword of
            ``programs.download`` to pass.

    Raises:
        InvalidArgument: the first rule broken, naming the line.
    """
    if not lines:
        raise InvalidArgument("the program is empty")
    seen: dict[str, int] = {}
    fixes = _FIXES[bool(at_terminal)]
    for line in lines:
        _check_line(line, model, fixes)
        label = _check_label(line, model)
        if label is None:
            continue
        if label in seen:
            raise InvalidArgument(
                f"program line {line.source}: label {label} is already on line {seen[label]}",
                model=model.name,
            )
        seen[label] = line.source
    if len(seen) > model.labels:
        raise InvalidArgument(
            f"the program has {len(seen)} labels; {model.name} holds {model.labels}",
            model=model.name,
        )
    room = model.program_lines - reserve
    if len(lines) > room:
        taken = f" ({reserve} are the library's routines)" if reserve else ""
        raise InvalidArgument(
            f"the program has {len(lines)} lines; {model.name} holds {model.program_lines}{taken}",
            model=model.name,
        )
