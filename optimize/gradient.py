"""How the optimizer computes an objective's value and gradient: a strategy passed in as a value.

A strategy has ``value_and_grad(objective, params, args=()) -> ((value, aux), gradient)`` and
``compile_ahead(objective, params, args=()) -> Future``, and a ``build``: "fast" (hot programs,
compiled with ``jaxflex.runtime.options.HOT_LOOP``: slower to compile, faster to run), "quick" (XLA's
options of the process: quicker to compile) or None (``resolved`` chooses by the number of steps).

- ``OneProgram`` (here): ``jax.value_and_grad`` of the whole objective as one compiled program, in
  reverse mode or, with ``mode="forward"``, forward mode (``value_and_grad_fwd``: a vmapped
  ``jax.jvp`` per parameter, no stored trajectory; cheaper only for two or three parameters);
- ``optimize.staged.Staged``: the design objective's rollout stage by stage, model by model.

The objective is ``objective(params, *args) -> (value, aux)``: a pytree (``objective.DesignObjective``,
``objective.LawObjective``: their data are traced, their configuration is static) or a plain
function (static). Calls with the same objective structure and argument shapes reuse one compiled
program.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from jaxflex.runtime import compiled, options

HOT_STEPS = 20     # optimizations of at least this many steps run the fast build


def resolved(gradient, steps: int):
    """The strategy with its build chosen if it has none: "fast" for an optimization of at least
    ``HOT_STEPS`` steps (it runs many times), else "quick" (smoke runs, gradient checks)."""
    if gradient.build is not None:
        return gradient
    return dataclasses.replace(gradient, build="fast" if steps >= HOT_STEPS else "quick")


def check_build(build) -> None:
    """ValueError unless ``build`` is None or one of ``runtime.options.BUILDS``."""
    if build is not None and build not in options.BUILDS:
        raise ValueError(f"build must be None or one of {options.BUILDS}, got {build!r}")


def value_and_grad_fwd(f: Callable) -> Callable:
    """(value, aux), gradient of a scalar function f(params) -> (value, aux) by forward mode."""
    def vg(params):
        flat, unravel = ravel_pytree(params)
        g = lambda v: f(unravel(v))
        basis = jnp.eye(flat.shape[0], dtype=flat.dtype)
        primal, tangent = jax.vmap(lambda t: jax.jvp(g, (flat,), (t,)))(basis)
        value, aux = jax.tree_util.tree_map(lambda a: a[0], primal)
        return (value, aux), unravel(tangent[0])
    return vg


def is_pytree(objective) -> bool:
    """Whether ``objective`` is a pytree with data (a registered dataclass such as
    ``objective.DesignObjective``), traced by the compiled programs, rather than a function."""
    return not jax.tree_util.treedef_is_leaf(jax.tree_util.tree_structure(objective))


def _value_and_grad(objective, params, args, fn, mode):
    f = objective if fn is None else fn
    g = lambda p: f(p, *args)
    return value_and_grad_fwd(g)(params) if mode == "forward" else jax.value_and_grad(g, has_aux=True)(params)


_PROGRAMS = {b: jax.jit(_value_and_grad, static_argnames=("fn", "mode"), compiler_options=options.build(b))
             for b in options.BUILDS}


def cache_size() -> int:
    """Executables the one-program gradients compiled in this process."""
    return sum(p._cache_size() for p in _PROGRAMS.values())


@dataclasses.dataclass(frozen=True)
class OneProgram:
    """The value and gradient as one compiled program: ``jax.value_and_grad`` of the objective
    (``mode="reverse"``) or forward mode (``"forward"``, ``value_and_grad_fwd``); ``build`` as the
    module docstring says."""

    mode: str = "reverse"
    build: str | None = None

    def __post_init__(self):
        if self.mode not in ("reverse", "forward"):
            raise ValueError(f"mode must be 'reverse' or 'forward', got {self.mode!r}")
        check_build(self.build)

    def _call(self, objective, params, args):
        traced = is_pytree(objective)
        return ((objective if traced else None, params, tuple(args)),
                {"fn": None if traced else objective, "mode": self.mode})

    def value_and_grad(self, objective, params, args=()):
        """((value, aux), gradient) of ``objective(params, *args)`` at ``params``."""
        call_args, static = self._call(objective, params, args)
        return compiled.call(_PROGRAMS[self.build or "quick"], call_args, static)

    def compile_ahead(self, objective, params, args=()):
        """Start compiling the program for an objective and parameters of these shapes (arrays or
        ``jax.ShapeDtypeStruct``) in a background thread (``jaxflex.runtime.compiled.compile_ahead``); the
        first ``value_and_grad`` with the same shapes waits for it and uses it."""
        call_args, static = self._call(objective, params, args)
        return compiled.compile_ahead(_PROGRAMS[self.build or "quick"], call_args, static)
