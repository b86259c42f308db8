"""Gauss-Legendre quadrature on [0, 1] (nodes are host constants, static under jit)."""
from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np


@functools.lru_cache(maxsize=None)
def gauss_legendre(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the m-point Gauss-Legendre rule mapped to [0, 1].

    Exact for polynomials of degree <= 2m - 1. Returned as float64 numpy arrays so that they are
    embedded as constants when traced.
    """
    if m < 1:
        raise ValueError(f"quadrature order must be >= 1, got {m}")
    x, w = np.polynomial.legendre.leggauss(m)
    return 0.5 * (x + 1.0), 0.5 * w


def integrate(f, a, b, m: int):
    """Integral of f over [a, b] with the m-point Gauss-Legendre rule.

    f maps an array of abscissae of shape (m,) to values of shape (m, ...); a and b are scalars
    (traced or not). Differentiable with respect to a, b and anything f closes over.
    """
    x, w = gauss_legendre(m)
    h = b - a
    vals = f(a + h * jnp.asarray(x))
    return h * jnp.tensordot(jnp.asarray(w), vals, axes=1)
