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
a long job's memory (docs/performance.md), so the heaviest stages of a long job run in a fresh
process of their own (``run_isolated``), for their peak memory.

``compile_ahead`` starts compiling a jitted function for arguments of given shapes in a background
thread while the caller goes on (XLA releases the interpreter lock while it compiles), and
``call`` runs that program once it is ready, or the function itself when nothing was compiled
ahead for those shapes. The optimization study compiles its gradient while it builds the paper
sweep. The program is the one the jitted function would compile for the same abstract arguments,
so the results are identical. ``submit_chain`` runs a whole chain of such compilations in the
background under a key that ``wait_chain`` waits for (the staged gradient's programs, each lowered
from the output shapes of the one before). The compile threads start on first use.
"""
from __future__ import annotations

import gc
import multiprocessing
import threading
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor

import jax
import numpy as np

from jaxflex.runtime import heap

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
    them, returning their memory mappings, and give the freed heap back to the system
    (``heap.trim``: the trimming thread acts only when the resident size grows, and what a section
    freed would otherwise stay resident while a child process runs the next one). Later calls
    recompile, or load from the persistent compilation cache when it is enabled (the CLI enables it)."""
    global _GENERATION
    with _AHEAD_LOCK:
        _AHEAD.clear()
        _AHEAD_OUT.clear()
        _GENERATION += 1
    jax.clear_caches()
    gc.collect()
    heap.trim()


MAPPING_SHARE = 0.5     # release_if_crowded: the share of the mapping limit above which programs go


def release_if_crowded(share: float = MAPPING_SHARE) -> bool:
    """``release_compiled`` if this process holds more than ``share`` of its mapping limit; returns
    whether it released. Long jobs call it between stages: programs that a later stage runs again
    (the engine's rollouts, the coefficient and full-model programs) stay compiled while there is room,
    instead of being reloaded from the persistent cache (slow for large programs) or recompiled."""
    count, limit = mapping_count(), mapping_limit()
    if count is None or limit is None or count <= share * limit:
        return False
    release_compiled()
    return True


_AHEAD: dict = {}                   # signature -> Future of a compiled program (compile_ahead)
_AHEAD_LOCK = threading.Lock()
_AHEAD_OUT: dict = {}               # signature -> the program's output shapes (lower_ahead)
_POOLS: dict = {}                   # name -> ThreadPoolExecutor, created on first use
_POOLS_LOCK = threading.Lock()
_CHAINS: dict = {}                  # key -> Future of a chain of compilations (submit_chain)
_GENERATION = 0                     # how often release_compiled has dropped the programs


def generation() -> int:
    """A count of ``release_compiled`` calls: a program compiled (or run) at one generation is still
    compiled while the generation is the same."""
    return _GENERATION


def _pool(name: str) -> ThreadPoolExecutor:
    """The thread pool ``name``, created on first use: "compile" runs two compilations at a time (XLA
    compiles without the interpreter lock, so a chain of programs lowered one after the other,
    ``lower_ahead``, compiles on both cores); "chain" runs one chain of lowerings at a time."""
    with _POOLS_LOCK:
        if name not in _POOLS:
            _POOLS[name] = ThreadPoolExecutor(max_workers=2 if name == "compile" else 1,
                                              thread_name_prefix=f"jaxflex-{name}")
        return _POOLS[name]


def submit_chain(key, fn, *args) -> Future:
    """Run ``fn(*args)`` (a chain of ``lower_ahead`` calls) in a background thread under ``key``,
    unless a chain with that key was submitted and not yet waited for; returns its Future."""
    pool = _pool("chain")
    with _AHEAD_LOCK:
        if key not in _CHAINS:
            _CHAINS[key] = pool.submit(fn, *args)
        return _CHAINS[key]


def wait_chain(key) -> None:
    """Wait for the chain submitted under ``key``, if any, and forget it (its programs stay in the
    registry of ahead compilations until ``release_compiled``)."""
    with _AHEAD_LOCK:
        pending = _CHAINS.pop(key, None)
    if pending is not None:
        pending.result()


_DTYPE_STR: dict = {}


def _aval(x) -> tuple:
    """(shape, dtype string, weak type) of an array, a ShapeDtypeStruct or a scalar. A jax array's
    cached abstract value and a memo of dtype strings are much cheaper than ``jax.typeof`` and
    ``np.dtype(...).str``, and ``call`` takes the signature of thousands of leaves per call of a
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
            _AHEAD[key] = _pool("compile").submit(lambda: fn.lower(*args, **static).compile())
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
            _AHEAD[key] = _pool("compile").submit(lowered.compile)
            _AHEAD_OUT[key] = lowered.out_info
        return lowered.out_info, _AHEAD[key]


def call(fn, args: tuple, static: dict | None = None, register: bool = False):
    """``fn(*args, **static)``, through the program ``compile_ahead`` compiled for these shapes if
    there is one (waiting for it to finish), else through ``fn`` itself. With ``register`` such a
    program is compiled here instead, and registered as ``compile_ahead`` registers its own: a
    function whose every call passes ``register`` has one set of programs, and a later
    ``compile_ahead`` for shapes it has run finds the program rather than compiling it again."""
    static = dict(static or {})
    if not (_AHEAD or register):
        return fn(*args, **static)
    key = _signature(fn, args, static)
    mine = None
    with _AHEAD_LOCK:
        fut = _AHEAD.get(key)
        if fut is None and register:
            fut = mine = _AHEAD[key] = Future()
    if fut is None:
        return fn(*args, **static)
    if mine is not None:
        try:
            mine.set_result(fn.lower(*args, **static).compile())
        except BaseException as err:
            with _AHEAD_LOCK:
                _AHEAD.pop(key, None)
            mine.set_exception(err)
            raise
    return fut.result()(*args)


def registered(fn) -> int:
    """The programs of the jitted ``fn`` compiled ahead or registered by ``call`` (every shape)."""
    with _AHEAD_LOCK:
        return sum(1 for key in _AHEAD if key[0] is fn)


def _call_configured(config: dict, trim: bool, fn, args, kwargs):
    if trim:
        heap.start_trimming()
    for name, value in config.items():
        jax.config.update(name, value)
    return fn(*args, **kwargs)


def run_isolated(fn, /, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh Python process (spawned, with this process's float64 and
    persistent-cache settings and its heap trimming, ``jaxflex.runtime.heap``), returning its result or
    raising its exception. The child's compiled programs and memory mappings end with it. ``fn``
    must be importable (a module-level function), its arguments and result picklable; the child's
    output goes to this process's stdout/stderr."""
    return _isolated({}, fn, args, kwargs)


def run_isolated_uncached(fn, /, *args, **kwargs):
    """``run_isolated`` with the persistent compilation cache off in the child: nothing it compiles
    is written to the cache or read from it. For the closed loop's gradient: writing a program to
    the cache serializes it, and for that program (about 26,000 memory mappings) the serialization
    briefly doubled the process's mappings, past the kernel's limit (docs/performance.md)."""
    return _isolated({"jax_enable_compilation_cache": False}, fn, args, kwargs)


def _isolated(overrides: dict, fn, args, kwargs):
    config = {name: getattr(jax.config, name) for name in _CONFIG} | overrides
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_call_configured, config, heap.trimming(), fn, args, kwargs).result()
