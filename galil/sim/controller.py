"""The simulated DMC controller: an interpreter fed bytes, answering bytes.

:class:`SimController` behaves like a controller of the chosen model on its command port: it
answers ``:`` or ``?`` for every command, prints queries in the PF/VF/LZ formats, keeps the TC
error code, holds the ``:`` of a trippoint (``AM``, ``MC``, ``WC``, ``WT``) until it is
satisfied, runs downloaded programs (``MG``, ``WT``, ``JP`` and any command) in threads, and
sends their output as unsolicited messages. Motion runs in a servo loop, sample by sample, on
the one motion engine shared with the predictor (:class:`galil.predict.engine.AxisProfiler`),
in vectorised chunks between events.

Time comes from a clock: with :class:`~galil.sim.clock.ManualClock` (the default) nothing moves
until a test calls :meth:`SimController.advance`; servers use a real-time clock. Every public
method is thread-safe.

Choices where the sources are silent (see ``shared/reference/galil-protocol.md``):

- replies put a blank in the sign position of positive numbers (``" 1000"``, ``" 4, 52, 26,
  36"``), LZ 1 is the default, ``TC`` clears the code while ``_TC`` does not;
- soft limits act on the reference position (``RP``) and stop at DC, like a limit switch;
- ``_LFx``/``_LRx`` are 1 while the switch is inactive, as the TS bits are;
- ``TD`` reads an auxiliary encoder rigidly coupled to the motor (equal to ``TP``);
- ``WC`` holds until at most one contour segment (the one running) is left, i.e. the previous
  interval is complete; a ``CD`` into a full buffer holds its ``:`` until there is room; an
  emptied buffer while contouring sets the error code to 42;
- a program command that fails halts its thread and sets the error code; nothing is printed.
"""

from __future__ import annotations

import copy
import functools
import math
import re
import struct
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from galil.codes import tc_text
from galil.errors import CommandError, GalilConnectionError, InvalidArgument, LimitError
from galil.models import INT32_MAX, INT32_MIN, ModelSpec, get_model
from galil.predict.checks import quantise_accel, quantise_speed
from galil.predict.smoothing import quantise_it
from galil.protocol.numbers import format_reply, parse_format
from galil.sim.clock import Clock, ManualClock
from galil.sim.motion import AxisMotion
from galil.sim.parse import Refused, evaluate, next_command, split_fields, split_program_line

__all__ = ["SimController"]

#: Longest run of servo samples evaluated in one vectorised step.
_MAX_CHUNK = 2048
#: Program commands one thread may execute per servo sample (the firmware runs a few per ms).
_LINES_PER_SAMPLE = 16
#: Ethernet handle letters, in the order the controller hands them out.
_HANDLES = "ABCDEFGH"

_AXIS_VALUE = frozenset(["PR", "PA", "SP", "AC", "DC", "JG", "IP", "IT", "DP", "FL", "BL"])
_AXIS_LIST = frozenset(
    ["BG", "ST", "AM", "MC", "SH", "MO", "TP", "TV", "TE", "RP", "TD", "SC", "TS", "CM"]
)
_OTHER = frozenset(
    [
        "CD",
        "DT",
        "WC",
        "TC",
        "MG",
        "TM",
        "CW",
        "EO",
        "QZ",
        "QR",
        "TH",
        "AB",
        "DL",
        "UL",
        "XQ",
        "HX",
        "WT",
        "JP",
        "EN",
        "LZ",
        "PF",
        "VF",
        "RS",
        "NO",
        "AD",
        "CF",
        "WH",
        "DR",
        "TB",
    ]
)
COMMANDS = _AXIS_VALUE | _AXIS_LIST | _OTHER

_VARIABLE = re.compile(r"[A-Za-z][A-Za-z0-9]{0,7}")
_RESERVED = frozenset({"TIME"})
_LABEL = re.compile(r"#([A-Za-z][A-Za-z0-9]*)")  # length checked against the model
_BRACES = re.compile(r"\{([^}]*)\}")


@dataclass
class _Wait:
    """A held reply or a stalled thread: released when time and condition are met."""

    predicate: Callable[[], bool] | None = None
    wake: int | None = None  # absolute sample number
    then: Callable[[], str] | None = None  # run on release (a CD that waited for room)
    # True when the predicate can only change where a step ends anyway (a known profile end),
    # so the step needs no snapshot and bisection.
    exact: Callable[[], bool] | None = None


@dataclass
class _Port:
    """One command handle: its unparsed input, its output and what it is waiting for."""

    name: str
    number: int = 0
    letter: str = ""  # Ethernet handle letter (A-H); "" for the main (serial) port
    inbuf: str = ""
    out: bytearray = field(default_factory=bytearray)
    wait: _Wait | None = None
    download: list[str] | None = None
    swallow_cr: bool = False


@dataclass
class _Thread:
    number: int
    line: int = 0
    cmd: int = 0
    wait: _Wait | None = None
    sample: int = -1
    ran: int = 0


@dataclass
class _Axis:
    """Parameters and switches of one axis; ``m`` is its servo-loop state."""

    letter: str
    m: AxisMotion
    sp: float = 25000.0
    ac: float = 256000.0
    dc: float = 256000.0
    jg: float = 25000.0
    it: float = 1.0
    pr: int = 0
    pa: int = 0
    absolute: bool = False
    next_mode: str = "position"
    fl: int = INT32_MAX
    bl: int = INT32_MIN
    switch_fwd: bool = False
    switch_rev: bool = False
    limit_stopping: bool = False
    contour: bool = False
    contour_fed: bool = False
    move_start: int = 0  # profiler position at the last BG: AD/AR measure from here


class SimController:
    """A simulated Galil DMC controller.

    Args:
        model: model name (``"DMC-4040"``, ``"DMC-1806"``, ...); see :mod:`galil.models`.
        clock: where time comes from; a new :class:`ManualClock` by default.
        firmware: the revision reported by ``^R^V``.
        servo_lag: time constant (s) of the motor following the reference, for every axis.

    Raises:
        InvalidArgument: unknown model.
    """

    def __init__(
        self,
        model: str = "DMC-4040",
        clock: Clock | None = None,
        *,
        firmware: str = "1.2f-sim",
        servo_lag: float = 0.003,
    ) -> None:
        self.spec: ModelSpec = get_model(model)
        compact = model.strip().upper().replace("-", "")
        self.identity = f"{compact} Rev {firmware}"
        self.clock: Clock = clock if clock is not None else ManualClock()
        self._lock = threading.RLock()
        self._servo_lag = servo_lag
        self._ports: dict[int, _Port] = {0: _Port("main")}
        self._next_port = 1
        #: Port that receives unsolicited output (``CF``); None: the default destination.
        self._cf: int | None = None
        #: ``DR`` stream: (samples between records, port number), and the next record's sample.
        self._dr: tuple[int, int] | None = None
        self._dr_next = 0
        #: Port whose host command is executing (None inside program threads).
        self._current: _Port | None = None
        #: When True, unsolicited output goes to :meth:`read_messages` (a TCP message handle);
        #: otherwise it is interleaved with the replies of the main port (serial behaviour).
        self.separate_messages = False
        self._messages = bytearray()
        self._sample = 0
        #: ``(sample, command text)`` of the latest host commands, oldest first.
        self.command_log: deque[tuple[int, str]] = deque(maxlen=10_000)
        self._tm = self.spec.tm_default
        self._ts = self.spec.sample_period
        self._time_base = self.clock.now()
        self._sample_base = 0
        self._program: list[str] = []
        self._labels: dict[str, int] = {}
        self._reset_state()

    # ---- state -------------------------------------------------------------------------
    def _reset_state(self) -> None:
        """Power-on defaults (also ``RS`` and ``^R^S``); time keeps running."""
        self._set_tm(self.spec.tm_default)
        self._axes: dict[str, _Axis] = {
            letter: _Axis(letter, AxisMotion(self._ts, 0, self._servo_lag))
            for letter in self.spec.axes
        }
        self._variables: dict[str, float] = {}
        self._tc = 0
        self._pf = "10.0"
        self._vf = "10.4"
        self._lz = True
        self._cw = 2
        self._cw_mode = 0
        self._echo = False
        self._dt = 1
        self._threads: dict[int, _Thread] = {}
        for port in self._ports.values():
            port.wait = None
            port.download = None

    def _set_tm(self, tm: float) -> None:
        """Change the sample period; samples already run keep their times."""
        now = self._time_now()
        self._tm = tm
        self._ts = self.spec.sample_period_for(tm)
        self._time_base = now
        self._sample_base = self._sample

    def _time_now(self) -> float:
        return self._time_base + (self._sample - self._sample_base) * self._ts

    # ---- public API --------------------------------------------------------------------
    @property
    def sample(self) -> int:
        """Servo samples run since the controller was created (what ``TIME`` reports)."""
        return self._sample

    @property
    def sample_period(self) -> float:
        """Seconds per servo sample at the present TM."""
        return self._ts

    @property
    def time(self) -> float:
        """Simulated time of the last servo sample, in clock seconds."""
        return self._time_now()

    def motion(self, axis: str) -> AxisMotion:
        """The servo-loop state of ``axis`` (read it; drive it through commands).

        Raises:
            InvalidArgument: no such axis.
        """
        return self._axes[self.spec.axis_letter(axis)].m

    def feed(self, data: bytes, port: int = 0) -> bytes:
        """Give the controller bytes from the host; return what it answers right away.

        Replies held by a trippoint come later from :meth:`poll`.
        """
        with self._lock:
            self._sync()
            p = self._port(port)
            if self._echo:
                p.out += data
            p.inbuf += data.decode("latin-1")
            self._pump(p)
            self._service()
            return self._take(p)

    def poll(self, port: int = 0) -> bytes:
        """Run the servo loop up to the clock's time; return replies and messages released."""
        with self._lock:
            self._sync()
            return self._take(self._port(port))

    def read_messages(self) -> bytes:
        """Unsolicited output waiting for the message handle (``separate_messages``)."""
        with self._lock:
            self._sync()
            out = bytes(self._messages)
            self._messages.clear()
            return out

    def advance(self, seconds: float) -> None:
        """Move a manual clock on by ``seconds`` and run the servo loop to it.

        Raises:
            InvalidArgument: the clock is not a :class:`ManualClock`, or ``seconds`` < 0.
        """
        with self._lock:
            clock = self.clock
            if not isinstance(clock, ManualClock):
                raise InvalidArgument("advance() needs a ManualClock; this one runs by itself")
            clock.advance(seconds)
            self._sync()

    def advance_until_output(self, seconds: float, port: int = 0) -> bytes:
        """Advance a manual clock by up to ``seconds``, stopping at the first output.

        This is how the in-process link lets simulated time pass while a host waits.

        Raises:
            InvalidArgument: the clock is not a :class:`ManualClock`, or ``seconds`` < 0.
        """
        with self._lock:
            clock = self.clock
            if not isinstance(clock, ManualClock):
                raise InvalidArgument("advance_until_output() needs a ManualClock")
            if not seconds >= 0:
                raise InvalidArgument(f"cannot advance by {seconds!r} s")
            p = self._port(port)
            self._sync()
            if not p.out:
                n = math.floor(seconds / self._ts + 1e-9)
                ran = self._run(n, stop_on=p)
                clock.advance(ran * self._ts)
                self._sync()
            return self._take(p)

    def open_port(self, name: str) -> int:
        """Open another command handle (an Ethernet handle); return its number.

        The handle takes the first free letter A-H (what ``TH``, ``WH`` and ``CF`` name).

        Raises:
            GalilConnectionError: all eight handles are in use.
        """
        with self._lock:
            used = {p.letter for p in self._ports.values()}
            free = [c for c in _HANDLES if c not in used]
            if not free:
                raise GalilConnectionError("all eight Ethernet handles are in use")
            number = self._next_port
            self._next_port += 1
            self._ports[number] = _Port(name, number=number, letter=free[0])
            return number

    def close_port(self, port: int) -> None:
        """Close a handle opened with :meth:`open_port` (its pending input is dropped)."""
        with self._lock:
            if port != 0:
                self._ports.pop(port, None)
                # Output aimed at a closed handle would pile up unread: fall back.
                if self._cf == port:
                    self._cf = None
                if self._dr is not None and self._dr[1] == port:
                    self._dr = None

    def set_limit_switch(self, axis: str, which: str, active: bool) -> None:
        """Test hook: set a limit switch; an active one stops motion towards it (SC 2/3).

        Args:
            axis: axis letter.
            which: ``"forward"`` or ``"reverse"``.
            active: True when the switch is tripped.

        Raises:
            InvalidArgument: bad axis or ``which``.
        """
        if which not in ("forward", "reverse"):
            raise InvalidArgument(f"which must be 'forward' or 'reverse', not {which!r}")
        with self._lock:
            self._sync()
            ax = self._axes[self.spec.axis_letter(axis)]
            if which == "forward":
                ax.switch_fwd = bool(active)
            else:
                ax.switch_rev = bool(active)
            self._check_switches(ax)
            self._service()

    def set_servo_lag(self, seconds: float, axis: str | None = None) -> None:
        """Test hook: the time constant of the motor following the reference.

        Raises:
            InvalidArgument: negative lag or bad axis.
        """
        with self._lock:
            letters = self.spec.axes if axis is None else self.spec.axis_letter(axis)
            for letter in letters:
                self._axes[letter].m.set_lag(seconds)
            if axis is None:
                self._servo_lag = seconds

    def emit_message(self, text: str) -> None:
        """Test hook: send ``text`` as a running program's ``MG`` would (CR LF added)."""
        with self._lock:
            self._emit(text + "\r\n")

    def describe_handles(self) -> str:
        """The ``TH`` text for the open handles."""
        with self._lock:
            return self._th()

    # ---- time --------------------------------------------------------------------------
    def _sync(self) -> None:
        elapsed = self.clock.now() - self._time_base
        target = self._sample_base + math.floor(elapsed / self._ts + 1e-9)
        if target > self._sample:
            self._run(target - self._sample)

    def _run(self, n: int, stop_on: _Port | None = None) -> int:
        """Run ``n`` samples (events handled at their exact sample); return samples run."""
        done = 0
        self._service()
        while done < n:
            if stop_on is not None and stop_on.out:
                break
            step = min(n - done, self._horizon())
            done += self._step(step)
            self._service()
        return done

    def _horizon(self) -> int:
        h = _MAX_CHUNK
        now = self._sample
        for th in self._threads.values():
            if th.wait is None:
                return 1
            if th.wait.wake is not None:
                h = min(h, th.wait.wake - now)
        for p in self._ports.values():
            w = p.wait
            if w is not None and w.wake is not None:
                h = min(h, w.wake - now)
        if self._dr is not None:
            h = min(h, self._dr_next - now)  # a DR record is due at that sample
        # Ending chunks where a profile ends saves a bisection for AM.
        for ax in self._axes.values():
            prof = ax.m.profiler
            if prof.moving:
                end = prof.end_sample
                if end is not None and end > now:
                    h = min(h, end - now)
        return max(1, h)

    def _watches(self) -> list[Callable[[], bool]]:
        out: list[Callable[[], bool]] = []
        waits = [p.wait for p in self._ports.values() if p.wait is not None]
        if self._threads:
            waits += [t.wait for t in self._threads.values() if t.wait is not None]
        for w in waits:
            if w.predicate is not None:
                if w.exact is not None and w.exact():
                    continue
                out.append(w.predicate)
        for ax in self._axes.values():
            if ax.contour and ax.contour_fed:
                out.append(self._underrun_watch(ax.letter))
        return out

    def _underrun_watch(self, letter: str) -> Callable[[], bool]:
        return lambda: self._axes[letter].m.profiler.queued_segments == 0

    def _snapshot(self) -> tuple[int, dict[str, AxisMotion]]:
        return self._sample, {k: copy.deepcopy(a.m) for k, a in self._axes.items()}

    def start_trace(self, axes: str | None = None) -> int:
        """Record every sample's reference position on ``axes`` (default: all) from now on.

        Returns:
            The sample number of the trace's first value (compare with :attr:`command_log`).
        """
        with self._lock:
            self._sync()
            for letter in axes or self.spec.axes:
                self.motion(letter).start_trace()
            return self._sample

    def stop_trace(self, axes: str | None = None) -> dict[str, npt.NDArray[np.int64]]:
        """Stop recording; return the reference positions per axis since :meth:`start_trace`.

        Each array starts with the position at the start of the trace, then one value per
        servo sample (``sample_period`` apart).
        """
        with self._lock:
            self._sync()
            return {
                self.spec.axis_letter(a): self.motion(a).stop_trace()
                for a in (axes or self.spec.axes)
            }

    def _restore(self, snap: tuple[int, dict[str, AxisMotion]]) -> None:
        self._sample = snap[0]
        for k, m in snap[1].items():
            self._axes[k].m = copy.deepcopy(m)

    def _advance_axes(self, n: int) -> None:
        """Run every axis ``n`` samples."""
        for ax in self._axes.values():
            ax.m.step(n)
        self._sample += n

    def _limited(self) -> list[_Axis]:
        return [
            ax
            for ax in self._axes.values()
            if (ax.fl < INT32_MAX or ax.bl > INT32_MIN)
            and ax.m.moving
            and not ax.limit_stopping
            and not ax.contour
        ]

    def _step(self, n: int) -> int:
        """Advance up to ``n`` samples, stopping at the first event; return samples run."""
        watches = self._watches()
        k = n
        # A soft limit crossed ends the step there: found on a preview of the references
        # (what advance() would return), so no snapshot of the axes is needed for it.
        for ax in self._limited():
            k = min(k, self._crossing(ax, ax.m.profiler.preview(n)))
        if not watches:
            for ax in self._axes.values():
                ax.m.step(k)
                self._check_soft_limits(ax)
            self._sample += k
            return k
        snap = self._snapshot()
        self._advance_axes(k)
        if any(w() for w in watches):
            lo, hi = 0, k  # nothing fires after 0 samples; something fires after hi
            at = k  # where the axes are now
            while hi - lo > 1:
                mid = (lo + hi) // 2
                self._restore(snap)
                self._advance_axes(mid)
                at = mid
                if any(w() for w in watches):
                    hi = mid
                else:
                    lo = mid
            if at != hi:
                # The last probe may have been a "not yet" one: go back to where it fires.
                self._restore(snap)
                self._advance_axes(hi)
            k = hi
        for ax in self._axes.values():
            self._check_soft_limits(ax)
        return k

    def _crossing(self, ax: _Axis, refs: object) -> int:
        """Samples until ``ax`` is beyond a soft limit moving outwards (large if never)."""
        r = np.asarray(refs)
        prev = np.concatenate(([r[0]], r[:-1]))
        beyond = ((r > ax.fl) & (r > prev)) | ((r < ax.bl) & (r < prev))
        hits = np.flatnonzero(beyond)
        return int(hits[0]) + 1 if hits.size else r.size + 1

    def _check_soft_limits(self, ax: _Axis) -> None:
        prof = ax.m.profiler
        if not prof.moving or ax.limit_stopping or ax.contour:
            return
        v = prof.velocity
        if v > 0 and prof.reference > ax.fl:
            ax.limit_stopping = True
            prof.limit_stop(2)
        elif v < 0 and prof.reference < ax.bl:
            ax.limit_stopping = True
            prof.limit_stop(3)

    def _check_switches(self, ax: _Axis) -> None:
        if not (ax.switch_fwd or ax.switch_rev):
            return  # the common case, checked first: the servo loop asks every step
        m = ax.m
        if not m.moving or ax.limit_stopping or ax.contour:
            return
        v = m.profiler.velocity
        if ax.switch_fwd and v > 0:
            ax.limit_stopping = True
            m.profiler.limit_stop(2)
        elif ax.switch_rev and v < 0:
            ax.limit_stopping = True
            m.profiler.limit_stop(3)

    def _service(self) -> None:
        """Release what is due at this sample and run program threads until they block."""
        if self._dr is not None and self._sample >= self._dr_next:
            self._stream_record()
        progress = True
        while progress:
            progress = False
            for ax in self._axes.values():
                if ax.switch_fwd or ax.switch_rev:
                    self._check_switches(ax)
                if ax.contour:
                    prof = ax.m.profiler
                    if prof.mode != "contour":
                        ax.contour = ax.contour_fed = False
                    elif ax.contour_fed and prof.queued_segments == 0:
                        ax.contour_fed = False
                        self._tc = 42  # the buffer ran dry: data sent too slowly
            for port in list(self._ports.values()):
                if port.wait is not None and self._ready(port.wait):
                    w, port.wait = port.wait, None
                    self._release(port, w)
                    self._pump(port)
                    progress = True
            if self._threads:
                for th in list(self._threads.values()):
                    if self._run_thread(th):
                        progress = True

    def _ready(self, w: _Wait) -> bool:
        if w.wake is not None and self._sample < w.wake:
            return False
        return w.predicate is None or w.predicate()

    def _release(self, port: _Port, w: _Wait) -> None:
        data = ""
        if w.then is not None:
            try:
                data = w.then()
            except Refused as e:
                self._tc = e.code
                port.out += b"?"
                return
        port.out += data.encode("latin-1") + b":"

    # ---- output ------------------------------------------------------------------------
    def _port(self, port: int) -> _Port:
        try:
            return self._ports[port]
        except KeyError:
            raise InvalidArgument(f"no open port {port}") from None

    @staticmethod
    def _take(p: _Port) -> bytes:
        out = bytes(p.out)
        p.out.clear()
        return out

    def _emit(self, text: str) -> None:
        data = text.encode("latin-1", "replace")
        if self._cw == 1:
            data = bytes(b | 0x80 for b in data)
        if self._cf is not None and self._cf in self._ports:
            self._ports[self._cf].out += data
        elif self.separate_messages:
            self._messages += data
        else:
            self._ports[0].out += data

    # ---- host command handling ---------------------------------------------------------
    def _pump(self, p: _Port) -> None:
        while p.wait is None:
            if p.download is not None:
                if not self._download(p):
                    return
                continue
            if p.swallow_cr and p.inbuf:
                p.swallow_cr = False
                if p.inbuf[0] == "\r":
                    p.inbuf = p.inbuf[1:]
            found = next_command(p.inbuf)
            if found is None:
                return
            text, end = found
            p.inbuf = p.inbuf[end:]
            self._host_command(p, text)

    def _host_command(self, p: _Port, text: str) -> None:
        # Which sample each host command ran in: lets a test or the demo rebuild the exact
        # schedule of changes in motion and predict it.
        self.command_log.append((self._sample, text))
        self._current = p  # CF I, WH and DR act on the handle that sent the command
        try:
            result = self._execute(text, None)
        except Refused as e:
            self._tc = e.code
            p.out += b"?"
            return
        finally:
            self._current = None
        if isinstance(result, _Wait):
            if self._ready(result):
                self._release(p, result)
            else:
                p.wait = result
        elif isinstance(result, _Download):
            p.download = []
        else:
            p.out += result.encode("latin-1") + b":"

    def _download(self, p: _Port) -> bool:
        """Collect program lines until ``\\``; return False when more input is needed."""
        assert p.download is not None
        while True:
            cut = [i for i in (p.inbuf.find("\r"), p.inbuf.find("\n")) if i >= 0]
            slash = p.inbuf.find("\\")
            if slash >= 0 and (not cut or slash < min(cut)):
                head = p.inbuf[:slash]
                if head.strip():
                    p.download.append(head)
                p.inbuf = p.inbuf[slash + 1 :]
                self._install_program(p.download)
                p.download = None
                p.swallow_cr = True
                p.out += b"::"
                return True
            if not cut:
                return False
            i = min(cut)
            line = p.inbuf[:i]
            p.inbuf = p.inbuf[i + 1 :]
            if line.strip():
                p.download.append(line)

    def _install_program(self, lines: list[str]) -> None:
        self._threads.clear()
        self._program = [ln.strip() for ln in lines]
        self._labels = {}
        for i, line in enumerate(self._program):
            m = _LABEL.match(line)
            if m and m.group(1) not in self._labels:
                self._labels[m.group(1)] = i

    # ---- program threads ---------------------------------------------------------------
    def _run_thread(self, th: _Thread) -> bool:
        """Run ``th`` until it blocks or uses its budget; return True if it did anything."""
        did = False
        while True:
            if th.wait is not None:
                if not self._ready(th.wait):
                    return did
                w, th.wait = th.wait, None
                did = True
                if w.then is not None:
                    try:
                        out = w.then()
                    except Refused as e:
                        self._halt(th, e.code)
                        return True
                    if out:
                        self._emit(out)
            if th.sample != self._sample:
                th.sample, th.ran = self._sample, 0
            if th.ran >= _LINES_PER_SAMPLE:
                return did
            if th.line >= len(self._program):
                self._threads.pop(th.number, None)
                return True
            cmds = split_program_line(self._program[th.line])
            if th.cmd >= len(cmds):
                th.line, th.cmd = th.line + 1, 0
                continue
            text = cmds[th.cmd].strip()
            th.cmd += 1
            th.ran += 1
            did = True
            if not text or text[0] in "#'" or text.startswith(("REM", "NO")):
                continue
            try:
                if text.startswith("EN"):
                    self._threads.pop(th.number, None)
                    return True
                if text.startswith("JP"):
                    self._jump(th, text[2:])
                    continue
                result = self._execute(text, th)
            except Refused as e:
                self._halt(th, e.code)
                return True
            if isinstance(result, _Wait):
                th.wait = result
            elif isinstance(result, _Download):
                self._halt(th, 3)
                return True
            elif result:
                self._emit(result)
            if th.number not in self._threads:
                return True

    def _halt(self, th: _Thread, code: int) -> None:
        self._tc = code
        self._threads.pop(th.number, None)

    def _jump(self, th: _Thread, args: str) -> None:
        fields = split_fields(args)
        m = _LABEL.fullmatch(fields[0].strip())
        if m is None or m.group(1) not in self._labels:
            raise Refused(10, "undefined label")
        if len(fields) > 2:
            raise Refused(1, "JP takes a label and one condition")
        if len(fields) == 2 and not evaluate(fields[1], self._lookup):
            return
        th.line, th.cmd = self._labels[m.group(1)], 0

    # ---- the interpreter ---------------------------------------------------------------
    def _execute(self, text: str, th: _Thread | None) -> str | _Wait | _Download:
        """Run one command; return its data text (with CR LF), a wait, or ``_DOWNLOAD``.

        Raises:
            Refused: the command is rejected; nothing was changed.
        """
        s = text.strip(" \t\n")
        if not s:
            return ""
        if s[0] == "\x12":
            if s == "\x12\x16":
                return self.identity + "\r\n"
            if s == "\x12\x13":
                self._reset_state()
                return ""
            raise Refused(1, "unknown control command")
        head = s[:2]
        eq = _find_eq(s)
        if head in COMMANDS:
            if eq > 0 and head != "CD":
                name = s[:eq].strip()
                rest = s[2:eq].strip()
                if not self._is_axis_spec(rest) and _VARIABLE.fullmatch(name):
                    return self._assign(name, s[eq + 1 :])
            handler: Callable[[str, _Thread | None], str | _Wait | _Download] = getattr(
                self, "_cmd_" + head.lower()
            )
            return handler(s[2:], th)
        if eq > 0:
            return self._assign(s[:eq].strip(), s[eq + 1 :])
        raise Refused(1, f"unrecognised command {s!r}")

    def _is_axis_spec(self, text: str) -> bool:
        letters = text.replace(" ", "").replace(",", "")
        return bool(letters) and all(c in self.spec.axes or c in self.spec.aliases for c in letters)

    def _assign(self, name: str, rhs: str) -> str:
        if not _VARIABLE.fullmatch(name) or name in _RESERVED:
            raise Refused(1, f"bad variable name {name!r}")
        rhs = rhs.strip()
        if rhs in ("", "?"):
            if name not in self._variables:
                raise Refused(1, f"undefined variable {name!r}")
            return self._vnum(self._variables[name]) + "\r\n"
        value = self._eval(rhs)
        if not INT32_MIN <= value < INT32_MAX + 1:
            raise Refused(6, "out of range")
        self._variables[name] = round(value * 65536) / 65536
        return ""

    def _eval(self, text: str) -> float:
        return evaluate(text, self._lookup)

    def _lookup(self, name: str) -> float:
        if name == "TIME":
            return float(self._sample)
        if name.startswith("_"):
            return self._operand(name[1:])
        try:
            return self._variables[name]
        except KeyError:
            raise Refused(1, f"undefined variable {name!r}") from None

    def _operand(self, name: str) -> float:
        code, rest = name[:2], name[2:]
        if code == "TC" and not rest:
            return float(self._tc)
        if code == "TM" and not rest:
            return float(self._tm)
        if code == "DT" and not rest:
            return float(self._dt)
        if code == "CM" and not rest:
            return float(self._contour_free())
        if code == "LZ" and not rest:
            return 1.0 if self._lz else 0.0
        if code == "CW" and not rest:
            return float(self._cw)
        if code == "EO" and not rest:
            return 1.0 if self._echo else 0.0
        if code == "TB" and not rest:
            return float(self._tb())
        if code == "DR" and not rest:
            return float(self._dr[0]) if self._dr is not None else 0.0
        if code == "WH" and not rest:
            p = self._current
            return float(_HANDLES.index(p.letter)) if p is not None and p.letter else -1.0
        if code == "BN" and not rest:
            return 4040.0
        if code == "NO" and not rest:
            return float(sum(1 << n for n in self._threads))
        if code == "XQ":
            n = int(rest) if rest.isdigit() else 0 if not rest else -1
            if not 0 <= n < self.spec.threads:
                raise Refused(1, "bad thread")
            th = self._threads.get(n)
            return float(th.line) if th is not None else -1.0
        if len(rest) != 1:
            raise Refused(1, f"unknown operand _{name}")
        ax = self._axis(rest)
        getter = _AXIS_OPERANDS.get(code)
        if getter is None:
            raise Refused(1, f"unknown operand _{name}")
        return float(getter(self, ax))

    # ---- argument helpers --------------------------------------------------------------
    def _axis(self, letter: str) -> _Axis:
        try:
            return self._axes[self.spec.axis_letter(letter)]
        except InvalidArgument:
            raise Refused(4, f"no axis {letter!r}") from None

    def _axis_list(self, args: str) -> list[_Axis]:
        letters = args.replace(" ", "").replace(",", "")
        if not letters:
            return list(self._axes.values())
        out: list[_Axis] = []
        for c in letters:
            ax = self._axis(c)
            if ax not in out:
                out.append(ax)
        return out

    def _axis_fields(self, args: str) -> list[tuple[_Axis, str]]:
        a = args.strip()
        if not a:
            return []
        eq = a.find("=")
        if eq >= 0:
            value = a[eq + 1 :].strip()
            if not value:
                raise Refused(1, "missing value")
            return [(ax, value) for ax in self._axis_list(a[:eq])] if a[:eq].strip() else []
        fields = split_fields(a)
        if len(fields) > len(self._axes):
            raise Refused(4, "more fields than axes")
        axes = list(self._axes.values())
        return [(axes[i], f.strip()) for i, f in enumerate(fields) if f.strip()]

    def _pnum(self, value: float) -> str:
        return format_reply(value, self._pf, self._lz, sign_space=True)

    def _vnum(self, value: float) -> str:
        return format_reply(value, self._vf, self._lz, sign_space=True)

    def _num(self, value: float, fmt: str) -> str:
        return format_reply(value, fmt, self._lz, sign_space=True)

    def _params(
        self,
        args: str,
        get: Callable[[_Axis], float],
        check: Callable[[_Axis, float], float],
        apply: Callable[[_Axis, float], None],
        fmt: Callable[[float], str],
    ) -> str:
        """Set and/or interrogate a per-axis parameter; all checks come before any change."""
        queries: list[_Axis] = []
        sets: list[tuple[_Axis, float]] = []
        for ax, text in self._axis_fields(args):
            if text == "?":
                queries.append(ax)
            else:
                sets.append((ax, check(ax, self._eval(text))))
        for ax, value in sets:
            apply(ax, value)
        if not queries:
            return ""
        return ",".join(fmt(get(ax)) for ax in queries) + "\r\n"

    def _engine(self, call: Callable[[], None]) -> None:
        try:
            call()
        except CommandError as e:
            raise Refused(e.code or 1, e.text) from None
        except InvalidArgument as e:
            raise Refused(6, str(e)) from None

    # ---- quantisation as the controller stores values ----------------------------------
    # The predictor's quantisation, so the values stored here are the ones it plans with.
    def _q_accel(self, value: float) -> float:
        try:
            return float(quantise_accel(value, self.spec))
        except LimitError:
            raise Refused(6, "AC/DC out of range") from None

    def _q_speed(self, value: float) -> float:
        try:
            return float(quantise_speed(value, self.spec, signed=True))
        except LimitError:
            raise Refused(6, "speed out of range") from None

    @staticmethod
    def _q_position(value: float) -> int:
        if not INT32_MIN <= value <= INT32_MAX:
            raise Refused(6, "position out of range")
        return round(value)

    # ---- motion commands ---------------------------------------------------------------
    def _cmd_pr(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            if ax.m.moving:
                raise Refused(7, "PR while moving")
            return self._q_position(v)

        def apply(ax: _Axis, v: float) -> None:
            ax.pr, ax.absolute, ax.next_mode = int(v), False, "position"

        return self._params(args, lambda ax: ax.pr, check, apply, self._pnum)

    def _cmd_pa(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            if ax.m.moving:
                raise Refused(7, "PA while moving")
            return self._q_position(v)

        def apply(ax: _Axis, v: float) -> None:
            ax.pa, ax.absolute, ax.next_mode = int(v), True, "position"

        return self._params(args, lambda ax: ax.pa, check, apply, self._pnum)

    def _cmd_sp(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            if v < 0:
                raise Refused(6, "negative speed")
            return self._q_speed(v)

        def apply(ax: _Axis, v: float) -> None:
            ax.sp = v
            prof = ax.m.profiler
            if prof.moving and prof.mode == "position" and v > 0:
                self._engine(lambda: prof.set_speed(v))

        return self._params(args, lambda ax: ax.sp, check, apply, lambda v: self._num(v, "10.0"))

    def _cmd_ac(self, args: str, th: _Thread | None) -> str:
        def apply(ax: _Axis, v: float) -> None:
            ax.ac = v
            prof = ax.m.profiler
            if prof.moving and prof.mode in ("position", "jog"):
                self._engine(lambda: prof.set_accel(v))

        return self._params(
            args,
            lambda ax: ax.ac,
            lambda ax, v: self._q_accel(v),
            apply,
            lambda v: self._num(v, "10.0"),
        )

    def _cmd_dc(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            if ax.m.moving:
                raise Refused(7, "DC while moving")
            return self._q_accel(v)

        def apply(ax: _Axis, v: float) -> None:
            ax.dc = v

        return self._params(args, lambda ax: ax.dc, check, apply, lambda v: self._num(v, "10.0"))

    def _cmd_jg(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            prof = ax.m.profiler
            if prof.moving and prof.mode != "jog":
                raise Refused(13, "JG while not jogging")
            return self._q_speed(v)

        def apply(ax: _Axis, v: float) -> None:
            ax.jg, ax.next_mode = v, "jog"
            prof = ax.m.profiler
            if prof.moving and prof.mode == "jog":
                self._engine(lambda: prof.set_speed(v))

        return self._params(args, lambda ax: ax.jg, check, apply, lambda v: self._num(v, "10.0"))

    def _cmd_it(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            try:
                return quantise_it(v)
            except InvalidArgument:
                raise Refused(6, "IT out of range") from None

        def apply(ax: _Axis, v: float) -> None:
            ax.it = v

        return self._params(args, lambda ax: ax.it, check, apply, lambda v: self._num(v, "1.4"))

    def _cmd_fl(self, args: str, th: _Thread | None) -> str:
        def apply(ax: _Axis, v: float) -> None:
            ax.fl = int(v)

        return self._params(
            args, lambda ax: ax.fl, lambda ax, v: self._q_position(v), apply, self._pnum
        )

    def _cmd_bl(self, args: str, th: _Thread | None) -> str:
        def apply(ax: _Axis, v: float) -> None:
            ax.bl = int(v)

        return self._params(
            args, lambda ax: ax.bl, lambda ax, v: self._q_position(v), apply, self._pnum
        )

    def _cmd_dp(self, args: str, th: _Thread | None) -> str:
        def check(ax: _Axis, v: float) -> float:
            if ax.m.moving:
                raise Refused(7, "DP while moving")
            return self._q_position(v)

        def apply(ax: _Axis, v: float) -> None:
            self._reseat(ax, int(v))
            ax.pa = int(v)

        return self._params(args, lambda ax: ax.m.encoder, check, apply, self._pnum)

    def _reseat(self, ax: _Axis, position: int) -> None:
        """Start a fresh servo loop for ``ax`` at ``position`` (DP, SH, TM)."""
        old = ax.m
        ax.m = AxisMotion(self._ts, position, old.lag)
        ax.m.motor_on = old.motor_on
        ax.m.profiler.stop_code = old.profiler.stop_code

    def _start_check(self, ax: _Axis, direction: float) -> None:
        if ax.contour:
            raise Refused(18, "axis is contouring")
        if not ax.m.motor_on:
            raise Refused(20, "motor off")
        if ax.m.moving:
            raise Refused(21, "already moving")
        ref = ax.m.reference
        if direction > 0 and (ax.switch_fwd or ref > ax.fl):
            raise Refused(22, "forward limit")
        if direction < 0 and (ax.switch_rev or ref < ax.bl):
            raise Refused(22, "reverse limit")

    def _cmd_bg(self, args: str, th: _Thread | None) -> str:
        axes = self._axis_list(args)
        plans: list[tuple[_Axis, int | None]] = []
        for ax in axes:
            if ax.next_mode == "jog":
                self._start_check(ax, ax.jg)
                plans.append((ax, None))
            else:
                base = ax.m.profiler.position
                target = ax.pa if ax.absolute else base + ax.pr
                self._q_position(target)
                self._start_check(ax, target - base)
                if ax.sp <= 0:
                    raise Refused(6, "SP is 0")
                plans.append((ax, target))
        for ax, goal in plans:
            prof = ax.m.profiler
            ax.limit_stopping = False
            ax.move_start = prof.position
            if goal is None:
                self._engine(functools.partial(prof.begin_jog, ax.jg, ax.ac, ax.dc, ax.it))
            else:
                ax.pa = goal
                self._engine(functools.partial(prof.begin_move, goal, ax.sp, ax.ac, ax.dc, ax.it))
        return ""

    def _cmd_ip(self, args: str, th: _Thread | None) -> str:
        fields = [(ax, t) for ax, t in self._axis_fields(args)]
        if any(t == "?" for _, t in fields):
            return ",".join(self._pnum(ax.m.profiler.target) for ax, _ in fields) + "\r\n"
        moves = [(ax, self._q_position(self._eval(t))) for ax, t in fields]
        for ax, n in moves:
            if ax.contour:
                raise Refused(18, "axis is contouring")
            if not ax.m.moving:
                self._start_check(ax, n)
                if ax.sp <= 0:
                    raise Refused(6, "SP is 0")
        for ax, n in moves:
            prof = ax.m.profiler
            if not prof.moving:
                ax.pr, ax.absolute, ax.next_mode, ax.limit_stopping = n, False, "position", False
            self._engine(functools.partial(prof.increment, n, ax.sp, ax.ac, ax.dc, ax.it))
            ax.pa = prof.target
        return ""

    def _cmd_st(self, args: str, th: _Thread | None) -> str:
        for ax in self._axis_list(args):
            ax.m.profiler.stop()
        return ""

    def _cmd_ab(self, args: str, th: _Thread | None) -> str:
        a = args.strip()
        if a not in ("", "0", "1"):
            raise Refused(6, "AB takes 0 or 1")
        for ax in self._axes.values():
            if ax.m.moving:
                ax.m.profiler.abort()
            ax.contour = ax.contour_fed = False
        if a != "1":
            self._threads.clear()
        return ""

    def _cmd_sh(self, args: str, th: _Thread | None) -> str:
        for ax in self._axis_list(args):
            if not ax.m.motor_on:
                ax.m.motor_on = True
                self._reseat(ax, ax.m.encoder)
        return ""

    def _cmd_mo(self, args: str, th: _Thread | None) -> str:
        axes = self._axis_list(args)
        if any(ax.m.moving for ax in axes):
            raise Refused(7, "MO while moving")
        for ax in axes:
            ax.m.motor_on = False
        return ""

    def _cmd_am(self, args: str, th: _Thread | None) -> _Wait:
        letters = [ax.letter for ax in self._axis_list(args)]

        def exact() -> bool:
            # A profile's end is a step boundary (see _horizon); a jog without a stop never ends.
            for c in letters:
                prof = self._axes[c].m.profiler
                if prof.moving and prof.end_sample is None and prof.mode != "jog":
                    return False
            return True

        return _Wait(lambda: not any(self._axes[c].m.moving for c in letters), exact=exact)

    def _cmd_ad(self, args: str, th: _Thread | None) -> _Wait:
        """AD: hold until each named axis's profile has gone the distance from the move's start.

        Like the controller, AD watches the profiler (before IT smoothing); distances are
        magnitudes, and a move that ends first releases the wait.
        """
        fields = split_fields(args.partition("=")[2] if "=" in args else args)
        if "=" in args:
            letters = [self.spec.axis_letter(c) for c in args.partition("=")[0].strip()]
            values = [self._eval(fields[0])] * len(letters)
        else:
            letters = [a for a, f in zip(self._axes, fields, strict=False) if f.strip()]
            values = [self._eval(f) for f in fields if f.strip()]
        if not letters:
            raise Refused(4, "AD needs a distance")
        goal: dict[str, float] = {}
        for c, v in zip(letters, values, strict=True):
            if not 0 <= v <= INT32_MAX:
                raise Refused(6, "AD distance out of range")
            goal[c] = v

        def reached() -> bool:
            for c, d in goal.items():
                ax = self._axes[c]
                prof = ax.m.profiler
                if prof.moving and abs(prof.position - ax.move_start) < d:
                    return False
            return True

        return _Wait(reached)

    def _cmd_mc(self, args: str, th: _Thread | None) -> _Wait:
        letters = [ax.letter for ax in self._axis_list(args)]

        def exact() -> bool:
            # An axis still running a profile with a known end is not in position before
            # that end, which is a step boundary (see _horizon): no need to bisect the step.
            for c in letters:
                m = self._axes[c].m
                if m.motor_on and m.profiler.moving and m.profiler.end_sample is not None:
                    return True
            return False

        return _Wait(lambda: all(self._axes[c].m.in_position for c in letters), exact=exact)

    def _cmd_wt(self, args: str, th: _Thread | None) -> _Wait:
        fields = split_fields(args)
        ms = self._eval(fields[0]) if fields[0].strip() else -1
        if not 0 <= ms <= INT32_MAX:
            raise Refused(6, "WT out of range")
        samples = len(fields) > 1 and fields[1].strip() == "1"
        n = round(ms) if samples else math.ceil(ms / 1000 / self._ts - 1e-9)
        return _Wait(wake=self._sample + n)

    # ---- contour -----------------------------------------------------------------------
    def _contour_axes(self) -> list[_Axis]:
        return [ax for ax in self._axes.values() if ax.contour]

    def _contour_free(self) -> int:
        waiting = max((ax.m.profiler.queued_segments for ax in self._contour_axes()), default=0)
        return self.spec.contour_buffer - max(0, waiting - 1)

    def _cmd_cm(self, args: str, th: _Thread | None) -> str:
        axes = self._axis_list(args)
        for ax in axes:
            if ax.m.moving and not ax.contour:
                raise Refused(7, "CM while moving")
        for ax in axes:
            if not ax.contour:
                self._engine(ax.m.profiler.begin_contour)
                ax.contour, ax.contour_fed = True, False
        return ""

    def _cmd_dt(self, args: str, th: _Thread | None) -> str:
        a = args.strip()
        if a == "?":
            return self._num(self._dt, "1.0") + "\r\n"
        value = self._eval(a)
        low, high = self.spec.dt_range
        if (value != 0 and not low <= value <= high) or value != int(value):
            raise Refused(6, "DT out of range")
        self._dt = int(value)
        return ""

    def _cmd_cd(self, args: str, th: _Thread | None) -> str | _Wait:
        text, _, dt_text = args.partition("=")
        fields = split_fields(text)
        if len(fields) > len(self._axes):
            raise Refused(4, "more fields than axes")
        n = int(self._eval(dt_text)) if dt_text.strip() else self._dt
        incs: dict[str, int] = {}
        for ax, f in zip(self._axes.values(), fields, strict=False):
            value = self._eval(f) if f.strip() else 0.0
            if abs(value) > self.spec.cd_max or value != int(value):
                raise Refused(41, "CD increment out of range")
            if value and not ax.contour:
                raise Refused(41, "axis is not in contour mode")
            incs[ax.letter] = int(value)
        axes = self._contour_axes()
        if not axes:
            raise Refused(8, "not in contour mode")
        if n == 0:
            if any(incs.values()):
                raise Refused(41, "increment with DT 0")
            for ax in axes:
                ax.m.profiler.end_contour()
                ax.contour_fed = False
            return ""
        if not self.spec.dt_range[0] <= n <= self.spec.dt_range[1]:
            raise Refused(41, "DT out of range")

        def add() -> str:
            for ax in axes:
                self._engine(
                    functools.partial(ax.m.profiler.add_segment, incs.get(ax.letter, 0), n)
                )
                ax.contour_fed = True
            return ""

        if self._contour_free() > 0:
            return add()
        return _Wait(lambda: self._contour_free() > 0, then=add)

    def _cmd_wc(self, args: str, th: _Thread | None) -> _Wait:
        return _Wait(lambda: all(ax.m.profiler.queued_segments <= 1 for ax in self._contour_axes()))

    # ---- interrogation -----------------------------------------------------------------
    def _report(self, args: str, get: Callable[[_Axis], float], fmt: Callable[[float], str]) -> str:
        return ",".join(fmt(get(ax)) for ax in self._axis_list(args)) + "\r\n"

    def _cmd_tp(self, args: str, th: _Thread | None) -> str:
        return self._report(args, lambda ax: ax.m.encoder, self._pnum)

    def _cmd_rp(self, args: str, th: _Thread | None) -> str:
        return self._report(args, lambda ax: ax.m.reference, self._pnum)

    def _cmd_te(self, args: str, th: _Thread | None) -> str:
        return self._report(args, lambda ax: ax.m.error, self._pnum)

    def _cmd_td(self, args: str, th: _Thread | None) -> str:
        return self._report(args, lambda ax: ax.m.encoder, self._pnum)

    def _cmd_tv(self, args: str, th: _Thread | None) -> str:
        return self._report(args, lambda ax: round(ax.m.velocity), lambda v: self._num(v, "8.0"))

    def _cmd_sc(self, args: str, th: _Thread | None) -> str:
        return self._report(args, _stop_code, lambda v: self._num(v, "3.0"))

    def _cmd_ts(self, args: str, th: _Thread | None) -> str:
        return self._report(args, _status_byte, lambda v: self._num(v, "3.0"))

    def _cmd_tc(self, args: str, th: _Thread | None) -> str:
        a = args.strip()
        if a not in ("", "0", "1"):
            raise Refused(6, "TC takes 0 or 1")
        code = self._tc
        self._tc = 0
        if a == "1" and code:
            return f"{self._num(code, '3.0')} {tc_text(code)}\r\n"
        return self._num(code, "3.0") + "\r\n"

    def _cmd_mg(self, args: str, th: _Thread | None) -> str:
        out: list[str] = []
        newline = True
        if not args.strip():
            return "\r\n"
        for part in split_fields(args):
            specs = _BRACES.findall(part)
            expr = _BRACES.sub("", part).strip()
            fmt: str | None = None
            for spec in specs:
                s = spec.strip()
                if s.upper() == "N":
                    newline = False
                elif s.startswith("^"):
                    code = int(self._eval(s[1:]))
                    if not 0 <= code <= 255:
                        raise Refused(53, "bad character code")
                    out.append(chr(code))
                elif s[:1].upper() in ("F", "Z", "$"):
                    fmt = s
                elif s[:1].upper() in ("E", "P"):
                    continue
                else:
                    raise Refused(53, f"bad format {{{s}}}")
            if expr.startswith('"'):
                if len(expr) < 2 or not expr.endswith('"') or '"' in expr[1:-1]:
                    raise Refused(52, "missing quote")
                out.append(expr[1:-1])
            elif expr:
                out.append(self._mg_number(self._eval(expr), fmt))
        text = "".join(out)
        return text + ("\r\n" if newline else "")

    def _mg_number(self, value: float, fmt: str | None) -> str:
        if fmt is None:
            return self._vnum(value)
        kind, body = fmt[0].upper(), fmt[1:]
        try:
            if kind == "$":
                return format_reply(value, "$" + body)
            return format_reply(value, body, kind == "Z", sign_space=True)
        except InvalidArgument:
            raise Refused(53, f"bad format {fmt}") from None

    # ---- settings ----------------------------------------------------------------------
    def _setting(self, args: str, choices: tuple[int, ...], current: int) -> int | None:
        a = args.strip()
        if a == "?":
            return None
        value = self._eval(a) if a else choices[0]
        if value not in choices:
            raise Refused(6, f"value must be one of {choices}")
        return int(value)

    def _cmd_lz(self, args: str, th: _Thread | None) -> str:
        v = self._setting(args, (1, 0), int(self._lz))
        if v is None:
            return self._num(int(self._lz), "1.0") + "\r\n"
        self._lz = bool(v)
        return ""

    def _cmd_eo(self, args: str, th: _Thread | None) -> str:
        v = self._setting(args, (1, 0), int(self._echo))
        if v is None:
            return self._num(int(self._echo), "1.0") + "\r\n"
        self._echo = bool(v)
        return ""

    def _cmd_cw(self, args: str, th: _Thread | None) -> str:
        fields = split_fields(args)
        if fields[0].strip() == "?":
            return self._num(self._cw, "1.0") + "\r\n"
        mode = self._cw
        if fields[0].strip():
            mode = int(self._eval(fields[0]))
            if mode not in (0, 1, 2):
                raise Refused(6, "CW takes 1 or 2")
        pause = self._cw_mode
        if len(fields) > 1 and fields[1].strip():
            pause = int(self._eval(fields[1]))
            if pause not in (0, 1):
                raise Refused(6, "CW second field is 0 or 1")
        self._cw = 2 if mode == 0 else mode
        self._cw_mode = pause
        return ""

    def _format_setting(self, args: str, current: str) -> str | None:
        a = args.strip()
        if a == "?":
            return None
        try:
            is_hex, m, n = parse_format(a)
        except InvalidArgument:
            raise Refused(6, "bad format") from None
        return f"{'$' if is_hex else ''}{m}.{n}"

    def _cmd_pf(self, args: str, th: _Thread | None) -> str:
        v = self._format_setting(args, self._pf)
        if v is None:
            return f" {self._pf}\r\n"
        self._pf = v
        return ""

    def _cmd_vf(self, args: str, th: _Thread | None) -> str:
        v = self._format_setting(args, self._vf)
        if v is None:
            return f" {self._vf}\r\n"
        self._vf = v
        return ""

    def _cmd_tm(self, args: str, th: _Thread | None) -> str:
        a = args.strip()
        if a == "?":
            return self._num(self._tm, "5.2") + "\r\n"
        if not a:
            return ""
        value = self._eval(a)
        if not self.spec.tm_adjustable:
            if value != self._tm:
                raise Refused(6, "this model's sample period is fixed")
            return ""
        low, high = self.spec.tm_range
        if not low <= value <= high:
            raise Refused(6, "TM out of range")
        if any(ax.m.moving for ax in self._axes.values()):
            raise Refused(7, "TM while moving")
        self._set_tm(value)
        for ax in self._axes.values():
            self._reseat(ax, ax.m.reference)
        return ""

    def _cmd_rs(self, args: str, th: _Thread | None) -> str:
        if args.strip():
            raise Refused(6, "RS takes no argument")
        self._reset_state()
        return ""

    def _cmd_no(self, args: str, th: _Thread | None) -> str:
        return ""

    def _cmd_qz(self, args: str, th: _Thread | None) -> str:
        if self.spec.qz is None:
            raise Refused(1, "no data record on this model")
        return ",".join(self._num(v, "10.0") for v in self.spec.qz) + "\r\n"

    def _cmd_qr(self, args: str, th: _Thread | None) -> str:
        if self.spec.qz is None or self.spec.qz[1] not in (52, 24, 18):
            raise Refused(1, "no data record on this model")
        # QR AB asks for those axis blocks only (the header says which); the general and
        # coordinated blocks always come (I, S, T, N letters are accepted and change nothing).
        letters = args.replace(" ", "").replace(",", "").upper()
        axes = ""
        for c in letters:
            if c in "ISTN":
                continue
            letter = self._axis(c).letter
            if letter not in axes:
                axes += letter
        return self.record(axes).decode("latin-1")

    def _cmd_th(self, args: str, th: _Thread | None) -> str:
        return self._th()

    def _th(self) -> str:
        lines = ["CONTROLLER IP ADDRESS 127,0,0,1 ETHERNET ADDRESS 00-50-4C-00-00-01"]
        names = {p.letter: p.name for p in self._ports.values() if p.letter}
        for letter in _HANDLES:
            lines.append(f"IH{letter} {names.get(letter, 'AVAILABLE')}")
        return "\r\n".join(lines) + "\r\n"

    # ---- handles: CF, WH, DR -----------------------------------------------------------
    def _handle(self, letter: str) -> _Port:
        for p in self._ports.values():
            if p.letter == letter:
                return p
        raise Refused(126, f"Ethernet handle {letter} is not open")

    def _cmd_cf(self, args: str, th: _Thread | None) -> str:
        a = args.strip().upper()
        if a == "I":
            # The handle that sends CF I receives the messages (how a host claims them).
            if self._current is None:
                raise Refused(6, "CF I names the sending handle; a program has none")
            self._cf = self._current.number
        elif a == "S":
            # The main port: on the simulator's TCP server, its message port.
            self._cf = None
        elif len(a) == 1 and a in _HANDLES:
            self._cf = self._handle(a).number
        else:
            raise Refused(6, "CF takes I, S or a handle letter A-H")
        return ""

    def _cmd_wh(self, args: str, th: _Thread | None) -> str:
        if args.strip():
            raise Refused(6, "WH takes no argument")
        p = self._current
        return ("RS232" if p is None or not p.letter else f"IH{p.letter}") + "\r\n"

    def _cmd_dr(self, args: str, th: _Thread | None) -> str:
        fields = split_fields(args)
        if len(fields) > 2 or not fields[0].strip():
            raise Refused(6, "DR takes samples and an optional handle")
        period = self._eval(fields[0])
        if period == 0:
            self._dr = None
            return ""
        if self.spec.qz is None or self.spec.qz[1] not in (52, 24, 18):
            raise Refused(1, "no data record on this model")
        low, high = self.spec.dr_range
        if period != int(period) or not low <= period <= high:
            raise Refused(6, f"DR period must be 0 or {low}..{high} samples")
        if len(fields) == 2 and fields[1].strip():
            index = self._eval(fields[1])
            if index != int(index) or not 0 <= index < len(_HANDLES):
                raise Refused(6, "DR handle is 0..7 (A..H)")
            port = self._handle(_HANDLES[int(index)])
        elif self._current is not None and self._current.letter:
            port = self._current
        else:
            raise Refused(6, "DR streams to an Ethernet handle; name one (DR n,h)")
        self._dr = (int(period), port.number)
        self._dr_next = self._sample + int(period)
        return ""

    def _stream_record(self) -> None:
        assert self._dr is not None
        period, number = self._dr
        port = self._ports.get(number)
        if port is None:
            self._dr = None
            return
        # Streamed records carry no ':' (only a solicited QR has one).
        port.out += self.record()
        while self._dr_next <= self._sample:
            self._dr_next += period

    def _cmd_tb(self, args: str, th: _Thread | None) -> str:
        if args.strip():
            raise Refused(6, "TB takes no argument")
        return self._num(self._tb(), "3.0") + "\r\n"

    def _tb(self) -> int:
        value = 0x80 if self._threads else 0
        if any(ax.contour for ax in self._axes.values()):
            value |= 0x20
        if self._dr is not None:
            value |= 0x40  # "data record active" on the families that report it
        return value | (1 if self._echo else 0)

    # ---- programs ----------------------------------------------------------------------
    def _cmd_dl(self, args: str, th: _Thread | None) -> _Download:
        if th is not None:
            raise Refused(3, "DL not valid in a program")
        if self._threads:
            raise Refused(17, "DL while a program runs")
        return _DOWNLOAD

    def _cmd_ul(self, args: str, th: _Thread | None) -> str:
        if th is not None:
            raise Refused(3, "UL not valid in a program")
        return "".join(line + "\r\n" for line in self._program) + "\x1a"

    def _cmd_xq(self, args: str, th: _Thread | None) -> str:
        fields = split_fields(args)
        label = fields[0].strip()
        number = int(self._eval(fields[1])) if len(fields) > 1 and fields[1].strip() else 0
        if not 0 <= number < self.spec.threads:
            raise Refused(6, "no such thread")
        if label:
            m = _LABEL.fullmatch(label)
            if m is None or m.group(1) not in self._labels:
                raise Refused(10, "undefined label")
            line = self._labels[m.group(1)]
        else:
            if not self._program:
                raise Refused(10, "no program")
            line = 0
        if number in self._threads and self._threads[number] is not th:
            raise Refused(19, "thread already running")
        self._threads[number] = _Thread(number, line=line)
        return ""

    def _cmd_hx(self, args: str, th: _Thread | None) -> str:
        a = args.strip()
        if not a:
            self._threads.clear()
            return ""
        n = int(self._eval(a))
        if not 0 <= n < self.spec.threads:
            raise Refused(6, "no such thread")
        self._threads.pop(n, None)
        return ""

    def _cmd_jp(self, args: str, th: _Thread | None) -> str:
        raise Refused(2, "JP only in a program")

    def _cmd_en(self, args: str, th: _Thread | None) -> str:
        raise Refused(2, "EN only in a program")

    # ---- data record -------------------------------------------------------------------
    def record(self, axes: str = "") -> bytes:
        """The QR data record of this model's layout (4000 or 21x3 style), then ``:`` is added
        by the caller. ``axes`` (letters) limits the axis blocks; default all.

        Raises:
            InvalidArgument: the model has no data record layout here.
        """
        qz = self.spec.qz
        if qz is None or qz[1] not in (52, 24, 18):
            raise InvalidArgument(f"{self.spec.name}: no data record layout in the simulator")
        n, general, coord, per_axis = qz
        present = [
            (i, ax)
            for i, ax in enumerate(list(self._axes.values())[:n])
            if not axes or ax.letter in axes
        ]
        size = 4 + general + coord + len(present) * per_axis
        buf = bytearray(size)
        mask = sum(1 << i for i, _ in present)
        struct.pack_into("<BBH", buf, 0, 0x87, mask, size)
        struct.pack_into("<H", buf, 4, self._sample & 0xFFFF)
        buf[6:16] = b"\xff" * 10  # inputs read high when nothing is connected
        threads = sum(1 << t for t in self._threads)
        if general == 52:
            buf[50] = self._tc & 0xFF
            buf[51] = threads & 0xFF
            struct.pack_into("<H", buf, 60, self._contour_free())
            base = 82
        elif general == 24:
            buf[26] = self._tc & 0xFF
            buf[27] = (0x80 if threads else 0) | (1 if self._echo else 0)
            base = 44
        else:
            # DMC-30010: an 18-byte general block whose layout is not sourced (kept raw by
            # galil.protocol.records); only the sample number is filled in. Axis blocks as 4000.
            base = 4 + general + coord
        for i, (_, ax) in enumerate(present):
            at = base + i * per_axis
            m = ax.m
            struct.pack_into(
                "<HBBiiiii",
                buf,
                at,
                _status_word(ax),
                _switches(ax),
                _stop_code(ax) & 0xFF,
                _clamp32(m.reference),
                _clamp32(m.encoder),
                _clamp32(m.error),
                _clamp32(m.encoder),
                _clamp32(round(64 * m.velocity)),
            )
        return bytes(buf)


class _Download:
    """Returned by DL: the port switches to collecting program lines."""


_DOWNLOAD = _Download()


def _find_eq(s: str) -> int:
    quoted = False
    for i, ch in enumerate(s):
        if ch == '"':
            quoted = not quoted
        elif ch == "=" and not quoted:
            return i
    return -1


def _clamp32(v: int) -> int:
    return max(INT32_MIN, min(INT32_MAX, int(v)))


def _stop_code(ax: _Axis) -> int:
    return int(ax.m.profiler.stop_code)


def _status_byte(ax: _Axis) -> int:
    m = ax.m
    value = 0x02 | 0x01  # home input high, latch not armed
    if m.moving:
        value |= 0x80
    if not m.motor_on:
        value |= 0x20
    if not ax.switch_fwd:
        value |= 0x08
    if not ax.switch_rev:
        value |= 0x04
    return value


def _switches(ax: _Axis) -> int:
    value = 0x02
    if not ax.switch_fwd:
        value |= 0x08
    if not ax.switch_rev:
        value |= 0x04
    return value


def _status_word(ax: _Axis) -> int:
    m = ax.m
    prof = m.profiler
    word = 0
    if m.moving:
        word |= 0x8000
        if prof.mode == "position":
            word |= 0x4000 | (0x2000 if ax.absolute else 0)
        if prof.velocity < 0:
            word |= 0x0080
        if ax.limit_stopping or prof.stop_code in (2, 3, 4):
            word |= 0x0010
    if prof.mode == "contour":
        word |= 0x0040
    if not m.motor_on:
        word |= 0x0001
    return word


_AXIS_OPERANDS: dict[str, Callable[[SimController, _Axis], float]] = {
    "TP": lambda c, ax: ax.m.encoder,
    "RP": lambda c, ax: ax.m.reference,
    "TE": lambda c, ax: ax.m.error,
    "TD": lambda c, ax: ax.m.encoder,
    "TV": lambda c, ax: round(ax.m.velocity),
    "SC": lambda c, ax: ax.m.profiler.stop_code,
    "TS": lambda c, ax: _status_byte(ax),
    "MO": lambda c, ax: 0 if ax.m.motor_on else 1,
    "BG": lambda c, ax: 1 if ax.m.moving else 0,
    "LF": lambda c, ax: 0 if ax.switch_fwd else 1,
    "LR": lambda c, ax: 0 if ax.switch_rev else 1,
    "AC": lambda c, ax: ax.ac,
    "DC": lambda c, ax: ax.dc,
    "SP": lambda c, ax: ax.sp,
    "JG": lambda c, ax: ax.jg,
    "IT": lambda c, ax: ax.it,
    "PA": lambda c, ax: ax.pa,
    "PR": lambda c, ax: ax.pr,
    "FL": lambda c, ax: ax.fl,
    "BL": lambda c, ax: ax.bl,
}
