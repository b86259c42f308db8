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
import jax.numpy as jnp
import numpy as np

from jaxflex.metrics import METRICS, metrics
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.reference import DEFAULT_DT, METHOD_NAMES, reference_rollout
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import PAPER_CASES, Case, SweepConfig, default_grid, run_sweep

from .io import design_of_record, table

INSTANT = ("residual_pos_mm", "residual_vel", "residual_acc", "residual_acc_low", "residual_energy")


def _changes(a: np.ndarray, b: np.ndarray):
    rel = np.abs(a / b - 1.0)
    return float(np.max(rel)), np.unravel_index(int(np.argmax(rel)), rel.shape)


def dt_study(dwell: float = 0.1) -> dict:
    """Metrics of the 24 runs at the default grid, with their error estimate (``jaxflex.accuracy``),
    and at a quarter of every step (the reference: its own error is about 1/16 of the default's)."""
    robot, cycle = robot_preset("default"), cycle_preset()
    base = default_grid(robot, [c.tf for c in PAPER_CASES], dwell)
    fine = base._replace(coarse=4 * base.coarse, dwell_steps=4 * base.dwell_steps)
    out = {"grids": {"base": base._asdict(), "quarter": fine._asdict()}, "rows": []}
    runs = {}
    for label, grid in (("base", base), ("quarter", fine)):
        print(f"  dt study: grid {label} {tuple(grid)[:3]}", flush=True)
        runs[label] = run_sweep(robot, cycle, PAPER_CASES, SweepConfig(grid=grid, dwell=dwell, timed=False,
                                                                       estimate=label == "base"))
    res = runs["base"]
    for m in METRICS:
        worst, (b, p, c) = _changes(runs["base"].metrics[m], runs["quarter"].metrics[m])
        limit = 0.02 if m in INSTANT else 0.01
        out["rows"].append({"metric": m, "max_rel_change": worst, "limit": limit,
                            "worst_run": f"{res.blends[b]}/{res.profiles[p]}/{res.cases[c].payload:g} kg"})
    out["estimate"] = estimate_rows(res, runs["quarter"].metrics)
    return out


def dt_markdown(study: dict) -> str:
    """The dt-convergence table of ``dt_study`` (largest relative change [%] per metric, limit, worst
    run) as Markdown."""
    g0, g1 = study["grids"]["base"], study["grids"]["quarter"]
    rows = [[r["metric"], f"{100 * r['max_rel_change']:.3f}", f"{100 * r['limit']:.0f}", r["worst_run"],
             "yes" if r["max_rel_change"] < r["limit"] else "NO"] for r in study["rows"]]
    head = (f"Default grid: {g0['coarse']} frozen intervals x {g0['fine']} steps over tf, "
            f"{g0['dwell_steps']} dwell steps; quartered: {g1['coarse']} x {g1['fine']}, "
            f"{g1['dwell_steps']}. Largest relative change over the 24 runs:")
    return head + "\n\n" + table(["metric", "max change [%]", "limit [%]", "worst run", "within"], rows)


def estimate_rows(res, reference: dict) -> dict:
    """The error estimate of a sweep ``res`` (``SweepResult.accuracy``) against its error measured
    from ``reference`` (the same runs on a finer grid), per metric: how many runs the estimate
    covers (estimate >= error), and for the dwell residual every run's value, estimate, error and
    tolerance [mm], and whether the ranking of the runs by it is the same in each case."""
    acc = res.accuracy
    rows = []
    for m in METRICS:
        est, err = np.asarray(acc.errors[m]), np.abs(np.asarray(res.metrics[m]) - np.asarray(reference[m]))
        rows.append({"metric": m, "covered": int(np.sum(est >= err)), "runs": int(est.size),
                     "max_error_rel": float(np.max(err / np.abs(reference[m]))),
                     "max_estimate_rel": float(np.max(est / np.abs(reference[m])))})
    m = "dwell_residual_mm"
    runs = []
    for b, blend in enumerate(res.blends):
        for p, prof in enumerate(res.profiles):
            for c, case in enumerate(res.cases):
                runs.append({"run": f"{blend}/{prof}", "payload": case.payload, "tf": case.tf,
                             "value_mm": float(res.metrics[m][b, p, c]), "estimate_mm": float(acc.errors[m][b, p, c]),
                             "error_mm": float(abs(res.metrics[m][b, p, c] - reference[m][b, p, c])),
                             "tolerance_mm": float(acc.tolerance_mm[b, p, c])})
    order = lambda v: [np.argsort(np.asarray(v)[..., c].ravel()).tolist() for c in range(len(res.cases))]
    return {"grid": acc.grid._asdict(), "compared_with": acc.compared_with._asdict(), "ratio": acc.ratio,
            "met": acc.met, "rows": rows, "dwell_runs": runs,
            "same_ranking": order(res.metrics[m]) == order(reference[m])}


def estimate_markdown(study: dict) -> str:
    """The error estimate against the measured error: one row per metric, then the dwell residual's
    worst runs."""
    e = study["estimate"]
    rows = [[r["metric"], f"{r['covered']}/{r['runs']}", f"{100 * r['max_estimate_rel']:.3f}",
             f"{100 * r['max_error_rel']:.3f}"] for r in e["rows"]]
    runs = e["dwell_runs"]
    over = max(runs, key=lambda r: r["error_mm"] / r["tolerance_mm"])
    under = [r for r in runs if r["estimate_mm"] < r["error_mm"]]
    text = (f"Error estimate by step doubling (the default grid against one with every step {e['ratio']:.2g}x "
            f"longer) and the error measured against the quartered grid, 24 runs:\n\n"
            + table(["metric", "runs with estimate >= error", "largest estimate [%]", "largest error [%]"], rows)
            + f"\n\nDwell residual: tolerance {'met' if e['met'] else 'MISSED'} by the estimate in every run; the "
            f"largest measured error is {over['error_mm'] / over['tolerance_mm']:.2f} of its tolerance "
            f"({over['run']}, {over['payload']:g} kg). ")
    if under:
        worst_under = max(under, key=lambda r: r["error_mm"] / r["tolerance_mm"])
        text += (f"Where the estimate is below the error ({len(under)} runs), the error is at most "
                 f"{worst_under['error_mm'] / worst_under['tolerance_mm']:.2f} of the tolerance. ")
    return text + ("The ranking of the 12 combinations by dwell residual is the same on both grids in both cases."
                   if e["same_ranking"] else "The ranking by dwell residual CHANGES between the grids.")


def design_estimates(designs, dwell: float = 0.1, refine: int = 3) -> list[dict]:
    """The error estimate of optimized designs on their nominal robot, against the same design on a
    grid with every step ``2**refine`` times shorter. ``designs``: (label, payload [kg], tf [s],
    design record (``jaxflex optimize``'s ``design``)) tuples."""
    from jaxflex.accuracy import coarser_grid, estimated
    from jaxflex.designs import design_path
    from jaxflex.engine import LawEvaluator
    from jaxflex.model_sets import model_set
    from jaxflex.profiles import shaped
    from jaxflex.sweep import grid_step, step_squarings

    robot, cycle = robot_preset("default"), cycle_preset()
    out = []
    for label, payload, tf, rec in designs:
        x, blend, _ = design_of_record(rec)
        grid = default_grid(robot, [tf], dwell)
        coarse, ratio = coarser_grid(grid, step_squarings(robot, 2 * grid_step(grid, tf, dwell)))
        ref = grid._replace(coarse=grid.coarse * 2**refine, dwell_steps=grid.dwell_steps * 2**refine)
        ev = LawEvaluator(model_set(robot, [payload]), design_path(cycle, x, blend), tf, dwell, grid)
        law = shaped(jnp.asarray(rec["coef"]), rec.get("order", 3), name=label)
        print(f"  error estimate of the design {label}: grids {tuple(coarse)[:3]}, {tuple(grid)[:3]}, "
              f"reference {tuple(ref)[:3]}", flush=True)
        run = lambda g: ev.with_grid(g)(law)
        mets = run(grid)
        acc, final = estimated(run, grid, mets, (coarse, ratio), refine=2)
        reference = run(ref)
        value = lambda m, k: float(m[k][0])
        out.append({"design": label, "payload": payload, "tf": tf, "grid": acc.grid._asdict(),
                    "compared_with": acc.compared_with._asdict(), "refinements": acc.refinements, "met": acc.met,
                    "dwell_residual_mm": value(final, "dwell_residual_mm"),
                    "estimate_mm": value(acc.errors, "dwell_residual_mm"),
                    "error_mm": abs(value(final, "dwell_residual_mm") - value(reference, "dwell_residual_mm")),
                    "tolerance_mm": float(acc.tolerance_mm[0]),
                    "errors": {k: value(acc.errors, k) for k in METRICS},
                    "measured": {k: abs(value(final, k) - value(reference, k)) for k in METRICS}})
    return out


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
