"""The design objective's value and gradient as a chain of small compiled programs, model by model.

``loop.value_and_grad`` (reverse mode) on ``objective.DesignObjective`` runs ``value_and_grad`` here
instead of differentiating the whole objective over the K training models as one program. The
value and the gradient are the same to round-off. The compilation is shorter, and the same
programs serve any number of models, any tf and any scales of the same grid.

How it works, for parameters theta:

- For each training model k, the forward pass runs as four programs. Each returns, beside its
  outputs, what its backward pass needs (``jax.vjp``):
  0. the design's path, its tables interpolated from the model's workspace, the motion samples;
  1. the rollout's first pass (``engine.first_stage``);
  2. the full model's remainder at the first pass's sites (``simulate.remainders``);
  3. the second pass (``engine.second_stage``), the model's terms and metrics
     (``objective.series_terms``).
- ``objective.combine`` depends on model k's energy and dwell terms only through its scaled
  residual r_k (``objective.scaled_residual``), and on its peak torque tau_k only through the
  torque penalty, which is zero while tau_k is within its bound. So one backward pass per model
  (cotangent 1 on r_k) gives dr_k/dtheta, and a second one (on tau_k) runs only for the models
  above their bound.
- J and its partial derivatives dJ/dr_k, dJ/dtau_k come from ``objective.combine_scaled`` on the
  K models' values (a small program of its own). The gradient is then
  sum_k dJ/dr_k dr_k/dtheta + dJ/dtau_k dtau_k/dtheta, summed on the host in model order.

The models run side by side on the host's cores (``jaxflex.parallel.host_map``). Each model's
programs and sum are the same whatever the threads, so the result does not depend on them. A
thread holds one model's stored forward pass at a time (about 0.18 GB on the default grid).

Measured on the studies' design gradient over the 9 box models (6 kg, tf = 0.43 s, default grid,
hot programs, XLA's default options, 2 cores, no compilation cache):
- compile: 32.8-36.9 s, against 63.8-68.5 s for the one-program gradient;
- a step with every model within its torque bound (the 6 kg study's 50 steps): 1.04-1.23 s,
  against 1.41-1.73 s; with 6 of the 9 models above it (a second backward pass each): 1.9-2.3 s,
  against 1.49 s;
- the same value to 2e-11 and gradient to 3e-10 relative (the round-off of two different
  programs, amplified by the log and the power mean of order 8).
"""
from __future__ import annotations

import functools
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from jaxflex import compiled, trees
from jaxflex.designs import design_path
from jaxflex.engine import first_stage, second_stage
from jaxflex.parallel import host_map
from jaxflex.profiles import shaped
from jaxflex.simulate import motion_samples, remainders
from jaxflex.workspace import workspace_tables

from .objective import combine_scaled, decode, scaled_residual, series_terms


def _path_stage(params, robot, cycle, workspace, tf, grid, blend, order):
    x = decode(cycle, params)
    path = design_path(cycle, x, blend)
    return workspace_tables(workspace, robot, path), motion_samples(path.length, shaped(x.coef, order), tf, grid)


def _forward_path(params, robot, cycle, workspace, tf, grid, blend, order):
    return jax.vjp(lambda p: _path_stage(p, robot, cycle, workspace, tf, grid, blend, order), params)


def _forward_first(tables, samples, tf, grid):
    return jax.vjp(lambda t, s: first_stage(t, s, tf, grid), tables, samples)


def _forward_remainder(robot, sites):
    return jax.vjp(lambda s: remainders(robot, s), sites)


def _forward_last(tables, prep, r_all, samples, tf, dwell, energy_ref, dwell_ref, grid):
    def last(t, p, r, s):
        terms = series_terms(second_stage(t, p, r, s, tf, dwell, grid))
        return jnp.stack([scaled_residual(terms, energy_ref, dwell_ref), terms["torque"]]), terms
    return jax.vjp(last, tables, prep, r_all, samples, has_aux=True)


def _backward(vjp, cotangent):
    return vjp(cotangent)


def _backward_sum(vjp, a, b):
    """The backward pass of a stage whose outputs two later stages use: their cotangents added."""
    return vjp(jax.tree_util.tree_map(jnp.add, a, b))


@functools.partial(jax.jit, static_argnames=("torque_weight", "power"))
def _combined(residuals, torques, scales, torque_weight, power):
    """J and (dJ/dr, dJ/dtau) of ``combine_scaled`` at the K models' values (one small program)."""
    return jax.value_and_grad(combine_scaled, argnums=(0, 1))(residuals, torques, scales, torque_weight, power)


class _Programs:
    """The jitted stages, with XLA's options of the process or as hot programs
    (``compiled.HOT_LOOP``), as ``loop.value_and_grad``'s two programs."""

    def __init__(self, hot: bool):
        options = compiled.HOT_LOOP if hot else None
        jit = lambda fn, *static: jax.jit(fn, static_argnames=static, compiler_options=options)
        self.path = jit(_forward_path, "grid", "blend", "order")
        self.first = jit(_forward_first, "grid")
        self.remainder = jit(_forward_remainder)
        self.last = jit(_forward_last, "grid")
        self.back = jit(_backward)
        self.back_sum = jit(_backward_sum)

    def cache_size(self) -> int:
        return sum(p._cache_size() for p in (self.path, self.first, self.remainder, self.last, self.back,
                                             self.back_sum))


_PROGRAMS = {False: _Programs(False), True: _Programs(True)}
RESIDUAL_ROW = (1.0, 0.0)       # the cotangents of the last stage's outputs (r_k, tau_k)
TORQUE_ROW = (0.0, 1.0)


def cache_size() -> int:
    """Executables the staged programs compiled in this process."""
    return sum(p.cache_size() for p in _PROGRAMS.values()) + _combined._cache_size()


def _unpack(args):
    robots, cycle, tf, dwell, scales, workspaces = args
    if workspaces is None:
        raise ValueError("the staged design gradient takes the models' workspace tables "
                         "(study.design_objective builds them)")
    k = np.shape(robots.payload)[0] if np.ndim(robots.payload) else None
    if k is None:
        raise ValueError("the design objective takes the models stacked along a leading axis (stack_robots)")
    return robots, cycle, tf, dwell, scales, workspaces, k


def _at(tree, k: int):
    return jax.tree_util.tree_map(lambda a: a[k], tree)


_SLICES: list = []          # [(robots, workspaces, scales), per-model slices] of the last call
_SLICES_LOCK = threading.Lock()


def _models(robots, workspaces, scales, k: int) -> list:
    """Each model's robot, workspace and references, sliced from the stacked arguments once per
    set of arguments: an optimizer calls with the same ones at every step, and slicing every leaf
    of 9 models took 56-79 ms a step (34 small programs). One set is kept (one more copy of the
    models' workspaces, 8 MB per model on the default cycle)."""
    with _SLICES_LOCK:
        if _SLICES and all(a is b for a, b in zip(_SLICES[0], (robots, workspaces, scales))):
            return _SLICES[1]
        slices = [(_at(robots, i), _at(workspaces, i), scales.energy[i], scales.dwell_ms[i]) for i in range(k)]
        _SLICES[:] = [(robots, workspaces, scales), slices]
        return slices


def _per_model(v, k: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=float), (k,))


class _Model:
    """One model's forward pass (stored for the backward) and its backward passes."""

    def __init__(self, programs: _Programs, f, params, robot, cycle, workspace, tf, dwell, energy_ref, dwell_ref,
                 call=compiled.call):
        p = programs
        self.programs, self.call = programs, call
        (tables, samples), self.v_path = call(p.path, (params, robot, cycle, workspace, tf),
                                              {"grid": f.grid, "blend": f.blend, "order": f.order})
        (prep, sites), self.v_first = call(p.first, (tables, samples, tf), {"grid": f.grid})
        r_all, self.v_remainder = call(p.remainder, (robot, sites))
        y, self.v_last, self.terms = call(p.last, (tables, prep, r_all, samples, tf, dwell, energy_ref, dwell_ref),
                                          {"grid": f.grid})
        self.residual, self.torque = (float(v) for v in np.asarray(y))

    def gradient(self, row) -> np.ndarray:
        """The gradient of r_k (``RESIDUAL_ROW``) or tau_k (``TORQUE_ROW``), flattened."""
        p, call = self.programs, self.call
        c_tables, c_prep, c_r, c_samples = call(p.back, (self.v_last, jnp.asarray(row, dtype=jnp.float64)))
        (c_sites,) = call(p.back, (self.v_remainder, c_r))
        c_tables1, c_samples1 = call(p.back, (self.v_first, (c_prep, c_sites)))
        (g,) = call(p.back_sum, (self.v_path, (c_tables, c_samples), (c_tables1, c_samples1)))
        return np.asarray(ravel_pytree(g)[0])


def _run(f, params, args, hot: bool, gradient: bool):
    """The K models' forward passes (and backward passes with ``gradient``), then J."""
    robots, cycle, tf, dwell, scales, workspaces, k = _unpack(args)
    _wait_for_compilation(f, hot)
    programs = _PROGRAMS[bool(hot)]
    bounds = _per_model(scales.torque_bound, k)

    models = _models(robots, workspaces, scales, k)

    def one(i):
        robot, workspace, energy_ref, dwell_ref = models[i]
        m = _Model(programs, f, params, robot, cycle, workspace, tf, dwell, energy_ref, dwell_ref)
        over = m.torque / bounds[i] - 1.0 > 0.0          # the penalty's excess is positive (``combine_scaled``)
        grads = None
        if gradient:
            grads = (m.gradient(RESIDUAL_ROW), m.gradient(TORQUE_ROW) if over else None)
        return m.residual, m.torque, m.terms, grads

    out = host_map(one, range(k))
    residuals = jnp.asarray([o[0] for o in out], dtype=jnp.float64)
    torques = jnp.asarray([o[1] for o in out], dtype=jnp.float64)
    value, partials = _combined(residuals, torques, scales, torque_weight=f.torque_weight, power=f.power)
    return value, trees.stack([o[2] for o in out]), partials, [o[3] for o in out]


def value(f, params, args, *, hot: bool = False):
    """(J, per-model terms) of the design objective ``f`` through the staged forward programs
    alone (no backward pass): ``f(params, *args)`` to round-off."""
    v, terms, _, _ = _run(f, params, args, hot, gradient=False)
    return v, terms


def value_and_grad(f, params, args, *, hot: bool = False):
    """((J, per-model terms), dJ/dparams) of the design objective ``f`` (``objective.DesignObjective``)
    at ``params`` with its ``args`` (``study.design_objective``), as ``jax.value_and_grad(f,
    has_aux=True)`` gives them, through the staged programs (module docstring)."""
    v, terms, (d_residual, d_torque), grads = _run(f, params, args, hot, gradient=True)
    d_residual, d_torque = np.asarray(d_residual), np.asarray(d_torque)
    flat0, unravel = ravel_pytree(params)
    total = np.zeros(np.shape(flat0))
    for i, (g_residual, g_torque) in enumerate(grads):
        total = total + d_residual[i] * g_residual
        if g_torque is not None:
            total = total + d_torque[i] * g_torque
        elif d_torque[i] != 0.0:
            raise RuntimeError(f"model {i}: the torque penalty has a gradient but the torque is within its bound")
    return (v, terms), unravel(jnp.asarray(total, dtype=flat0.dtype))


STAGES = ("forward: path and tables", "forward: first pass", "forward: remainder", "forward: last pass",
          "backward: last pass", "backward: remainder", "backward: first pass", "backward: path and tables")


def stage_times(f, params, args, *, hot: bool = False, repeats: int = 5) -> dict:
    """Where a step of ``value_and_grad`` goes: the median wall time [s] of each of its programs
    (``STAGES``, in the order they run) on the first training model, each program run to completion
    before the next starts (``jax.block_until_ready``; in a step the models' programs overlap on the
    host's cores). The first pass, which may compile, is not counted."""
    robots, cycle, tf, dwell, scales, workspaces, k = _unpack(args)
    _wait_for_compilation(f, hot)
    robot, workspace, energy_ref, dwell_ref = _models(robots, workspaces, scales, k)[0]
    times: list = []

    def timed(fn, fn_args, static=None):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled.call(fn, fn_args, static))
        times.append(time.perf_counter() - t0)
        return out

    runs = []
    for _ in range(int(repeats) + 1):
        times.clear()
        _Model(_PROGRAMS[bool(hot)], f, params, robot, cycle, workspace, tf, dwell, energy_ref, dwell_ref,
               call=timed).gradient(RESIDUAL_ROW)
        runs.append(list(times))
    return dict(zip(STAGES, np.median(np.asarray(runs[1:]), axis=0).tolist()))


# compile_ahead: chains of ahead compilations, one per objective and program set, that value_and_grad
# waits for (a stage whose compilation has not started yet would otherwise compile twice)
_CHAINS: dict = {}
_CHAINS_LOCK = threading.Lock()
_CHAIN_POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxflex-staged")


def _wait_for_compilation(f, hot: bool) -> None:
    """Wait for the chains compiling f's programs; they are then forgotten here (the programs stay
    in ``compiled``'s registry until ``compiled.release_compiled``)."""
    with _CHAINS_LOCK:
        keys = [key for key in _CHAINS if key[0] == f and key[1] == bool(hot)]
        pending = [_CHAINS.pop(key) for key in keys]
    for fut in pending:
        fut.result()


def _abstract(tree, drop_lead: bool = False):
    def one(a):
        shape = tuple(np.shape(a))[1:] if drop_lead else tuple(np.shape(a))
        weak = bool(getattr(a, "weak_type", False)) if isinstance(a, jax.ShapeDtypeStruct) else \
            bool(getattr(jax.typeof(a), "weak_type", False))
        return jax.ShapeDtypeStruct(shape, a.dtype, weak_type=weak)
    return jax.tree_util.tree_map(one, tree)


def compile_ahead(f, params, args, *, hot: bool = False) -> Future:
    """Start compiling the staged programs for parameters and arguments of these shapes (arrays or
    ``jax.ShapeDtypeStruct``; ``compiled.compile_ahead``) in a background thread. Returns a Future
    of the list of compiled programs; ``value_and_grad`` with the same f and hot waits for it."""
    robots, cycle, tf, dwell, scales, workspaces, _ = _unpack(args)
    robot, workspace = _abstract(robots, True), _abstract(workspaces, True)
    params, tf, dwell = _abstract(params), _abstract(tf), _abstract(dwell)
    ref = jax.ShapeDtypeStruct((), np.float64)        # a model's reference (``study._canonical`` scales)
    key = (f, bool(hot), repr(jax.tree_util.tree_structure((params, robot, workspace))) + repr(
        [(x.shape, x.dtype) for x in jax.tree_util.tree_leaves((params, robot, workspace))]))
    with _CHAINS_LOCK:
        if key not in _CHAINS:
            _CHAINS[key] = _CHAIN_POOL.submit(_compile_chain, _PROGRAMS[bool(hot)], f, params, robot, cycle,
                                              workspace, tf, dwell, ref)
        return _CHAINS[key]


def _compile_chain(p: _Programs, f, params, robot, cycle, workspace, tf, dwell, ref) -> list:
    """Every stage lowered in the order ``value_and_grad`` runs them, each from the output shapes of
    the ones before (the stored forward passes' structure included), and compiled two at a time
    (``compiled.lower_ahead``); returns the compiled programs once all are done."""
    pending = []

    def ahead(fn, args, static=None):
        out, fut = compiled.lower_ahead(fn, args, static)
        pending.append(fut)
        return out

    (tables, samples), v_path = ahead(p.path, (params, robot, cycle, workspace, tf),
                                      {"grid": f.grid, "blend": f.blend, "order": f.order})
    (prep, sites), v_first = ahead(p.first, (tables, samples, tf), {"grid": f.grid})
    r_all, v_remainder = ahead(p.remainder, (robot, sites))
    y, v_last, _ = ahead(p.last, (tables, prep, r_all, samples, tf, dwell, ref, ref), {"grid": f.grid})
    c_tables, c_prep, c_r, c_samples = ahead(p.back, (v_last, jax.ShapeDtypeStruct((2,), np.float64)))
    (c_sites,) = ahead(p.back, (v_remainder, c_r))
    c_tables1, c_samples1 = ahead(p.back, (v_first, (c_prep, c_sites)))
    ahead(p.back_sum, (v_path, (c_tables, c_samples), (c_tables1, c_samples1)))
    return [fut.result() for fut in pending]
