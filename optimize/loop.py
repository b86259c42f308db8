"""optax optimizer loop: jitted update, checkpoint and resume, progress, early stop.

The gradient is computed as the strategy passed to ``minimize`` says (``optimize.gradient``: one
program in reverse mode by default, forward mode, or the design objective's stages,
``optimize.staged.Staged``).

The loop is deterministic for a given start (no randomness is drawn; ``seed`` only perturbs the
start when nonzero). A checkpoint (``.npz``, written atomically) holds the parameters, the optimizer
state, the history and the step; a rerun with the same checkpoint path resumes from it.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import time
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxflex import checks
from jaxflex.progress import Progress

from .config import OptimizerConfig
from .gradient import OneProgram, is_pytree, resolved


class OptResult(NamedTuple):
    """Best parameters, their objective value and aux terms; the history of (step, value, *monitor)
    rows (deterministic), the wall time [s] after each step (``times``), steps run, why it stopped,
    wall time of the loop [s] (compilation included)."""

    params: object
    value: float
    aux: object
    history: list
    steps_run: int
    stopped: str
    wall_s: float
    times: tuple = ()


def _save(path: Path, params, opt_state, history, times, step, best, best_value, stopped: str = ""):
    leaves = {f"p{i}": np.asarray(v) for i, v in enumerate(jax.tree_util.tree_leaves(params))}
    leaves.update({f"s{i}": np.asarray(v) for i, v in enumerate(jax.tree_util.tree_leaves(opt_state))})
    leaves.update({f"b{i}": np.asarray(v) for i, v in enumerate(jax.tree_util.tree_leaves(best))})
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
    width = len(history[0]) if history else 2
    np.savez(tmp, history=np.asarray(history, dtype=float).reshape(-1, width), times=np.asarray(times, dtype=float),
             step=step, best_value=best_value, stopped=stopped, **leaves)
    os.replace(tmp, path)


def _load(path: Path, params, opt_state):
    z = np.load(path)
    rebuild = lambda tree, tag: jax.tree_util.tree_unflatten(
        jax.tree_util.tree_structure(tree),
        [jnp.asarray(z[f"{tag}{i}"]) for i in range(len(jax.tree_util.tree_leaves(tree)))])
    # why the run stopped: "" while it runs (and in checkpoints of older versions)
    stopped = str(z["stopped"]) if "stopped" in z.files else ""
    return (rebuild(params, "p"), rebuild(opt_state, "s"), [tuple(r) for r in z["history"].tolist()],
            z["times"].tolist(), int(z["step"]), rebuild(params, "b"), float(z["best_value"]), stopped)


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """A digest of the library's source (``jaxflex`` with ``jaxflex.optimize``) and of the JAX version:
    a finished optimization is reused (``OptimizerConfig.memo``) only by the code that ran it."""
    import jaxflex
    from jaxflex import optimize

    h = hashlib.sha1(jax.__version__.encode())
    for root in sorted({Path(jaxflex.__file__).parent, Path(optimize.__file__).parent}):
        for src in sorted(root.rglob("*.py")):
            h.update(str(src.relative_to(root)).encode())
            h.update(src.read_bytes())
    return h.hexdigest()


def _is_dataclass_instance(f) -> bool:
    return dataclasses.is_dataclass(f) and not isinstance(f, type) and f.__dataclass_params__.frozen


def fingerprint(f, params0, args, config: "OptimizerConfig", gradient=OneProgram()) -> str:
    """A digest of everything that determines ``minimize(f, params0, args, config, gradient)``'s
    result: the objective (a frozen dataclass instance such as ``objective.DesignObjective``: its
    class, its static fields and every array of its data), the start, every array of ``args``
    (values, shapes and dtypes), the schedule and stopping rules, the gradient strategy, the
    monitor's name (its numbers are in the history) and the code (``code_digest``). Raises
    ValueError for another kind of objective (a function's name does not say what it computes)."""
    if not _is_dataclass_instance(f):
        raise ValueError("a memo of optimizations needs an objective that a frozen dataclass instance describes "
                         f"(e.g. jaxflex.optimize.objective.DesignObjective), got {f!r}")
    h = hashlib.sha1(code_digest().encode())
    c = config
    described = repr(jax.tree_util.tree_structure(f)) if is_pytree(f) else repr(f)
    h.update(repr((type(f).__module__, type(f).__qualname__, described, c.steps, float(c.learning_rate), c.decay,
                   c.patience, float(c.rel_tol), c.target, gradient, getattr(c.monitor, "__module__", None),
                   getattr(c.monitor, "__qualname__", None))).encode())
    for tree in (f if is_pytree(f) else None, params0, args):
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        h.update(repr(treedef).encode())
        for leaf in leaves:
            a = np.ascontiguousarray(np.asarray(leaf))
            h.update(repr((a.shape, a.dtype.str)).encode())
            h.update(a.tobytes())
    return h.hexdigest()


DECAY_FLOOR = 0.1     # the cosine schedule ends at this fraction of the learning rate
WARMUP = 0.1          # ... and starts with a linear warm-up over this fraction of the steps


def _optimizer():
    """Adam's update direction after gradient clipping; the (traced) learning rate scales it in
    ``_update``, so a new rate or schedule length reuses the compiled step."""
    return optax.chain(optax.clip_by_global_norm(10.0), optax.scale_by_adam())


def schedule(steps: int, learning_rate: float, decay: bool) -> optax.Schedule:
    """The learning-rate schedule (an optax schedule of the 0-based update index): constant, or with
    ``decay`` a linear warm-up over the first WARMUP of ``steps`` (Adam's first steps move every
    parameter by the full rate, whatever its gradient) from rate / warm-up steps to the rate,
    followed by a cosine decay that reaches DECAY_FLOOR of the rate at index ``steps`` (one past the
    last update)."""
    if not decay or steps <= 0:
        return optax.constant_schedule(learning_rate)
    warm = max(1, int(round(WARMUP * steps)))
    return optax.join_schedules(
        [optax.linear_schedule(learning_rate / warm, learning_rate, warm - 1),
         optax.cosine_decay_schedule(learning_rate, max(1, steps - warm), alpha=DECAY_FLOOR)], [warm])


def learning_rate_at(step: int, steps: int, learning_rate: float, decay: bool) -> float:
    """The learning rate [-] of update ``step`` (0-based) under ``schedule(steps, learning_rate, decay)``."""
    return float(schedule(steps, learning_rate, decay)(step))


def value_and_grad(f, params, args=(), gradient=OneProgram()):
    """((value, aux), gradient) of f(params, *args) -> (value, aux): what the optimizer runs at every
    step, as the ``gradient`` strategy computes it (``optimize.gradient``; its build resolved by the
    strategy's own default when None). Calls with the same objective structure and argument shapes
    reuse one compilation (e.g. a sweep over tf or payloads, a benchmark or a gradient check of the
    optimizer's own gradient)."""
    return resolved(gradient, 0).value_and_grad(f, params, args)


@jax.jit
def _adam_step(params, state, grad, learning_rate):
    """One Adam update from a gradient (a small program shared by every objective of the same
    parameter shapes); the traced learning rate scales the direction."""
    with jax.numpy_dtype_promotion("standard"):     # optax mixes Python floats and int32 counts
        direction, state = _optimizer().update(grad, state, params)
    step = jax.tree_util.tree_map(lambda u: -learning_rate * u, direction)
    return optax.apply_updates(params, step), state


def _compile_key(f, params, args, gradient) -> str:
    """Name of the gradient program for the progress ETA memory: the objective, the strategy and the
    argument shapes (a program of other shapes compiles in another time)."""
    shapes = [np.shape(a) for a in jax.tree_util.tree_leaves((f, params, args))]
    name = type(f).__qualname__ if _is_dataclass_instance(f) else getattr(f, "__qualname__", repr(f))
    digest = hashlib.sha1(repr((name, gradient, shapes)).encode()).hexdigest()[:12]
    return f"compile gradient {digest}"


def _update(params, state, args, learning_rate, *, f, gradient):
    """One optimizer step: the objective's value and gradient, then Adam."""
    (value, aux), grad = gradient.value_and_grad(f, params, args)
    new_params, state = _adam_step(params, state, grad, learning_rate)
    return new_params, state, value, aux


def minimize(f: Callable, params0, args: tuple = (), config: OptimizerConfig = OptimizerConfig(),
             gradient=OneProgram()) -> OptResult:
    """Minimize f(params, *args) -> (value, aux) with Adam, as ``config`` says (``OptimizerConfig``),
    the gradient computed as the strategy ``gradient`` says (``optimize.gradient``; a build of None
    is chosen by the number of steps, ``gradient.resolved``).

    f is a pytree whose data are traced (``objective.DesignObjective``) or a function; ``args`` are
    traced (pytrees of arrays): reuse the same objective structure with new data or ``args`` values
    to avoid recompiling. Returns the best parameters seen (``OptResult``)."""
    c = config
    if not isinstance(c, OptimizerConfig):
        raise TypeError(f"config must be an OptimizerConfig, got {type(c).__name__}")
    checkpoint, progress, label, monitor, target = c.checkpoint, c.progress, c.label, c.monitor, c.target
    decay, rel_tol = c.decay, c.rel_tol
    learning_rate, steps, patience = c.learning_rate, c.steps, c.patience
    checks.positive("learning_rate", learning_rate)
    steps = checks.count("steps", steps, 0)
    patience = checks.count("patience", patience, 1)
    checks.nonnegative("rel_tol", rel_tol)
    if target is not None and not np.isnan(target):
        float(target)
    gradient = resolved(gradient, steps)
    update = functools.partial(_update, f=f, gradient=gradient)
    params, state = params0, _optimizer().init(params0)
    history, times, step, best, best_value, best_aux = [], [], 0, params0, np.inf, None
    ckpt = Path(checkpoint) if checkpoint else None
    memo = Path(c.memo) / f"{fingerprint(f, params0, args, c, gradient)}.npz" if c.memo else None
    recalled = memo is not None and memo.exists()
    resumed = recalled or (ckpt is not None and ckpt.exists())
    stopped = "steps"
    if resumed:
        params, state, history, times, step, best, best_value, saved = _load(memo if recalled else ckpt, params0,
                                                                            state)
        stopped = saved if recalled else stopped          # a finished run's reason; a checkpoint runs on
    bar = Progress(label, total=steps, unit="step", enabled=progress, start=step)
    if recalled:
        bar.say(f"the same optimization finished before ({memo.name[:12]}): {step} steps, best {best_value:.4g}")
    elif resumed:
        bar.say(f"resumed at step {step} (best {best_value:.4g})")
    offset = times[-1] if times else 0.0
    started, last_gain = time.perf_counter(), step
    rate = schedule(steps, float(learning_rate), decay)        # built once, evaluated per step
    while step < steps and not recalled:
        # always a strongly typed float64 scalar: a change of type would retrace the update
        lr = jnp.asarray(rate(step), dtype=jnp.float64)
        if not bar.counting:       # the first step of this run: compiles the gradient unless done before
            with bar.waiting(f"step {step + 1} (compiling the gradient unless cached)",
                             key=_compile_key(f, params, args, gradient)):
                new_params, state, value, aux = update(params, state, args, lr)
                value = float(value)
        else:
            new_params, state, value, aux = update(params, state, args, lr)
            value = float(value)
        if not np.isfinite(value):
            raise FloatingPointError(f"{label}: non-finite objective at step {step}")
        extra = () if monitor is None else tuple(float(v) for v in np.ravel(np.asarray(monitor(aux))))
        history.append((step, value) + extra)
        times.append(offset + time.perf_counter() - started)
        if value < best_value:
            if value < best_value - rel_tol * max(1.0, abs(best_value)):
                last_gain = step
            best, best_value, best_aux = params, value, aux
        params, step = new_params, step + 1
        bar.update(step, f"objective {value:.4g}, best {best_value:.4g}")
        if ckpt and (step % 10 == 0 or step == steps):
            _save(ckpt, params, state, history, times, step, best, best_value)
        if target is not None and best_value < target:
            stopped = "target"
            break
        if step - last_gain > patience:
            stopped = "plateau"
            break
    bar.close(f"stopped: {stopped}, best {best_value:.4g}")
    if ckpt:
        _save(ckpt, params, state, history, times, step, best, best_value, stopped)
    if memo is not None and not recalled:
        memo.parent.mkdir(parents=True, exist_ok=True)
        _save(memo, params, state, history, times, step, best, best_value, stopped)
    if best_aux is None:                       # resumed at the end: evaluate the best once
        (best_value, best_aux), _ = gradient.value_and_grad(f, best, args)
        best_value = float(best_value)
    return OptResult(best, best_value, best_aux, history, step, stopped, time.perf_counter() - started, times)
