"""Trajectories judged under a servo loop (docs/conventions.md#servo): the controller's uncertainty
box, the closed-loop evaluation of candidates on it, and the design refined with the closed loop in
its objective.

The controller is a ``jaxflex.servo.Servo`` set up on the nominal robot (``servo.cycle_servo``: the
default gain rule at a bandwidth fc). On a real robot the loop is not what was set up: the
achieved bandwidth differs (the gains act on an inertia the rule only estimated), the rotor
inertia is known to a few percent and the drive may sample at another rate. ``ServoBox`` bounds
that, beside the robot's own box (``jaxflex.uncertainty.Box``):

- the bandwidth fc x (1 +- ``fc``): Kp scaled by the factor squared, Kd by the factor;
- the servo rate in [``rates[0]``, ``rates[1]``] [Hz];
- the rotor inertia x (1 +- the robot box's ``rotor``), through ``ModelId.rotor_scale``.

The feedforward is always the nominal model's (the controller knows no better): the rigid inverse
dynamics of the nominal robot, or the flexible one from the nominal model's perfect-controller
rollout, advanced for the nominal rate (``servo.feedforward_advance``).
"""
from __future__ import annotations

import dataclasses
import time
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.engine import LawEvaluator
from jaxflex.model_sets import ModelSet, models_of
from jaxflex.path import Cycle, Path
from jaxflex.progress import Progress
from jaxflex.robot import Robot
from jaxflex.servo import Servo, cycle_servo, feedforward_advance, with_rotor
from jaxflex.simulate import Grid
from jaxflex.uncertainty import Box, ModelId

DEFAULT_RATE_HZ = 8000.0
DEFAULT_ROTOR = 0.01        # kg m^2


@dataclasses.dataclass(frozen=True)
class ServoBox:
    """The controller's uncertainty (module docstring): ``fc`` the relative half-width of the
    achieved bandwidth, ``rates`` the (low, high) servo rate [Hz]."""

    fc: float = 0.2
    rates: tuple = (4000.0, 16000.0)

    def checked(self) -> "ServoBox":
        fc = checks.nonnegative("servo box fc", self.fc)
        if fc >= 1:
            raise ValueError(f"servo box fc must be a relative half-width < 1, got {fc:g}")
        lo, hi = (checks.positive("servo box rate", r, "Hz") for r in self.rates)
        if lo > hi:
            raise ValueError(f"servo box rates must be (low, high), got ({lo:g}, {hi:g})")
        return ServoBox(fc, (lo, hi))


class ServoModel(NamedTuple):
    """One closed-loop model: the robot's ``ModelId``, the achieved bandwidth's factor and the rate."""

    model: ModelId
    fc_scale: float = 1.0
    rate: float | None = None       # None: the nominal servo's

    @property
    def label(self) -> str:
        rate = "" if self.rate is None else f", {self.rate / 1e3:.4g} kHz"
        fc = "" if self.fc_scale == 1.0 else f", fc x{self.fc_scale:.4g}"
        return f"{self.model.label}{fc}{rate}"


def servo_of(nominal: Servo, which: ServoModel) -> Servo:
    """The servo a model of the box runs: the nominal one's gains scaled for the achieved bandwidth,
    its rate, and the nominal rotor inertia scaled by the model's rotor factor."""
    f = float(which.fc_scale)
    rate = nominal.rate if which.rate is None else jnp.asarray(float(which.rate))
    return dataclasses.replace(nominal, kp=nominal.kp * f**2, kd=nominal.kd * f, rate=rate,
                               rotor_inertia=nominal.rotor_inertia * which.model.rotor_scale,
                               fc=nominal.fc * f).checked()


def random_models(payload: float, box: Box, servo_box: ServoBox, n: int, seed: int = 0) -> tuple:
    """``n`` closed-loop models drawn uniformly in both boxes (the robot's as ``Box.random``, the same
    seed; then the bandwidth factor and the rate, uniform), the nominal one first. ``ServoModel``s."""
    sb = servo_box.checked()
    robots = box.random([payload], n, seed)
    rng = np.random.default_rng(seed + 1)
    u = rng.uniform(-1.0, 1.0, size=(n, 2))
    rates = sb.rates[0] + (sb.rates[1] - sb.rates[0]) * 0.5 * (u[:, 1] + 1.0)
    return (ServoModel(ModelId(float(payload))),) + tuple(
        ServoModel(m, float(1 + sb.fc * u[k, 0]), float(rates[k])) for k, m in enumerate(robots))


def corner_models(payload: float, box: Box, servo_box: ServoBox) -> tuple:
    """The corners of both boxes along the factors that move the closed loop most: E, the payload,
    the rotor, the bandwidth and the rate (damping at the box's low end, nominal link lengths):
    2^5 ``ServoModel``s."""
    b, sb = box.checked(), servo_box.checked()
    out = []
    for k in (1 - b.young, 1 + b.young):
        for ps in (1 - b.payload, 1 + b.payload):
            for rs in (1 - b.rotor, 1 + b.rotor):
                for f in (1 - sb.fc, 1 + sb.fc):
                    for rate in sb.rates:
                        out.append(ServoModel(ModelId(float(payload), float(ps), float(k), b.damping[0], 0.0, 0.0,
                                                      float(rs)), float(f), float(rate)))
    return tuple(out)


def model_robots(robot: Robot, cycle: Cycle, nominal: Servo, which: Sequence[ServoModel]) -> tuple:
    """(ModelSet, servos): the robots of ``which`` built from ``robot`` carrying the nominal rotor
    inertia (so that each model's rotor factor applies), and each model's servo (``servo_of``)."""
    base = with_rotor(robot, nominal)
    return models_of(base, [w.model for w in which], cycle), [servo_of(nominal, w) for w in which]


class Trajectory(NamedTuple):
    """A candidate: its path, its law (a ``Profile``, or a function grid -> ``MotionSamples`` for
    sampled laws such as Ruckig's) and the feedforward kind its controller is given."""

    path: Path
    law: object
    feedforward: str = "rigid"


def evaluate(trajectories: dict, robot: Robot, cycle: Cycle, tf: float, dwell: float, grid: Grid, fc: float,
             which: Sequence[ServoModel], *, rate: float = DEFAULT_RATE_HZ, rotor: float = DEFAULT_ROTOR,
             progress: bool = False) -> dict:
    """Every trajectory (name -> ``Trajectory``) under the servo of bandwidth fc [Hz] (``cycle_servo``
    on ``robot``, at ``rate`` [Hz] with ``rotor`` [kg m^2], the trajectory's feedforward kind) on the
    closed-loop models ``which``: name -> metrics dict name -> (K,) numpy arrays."""
    out = {}
    bar = Progress(f"closed loop at fc {fc:g} Hz on {len(which)} models", total=len(trajectories), unit="law",
                   enabled=progress)
    with bar:
        for name, tr in trajectories.items():
            nominal = cycle_servo(robot, cycle, fc, rate=rate, rotor_inertia=rotor, feedforward=tr.feedforward)
            models, servos = model_robots(robot, cycle, nominal, which)
            ev = LawEvaluator(models, tr.path, tf, dwell, grid, keep=False, servo=servos,
                              controller=with_rotor(robot, nominal), advance=float(feedforward_advance(nominal)))
            law = tr.law(ev.grid) if callable(tr.law) else tr.law
            out[name] = ev(law)
            bar.update(note=name)
    return out


def summary(metrics: dict) -> dict:
    """The closed-loop figures of one trajectory on a set whose first model is the nominal one:
    dwell residual [um] nominal, worst, 95th percentile and median, and the nominal peak torque [N m]."""
    r = np.asarray(metrics["dwell_residual_mm"]) * 1e3
    return {"nominal_um": float(r[0]), "worst_um": float(np.max(r)), "p95_um": float(np.percentile(r, 95)),
            "median_um": float(np.median(r)), "max_torque_nm": float(np.asarray(metrics["max_torque_nm"])[0])}


def train_models(payload: float, box: Box, servo_box: ServoBox) -> tuple:
    """The closed-loop training models: the nominal one, then the corners of E, the payload and the
    achieved bandwidth with the rate at its low end (the longest hold) and at its high end. The
    rotor's and the rate's effects are smaller (``corner_models`` checks them). 9 ``ServoModel``s."""
    b, sb = box.checked(), servo_box.checked()
    out = [ServoModel(ModelId(float(payload)))]
    for k, ps, f, rate in ((1 - b.young, 1 - b.payload, 1 - sb.fc, sb.rates[0]),
                           (1 - b.young, 1 + b.payload, 1 + sb.fc, sb.rates[1]),
                           (1 + b.young, 1 - b.payload, 1 + sb.fc, sb.rates[0]),
                           (1 + b.young, 1 + b.payload, 1 - sb.fc, sb.rates[1]),
                           (1 - b.young, 1 - b.payload, 1 + sb.fc, sb.rates[1]),
                           (1 - b.young, 1 + b.payload, 1 - sb.fc, sb.rates[0]),
                           (1 + b.young, 1 - b.payload, 1 - sb.fc, sb.rates[1]),
                           (1 + b.young, 1 + b.payload, 1 + sb.fc, sb.rates[0])):
        out.append(ServoModel(ModelId(float(payload), float(ps), float(k), b.damping[0]), float(f), float(rate)))
    return tuple(out)


def closed_loop_objective(x0, robot: Robot, cycle: Cycle, tf: float, dwell: float, grid: Grid, fc: float,
                          which: Sequence[ServoModel], reference: dict, torque_bound: float, *,
                          feedforward: str = "flexible", rate: float = DEFAULT_RATE_HZ, rotor: float = DEFAULT_ROTOR,
                          blend: str = "smoothstep", order: int = 3, power: float = 8.0):
    """The design objective (``objective.DesignObjective``) with the servo in the loop: the closed
    loop's residual on the models ``which`` (the first the nominal one, whose model the
    feedforward of kind ``feedforward`` is computed on), in units of ``reference`` (a metrics dict,
    e.g. the best paper combination's closed-loop metrics on the nominal model: its
    ``residual_energy`` [J] and ``dwell_residual_mm`` [mm], first entry; one constant for every
    model, absolute as docs/conventions.md#uncertainty-box asks), the power mean of order ``power`` over the models,
    the peak torque bounded by ``torque_bound`` [N m] on every model. Returns (objective, params0)."""
    from jaxflex.servo_simulate import servo_grid
    from jaxflex import trees
    from jaxflex.tables import build_workspaces

    from .objective import DesignObjective, Scales, encode

    nominal = cycle_servo(robot, cycle, fc, rate=rate, rotor_inertia=rotor, feedforward=feedforward)
    models, servos = model_robots(robot, cycle, nominal, which)
    if which[0].model != ModelId(which[0].model.payload) or which[0].fc_scale != 1.0:
        raise ValueError("the first closed-loop model must be the nominal one (the feedforward's model)")
    k = len(which)
    fine = servo_grid(grid, tf, dwell, max(float(s.rate) for s in servos))
    robots = models.robots
    energy = float(np.ravel(reference["residual_energy"])[0])
    amp = float(np.ravel(reference["dwell_residual_mm"])[0]) * 1e-3
    scales = Scales(energy=jnp.full(k, energy), dwell_ms=jnp.full(k, amp**2 / 2),
                    torque_bound=jnp.full(k, float(torque_bound)))
    objective = DesignObjective(robots, cycle, jnp.asarray(float(tf)), jnp.asarray(float(dwell)), scales,
                                build_workspaces(robots, cycle), servos=trees.stack(servos, dtype=float),
                                advance=jnp.asarray(float(feedforward_advance(nominal))), grid=fine, blend=blend,
                                order=order, power=power, controller=0)
    return objective, encode(cycle, x0)
