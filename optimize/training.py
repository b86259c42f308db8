"""What a design trains on: the training sets of models, the objective's scales, and the trainings.

Training sets (a design counts only if its advantage survives model error,
docs/conventions.md#uncertainty-box): ``box`` (the default: a grid over the uncertainty box,
``jaxflex.uncertainty.Box.grid``), ``nominal`` (the payloads), ``spanning`` (per payload the
nominal model and the four corners of the perturbation box E x {0.95, 1.05}, payload x {0.9, 1.1};
the evaluation's four edge midpoints stay unseen) or ``perturbed`` (all nine models of the
evaluation box per payload).

The scales (``objective.Scales``) put each model's residual in units of a reference law's; the
torque bound per model is poly7-Lamé's peak torque. ``train_design`` optimizes a design (blends
and law, the staged gradient) and ``train_law`` a law alone on a fixed path (one program).
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks, trees
from jaxflex.designs import Design, design
from jaxflex.engine import LawEvaluator
from jaxflex.model_sets import ModelSet, model_set, models_of
from jaxflex.path import Cycle, make_path
from jaxflex.problem import Timing
from jaxflex.profiles import make_profile
from jaxflex.robot import Robot
from jaxflex.simulate import Grid, check_grid
from jaxflex.tables import build_workspaces
from jaxflex.uncertainty import Box, ModelId
from jaxflex.workspace import Workspace

from .config import BLEND_FAMILY, TRAINING, TRAINING_SETS, TrainConfig, dwell_residuals
from .gradient import OneProgram
from .loop import OptResult, minimize
from .objective import DesignObjective, LawObjective, Params, Scales
from .staged import Staged

PERTURB_E = (0.95, 1.0, 1.05)
PERTURB_PAYLOAD = (0.9, 1.0, 1.1)
SPANNING = ((1.0, 1.0), (0.95, 0.9), (0.95, 1.1), (1.05, 0.9), (1.05, 1.1))   # (E factor, payload factor)
START_E = {"smoothstep": 0.08}      # start: e [m] per family (default 25 mm, the paper's); the smoothstep
                                    # blend needs a long horizontal part to spread its turn
START_D_FRACTION = 0.98             # start: d = 0.98 h (d = h is the open end of the decoded range)
LAW_TRAINING = TrainConfig(optimizer=dataclasses.replace(TRAINING, label="law"))


def training_models(robot: Robot, payloads: Sequence[float], kind: str = "spanning", *, box: Box = Box(),
                    points: int = 3, cycle: Cycle | None = None) -> ModelSet:
    """The models an optimization trains on (module docstring): ``kind`` one of ``TRAINING_SETS``;
    labels name each model. ``box``:
    ``box.grid(payloads, points)`` (``cycle`` needed if the box's low damping is > 0)."""
    if kind == "box":
        return models_of(robot, box.grid(payloads, points), cycle)
    if kind == "nominal":
        return model_set(robot, payloads)
    if kind == "perturbed":
        return model_set(robot, payloads, stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD)
    if kind == "spanning":
        sets = [model_set(robot, [m], stiffness=(k,), payload_scale=(p,)) for m in payloads for k, p in SPANNING]
        robots = trees.concatenate([s.robots for s in sets])
        return ModelSet(robots, tuple(i for s in sets for i in s.ids))
    raise ValueError(f"unknown training set {kind!r}; choose one of {TRAINING_SETS}")


def nominal_indices(models: ModelSet, payloads: Sequence[float]) -> np.ndarray:
    """Index in ``models`` of the nominal model (``ModelId.nominal``) of each payload [kg]."""
    out = []
    for p in payloads:
        if ModelId(float(p)) not in models.ids:
            raise ValueError(f"no nominal {p:g} kg model among {list(models.labels)}")
        out.append(models.index(ModelId(float(p))))
    return np.asarray(out, dtype=int)


def nominal_of_each(models: ModelSet) -> np.ndarray:
    """Index (K,) of the nominal model of each model's payload case."""
    return np.asarray([models.index(ModelId(i.payload)) for i in models.ids], dtype=int)


def subset(models: ModelSet, idx) -> ModelSet:
    """The models at the positions ``idx`` of ``models``, in that order."""
    idx = [int(i) for i in idx]
    return ModelSet(jax.tree_util.tree_map(lambda a: a[np.asarray(idx)], models.robots),
                    tuple(models.ids[i] for i in idx))


def start_design(cycle: Cycle, n_coef: int = 6, blend: str = BLEND_FAMILY) -> Design:
    """The starting design: d = 0.98 h, e = ``START_E[blend]`` (default 25 mm: the paper's Lamé path
    with n = 3) at both corners, with poly7 (the shaped law with equal coefficients)."""
    return design(START_D_FRACTION * float(cycle.h), START_E.get(blend, 0.025), 3.0, np.ones(n_coef))


def torque_bounds(models: ModelSet, cycle: Cycle, tf: float, dwell: float, grid: Grid,
                  evaluator: LawEvaluator | None = None) -> np.ndarray:
    """Peak torque bound [N m] per model (K,): the poly7-Lamé combination's (d = e = 25 mm) peak
    torque on that model at motion time tf [s] (a heavier perturbed payload gets its own bound).
    ``evaluator``: one already built for these models, reused if its path is the Lamé one."""
    if evaluator is None or evaluator.path.kind != "lame" or evaluator.models is not models:
        evaluator = LawEvaluator(models, make_path(cycle, "lame", 0.025), tf, dwell, grid)
    return evaluator(make_profile("poly7"), tf=tf)["max_torque_nm"]


def training_weights(kind: str, n_payloads: int = 1) -> np.ndarray:
    """Weights of the training models in the objective's mean (the payloads share it equally): a
    probability over the perturbation box concentrated at the nominal model. ``spanning``: 1/2 for
    the nominal model, 1/8 for each corner; ``perturbed``: Simpson's tensor weights (1, 4, 1)/6 per
    axis (4/9 nominal, 1/9 edge midpoints, 1/36 corners); ``nominal``: 1; ``box``: None (equal
    weights: with the power mean of ``ROBUST_POWER`` every sample of the box counts as a worst case)."""
    if kind == "box":
        return None                                     # equal weights: the box's samples are its worst case
    if kind == "nominal":
        w = np.ones(1)
    elif kind == "spanning":
        w = np.array([0.5, 0.125, 0.125, 0.125, 0.125])
    elif kind == "perturbed":
        simpson = np.array([1.0, 4.0, 1.0]) / 6.0
        w = np.outer(simpson, simpson).ravel()          # model_set order: E outer, payload inner
    else:
        raise ValueError(f"unknown training set {kind!r}; choose one of {TRAINING_SETS}")
    return np.tile(w, n_payloads) / n_payloads


def reference_scales(evaluator: LawEvaluator, law, torque_bound, tf: float | None = None,
                     weights=None, absolute: bool = False) -> Scales:
    """Objective scales from the reference law's residuals at motion time tf [s] (default: the
    evaluator's) on the evaluator's models (``scales_from_metrics``; with ``absolute`` every model
    of a payload is scaled by the reference on that payload's nominal model); torque bound per
    model (K,) [N m]; ``weights`` (K,) of the models (None: equal)."""
    return scales_from_metrics(evaluator(law, tf=tf), torque_bound, weights, evaluator.models if absolute else None)


def scales_from_metrics(ref: dict, torque_bound, weights=None, models: ModelSet | None = None) -> Scales:
    """``reference_scales`` from the reference law's metrics (name -> (K,)) on the models. With
    ``models`` the scales are absolute (docs/conventions.md#optimization): every model of a payload
    case is divided by the reference's vibration energy and mean-square dwell amplitude on that
    case's nominal model, the same constants for the whole case, so the objective compares absolute
    residuals across the perturbed models (a per-model reference would follow its own luck: the paper
    combinations' residuals swing widely with small model changes, docs/conventions.md#uncertainty-box).
    Without ``models``: each model by its own."""
    energy = np.asarray(ref["residual_energy"], dtype=float)
    amp = np.asarray(ref["dwell_residual_mm"], dtype=float) * 1e-3
    if models is not None:
        idx = nominal_of_each(models)
        energy, amp = energy[idx], amp[idx]
    return Scales(energy=jnp.asarray(energy), dwell_ms=jnp.asarray(amp**2 / 2),
                  torque_bound=jnp.asarray(torque_bound, dtype=float),
                  weights=None if weights is None else jnp.asarray(weights, dtype=float))


class Training(NamedTuple):
    """What ``train_design`` optimizes a design on: the ``models`` (a ``ModelSet``, stacked), the
    ``cycle``, the ``timing`` (tf [s], dwell [s] and the rollout grid, which must be given), the
    normalization ``scales`` (``objective.Scales``, one per model) and the models' ``workspaces``
    (``jaxflex.workspace``; None: built from the models)."""

    models: ModelSet
    cycle: Cycle
    timing: Timing
    scales: Scales
    workspaces: Workspace | None = None


def train_design(training: Training, init: Params, config: TrainConfig = TrainConfig(),
                 gradient=Staged()) -> OptResult:
    """Optimize the design parameters (start ``init``) on ``training`` (its models at its motion
    time with its normalization; ``Training``) as ``config`` says (``TrainConfig``), the gradient
    as the strategy ``gradient`` computes it (default: the rollout's stages, ``staged.Staged``, its
    build chosen by the number of steps). The path tables inside the objective come from
    the models' workspace tables (``jaxflex.workspace``, built here unless ``training.workspaces``
    holds them): the gradient compiles much sooner than through the model's table build."""
    _check_training(training.timing.tf, training.timing.dwell, config)
    return minimize(design_objective(training, config), init, (), _optimizer(config), gradient=gradient)


def design_objective(training: Training, config: TrainConfig = TrainConfig()) -> DesignObjective:
    """The design objective on ``training`` (its models, cycle, timing, scales and workspace tables,
    built here if None; the scales and workspaces may be ``jax.ShapeDtypeStruct`` shapes, to compile
    ahead) with ``config``'s power, law order and blend, exactly as ``train_design`` hands it to the
    optimizer, so that ``Staged().value_and_grad(objective, params)`` is the optimizer's own value
    and gradient (one set of compiled programs per grid)."""
    models, cycle, (tf, dwell, grid), scales, workspaces = training
    if grid is None:
        raise ValueError("the design objective needs the timing's grid (jaxflex.sweep.default_grid gives the "
                         "default one)")
    check_grid(grid)
    if workspaces is None:
        workspaces = build_workspaces(models.robots, cycle)
    return DesignObjective(models.robots, cycle, host_scalar(tf), host_scalar(dwell), canonical(scales), workspaces,
                           grid=grid, blend=config.blend, order=int(config.order), power=float(config.power))


def abstract_scales(k: int, weights) -> Scales:
    """The shapes (``jax.ShapeDtypeStruct``) of the scales ``design_objective`` hands the optimizer
    for k models (weights None or (k,)): to compile the gradient before the scales are known."""
    v = jax.ShapeDtypeStruct((k,), jnp.float64)
    return Scales(energy=v, dwell_ms=v, torque_bound=v, weights=None if weights is None else v)


def host_scalar(v):
    """A strongly typed float64 array on the device (a Python float would be weakly typed)."""
    return jax.device_put(np.asarray(v, dtype=np.float64))


def canonical(scales: Scales) -> Scales:
    """Scales as strongly typed float64 arrays: a weakly typed value (e.g. ``jnp.full(1, 1e-3)``)
    would give the same objective a second compiled program."""
    return Scales(*(v if v is None or isinstance(v, jax.ShapeDtypeStruct) else host_scalar(v) for v in scales))


def train_law(evaluator: LawEvaluator, scales: Scales, init, config: TrainConfig = LAW_TRAINING,
              gradient=OneProgram()) -> OptResult:
    """Optimize the shaped-law coefficients (start ``init`` (m + 1,)) on the training models of
    ``evaluator`` (along its path, at its motion time tf [s], dwell and grid, with its tables) with
    the normalization ``scales``, as ``config`` says (``TrainConfig``; its blend is not used)."""
    _check_training(evaluator.tf, evaluator.dwell, config)
    return minimize(law_objective(evaluator, scales, config), jnp.asarray(init, dtype=float), (), _optimizer(config),
                    gradient=gradient)


def law_objective(evaluator: LawEvaluator, scales: Scales, config: TrainConfig = LAW_TRAINING) -> LawObjective:
    """The law objective on ``evaluator``'s path, models, tf, dwell, grid and tables, with the
    normalization ``scales`` and ``config``'s power and law order, as ``train_law`` hands it to the
    optimizer."""
    check_grid(evaluator.grid)
    return LawObjective(evaluator.tables, jnp.asarray(evaluator.path.length, dtype=float), host_scalar(evaluator.tf),
                        host_scalar(evaluator.dwell), canonical(scales), evaluator.models.robots,
                        grid=evaluator.grid, order=int(config.order), power=float(config.power))


def _check_training(tf, dwell, config: TrainConfig) -> None:
    if not isinstance(config, TrainConfig):
        raise TypeError(f"config must be a TrainConfig, got {type(config).__name__}")
    checks.positive("tf", tf, "s")
    checks.positive("dwell", dwell, "s")
    checks.count("steps", config.optimizer.steps, 0)
    checks.positive("learning_rate", config.optimizer.learning_rate)


def _optimizer(config: TrainConfig):
    """The training's optimizer configuration: the training models' dwell residuals recorded at
    every step unless it has a monitor of its own."""
    o = config.optimizer
    return o if o.monitor is not None else dataclasses.replace(o, monitor=dwell_residuals)
