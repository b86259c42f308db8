"""Designs: the blend parameters of each corner and the coefficients of a shaped motion law.

A *design* is a point of the optimization space (docs/conventions.md#optimization): the blend
parameters of each corner (d, e [m], Lamé order n) of a blend family and the coefficients of a
shaped monotone motion law (``jaxflex.profiles.shaped``). ``jaxflex.rollout.design_rollout``
simulates one (a pure, differentiable function of the design); ``jaxflex.design_sweep`` evaluates
thousands.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxflex.path import Cycle, Path, make_path


class Design(NamedTuple):
    """Blend parameters per corner and the shaped motion-law coefficients.

    d, e [m] and the Lamé order n have a trailing corner axis: (2,) = (pick corner, place corner) for
    one design, (D, 2) for a batch; coef ((m + 1,), or (D, m + 1)) are the coefficients of
    ``jaxflex.profiles.shaped``."""

    d: jax.Array
    e: jax.Array
    n: jax.Array
    coef: jax.Array


def design(d=0.025, e=None, n=3.0, coef=(1.0, 1.0, 1.0, 1.0), *, d2=None, e2=None, n2=None) -> Design:
    """A single design as float64 arrays: corner 1 (d, e [m], n), corner 2 (d2, e2, n2; default the
    mirror image of corner 1); e defaults to d."""
    e = d if e is None else e
    pair = lambda a, b: jnp.asarray([a, a if b is None else b], dtype=float)
    return Design(pair(d, d2), pair(e, e2), pair(n, n2), jnp.asarray(coef, dtype=float))


def design_path(cycle: Cycle, x: Design, blend: str = "lame") -> Path:
    """The blended path of one design (corner axis (2,)); validated when the values are concrete."""
    return make_path(cycle, blend, x.d[0], x.e[0], x.n[0], x.d[1], x.e[1], x.n[1])
