"""Lifetime of compiled XLA programs in a long-running process.

XLA:CPU maps every compiled kernel into its own small memory regions (about three per kernel). A
process that compiles many large programs, such as ``jaxflex reproduce`` (sweeps, convergence
studies, several optimizations), can exceed the kernel's per-process limit on memory mappings
(``/proc/sys/vm/max_map_count``, 65530 by default on Linux) long before it runs out of memory; LLVM
then aborts with "Unable to allocate section memory". Long jobs call ``release_compiled`` between
independent stages, or ``release_if_crowded`` (which releases only above half the limit) where the
next stage runs many of the same programs: the mappings of the programs are returned, and a
program needed again is reloaded from the persistent compilation cache (or recompiled). Releasing
does not return everything (a few mappings per program stay). Compiled programs also hold most of
a long job's memory (an optimization study's about 1.3 GB for 20.7 thousand mappings, measured on
2 cores), so the heaviest stages of a long job run in a fresh process of their own
(``run_isolated``), for their peak memory.

``compile_ahead`` starts compiling a jitted function for arguments of given shapes in a background
thread while the caller goes on (XLA releases the interpreter lock while it compiles), and
``call`` runs that program once it is ready, or the function itself when nothing was compiled
ahead for those shapes. The optimization study compiles its gradient (about half a minute cold on 2
cores) while it builds the paper sweep. The program is the one the jitted function would compile
for the same abstract arguments, so the results are identical.
"""
from __future__ import annotations

import gc
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor

import jax
import numpy as np

from jaxflex import heap

_CONFIG = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")

# XLA options of the hot programs, compiled once and then run many times: the engine's rollout
# (thousands of steps, hundreds of runs per study) and the value and gradient of a long optimization
# (hundreds of steps; ``optimize.loop.is_hot``). They override XLA_FLAGS for these programs only.
# Measured cold on 2 cores:
# - LLVM level 1 runs them as fast as level 3 and compiles them sooner (the gradient: 126 ms per
#   step and 42 s to compile, against 147 ms and 50 s at the default level 3); at level 0 (the test
#   suite's global setting, which cuts the compile time of its run-once programs by a third) they
#   would run 2.3-2.9x slower;
# - XLA's classic elemental emitters instead of the fusion emitters compile the gradient sooner.
HOT_LOOP = {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False}

_LEVEL_IN_FLAGS = "xla_backend_optimization_level" in os.environ.get("XLA_FLAGS", "")

# XLA options of the other large programs, compiled once per process and run from a few to hundreds
# of times: the coefficient program of every table build (``linearized.coeffs_many``), the table
# poses, the locked modes at a point, the paper combinations' kinematics (``trajectory``), and the
# full model's stepping program and motor motion (``jaxflex.reference``). The hot programs'
# options, unless XLA_FLAGS choose an optimization level themselves (the test suite's level 0, for
# its run-once programs). Measured cold on 2 cores: the coefficient program (252 poses per chunk)
# compiles in 10.5 s instead of 17.3 s at the default level 3 and runs as fast (127 against 121 ms
# per chunk; at level 0: 7.7 s and 2.2x slower), the locked modes at a point in 4.0 s instead of
# 6.0 s. (The coefficient program measured then took three probes of the whole residual; its terms
# one by one, ``model.residual_term``, compile in about 7 s at these options and run a chunk in
# 32 ms.) On 2026-11-28 (a slow host, three runs each): the full model's stepping program in 17-26 s
# against 21-39 s, as fast per chunk; the kinematics study (``experiments.kinematics.compute``, six
# combination programs) 20.3 s against 27.3 s.
BUILD = None if _LEVEL_IN_FLAGS else HOT_LOOP

# XLA options of large programs run once or twice per call: the full model's start and its outputs
# at the ends (``jaxflex.reference``). LLVM level 0, unless XLA_FLAGS choose a level themselves.
# Measured cold on 2 cores on 2026-11-28 (a slow host, three runs each): the start compiles in
# 8-14 s against 19-32 s, the outputs in 11-18 s against 24-37 s; each runs in milliseconds.
ONCE = None if _LEVEL_IN_FLAGS else {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}


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
    them, returning their memory mappings, and give the freed heap back to the system
    (``heap.trim``: the trimming thread acts only when the resident size grows, and what a section
    freed would otherwise stay resident while a child process runs the next one). Later calls
    recompile, or load from the persistent compilation cache when it is enabled (the CLI enables it)."""
    with _AHEAD_LOCK:
        _AHEAD.clear()
        _AHEAD_OUT.clear()
    jax.clear_caches()
    gc.collect()
    heap.trim()


MAPPING_SHARE = 0.5     # release_if_crowded: the share of the mapping limit above which programs go


def release_if_crowded(share: float = MAPPING_SHARE) -> bool:
    """``release_compiled`` if this process holds more than ``share`` of its mapping limit; returns
    whether it released. Long jobs call it between stages: programs that a later stage runs again
    (the engine's rollouts, the coefficient and full-model programs) stay compiled while there is room,
    instead of being reloaded from the persistent cache (seconds each) or recompiled."""
    count, limit = mapping_count(), mapping_limit()
    if count is None or limit is None or count <= share * limit:
        return False
    release_compiled()
    return True


_AHEAD: dict = {}                   # signature -> Future of a compiled program (compile_ahead)
_AHEAD_LOCK = threading.Lock()
_AHEAD_OUT: dict = {}               # signature -> the program's output shapes (lower_ahead)
# two compilations at a time: XLA compiles without the interpreter lock, so a chain of programs
# lowered one after the other (``lower_ahead``) compiles on both cores
_AHEAD_POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="jaxflex-compile")


_DTYPE_STR: dict = {}


def _aval(x) -> tuple:
    """(shape, dtype string, weak type) of an array, a ShapeDtypeStruct or a scalar. A jax array's
    cached abstract value and a memo of dtype strings take a tenth of the time of ``jax.typeof``
    and ``np.dtype(...).str``: ``call`` takes the signature of thousands of leaves per call of a
    staged gradient's programs."""
    a = getattr(x, "aval", None)
    if a is None:
        a = x if isinstance(x, jax.ShapeDtypeStruct) else jax.typeof(x)
    d = a.dtype
    name = _DTYPE_STR.get(d)
    if name is None:
        name = _DTYPE_STR.setdefault(d, np.dtype(d).str)
    return tuple(a.shape), name, bool(getattr(a, "weak_type", False))


def _signature(fn, args: tuple, static: dict) -> tuple:
    leaves, tree = jax.tree_util.tree_flatten(args)
    return fn, tuple(sorted(static.items())), tree, tuple(_aval(x) for x in leaves)


def compile_ahead(fn, args: tuple, static: dict | None = None) -> Future:
    """Start compiling the jitted ``fn`` for ``args`` (a tuple of pytrees of arrays or
    ``jax.ShapeDtypeStruct``: only shapes and dtypes matter) and the static keyword arguments
    ``static`` in a background thread; returns its Future. ``call`` with arguments of the same
    shapes then uses the program. Compiling the same signature twice starts one compilation."""
    static = dict(static or {})
    key = _signature(fn, args, static)
    with _AHEAD_LOCK:
        if key not in _AHEAD:
            _AHEAD[key] = _AHEAD_POOL.submit(lambda: fn.lower(*args, **static).compile())
        return _AHEAD[key]


def lower_ahead(fn, args: tuple, static: dict | None = None) -> tuple[object, Future]:
    """Lower the jitted ``fn`` for ``args`` and ``static`` (as ``compile_ahead``) in this thread and
    compile it in the background; returns the program's output shapes (a pytree of
    ``jax.ShapeDtypeStruct``) at once and its Future. A chain of programs, each lowered from the
    output shapes of the one before, thus compiles two programs at a time instead of one after the
    other (the design gradient's eight, ``optimize.staged.compile_ahead``)."""
    static = dict(static or {})
    key = _signature(fn, args, static)
    with _AHEAD_LOCK:
        fut, out = _AHEAD.get(key), _AHEAD_OUT.get(key)
    if fut is not None:
        return (out if out is not None else fut.result().out_info), fut
    lowered = fn.lower(*args, **static)
    with _AHEAD_LOCK:
        if key not in _AHEAD:
            _AHEAD[key] = _AHEAD_POOL.submit(lowered.compile)
            _AHEAD_OUT[key] = lowered.out_info
        return lowered.out_info, _AHEAD[key]


def call(fn, args: tuple, static: dict | None = None):
    """``fn(*args, **static)``, through the program ``compile_ahead`` compiled for these shapes if
    there is one (waiting for it to finish), else through ``fn`` itself."""
    static = dict(static or {})
    if _AHEAD:
        with _AHEAD_LOCK:
            fut = _AHEAD.get(_signature(fn, args, static))
        if fut is not None:
            return fut.result()(*args)
    return fn(*args, **static)


def _call_configured(config: dict, trim: bool, fn, args, kwargs):
    if trim:
        heap.start_trimming()
    for name, value in config.items():
        jax.config.update(name, value)
    return fn(*args, **kwargs)


def run_isolated(fn, /, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh Python process (spawned, with this process's float64 and
    persistent-cache settings and its heap trimming, ``jaxflex.heap``), returning its result or
    raising its exception. The child's compiled programs and memory mappings end with it. ``fn``
    must be importable (a module-level function), its arguments and result picklable; the child's
    output goes to this process's stdout/stderr."""
    config = {name: getattr(jax.config, name) for name in _CONFIG}
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_call_configured, config, heap.trimming(), fn, args, kwargs).result()
