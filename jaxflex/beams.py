"""Assumed modes of the links (paper Section 2, Eqs. 1-2, Table 1) and their exact modal integrals.

Proximal links are clamped-free Euler-Bernoulli beams in bending,
    phi_k(xi) = sin(b_k xi) + a_k cos(b_k xi) - sinh(b_k xi) - a_k cosh(b_k xi),
with b_k the roots of cos b cosh b = -1 and a_k = -(sin b_k + sinh b_k) / (cos b_k + cosh b_k).
Distal links are fixed-free bars in tension-compression, phi_k(xi) = sin((2k - 1) pi xi / 2).

The mode shapes only enter the model through integrals over xi in [0, 1] and tip values, which are
dimensionless numbers that depend on the number of modes alone. They are computed once on the host in
float64 with a 96-point Gauss-Legendre rule (exact to round-off for these entire functions) and a
cancellation-free evaluation of the hyperbolic terms.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from jaxflex.quadrature import gauss_legendre

_NODES = 96


class BeamModes(NamedTuple):
    """Dimensionless modal data of one link type with n modes (numpy float64).

    phi_int (n,) = int phi; xi_phi_int (n,) = int xi phi; mass (n, n) = int phi phi^T;
    stiffness (n, n) = int phi'' phi''^T (bending) or int phi' phi'^T (axial), derivatives w.r.t. xi;
    tip (n,) = phi(1). Physical matrices: M = rho A l * mass; K = E I / l^3 * stiffness (bending) or
    E A / l * stiffness (axial) (paper Eqs. 7, 9, 11, 13).
    """

    phi_int: np.ndarray
    xi_phi_int: np.ndarray
    mass: np.ndarray
    stiffness: np.ndarray
    tip: np.ndarray


def bending_roots(n: int) -> np.ndarray:
    """First n roots b_k of cos(b) cosh(b) = -1 (1.8751, 4.6941, 7.8548, ...), to round-off."""
    roots = []
    for k in range(1, n + 1):
        b = (2 * k - 1) * np.pi / 2            # asymptote; Newton on cos b + 1/cosh b = 0
        for _ in range(50):
            f = np.cos(b) + 1.0 / np.cosh(b)
            df = -np.sin(b) - np.tanh(b) / np.cosh(b)
            step = f / df
            b -= step
            if abs(step) < 1e-15:
                break
        roots.append(b)
    return np.array(roots)


def bending_coefficients(b: np.ndarray) -> np.ndarray:
    """a_k = -(sin b_k + sinh b_k) / (cos b_k + cosh b_k) (Table 1: -1.3622, -0.98186, -1.0008)."""
    return -(np.sin(b) + np.sinh(b)) / (np.cos(b) + np.cosh(b))


def _bending_shapes(n: int, xi: np.ndarray, deriv: int = 0) -> np.ndarray:
    """phi_k^(deriv)(xi) for k = 1..n, shape (len(xi), n), evaluated without cancellation.

    sinh(x) + a cosh(x) = e^x (1 + a) / 2 - e^-x (1 - a) / 2 and 1 + a = (cos b - sin b + e^-b) /
    (cos b + cosh b), so e^(b xi) (1 + a) stays O(1) even for large b.
    """
    b = bending_roots(n)
    a = bending_coefficients(b)
    one_plus_a = (np.cos(b) - np.sin(b) + np.exp(-b)) / (np.cos(b) + np.cosh(b))
    x = np.asarray(xi, dtype=float)[:, None] * b
    # growing part e^(x) (1 + a) / 2 written as e^(x - b) * [e^b (1 + a)] / 2
    grow = np.exp(x - b) * (np.exp(b) * one_plus_a) / 2.0
    decay = np.exp(-x) * (1.0 - a) / 2.0
    # d^m/dx^m of sin x + a cos x and of -(sinh x + a cosh x) = -(grow - decay)
    trig = [np.sin(x) + a * np.cos(x), np.cos(x) - a * np.sin(x),
            -np.sin(x) - a * np.cos(x), -np.cos(x) + a * np.sin(x)][deriv % 4]
    hyp = -(grow - (-1) ** deriv * decay)
    return (trig + hyp) * b**deriv


def _axial_shapes(n: int, xi: np.ndarray, deriv: int = 0) -> np.ndarray:
    c = (2 * np.arange(1, n + 1) - 1) * np.pi / 2
    x = np.asarray(xi, dtype=float)[:, None] * c
    return [np.sin(x), np.cos(x), -np.sin(x), -np.cos(x)][deriv % 4] * c**deriv


def mode_shapes(kind: str, n: int, xi, deriv: int = 0) -> np.ndarray:
    """Mode shapes (or their xi-derivatives) of ``kind`` 'bending' or 'axial': (len(xi), n)."""
    if kind == "bending":
        return _bending_shapes(n, xi, deriv)
    if kind == "axial":
        return _axial_shapes(n, xi, deriv)
    raise ValueError(f"unknown beam kind {kind!r}")


@functools.lru_cache(maxsize=None)
def cross_mass(n_axial: int, n_bending: int) -> np.ndarray:
    """(n_axial, n_bending) = int phi_axial phi_bending^T dxi: the coupling of the two mode sets of a
    link that has both (the rotation of the link frame mixes the axial and transverse motions)."""
    x, w = gauss_legendre(_NODES)
    return (mode_shapes("axial", n_axial, x) * w[:, None]).T @ mode_shapes("bending", n_bending, x)


@functools.lru_cache(maxsize=None)
def beam_modes(kind: str, n: int) -> BeamModes:
    """Modal integrals for ``n`` modes of a 'bending' (clamped-free) or 'axial' (fixed-free) link."""
    if int(n) != n or n < 1:
        raise ValueError(f"number of modes must be a positive integer, got {n}")
    x, w = gauss_legendre(_NODES)
    phi = mode_shapes(kind, n, x)
    dphi = mode_shapes(kind, n, x, 2 if kind == "bending" else 1)
    return BeamModes(
        phi_int=w @ phi,
        xi_phi_int=(w * x) @ phi,
        mass=(phi * w[:, None]).T @ phi,
        stiffness=(dphi * w[:, None]).T @ dphi,
        tip=mode_shapes(kind, n, np.array([1.0]))[0],
    )
