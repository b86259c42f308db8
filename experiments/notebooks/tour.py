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
# # A tour of jaxflex
#
# Build the five-bar robot of the paper, an Adept pick-and-place path with Lamé corner blends and a
# motion law, then simulate the flexible robot along the trajectory with the fast model (linearized
# elastodynamics with a perfect controller) and look at the end-effector error and the motor
# torques, during the motion and over the dwell at the place point.
#
# Environment: `JAXFLEX_QUICK=1` runs a coarse version (one assumed mode per link, ~2 ms steps,
# first-order model; its time is almost all JAX compilation); `JAXFLEX_NB_OUT` is the output
# directory (default `results/notebooks`; figures go to its `tour/` subdirectory).

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

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import jaxflex as jf
from jaxflex.experiments.io import fmt, save_figure, table

QUICK = os.environ.get("JAXFLEX_QUICK", "") == "1"
OUT = Path(os.environ.get("JAXFLEX_NB_OUT", "results/notebooks")) / "tour"
OUT.mkdir(parents=True, exist_ok=True)
print(f"quick mode: {QUICK}; figures in {OUT}")

# %% [markdown]
# ## Robot, cycle, path, motion law
#
# `robot_preset("default")` is the paper's five-bar (Table 3 links, motors 0.2 m apart) with three
# assumed modes per link; `cycle_preset` places the Adept cycle (25 mm lift, 350 mm traverse)
# symmetrically in its workspace. The payload is a point mass at the end effector.
# Quick mode keeps one assumed mode per link: the same code, a much smaller model.

# %%
PAYLOAD, TF, DWELL = 6.0, 0.43, 0.1        # kg, s (paper case 1), s
BLEND, LAW = "lame", "poly7"

modes = dict(n_bending=1, n_axial=1) if QUICK else {}
robot = jf.robot_preset("default", payload=PAYLOAD, **modes)
cycle = jf.cycle_preset("default")
path = jf.make_path(cycle, BLEND, d=0.025, e=0.025, n=3.0)
profile = jf.make_profile(LAW)

print(f"pick {np.asarray(cycle.pick)} m -> place {np.asarray(cycle.place)} m, lift {float(cycle.h):g} m")
print(f"{BLEND} blends d = e = 25 mm: path length {float(path.length) * 1e3:.2f} mm")
print(f"assumed modes per link: {robot.n_bending} bending (proximal), {robot.n_axial} axial (distal)")

# %% [markdown]
# The motion law S(eta), eta = t / tf, gives the fraction of the path covered. The four paper laws
# (`jf.plotting.motion_laws` is the paper's Fig. 7):

# %%
eta = jnp.linspace(0.0, 1.0, 401)
fig = jf.plotting.motion_laws(np.asarray(eta), {p: jf.profile_eval(jf.make_profile(p), eta) for p in jf.PROFILES})
save_figure(fig, OUT / "motion_laws.png", show=True)
v = jf.profile_eval(profile, eta)
print(f"{LAW}: peak S' = {float(jnp.max(v.ds)):.4f}, peak |S''| = {float(jnp.max(jnp.abs(v.dds))):.4f} "
      f"(x L / tf, x L / tf^2 for the path speed and acceleration)")

# %% [markdown]
# ## Simulating with the fast model
#
# `jf.run_sweep` is the entry point of the fast model: it tabulates the linearization
# coefficients along each path, then simulates every blend x law x case in ONE compiled, vmapped
# program (motion over [0, tf], then the dwell with the motors holding the place pose).
# `with_series=True` returns the time series besides the metrics. One trajectory is the sweep
# restricted to one blend; we keep the four laws (they share the compiled program, so they cost
# almost nothing more) and follow `poly7` below.
#
# Quick mode: ~2 ms steps over the motion (`default_grid(..., dt=2e-3)`; the integrator is exact per
# step for the frozen coefficients, so coarse steps stay stable) and the plain linearized model
# (`second_order=False`; the default adds the full model's second-order remainder).

# %%
if QUICK:
    # ~2 ms steps over the motion, 0.2 ms over the dwell, no loop unrolling (a smaller program, the
    # same result). The same grid in every notebook's quick mode: run in one process, they share the
    # compiled programs.
    grid = jf.default_grid(robot, [0.43], DWELL, dt=2e-3)._replace(dwell_steps=500, unroll=1)
    second_order = False
else:
    grid = None                               # default: ~0.1 ms steps
    second_order = True
config = jf.SweepConfig(dwell=DWELL, blends=(BLEND,), profiles=jf.PROFILES, grid=grid, with_series=True,
                        second_order=second_order, estimate=not QUICK)   # the quick grid is coarse by design
res = jf.run_sweep(robot, cycle, [jf.Case(PAYLOAD, TF)], config)
print(f"grid {res.grid}; tables {res.tables_s:.1f} s, compile {res.compile_s:.1f} s, "
      f"run {res.run_s * 1e3:.0f} ms for {len(res.blends) * len(res.profiles)} trajectories")

j = res.profiles.index(LAW)
all_series = jax.tree_util.tree_map(np.asarray, res.series)    # leaves (blend, law, case, ...) as numpy
series = jax.tree_util.tree_map(lambda a: a[0, j, 0], all_series)
run_metrics = {k: float(res.metrics[k][0, j, 0]) for k in jf.METRICS}
print(table(["metric", "value", "unit"], [[k, fmt(v, 4), jf.UNITS[k]] for k, v in run_metrics.items()]))

# %% [markdown]
# ## End-effector error
#
# e = X_flexible - X_desired. During the motion it is the elastic deflection (including the static
# gravity sag); over the dwell, e - e_static is the residual vibration that delays the next pick.

# %%
e_mm = 1e3 * series.e
dwell_mm = 1e3 * (series.e_dwell - series.e_static[None])
fig, ax = plt.subplots(1, 2, figsize=(12, 4))
ax[0].plot(series.t, e_mm[:, 0], label="e_x")
ax[0].plot(series.t, e_mm[:, 1], label="e_y")
ax[0].plot(series.t, np.linalg.norm(e_mm, axis=-1), "k", lw=0.8, label="|e|")
ax[0].set(xlabel="t [s]", ylabel="error [mm]", title=f"during the motion ({BLEND}/{LAW}, {PAYLOAD:g} kg)")
ax[1].plot(series.t_dwell, dwell_mm[:, 0], label="x")
ax[1].plot(series.t_dwell, dwell_mm[:, 1], label="y")
ax[1].set(xlabel="t [s]", ylabel="e - e_static [mm]", title="residual vibration over the dwell")
for a in ax:
    a.grid(alpha=0.3)
    a.legend()
fig.tight_layout()
save_figure(fig, OUT / "error.png", show=True)

# All four laws on the same path (the paper's Fig. 12 layout, library plot):
s_ = all_series
fig = jf.plotting.tracking_errors(
    s_.t[0, 0, 0], s_.t_dwell[0, 0, 0],
    {f"{BLEND}/{p}": 1e3 * np.linalg.norm(s_.e[0, k, 0], axis=-1) for k, p in enumerate(res.profiles)},
    {f"{BLEND}/{p}": 1e3 * np.linalg.norm(s_.e_dwell[0, k, 0] - s_.e_static[0, k, 0][None], axis=-1)
     for k, p in enumerate(res.profiles)},
    f"End-effector error, {PAYLOAD:g} kg, tf = {TF:g} s")
save_figure(fig, OUT / "error_all_laws.png", show=True)

# %% [markdown]
# ## Motor torques
#
# The perfect controller imposes the rigid inverse-kinematics motion on the motors; the torques it
# needs include the elastic reaction of the links.

# %%
fig, ax = plt.subplots(figsize=(8, 4))
for k in range(2):
    ax.plot(series.t, series.tau[:, k], f"C{k}", label=f"motor {k + 1}")
    ax.plot(series.t_dwell, series.tau_dwell[:, k], f"C{k}", lw=0.8)
ax.axvline(TF, color="k", lw=0.6, ls=":")
ax.set(xlabel="t [s]", ylabel="torque [N m]",
       title=f"motor torques ({BLEND}/{LAW}, {PAYLOAD:g} kg; dwell after the dotted line)")
ax.grid(alpha=0.3)
ax.legend()
fig.tight_layout()
save_figure(fig, OUT / "torques.png", show=True)

# %%
summary = {
    "quick": QUICK, "payload_kg": PAYLOAD, "tf_s": TF, "blend": BLEND, "law": LAW,
    "path_length_m": float(path.length), "metrics": run_metrics,
    "peak_error_mm": float(np.max(np.linalg.norm(e_mm, axis=-1))),
    "peak_torque_nm": float(np.max(np.abs(series.tau))),
    "figures": sorted(p.name for p in OUT.glob("*.png")),
}
(OUT / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
print(json.dumps({k: summary[k] for k in ("peak_error_mm", "peak_torque_nm")}))
