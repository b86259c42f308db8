"""The design objective's value and gradient through the rollout's stages, model by model.

``Staged`` is a gradient strategy (``optimize.gradient``): instead of differentiating the whole
objective over the K training models as one program, it runs each stage of ``jaxflex.rollout``
(``groups``) as a compiled forward program that also returns what its backward pass needs
(``jax.vjp``), then the backward programs in reverse order. The value and the gradient are those of
the one-program gradient to round-off; the compilation is shorter, and the same programs serve any
number of models, any tf and any scales of the same grid.

How it works, for parameters theta:

- For each training model k, the forward pass runs the stage programs in turn: the first decodes
  the parameters into the design (``DesignObjective.start``) and builds its path and tables; the
  last ends with the model's terms and the pair y_k = [r_k, tau_k] (``DesignObjective.head``).
- ``objective.combine`` depends on model k's energy and dwell terms only through its scaled
  residual r_k (``objective.scaled_residual``), and on its peak torque tau_k only through the
  torque penalty, which is zero while tau_k is within its bound. So one backward pass per model
  (cotangent 1 on r_k) gives dr_k/dtheta, and a second one (on tau_k) runs only for the models
  above their bound. A stage's backward program adds the cotangents of every later stage that
  reads its outputs.
- J and its partial derivatives dJ/dr_k, dJ/dtau_k come from ``objective.combine_scaled`` on the
  K models' values (a small program of its own). The gradient is then
  sum_k dJ/dr_k dr_k/dtheta + dJ/dtau_k dtau_k/dtheta, summed on the host in model order.

The models run side by side on the host's cores (``jaxflex.runtime.threads.host_map``). Each model's
programs and sum are the same whatever the threads, so the result does not depend on them. A
thread holds one model's stored forward pass at a time. The first run of an objective's programs
starts with one model alone (its programs compile once, not once per thread); once a run has
compiled them all, every later one (an optimizer's steps) runs all its models side by side from
the start.

The same traversal of the stages (``_Chain``) runs the programs, times them one at a time
(``stage_times``) and compiles them ahead of time from the shapes alone (``Staged.compile_ahead``).
"""
from __future__ import annotations

import dataclasses
import functools
import time
from concurrent.futures import Future

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from jaxflex import trees
from jaxflex import rollout as rl
from jaxflex.runtime import compiled, options
from jaxflex.runtime.memo import LastCall
from jaxflex.runtime.threads import host_map
from jaxflex.rollout import RolloutState

from .gradient import check_build
from .objective import DesignObjective, combine_scaled


def groups(servo: bool = False) -> tuple[rl.Stage, ...]:
    """The stages of a design's rollout (under a servo with ``servo``) as the staged gradient runs
    them: each stage a program of its own, but the last (the metrics), which runs with the one
    before it, so that the series is never stored between programs."""
    stages = tuple(s for s in rl.STAGES if s.runs_with(servo))
    return stages[:-2] + (rl.compose(stages[-2:]),)


PROGRAMS = tuple(f"forward: {g.name}" for g in groups()) + tuple(f"backward: {g.name}" for g in groups()[::-1])


def _forward(model, inputs, head_data, *, stage, start, head):
    """One stage's forward pass and its vjp: ``start`` (parameters -> first state) before the stage
    if given, ``head`` (terms -> (y, terms)) after it if given."""
    def f(inp):
        state = inp if start is None else start(model, inp)
        out = rl.restrict(stage.fn(model, state), stage.writes)
        return out if head is None else head(out.terms, *head_data)
    return jax.vjp(f, inputs, has_aux=head is not None)


def _total(cotangents: tuple):
    """The cotangent of a stage's outputs: the one given, or the sum, field by field, of the
    cotangents of every later stage that reads them (``RolloutState``s; None: not read there)."""
    if len(cotangents) == 1:
        return cotangents[0]
    fields: dict = {}
    for ct in cotangents:
        for name, value in zip(ct._fields, ct):
            if value is not None:
                fields[name] = value if name not in fields else jax.tree_util.tree_map(jnp.add, fields[name], value)
    return RolloutState(**fields)


def _backward(vjp, cotangents: tuple):
    return vjp(_total(cotangents))


@functools.partial(jax.jit, static_argnames=("torque_weight", "power"))
def _combined(residuals, torques, scales, torque_weight, power):
    """J and (dJ/dr, dJ/dtau) of ``combine_scaled`` at the K models' values (one small program)."""
    return jax.value_and_grad(combine_scaled, argnums=(0, 1))(residuals, torques, scales, torque_weight, power)


class _Programs:
    """The forward and backward programs of the stages, with XLA's options of the process
    (``build="quick"``) or as hot programs (``build="fast"``: ``runtime.options.HOT_LOOP``)."""

    def __init__(self, build: str):
        opts = options.build(build)
        self.forward = jax.jit(_forward, static_argnames=("stage", "start", "head"), compiler_options=opts)
        self.backward = jax.jit(_backward, compiler_options=opts)

    def cache_size(self) -> int:
        return self.forward._cache_size() + self.backward._cache_size()


_PROGRAMS = {"quick": _Programs("quick"), "fast": _Programs("fast")}
RESIDUAL_ROW = (1.0, 0.0)       # the cotangents of the head's outputs (r_k, tau_k)
TORQUE_ROW = (0.0, 1.0)


def cache_size(stages_only: bool = False) -> int:
    """Executables the staged programs compiled in this process (``stages_only``: the stages'
    forward and backward programs alone, without the small program that combines the models)."""
    own = sum(p.cache_size() for p in _PROGRAMS.values())
    return own if stages_only else own + _combined._cache_size()


class _Chain:
    """One model's forward pass through the stage programs (each stored for its backward pass) and
    its backward passes. ``call(fn, args, static)`` runs a program: ``compiled.call`` to compute,
    a timed call (``stage_times``) or ``compiled.lower_ahead`` on shapes (the ahead-of-time chain)."""

    def __init__(self, programs: _Programs, model, params, head_data, call=compiled.call):
        self.programs, self.call, self.groups = programs, call, groups()
        state, self.vjps, self.outputs = RolloutState(), [], []
        last = len(self.groups) - 1
        for i, g in enumerate(self.groups):
            inputs = params if i == 0 else rl.restrict(state, g.reads)
            static = {"stage": g, "start": DesignObjective.start if i == 0 else None,
                      "head": DesignObjective.head if i == last else None}
            out = call(programs.forward, (model, inputs, head_data if i == last else None), static)
            if i == last:
                self.y, vjp, self.terms = out
            else:
                new, vjp = out
                state = rl.merge(state, new, g.writes)
                self.outputs.append(new)
            self.vjps.append(vjp)

    def gradient(self, row):
        """The gradient of r_k (``RESIDUAL_ROW``) or tau_k (``TORQUE_ROW``): the params' cotangent."""
        p, call = self.programs, self.call
        (later,) = call(p.backward, (self.vjps[-1], (row,)))
        pending = [later]                    # cotangents of the later stages' inputs, the last stage's first
        for i in range(len(self.groups) - 2, -1, -1):
            g = self.groups[i]
            cts = []
            for j, ct in enumerate(pending):
                if any(getattr(ct, f) is not None for f in g.writes):
                    cts.append(rl.restrict(ct, g.writes))
                    # consumed: a stage that wrote these fields before this one gets none of it
                    pending[j] = ct._replace(**{f: None for f in g.writes})
            cts = tuple(cts)
            for name in g.writes:
                if getattr(self.outputs[i], name) is not None and all(getattr(ct, name) is None for ct in cts):
                    raise ValueError(f"stage {g.name!r} writes {name!r} but no later stage reads it")
            (ct_in,) = call(p.backward, (self.vjps[i], cts))
            pending.append(ct_in)
        return pending[-1]


def _at(tree, k: int):
    return jax.tree_util.tree_map(lambda a: a[k], tree)


_SLICES = LastCall()        # the per-model slices of the last objective's data
_RAN: dict = {}             # (chain key, gradient) -> compiled.generation() of its last complete run


def _slices(objective: DesignObjective, robots, workspaces, scales) -> list:
    refs = lambda i: (scales.energy[i], scales.dwell_ms[i]) + (
        () if scales.dwell_peak is None else (scales.dwell_peak[i],))
    return [(objective.rollout_model(_at(robots, i), _at(workspaces, i)), refs(i)) for i in range(objective.count)]


def _models(objective: DesignObjective) -> list:
    """Each model's rollout model and references, sliced from the objective's stacked data once per
    set of data (``runtime.memo.LastCall``): an optimizer calls with the same objective at every
    step, and slicing every leaf of 9 models takes dozens of small programs. One set is kept (one
    more copy of the models' workspaces)."""
    return _SLICES(functools.partial(_slices, objective), objective.robots, objective.workspaces, objective.scales)


def _per_model(v, k: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=float), (k,))


def _check(objective) -> DesignObjective:
    if not isinstance(objective, DesignObjective):
        raise TypeError("the staged gradient runs the stages of a design's rollout: it takes a "
                        f"jaxflex.optimize.objective.DesignObjective, got {type(objective).__name__}")
    if objective.workspaces is None:
        raise ValueError("the staged design gradient takes the models' workspace tables "
                         "(study.design_objective builds them)")
    return objective


def _no_args(args) -> None:
    if tuple(args):
        raise TypeError("a DesignObjective holds its data: the staged gradient takes no args")


def _run(build: str, objective: DesignObjective, params, gradient: bool):
    """The K models' forward passes (and backward passes with ``gradient``), then J."""
    objective = _check(objective)
    _wait_for_compilation(build, objective)
    programs = _PROGRAMS[build]
    k = objective.count
    bounds = _per_model(objective.scales.torque_bound, k)
    models = _models(objective)

    def one(i):
        model, head_data = models[i]
        chain = _Chain(programs, model, params, head_data)
        residual, torque = (float(v) for v in np.asarray(chain.y))
        over = torque / bounds[i] - 1.0 > 0.0          # the penalty's excess is positive (``combine_scaled``)
        grads = None
        if gradient:
            row = lambda r: np.asarray(ravel_pytree(chain.gradient(jnp.asarray(r, dtype=jnp.float64)))[0])
            grads = (row(RESIDUAL_ROW), row(TORQUE_ROW) if over else None)
        return residual, torque, chain.terms, grads

    warm = (_key(build, objective), gradient)        # this run's programs: compiled by an earlier run?
    out = host_map(one, range(k), first_alone=_RAN.get(warm) != compiled.generation())
    _RAN[warm] = compiled.generation()
    residuals = jnp.asarray([o[0] for o in out], dtype=jnp.float64)
    torques = jnp.asarray([o[1] for o in out], dtype=jnp.float64)
    value, partials = _combined(residuals, torques, objective.scales, torque_weight=objective.torque_weight,
                                power=objective.power)
    return value, trees.stack([o[2] for o in out]), partials, [o[3] for o in out]


def _abstract(tree, drop_lead: bool = False):
    def one(a):
        shape = tuple(np.shape(a))[1:] if drop_lead else tuple(np.shape(a))
        weak = bool(getattr(a, "weak_type", False)) if isinstance(a, jax.ShapeDtypeStruct) else \
            bool(getattr(jax.typeof(a), "weak_type", False))
        return jax.ShapeDtypeStruct(shape, a.dtype, weak_type=weak)
    return jax.tree_util.tree_map(one, tree)


def _key(build: str, objective) -> tuple:
    """The name of the ahead-of-time chain of an objective's programs (``compiled.submit_chain``):
    a run waits for the chain of its build and objective structure (a program whose compilation has
    not started yet would otherwise compile twice)."""
    return "staged", build, jax.tree_util.tree_structure(objective)


def _wait_for_compilation(build: str, objective) -> None:
    compiled.wait_chain(_key(build, objective))


def _compile_chain(programs: _Programs, model, params, head_data) -> list:
    """Every program lowered in the order a step runs them, each from the output shapes of the ones
    before (the stored forward passes' structure included), and compiled two at a time
    (``compiled.lower_ahead``); returns the compiled programs once all are done."""
    pending = []

    def ahead(fn, args, static=None):
        out, fut = compiled.lower_ahead(fn, args, static)
        pending.append(fut)
        return out

    _Chain(programs, model, params, head_data, call=ahead).gradient(jax.ShapeDtypeStruct((2,), np.float64))
    return [fut.result() for fut in pending]


@dataclasses.dataclass(frozen=True)
class Staged:
    """The staged gradient strategy (module docstring) for a ``DesignObjective``, reverse mode.
    ``build``: "fast" (the hot programs, ``runtime.options.HOT_LOOP``), "quick" (XLA's options of the
    process: quicker to compile) or None (the optimizer chooses by its number of steps,
    ``optimize.gradient.resolved``)."""

    build: str | None = None

    def __post_init__(self):
        check_build(self.build)

    def value(self, objective: DesignObjective, params, args=()):
        """(J, per-model terms) through the staged forward programs alone (no backward pass):
        ``objective(params)`` to round-off."""
        _no_args(args)
        v, terms, _, _ = _run(self.build or "quick", objective, params, gradient=False)
        return v, terms

    def value_and_grad(self, objective: DesignObjective, params, args=()):
        """((J, per-model terms), dJ/dparams), as ``jax.value_and_grad(objective, has_aux=True)``
        gives them, through the staged programs (module docstring)."""
        _no_args(args)
        v, terms, (d_residual, d_torque), grads = _run(self.build or "quick", objective, params, gradient=True)
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

    def compile_ahead(self, objective: DesignObjective, params, args=()) -> Future:
        """Start compiling the staged programs for an objective and parameters of these shapes
        (arrays or ``jax.ShapeDtypeStruct``; ``compiled.compile_ahead``) in a background thread.
        Returns a Future of the list of compiled programs; the runs of an objective of the same
        structure wait for it."""
        _no_args(args)
        o = _check(objective)
        build = self.build or "quick"
        model = o.rollout_model(_abstract(o.robots, True), _abstract(o.workspaces, True))
        model = dataclasses.replace(model, tf=_abstract(o.tf), dwell=_abstract(o.dwell))
        ref = jax.ShapeDtypeStruct((), np.float64)        # a model's reference (``study._canonical`` scales)
        return compiled.submit_chain(_key(build, o), _compile_chain, _PROGRAMS[build], model, _abstract(params),
                                     (ref, ref))

    def stage_times(self, objective: DesignObjective, params, repeats: int = 5) -> dict:
        """Where a step goes: the median wall time [s] of each of its programs (``PROGRAMS``, in the
        order they run) on the first training model, each program run to completion before the next
        starts (``jax.block_until_ready``; in a step the models' programs overlap on the host's
        cores). The first pass, which may compile, is not counted."""
        build = self.build or "quick"
        objective = _check(objective)
        _wait_for_compilation(build, objective)
        model, head_data = _models(objective)[0]
        times: list = []

        def timed(fn, fn_args, static=None):
            t0 = time.perf_counter()
            out = jax.block_until_ready(compiled.call(fn, fn_args, static))
            times.append(time.perf_counter() - t0)
            return out

        runs = []
        for _ in range(int(repeats) + 1):
            times.clear()
            _Chain(_PROGRAMS[build], model, params, head_data, call=timed).gradient(
                jnp.asarray(RESIDUAL_ROW, dtype=jnp.float64))
            runs.append(list(times))
        return dict(zip(PROGRAMS, np.median(np.asarray(runs[1:]), axis=0).tolist()))
