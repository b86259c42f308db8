# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Vibration study: 3 blends x 4 motion laws (paper Section 4)
#
# The paper compares the residual vibration of the flexible five-bar for the 12 combinations of a
# corner blend (Lamé, clothoid pair, polar polynomial; d = e = 25 mm) and a motion law (poly7,
# bang-bang, trapezoids with 1/4 and 1/8 acceleration time), in two cases: 6 kg in 0.43 s and
# 0.1 kg in 0.3 s, each followed by a 0.1 s dwell at the place point. This notebook runs that
# sweep with `jf.run_sweep` (one compiled program for every run), prints the metrics
# table with the paper's published torques beside ours, ranks the combinations by their dwell
# residual and draws bar plots and the dwell time histories.
#
# Environment: `JAXFLEX_QUICK=1` runs a coarse version (the Lamé blend only, the 6 kg case, one
# assumed mode per link, ~2 ms steps, first-order model: numbers are NOT the paper's);
# `JAXFLEX_NB_OUT` is the output directory (default `results/notebooks`; files go to its
# `vibration_study/` subdirectory).

# %%
import jax

jax.config.update("jax_enable_x64", True)
import sys

import matplotlib

if "ipykernel" not in sys.modules:      # run as a script (python file.py, the tests): no display, files only
    matplotlib.use("Agg")

import json
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import jaxflex as jf
from jaxflex.experiments import paper_data
from jaxflex.experiments.io import fmt, save_figure, table

QUICK = os.environ.get("JAXFLEX_QUICK", "") == "1"
OUT = Path(os.environ.get("JAXFLEX_NB_OUT", "results/notebooks")) / "vibration_study"
OUT.mkdir(parents=True, exist_ok=True)
print(f"quick mode: {QUICK}; output in {OUT}")

# %% [markdown]
# ## Settings
#
# Full mode: the paper's robot with three assumed modes per link, both paper cases, all 12
# combinations, the default grid (~0.1 ms steps) and the second-order fast model (within 0.3 % of
# the full nonlinear model on the residuals). Quick mode shrinks every axis but keeps the code path.

# %%
DWELL = 0.1
if QUICK:
    robot = jf.robot_preset("default", n_bending=1, n_axial=1)
    cases = jf.PAPER_CASES[:1]
    blends = ("lame",)
    # ~2 ms steps over the motion, 0.2 ms over the dwell, no loop unrolling: the same grid as the
    # other notebooks' quick mode, so the compiled programs are shared when they run in one process
    grid = jf.default_grid(robot, [0.43], DWELL, dt=2e-3)._replace(dwell_steps=500, unroll=1)
    second_order = False
else:
    robot = jf.robot_preset("default")
    cases = jf.PAPER_CASES
    blends = jf.BLENDS
    grid = None
    second_order = True
cycle = jf.cycle_preset("default")
print("cases:", ", ".join(f"{c.payload:g} kg in {c.tf:g} s" for c in cases))

# %% [markdown]
# ## The sweep
#
# Tables of linearization coefficients per blend and payload, then every blend x law x case rollout
# and its metrics in one jitted, vmapped call. The metrics (docs/conventions.md#metrics) come back as arrays indexed
# (blend, law, case).

# %%
res = jf.run_sweep(robot, cycle, cases, jf.SweepConfig(dwell=DWELL, blends=blends, profiles=jf.PROFILES, grid=grid,
                                            with_series=True, second_order=second_order,
                                            estimate=not QUICK))   # the quick grid is coarse by design
print(f"{len(res.blends) * len(res.profiles) * len(res.cases)} runs; grid {res.grid}")
print(f"tables {res.tables_s:.1f} s, rollout compile {res.compile_s:.1f} s, run {res.run_s * 1e3:.0f} ms")

# %% [markdown]
# ## Metrics table
#
# Torque, RMS acceleration error and maximum deflection over the motion, the residual position at
# tf, the dwell residual amplitude max |e - e_static| over the dwell, and the vibration energy at tf.
# `paper` columns: the published Table 7 (6 kg) / Table 9 (0.1 kg) values where they exist.

# %%
COLUMNS = ("max_torque_nm", "rms_acc_error", "max_deflection_mm", "residual_pos_mm", "dwell_residual_mm",
           "residual_energy")
PAPER_TABLES = {(6.0, 0.43): paper_data.TABLE7, (0.1, 0.3): paper_data.TABLE9}


def paper_value(case, metric, blend, law):
    tab = PAPER_TABLES.get((case.payload, case.tf), {})
    return tab.get(metric, {}).get(blend, {}).get(law)


records, tables_md = [], []
for k, case in enumerate(res.cases):
    rows = []
    for i, b in enumerate(res.blends):
        for j, p in enumerate(res.profiles):
            rec = {"payload": case.payload, "tf": case.tf, "blend": b, "profile": p}
            rec.update({m: float(res.metrics[m][i, j, k]) for m in COLUMNS})
            records.append(rec)
            rows.append(rec)
    rows.sort(key=lambda r: r["dwell_residual_mm"])
    head = (["rank", "blend", "law"] + [f"{m} [{jf.UNITS[m]}]" for m in COLUMNS]
            + ["paper torque", "paper max defl."])
    body = [[n + 1, r["blend"], r["profile"]] + [fmt(r[m], 4) for m in COLUMNS]
            + [fmt(paper_value(case, m, r["blend"], r["profile"]), 4)
               for m in ("max_torque_nm", "max_deflection_mm")] for n, r in enumerate(rows)]
    text = f"### {case.payload:g} kg, tf = {case.tf:g} s (sorted by dwell residual)\n\n" + table(head, body)
    tables_md.append(text)
    print(text, "\n")
(OUT / "metrics.md").write_text("\n\n".join(tables_md) + "\n")

best = {}
for k, case in enumerate(res.cases):
    dw = res.metrics["dwell_residual_mm"][:, :, k]
    i, j = np.unravel_index(np.argmin(dw), dw.shape)
    worst = np.unravel_index(np.argmax(dw), dw.shape)
    best[f"{case.payload:g} kg / {case.tf:g} s"] = {
        "blend": res.blends[i], "profile": res.profiles[j], "dwell_residual_mm": float(dw[i, j]),
        "worst": f"{res.blends[worst[0]]}/{res.profiles[worst[1]]}",
        "worst_over_best": float(dw[worst] / dw[i, j])}
for name, b in best.items():
    print(f"{name}: best {b['blend']}/{b['profile']} ({b['dwell_residual_mm']:.4g} mm), "
          f"worst {b['worst']} ({b['worst_over_best']:.1f} x the best)")

# %% [markdown]
# ## Bar plots
#
# Dwell residual (log scale) and peak motor torque per combination, one group per motion law and one
# colour per blend, one row per case.

# %%
nc = len(res.cases)
fig, axes = plt.subplots(nc, 2, figsize=(12, 3.8 * nc), squeeze=False)
width = 0.8 / len(res.blends)
x = np.arange(len(res.profiles))
for k, case in enumerate(res.cases):
    for col, metric in enumerate(("dwell_residual_mm", "max_torque_nm")):
        ax = axes[k, col]
        for i, b in enumerate(res.blends):
            ax.bar(x + (i - (len(res.blends) - 1) / 2) * width, res.metrics[metric][i, :, k], width,
                   color=jf.plotting.BLEND_COLOR.get(b), label=b)
        ax.set_xticks(x, res.profiles)
        ax.set_ylabel(f"{metric} [{jf.UNITS[metric]}]")
        ax.set_title(f"{case.payload:g} kg, tf = {case.tf:g} s")
        if metric == "dwell_residual_mm":
            ax.set_yscale("log")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
fig.tight_layout()
save_figure(fig, OUT / "bars.png", show=True)

# %% [markdown]
# ## Dwell time histories (paper Fig. 12)
#
# |e| during the motion and |e - e_static| over the dwell for every combination of the first case.

# %%
s = jax.tree_util.tree_map(np.asarray, res.series)           # leaves (blend, law, case, time, ...)
keys = [(i, j, f"{b}/{p}") for i, b in enumerate(res.blends) for j, p in enumerate(res.profiles)]
fig = jf.plotting.tracking_errors(
    s.t[0, 0, 0], s.t_dwell[0, 0, 0],
    {key: 1e3 * np.linalg.norm(s.e[i, j, 0], axis=-1) for i, j, key in keys},
    {key: 1e3 * np.linalg.norm(s.e_dwell[i, j, 0] - s.e_static[i, j, 0][None], axis=-1)
     for i, j, key in keys},
    f"End-effector error, {res.cases[0].payload:g} kg, tf = {res.cases[0].tf:g} s")
save_figure(fig, OUT / "dwell_histories.png", show=True)

# %%
summary = {"quick": QUICK, "cases": [c._asdict() for c in res.cases], "blends": list(res.blends),
           "profiles": list(res.profiles), "best": best, "records": records,
           "timing_s": {"tables": res.tables_s, "compile": res.compile_s, "run": res.run_s},
           "figures": sorted(p.name for p in OUT.glob("*.png"))}
(OUT / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
