"""Progress of long work on stderr: what runs, how far it has got, the elapsed time and an ETA.

On a terminal a stage is one line rewritten in place; when stderr is a file or a pipe (a log, CI) it
is plain lines, at most one per ``LOG_INTERVAL`` seconds plus the first and the last, so logs stay
short. Counted work (optimizer steps, integrator chunks, sweep runs) gets its ETA from its own rate,
measured from the first completed unit on (the first one usually includes compiling). Uncounted
waits (compiling a program) get theirs from the duration of the same stage in an earlier run, when
``remember`` names a file to keep them in (the CLI keeps it next to its compilation cache); a stage
never seen before shows its elapsed time only.

    with Progress("design tf=0.43", total=100, unit="step") as bar:
        with bar.waiting("compiling the gradient", key="design-gradient"):
            first = step()                 # blocks: a ticker updates the elapsed time
        bar.update(1)
        ...

``Progress(..., enabled=False)`` prints nothing (library calls with ``progress=False``).
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import threading
import time
from pathlib import Path

import jax

LOG_INTERVAL = 10.0      # s between plain lines in a log
TTY_INTERVAL = 0.2       # s between rewrites on a terminal

_memory: dict = {"path": None}


def remember(path: str | os.PathLike | None) -> None:
    """Keep the durations of named waits in the JSON file ``path`` (None: forget nothing, keep
    nothing), so later runs can show an ETA for them."""
    _memory["path"] = Path(path) if path else None


def recorded(key: str) -> float | None:
    """The duration [s] remembered for ``key`` (None: none, or no memory file)."""
    p = _memory["path"]
    if p is None or not p.is_file():
        return None
    try:
        return float(json.loads(p.read_text()).get(key))
    except (ValueError, TypeError, OSError):
        return None


def record(key: str, seconds: float) -> None:
    """Remember that ``key`` took ``seconds`` (no-op without a memory file)."""
    p = _memory["path"]
    if p is None:
        return
    try:
        data = json.loads(p.read_text()) if p.is_file() else {}
        data[key] = round(seconds, 2)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + f".tmp{os.getpid()}")
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True))
        os.replace(tmp, p)
    except (ValueError, OSError):
        pass                            # a timing memory is a convenience, never an error


def clock(seconds: float) -> str:
    """Seconds as '42 s', '3:07' or '1:02:03'."""
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f"{s} s"
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


_compilations = [0]


def _count_compilations(event: str, duration: float, **kwargs) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        _compilations[0] += 1


jax.monitoring.register_event_duration_secs_listener(_count_compilations)


class Wait:
    """Handle of a ``Progress.waiting`` block. ``compiled``: whether XLA compiled a program during
    the wait (only such waits are remembered: a program loaded from a cache takes far less)."""

    compiled: bool = False


class Progress:
    """One stage of work: ``label``, ``total`` units (None: uncounted), reported on ``stream``
    (default: stderr at the time of each write)."""

    def __init__(self, label: str, total: int | None = None, *, unit: str = "", stream=None,
                 enabled: bool = True, start: int = 0):
        self.label, self.total, self.unit, self.enabled = label, total, unit, enabled
        self._stream = stream
        self.started = time.perf_counter()
        self.done = start
        self._mark: tuple[int, float] | None = None        # (units, time) of the first update
        self._last_write = float("-inf")
        self._lock = threading.Lock()
        self._width = 0

    # -- output ------------------------------------------------------------------------------
    @property
    def stream(self):
        return self._stream if self._stream is not None else sys.stderr

    @property
    def tty(self) -> bool:
        isatty = getattr(self.stream, "isatty", None)
        try:
            return bool(isatty and isatty())
        except ValueError:               # a closed stream
            return False

    def _write(self, text: str, *, final: bool = False, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        with self._lock:
            if self.tty:
                if not (final or force or now - self._last_write >= TTY_INTERVAL):
                    return
                pad = max(0, self._width - len(text))
                self.stream.write("\r" + text + " " * pad + ("\n" if final else ""))
                self._width = 0 if final else len(text)
            else:
                if not (final or force or now - self._last_write >= LOG_INTERVAL):
                    return
                self.stream.write(text + "\n")
            self.stream.flush()
            self._last_write = now

    # -- state -------------------------------------------------------------------------------
    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def eta(self) -> float | None:
        """Seconds left at the rate measured since the first update (None: not known yet)."""
        if self.total is None or self._mark is None:
            return None
        n0, t0 = self._mark
        if self.done <= n0:
            return None
        rate = (time.perf_counter() - t0) / (self.done - n0)
        return rate * max(self.total - self.done, 0)

    def line(self, note: str = "") -> str:
        parts = [f"{self.label}:"]
        if self.total is not None:
            unit = f" {self.unit}s" if self.unit else ""
            parts.append(f"{self.done}/{self.total}{unit}")
        if note:
            parts.append(note)
        tail = f"[{clock(self.elapsed())}"
        eta = self.eta()
        if eta is not None and (self.total is None or self.done < self.total):
            tail += f", ETA {clock(eta)}"
        parts.append(tail + "]")
        return " ".join(parts)

    def update(self, done: int | None = None, note: str = "", *, force: bool = False) -> None:
        """``done`` units completed (default: one more); ``note``: a short status (a value, a name)."""
        self.done = self.done + 1 if done is None else int(done)
        if self._mark is None:
            self._mark = (self.done, time.perf_counter())
        finished = self.total is not None and self.done >= self.total
        self._write(self.line(note), force=force or finished or self._last_write == float("-inf"))

    @property
    def counting(self) -> bool:
        """Whether a unit has been completed since the start (the rate, hence the ETA, is known
        from the second one on)."""
        return self._mark is not None

    def say(self, text: str) -> None:
        """A message line of the stage (always written, on its own line)."""
        if self.tty and self._width:
            self._write(self.line(), final=True)
        self._write(f"{self.label}: {text}", final=True)

    def close(self, note: str = "") -> None:
        """The last line (with a newline on a terminal)."""
        self._write(self.line(note), final=True)

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.close("done")
        elif self.tty and self._width:
            self._write(self.line("stopped"), final=True)

    # -- waits -------------------------------------------------------------------------------
    @contextlib.contextmanager
    def waiting(self, what: str, key: str | None = None):
        """A blocking call inside the stage (compiling, one long run): on a terminal a ticker
        rewrites the line with the time spent so far once a second; in a log one line before. With
        ``key`` the duration is remembered (``remember``) and an earlier one gives the ETA."""
        expected = recorded(key) if key else None
        began = time.perf_counter()
        wait = Wait()
        compilations = _compilations[0]

        def text():
            spent = time.perf_counter() - began
            eta = "" if expected is None else f", ETA ~{clock(max(expected - spent, 0.0))}"
            return self._wait_line(what, spent, eta)

        stop = threading.Event()

        def tick():
            while not stop.wait(1.0):
                self._write(text(), force=True)

        self._write(text(), force=True)
        ticker = threading.Thread(target=tick, daemon=True) if self.enabled and self.tty else None
        if ticker:
            ticker.start()
        try:
            yield wait
        finally:
            stop.set()
            if ticker:
                ticker.join()
        spent = time.perf_counter() - began
        wait.compiled = _compilations[0] > compilations
        if key and wait.compiled:
            record(key, spent)
        if not self.tty:
            self._write(f"{self.label}: {what}: {clock(spent)}", force=True)

    def _wait_line(self, what: str, spent: float, eta: str) -> str:
        count = ""
        if self.total is not None:
            unit = f" {self.unit}s" if self.unit else ""
            count = f" {self.done}/{self.total}{unit}"
        return f"{self.label}:{count} {what} ... [{clock(spent)}{eta}]"


def stage(label: str, total: int | None = None, **kwargs) -> Progress:
    """``Progress(label, total, ...)``: use it as a context manager."""
    return Progress(label, total, **kwargs)
