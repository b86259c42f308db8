"""Motion laws S(eta), eta = t / tf in [0, 1] (paper Section 3, Fig. 7; docs/conventions.md#motion-laws).

A motion law is monotone from S(0) = 0 to S(1) = 1 and gives the fraction of the path covered at the
normalized time eta. Families:

- ``poly7``: 35 eta^4 - 84 eta^5 + 70 eta^6 - 20 eta^7 (zero velocity, acceleration and jerk at both
  ends).
- ``trapezoid``: trapezoidal velocity with acceleration time ``ta`` (fraction of tf, 0 < ta <= 1/2) and
  cruise speed 1 / (1 - ta). ``bang_bang`` is ta = 1/2 (2 eta^2, then 1 - 2 (1 - eta)^2),
  ``trap_1_4`` is ta = 1/4 and ``trap_1_8`` ta = 1/8.
- ``impulses`` (input shaping, ``input_shaped``): a paper law compressed to [0, 1 - tau_K] and
  convolved with impulses A_k at tau_k: S(eta) = sum_k A_k S0((eta - tau_k) / (1 - tau_K)). ZV and ZVD
  shapers (``zv``, ``zvd``) cancel the residual vibration of one undamped mode at equal total time.
- ``shaped`` (the parametric family for optimization): velocity
  S'(eta) = eta^r (1 - eta)^r g(eta)^2 / Z, g a Bernstein polynomial with free coefficients ``coef``
  and Z the normalization making S(1) = 1. Monotone, with S(0) = 0, S(1) = 1 and zero velocity and
  acceleration at both ends (also zero jerk for r = 3) for ANY coefficients, so optimization needs no
  constraints for these properties. With r = 3 and equal coefficients it is exactly ``poly7``.

Derivatives are with respect to eta; ``time_scaled`` converts them to time for a given tf.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.names import PROFILES  # noqa: F401  (the paper's laws)
from jaxflex.quadrature import gauss_legendre

_TRAP_FRACTION = {"bang_bang": 0.5, "trap_1_4": 0.25, "trap_1_8": 0.125}


class LawValues(NamedTuple):
    """S and its first three derivatives (w.r.t. eta, or w.r.t. time after ``time_scaled``)."""

    s: jax.Array
    ds: jax.Array
    dds: jax.Array
    ddds: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Profile:
    """A motion law.

    Attributes:
        kind: ``"poly7"``, ``"trapezoid"``, ``"shaped"`` or ``"impulses"`` (static).
        ta: acceleration time as a fraction of tf (trapezoid only).
        coef: Bernstein coefficients of g (shaped; shape (m + 1,)) or impulse amplitudes (impulses;
            (K,), summing to 1).
        order: exponent r of the end factor eta^r (1 - eta)^r (shaped only; static, 2, 3 or 4:
            the derivatives of S up to order r vanish at both ends, and S^(r+1) jumps there).
        name: display name (static).
        times: impulse times as fractions of tf, (K,) ascending from 0 (impulses only).
        base: name of the paper law that the impulses convolve (impulses only; static).
    """

    ta: jax.Array
    coef: jax.Array
    kind: str = dataclasses.field(metadata=dict(static=True), default="poly7")
    order: int = dataclasses.field(metadata=dict(static=True), default=3)
    name: str = dataclasses.field(metadata=dict(static=True), default="poly7")
    times: jax.Array | None = None
    base: str = dataclasses.field(metadata=dict(static=True), default="")


def make_profile(name: str) -> Profile:
    """One of the paper's motion laws by name: ``poly7``, ``bang_bang``, ``trap_1_4``, ``trap_1_8``."""
    if name == "poly7":
        return Profile(ta=jnp.asarray(0.0), coef=jnp.zeros(1), kind="poly7", name=name)
    if isinstance(name, str) and name in _TRAP_FRACTION:
        return trapezoid(_TRAP_FRACTION[name], name=name)
    raise ValueError(f"unknown motion profile {name!r}; choose one of {', '.join(PROFILES)} "
                     "(or build one with trapezoid(ta) / shaped(coef))")


def trapezoid(ta, name: str | None = None) -> Profile:
    """Trapezoidal velocity law with acceleration time ``ta`` * tf, 0 < ta <= 1/2."""
    if not isinstance(ta, jax.core.Tracer) and (np.ndim(ta) != 0 or not 0.0 < float(ta) <= 0.5):
        raise ValueError(f"trapezoid acceleration fraction ta must be in (0, 1/2], got {ta}")
    return Profile(ta=jnp.asarray(ta, dtype=float), coef=jnp.zeros(1), kind="trapezoid",
                   name=name or f"trap_{float(ta):g}")


def shaped(coef, order: int = 3, name: str = "shaped") -> Profile:
    """Parametric law S' = eta^r (1-eta)^r g(eta)^2 / Z with g = sum_k coef_k B_k(eta) (Bernstein)."""
    coef = jnp.asarray(coef, dtype=float)
    if coef.ndim != 1 or coef.shape[0] < 1:
        raise ValueError("shaped profile coefficients must be a non-empty 1-D array")
    if order not in (2, 3, 4):
        raise ValueError(f"shaped profile order must be 2, 3 or 4, got {order}")
    if not isinstance(coef, jax.core.Tracer):
        c = np.asarray(coef)
        if not np.all(np.isfinite(c)):
            raise ValueError(f"shaped profile coefficients must be finite, got {c.tolist()}")
        if not np.any(c != 0.0):
            raise ValueError("shaped profile coefficients are all zero: the velocity g^2 vanishes and "
                             "S cannot be normalized to S(1) = 1")
    return Profile(ta=jnp.asarray(0.0), coef=coef, kind="shaped", order=int(order), name=name)


def elevate(coef, n: int) -> np.ndarray:
    """The coefficients (n,) of the same g as ``coef`` (k,), k <= n, in the Bernstein basis of degree
    n - 1 (degree elevation: B^m_j = ((m + 1 - j) B^{m+1}_j + (j + 1) B^{m+1}_{j+1}) / (m + 1)), so
    ``shaped(elevate(c, n))`` is the law of ``shaped(c)`` with more coefficients to optimize.
    Concrete arrays only."""
    c = np.asarray(coef, dtype=float)
    if c.ndim != 1 or c.size < 1:
        raise ValueError("coefficients to elevate must be a non-empty 1-D array")
    if int(n) < c.size:
        raise ValueError(f"a law of {c.size} coefficients cannot be written exactly with {int(n)}")
    while c.size < int(n):
        m = c.size - 1                                   # degree m -> m + 1
        j = np.arange(1, m + 1)
        c = np.concatenate([c[:1], (j / (m + 1)) * c[:-1] + (1 - j / (m + 1)) * c[1:], c[-1:]])
    return c


def input_shaped(base: str, amplitudes, times, name: str | None = None) -> Profile:
    """Paper law ``base`` convolved with impulses (amplitudes (K,) summing to 1, times (K,) as
    fractions of the total time, ascending from 0 and < 1); the total motion time is unchanged."""
    make_profile(base)
    amps, ts = jnp.asarray(amplitudes, dtype=float), jnp.asarray(times, dtype=float)
    if amps.ndim != 1 or amps.shape != ts.shape:
        raise ValueError("impulse amplitudes and times must be 1-D arrays of equal length")
    if not isinstance(ts, jax.core.Tracer):
        t, a = np.asarray(ts), np.asarray(amps)
        if t.size == 0 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
            raise ValueError(f"impulse amplitudes and times must be finite and non-empty, got {a} at {t}")
        if t[0] != 0.0 or np.any(np.diff(t) < 0) or not t[-1] < 1.0:
            raise ValueError(f"impulse times must ascend from 0 and stay below 1 (fractions of tf), got {t}")
        if abs(a.sum() - 1.0) > 1e-12:
            raise ValueError(f"impulse amplitudes must sum to 1, got {a.sum()}")
    return Profile(ta=jnp.asarray(0.0), coef=amps, kind="impulses", name=name or f"{base}+shaper",
                   times=ts, base=base)


def _check_shaper(freq_hz, tf):
    for name, v in (("mode frequency freq_hz", freq_hz), ("motion time tf", tf)):
        if not (np.ndim(v) == 0 and np.isfinite(float(v)) and float(v) > 0):
            raise ValueError(f"shaper {name} must be finite and > 0, got {v}")


def zv(base: str, freq_hz: float, tf: float) -> Profile:
    """ZV shaper (two impulses 1/2, half a period apart) for an undamped mode at freq_hz [Hz]."""
    _check_shaper(freq_hz, tf)
    half = 0.5 / float(freq_hz) / float(tf)
    return input_shaped(base, [0.5, 0.5], [0.0, half], name=f"{base}+ZV")


def zvd(base: str, freq_hz: float, tf: float) -> Profile:
    """ZVD shaper (1/4, 1/2, 1/4 at 0, T/2, T) for an undamped mode at freq_hz [Hz]: robust to
    frequency errors (zero derivative of the residual w.r.t. frequency)."""
    _check_shaper(freq_hz, tf)
    half = 0.5 / float(freq_hz) / float(tf)
    return input_shaped(base, [0.25, 0.5, 0.25], [0.0, half, 2 * half], name=f"{base}+ZVD")


def _impulses(profile: Profile, eta, side):
    base = make_profile(profile.base)
    span = 1.0 - profile.times[-1]
    raw = (eta[..., None] - profile.times.reshape((1,) * eta.ndim + (-1,))) / span    # (..., K)
    inside = (raw >= 0.0) & (raw < 1.0) if side > 0 else (raw > 0.0) & (raw <= 1.0)
    v = profile_eval(base, jnp.clip(raw, 0.0, 1.0), side)
    a = profile.coef
    return LawValues(v.s @ a, jnp.where(inside, v.ds, 0.0) @ a / span,
                     jnp.where(inside, v.dds, 0.0) @ a / span**2, jnp.where(inside, v.ddds, 0.0) @ a / span**3)


# ----------------------------------------------------------------------------------------------


def _poly7(eta):
    e2 = eta * eta
    e3 = e2 * eta
    s = e2 * e2 * (35.0 - 84.0 * eta + 70.0 * e2 - 20.0 * e3)
    ds = 140.0 * e3 * (1.0 - eta) ** 3
    dds = 420.0 * e2 * (1.0 - eta) ** 2 * (1.0 - 2.0 * eta)
    ddds = 840.0 * eta * (1.0 - eta) * (1.0 - 5.0 * eta + 5.0 * e2)
    return LawValues(s, ds, dds, ddds)


def _trapezoid(ta, eta, side):
    v = 1.0 / (1.0 - ta)
    a = v / ta
    if side > 0:      # right limits at the acceleration jumps
        rise, fall = eta < ta, eta >= 1.0 - ta
    else:             # left limits
        rise, fall = eta <= ta, eta > 1.0 - ta
    r = 1.0 - eta
    s = jnp.where(rise, 0.5 * a * eta**2, jnp.where(fall, 1.0 - 0.5 * a * r**2, v * (eta - 0.5 * ta)))
    ds = jnp.where(rise, a * eta, jnp.where(fall, a * r, v))
    dds = jnp.where(rise, a, jnp.where(fall, -a, 0.0))
    return LawValues(s, ds, dds, jnp.zeros_like(eta))


def _bernstein(coef, x):
    """sum_k coef_k C(m, k) x^k (1 - x)^(m - k) for x of any shape, by de Casteljau's algorithm (m
    rounds of linear interpolation: no powers, exact derivatives at the ends, a small program)."""
    b = jnp.broadcast_to(coef, jnp.shape(x) + coef.shape)
    xe = jnp.expand_dims(x, -1)
    for _ in range(coef.shape[0] - 1):
        b = (1.0 - xe) * b[..., :-1] + xe * b[..., 1:]
    return b[..., 0]


def _shaped_velocity(coef, order, x):
    g = _bernstein(coef, x)
    return (x * (1.0 - x)) ** order * g * g


def _shaped(coef, order, eta):
    m = coef.shape[0] - 1
    nodes, weights = gauss_legendre(order + m + 2)   # exact: velocity has degree 2 (r + m)
    nodes, weights = jnp.asarray(nodes), jnp.asarray(weights)
    z = weights @ _shaped_velocity(coef, order, nodes)
    grid = eta[..., None] * nodes.reshape((1,) * eta.ndim + (-1,))
    s = eta * (_shaped_velocity(coef, order, grid) @ weights) / z
    vel = lambda x: _shaped_velocity(coef, order, x) / z
    d1 = lambda x: jax.jvp(vel, (x,), (jnp.ones_like(x),))[1]
    d2 = lambda x: jax.jvp(d1, (x,), (jnp.ones_like(x),))[1]
    return LawValues(s, vel(eta), d1(eta), d2(eta))


def profile_eval(profile: Profile, eta, side: int = 1) -> LawValues:
    """S(eta) and its derivatives w.r.t. eta; eta is clipped to [0, 1] (any shape).

    ``side`` (+1 or -1, static) selects right or left limits where the law's acceleration jumps
    (trapezoids): right limits by default, so that S''(0) is the starting acceleration; use -1 for
    the value at the end of an interval, e.g. S''(1) = -a.
    """
    eta = jnp.clip(jnp.asarray(eta, dtype=float), 0.0, 1.0)
    if profile.kind == "poly7":
        return _poly7(eta)
    if profile.kind == "trapezoid":
        return _trapezoid(profile.ta, eta, side)
    if profile.kind == "shaped":
        return _shaped(profile.coef, profile.order, eta)
    if profile.kind == "impulses":
        return _impulses(profile, eta, side)
    raise ValueError(f"unknown profile kind {profile.kind!r}")


@functools.partial(jax.jit, static_argnames=("side",))
def _profile_eval_jit(profile: Profile, eta, side: int) -> LawValues:
    return profile_eval(profile, eta, side)


def profile_values(profile: Profile, eta, side: int = 1) -> LawValues:
    """``profile_eval`` on concrete values (plots, tables) through one compiled program per kind of
    law and shape of eta (the display name does not matter). Evaluated eagerly, a law dispatches
    (and in a fresh process compiles) every small operation on its own, which is far slower."""
    return _profile_eval_jit(dataclasses.replace(profile, name=""), jnp.asarray(eta, dtype=float), side)


def time_scaled(values: LawValues, tf) -> LawValues:
    """Convert derivatives w.r.t. eta into derivatives w.r.t. time for a motion of duration tf [s]."""
    return LawValues(values.s, values.ds / tf, values.dds / tf**2, values.ddds / tf**3)
