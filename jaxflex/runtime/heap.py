"""The process's malloc heap: return the memory freed by XLA's buffers to the system.

XLA:CPU allocates every buffer of a program run with the C library's ``malloc`` and frees it at
the end. In a long run (an optimization study: thousands of program runs from several threads,
plus compilations) glibc keeps most of the freed memory in its per-thread arenas instead of
returning it, so the resident size grows far beyond what is live, and one ``malloc_trim(0)`` gives
most of the difference back (docs/performance.md). ``start_trimming`` runs a daemon thread that
trims the heap whenever the resident size has grown by ``slack`` bytes since its last trim (checked
every ``period`` seconds). It changes where memory sits, never a result. The command-line entry
points start it (the test suite's workers do not); a library user may call it too. Linux with glibc
only (elsewhere it does nothing).

The cost is kernel time: returned pages are faulted in again when the next buffers need them. A
smaller ``slack`` trims more often, for a lower peak resident size and more system time; trimming
lowers a long run's peak resident size at a small cost in wall time (docs/performance.md).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import threading
import time

# No trimming below this resident size [bytes]: an optimizer's steps free and reallocate large XLA
# buffers at every step, and trimming them each time costs the page faults of refilling them, which
# makes the steps slower (docs/performance.md).
TRIM_ABOVE = 2 * 2**30

_LOCK = threading.Lock()
_THREAD: threading.Thread | None = None
_LIBC = None


def _libc():
    global _LIBC
    if _LIBC is None:
        _LIBC = False
        if sys.platform.startswith("linux"):
            try:
                lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                lib.malloc_trim.argtypes, lib.malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
                _LIBC = lib
            except (OSError, AttributeError):       # not glibc (musl has no malloc_trim)
                pass
    return _LIBC


def available() -> bool:
    """Whether this process can trim its heap (Linux with glibc)."""
    return bool(_libc())


def resident_bytes() -> int | None:
    """This process's resident set size [bytes] (Linux; None elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def trim() -> bool:
    """Return the heap's free memory to the system now (glibc ``malloc_trim(0)``); False where that
    is not available."""
    lib = _libc()
    if not lib:
        return False
    lib.malloc_trim(0)
    return True


def start_trimming(period: float = 1.0, slack: int = 128 * 2**20, above: int = TRIM_ABOVE) -> bool:
    """Start (once per process) the daemon thread that trims the heap when the resident size is
    above ``above`` [bytes] and has grown by ``slack`` [bytes] since the last trim, checking every
    ``period`` [s]. Returns whether it runs (False where trimming is not available or
    ``JAXFLEX_HEAP_TRIM=0``)."""
    global _THREAD
    if os.environ.get("JAXFLEX_HEAP_TRIM", "1") == "0" or not available() or resident_bytes() is None:
        return False
    with _LOCK:
        if _THREAD is None:
            _THREAD = threading.Thread(target=_watch, args=(float(period), int(slack), int(above)),
                                       name="jaxflex-heap-trim", daemon=True)
            _THREAD.start()
    return True


def trimming() -> bool:
    """Whether the trimming thread runs in this process."""
    return _THREAD is not None


def should_trim(now: int, floor: int, slack: int, above: int) -> bool:
    """The trimming thread's rule: trim when the resident size ``now`` [bytes] is above ``above`` and
    has grown by more than ``slack`` since ``floor`` (the size after the last trim, or the lowest
    seen since)."""
    return now > max(floor + slack, above)


def _watch(period: float, slack: int, above: int) -> None:
    floor = resident_bytes() or 0
    while True:
        time.sleep(period)
        now = resident_bytes() or 0
        if should_trim(now, floor, slack, above):
            trim()
            floor = resident_bytes() or 0
        else:
            floor = min(floor, now)
