"""``jaxflex optimize``: optimize the motion law for residual vibration and compare with the baselines.

Thin wrapper around ``jaxflex.optimize.study.optimize_law``: prints the comparison (dwell residual on
the nominal, perturbed and damped models; peak torque), writes the SPEC 7 JSON, and with ``--out DIR``
the checkpoint (resumable), ``trajectory.csv`` (t, x, y, q1, q2 at 10 kHz) and a figure.
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.path import make_path
from jaxflex.profiles import profile_eval, shaped
from jaxflex.robot import cycle_preset, igm, robot_preset
from jaxflex.trajectory import task_from_arc
from jaxflex.optimize.cycle_time import TORQUE_TOL
from jaxflex.optimize.study import optimize_law, verify_law

from .io import atomic_path, fmt, provenance, save_figure, table, write_json

CSV_RATE_HZ = 10_000


def trajectory_rows(robot, path, profile, tf: float, rate: float = CSV_RATE_HZ) -> np.ndarray:
    """(T, 5) rows t [s], x, y [m], q1, q2 [rad] sampled at ``rate`` [Hz] over [0, tf]."""
    t = np.arange(int(round(tf * rate)) + 1) / rate
    t[-1] = min(t[-1], tf)
    x, q = _positions(robot, path, profile, jnp.asarray(t / tf))
    return np.column_stack([t, np.asarray(x), np.asarray(q)])


@jax.jit
def _positions(robot, path, profile, eta):
    s = profile_eval(profile, eta).s * path.length
    x = task_from_arc(path, s, jnp.zeros_like(s), jnp.zeros_like(s), jnp.zeros_like(s))[0]
    return x, jax.vmap(lambda p: igm(robot, p))(x)


def write_trajectory_csv(path_out, rows: np.ndarray) -> None:
    with atomic_path(path_out) as tmp:
        np.savetxt(tmp, rows, delimiter=",", header="t,x,y,q1,q2", comments="", fmt="%.12g")


def summary(study) -> dict:
    """Per law: dwell residual [mm] (nominal per payload, worst perturbed, damped per payload), peak
    torque [N m] (nominal), and the ratio of the best paper law's residual to the law's."""
    ev = study.evaluations
    best = next(k for k in ev["nominal"] if k.endswith("(best paper)"))
    out = {}
    for law in ev["nominal"]:
        nom = ev["nominal"][law]
        pert = ev["perturbed"][law]["dwell_residual_mm"]
        pert_ref = ev["perturbed"][best]["dwell_residual_mm"]
        out[law] = {
            "dwell_residual_mm": nom["dwell_residual_mm"].tolist(),
            "ratio_best_paper": (ev["nominal"][best]["dwell_residual_mm"] / nom["dwell_residual_mm"]).tolist(),
            "perturbed_worst_mm": float(pert.max()),
            "perturbed_ratio_worst": float(np.min(pert_ref / pert)),
            "perturbed_ratio_of_worst": float(pert_ref.max() / pert.max()),
            "damped_mm": ev["damped"][law]["dwell_residual_mm"].tolist(),
            "max_torque_nm": nom["max_torque_nm"].tolist(),
            "residual_energy": nom["residual_energy"].tolist(),
            "metrics": {k: v.tolist() for k, v in nom.items()},
        }
    return out


def text(rec: dict) -> str:
    head = ["law", "dwell [mm]", "x best paper", "perturbed worst [mm]", "x (worst/worst)",
            "min x per model", "damped [mm]", "torque [N m]"]
    j = lambda v: " / ".join(fmt(x, 3) for x in v)
    rows = [[k, j(v["dwell_residual_mm"]), j(v["ratio_best_paper"]), fmt(v["perturbed_worst_mm"], 3),
             fmt(v["perturbed_ratio_of_worst"], 3), fmt(v["perturbed_ratio_worst"], 3), j(v["damped_mm"]),
             j(v["max_torque_nm"])] for k, v in rec["laws"].items()]
    return (f"Motion-law optimization: payloads {rec['payloads']} kg, tf {rec['tf']:g} s, path {rec['blend']} "
            f"(d = e = 25 mm); torque bound (poly7-Lame) {j(rec['torque_bound_nm'])} N m\n\n"
            + table(head, rows)
            + f"\n\noptimizer: {rec['steps_run']} steps, stopped: {rec['stopped']}, {rec['optimize_s']:.0f} s; "
              f"study {rec['provenance']['wall_time_s']:.0f} s" + _verification_text(rec))


def _verification_text(rec: dict) -> str:
    if "verification" not in rec:
        return ""
    lines = ["", "", "Verification (dwell residual [mm], nominal model):"]
    for case, laws in rec["verification"].items():
        methods = list(next(iter(laws.values())))
        rows = [[law] + [fmt(v[m], 4) for m in methods] for law, v in laws.items()]
        lines += [f"{case}:", table(["law"] + methods, rows)]
    return "\n".join(lines)


def figure(study, robot, path, out_dir: Path):
    import matplotlib.pyplot as plt

    from jaxflex.profiles import make_profile

    best = make_profile(study.best_paper)
    opt = shaped(jnp.asarray(study.coef))
    eta = jnp.linspace(0, 1, 400)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    for p, lab in ((best, f"{study.best_paper} (best paper)"), (make_profile("poly7"), "poly7"), (opt, "optimized")):
        v = profile_eval(p, eta)
        ax[0].plot(eta, v.ds, label=lab)
        ax[1].plot(eta, v.dds, label=lab)
    ax[0].set(xlabel="t / tf", ylabel="S'", title="motion law: velocity")
    ax[1].set(xlabel="t / tf", ylabel="S''", title="acceleration")
    ax[0].legend()
    save_figure(fig, out_dir / "optimized_law.png")


def error_figure(study, out_path: Path, payload_index: int = 0):
    """End-effector error |e| [mm] during the motion and |e - e_static| over the dwell, per law
    (nominal model of the first payload)."""
    import matplotlib.pyplot as plt

    k = payload_index
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    for i, (name, law) in enumerate(study.laws.items()):
        s = study.nominal.series(law)
        e = np.linalg.norm(np.asarray(s.e[k]), axis=-1) * 1e3
        ed = np.linalg.norm(np.asarray(s.e_dwell[k] - s.e_static[k][None]), axis=-1) * 1e3
        style = dict(lw=1.6, color="k") if name == "optimized" else dict(lw=0.9, color=f"C{i}")
        a.plot(np.asarray(s.t[k]), e, label=name, **style)
        b.semilogy(np.asarray(s.t_dwell[k]), np.maximum(ed, 1e-7), **style)
    a.set(xlabel="t [s]", ylabel="|e| [mm]", title="end-effector error during the motion")
    b.set(xlabel="t [s]", ylabel="|e - e_static| [mm]", title="residual vibration in the dwell")
    a.legend(fontsize=7)
    fig.suptitle(f"{study.payloads[k]:g} kg, tf = {study.tf:g} s, {study.blend} path")
    save_figure(fig, out_path)


def compute(preset="default", payloads=(6.0,), tf=0.43, steps=150, n_coef=6, robust=False, out=None,
            learning_rate=0.05, verify=False) -> dict:
    started = time.time()
    robot, cycle = robot_preset(preset), cycle_preset(preset)
    ckpt = None
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        ckpt = Path(out) / "checkpoint.npz"
    study = optimize_law(robot, cycle, payloads, tf, steps=steps, n_coef=n_coef, robust=robust,
                         checkpoint=ckpt, learning_rate=learning_rate)
    path = make_path(cycle, study.blend, 0.025)
    rec = {"payloads": list(study.payloads), "tf": tf, "blend": study.blend, "best_paper": study.best_paper,
           "design": {"blend": study.blend, "d": 0.025, "e": 0.025, "law": "shaped", "order": 3,
                      "coef": study.coef.tolist()},
           "laws": summary(study), "torque_bound_nm": study.torque_bound.tolist(),
           "ruckig_limits": study.ruckig_limits, "first_mode_hz": list(study.first_mode_hz),
           "model_sets": {k: list(v) for k, v in study.sets.items()},
           "history": [list(h) for h in study.result.history], "steps_run": study.result.steps_run,
           "stopped": study.result.stopped, "optimize_s": study.result.wall_s,
           "grid": study.grid._asdict(),
           "provenance": provenance({"preset": preset, "payloads": list(payloads), "tf": tf, "steps": steps,
                                     "n_coef": n_coef, "robust": robust, "learning_rate": learning_rate},
                                    started)}
    if verify:
        from jaxflex.profiles import make_profile

        laws = {f"{study.blend}/{study.best_paper} (best paper)": make_profile(study.best_paper),
                "optimized": shaped(jnp.asarray(study.coef))}
        rec["verification"] = {f"{m:g} kg": verify_law(robot, cycle, study.blend, laws, m, tf) for m in payloads}
    if out:
        out = Path(out)
        rows = trajectory_rows(robot.replace(payload=payloads[0]), path, shaped(jnp.asarray(study.coef)), tf)
        write_trajectory_csv(out / "trajectory.csv", rows)
        figure(study, robot, path, out)
        error_figure(study, out / "error_series.png")
        write_json(out / "optimize.json", rec)
    return rec


def run(preset="default", payloads=(6.0,), tf=0.43, steps=150, n_coef=6, robust=False, out=None,
        json_path=None, learning_rate=0.05, verify=False) -> dict:
    rec = compute(preset, payloads, tf, steps, n_coef, robust, out, learning_rate, verify)
    print(text(rec))
    if json_path:
        write_json(json_path, rec)
    return rec


def cycle_time_record(st) -> dict:
    """JSON record of a ``CycleTimeStudy``."""
    return {"payload": st.payload, "tf_ref": st.tf_ref, "blend": st.blend, "target_mm": st.target,
            "tf_min": st.tf_min, "reduction": st.reduction, "wall_s": st.wall_s,
            "rows": [{"tf": float(t), "paper_best": pb, "paper_best_mm": float(pr), "optimized_mm": float(o),
                      "optimized_torque_nm": float(tq), "torque_bound_nm": float(b), "coef": c.tolist()}
                     for t, pb, pr, o, tq, b, c in zip(st.tfs, st.paper_best, st.paper_residual,
                                                       st.optimized_residual, st.optimized_torque,
                                                       st.torque_bound, st.coefs)]}


def cycle_time_text(rec: dict) -> str:
    rows = [[fmt(r["tf"], 4), r["paper_best"], fmt(r["paper_best_mm"], 4), fmt(r["optimized_mm"], 4),
             fmt(r["optimized_torque_nm"], 4), fmt(r["torque_bound_nm"], 4),
             "yes" if r["optimized_mm"] <= rec["target_mm"] else "no",
             "yes" if r["optimized_torque_nm"] <= TORQUE_TOL * r["torque_bound_nm"] else "NO"] for r in rec["rows"]]
    verdict = ("no tf in the list reaches it" if rec["tf_min"] is None else
               f"shortest tf {rec['tf_min']:g} s: {100 * rec['reduction']:.1f} % shorter than {rec['tf_ref']:g} s")
    return (f"Cycle-time study, {rec['payload']:g} kg, optimized law on the {rec['blend']} path; target: the best "
            f"paper combination at tf = {rec['tf_ref']:g} s, dwell residual {rec['target_mm']:.4g} mm\n\n"
            + table(["tf [s]", "best paper", "best paper [mm]", "optimized [mm]", "torque [N m]",
                     "bound (poly7-Lame) [N m]", "<= target", "torque <= bound"], rows)
            + f"\n\n{verdict} (study {rec['wall_s']:.0f} s)")


def cycle_time_figure(rec: dict, out_path: Path):
    import matplotlib.pyplot as plt

    tf = [r["tf"] for r in rec["rows"]]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(tf, [r["paper_best_mm"] for r in rec["rows"]], "o-", label="best of the 12 paper combinations")
    ax.semilogy(tf, [r["optimized_mm"] for r in rec["rows"]], "s-", label="optimized law")
    ax.axhline(rec["target_mm"], color="k", ls="--", lw=0.8, label=f"best paper at tf = {rec['tf_ref']:g} s")
    ax.set(xlabel="motion time tf [s]", ylabel="dwell residual [mm]",
           title=f"Residual vibration vs cycle time, {rec['payload']:g} kg")
    ax.legend()
    save_figure(fig, out_path)


def run_cycle_time(preset="default", payload=6.0, tf_ref=0.43, tfs=(0.43, 0.40, 0.37, 0.34, 0.31), steps=150,
                   n_coef=6, out=None, json_path=None, learning_rate=0.05) -> dict:
    from jaxflex.optimize.cycle_time import cycle_time_study

    started = time.time()
    robot, cycle = robot_preset(preset), cycle_preset(preset)
    st = cycle_time_study(robot, cycle, payload, tf_ref, tfs, n_coef=n_coef, steps=steps,
                          learning_rate=learning_rate)
    rec = cycle_time_record(st)
    rec["provenance"] = provenance({"preset": preset, "payload": payload, "tf_ref": tf_ref, "tfs": list(tfs),
                                    "steps": steps, "n_coef": n_coef, "learning_rate": learning_rate}, started)
    print(cycle_time_text(rec))
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        cycle_time_figure(rec, Path(out) / "cycle_time.png")
        write_json(Path(out) / "cycle_time.json", rec)
    if json_path:
        write_json(json_path, rec)
    return rec
