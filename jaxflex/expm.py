"""Fixed-cost matrix exponential and phi functions (no data-dependent branches: vmap- and
grad-friendly).

``expm_fixed``: scaling and squaring with a static number of squarings and a degree-12 Taylor
polynomial evaluated by Paterson-Stockmeyer (6 products). With ||A|| / 2^s <= 1/2 the truncation
error is below 0.5^13 / 13! ~ 2e-14 relative; callers choose s from a bound on the norm
(``squarings_for``). ``phi_series``: e^X, phi_1(X) and phi_2(X) of a small X (||X|| below about 1)
by their Taylor series, with no squaring.
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

_COEF = [1.0 / math.factorial(k) for k in range(13)]


def squarings_for(norm_bound: float) -> int:
    """Number of squarings s such that norm_bound / 2^s <= 1/2."""
    if not np.isfinite(norm_bound) or norm_bound < 0:
        raise ValueError(f"invalid norm bound {norm_bound}")
    return max(0, int(math.ceil(math.log2(max(norm_bound, 1e-300) / 0.5))))


def expm_fixed(a, squarings: int):
    """exp(a) for a (..., n, n) with ``squarings`` (static) scaling-and-squaring steps."""
    x = a / (2.0**squarings)
    eye = jnp.broadcast_to(jnp.eye(a.shape[-1]), a.shape)
    x2 = x @ x
    x3 = x2 @ x
    x4 = x2 @ x2
    c = _COEF

    def block(k):  # c_k I + c_{k+1} X + c_{k+2} X^2 + c_{k+3} X^3
        return c[k] * eye + c[k + 1] * x + c[k + 2] * x2 + c[k + 3] * x3

    # P = B0 + X^4 (B4 + X^4 (B8 + c12 X^4))
    p = block(8) + c[12] * x4
    p = block(4) + x4 @ p
    p = block(0) + x4 @ p
    for _ in range(squarings):
        p = p @ p
    return p



def phi_times(a, vectors, squarings: int):
    """sum_k phi_k(a) v_k over the vectors v_1 .. v_p (each (n,)), for a (n, n), where
    phi_0(z) = e^z, phi_{k+1}(z) = (phi_k(z) - 1/k!) / z (the functions of exponential integrators).

    One exponential of the (n + p)-augmented matrix [[a, W], [0, N]], W = [v_p .. v_1] and N the
    p x p shift, whose last column holds the sum (Al-Mohy & Higham 2011, Theorem 2.1). W is scaled
    inside to unit column sums, which keeps the augmented matrix's 1-norm at most max(||a||_1, 2):
    choose ``squarings`` for that bound (``squarings_for``)."""
    n, p = a.shape[-1], len(vectors)
    w = jnp.stack(vectors[::-1], axis=-1)
    size = jnp.max(jnp.sum(jnp.abs(w), axis=0))
    scale = 1.0 / jnp.where(size > 0, size, 1.0)
    top = jnp.concatenate([a, scale * w], axis=-1)
    bottom = jnp.concatenate([jnp.zeros((p, n)), jnp.eye(p, k=1)], axis=-1)
    return expm_fixed(jnp.concatenate([top, bottom], axis=-2), squarings)[:n, -1] / scale


PS_BLOCK = 4        # powers X^2 .. X^PS_BLOCK formed once (``phi_series``), then Horner in X^PS_BLOCK


def phi_series(x, terms: int):
    """(e^X, phi_1(X), phi_2(X)) for a small X (..., n, n), phi_1(z) = (e^z - 1) / z and phi_2(z) =
    (e^z - 1 - z) / z^2: phi_2 as its Taylor series sum_{j < terms} X^j / (j + 2)!, evaluated by
    Paterson and Stockmeyer's scheme (``PS_BLOCK`` - 1 products for the powers, then one per block
    of ``PS_BLOCK`` terms: 7 products for 20 terms instead of 19 term by term), then phi_1 = I + X
    phi_2 and e^X = I + X phi_1 (two more products; each carries the series two and one terms
    further). The truncation error is about ||X||^terms / (terms + 2)!: 20 terms at ||X|| = 0.8
    leave ~1e-20 relative."""
    eye = jnp.broadcast_to(jnp.eye(x.shape[-1]), x.shape)
    powers = [eye, x]
    for k in range(2, PS_BLOCK + 1):
        powers.append(powers[k // 2] @ powers[k - k // 2])
    coef = [1.0 / math.factorial(j + 2) for j in range(terms)]
    blocks = [sum(coef[k + i] * powers[i] for i in range(PS_BLOCK) if k + i < terms)
              for k in range(0, terms, PS_BLOCK)]
    phi2 = blocks[-1]
    for block in blocks[-2::-1]:
        phi2 = block + powers[PS_BLOCK] @ phi2
    phi1 = eye + x @ phi2
    return eye + x @ phi1, phi1, phi2
