"""Design space and residual-vibration objective (docs/conventions.md#optimization).

Parameters are unconstrained reals, decoded into a valid design by construction, per corner
(pick corner, place corner):

- blend size d = h * sigmoid(u_d) in (0, h) (the lift height: the blend starts above the pick or
  place point), e = (l / 2) * sigmoid(u_e) in (0, l / 2) (the two blends never overlap), Lamé order
  n = 2 + 6 * sigmoid(u_n) in (2, 8);
- motion-law coefficients ``coef`` of the shaped family (``jaxflex.profiles.shaped``): monotone,
  S(0) = 0, S(1) = 1, zero velocity and acceleration (and jerk, order 3) at both ends for any values.

The objective is the residual vibration at the place point in units of reference values, on a
log scale, through the weighted power mean of order p over the models:

    r_k = (E_k / E_ref,k + A_k / A_ref,k) / 2
    J = (1/p) log( sum_k w_k r_k^p ) + W * sum_k max(tau_k / tau_max,k - 1, 0)^2

(under a servo, optionally the dwell's smooth maximum in place of both: ``Scales.dwell_peak``)
with E the vibration energy at tf [J] and A the mean square dwell amplitude [m^2] of model k (a
set of payloads, stiffness and payload perturbations: the robust variant) with weight w_k (equal
by default), tau the peak motor torque and tau_max its bound (``Scales``). p = 1 is the weighted
mean (the studies' default, each model scaled by the reference on itself); a large p a smooth
worst case (``StudyConfig(robust_power=8, absolute=True)``: absolute references, the reference law
on the payload case's nominal model, one constant per case, docs/conventions.md#uncertainty-box).
J = 0 for a design as good as the reference on every model; a design with 10x less residual
amplitude and energy scaled alike scores log(1/100) = -4.6. The log keeps the gradient's scale (and
Adam's steps) meaningful across the orders of magnitude the residual spans during an optimization.
tf is fixed.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.special  # noqa: F401  (logsumexp)

from jaxflex import rollout as rl
from jaxflex import trees
from jaxflex.designs import Design
from jaxflex.linearized import Tables
from jaxflex.metrics import Terms
from jaxflex.path import Cycle
from jaxflex.profiles import shaped
from jaxflex.robot import Robot
from jaxflex.servo import Servo
from jaxflex.servo_simulate import feedforward_torques
from jaxflex.rollout import RolloutModel, RolloutState
from jaxflex.simulate import Grid, motion_samples
from jaxflex.workspace import Workspace

from .config import BLEND_FAMILY

N_MIN, N_MAX = 2.0, 8.0
TORQUE_WEIGHT = 1e5     # penalty weight on (peak torque / bound - 1)^2: 1 % excess costs 10 in J (a
                        # factor e^10 in residual), so the bound holds closely at the optimum


class Params(NamedTuple):
    """Unconstrained optimization variables: blend (6,) = (u_d, u_e, u_n) of corner 1 then corner 2,
    coef (m + 1,)."""

    blend: jax.Array
    coef: jax.Array


def _logit(p):
    return jnp.log(p) - jnp.log1p(-p)


def encode(cycle: Cycle, x: Design) -> Params:
    """Parameters of a valid design (inverse of ``decode``); d must be < h and e < l/2."""
    h, half = cycle.h, 0.5 * cycle.l
    u = jnp.stack([_logit(x.d / h), _logit(x.e / half), _logit((x.n - N_MIN) / (N_MAX - N_MIN))], axis=-1)
    return Params(blend=u.reshape(-1), coef=jnp.asarray(x.coef, dtype=float))


def decode(cycle: Cycle, p: Params) -> Design:
    """Valid design from unconstrained parameters (blend sizes within the legs by construction)."""
    s = jax.nn.sigmoid(p.blend.reshape(2, 3))
    return Design(d=cycle.h * s[:, 0], e=0.5 * cycle.l * s[:, 1], n=N_MIN + (N_MAX - N_MIN) * s[:, 2],
                  coef=p.coef)


class Scales(NamedTuple):
    """Reference values per model (K,): vibration energy at tf [J] and mean square dwell amplitude
    [m^2]; peak torque bound [N m] per model (K,) or scalar (inf: no bound); optional weights (K,)
    of the models in the mean (summing to 1; None: equal weights); optional reference (K,) [m^2] of
    the dwell's smooth maximum ``metrics.Terms.dwell_peak`` (None: no such term)."""

    energy: jax.Array
    dwell_ms: jax.Array
    torque_bound: jax.Array
    weights: jax.Array | None = None
    dwell_peak: jax.Array | None = None


def scaled_residual(terms: Terms, energy_ref, dwell_ref, peak_ref=None):
    """E / E_ref + A / A_ref (+ P / P_ref with a peak reference, P the dwell's smooth maximum
    ``terms.dwell_peak``): a model's residual in units of its references (twice the module
    docstring's r_k), the only way ``combine`` depends on the energy and dwell terms."""
    r = terms.energy / energy_ref + terms.dwell_ms / dwell_ref
    return r if peak_ref is None else r + terms.dwell_peak / peak_ref


def combine(terms: Terms, scales: Scales, torque_weight: float = TORQUE_WEIGHT, power: float = 1.0):
    """The scalar objective J (module docstring) from per-model terms (leaves (K,)): the log of the
    weighted power mean of order ``power`` of the models' scaled residuals r_k (1: the weighted
    mean; larger: a smooth stand-in for the worst model, within a factor w_min^(-1/power) of it)."""
    per_model = scaled_residual(terms, scales.energy, scales.dwell_ms, scales.dwell_peak)
    return combine_scaled(per_model, terms.torque, scales, torque_weight, power)


def combine_scaled(per_model, torque, scales: Scales, torque_weight: float = TORQUE_WEIGHT, power: float = 1.0):
    """``combine`` from the models' ``scaled_residual`` (K,) and peak torques [N m] (K,)."""
    excess = jnp.maximum(torque / scales.torque_bound - 1.0, 0.0)
    penalty = torque_weight * jnp.sum(excess**2)
    if power == 1.0:
        vib = jnp.mean(per_model) if scales.weights is None else jnp.sum(scales.weights * per_model)
        return jnp.log(0.5 * vib) + penalty
    k = per_model.shape[0]
    w = jnp.full(k, 1.0 / k) if scales.weights is None else scales.weights
    log_mean = jax.scipy.special.logsumexp(power * jnp.log(0.5 * per_model), b=w) / power
    return log_mean + penalty


VMAP_MODELS = 2     # objectives over at most this many models vmap them; more go one at a time


def _count(batched) -> int:
    return jax.tree_util.tree_leaves(batched)[0].shape[0]


def over_models(fn, *batched):
    """fn(*one model's slices) over the leading (model) axis K of ``batched`` (pytrees; None allowed).

    Up to ``VMAP_MODELS`` models are vmapped. More run one at a time (``lax.map``) with ``fn``
    rematerialized in reverse mode (``jax.checkpoint``): the backward pass then holds one model's
    rollout at a time instead of all K. That takes a small fraction of the vmapped program's XLA
    temporary memory, at the cost of a longer compilation, and gives the same value and gradient to
    round-off (figures in docs/performance.md). The optimizer differentiates the design objective
    model by model instead (``optimize.staged``, which compiles sooner); this serves the law
    objective and the one-program gradient."""
    if _count(batched) <= VMAP_MODELS:
        return jax.vmap(fn)(*batched)
    remat = jax.checkpoint(fn)
    return jax.lax.map(lambda xs: remat(*xs), batched)


_static = dict(metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DesignObjective:
    """The design objective J (path and law, module docstring) on K training models: a pytree whose
    data are the models and references, and whose static configuration decides the compiled program
    (the same program for every tf, payload set and scale of the same shapes).

    Data: ``robots`` the K models stacked (``stack_robots``), the ``cycle``, ``tf`` and ``dwell`` [s],
    ``scales`` (``Scales``, one per model) and ``workspaces``, the models' workspace tables stacked
    alike (``jaxflex.workspace``; None: each path's tables built from the model). Static: the rollout
    ``grid``, the design's ``blend`` family, the shaped law's end-factor ``order``, the torque
    penalty's weight and the ``power`` of the mean over the models (``combine``).

    ``objective(params) -> (J, terms)``, terms (``metrics.Terms``) with leaves of leading axis K.
    How its gradient is computed is the optimizer's choice (``optimize.gradient``): one program, or
    the stages of the rollout model by model (``optimize.staged.Staged``, which reads
    ``rollout_model``, ``start`` and ``head``)."""

    robots: Robot
    cycle: Cycle
    tf: jax.Array
    dwell: jax.Array
    scales: Scales
    workspaces: Workspace | None = None
    servos: Servo | None = None
    advance: jax.Array | None = None
    grid: Grid = dataclasses.field(default=Grid(), **_static)
    blend: str = dataclasses.field(default=BLEND_FAMILY, **_static)
    order: int = dataclasses.field(default=3, **_static)
    torque_weight: float = dataclasses.field(default=TORQUE_WEIGHT, **_static)
    power: float = dataclasses.field(default=1.0, **_static)
    controller: int = dataclasses.field(default=0, **_static)

    @property
    def count(self) -> int:
        """The number K of training models."""
        return int(self.robots.payload.shape[0])

    def rollout_model(self, robot: Robot, workspace: Workspace | None, servo: Servo | None = None,
                      controller: Robot | None = None) -> RolloutModel:
        """The rollout of one model (one robot and its workspace tables) of this objective, under
        ``servo`` with the feedforward of the ``controller``'s model (None: the perfect controller)."""
        return RolloutModel(robot=robot, tf=self.tf, dwell=self.dwell, cycle=self.cycle, workspace=workspace,
                            servo=servo, controller=controller, grid=self.grid, second_order=True, blend=self.blend,
                            order=self.order)

    @staticmethod
    def start(model: RolloutModel, params: Params) -> RolloutState:
        """The rollout's first state: the design the parameters decode to."""
        return RolloutState(design=decode(model.cycle, params))

    @staticmethod
    def head(terms: Terms, energy_ref, dwell_ref, peak_ref=None):
        """(y, terms): y = [r_k, tau_k] (2,), the only values of one model's terms that ``combine``
        depends on: its scaled residual (``scaled_residual``) and its peak torque [N m]."""
        return jnp.stack([scaled_residual(terms, energy_ref, dwell_ref, peak_ref), terms.torque]), terms

    def terms(self, params: Params) -> Terms:
        """The per-model terms (leaves with the leading axis K) of the decoded design on the
        second-order fast model; under ``servos`` (one per model, stacked; their robots carry their
        rotors) the closed loop's, the feedforward computed on the model of index ``controller``
        (the nominal one: what the controller knows), a flexible one advanced by ``advance`` [s]."""
        x = decode(self.cycle, params)
        if self.servos is None:
            one = lambda robot, ws: rl.run(self.rollout_model(robot, ws), RolloutState(design=x)).terms
            return over_models(one, self.robots, self.workspaces)
        pick = lambda tree: None if tree is None else jax.tree_util.tree_map(lambda a: a[self.controller], tree)
        nominal, nominal_ws = pick(self.robots), pick(self.workspaces)
        ff = None
        if self.servos.feedforward == "flexible":
            prescribed = self.rollout_model(nominal, nominal_ws)
            perfect = rl.run(prescribed, RolloutState(design=x), rl.active(prescribed, rl.between(None, "last pass")))
            ff = feedforward_torques("flexible", nominal, perfect.tables, perfect.samples, self.grid, perfect.series,
                                     self.advance)

        def one(robot, ws, servo):
            model = self.rollout_model(robot, ws, servo, None if ff is not None else nominal)
            return rl.run(model, RolloutState(design=x, feedforward=ff)).terms

        return over_models(one, self.robots, self.workspaces, self.servos)

    def __call__(self, params: Params):
        t = self.terms(params)
        return combine(t, self.scales, self.torque_weight, self.power), t


def stack_robots(robots) -> Robot:
    """Stack robots with equal static fields into one pytree with a leading axis."""
    return trees.stack(robots, dtype=float)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class LawObjective:
    """Objective J of the motion law alone on a fixed path (cheaper than ``DesignObjective``, as the
    tables do not depend on the law): a pytree like it.

    Data: ``tables`` of the path on the K models (leading axis K, e.g. from
    ``jaxflex.engine.LawEvaluator``), the path ``length`` [m], ``tf`` and ``dwell`` [s], ``scales``
    (``Scales``), ``robots`` the K models stacked for the second-order fast model (None: the
    first-order one). Static: the ``grid``, the shaped law's end-factor ``order``, the torque
    penalty's weight and the ``power`` of the mean. ``objective(coef) -> (J, terms)`` for the law's
    coefficients coef (m + 1,)."""

    tables: Tables
    length: jax.Array
    tf: jax.Array
    dwell: jax.Array
    scales: Scales
    robots: Robot | None = None
    grid: Grid = dataclasses.field(default=Grid(), **_static)
    order: int = dataclasses.field(default=3, **_static)
    torque_weight: float = dataclasses.field(default=TORQUE_WEIGHT, **_static)
    power: float = dataclasses.field(default=1.0, **_static)

    def __call__(self, coef):
        samples = motion_samples(self.length, shaped(coef, self.order), self.tf, self.grid)

        def one(tab, robot):
            model = RolloutModel(robot=robot, tf=self.tf, dwell=self.dwell, grid=self.grid,
                                 second_order=robot is not None)
            return rl.run(model, RolloutState(tables=tab, samples=samples)).terms

        t = over_models(one, self.tables, self.robots)
        return combine(t, self.scales, self.torque_weight, self.power), t
