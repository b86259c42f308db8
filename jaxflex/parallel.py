"""Independent compiled calls on the host's cores.

An XLA:CPU program of the engine (a table chunk, a rollout) runs mostly on one core, and JAX's
asynchronous dispatch runs queued calls one after another; from a few Python threads (JAX releases
the interpreter lock while a program runs) they run side by side. On a 2-core machine the tables
and rollouts of a large model set (the 200 random models of an uncertainty box) take about 0.7x
the time. Every call is the same program on its own inputs, so the results are identical to the
sequential ones, in the same order.

``JAXFLEX_THREADS`` sets the number of threads (default: the number of cores, at most 4; 1 turns
the pool off).
"""
from __future__ import annotations

import os
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


def host_map(fn: Callable, items: Sequence) -> list:
    """[fn(x) for x in items], each result ready (``jax.block_until_ready``), computed by up to
    ``threads()`` threads. The first item runs alone, so that a program compiles once, not once per
    thread. Exceptions propagate as in the sequential loop (the first failing item's)."""
    items = list(items)
    run = lambda x: jax.block_until_ready(fn(x))
    n = threads()
    if n == 1 or len(items) < 2:
        return [run(x) for x in items]
    first = run(items[0])
    with ThreadPoolExecutor(max_workers=min(n, len(items) - 1)) as pool:
        return [first] + list(pool.map(run, items[1:]))
