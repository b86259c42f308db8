"""Independent compiled calls on the host's cores.

An XLA:CPU program of the engine (a table chunk, a rollout) runs mostly on one core, and JAX's
asynchronous dispatch runs queued calls one after another; from a few Python threads (JAX releases
the interpreter lock while a program runs) they run side by side, so the tables and rollouts of a
large model set (the 200 random models of an uncertainty box) take less wall time than one after
another (docs/performance.md). Every call is the same program on its own inputs, so the results are
identical to the sequential ones, in the same order.

``Beside`` runs one function in a background thread while the caller goes on, with cancellation
when the caller fails.

``JAXFLEX_THREADS`` sets the number of threads (default: the number of cores, at most 4; 1 turns
the pool off).
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

import jax

MAX_THREADS = 4


def threads() -> int:
    """Threads for ``host_map``: ``JAXFLEX_THREADS`` if set (>= 1), else min(cores, MAX_THREADS)."""
    env = os.environ.get("JAXFLEX_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"JAXFLEX_THREADS must be an integer >= 1, got {env!r}") from None
        if n < 1:
            raise ValueError(f"JAXFLEX_THREADS must be an integer >= 1, got {env!r}")
        return n
    return max(1, min(os.cpu_count() or 1, MAX_THREADS))


def host_map(fn: Callable, items: Sequence, parallel: bool = True, first_alone: bool = True) -> list:
    """[fn(x) for x in items], each result ready (``jax.block_until_ready``), computed by up to
    ``threads()`` threads (one with ``parallel=False``). With ``first_alone`` the first item runs
    alone, so that a program compiles once, not once per thread; a caller whose programs are
    compiled already passes False, and every item runs side by side from the start. Exceptions
    propagate as in the sequential loop (the first failing item's)."""
    items = list(items)
    run = lambda x: jax.block_until_ready(fn(x))
    n = threads() if parallel else 1
    if n == 1 or len(items) < 2:
        return [run(x) for x in items]
    if not first_alone:
        with ThreadPoolExecutor(max_workers=min(n, len(items))) as pool:
            return list(pool.map(run, items))
    first = run(items[0])
    with ThreadPoolExecutor(max_workers=min(n, len(items) - 1)) as pool:
        return [first] + list(pool.map(run, items[1:]))


class Beside:
    """``fn(cancelled, *args)`` (``cancelled``: a ``threading.Event``) in a background thread from
    ``with`` entry, for work that goes on beside the caller's (the optimization study evaluates the
    baselines beside its optimizer); ``result()`` waits for it (re-raising its exception). Leaving the
    block by an exception cancels it (``fn`` checks the event between its steps) and waits for it to
    stop."""

    def __init__(self, fn, *args):
        self._fn, self._args = fn, args
        self._cancelled = threading.Event()
        self._pool = None
        self._future = None

    def __enter__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxflex-beside")
        self._future = self._pool.submit(self._fn, self._cancelled, *self._args)
        return self

    def result(self):
        return self._future.result()

    def __exit__(self, kind, value, tb):
        if kind is not None:
            self._cancelled.set()
        self._pool.shutdown(wait=True)
        return False
