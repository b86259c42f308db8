"""Design space and residual-vibration objective (SPEC 6).

Parameters are unconstrained reals, decoded into a valid design by construction:

- blend size d = h * sigmoid(u_d) in (0, h) (the lift height: the blend starts above the pick point),
  e = (l / 2) * sigmoid(u_e) in (0, l / 2) (the two blends never overlap), Lamé order
  n = 2 + 6 * sigmoid(u_n) in (2, 8);
- motion-law coefficients ``coef`` of the shaped family (``jaxflex.profiles.shaped``): monotone,
  S(0) = 0, S(1) = 1, zero velocity and acceleration (and jerk, order 3) at both ends for any values.

The objective is the residual vibration at the place point, normalized by a reference run
(usually the best paper combination): vibration energy at tf plus the mean square dwell amplitude,
averaged over a set of models (payloads, stiffness and payload perturbations: the robust variant),
plus a quadratic penalty when the peak motor torque exceeds a bound. tf is fixed.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxflex.designs import Design, design_rollout
from jaxflex.metrics import metrics
from jaxflex.path import Cycle
from jaxflex.profiles import shaped
from jaxflex.robot import Robot
from jaxflex.simulate import Grid, motion_samples, rollout

N_MIN, N_MAX = 2.0, 8.0


class Params(NamedTuple):
    """Unconstrained optimization variables: blend (3,) = (u_d, u_e, u_n), coef (m + 1,)."""

    blend: jax.Array
    coef: jax.Array


def _logit(p):
    return jnp.log(p) - jnp.log1p(-p)


def encode(cycle: Cycle, x: Design) -> Params:
    """Parameters of a valid design (inverse of ``decode``)."""
    h, half = cycle.h, 0.5 * cycle.l
    u = jnp.stack([_logit(x.d / h), _logit(x.e / half), _logit((x.n - N_MIN) / (N_MAX - N_MIN))])
    return Params(blend=u, coef=jnp.asarray(x.coef, dtype=float))


def decode(cycle: Cycle, p: Params) -> Design:
    """Valid design from unconstrained parameters (blend sizes within the legs by construction)."""
    s = jax.nn.sigmoid(p.blend)
    return Design(d=cycle.h * s[0], e=0.5 * cycle.l * s[1], n=N_MIN + (N_MAX - N_MIN) * s[2], coef=p.coef)


class Scales(NamedTuple):
    """Reference values that make the objective dimensionless: vibration energy at tf [J] and mean
    square dwell amplitude [m^2], per model (K,); peak torque bound [N m] (inf: no bound)."""

    energy: jax.Array
    dwell_ms: jax.Array
    torque_bound: jax.Array


def residual_terms(series) -> tuple:
    """(energy at tf [J], mean square dwell amplitude |e - e_static|^2 [m^2], peak |tau| [N m])."""
    amp = series.e_dwell - series.e_static[None]
    return series.energy_tf, jnp.mean(jnp.sum(amp * amp, axis=-1)), jnp.max(jnp.abs(series.tau))


def objective_terms(params: Params, robots: Robot, cycle: Cycle, tf, dwell, grid: Grid, *,
                    blend: str = "lame", order: int = 3, second_order: bool = True) -> dict:
    """Per-model terms for a batch of K robots (leaves with a leading axis K, e.g. payloads)."""
    x = decode(cycle, params)

    def one(robot):
        series = design_rollout(robot, cycle, x, tf, dwell, grid, blend=blend, order=order,
                                second_order=second_order)
        energy, dwell_ms, torque = residual_terms(series)
        return {"energy": energy, "dwell_ms": dwell_ms, "torque": torque, "metrics": metrics(series)}

    return jax.vmap(one)(robots)


def objective(params: Params, robots: Robot, cycle: Cycle, tf, dwell, grid: Grid, scales: Scales, *,
              blend: str = "lame", order: int = 3, torque_weight: float = 10.0, second_order: bool = True):
    """Scalar objective (dimensionless; 2 for a design as good as the reference on every model) and
    the per-model terms."""
    t = objective_terms(params, robots, cycle, tf, dwell, grid, blend=blend, order=order,
                        second_order=second_order)
    vib = jnp.mean(t["energy"] / scales.energy + t["dwell_ms"] / scales.dwell_ms)
    excess = jnp.maximum(t["torque"] / scales.torque_bound - 1.0, 0.0)
    return vib + torque_weight * jnp.sum(excess**2), t


def stack_robots(robots) -> Robot:
    """Stack robots with equal static fields into one pytree with a leading axis."""
    return jax.tree_util.tree_map(lambda *a: jnp.stack([jnp.asarray(v, dtype=float) for v in a]), *robots)


def perturbed(robot: Robot, payloads, stiffness=(1.0,), payload_scale=(1.0,)) -> list:
    """Models for a robust objective: every payload [kg] x Young's modulus factor x payload factor."""
    return [robot.replace(payload=m * ps, young=robot.young * k)
            for m in payloads for k in stiffness for ps in payload_scale]


def law_objective(coef, tables, length, cycle_tf, dwell, grid: Grid, scales: Scales, *, order: int = 3,
                  torque_weight: float = 10.0, robots: Robot | None = None):
    """Objective of the motion law alone on a fixed path: ``tables`` stacked over K models (leading
    axis K, e.g. from ``jax.vmap(build_tables, (0, None))``), path length [m]; ``robots`` the K
    models stacked (``stack_robots``) for the second-order fast model, None for the first-order one.
    Cheaper than ``objective``: the tables do not depend on the law."""
    samples = motion_samples(length, shaped(coef, order), cycle_tf, grid)

    def one(tab, robot):
        series = rollout(tab, samples, cycle_tf, dwell, grid, robot)
        energy, dwell_ms, torque = residual_terms(series)
        return {"energy": energy, "dwell_ms": dwell_ms, "torque": torque, "metrics": metrics(series)}

    t = jax.vmap(one)(tables, robots)
    vib = jnp.mean(t["energy"] / scales.energy + t["dwell_ms"] / scales.dwell_ms)
    excess = jnp.maximum(t["torque"] / scales.torque_bound - 1.0, 0.0)
    return vib + torque_weight * jnp.sum(excess**2), t
