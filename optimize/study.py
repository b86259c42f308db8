"""Trajectory optimization against the paper's best combination and the industrial baselines.

``optimize_design`` is the whole study for one or several payloads at a fixed motion time:

1. the 12 paper combinations, simulated on the nominal model of each payload
   (``evaluation.paper_sweep``), give the best one (smallest dwell residual; for several payloads
   the smallest worst-case ratio to each payload's best) and the objective's scales (the best
   combination's residuals); poly7-Lamé on every training model gives the torque bound of each
   (``training_references``; with per-model scales or the law-only optimizer the best combination
   runs on every training model too);
2. a design (the blend parameters of each corner, by default of the G4 ``smoothstep`` family, and
   a shaped monotone motion law, ``jaxflex.designs``) is optimized by gradient (reverse mode
   through the workspace tables and the whole second-order rollout, optax Adam) on the training
   models (``training``). By default (``config.StudyConfig``: absolute scales, a power mean of
   order ``config.ROBUST_POWER``) the objective is a smooth worst case of their absolute residuals,
   in units of the best paper combination's residual on the payload's nominal model
   (docs/conventions.md#optimization); with ``absolute=False`` each model is normalized by the best
   paper combination on the same model. It starts from ``training.start_design`` with poly7. With
   ``free_path=False`` only the law is optimized, on the best paper combination's path;
3. the optimized design and every baseline (best paper combination, its ZV/ZVD shaping, Ruckig along
   the best paper path) are evaluated on the same models: nominal, perturbed, damped, random
   models of the uncertainty box and the richer validation model (``evaluation``).

The design gradient compiles in a background thread from the start, while the workspace tables are
built and the paper sweep runs, and the evaluation sets with every baseline on them, which do not
depend on the design, are computed beside the optimizer (``jaxflex.runtime.threads.Beside``); only
the optimized design is evaluated after it. The results are those of the sequential order, bit for
bit.
"""
from __future__ import annotations

import contextlib
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks, engine
from jaxflex.designs import Design, design_path
from jaxflex.engine import LawEvaluator
from jaxflex.model_sets import ModelSet
from jaxflex.problem import Problem
from jaxflex.profiles import make_profile, shaped
from jaxflex.progress import Progress
from jaxflex.robot import check_cycle_reachable, check_motion_loads
from jaxflex.runtime.threads import Beside
from jaxflex.simulate import Grid
from jaxflex.sweep import SweepConfig, estimate_grid
from jaxflex.workspace import workspace_shapes

from .baselines import ruckig_samples
from .config import StudyConfig
from .evaluation import Candidate, PaperSweep, baselines, best_combination, paper_sweep
from .gradient import resolved
from .loop import OptResult
from .objective import decode, encode
from .staged import Staged
from .training import (Training, abstract_scales, design_objective, nominal_indices, nominal_of_each,
                       scales_from_metrics, start_design, subset, train_design, train_law, training_models,
                       training_weights)
from .workspaces import training_workspaces


class DesignStudy(NamedTuple):
    """Everything the study computed. ``evaluations[set][candidate]`` is a metrics dict name -> (K,)
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


class TrainingReferences(NamedTuple):
    """What the study takes of the paper combinations on its training models: the torque ``bounds``
    (K,) [N m], the best combination's metrics ``ref`` (name -> (K,)) and its ``evaluator`` on every
    training model (None when not built)."""

    bounds: np.ndarray
    ref: dict
    evaluator: LawEvaluator | None


def training_references(models: ModelSet, nominal, sweep: PaperSweep, blend: str, law: str, tf: float,
                        dwell: float, grid: Grid, *, per_model: bool, progress: bool) -> TrainingReferences:
    """What the study needs of the paper combinations on the training models beyond their nominal
    ones (``sweep``: the 12 combinations on the nominal models, one per payload case): the torque
    bound of every model (the poly7-Lamé peak torque) and the best combination's metrics (name ->
    (K,)). Those metrics are simulated on every model only when ``per_model`` (per-model scales,
    or the law-only optimizer, which trains on that evaluator); absolute scales use the nominal
    model's values for its whole case, so they are taken from ``sweep``."""
    i, j = sweep.blends.index(blend), sweep.profiles.index(law)
    if list(map(int, nominal)) == list(range(len(models.ids))):               # the sweep ran every model
        lame_poly7 = sweep.metrics["max_torque_nm"][sweep.blends.index("lame"), sweep.profiles.index("poly7")]
        return TrainingReferences(np.asarray(lame_poly7), {k: np.asarray(v[i, j]) for k, v in sweep.metrics.items()},
                                  sweep.evaluators[blend])
    bar = Progress(f"paper references on {len(models.ids)} training models", enabled=progress)
    lame = sweep.evaluators["lame"].path
    with bar.waiting("poly7-Lamé (the torque bound) on every model"):
        train_lame = LawEvaluator(models, lame, tf, dwell, grid)
        bounds = np.asarray(train_lame(make_profile("poly7"))["max_torque_nm"])
    if not per_model:
        position = {int(n): c for c, n in enumerate(nominal)}
        case = np.asarray([position[int(n)] for n in nominal_of_each(models)])     # each model's payload case
        return TrainingReferences(bounds, {k: np.asarray(v[i, j])[case] for k, v in sweep.metrics.items()}, None)
    with bar.waiting(f"{blend}/{law} (the best combination) on every model"):
        train = train_lame if blend == "lame" else LawEvaluator(models, sweep.evaluators[blend].path, tf, dwell,
                                                                  grid)
        return TrainingReferences(bounds, train(make_profile(law)), train)


def checked_study(name: str, problem: Problem, config: StudyConfig) -> tuple[Problem, StudyConfig]:
    """Eager validation of a study's ``problem`` and ``config`` for the entry point ``name`` (before
    anything compiles, docs/conventions.md#bad-input): (the problem with its payloads a tuple and tf,
    dwell floats, the config with its box checked). Raises TypeError for other types, ValueError
    naming a bad field."""
    if not isinstance(problem, Problem) or not isinstance(config, StudyConfig):
        raise TypeError(f"{name}(problem, config) takes a jaxflex.problem.Problem and a StudyConfig, got "
                        f"{type(problem).__name__} and {type(config).__name__}")
    payloads = checks.nonnegatives("payloads", problem.payloads, "kg")
    if any(m <= 0 for m in payloads):
        raise ValueError(f"payloads must be > 0 kg for an optimization study (the torque bound and the "
                         f"perturbed models scale with them), got {list(payloads)}")
    timing = problem.timing.checked()
    config = config.checked()
    check_cycle_reachable(problem.robot, problem.cycle)
    for m in payloads:
        check_motion_loads(problem.robot.replace(payload=m), problem.cycle, timing.tf)
    return problem._replace(payloads=payloads, timing=timing), config


def optimize_design(problem: Problem, config: StudyConfig = StudyConfig()) -> DesignStudy:
    """Run the study (see module docstring) on ``problem`` (robot, cycle, payloads [kg], timing)
    with ``config``. Returns a ``DesignStudy``."""
    started = time.time()
    problem, c = checked_study("optimize_design", problem, config)
    robot, cycle, payloads = problem.robot, problem.cycle, problem.payloads
    n_coef, train, free_path, ruckig, init = c.n_coef, c.training_set, c.free_path, c.ruckig, c.init
    steps, progress, blend_family = c.train.optimizer.steps, c.train.optimizer.progress, c.train.blend
    if init is not None:
        design_path(cycle, init, blend_family)
        shaped(init.coef)
    problem = problem._replace(timing=problem.timing._replace(grid=problem.grid()))   # its grid, or the default
    tf, dwell, grid = problem.timing
    # the training models; the paper combinations on their nominal models give the best combination
    # and the scales, poly7-Lamé on every one the torque bounds (``training_references``)
    models = training_models(robot, payloads, train, box=c.box, points=c.box_points, cycle=cycle)
    weights = training_weights(train, len(payloads))
    nominal = nominal_indices(models, payloads)
    # the rollout's programs, which the paper sweep runs first after the workspace tables, compile in
    # the background from the start (before the design gradient's)
    engine.compile_ahead(models.singles()[nominal[0]], grid)
    workspaces = None
    train_config = c.train.with_optimizer(label=f"{'design' if free_path else 'law'} tf={tf:g}")
    gradient = resolved(Staged(), steps)        # the design gradient: compiled ahead, then trained with
    if free_path:
        # the design gradient compiles in the background from the start, during the workspace tables
        # and the paper sweep: its workspace and scales are only shapes until then
        x0 = init if init is not None else start_design(cycle, n_coef, blend_family)
        if steps > 0:
            shapes = Training(models, cycle, problem.timing, abstract_scales(len(models.ids), weights),
                              workspace_shapes(models.robots, cycle, models=len(models.ids)))
            gradient.compile_ahead(design_objective(shapes, train_config), encode(cycle, x0))
        workspaces = training_workspaces(models, cycle, progress, c.train.optimizer.memo)
    sweep = paper_sweep(subset(models, nominal), cycle, tf, SweepConfig(dwell=dwell, grid=grid, progress=progress))
    paper = sweep.metrics                                                       # (B, P, C)
    i, j = best_combination(paper["dwell_residual_mm"])
    blend, law = sweep.blends[i], sweep.profiles[j]
    if progress:
        print(f"best paper combination at tf = {tf:g} s for {list(payloads)} kg: {blend} / {law}", flush=True)
    paths = {"paper": sweep.evaluators[blend].path}
    bounds, ref, train_paper = training_references(models, nominal, sweep, blend, law, tf, dwell, grid,
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
    # the error estimate's grid (``evaluation.nominal_accuracy``) compiles beside the optimizer
    coarser = estimate_grid(robot, grid, tf, dwell)
    if coarser is not None:
        engine.compile_ahead(models.singles()[nominal[0]], coarser[0])
    beside = Beside(baselines, problem, c, paths["paper"], (blend, law), ruckig_candidate)
    setup_s = time.time() - started
    with beside:
        if free_path:
            result = train_design(Training(models, cycle, problem.timing, scales, workspaces),
                                  encode(cycle, x0), train_config, gradient)
            x = jax.tree_util.tree_map(np.asarray, decode(cycle, result.params))
            paths["optimized"] = design_path(cycle, x, blend_family)
            coef = np.asarray(x.coef)
        else:
            c0 = np.ones(n_coef) if init is None else np.asarray(init.coef)
            result = train_law(train_paper, scales, c0, train_config)
            x, coef = None, np.asarray(result.params)
            paths["optimized"] = paths["paper"]
        wait = Progress("evaluation sets and baselines", enabled=progress)
        with wait.waiting("finishing the baselines computed beside the optimizer", key="baselines beside"):
            freqs, candidates, sets, grids, evaluators, evaluations = beside.result()     # ``Baselines``
    candidates["optimized"] = Candidate("optimized", shaped(jnp.asarray(coef), c.train.order, name="optimized"))
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
