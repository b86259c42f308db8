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
# # Optimizing the trajectory for a new payload and cycle time
#
# The paper tunes its trajectories for 6 kg in 0.43 s and 0.1 kg in 0.3 s. Here the robot carries a
# new payload on a new cycle time. We
#
# 1. run the 12 paper combinations (3 blends x 4 motion laws) for the new case and take the one
#    with the smallest dwell residual: the best paper combination;
# 2. optimize a design by gradient (reverse mode through the whole rollout, optax Adam:
#    `jf.minimize`) against the residual-vibration objective of
#    `jf.LawObjective` (log scale, relative to the best paper combination: 0 = as good as
#    it, -4.6 = 10x less residual), with a penalty above the poly7-Lamé peak torque;
# 3. compare the optimized trajectory with the best paper combination.
#
# Full mode runs the library's whole study, `jf.optimize_design`: the design is
# the Lamé blend (d, e, n) of both corners plus a shaped monotone motion law
# (`jf.shaped`: zero velocity and acceleration at both ends for any coefficients),
# trained on five models (nominal and the four corners of the perturbation box E +-5 %, payload
# +-10 %), second-order fast model, 100 Adam steps, then evaluated on nominal, perturbed (the nine
# models of that box) and damped models beside the ZV/ZVD input-shaped and Ruckig baselines.
# The first run compiles the design gradient (several minutes on 2 cores; the CLI's persistent cache
# keeps it). `JAXFLEX_QUICK=1` runs steps 1-3 with the study's building blocks on a small model (one
# assumed mode per link, the Lamé blend only, ~2 ms steps, first-order model, nominal model only) and
# optimizes the law alone on the best paper path (`LawObjective`, 10 Adam steps): numbers are not
# meaningful, the code path is. `JAXFLEX_NB_OUT`: output directory (default `results/notebooks`;
# files go to its `optimize_new_payload/` subdirectory).

# %%
import jax

jax.config.update("jax_enable_x64", True)
import sys

import matplotlib

if "ipykernel" not in sys.modules:      # run as a script (python file.py, the tests): no display, files only
    matplotlib.use("Agg")

import dataclasses
import json
import os
from pathlib import Path

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxflex as jf
from jaxflex.experiments.io import fmt, save_figure, table

QUICK = os.environ.get("JAXFLEX_QUICK", "") == "1"
OUT = Path(os.environ.get("JAXFLEX_NB_OUT", "results/notebooks")) / "optimize_new_payload"
OUT.mkdir(parents=True, exist_ok=True)
print(f"quick mode: {QUICK}; output in {OUT}")

# %% [markdown]
# ## The new case
#
# Edit these: payload [kg], motion time tf [s], dwell [s] at the place point, number of Bernstein
# coefficients of the shaped law, Adam learning rate and steps.

# %%
PAYLOAD, TF, DWELL = 3.0, 0.38, 0.1
N_COEF = 6
LEARNING_RATE = 0.05
cycle = jf.cycle_preset("default")
if QUICK:
    robot = jf.robot_preset("default", n_bending=1, n_axial=1)
    STEPS = 10
    blends = ("lame",)
    # the quick grid of every notebook (shared compiled programs when run in one process); built for
    # tf = 0.43 s, the longest paper case, so it has enough exponential squarings for any TF <= 0.43 s
    grid = jf.default_grid(robot, [max(TF, 0.43)], DWELL, dt=2e-3)._replace(dwell_steps=500, unroll=1)
else:
    robot = jf.robot_preset("default")
    STEPS = 100
    blends = jf.BLENDS
    grid = None
print(f"new case: {PAYLOAD:g} kg in {TF:g} s, dwell {DWELL:g} s")

# %% [markdown]
# ## Steps 1-3
#
# Full mode: one call (it checkpoints the optimizer in the output directory: a rerun with the same
# payload, tf and number of coefficients resumes). Quick mode: the steps spelled out, law only. The
# sweep gives the best paper combination and the references of the objective (the best law's
# vibration energy at tf and dwell amplitude, and the poly7-Lamé peak torque as the torque bound).
# The law objective needs the linearization tables of that path for the new payload:
# `jf.sweep_tables` builds them with the sweep's own compiled programs.

# %%
if QUICK:
    config = jf.SweepConfig(dwell=DWELL, blends=blends, profiles=jf.PROFILES, grid=grid, with_series=True,
                         second_order=False, timed=False, estimate=False)   # the quick grid is coarse by design
    res = jf.run_sweep(robot, cycle, [jf.Case(PAYLOAD, TF)], config)
    paper = {k: np.asarray(v) for k, v in res.metrics.items()}               # (blend, law, case)
    paper_blends, paper_profiles = res.blends, res.profiles
    dw = paper["dwell_residual_mm"][:, :, 0]
    bi, bj = np.unravel_index(np.argmin(dw), dw.shape)
    blend, best_law = paper_blends[bi], paper_profiles[bj]
    path = jf.make_path(cycle, blend, 0.025)
    tables = jf.sweep_tables(robot, cycle, [PAYLOAD], blend, config)
    ref = {k: v[bi, bj, 0] for k, v in paper.items()}
    torque_bound = paper["max_torque_nm"][paper_blends.index("lame"), paper_profiles.index("poly7"), 0]
    scales = jf.Scales(energy=jnp.asarray([ref["residual_energy"]]),
                    dwell_ms=jnp.asarray([(1e-3 * ref["dwell_residual_mm"]) ** 2 / 2]),
                    torque_bound=jnp.asarray([torque_bound]))
    # the study's penalty weight; first-order model (no robots)
    objective = jf.LawObjective(tables, jnp.asarray(path.length), jnp.asarray(TF), jnp.asarray(DWELL), scales,
                                grid=res.grid)
    result = jf.minimize(objective, jnp.ones(N_COEF),
                         config=jf.OptimizerConfig(steps=STEPS, learning_rate=LEARNING_RATE, patience=40, label="law"))
    coef = np.asarray(result.params)
    best_key = f"{blend}/{best_law} (best paper)"
    laws = {best_key: {k: float(v) for k, v in ref.items()},
            "optimized": {k: float(np.asarray(v)[0]) for k, v in result.aux.metrics.items()}}
    robust = None
else:
    checkpoint = OUT / f"checkpoint_{PAYLOAD:g}kg_{TF:g}s_{N_COEF}coef.npz"
    study = jf.optimize_design(jf.Problem(robot, cycle, (PAYLOAD,), jf.Timing(TF, DWELL)),
                               dataclasses.replace(jf.StudyConfig(), n_coef=N_COEF).with_optimizer(
                                   steps=STEPS, learning_rate=LEARNING_RATE, checkpoint=checkpoint))
    paper = study.paper
    paper_blends, paper_profiles = jf.BLENDS, jf.PROFILES                        # the study sweeps them all
    blend, best_law, coef, result = study.blend, study.best_paper, study.coef, study.result
    path = study.paths["optimized"]
    x = study.design
    print("optimized blends (pick, place corner): d = {} mm, e = {} mm, n = {}".format(
        *(np.round(1e3 * np.asarray(v), 1).tolist() for v in (x.d, x.e)), np.round(np.asarray(x.n), 2).tolist()))
    torque_bound = float(study.torque_bound[0])
    best_key = f"{blend}/{best_law} (best paper)"
    laws = {name: {k: float(v[0]) for k, v in m.items()} for name, m in study.evaluations["nominal"].items()}
    ev = study.evaluations
    robust = {name: {"perturbed_worst_mm": float(ev["perturbed"][name]["dwell_residual_mm"].max()),
                     "damped_mm": float(ev["damped"][name]["dwell_residual_mm"][0])} for name in laws}
print(f"best paper combination: {blend}/{best_law}; torque bound {float(torque_bound):.4g} N m")
print(f"optimizer: {result.steps_run} steps ({result.stopped}), best objective {result.value:.4g} "
      f"(best paper combination = 0), {result.wall_s:.1f} s")

# %% [markdown]
# ## Comparison with the best paper combination
#
# Same models, same grid. `x best paper`: the best paper combination's dwell residual over the
# trajectory's (above 1: less residual vibration). Full mode adds the worst dwell residual over the
# 9 perturbed models and the residual with 1 % damping at the first mode.

# %%
ref_dwell = laws[best_key]["dwell_residual_mm"]
head = ["law", "dwell residual [mm]", "x best paper", "peak torque [N m]", "energy at tf [J]"]
if robust:
    head += ["perturbed worst [mm]", "damped [mm]"]
rows = []
for name, m in laws.items():
    row = [name, fmt(m["dwell_residual_mm"], 4), fmt(ref_dwell / m["dwell_residual_mm"], 3),
           fmt(m["max_torque_nm"], 4), fmt(m["residual_energy"], 3)]
    if robust:
        row += [fmt(robust[name]["perturbed_worst_mm"], 4), fmt(robust[name]["damped_mm"], 4)]
    rows.append(row)
where = "optimized Lamé blends" if not QUICK else f"law only on the {blend} path (d = e = 25 mm)"
text = (f"{PAYLOAD:g} kg, tf = {TF:g} s, best paper combination {blend}/{best_law}; {where}; "
        f"torque bound {float(torque_bound):.4g} N m\n\n" + table(head, rows))
print(text)
(OUT / "comparison.md").write_text(text + "\n")

# %% [markdown]
# ## Figures
#
# The paper sweep at the new case with the optimized law's dwell residual as a line; the optimized
# law against the best paper law and poly7; the objective along the optimization; the comparison.

# %%
fig, ax = plt.subplots(figsize=(8, 4))
width = 0.8 / len(paper_blends)
x = np.arange(len(paper_profiles))
for i, b in enumerate(paper_blends):
    ax.bar(x + (i - (len(paper_blends) - 1) / 2) * width, paper["dwell_residual_mm"][i, :, 0], width,
           color=jf.plotting.BLEND_COLOR.get(b), label=b)
ax.axhline(laws["optimized"]["dwell_residual_mm"], color="k", ls="--", lw=1, label="optimized")
ax.set_xticks(x, paper_profiles)
ax.set(yscale="log", ylabel="dwell residual [mm]",
       title=f"paper combinations at {PAYLOAD:g} kg, tf = {TF:g} s")
ax.grid(alpha=0.3, axis="y")
ax.legend(fontsize=8)
fig.tight_layout()
save_figure(fig, OUT / "paper_sweep.png", show=True)

eta = jnp.linspace(0.0, 1.0, 401)
curves = {f"{best_law} (best paper)": jf.make_profile(best_law), "poly7": jf.make_profile("poly7"),
          "optimized": jf.shaped(jnp.asarray(coef), name="optimized")}
fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
for label, prof in curves.items():
    v = jf.profile_values(prof, eta)       # one small compiled program per law, not op by op
    ax[0].plot(eta, v.ds, label=label)
    ax[1].plot(eta, v.dds, label=label)
ax[0].set(xlabel="t / tf", ylabel="S'", title="motion law: velocity")
ax[1].set(xlabel="t / tf", ylabel="S''", title="acceleration")
for a in ax:
    a.grid(alpha=0.3)
ax[0].legend()
fig.tight_layout()
save_figure(fig, OUT / "law.png", show=True)

hist = np.asarray([row[:2] for row in result.history], dtype=float).reshape(-1, 2)   # (step, objective)
fig, ax = plt.subplots(figsize=(6, 3.6))
ax.plot(hist[:, 0], hist[:, 1], ".-")
ax.axhline(0.0, color="k", ls=":", lw=1, label="best paper combination")
ax.set(xlabel="Adam step", ylabel="objective (log scale of the residual)", title="optimization")
ax.grid(alpha=0.3)
ax.legend()
fig.tight_layout()
save_figure(fig, OUT / "history.png", show=True)

fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
names = list(laws)
for a, metric, label in ((ax[0], "dwell_residual_mm", "dwell residual [mm]"),
                         (ax[1], "max_torque_nm", "peak torque [N m]")):
    a.bar(np.arange(len(names)), [laws[n][metric] for n in names], color=[f"C{k}" for k in range(len(names))])
    a.set_xticks(np.arange(len(names)), names, rotation=20, ha="right", fontsize=8)
    a.set_ylabel(label)
    a.grid(alpha=0.3, axis="y")
ax[1].axhline(float(torque_bound), color="k", ls=":", lw=1)
fig.suptitle(f"{PAYLOAD:g} kg, tf = {TF:g} s")
fig.tight_layout()
save_figure(fig, OUT / "comparison.png", show=True)

# %%
summary = {"quick": QUICK, "payload_kg": PAYLOAD, "tf_s": TF, "dwell_s": DWELL, "blend": blend,
           "best_paper_law": best_law, "coef": np.asarray(coef).tolist(), "objective": float(result.value),
           "steps_run": int(result.steps_run), "stopped": result.stopped,
           "torque_bound_nm": float(torque_bound),
           "laws": laws, "robust": robust,
           "improvement_over_best_paper": float(ref_dwell / laws["optimized"]["dwell_residual_mm"]),
           "figures": sorted(p.name for p in OUT.glob("*.png"))}
(OUT / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
print(f"optimized law: dwell residual {laws['optimized']['dwell_residual_mm']:.4g} mm, "
      f"{summary['improvement_over_best_paper']:.2f} x less than {best_key}")
