"""Trajectory optimization against the paper's best combination and the industrial baselines.

``optimize_design`` is the whole study for one or several payloads at a fixed motion time:

1. the 12 paper combinations, simulated on the nominal model of each payload (``paper_sweep``),
   give the best one (smallest dwell residual; for several payloads the smallest worst-case ratio
   to each payload's best) and the objective's scales (the best combination's residuals); poly7-Lamé
   on every training model gives the torque bound of each (``_training_references``; with per-model
   scales or the law-only optimizer the best combination runs on every training model too);
2. a design (the blend parameters of each corner, by default of the G4 ``smoothstep`` family, and
   a shaped monotone motion law, ``jaxflex.designs``) is optimized by gradient (reverse mode
   through the workspace tables and the whole second-order rollout, optax Adam) on the training
   models. By default (``StudyConfig``: absolute, ``robust_power=ROBUST_POWER``) the objective is a
   smooth worst case (power mean) of their absolute residuals, in units of the best paper
   combination's residual on the payload's nominal model (SPEC 6); with ``absolute=False`` each
   model is normalized by the best paper combination on the same model. It starts from
   ``start_design`` with poly7. With ``free_path=False`` only the law is optimized, on the best
   paper combination's path;
3. the optimized design and every baseline (best paper combination, its ZV/ZVD shaping, Ruckig along
   the best paper path) are evaluated on the same models: nominal, perturbed (E x {0.95, 1, 1.05},
   payload x {0.9, 1, 1.1}), with 1 % damping at the first mode, on random models of the
   uncertainty box and on the richer validation model (``evaluation_sets``).

Time: the design gradient compiles in a background thread from the start, while the workspace tables
are built and the paper sweep runs
(``loop.compile_gradient_ahead``), and the evaluation sets with every baseline on them, which do
not depend on the design, are computed beside the optimizer (``jaxflex.runtime.threads.Beside``); only the optimized
design is evaluated after it. The results are those of the sequential order, bit for bit.

Training sets (SPEC 6: a design counts only if its advantage survives model error): ``box``
(default: a grid over the uncertainty box, ``jaxflex.uncertainty.Box.grid``), ``nominal``
(the payloads), ``spanning`` (per payload the nominal model and the four corners of the
perturbation box E x {0.95, 1.05}, payload x {0.9, 1.1}; the evaluation's four edge midpoints stay
unseen) or ``perturbed`` (all nine models of the evaluation box per payload).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import pathlib
import time
import zipfile
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex import checks
from jaxflex.blends import DESIGN_BLENDS
from jaxflex.designs import Design, design, design_path
from jaxflex.engine import LawEvaluator
from jaxflex.model import richer
from jaxflex.model_sets import ModelId, ModelSet, model_set, models_of, place_first_mode_hz
from jaxflex.runtime.threads import Beside
from jaxflex.path import Cycle, make_path
from jaxflex.problem import Problem, Timing
from jaxflex.profiles import make_profile, shaped
from jaxflex.progress import Progress
from jaxflex.robot import Robot, check_cycle_reachable
from jaxflex.simulate import Grid, check_grid
from jaxflex.uncertainty import Box
from jaxflex.sweep import SweepConfig, default_grid
from jaxflex.tables import build_workspaces
from jaxflex.workspace import Workspace, workspace_shapes

from .baselines import ruckig_samples, shaper_profiles
from .gradient import OneProgram, resolved
from .loop import OptimizerConfig, OptResult, minimize
from .objective import BLEND_FAMILY, DesignObjective, LawObjective, Params, Scales, decode, encode
from .staged import Staged

PERTURB_E = (0.95, 1.0, 1.05)
PERTURB_PAYLOAD = (0.9, 1.0, 1.1)
SPANNING = ((1.0, 1.0), (0.95, 0.9), (0.95, 1.1), (1.05, 0.9), (1.05, 1.1))   # (E factor, payload factor)
DAMPING_RATIO = 0.01
TRAINING_SETS = ("box", "nominal", "spanning", "perturbed")
START_E = {"smoothstep": 0.08}      # start: e [m] per family (default 25 mm, the paper's); the smoothstep
                                    # blend needs a long horizontal part to spread its turn (issue 21)
START_D_FRACTION = 0.98             # start: d = 0.98 h (d = h is the open end of the decoded range)
ROBUST_POWER = 8.0                  # a power mean of this order over the training models is a smooth worst
                                    # case (StudyConfig(robust_power=ROBUST_POWER, absolute=True), SPEC 6)


def training_models(robot: Robot, payloads: Sequence[float], kind: str = "spanning", *, box: Box = Box(),
                    points: int = 3, cycle: Cycle | None = None) -> ModelSet:
    """The models an optimization trains on (module docstring); labels name each model. ``box``:
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


class Candidate(NamedTuple):
    """A trajectory to evaluate: the name of its path (a key of ``DesignStudy.paths``) and its law."""

    path: str
    law: object         # Profile or MotionSamples


class DesignStudy(NamedTuple):
    """Everything the study measured. ``evaluations[set][candidate]`` is a metrics dict name -> (K,)
    array over that set's models; ``sets`` maps a set name to its models' ``ModelId``; ``paths`` holds the
    best paper path ("paper") and the optimized one ("optimized")."""

    payloads: tuple
    tf: float
    blend: str                  # the best paper combination's blend
    best_paper: str             # ... and motion law
    design: Design | None       # the optimized design (None with free_path=False)
    coef: np.ndarray
    result: OptResult
    train: str
    train_models: tuple         # ModelId of each training model (the optimizer's history records their dwell residuals)
    candidates: dict            # name -> Candidate
    paths: dict                 # "paper" / "optimized" -> Path
    evaluations: dict
    sets: dict
    paper: dict
    torque_bound: np.ndarray
    ruckig_limits: tuple | None
    first_mode_hz: tuple
    grid: Grid
    wall_s: float
    evaluators: dict            # "nominal" -> path name -> LawEvaluator (the other sets' are dropped after use)
    setup_s: float = 0.0        # wall time [s] from the study's start to the optimizer's start

    def series(self, name: str):
        """Simulation ``Series`` of a candidate on the nominal models (leading axis: payloads)."""
        c = self.candidates[name]
        return self.evaluators["nominal"][c.path].series(c.law)


class PaperSweep(NamedTuple):
    """The 12 paper combinations on a set of models: ``metrics`` name -> (B, P, K) arrays (blend,
    law, model), ``evaluators`` blend -> ``LawEvaluator`` of that blend's paper path (d = e = 25 mm,
    n = 3) on the models."""

    metrics: dict
    blends: tuple
    profiles: tuple
    evaluators: dict


def paper_sweep(models: ModelSet, cycle: Cycle, tf: float, config: SweepConfig) -> PaperSweep:
    """Every blend x paper law of ``config`` (``jaxflex.sweep.SweepConfig``: its blends, laws, blend
    parameters, dwell [s], grid, which must be given, and progress on stderr) on the models at motion
    time tf [s]: one table build per blend and one compiled rollout program (the evaluators') for
    every law, blend and later evaluation on the same number of models. Same model and metrics as
    ``jaxflex.sweep.run_sweep`` with that config."""
    c = config.checked(cycle)
    if c.grid is None:
        raise ValueError("paper_sweep needs the config's grid (jaxflex.sweep.default_grid gives the default one)")
    if not c.second_order:
        raise ValueError("paper_sweep runs the second-order fast model (the evaluators'): second_order=False "
                         "is run_sweep's")
    blends, profiles, dwell, grid, progress = c.blends, c.profiles, c.dwell, c.grid, c.progress
    bar = Progress(f"paper combinations on {len(models.labels)} model(s)", total=len(blends) * len(profiles),
                   unit="combination", enabled=progress)
    evaluators, runs = {}, []
    with bar:
        for b in blends:
            with bar.waiting(f"{b} path tables") if not bar.counting else contextlib.nullcontext():
                evaluators[b] = LawEvaluator(models, make_path(cycle, b, c.d, c.e, c.n), tf, dwell, grid)
            runs.append([])
            for p in profiles:
                with bar.waiting(f"{b}/{p} (compiling the rollout unless cached)") if not bar.counting \
                        else contextlib.nullcontext():
                    runs[-1].append(evaluators[b](make_profile(p)))
                bar.update(note=f"{b}/{p}")
    mets = {k: np.stack([np.stack([r[k] for r in row]) for row in runs]) for k in runs[0][0]}
    return PaperSweep(mets, blends, profiles, evaluators)


def nominal_indices(models: ModelSet, payloads: Sequence[float]) -> np.ndarray:
    """Index in ``models`` of the nominal model (``ModelId.nominal``) of each payload [kg]."""
    out = []
    for p in payloads:
        if ModelId(float(p)) not in models.ids:
            raise ValueError(f"no nominal {p:g} kg model among {list(models.labels)}")
        out.append(models.index(ModelId(float(p))))
    return np.asarray(out, dtype=int)


def best_combination(dwell_residual) -> tuple[int, int]:
    """(blend, law) indices of the best paper combination from dwell residuals (B, P, C): the
    smallest one, for several payloads C the smallest worst-case ratio to each payload's best."""
    dw = np.asarray(dwell_residual)
    ratio = np.max(dw / dw.min(axis=(0, 1), keepdims=True), axis=-1)
    i, j = np.unravel_index(np.argmin(ratio), ratio.shape)
    return int(i), int(j)


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


def nominal_of_each(models: ModelSet) -> np.ndarray:
    """Index (K,) of the nominal model of each model's payload case."""
    return np.asarray([models.index(ModelId(i.payload)) for i in models.ids], dtype=int)


def scales_from_metrics(ref: dict, torque_bound, weights=None, models: ModelSet | None = None) -> Scales:
    """``reference_scales`` from the reference law's metrics (name -> (K,)) on the models. With
    ``models`` the scales are absolute (SPEC 6): every model of a payload case is divided by the
    reference's vibration energy and mean-square dwell amplitude on that case's nominal model, the
    same constants for the whole case, so the objective compares absolute residuals across the
    perturbed models (a per-model reference would follow its own luck: the paper combinations'
    residuals swing 10x with 1 % of model change). Without ``models``: each model by its own."""
    energy = np.asarray(ref["residual_energy"], dtype=float)
    amp = np.asarray(ref["dwell_residual_mm"], dtype=float) * 1e-3
    if models is not None:
        idx = nominal_of_each(models)
        energy, amp = energy[idx], amp[idx]
    return Scales(energy=jnp.asarray(energy), dwell_ms=jnp.asarray(amp**2 / 2),
                  torque_bound=jnp.asarray(torque_bound, dtype=float),
                  weights=None if weights is None else jnp.asarray(weights, dtype=float))


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """How an optimization study runs (defaults: the robust design of SPEC 6).

    steps: optimizer updates (Adam, warm-up then cosine decay of ``learning_rate``);
    n_coef: free coefficients of the shaped motion law; train: the training models ("box" (default):
    ``box.grid(payloads, box_points)``, per payload a box_points x box_points grid over E and the
    payload mass; "nominal", "spanning" or "perturbed", module docstring); free_path: optimize the
    blends too (False: the law alone on the best paper path); init: the starting design (None:
    ``start_design``); checkpoint: a .npz file to save to and resume from; ruckig: include the
    Ruckig baseline (needs the optional dependency); progress: report on stderr.

    absolute (default): scale every training model by the best paper combination's residual on its
    payload's nominal model (SPEC 6); False: by that combination's residual on the same model
    (the old objective, which follows the reference's luck); robust_power: order of the power mean
    over the training models (1: weighted mean; ROBUST_POWER (default): a smooth worst case);
    law_order: exponent r of the shaped law's end factor (3: zero velocity, acceleration and jerk
    at both ends, poly7 at the start; 4: zero snap too, poly9 at the start); blend: the design's
    blend family (``jaxflex.blends.DESIGN_BLENDS``; default "smoothstep", G4 joins).

    box: the uncertainty box (``jaxflex.uncertainty.Box``; default E +-5 %, payload +-10 %,
    damping ratio 0-1 %, link lengths +-0.5 mm, rotor inertia +-10 %); box_samples: random models
    of the box (seed ``box_seed``) on which every trajectory is evaluated after training (the
    "box" evaluation set; 0: none); richer_modes: modes of each kind added to every link of the
    richer validation model (``jaxflex.model.richer``; the "richer" evaluation set: the nominal
    payloads; 0: none). Neither set ever trains the design. memo: a directory of finished
    optimizations (``loop.OptimizerConfig.memo``): an optimization with the same inputs (e.g. the
    cycle-time study's at the reference tf and the main study's) runs once.

    Why these defaults (6 kg, tf 0.43 s, 100 steps; nominal / worst of the 9 perturbed models /
    damped, dwell residual): the Lamé design space with the relative objective gave 0.32 / 33.8 /
    6.8 um, with the absolute power-8 objective 23 / 35.7 / 5.6 um; its G2 corners excite the modes
    over a whole band, so no weighting fixes it. The smoothstep family (G4 corners, long turns)
    with the relative objective gives 0.02 / 3.5 / 0.28 um (a deep nominal notch, 175x shallower
    at the worst model); these defaults (absolute power-8 objective on the 3 x 3 grid) 1.14 / 1.14 /
    0.51 um, at most 1.13 um over 200 random models of the box (95th percentile 0.99 um), 1.19 um
    over its 32 corners and 1.15 um on the richer model, with a peak torque of at most 0.70 of
    poly7-Lamé's on every model (best paper combination: 16.6 / 224 / 56 um, 217 um over the
    random models, 29 um on the richer model). Those figures came from path tables with 48 nodes per
    blend, which read this design's residual ~8 % low (the full nonlinear model, RK4 at 10 us, gave
    1.25 um); with 96 (``linearized.SEGMENT_NODES``) the fast model and the full model agree.

    steps = 50 (default), 96 nodes per blend: 1.23 / 1.23 / 0.82 um; 200 random models: worst 1.22,
    95th percentile 1.09; richer model 1.24; peak torque 63.8 N m; the full model gives 1.225 um on
    the nominal model (fast: 1.23). Every one is below a tenth of the best paper combination
    (1.66 um), and a cold ``jaxflex optimize --payload 6 --tf 0.43`` takes 4 min 19 s on 2 cores
    (7 min 21 s with 100 steps before the evaluation ran beside the optimizer)."""

    steps: int = 50
    learning_rate: float = 0.05
    n_coef: int = 6
    train: str = "box"
    free_path: bool = True
    init: Design | None = None
    checkpoint: str | os.PathLike | None = None
    ruckig: bool = True
    progress: bool = True
    absolute: bool = True
    robust_power: float = ROBUST_POWER
    law_order: int = 3
    blend: str = BLEND_FAMILY
    box: Box = Box()
    box_points: int = 3
    box_samples: int = 200
    box_seed: int = 0
    richer_modes: int = 3
    memo: str | os.PathLike | None = None

    def train_config(self, label: str) -> "TrainConfig":
        """The training configuration of this study's optimizer (``train_design``, ``train_law``),
        reporting under ``label``."""
        return TrainConfig(steps=self.steps, learning_rate=self.learning_rate, checkpoint=self.checkpoint,
                           progress=self.progress, label=label, memo=self.memo, power=self.robust_power,
                           order=self.law_order, blend=self.blend)

    def checked(self) -> "StudyConfig":
        """Validate the fields that the study's own argument check does not (SPEC 8: before
        anything compiles); ValueError naming the field."""
        checks.one_of("blend", self.blend, DESIGN_BLENDS)
        box = self.box.checked() if isinstance(self.box, Box) else None
        if box is None:
            raise ValueError(f"box must be a jaxflex.uncertainty.Box, got {type(self.box).__name__}")
        points = checks.count("box_points", self.box_points, 1)
        if points % 2 == 0:
            raise ValueError(f"box_points must be odd (the grid must hold the nominal model), got {points}")
        checks.count("box_samples", self.box_samples, 0)
        checks.count("box_seed", self.box_seed, 0)
        checks.count("richer_modes", self.richer_modes, 0)
        checks.positive("robust_power", self.robust_power)
        if self.law_order not in (2, 3, 4):
            raise ValueError(f"law_order must be 2, 3 or 4, got {self.law_order!r}")
        return dataclasses.replace(self, box=box)


def evaluation_sets(problem: Problem, config: StudyConfig) -> tuple[dict, dict]:
    """(sets, grids): the models every trajectory of a study of ``problem`` is evaluated on, set name
    -> ModelSet (nominal, perturbed, damped; box and richer as ``config`` asks), and the grids of the
    sets that need another one than the problem's (the richer model's faster modes may need more
    squarings of the same steps)."""
    robot, cycle, payloads, (tf, dwell, _) = problem
    grid = problem.grid()
    sets = {
        "nominal": model_set(robot, payloads),
        "perturbed": model_set(robot, payloads, stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD),
        "damped": model_set(robot, payloads, damping_ratio=DAMPING_RATIO, cycle=cycle),
    }
    if config.box_samples:
        sets["box"] = models_of(robot, config.box.random(payloads, config.box_samples, config.box_seed), cycle)
    grids = {}
    if config.richer_modes:
        rich = richer(robot, config.richer_modes)
        sets["richer"] = models_of(rich, [ModelId(m) for m in payloads], cycle)
        grids["richer"] = grid._replace(squarings=max(grid.squarings, default_grid(rich, [tf], dwell).squarings))
    return sets, grids


def _baselines(cancelled, problem: Problem, config, path, best: tuple, ruckig_candidate):
    """The baselines of ``problem`` (its timing's grid given) on the best paper path ``path`` (``best``: the
    best paper combination's (blend, law)) and their evaluations: (freqs, candidates, sets, grids, evaluators,
    evaluations), freqs the first locked-motor mode at the place pose [Hz] per payload, candidates name ->
    Candidate (the best law, its input-shaped versions at the first payload's mode, then ``ruckig_candidate``
    (name, Candidate) unless None), the rest as ``_paper_evaluations``. None when ``cancelled`` is set."""
    robot, cycle, payloads, (tf, _, _) = problem
    blend, law = best
    freqs = tuple(place_first_mode_hz(robot.replace(payload=m), cycle) for m in payloads)
    candidates = {f"{blend}/{law} (best paper)": Candidate("paper", make_profile(law))}
    for p in shaper_profiles(law, freqs[0], tf):
        candidates[f"{blend}/{p.name}"] = Candidate("paper", p)
    if ruckig_candidate is not None:
        candidates[ruckig_candidate[0]] = ruckig_candidate[1]
    out = _paper_evaluations(cancelled, problem, config, path, candidates)
    return None if out is None else (freqs, candidates) + out


def _paper_evaluations(cancelled, problem: Problem, config, path, candidates):
    """The evaluation sets of ``problem`` (its timing's grid given), the best paper path's evaluators on them
    and every candidate on that path (the baselines) evaluated: (sets, grids, evaluators set -> {"paper":
    LawEvaluator} (for a free path the nominal set's only, else {}), evaluations set -> candidate -> metrics).
    Stops early when ``cancelled`` is set."""
    sets, grids = evaluation_sets(problem, config)
    tf, dwell, grid = problem.timing
    evaluators, evaluations = {}, {}
    for k, s in sets.items():
        if cancelled.is_set():
            return None
        # a free path's design is evaluated along its own path, and of the paper path's tables only
        # the nominal models' are used again (``DesignStudy.series``): the other sets' are not kept
        # (built, used for every candidate and dropped in groups of models: 0.5 GB per 200 models)
        keep = k == "nominal" or not config.free_path
        ev = LawEvaluator(s, path, tf, dwell, grids.get(k, grid), keep=keep)
        evaluations[k] = dict(zip(candidates, ev.metrics_many([cand.law for cand in candidates.values()])))
        evaluators[k] = {"paper": ev} if keep else {}
    return sets, grids, evaluators, evaluations


def subset(models: ModelSet, idx) -> ModelSet:
    """The models at the positions ``idx`` of ``models``, in that order."""
    idx = [int(i) for i in idx]
    return ModelSet(jax.tree_util.tree_map(lambda a: a[np.asarray(idx)], models.robots),
                    tuple(models.ids[i] for i in idx))


def _training_references(models: ModelSet, nominal, sweep: PaperSweep, blend: str, law: str, tf: float,
                         dwell: float, grid: Grid, *, per_model: bool, progress: bool):
    """What the study needs of the paper combinations on the training models beyond their nominal
    ones (``sweep``: the 12 combinations on the nominal models, one per payload case): the torque
    bound of every model (the poly7-Lamé peak torque) and the best combination's metrics (name ->
    (K,)). Those metrics are simulated on every model only when ``per_model`` (per-model scales,
    or the law-only optimizer, which trains on that evaluator); absolute scales use the nominal
    model's values for its whole case, so they are taken from ``sweep``. Returns (bounds (K,), ref,
    the best path's evaluator on every training model or None)."""
    i, j = sweep.blends.index(blend), sweep.profiles.index(law)
    if list(map(int, nominal)) == list(range(len(models.ids))):               # the sweep ran every model
        lame_poly7 = sweep.metrics["max_torque_nm"][sweep.blends.index("lame"), sweep.profiles.index("poly7")]
        return (np.asarray(lame_poly7), {k: np.asarray(v[i, j]) for k, v in sweep.metrics.items()},
                sweep.evaluators[blend])
    bar = Progress(f"paper references on {len(models.ids)} training models", enabled=progress)
    lame = sweep.evaluators["lame"].path
    with bar.waiting("poly7-Lamé (the torque bound) on every model"):
        train_lame = LawEvaluator(models, lame, tf, dwell, grid)
        bounds = np.asarray(train_lame(make_profile("poly7"))["max_torque_nm"])
    if not per_model:
        position = {int(n): c for c, n in enumerate(nominal)}
        case = np.asarray([position[int(n)] for n in nominal_of_each(models)])     # each model's payload case
        return bounds, {k: np.asarray(v[i, j])[case] for k, v in sweep.metrics.items()}, None
    with bar.waiting(f"{blend}/{law} (the best combination) on every model"):
        train = train_lame if blend == "lame" else LawEvaluator(models, sweep.evaluators[blend].path, tf, dwell,
                                                                  grid)
        return bounds, train(make_profile(law)), train


def _workspaces(models: ModelSet, cycle: Cycle, progress: bool, memo=None) -> Workspace:
    """The training models' workspace tables (``jaxflex.workspace``), with progress on stderr; with a
    ``memo`` directory each model's tables are kept there and loaded by later studies
    (``remembered_workspaces``)."""
    bar = Progress(f"workspace tables of {len(models.ids)} model(s)", enabled=progress)
    if memo is None:
        with bar.waiting("building (the blends' design space around both corners)", key="workspace tables"):
            return jax.block_until_ready(build_workspaces(models.robots, cycle))
    with bar.waiting("building or loading (the blends' design space around both corners)",
                     key="workspace tables (memo)"):
        return remembered_workspaces(models.robots, cycle, memo)


WORKSPACE_MEMO = "workspaces"       # the subdirectory of a study memo that holds the models' workspaces


def remembered_workspaces(robots: Robot, cycle: Cycle, memo) -> Workspace:
    """``tables.build_workspaces(robots, cycle)`` for a stack of K robots, each model's tables kept in
    ``memo``/workspaces as a file named by a digest of the model, the cycle and the code
    (``loop.fingerprint``'s code digest). Models whose file is there are loaded, the others built
    (as one stack) and written: the studies of ``jaxflex reproduce`` train on the same models (the
    6 kg box in the 6 kg, both-payload and cycle-time studies), each in a process of its own, and
    building one model's tables takes a few seconds of the coefficient program. Each model's tables
    are those of a stacked build (the same program per robot and chunk of poses), so the result is
    the same, bit for bit, whichever models were loaded. About 8 MB per model on the default cycle."""
    from .loop import _code_digest

    folder = pathlib.Path(memo) / WORKSPACE_MEMO
    singles = trees.unstack(robots)
    code = _code_digest().encode()
    files = [folder / f"{hashlib.sha1(code + trees.content_key(r, cycle)).hexdigest()}.npz" for r in singles]
    shapes = workspace_shapes(singles[0], cycle)
    tables = [_load_workspace(f, shapes) for f in files]
    missing = [k for k, t in enumerate(tables) if t is None]
    if missing:
        built = build_workspaces(trees.stack([singles[k] for k in missing]), cycle)
        folder.mkdir(parents=True, exist_ok=True)
        for j, k in enumerate(missing):
            _save_workspace(files[k], jax.tree_util.tree_map(lambda a: a[j], built))
        if len(missing) == len(tables):
            return jax.block_until_ready(built)      # every model built here: the stack as built, no copy
        for j, k in enumerate(missing):
            tables[k] = jax.tree_util.tree_map(lambda a: np.asarray(a[j]), built)
        del built
    return jax.block_until_ready(trees.stack(tables))


def _save_workspace(file: pathlib.Path, ws: Workspace) -> None:
    tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, *[np.asarray(a) for a in jax.tree_util.tree_leaves(ws)])
    os.replace(tmp, file)                   # atomic: a reader sees the whole file or none


def _load_workspace(file: pathlib.Path, shapes: Workspace) -> Workspace | None:
    """The workspace in ``file`` if it is there and has the structure of ``shapes``, else None."""
    leaves, treedef = jax.tree_util.tree_flatten(shapes)
    try:
        with np.load(file) as z:
            arrays = [z[f"arr_{i}"] for i in range(len(z.files))]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):     # missing or damaged
        return None
    if len(arrays) != len(leaves) or any(a.shape != tuple(s.shape) or a.dtype != s.dtype
                                         for a, s in zip(arrays, leaves)):
        return None
    return jax.tree_util.tree_unflatten(treedef, arrays)


def checked_study(name: str, problem: Problem, config: StudyConfig) -> tuple[Problem, StudyConfig]:
    """Eager validation of a study's ``problem`` and ``config`` for the entry point ``name`` (SPEC 8:
    before anything compiles): (the problem with its payloads a tuple and tf, dwell floats, the
    config with its box checked). Raises TypeError for other types, ValueError naming a bad field."""
    if not isinstance(problem, Problem) or not isinstance(config, StudyConfig):
        raise TypeError(f"{name}(problem, config) takes a jaxflex.problem.Problem and a StudyConfig, got "
                        f"{type(problem).__name__} and {type(config).__name__}")
    payloads = checks.nonnegatives("payloads", problem.payloads, "kg")
    if any(m <= 0 for m in payloads):
        raise ValueError(f"payloads must be > 0 kg for an optimization study (the torque bound and the "
                         f"perturbed models scale with them), got {list(payloads)}")
    timing = problem.timing.checked()
    checks.count("n_coef", config.n_coef, 1)
    checks.count("steps", config.steps, 0)
    checks.positive("learning_rate", config.learning_rate)
    checks.one_of("training set", config.train, TRAINING_SETS)
    check_cycle_reachable(problem.robot, problem.cycle)
    return problem._replace(payloads=payloads, timing=timing), config.checked()


def optimize_design(problem: Problem, config: StudyConfig = StudyConfig()) -> DesignStudy:
    """Run the study (see module docstring) on ``problem`` (robot, cycle, payloads [kg], timing)
    with ``config``. Returns a ``DesignStudy``."""
    started = time.time()
    problem, c = checked_study("optimize_design", problem, config)
    robot, cycle, payloads = problem.robot, problem.cycle, problem.payloads
    n_coef, steps, train, free_path = c.n_coef, c.steps, c.train, c.free_path
    ruckig, progress, init = c.ruckig, c.progress, c.init
    if init is not None:
        design_path(cycle, init, c.blend)
        shaped(init.coef)
    problem = problem._replace(timing=problem.timing._replace(grid=problem.grid()))   # its grid, or the default
    tf, dwell, grid = problem.timing
    # the training models; the paper combinations on their nominal models give the best combination
    # and the scales, poly7-Lamé on every one the torque bounds (``_training_references``)
    models = training_models(robot, payloads, train, box=c.box, points=c.box_points, cycle=cycle)
    weights = training_weights(train, len(payloads))
    workspaces = None
    train_config = c.train_config(f"{'design' if free_path else 'law'} tf={tf:g}")
    if free_path:
        # the design gradient compiles (about half a minute cold) in the background from the start, during
        # the workspace tables and the paper sweep: its workspace and scales are only shapes until then
        x0 = init if init is not None else start_design(cycle, n_coef, c.blend)
        if steps > 0:
            shapes = Training(models, cycle, problem.timing, _abstract_scales(len(models.ids), weights),
                              workspace_shapes(models.robots, cycle, models=len(models.ids)))
            resolved(Staged(), steps).compile_ahead(design_objective(shapes, train_config), encode(cycle, x0))
        workspaces = _workspaces(models, cycle, progress, c.memo)
    nominal = nominal_indices(models, payloads)
    sweep = paper_sweep(subset(models, nominal), cycle, tf, SweepConfig(dwell=dwell, grid=grid, progress=progress))
    paper = sweep.metrics                                                       # (B, P, C)
    i, j = best_combination(paper["dwell_residual_mm"])
    blend, law = sweep.blends[i], sweep.profiles[j]
    if progress:
        print(f"best paper combination at tf = {tf:g} s for {list(payloads)} kg: {blend} / {law}", flush=True)
    paths = {"paper": sweep.evaluators[blend].path}
    bounds, ref, train_paper = _training_references(models, nominal, sweep, blend, law, tf, dwell, grid,
                                                    per_model=not (c.absolute and free_path), progress=progress)
    torque_bound = bounds[nominal]
    scales = scales_from_metrics(ref, bounds, weights, models if c.absolute else None)
    # baselines on the best paper path: the best law, its shaped versions (first payload's mode), Ruckig.
    # They, the evaluation sets and the baselines' evaluations on them do not depend on the design:
    # they are computed beside the optimizer (a background thread), the optimized design after it
    ruckig_candidate, limits = None, None
    if ruckig:
        try:
            smp, limits = ruckig_samples(float(paths["paper"].length), tf, grid)
            ruckig_candidate = (f"{blend}/ruckig", Candidate("paper", smp))
        except ImportError as err:
            if progress:
                print(f"  (Ruckig baseline skipped: {err})", flush=True)
    beside = Beside(_baselines, problem, c, paths["paper"], (blend, law), ruckig_candidate)
    setup_s = time.time() - started
    with beside:
        if free_path:
            result = train_design(Training(models, cycle, problem.timing, scales, workspaces),
                                  encode(cycle, x0), train_config)
            x = jax.tree_util.tree_map(np.asarray, decode(cycle, result.params))
            paths["optimized"] = design_path(cycle, x, c.blend)
            coef = np.asarray(x.coef)
        else:
            c0 = np.ones(n_coef) if init is None else np.asarray(init.coef)
            result = train_law(train_paper, scales, c0, train_config)
            x, coef = None, np.asarray(result.params)
            paths["optimized"] = paths["paper"]
        wait = Progress("evaluation sets and baselines", enabled=progress)
        with wait.waiting("finishing the baselines computed beside the optimizer", key="baselines beside"):
            freqs, candidates, sets, grids, evaluators, evaluations = beside.result()
    candidates["optimized"] = Candidate("optimized", shaped(jnp.asarray(coef), c.law_order, name="optimized"))
    total = sum(len(s.labels) for s in sets.values())
    bar = Progress(f"the optimized design on {total} models", total=len(sets), unit="set", enabled=progress)
    with bar:
        for k, s in sets.items():
            if paths["optimized"] is paths["paper"]:
                evaluators[k]["optimized"] = evaluators[k]["paper"]
            else:
                with bar.waiting(f"{k}: path tables") if not bar.counting else contextlib.nullcontext():
                    # the other sets' tables are built, used and dropped in groups of models
                    evaluators[k]["optimized"] = LawEvaluator(s, paths["optimized"], tf, dwell, grids.get(k, grid),
                                                              keep=k == "nominal")
            evaluations[k]["optimized"] = evaluators[k]["optimized"](candidates["optimized"].law)
            if k != "nominal":
                evaluators[k] = {}          # only the nominal evaluators are used again (their tables go)
            bar.update(note=k)
    return DesignStudy(payloads, tf, blend, law, x, coef, result, train, models.ids, candidates, paths, evaluations,
                       {k: s.ids for k, s in sets.items()}, paper, torque_bound, limits, freqs, grid,
                       time.time() - started, evaluators, setup_s)


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


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How ``train_design`` and ``train_law`` run: Adam for at most ``steps`` updates at
    ``learning_rate`` (warmed up, then cosine-decayed; stop after ``patience`` steps without
    improvement), saving to and resuming from ``checkpoint`` (a .npz path), reporting on stderr under
    ``label`` with ``progress``, and a ``memo`` directory of finished optimizations
    (``loop.OptimizerConfig``); the objective's ``power`` (order of the power mean over the
    models, ``objective.combine``), the shaped law's end-factor ``order`` and the design's
    ``blend`` family (``train_design`` only)."""

    steps: int = 100
    learning_rate: float = 0.05
    patience: int = 40
    checkpoint: str | os.PathLike | None = None
    progress: bool = True
    label: str = "design"
    memo: str | os.PathLike | None = None
    power: float = 1.0
    order: int = 3
    blend: str = BLEND_FAMILY

    def optimizer(self) -> OptimizerConfig:
        """The optimizer's configuration (``loop.minimize``): decaying rate, the training models'
        dwell residuals recorded at every step."""
        return OptimizerConfig(steps=self.steps, learning_rate=self.learning_rate, decay=True, patience=self.patience,
                               checkpoint=self.checkpoint, progress=self.progress, label=self.label, monitor=_dwell,
                               memo=self.memo)


def train_design(training: Training, init: Params, config: TrainConfig = TrainConfig()) -> OptResult:
    """Optimize the design parameters (start ``init``) on ``training`` (its models at its motion
    time with its normalization; ``Training``) as ``config`` says (``TrainConfig``). The path tables
    inside the objective come from the models' workspace tables (``jaxflex.workspace``, built here
    unless ``training.workspaces`` holds them): the gradient compiles in about a third of the time
    it takes through the model's table build."""
    _check_training(training.timing.tf, training.timing.dwell, config.steps, config.learning_rate)
    return minimize(design_objective(training, config), init, (), config.optimizer(), gradient=Staged())


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
    return DesignObjective(models.robots, cycle, _host_scalar(tf), _host_scalar(dwell), _canonical(scales), workspaces,
                           grid=grid, blend=config.blend, order=int(config.order), power=float(config.power))


def _abstract_scales(k: int, weights) -> Scales:
    """The shapes of ``_canonical(scales_from_metrics(...))`` for k models (weights None or (k,))."""
    v = jax.ShapeDtypeStruct((k,), jnp.float64)
    return Scales(energy=v, dwell_ms=v, torque_bound=v, weights=None if weights is None else v)


def _host_scalar(v):
    return jax.device_put(np.asarray(v, dtype=np.float64))


def _canonical(scales: Scales) -> Scales:
    """Scales as strongly typed float64 arrays: a weakly typed value (e.g. ``jnp.full(1, 1e-3)``)
    would give the same objective a second compiled program."""
    return Scales(*(v if v is None or isinstance(v, jax.ShapeDtypeStruct) else _host_scalar(v) for v in scales))


def train_law(evaluator: LawEvaluator, scales: Scales, init,
              config: TrainConfig = TrainConfig(label="law")) -> OptResult:
    """Optimize the shaped-law coefficients (start ``init`` (m + 1,)) on the training models of
    ``evaluator`` (along its path, at its motion time tf [s], dwell and grid, with its tables) with
    the normalization ``scales``, as ``config`` says (``TrainConfig``; its blend is not used)."""
    _check_training(evaluator.tf, evaluator.dwell, config.steps, config.learning_rate)
    return minimize(law_objective(evaluator, scales, config), jnp.asarray(init, dtype=float), (), config.optimizer(),
                    gradient=OneProgram())


def law_objective(evaluator: LawEvaluator, scales: Scales, config: TrainConfig = TrainConfig(label="law")) \
        -> LawObjective:
    """The law objective on ``evaluator``'s path, models, tf, dwell, grid and tables, with the
    normalization ``scales`` and ``config``'s power and law order, as ``train_law`` hands it to the
    optimizer."""
    check_grid(evaluator.grid)
    return LawObjective(evaluator.tables, jnp.asarray(evaluator.path.length, dtype=float), _host_scalar(evaluator.tf),
                        _host_scalar(evaluator.dwell), _canonical(scales), evaluator.models.robots,
                        grid=evaluator.grid, order=int(config.order), power=float(config.power))


def _check_training(tf, dwell, steps, learning_rate):
    checks.positive("tf", tf, "s")
    checks.positive("dwell", dwell, "s")
    checks.count("steps", steps, 0)
    checks.positive("learning_rate", learning_rate)


def _dwell(aux):
    """What the optimizer records per step beside the objective: the dwell residual [mm] of every
    training model."""
    return aux.metrics["dwell_residual_mm"]


def verify(problem: Problem, trajectories: dict, method: str = "exprb3", full_dt: float | None = None) -> dict:
    """Independent check of the residual claims on the problem's robot with its one payload [kg],
    at its tf and dwell [s]: every trajectory (name -> (Path, Profile)) is re-simulated with the
    fast model on the timing's grid (None: the default grid), at a quarter of its step, and with the
    full nonlinear model (``jaxflex.reference.reference_rollout`` with ``method`` at ``full_dt``
    [s], its default step if None). Returns name -> {method: dwell residual [mm]}."""
    from jaxflex.metrics import metrics
    from jaxflex.reference import DEFAULT_DT, METHODS, reference_rollout

    robot, cycle, payloads, _ = problem
    if len(payloads) != 1:
        raise ValueError(f"payloads: verify takes one payload, got {list(payloads)}")
    payload = checks.nonnegative("payload", payloads[0], "kg")
    checks.one_of("full-model method", method, METHODS)
    timing = problem.timing.checked()
    tf, dwell = timing.tf, timing.dwell
    full_dt = checks.positive("full_dt", DEFAULT_DT[method] if full_dt is None else full_dt, "s")
    r = robot.replace(payload=payload)
    g = problem._replace(timing=timing).grid()
    fine = Grid(coarse=4 * g.coarse, fine=g.fine, dwell_steps=4 * g.dwell_steps, squarings=g.squarings)
    models = model_set(robot, [payload])
    out = {name: {} for name in trajectories}
    for name, (path, law) in trajectories.items():
        ev = LawEvaluator(models, path, tf, dwell, g)          # tables built once, used on both grids
        for label, evaluator in (("fast", ev), ("fast dt/4", ev.with_grid(fine))):
            out[name][label] = float(evaluator(law)["dwell_residual_mm"][0])
    paths, laws = zip(*trajectories.values())
    ref = jax.vmap(metrics)(reference_rollout(r, list(paths), list(laws), tf, dwell, dt=full_dt, method=method))
    for i, name in enumerate(trajectories):
        out[name][f"full model {method} {full_dt:g} s"] = float(ref["dwell_residual_mm"][i])
    return out
