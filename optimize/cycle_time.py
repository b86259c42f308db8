"""Cycle-time study: how much shorter can the motion be at equal residual vibration?

For a list of motion times tf the 12 paper combinations are simulated (one sweep, every tf a case)
and a design (blend parameters and motion law, ``study.train_design``) is optimized at each tf,
descending, warm-started from the previous tf's design, on the same training models as the main
study. The peak torque is bounded by the poly7-Lamé combination's at the reference time for every
tf (the same motors: a shorter cycle gets no extra torque); a tf counts only when the design keeps
that bound within 1 %. The Pareto curve is the optimized dwell residual against tf, beside the best
paper combination at each tf; the study reports the shortest tf whose optimized residual (nominal
model) is no worse than the best paper combination's at the reference time, and the shortest tf
whose worst residual over the nine perturbed models (E x 0.95/1/1.05, payload x 0.9/1/1.1) is no
worse than that combination's worst at the reference time (the robust criterion,
docs/conventions.md#uncertainty-box).

Every tf shares one grid (the longest tf's: a shorter tf gets a finer step), so the whole study
compiles its gradient once.
"""
from __future__ import annotations

import time
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxflex import checks
from jaxflex.designs import design_path
from jaxflex.engine import LawEvaluator
from jaxflex.model_sets import model_set
from jaxflex.path import make_path
from jaxflex.problem import Problem, Timing
from jaxflex.profiles import make_profile, shaped
from jaxflex.sweep import Case, SweepConfig, default_grid, run_sweep
from jaxflex.workspace import workspace_shapes

from .config import StudyConfig
from .gradient import resolved
from .objective import decode, encode
from .staged import Staged
from .study import checked_study
from .training import (PERTURB_E, PERTURB_PAYLOAD, Training, abstract_scales, design_objective, nominal_indices,
                       reference_scales, start_design, torque_bounds, train_design, training_models, training_weights)
from .workspaces import training_workspaces

TORQUE_TOL = 1.01   # a design counts when its peak torque is within 1 % of the bound (soft penalty)


class CycleTimeStudy(NamedTuple):
    """Per tf (T,): best paper dwell residual [mm] and its combination, optimized residual [mm]
    (nominal model; and the worst over the nine perturbed models) and peak torque [N m], the
    designs; the torque bound [N m]; the reference residual (best paper at tf_ref, nominal) and the
    same combination's worst over the perturbed models at tf_ref; the shortest tf meeting the
    nominal reference and the relative reduction 1 - tf_min / tf_ref; the same for the robust
    criterion (perturbed worst no worse than the reference combination's)."""

    payload: float
    tf_ref: float
    tfs: np.ndarray
    paper_best: list
    paper_residual: np.ndarray
    optimized_residual: np.ndarray
    optimized_perturbed_worst: np.ndarray
    optimized_torque: np.ndarray
    designs: list
    torque_bound: float
    target: float
    target_perturbed: float
    train: str
    tf_min: float | None
    reduction: float | None
    tf_min_robust: float | None
    reduction_robust: float | None
    wall_s: float


def cycle_time_study(problem: Problem, tfs: Sequence[float] = (0.43, 0.40, 0.37, 0.34, 0.31),
                     config: StudyConfig = StudyConfig()) -> CycleTimeStudy:
    """Run the study (module docstring) for the problem's single payload [kg], with its timing's tf as
    the reference motion time tf_ref [s]; ``tfs`` [s] are visited in descending order. Uses
    ``config``'s steps, learning rate, law coefficients, training set and progress."""
    started = time.time()
    if isinstance(problem, Problem) and len(problem.payloads) != 1:
        raise ValueError(f"payloads: the cycle-time study takes one payload, got {list(problem.payloads)}")
    problem, config = checked_study("cycle_time_study", problem, config)
    robot, cycle = problem.robot, problem.cycle
    (payload,), (tf_ref, dwell, _) = problem.payloads, problem.timing
    n_coef, train = config.n_coef, config.training_set
    steps, progress = config.train.optimizer.steps, config.train.optimizer.progress
    tfs = np.asarray(checks.positives("tfs", tfs, "s"))
    if tf_ref not in tfs:
        tfs = np.append(tfs, tf_ref)
    tfs = np.sort(tfs)[::-1]
    grid = default_grid(robot, [float(tfs.max())], dwell)     # step <= 0.1 ms at every tf
    models = training_models(robot, [payload], train, box=config.box, points=config.box_points, cycle=cycle)
    params = encode(cycle, start_design(cycle, n_coef, config.train.blend))
    gradient = resolved(Staged(), steps)        # one gradient for every tf: compiled ahead, then trained with
    if steps > 0:
        # the design gradient (one program for every tf) compiles in the background during the sweep
        shapes = design_objective(Training(models, cycle, Timing(float(tfs[0]), dwell, grid),
                                           abstract_scales(len(models.ids), training_weights(train)),
                                           workspace_shapes(models.robots, cycle, models=len(models.ids))),
                                  config.train)
        gradient.compile_ahead(shapes, params)
    res = run_sweep(robot, cycle, [Case(payload, float(t)) for t in tfs],
                    SweepConfig(dwell=dwell, grid=grid, timed=False, estimate=False))
    dw = res.metrics["dwell_residual_mm"]                                   # (B, P, T)
    k_ref = int(np.argmin(np.abs(tfs - tf_ref)))
    i, j = np.unravel_index(np.argmin(dw[:, :, k_ref]), dw.shape[:2])
    blend, law = res.blends[i], res.profiles[j]
    target = float(dw[i, j, k_ref])
    paper_best = [f"{res.blends[b]}/{res.profiles[p]}" for b, p in
                  (np.unravel_index(np.argmin(dw[:, :, k]), dw.shape[:2]) for k in range(len(tfs)))]
    paper_residual = dw.min(axis=(0, 1))
    bound = float(res.metrics["max_torque_nm"][res.blends.index("lame"), res.profiles.index("poly7"), k_ref])
    if progress:
        print(f"cycle-time study, {payload:g} kg: best paper at tf_ref = {tf_ref:g} s is {blend}/{law}, "
              f"dwell residual {target:.4g} mm; torque bound {bound:.1f} N m; optimizing designs for "
              f"tf = {', '.join(f'{t:g}' for t in np.asarray(tfs, dtype=float))} s", flush=True)
    ref_eval = LawEvaluator(models, make_path(cycle, blend, 0.025), tf_ref, dwell, grid)
    bounds = torque_bounds(models, cycle, tf_ref, dwell, grid, ref_eval)       # per training model
    perturbed = model_set(robot, [payload], stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD)
    i_nominal = int(nominal_indices(perturbed, [payload])[0])      # the nominal model is one of them
    paper_perturbed = LawEvaluator(perturbed, make_path(cycle, blend, 0.025), tf_ref, dwell, grid)
    target_perturbed = float(np.max(paper_perturbed(make_profile(law))["dwell_residual_mm"]))
    workspaces = training_workspaces(models, cycle, progress, config.train.optimizer.memo)      # once for every tf
    opt_res, opt_worst, opt_tau, designs = [], [], [], []
    for tf in tfs:
        scales = reference_scales(ref_eval, make_profile(law), bounds, tf=float(tf), weights=training_weights(train),
                                  absolute=config.absolute)
        # one optimization per tf: no checkpoint (the configuration's checkpoint is one file)
        train_config = config.train.with_optimizer(label=f"design tf={tf:g}", checkpoint=None)
        result = train_design(Training(models, cycle, Timing(float(tf), dwell, grid), scales, workspaces), params,
                              train_config, gradient)
        params = result.params
        x = jax.tree_util.tree_map(np.asarray, decode(cycle, params))
        path = design_path(cycle, x, config.train.blend)
        m = LawEvaluator(perturbed, path, float(tf), dwell, grid)(shaped(x.coef, config.train.order))
        opt_res.append(float(m["dwell_residual_mm"][i_nominal]))
        opt_tau.append(float(m["max_torque_nm"][i_nominal]))
        opt_worst.append(float(np.max(m["dwell_residual_mm"])))
        designs.append(x)
        if progress:
            print(f"  tf = {tf:.4g} s: optimized {opt_res[-1]:.4g} mm (perturbed worst {opt_worst[-1]:.4g}; "
                  f"torque {opt_tau[-1]:.1f} <= {bound:.1f} N m), best paper {paper_residual[len(designs) - 1]:.4g} "
                  f"mm ({paper_best[len(designs) - 1]})", flush=True)
    opt_res, opt_worst, opt_tau = np.asarray(opt_res), np.asarray(opt_worst), np.asarray(opt_tau)
    torque_ok = opt_tau <= TORQUE_TOL * bound
    tf_min, reduction = _shortest(tfs, (opt_res <= target) & torque_ok, tf_ref)
    tf_min_r, reduction_r = _shortest(tfs, (opt_worst <= target_perturbed) & torque_ok, tf_ref)
    return CycleTimeStudy(payload, tf_ref, tfs, paper_best, paper_residual, opt_res, opt_worst, opt_tau, designs,
                          bound, target, target_perturbed, train, tf_min, reduction, tf_min_r, reduction_r,
                          time.time() - started)


def _shortest(tfs, ok, tf_ref):
    """The shortest tf [s] whose design meets the criterion and its reduction relative to tf_ref."""
    hits = np.nonzero(ok)[0]
    if not hits.size:
        return None, None
    tf_min = float(tfs[hits].min())
    return tf_min, 1.0 - tf_min / tf_ref

