"""Lifetime of compiled XLA programs in a long-running process.

XLA:CPU maps every compiled kernel into its own small memory regions (about three per kernel). A
process that compiles many large programs, such as ``jaxflex reproduce`` (sweeps, convergence
studies, several optimizations), can exceed the kernel's per-process limit on memory mappings
(``/proc/sys/vm/max_map_count``, 65530 by default on Linux) long before it runs out of memory; LLVM
then aborts with "Unable to allocate section memory". Long jobs call ``release_compiled`` between
independent stages: the mappings of the programs no longer needed are returned, and a program
needed again is reloaded from the persistent compilation cache (or recompiled). Releasing does not
return everything (a few mappings per program stay), so the heaviest stages of a long job run in a
fresh process of their own (``run_isolated``).
"""
from __future__ import annotations

import gc
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import jax

_CONFIG = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")


def mapping_count() -> int | None:
    """Memory mappings of this process (Linux; None elsewhere)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return None


def mapping_limit() -> int | None:
    """The per-process mapping limit (Linux ``vm.max_map_count``; None elsewhere)."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def release_compiled() -> None:
    """Drop every compiled program JAX holds in this process (``jax.clear_caches``) and collect
    them, returning their memory mappings. Later calls recompile, or load from the persistent
    compilation cache when it is enabled (the CLI enables it)."""
    jax.clear_caches()
    gc.collect()


def _call_configured(config: dict, fn, args, kwargs):
    for name, value in config.items():
        jax.config.update(name, value)
    return fn(*args, **kwargs)


def run_isolated(fn, /, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh Python process (spawned, with this process's float64 and
    persistent-cache settings), returning its result or raising its exception. The child's compiled
    programs and memory mappings end with it. ``fn`` must be importable (a module-level function),
    its arguments and result picklable; the child's output goes to this process's stdout/stderr."""
    config = {name: getattr(jax.config, name) for name in _CONFIG}
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_call_configured, config, fn, args, kwargs).result()
