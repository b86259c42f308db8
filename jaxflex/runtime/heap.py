"""The process's malloc heap: return the memory freed by XLA's buffers to the system.

XLA:CPU allocates every buffer of a program run with the C library's ``malloc`` and frees it at
the end. In a long run (an optimization study: thousands of program runs from several threads,
plus compilations) glibc keeps most of the freed memory in its per-thread arenas instead of
returning it, so the resident size grows far beyond what is live: at the end of a cold ``jaxflex
optimize --payload 6 --tf 0.43``, 2.9 GB resident for 0.19 GB of live arrays, 1.0 GB after one
``malloc_trim(0)``. ``start_trimming`` runs a daemon thread that trims the heap whenever the
resident size has grown by ``slack`` bytes since its last trim (checked every ``period`` seconds).
It changes where memory sits, never a result. The command-line entry points start it (the test
suite's workers do not); a library user may call it too. Linux with glibc only (elsewhere it does
nothing).

The cost is kernel time: returned pages are faulted in again when the next buffers need them. Measured
cold on 2 cores (2026-11-27): ``jaxflex optimize --payload 6 --tf 0.43`` with a 128 MiB slack trims 138
times, peak RSS 2.5-2.8 GB (3.8-4.1 GB untrimmed), 83 s of system time; with 512 MiB, 25 trims, 2.96
GB, 61 s; ``jaxflex reproduce``: 367 s of system time against 232 s untrimmed, peak RSS 3.0 GB against
3.8 GB, 21:53 against 21:08 of wall time.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import threading
import time

# No trimming below this resident size [bytes]: an optimizer's steps free and reallocate a few hundred
# MB of XLA buffers each, and trimming them at every step costs the page faults of refilling them
# (the design gradient over the 9 box models, 10 steps on 2 cores, 2026-11-27: 1.25-1.28 s per step,
# 0.1-0.2 million page faults and 1.97 GB resident with this floor; 1.34-1.39 s, 0.5-0.6 million and
# 1.61-1.67 GB trimming from any size).
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
