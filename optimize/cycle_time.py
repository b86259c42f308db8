"""Cycle-time study (issue 5): how much shorter can the motion be at equal residual vibration?

For a list of motion times tf the 12 paper combinations are simulated (one sweep, every tf a case)
and a shaped law is optimized on the path of the best paper combination at the reference time
(nominal model, warm-started from the previous tf, torque bounded by the poly7-Lamé peak at the
same tf; a tf counts only when the design keeps that bound within 1 %). The Pareto curve is the optimized dwell residual against tf, beside the best paper
combination at each tf; the study reports the shortest tf whose optimized residual is no worse
than the best paper combination's at the reference time.

Every tf shares one grid (the longest tf's: a shorter tf gets a finer step) and the tables of
one path, so the whole study compiles its rollout and its gradient once.
"""
from __future__ import annotations

import time
from typing import NamedTuple, Sequence

import jax.numpy as jnp
import numpy as np

from jaxflex.path import Cycle, make_path
from jaxflex.profiles import make_profile, shaped
from jaxflex.robot import Robot
from jaxflex.sweep import Case, default_grid, run_sweep

from .baselines import LawEvaluator, model_set
from .objective import Scales
from .study import train_law


TORQUE_TOL = 1.01   # a design counts when its peak torque is within 1 % of the bound (soft penalty)


class CycleTimeStudy(NamedTuple):
    """Per tf (T,): best paper dwell residual [mm] and its combination, optimized residual [mm] and
    peak torque [N m], the torque bound [N m]; the reference residual (best paper at tf_ref), the
    shortest tf meeting it and the relative reduction 1 - tf_min / tf_ref."""

    payload: float
    tf_ref: float
    tfs: np.ndarray
    blend: str
    paper_best: list
    paper_residual: np.ndarray
    optimized_residual: np.ndarray
    optimized_torque: np.ndarray
    torque_bound: np.ndarray
    coefs: np.ndarray
    target: float
    tf_min: float | None
    reduction: float | None
    wall_s: float


def cycle_time_study(robot: Robot, cycle: Cycle, payload: float = 6.0, tf_ref: float = 0.43,
                     tfs: Sequence[float] = (0.43, 0.40, 0.37, 0.34, 0.31), *, dwell: float = 0.1,
                     n_coef: int = 6, steps: int = 150, learning_rate: float = 0.05,
                     progress: bool = True) -> CycleTimeStudy:
    """Run the study (module docstring). ``tfs`` [s] are visited in descending order."""
    started = time.time()
    tfs = np.sort(np.asarray([float(t) for t in tfs]))[::-1]
    if tf_ref not in tfs:
        tfs = np.sort(np.append(tfs, tf_ref))[::-1]
    if not np.all(tfs > 0):
        raise ValueError(f"motion times must be > 0 s, got {tfs}")
    grid = default_grid(robot, [float(tfs.max())], dwell)     # step <= 0.1 ms at every tf
    res = run_sweep(robot, cycle, [Case(payload, float(t)) for t in tfs], dwell=dwell, grid=grid)
    dw = res.metrics["dwell_residual_mm"]                                   # (B, P, T)
    k_ref = int(np.argmin(np.abs(tfs - tf_ref)))
    i, j = np.unravel_index(np.argmin(dw[:, :, k_ref]), dw.shape[:2])
    blend, law = res.blends[i], res.profiles[j]
    target = float(dw[i, j, k_ref])
    paper_best = [f"{res.blends[b]}/{res.profiles[p]}" for b, p in
                  (np.unravel_index(np.argmin(dw[:, :, k]), dw.shape[:2]) for k in range(len(tfs)))]
    paper_residual = dw.min(axis=(0, 1))
    i_lame = res.blends.index("lame")
    bounds = np.asarray(res.metrics["max_torque_nm"][i_lame, res.profiles.index("poly7"), :])
    if progress:
        print(f"cycle-time study, {payload:g} kg: best paper at tf_ref = {tf_ref:g} s is {blend}/{law}, "
              f"dwell residual {target:.4g} mm; optimizing on {blend} for tf = {list(np.round(tfs, 4))}",
              flush=True)
    path = make_path(cycle, blend, 0.025)
    ev = LawEvaluator(model_set(robot, [payload]), path, tf_ref, dwell, grid)
    coef = jnp.ones(n_coef)
    opt_res, opt_tau, coefs = [], [], []
    for k, tf in enumerate(tfs):
        ref = ev(make_profile(law), tf=float(tf))
        amp = ref["dwell_residual_mm"] * 1e-3
        scales = Scales(energy=jnp.asarray(ref["residual_energy"]), dwell_ms=jnp.asarray(amp**2 / 2),
                        torque_bound=jnp.asarray([bounds[k]]))
        result = train_law(ev, path, float(tf), scales, coef, steps=steps, learning_rate=learning_rate,
                           progress=progress)
        coef = result.params
        m = ev(shaped(coef), tf=float(tf))
        opt_res.append(float(m["dwell_residual_mm"][0]))
        opt_tau.append(float(m["max_torque_nm"][0]))
        coefs.append(np.asarray(coef))
        if progress:
            print(f"  tf = {tf:.4g} s: optimized {opt_res[-1]:.4g} mm (torque {opt_tau[-1]:.1f} <= "
                  f"{bounds[k]:.1f} N m), best paper {paper_residual[k]:.4g} mm ({paper_best[k]})", flush=True)
    opt_res = np.asarray(opt_res)
    ok = np.nonzero((opt_res <= target) & (np.asarray(opt_tau) <= TORQUE_TOL * bounds))[0]
    tf_min = float(tfs[ok].min()) if ok.size else None
    reduction = None if tf_min is None else 1.0 - tf_min / tf_ref
    return CycleTimeStudy(payload, tf_ref, tfs, blend, paper_best, paper_residual, opt_res,
                          np.asarray(opt_tau), bounds, np.asarray(coefs), target, tf_min, reduction,
                          time.time() - started)
