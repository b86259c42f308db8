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
from typing import NamedTuple, Sequence

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

from .config import ROBUST_POWER, SCENARIO_POOL, SCENARIOS, SERVO_LEARNING_RATE, SERVO_OBJECTIVES, SERVO_TRAININGS

DEFAULT_RATE_HZ = 8000.0
SCENARIO_SEED = 1000        # the refinement's scenario pool: random models apart from the evaluation's (seed 0)
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
    groups = {}             # trajectories along one path with one feedforward kind share an evaluator
    for name, tr in trajectories.items():
        groups.setdefault((id(tr.path), tr.feedforward), []).append(name)
    bar = Progress(f"closed loop at fc {fc:g} Hz on {len(which)} models", total=len(trajectories), unit="law",
                   enabled=progress)
    with bar:
        for names in groups.values():
            tr = trajectories[names[0]]
            nominal = cycle_servo(robot, cycle, fc, rate=rate, rotor_inertia=rotor, feedforward=tr.feedforward)
            models, servos = model_robots(robot, cycle, nominal, which)
            ok = stable(models, servos, tr.path, tf + dwell)
            if not ok.any():
                raise ValueError(f"every closed loop of the set is unstable at fc {fc:g} Hz")
            kept = np.flatnonzero(ok)
            sub = ModelSet(jax.tree_util.tree_map(lambda a: a[kept], models.robots),
                           tuple(models.ids[i] for i in kept))
            ev = LawEvaluator(sub, tr.path, tf, dwell, grid, keep=False, servo=[servos[i] for i in kept],
                              controller=with_rotor(robot, nominal), advance=float(feedforward_advance(nominal)),
                              checked=True)        # ``stable`` has checked them, over the same duration
            laws = [trajectories[n].law for n in names]
            mets = ev.metrics_many([law(ev.grid) if callable(law) else law for law in laws])
            for name, met in zip(names, mets):
                full = {}
                for k, v in met.items():
                    a = np.full(len(which), np.nan)
                    a[kept] = np.asarray(v)
                    full[k] = a
                out[name] = full
                bar.update(note=name)
    return out


def stable(models: ModelSet, servos: Sequence[Servo], path: Path, duration: float) -> np.ndarray:
    """Whether each model's loop passes ``servo.check_stable`` along the path over ``duration`` [s]
    (bool (K,)). An unstable loop is the controller's defect, which no trajectory repairs: the
    closed-loop comparison leaves those models out and counts them."""
    from jaxflex.servo import check_stable

    out = []
    for robot, servo in zip(models.singles(), servos):
        try:
            check_stable(robot, servo, path, duration)
            out.append(True)
        except ValueError:
            out.append(False)
    return np.asarray(out)


def summary(metrics: dict) -> dict:
    """The closed-loop figures of one trajectory on a set whose first model is the nominal one:
    dwell residual [um] nominal, worst, 95th percentile and median, and the nominal peak torque [N m]."""
    r = np.asarray(metrics["dwell_residual_mm"]) * 1e3
    return {"nominal_um": float(r[0]), "worst_um": float(np.nanmax(r)), "p95_um": float(np.nanpercentile(r, 95)),
            "median_um": float(np.nanmedian(r)), "max_torque_nm": float(np.asarray(metrics["max_torque_nm"])[0]),
            "unstable": int(np.sum(np.isnan(r)))}


def train_models(payload: float, box: Box, servo_box: ServoBox) -> tuple:
    """The closed-loop training models: the nominal one, then the corners of E, the payload and the
    achieved bandwidth with the rate at its low end (the longest hold) and at its high end, the
    rotor at the payload's side of its box: a heavier payload with a heavier rotor (and a lighter
    with a lighter), the largest inertia error of the feedforward's model. At 0.1 kg, where the
    rotor is most of the motors' inertia, those are the box's worst models under a slow servo; at
    6 kg the payload error dominates and the worst models found had the rotor on the other side,
    which ``refine``'s scenarios add. ``corner_models`` checks every combination. 9 ``ServoModel``s."""
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
        rs = 1 + b.rotor * np.sign(ps - 1)
        out.append(ServoModel(ModelId(float(payload), float(ps), float(k), b.damping[0], 0.0, 0.0, float(rs)),
                              float(f), float(rate)))
    return tuple(out)


def training_models(payload: float, box: Box, servo_box: ServoBox, training: str = "fixed") -> tuple:
    """The refinement's fixed training models, the nominal one first: ``"fixed"`` the nine of
    ``train_models``; ``"corners"`` all 32 corners of both boxes (``corner_models``, 33 models: the
    box's worst case is a corner more often than not, and a design trained on a few of them trades
    the others away; every step then runs about four times as many rollouts)."""
    if training == "fixed":
        return train_models(payload, box, servo_box)
    if training == "corners":
        return (ServoModel(ModelId(float(payload))),) + corner_models(payload, box, servo_box)
    raise ValueError(f"training must be one of {', '.join(SERVO_TRAININGS)}, got {training!r}")


def worst_models(residual, which: Sequence[ServoModel], k: int, exclude: Sequence[ServoModel] = ()) -> tuple:
    """The ``k`` models of ``which`` with the largest residuals (``residual``: one value per model,
    NaN for an unstable loop, left out), largest first, skipping those in ``exclude``."""
    r = np.asarray(residual, dtype=float)
    if r.shape != (len(which),):
        raise ValueError(f"{r.shape[0] if r.ndim else 0} residuals for {len(which)} models")
    seen = set(exclude)
    out = []
    for i in np.argsort(-np.where(np.isnan(r), -np.inf, r), kind="stable"):
        if len(out) == k or np.isnan(r[i]):
            break
        if which[i] not in seen:
            out.append(which[i])
            seen.add(which[i])
    return tuple(out)


def _check_objective(objective: str) -> None:
    if objective not in SERVO_OBJECTIVES:
        raise ValueError(f"the closed-loop objective must be one of {', '.join(SERVO_OBJECTIVES)}, got {objective!r}")


def closed_loop_scales(reference: dict, k: int, torque_bound: float, objective: str = "dwell"):
    """The references (``objective.Scales``) of the closed-loop objective on k models, from the
    ``reference`` metrics (first entries of ``residual_energy`` [J] and ``dwell_residual_mm`` [mm]).

    ``objective`` "energy+dwell" is the perfect controller's residual r_k = (E_k / E_ref + A_k /
    A_ref) / 2 (``jaxflex.optimize.objective``). "dwell" keeps the dwell amplitude alone, r_k = A_k /
    A_ref: the energy's reference is infinite, so its term and its gradient are exactly zero, and the
    dwell's is halved, so that r_k = 1 is still the reference's own residual. Under the perfect
    controller the vibration energy at tf fixes the residual vibration of the dwell; under a servo it
    does not: the loop keeps acting after tf and damps the flexible modes' motion. On the box's
    corners at low servo rates the energy at tf of a good design is then up to several times the
    reference's while its dwell residual is a few hundredths of it, and a refinement that
    weighs the energy trades the dwell amplitude, which the comparison measures, for it
    (docs/conventions.md#servo). "peak" keeps the dwell's smooth maximum alone (``metrics.dwell_peak``:
    a power mean over the dwell samples standing in for the maximum the comparison reports, where
    the mean square weighs the whole dwell alike), r_k = P_k / D^2 with D the reference's dwell
    residual, so that r_k is at most 1 for a design as good as the reference (the smooth maximum lies
    below the maximum); the energy's and the mean square's references are infinite."""
    from .objective import Scales

    _check_objective(objective)
    amp = float(np.ravel(reference["dwell_residual_mm"])[0]) * 1e-3
    bound = jnp.full(k, float(torque_bound))
    if objective == "peak":
        inf = jnp.full(k, jnp.inf)
        return Scales(energy=inf, dwell_ms=inf, torque_bound=bound, dwell_peak=jnp.full(k, amp**2 / 2))
    if objective == "dwell":
        return Scales(energy=jnp.full(k, jnp.inf), dwell_ms=jnp.full(k, amp**2 / 4), torque_bound=bound)
    energy = float(np.ravel(reference["residual_energy"])[0])
    return Scales(energy=jnp.full(k, energy), dwell_ms=jnp.full(k, amp**2 / 2), torque_bound=bound)


def closed_loop_objective(x0, robot: Robot, cycle: Cycle, tf: float, dwell: float, grid: Grid, fc: float,
                          which: Sequence[ServoModel], reference: dict, torque_bound: float, *,
                          feedforward: str = "flexible", rate: float = DEFAULT_RATE_HZ, rotor: float = DEFAULT_ROTOR,
                          blend: str = "smoothstep", order: int = 3, power: float = 8.0, objective: str = "dwell"):
    """The design objective (``objective.DesignObjective``) with the servo in the loop: the closed
    loop's residual on the models ``which`` (the first the nominal one, whose model the
    feedforward of kind ``feedforward`` is computed on), in units of ``reference`` (a metrics dict,
    e.g. the best paper combination's closed-loop metrics on the nominal model: its
    ``residual_energy`` [J] and ``dwell_residual_mm`` [mm], first entry; one constant for every
    model, absolute as docs/conventions.md#uncertainty-box asks; ``closed_loop_scales``), the power
    mean of order ``power`` over the models, the peak torque bounded by ``torque_bound`` [N m] on
    every model; models whose loop is unstable along x0's path are left out (``stable``). The
    residual is the dwell amplitude alone (``objective`` "dwell") or with the vibration energy at
    tf beside it ("energy+dwell"). Returns (objective, params0, the models kept)."""
    from jaxflex.servo_simulate import servo_grid
    from jaxflex import trees
    from jaxflex.tables import build_workspaces

    from .objective import DesignObjective, encode

    from jaxflex.designs import design_path

    nominal = cycle_servo(robot, cycle, fc, rate=rate, rotor_inertia=rotor, feedforward=feedforward)
    if which[0].model != ModelId(which[0].model.payload) or which[0].fc_scale != 1.0:
        raise ValueError("the first closed-loop model must be the nominal one (the feedforward's model)")
    models, servos = model_robots(robot, cycle, nominal, which)
    ok = stable(models, servos, design_path(cycle, x0, blend), tf + dwell)
    if not ok[0]:
        raise ValueError(f"the nominal closed loop is unstable at fc {fc:g} Hz, {rate:g} Hz")
    which = tuple(w for w, keep in zip(which, ok) if keep)      # unstable loops: no trajectory repairs them
    models, servos = model_robots(robot, cycle, nominal, which)
    k = len(which)
    fine = servo_grid(grid, tf, dwell, max(float(s.rate) for s in servos))
    robots = models.robots
    scales = closed_loop_scales(reference, k, torque_bound, objective)
    design_objective = DesignObjective(robots, cycle, jnp.asarray(float(tf)), jnp.asarray(float(dwell)), scales,
                                       build_workspaces(robots, cycle, servo=True),
                                       servos=trees.stack(servos, dtype=float),
                                       advance=jnp.asarray(float(feedforward_advance(nominal))), grid=fine,
                                       blend=blend, order=order, power=power, controller=0)
    return design_objective, encode(cycle, x0), which


class Controller(NamedTuple):
    """The controller a closed-loop study sets up: the bandwidth ``fc`` [Hz] it is trained at, the
    ``rate`` [Hz], the ``rotor`` inertia [kg m^2] and the ``feedforward`` kind of the optimized
    design (the paper's combinations and the industrial baselines get the rigid one, what a
    controller with a rigid model computes)."""

    fc: float
    rate: float = DEFAULT_RATE_HZ
    rotor: float = DEFAULT_ROTOR
    feedforward: str = "flexible"


def paper_under_servo(robot: Robot, cycle: Cycle, payload: float, tf: float, dwell: float, fc: float,
                      controller: Controller, progress: bool = False) -> tuple:
    """The 12 paper combinations under the servo of bandwidth fc (rigid feedforward) on the nominal
    robot: (metrics name -> (B, P) arrays, blends, profiles, (blend, law) of the least dwell residual)."""
    from jaxflex.sweep import Case, SweepConfig, run_sweep

    servo = cycle_servo(robot.replace(payload=payload), cycle, fc, rate=controller.rate, rotor_inertia=controller.rotor,
                        feedforward="rigid")
    # on the study's grid, as every other trajectory of the comparison (no estimate, which could move
    # the paper's combinations to a refined grid): its accuracy is docs/conventions.md#accuracy's
    res = run_sweep(robot, cycle, (Case(payload, tf),), SweepConfig(dwell=dwell, servo=servo, timed=False,
                                                                    progress=progress, estimate=False))
    m = {k: np.asarray(v)[..., 0] for k, v in res.metrics.items()}
    i, j = np.unravel_index(np.argmin(m["dwell_residual_mm"]), m["dwell_residual_mm"].shape)
    return m, res.blends, res.profiles, (res.blends[i], res.profiles[j])


def _perfect(path: Path, law, robot: Robot, payload: float, tf: float, dwell: float, grid: Grid) -> dict:
    from jaxflex.model_sets import model_set

    ev = LawEvaluator(model_set(robot, [payload]), path, tf, dwell, grid)
    return ev(law(ev.grid) if callable(law) else law)


def refine(x0, robot: Robot, cycle: Cycle, payload: float, tf: float, dwell: float, grid: Grid,
           controller: Controller, reference: dict, torque_bound: float, *, steps: int = 20,
           learning_rate: float = SERVO_LEARNING_RATE, box: Box = Box(), servo_box: ServoBox = ServoBox(),
           blend: str = "smoothstep",
           order: int = 3, scenarios: int = SCENARIOS, pool: int = SCENARIO_POOL, pool_seed: int = SCENARIO_SEED,
           training: str = "fixed", power: float = ROBUST_POWER, objective: str = "dwell", progress: bool = False):
    """The design x0 refined with the servo in the loop: Adam on ``closed_loop_objective`` (the power
    mean of order ``power`` over the models: larger is closer to the worst model; ``objective`` the
    residual minimized on each, ``closed_loop_scales``) over
    ``training_models`` (``training``: "fixed", the nominal model and eight corners of E, payload
    with the rotor, bandwidth and rate; "corners", all 32) and ``scenarios`` more: the models on which x0 does worst among ``pool`` random models
    of both boxes (drawn with ``pool_seed``, apart from the evaluation's) and the 32 corners (a
    scenario set for the worst case: the fixed corners miss the box's worst combinations, e.g. a
    rotor error at 0.1 kg), at the controller's bandwidth, the gradient through the closed-loop
    rollouts (one program, reverse mode). Returns (design, ``OptResult``, the training models
    kept: ``closed_loop_objective``)."""
    from jaxflex.designs import design_path
    from jaxflex.profiles import shaped

    from .config import OptimizerConfig
    from .gradient import OneProgram
    from .loop import minimize
    from .objective import decode

    scenarios = checks.count("scenarios", scenarios, minimum=0)
    power = checks.positive("power", power)
    _check_objective(objective)
    which = training_models(payload, box, servo_box, training)
    if scenarios:
        candidates = random_models(payload, box, servo_box, checks.count("pool", pool, minimum=0),
                                   pool_seed)[1:] + corner_models(payload, box, servo_box)
        trial = Trajectory(design_path(cycle, x0, blend), shaped(jnp.asarray(x0.coef), order), controller.feedforward)
        met = evaluate({"design": trial}, robot.replace(payload=payload), cycle, tf, dwell, grid, controller.fc,
                       candidates, rate=controller.rate, rotor=controller.rotor, progress=progress)["design"]
        which = which + worst_models(met["dwell_residual_mm"], candidates, scenarios, exclude=which)
    design_objective, p0, which = closed_loop_objective(
        x0, robot.replace(payload=payload), cycle, tf, dwell, grid, controller.fc, which, reference, torque_bound,
        feedforward=controller.feedforward, rate=controller.rate, rotor=controller.rotor, blend=blend, order=order,
        power=power, objective=objective)
    config = OptimizerConfig(steps=steps, learning_rate=learning_rate, patience=max(steps, 1), progress=progress,
                             label=f"closed loop fc={controller.fc:g}")
    result = minimize(design_objective, p0, (), config, gradient=OneProgram(build="quick"))
    return jax.tree_util.tree_map(np.asarray, decode(cycle, result.params)), result, which


def closed_loop_study(robot: Robot, cycle: Cycle, payload: float, tf: float, dwell: float, grid: Grid, design,
                      law, controller: Controller, *, fcs: Sequence[float] = (15.0, 40.0), steps: int = 0,
                      samples: int = 200, corners: bool = True, box: Box = Box(), servo_box: ServoBox = ServoBox(),
                      blend: str = "smoothstep", order: int = 3, first_mode_hz: float | None = None,
                      ruckig: bool = True, learning_rate: float = SERVO_LEARNING_RATE, seed: int = 0,
                      scenarios: int = SCENARIOS,
                      training: str = "fixed", power: float = ROBUST_POWER, rounds: int = 1,
                      objective: str = "dwell", progress: bool = False) -> dict:
    """The designs under the servo (module docstring), as a JSON-ready record.

    ``design`` (a ``Design`` of the ``blend`` family) with its shaped ``law`` is the perfect
    controller's optimized design. With ``steps`` > 0 it is first refined with the servo in the loop
    at ``controller.fc`` (``refine``: the closed-loop residual in units of the best paper
    combination's under the same servo, the peak torque bounded by poly7-Lamé's; ``training``,
    ``power``, ``scenarios``, ``learning_rate`` and ``objective`` as ``refine`` takes them), ``rounds`` times in a
    row: each round starts from the last one's design and picks its scenarios again, on the models
    where that design does worst. At every
    bandwidth of ``fcs`` and the controller's, the 12 paper combinations are run under the servo
    (rigid feedforward) on the nominal robot; the best of them, its ZV/ZVD versions (first mode
    ``first_mode_hz``), the Ruckig profile on its path and poly7-Lamé (rigid feedforward), and the
    optimized design (the controller's feedforward kind) are then evaluated on the nominal model,
    ``samples`` random models of both boxes (drawn with ``seed``) and (``corners``) their 32 corners
    (``corner_models``), beside their perfect-controller residual on the nominal model. The
    refinement's scenarios come from its own pool (``refine``) and the corners, so the random models
    stay unseen, while the corners may have been trained on."""
    from jaxflex.designs import design_path
    from jaxflex.path import make_path
    from jaxflex.profiles import make_profile, shaped

    from .baselines import ruckig_samples, shaper_profiles

    started = time.time()
    rounds = checks.count("rounds", rounds, minimum=1)
    training_models(payload, box, servo_box, training)          # a bad choice fails before the sweeps
    power = checks.positive("power", power)
    _check_objective(objective)
    fc_all = sorted(set(float(f) for f in fcs) | {float(controller.fc)})
    nominal_robot = robot.replace(payload=payload)
    sweeps = {fc: paper_under_servo(robot, cycle, payload, tf, dwell, fc, controller, progress) for fc in fc_all}
    rec = {"controller": controller._asdict(), "payload": payload, "tf": tf, "dwell": dwell,
           "box": dataclasses.asdict(box.checked()), "servo_box": dataclasses.asdict(servo_box.checked()),
           "samples": samples, "seed": seed, "corners": bool(corners), "paper": {}, "fcs": {}}
    for fc, (m, blends, profiles, best) in sweeps.items():
        rec["paper"][f"{fc:g}"] = {"best": "/".join(best), "dwell_residual_um": {
            f"{b}/{p}": float(m["dwell_residual_mm"][i, j]) * 1e3 for i, b in enumerate(blends)
            for j, p in enumerate(profiles)}}
    x = design
    if steps > 0:
        m, blends, profiles, best = sweeps[float(controller.fc)]
        i, j = blends.index(best[0]), profiles.index(best[1])
        reference = {k: m[k][i, j] for k in ("residual_energy", "dwell_residual_mm")}
        bound = float(m["max_torque_nm"][blends.index("lame"), profiles.index("poly7")])
        done = []
        for r in range(rounds):
            if progress and rounds > 1:
                print(f"closed-loop refinement, round {r + 1} of {rounds}", flush=True)
            x, result, trained = refine(x, robot, cycle, payload, tf, dwell, grid, controller, reference, bound,
                                        steps=steps, learning_rate=learning_rate, box=box, servo_box=servo_box,
                                        blend=blend, order=order, scenarios=scenarios, training=training, power=power,
                                        objective=objective, progress=progress)
            done.append({"history": [list(map(float, h)) for h in result.history], "steps_run": result.steps_run,
                         "training_models": [w.label for w in trained]})
        law = shaped(jnp.asarray(x.coef), order, name="optimized")
        rec["refined"] = {**done[-1], "rounds": done, "training": training, "power": power, "objective": objective,
                          "learning_rate": learning_rate, "scenarios": scenarios,
                          "torque_bound_nm": bound, "design": {"corners": [
                              {"d_m": float(x.d[k]), "e_m": float(x.e[k]), "n": float(x.n[k])} for k in range(2)],
                              "coef": np.asarray(x.coef).tolist()}}
    which = (random_models(payload, box, servo_box, samples, seed) if samples else (ServoModel(ModelId(float(payload))),))
    if corners:
        which = which + corner_models(payload, box, servo_box)
    opt_path = design_path(cycle, x, blend)
    for fc in fc_all:
        _, _, _, (b, p) = sweeps[fc]
        paper_path = make_path(cycle, b, 0.025)
        trs = {"optimized": Trajectory(opt_path, law, controller.feedforward),
               f"{b}/{p} (best paper)": Trajectory(paper_path, make_profile(p), "rigid")}
        if first_mode_hz is not None:
            for prof in shaper_profiles(p, first_mode_hz, tf):
                trs[f"{b}/{prof.name}"] = Trajectory(paper_path, prof, "rigid")
        if ruckig:
            try:
                ruckig_samples(float(paper_path.length), tf, grid)
                trs[f"{b}/ruckig"] = Trajectory(paper_path, lambda g, L=float(paper_path.length):
                                                ruckig_samples(L, tf, g)[0], "rigid")
            except ImportError:
                pass
        trs["lame/poly7"] = Trajectory(make_path(cycle, "lame", 0.025), make_profile("poly7"), "rigid")
        out = evaluate(trs, robot.replace(payload=payload), cycle, tf, dwell, grid, fc, which, rate=controller.rate,
                       rotor=controller.rotor, progress=progress)
        n_random = 1 + samples if samples else 1
        row = {}
        for name, tr in trs.items():
            met = out[name]
            perfect = _perfect(tr.path, tr.law, nominal_robot, payload, tf, dwell, grid)
            r = np.asarray(met["dwell_residual_mm"]) * 1e3
            row[name] = {**summary({k: np.asarray(v)[:n_random] for k, v in met.items()}),
                         "box_worst_um": float(np.nanmax(r)), "box_unstable": int(np.sum(np.isnan(r))),
                         "box_models": int(r.size),
                         "perfect_um": float(np.asarray(perfect["dwell_residual_mm"])[0]) * 1e3,
                         "perfect_max_torque_nm": float(np.asarray(perfect["max_torque_nm"])[0]),
                         "feedforward": tr.feedforward}
        paper = row[f"{b}/{p} (best paper)"]
        for v in row.values():
            v["ratio_best_paper_nominal"] = paper["nominal_um"] / v["nominal_um"]
            v["ratio_best_paper_worst"] = paper["box_worst_um"] / v["box_worst_um"]
        rec["fcs"][f"{fc:g}"] = row
    rec["wall_s"] = time.time() - started
    return rec
