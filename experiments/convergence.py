"""Step convergence of the fast rollouts and the cross-check against the full nonlinear model.

- ``dt_study``: all 24 paper runs at the default grid and with every step quartered (frozen
  intervals, fine steps and dwell steps), the relative change of every metric (limits: < 1 %, values
  at the single instant tf < 2 %).
- ``reference_study``: the fast formulation against the full nonlinear model (``jaxflex.reference``,
  its exponential integrator by default), Lamé path, four motion laws, both paper cases.
"""
from __future__ import annotations

import time

import jax
import numpy as np

from jaxflex.metrics import METRICS, metrics
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.reference import DEFAULT_DT, METHOD_NAMES, reference_rollout
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import PAPER_CASES, Case, SweepConfig, default_grid, run_sweep

from .io import table

INSTANT = ("residual_pos_mm", "residual_vel", "residual_acc", "residual_acc_low", "residual_energy")


def _changes(a: np.ndarray, b: np.ndarray):
    rel = np.abs(a / b - 1.0)
    return float(np.max(rel)), np.unravel_index(int(np.argmax(rel)), rel.shape)


def dt_study(dwell: float = 0.1) -> dict:
    """Metrics of the 24 runs at the default grid and at a quarter of every step."""
    robot, cycle = robot_preset("default"), cycle_preset()
    base = default_grid(robot, [c.tf for c in PAPER_CASES], dwell)
    fine = base._replace(coarse=4 * base.coarse, dwell_steps=4 * base.dwell_steps)
    out = {"grids": {"base": base._asdict(), "quarter": fine._asdict()}, "rows": []}
    runs = {}
    for label, grid in (("base", base), ("quarter", fine)):
        print(f"  dt study: grid {label} {tuple(grid)[:3]}", flush=True)
        runs[label] = run_sweep(robot, cycle, PAPER_CASES, SweepConfig(grid=grid, dwell=dwell, timed=False))
    res = runs["base"]
    for m in METRICS:
        worst, (b, p, c) = _changes(runs["base"].metrics[m], runs["quarter"].metrics[m])
        limit = 0.02 if m in INSTANT else 0.01
        out["rows"].append({"metric": m, "max_rel_change": worst, "limit": limit,
                            "worst_run": f"{res.blends[b]}/{res.profiles[p]}/{res.cases[c].payload:g} kg"})
    return out


def dt_markdown(study: dict) -> str:
    """The dt-convergence table (largest relative change [%] per metric, limit, worst run) as Markdown."""
    g0, g1 = study["grids"]["base"], study["grids"]["quarter"]
    rows = [[r["metric"], f"{100 * r['max_rel_change']:.3f}", f"{100 * r['limit']:.0f}", r["worst_run"],
             "yes" if r["max_rel_change"] < r["limit"] else "NO"] for r in study["rows"]]
    head = (f"Default grid: {g0['coarse']} frozen intervals x {g0['fine']} steps over tf, "
            f"{g0['dwell_steps']} dwell steps; quartered: {g1['coarse']} x {g1['fine']}, "
            f"{g1['dwell_steps']}. Largest relative change over the 24 runs:")
    return head + "\n\n" + table(["metric", "max change [%]", "limit [%]", "worst run", "within"], rows)


def reference_study(dt: float | None = None, cases=PAPER_CASES, dwell: float = 0.1, method: str = "exprb3") -> dict:
    """Fast formulation vs the full nonlinear model integrated by ``method`` at ``dt`` [s] (its
    default step if None; ``jaxflex.reference``), Lamé, four laws, for every case (payload [kg],
    tf [s]). The exponential integrator keeps the undamped 18.6 kHz axial modes undamped at its
    default step; RK4 damps them numerically by 1 - |R(i omega dt)| ~ (omega dt)^6 / 144 per step,
    so it needs a far smaller step to keep them (figures in docs/performance.md)."""
    robot, cycle = robot_preset("default"), cycle_preset()
    dt = DEFAULT_DT[method] if dt is None else dt
    out = {"dt": dt, "method": method, "cases": []}
    for case in cases:
        case = Case(*case)
        fast = run_sweep(robot, cycle, [case], SweepConfig(blends=("lame",), dwell=dwell, timed=False))
        profiles = [make_profile(p) for p in fast.profiles]
        print(f"  full nonlinear model, {case.payload:g} kg, tf = {case.tf:g} s: {METHOD_NAMES[method]}, "
              f"dt = {dt:g} s ({len(profiles)} laws) ...", flush=True)
        t0 = time.perf_counter()
        ref = jax.vmap(metrics)(reference_rollout(robot.replace(payload=case.payload),
                                                  make_path(cycle, "lame", 0.025), profiles, case.tf, dwell, dt=dt,
                                                  method=method))
        elapsed = time.perf_counter() - t0
        rows = {m: {"fast": fast.metrics[m][0, :, 0].tolist(), "full": np.asarray(ref[m]).tolist()} for m in METRICS}
        out["cases"].append({"payload": case.payload, "tf": case.tf, "profiles": list(fast.profiles),
                             "metrics": rows, "reference_s": elapsed})
    return out


def reference_changes(study: dict) -> dict:
    """Largest |fast / full - 1| per metric over every case and law."""
    return {m: max(abs(a / b - 1) for c in study["cases"] for a, b in zip(c["metrics"][m]["fast"],
                                                                            c["metrics"][m]["full"]))
            for m in METRICS}


def reference_markdown(study: dict) -> str:
    """Fast minus full-model metrics, relative [%], one table per case, one column per motion law."""
    parts = []
    for c in study["cases"]:
        rows = []
        for m, v in c["metrics"].items():
            rel = [100 * (a / b - 1) for a, b in zip(v["fast"], v["full"])]
            rows.append([m] + [f"{x:+.3f}" for x in rel])
        parts.append(f"Fast minus full, relative [%], {c['payload']:g} kg, tf = {c['tf']:g} s, Lamé; full model "
                     f"by {METHOD_NAMES[study.get('method', 'rk4')]}, h = {study['dt'] * 1e6:g} us "
                     f"({c['reference_s']:.0f} s):\n\n"
                     + table(["metric"] + c["profiles"], rows))
    return "\n\n".join(parts)
