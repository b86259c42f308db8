"""``jaxflex optimize``: optimize the trajectory (blends and motion law) for residual vibration and
compare it with the baselines.

Thin wrapper around ``jaxflex.optimize.study.optimize_design``: prints the comparison (dwell residual
on the nominal, perturbed and damped models; peak torque), writes the JSON
(docs/conventions.md#file-formats), and with ``--out DIR`` the checkpoint (resumable),
``trajectory.csv`` with ``controller.json`` (``jaxflex.export``) and figures.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.model_sets import build_model
from jaxflex.optimize.config import SERVO_OBJECTIVES, SERVO_TRAININGS, StudyConfig
from jaxflex.optimize.evaluation import nominal_accuracy
from jaxflex.export import DEFAULT_RATE_HZ as CSV_RATE_HZ, write_controller_files
from jaxflex.optimize.cycle_time import TORQUE_TOL
from jaxflex.optimize.study import optimize_design
from jaxflex.optimize.verification import verify as verify_trajectories
from jaxflex.path import path_frame
from jaxflex.problem import Problem, Timing
from jaxflex.profiles import profile_eval, profile_values
from jaxflex.progress import stage
from jaxflex.robot import igm
from jaxflex.sweep import StepWarning
from jaxflex.trajectory import task_from_arc
from jaxflex.uncertainty import ModelId

from .io import corners_design, fmt, provenance, robot_and_cycle, save_figure, setup_record, table, write_json, write_text



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


def _corners(x) -> list:
    """A design's blend parameters per corner (pick, place) as JSON: d, e [m] and the exponent n."""
    return [{"d_m": float(x.d[i]), "e_m": float(x.e[i]), "n": float(x.n[i])} for i in range(2)]


def design_record(study) -> dict:
    """The optimized trajectory: its path (blend family and per-corner parameters, or the best paper
    path with ``free_path=False``) and its law."""
    law = {"law": "shaped", "order": int(study.candidates["optimized"].law.order),
           "coef": np.asarray(study.coef).tolist()}
    if study.design is None:
        return {"path": {"blend": study.blend, "d": 0.025, "e": 0.025, "n": 3.0, "free": False}, **law}
    return {"path": {"blend": study.paths["optimized"].kind, "corners": _corners(study.design), "free": True,
                     "length_m": float(study.paths["optimized"].length)}, **law}


def summary(study, accuracy: dict | None = None) -> dict:
    """Per candidate: dwell residual [mm] (nominal per payload, worst perturbed, damped per payload),
    peak torque [N m] (nominal), and the ratio of the best paper combination's residual to the
    candidate's (nominal, per perturbed model, worst over worst); with ``accuracy``
    (``optimize.evaluation.nominal_accuracy``) the nominal metrics' error estimates
    (``error_estimate``: metric -> per payload, in the metric's unit) and the dwell residual's
    tolerance [mm] per payload."""
    ev = study.evaluations
    best = next(k for k in ev["nominal"] if k.endswith("(best paper)"))
    out = {}
    for name in ev["nominal"]:
        nom = ev["nominal"][name]
        pert = ev["perturbed"][name]["dwell_residual_mm"]
        pert_ref = ev["perturbed"][best]["dwell_residual_mm"]
        out[name] = {
            "path": study.candidates[name].path,
            "dwell_residual_mm": nom["dwell_residual_mm"].tolist(),
            "ratio_best_paper": (ev["nominal"][best]["dwell_residual_mm"] / nom["dwell_residual_mm"]).tolist(),
            "perturbed_mm": pert.tolist(),
            "perturbed_worst_mm": float(pert.max()),
            "perturbed_ratio_worst": float(np.min(pert_ref / pert)),
            "perturbed_ratio_of_worst": float(pert_ref.max() / pert.max()),
            "damped_mm": ev["damped"][name]["dwell_residual_mm"].tolist(),
            **(_box_summary(study, ev["box"][name]) if "box" in ev else {}),
            **({"richer_mm": ev["richer"][name]["dwell_residual_mm"].tolist(),
                "richer_max_torque_nm": ev["richer"][name]["max_torque_nm"].tolist()} if "richer" in ev else {}),
            "max_torque_nm": nom["max_torque_nm"].tolist(),
            "residual_energy": nom["residual_energy"].tolist(),
            "metrics": {k: v.tolist() for k, v in nom.items()},
        }
        if accuracy and name in accuracy:
            acc = accuracy[name]
            out[name]["error_estimate"] = {k: np.asarray(v).tolist() for k, v in acc.errors.items()}
            out[name]["dwell_residual_tolerance_mm"] = np.asarray(acc.tolerance_mm).tolist()
            out[name]["error_estimate_ratio"] = acc.ratio       # 2: against a coarser grid; 1/2: a finer one
    return out


def accuracy_summary(accuracy: dict) -> dict | None:
    """The nominal evaluations' error estimate as a record (``jaxflex sweep --json``'s ``accuracy``
    keys): met by every candidate or not, the largest estimate over its tolerance, the grids."""
    if not accuracy:
        return None
    accs = list(accuracy.values())
    worst = max(float(np.max(np.asarray(a.errors["dwell_residual_mm"]) / a.tolerance_mm)) for a in accs)
    a = accs[0]
    return {"method": "step doubling: |m - m_coarser| / (r - 1), the nominal models; where that misses the "
                      "tolerance, every step halved: 2 |m - m_finer| (each law's error_estimate_ratio: 2 or 1/2)",
            "rtol": a.rtol, "atol_mm": a.atol_mm, "met": all(x.met for x in accs), "ratio": a.ratio,
            "grid": a.grid._asdict(), "compared_with": a.compared_with._asdict(),
            "max_estimate_over_tolerance": worst}


def _box_summary(study, metrics: dict) -> dict:
    """Per payload: the worst, the 95th percentile and the median of the dwell residual [mm] and
    the largest peak torque [N m] over the study's random models of the uncertainty box."""
    ids = study.sets["box"]
    out = {"box_worst_mm": [], "box_p95_mm": [], "box_median_mm": [], "box_max_torque_nm": []}
    for m in study.payloads:
        k = np.asarray([i.payload == m for i in ids])
        r = metrics["dwell_residual_mm"][k]
        out["box_worst_mm"].append(float(r.max()))
        out["box_p95_mm"].append(float(np.percentile(r, 95)))
        out["box_median_mm"].append(float(np.median(r)))
        out["box_max_torque_nm"].append(float(metrics["max_torque_nm"][k].max()))
    out["box_mm"] = metrics["dwell_residual_mm"].tolist()
    return out


def milestones(study, factors=(5.0, 10.0)) -> dict:
    """When the optimizer first held a design with at most 1/factor of the best paper combination's
    nominal dwell residual on every nominal training model (the history's monitor), and on every
    training model ("<factor>x worst training model"): {factor: {"step",
    "wall_s" (since the loop started, compilation of the first step included), "first_step_s",
    "study_s" (since the study started: baselines, training tables and workspaces included)}}, or
    None for a factor never reached."""
    hist, times = study.result.history, list(study.result.times)
    best = next(k for k in study.evaluations["nominal"] if k.endswith("(best paper)"))
    ref = study.evaluations["nominal"][best]["dwell_residual_mm"]
    idx = [study.train_models.index(ModelId(m)) for m in study.payloads]
    out = {}
    for factor in factors:
        hit = next((k for k, row in enumerate(hist)
                    if len(row) > 2 and all(row[2 + i] * factor <= r for i, r in zip(idx, ref))), None)
        out[f"{factor:g}x"] = None if hit is None or hit >= len(times) else {
            "step": int(hist[hit][0]), "wall_s": float(times[hit]), "first_step_s": float(times[0]),
            "study_s": float(study.setup_s + times[hit])}
        # robust: every training model (the box grid) at most 1/factor of its payload's best paper residual
        payload_of = [i.payload for i in study.train_models]
        limit = {m: r / factor for m, r in zip(study.payloads, ref)}
        hit = next((k for k, row in enumerate(hist)
                    if len(row) > 2 and all(v <= limit[m] for v, m in zip(row[2:], payload_of))), None)
        out[f"{factor:g}x worst training model"] = None if hit is None or hit >= len(times) else {
            "step": int(hist[hit][0]), "wall_s": float(times[hit]), "first_step_s": float(times[0]),
            "study_s": float(study.setup_s + times[hit])}
    return out


def text(rec: dict) -> str:
    """The study record as text: design, comparison table (dwell residual [mm], ratios, perturbed, damped,
    torque [N m]), optimizer timing, milestones and verification."""
    first = next(iter(rec["laws"].values()))
    box, rich = "box_worst_mm" in first, "richer_mm" in first
    head = (["trajectory", "dwell [mm]", "x best paper", "perturbed worst [mm]", "x (worst/worst)",
             "min x per model", "damped [mm]"] + ["box worst [mm]", "box p95 [mm]"] * box
            + ["richer [mm]"] * rich + ["torque [N m]"])
    j = lambda v: " / ".join(fmt(x, 3) for x in v)
    pm = lambda v: " / ".join(fmt(x, 3) + (f" ± {fmt(e, 2)}" if e is not None else "") for x, e in zip(
        v["dwell_residual_mm"], v.get("error_estimate", {}).get("dwell_residual_mm", [None] * len(v["dwell_residual_mm"]))))
    rows = [[k, pm(v), j(v["ratio_best_paper"]), fmt(v["perturbed_worst_mm"], 3),
             fmt(v["perturbed_ratio_of_worst"], 3), fmt(v["perturbed_ratio_worst"], 3), j(v["damped_mm"])]
            + ([j(v["box_worst_mm"]), j(v["box_p95_mm"])] if box else []) + ([j(v["richer_mm"])] if rich else [])
            + [j(v["max_torque_nm"])] for k, v in rec["laws"].items()]
    p = rec["design"]["path"]
    if p["free"]:
        shape = lambda c: f", n = {c['n']:.2f}" if p["blend"] == "lame" else ""
        where = (f"optimized path: {p['blend']} blends, " + "; ".join(
            f"{corner} corner d = {1e3 * c['d_m']:.1f} mm, e = {1e3 * c['e_m']:.1f} mm{shape(c)}"
            for corner, c in zip(("pick", "place"), p["corners"])))
    else:
        where = f"law only, on the best paper path ({p['blend']}, d = e = 25 mm)"
    per = "/".join(f"{m:g}" for m in rec["payloads"])
    nbox = len(rec.get("model_sets", {}).get("box", [])) // max(len(rec["payloads"]), 1)
    return (f"Trajectory optimization: payloads {per} kg, tf {rec['tf']:g} s; best paper combination "
            f"{rec['blend']}/{rec['best_paper']}; trained on the {rec['train']} models; {where}; torque bound "
            f"(poly7-Lame) {j(rec['torque_bound_nm'])} N m. Baselines run along the best paper path; "
            "columns with / are per payload"
            + (f"; box: {nbox} random models of the uncertainty box per payload" if box else "")
            + ("; richer: the richer validation model (every link in bending and tension)" if rich else "")
            + ".\n\n"
            + table(head, rows) + _accuracy_text(rec)
            + f"\n\noptimizer: {rec['steps_run']} steps, stopped: {rec['stopped']}, {rec['optimize_s']:.0f} s "
              f"(the first step, {rec['step_times_s'][0] if rec['step_times_s'] else 0:.0f} s, includes compiling "
              f"the gradient unless the compilation cache had it); study {rec['provenance']['wall_time_s']:.0f} s"
            + _milestone_text(rec) + _verification_text(rec))


def _accuracy_text(rec: dict) -> str:
    """The line under the table on the nominal dwell residuals' error estimate."""
    acc = rec.get("accuracy")
    if not acc:
        return ""
    return (f"\n\nNominal dwell ± its estimated discretization error (step doubling against a grid "
            f"{acc['ratio']:.2g}x coarser, or where that misses, against every step halved; "
            f"docs/conventions.md#accuracy); tolerance {100 * acc['rtol']:g} % of it or "
            f"{1e6 * acc['atol_mm']:g} nm: " + ("met" if acc["met"] else "MISSED")
            + f" (largest estimate {acc['max_estimate_over_tolerance']:.2g} x its tolerance).")


def _milestone_text(rec: dict) -> str:
    parts = []
    for factor, m in rec.get("milestones", {}).items():
        parts.append(f"{factor}: not reached" if m is None else
                     f"{factor} at step {m['step']}, {m['wall_s']:.0f} s ({m['wall_s'] - m['first_step_s']:.0f} s "
                     "after the first step"
                     + (f"; {m['study_s']:.0f} s after the study started" if "study_s" in m else "") + ")")
    return ("\nbest paper combination's nominal dwell residual divided by " + "; ".join(parts)) if parts else ""


def _verification_text(rec: dict) -> str:
    if "verification" not in rec:
        return ""
    lines = ["", "", "Verification (dwell residual [mm], nominal model):"]
    for case, laws in rec["verification"].items():
        methods = list(next(iter(laws.values())))
        rows = [[law] + [fmt(v[m], 4) for m in methods] for law, v in laws.items()]
        lines += [f"{case}:", table(["trajectory"] + methods, rows)]
    return "\n".join(lines)


@jax.jit
def _path_points(path, sigma):
    return jax.vmap(lambda s: path_frame(path, s).pos)(sigma * path.length)


def figure(study, out_dir: Path):
    """The optimized motion law beside the best paper law and poly7, and the optimized path beside
    the best paper path (PNG ``optimized_law.png``, with its SVG copy)."""
    import matplotlib.pyplot as plt

    from jaxflex.names import display_name
    from jaxflex.plotting import LEGEND_SIZE, PAGE_WIDTH, legend_below
    from jaxflex.profiles import make_profile

    best = make_profile(study.best_paper)
    opt = study.candidates["optimized"].law
    eta = jnp.linspace(0, 1, 400)
    fig, ax = plt.subplot_mosaic([["v", "a"], ["path", "path"]], figsize=(PAGE_WIDTH, 5.0), layout="constrained",
                                 height_ratios=[1.0, 0.9])
    laws = ((best, f"{display_name(study.best_paper)} (best paper)", dict(ls="--")),
            (make_profile("poly7"), display_name("poly7"), dict(ls=":")),
            (opt, "optimized", dict(ls="-", color="k", lw=1.6)))
    if study.best_paper == "poly7":         # one curve, one legend entry
        laws = laws[:1] + laws[2:]
    for i, (p, lab, style) in enumerate(laws):
        v = profile_values(p, eta)
        style = dict(color=f"C{i}", lw=1.2) | style
        ax["v"].plot(eta, v.ds, label=lab, **style)
        ax["a"].plot(eta, v.dds, label=lab, **style)
    ax["v"].set(xlabel="t / tf", ylabel="S'", title="motion law: velocity")
    ax["a"].set(xlabel="t / tf", ylabel="S''", title="acceleration")
    legend_below(fig, *ax["v"].get_legend_handles_labels(), loc="outside upper center")
    sigma = jnp.linspace(0.0, 1.0, 801)
    for name, style in (("paper", dict(color="C0", lw=1.2, ls="--")), ("optimized", dict(color="k", lw=1.6))):
        if name == "optimized" and study.design is None:
            continue
        pts = 1e3 * (np.asarray(_path_points(study.paths[name], sigma)) - np.asarray(study.paths[name].cycle.pick))
        label = (f"{display_name(study.blend)}, d = e = 25 mm (best paper)" if name == "paper"
                 else f"optimized ({display_name(study.paths['optimized'].kind)})")
        ax["path"].plot(pts[:, 0], pts[:, 1], label=label, **style)
    ax["path"].set(xlabel="x from the pick point [mm]", ylabel="y [mm]", title="path", aspect="auto")
    ax["path"].legend(fontsize=LEGEND_SIZE, loc="lower center")
    for a in ax.values():
        a.grid(alpha=0.3)
    save_figure(fig, out_dir / "optimized_law.png")


def box_figure(study, robot, out_path: Path) -> None:
    """Dwell residual [mm] of every trajectory on the random models of the uncertainty box against
    the model's first-mode frequency error at the place pose [%] (relative to its payload's nominal
    model), one panel per payload; ``robot``: the study's nominal robot; saved to ``out_path``."""
    from jaxflex.model_sets import place_first_mode_hz
    from jaxflex.names import display_name
    from jaxflex.plotting import MARKERS, legend_below, panel_grid

    cycle = study.paths["paper"].cycle
    ids = study.sets["box"]
    f_nom = {m: place_first_mode_hz(build_model(ModelId(m), robot), cycle) for m in study.payloads}
    err = np.asarray([100 * (place_first_mode_hz(build_model(i, robot, cycle), cycle) / f_nom[i.payload] - 1)
                      for i in ids])
    names = list(study.evaluations["box"])
    fig, axes = panel_grid(len(study.payloads), 3.0, 0.3 + 0.17 * len(names))
    for ax, m in zip(axes, study.payloads):
        k = np.asarray([i.payload == m for i in ids])
        for n, (name, ev) in enumerate(study.evaluations["box"].items()):
            style = (dict(color="k", marker="*", s=22, zorder=3) if name == "optimized" else
                     dict(edgecolors=f"C{n}", facecolors="none", marker=MARKERS[n % len(MARKERS)], s=10, alpha=0.7))
            ax.scatter(err[k], 1e3 * ev["dwell_residual_mm"][k], label=display_name(name), linewidths=0.8, **style)
        ax.set(yscale="log", xlabel="first-mode frequency error\nat the place pose [%]", ylabel="dwell residual [µm]")
        ax.set_title(f"{m:g} kg, tf = {study.tf:g} s: {int(k.sum())} random models", fontsize=10)
        ax.grid(alpha=0.3, which="both")
    legend_below(fig, ncol=1 if len(study.payloads) == 1 else None)
    save_figure(fig, out_path)


def error_figure(study, out_path: Path, payload_index: int = 0):
    """End-effector error |e| [mm] during the motion and |e - e_static| over the dwell, per
    trajectory (nominal model of one payload); every curve has a line style and a marker of its
    own beside its colour (``jaxflex.plotting.curve_style``), the optimized one solid black."""
    import matplotlib.pyplot as plt

    from jaxflex.names import display_name
    from jaxflex.plotting import PAGE_WIDTH, curve_style, legend_below, legend_columns

    k = payload_index
    labels = [display_name(name) for name in study.candidates]
    rows = -(-len(labels) // legend_columns(labels, PAGE_WIDTH))
    fig, (a, b) = plt.subplots(1, 2, figsize=(PAGE_WIDTH, 3.2 + 0.3 + 0.17 * rows), layout="constrained")
    for i, name in enumerate(study.candidates):
        s = study.series(name)
        e = np.linalg.norm(np.asarray(s.e[k]), axis=-1) * 1e3
        ed = np.linalg.norm(np.asarray(s.e_dwell[k] - s.e_static[k][None]), axis=-1) * 1e3
        style = dict(lw=1.6, color="k", ls="-") if name == "optimized" else dict(lw=1.0, color=f"C{i}", **curve_style(i))
        a.plot(np.asarray(s.t[k]), e, label=display_name(name), **style)
        b.semilogy(np.asarray(s.t_dwell[k]), np.maximum(ed, 1e-7), **style)
    a.set(xlabel="t [s]", ylabel="|e| [mm]", title="during the motion")
    b.set(xlabel="t [s]", ylabel="|e - e_static| [mm]", title="residual vibration in the dwell")
    legend_below(fig)
    fig.suptitle(f"End-effector error, {study.payloads[k]:g} kg, tf = {study.tf:g} s", fontsize=11)
    save_figure(fig, out_path)


def closed_loop_section(study, robot, cycle, payload: float, tf: float, options: dict, config: StudyConfig):
    """The closed-loop study of the optimized design (``closed_loop_study``) with the CLI's options:
    (its record, (path, law, servo) of the trajectory to export)."""
    from jaxflex.designs import design_path
    from jaxflex.optimize.closed_loop import Controller, closed_loop_study
    from jaxflex.optimize.config import ROBUST_POWER, SCENARIOS, SERVO_LEARNING_RATE
    from jaxflex.profiles import shaped
    from jaxflex.runtime.compiled import run_isolated_uncached
    from jaxflex.servo import cycle_servo

    if study.design is None:
        raise ValueError("the closed-loop study refines a free-path design; drop --law-only with --servo")
    controller = Controller(options["fc"], options["rate"], options["rotor_inertia"], options["feedforward"])
    order = int(study.candidates["optimized"].law.order)
    # in a process of its own (as reproduce runs it) and without the persistent compilation cache:
    # the closed loop's gradient is one program of about 26,000 memory mappings, writing it to the
    # cache briefly doubles them, and LLVM aborted at the kernel's mapping limit ("Unable to
    # allocate section memory") in the study's process and in a fresh one with the cache on
    # (jaxflex.runtime.compiled, docs/performance.md)
    rec = run_isolated_uncached(closed_loop_study, robot, cycle, payload, tf, 0.1, study.grid, study.design,
                       study.candidates["optimized"].law, controller, fcs=options["fcs"], steps=options["steps"],
                       samples=options["samples"], corners=options["corners"], box=config.box,
                       blend=config.train.blend, order=order, first_mode_hz=study.first_mode_hz[0],
                       ruckig=config.ruckig, scenarios=options.get("scenarios", SCENARIOS),
                       training=options.get("training", "fixed"), power=options.get("power", ROBUST_POWER),
                       rounds=options.get("rounds", 1), objective=options.get("objective", "dwell"),
                       learning_rate=options.get("learning_rate", SERVO_LEARNING_RATE),
                       progress=True)
    path, law = study.paths["optimized"], study.candidates["optimized"].law
    if "refined" in rec:
        x = corners_design(rec["refined"]["design"])
        path, law = design_path(cycle, x, config.train.blend), shaped(x.coef, order, name="optimized")
    servo = cycle_servo(robot.replace(payload=payload), cycle, controller.fc, rate=controller.rate,
                        rotor_inertia=controller.rotor, feedforward=controller.feedforward)
    return rec, (path, law, servo)


def closed_loop_text(rec: dict) -> str:
    """The closed-loop comparison as text: per bandwidth, each trajectory's dwell residual [um]
    under the perfect controller and under the servo (nominal, box worst, p95), its ratio to the
    best paper combination's and its peak torque [N m]."""
    c = rec["controller"]
    parts = [f"Under the servo (rate {c['rate']:g} Hz, rotor {c['rotor']:g} kg m^2; the optimized design with "
             f"the {c['feedforward']} feedforward of the nominal model, the others with the rigid one; box: "
             f"{rec['samples']} random models{' and 32 corners' if rec['corners'] else ''} of the robot's and the "
             "controller's boxes):"]
    if "refined" in rec:
        ref = rec["refined"]
        objective = ref.get("objective", "energy+dwell")      # records written before the choice existed
        for k, rnd in enumerate(ref.get("rounds", [ref])):
            h = rnd["history"]
            which = f", round {k + 1}" if len(ref.get("rounds", ())) > 1 else ""
            models = f" on {len(rnd['training_models'])} models" if rnd.get("training_models") else ""
            parts.append(f"refined with the servo in the loop at fc {c['fc']:g} Hz{which}: {rnd['steps_run']} steps"
                         f"{models}, objective ({objective}) {h[0][1]:.3f} -> {min(r[1] for r in h):.3f}")
    if "shipped" in rec:
        sh = rec["shipped"]
        parts.append(f"the optimized design is examples/designs/{sh['name']}, refined with the servo in the loop at "
                     f"fc {sh['trained_at_hz']:g} Hz by jaxflex optimize --servo (evaluated here, not refined again)")
    head = ["trajectory", "perfect [um]", "nominal [um]", "box worst [um]", "box p95 [um]", "x best paper (nominal)",
            "x best paper (worst)", "torque [N m]"]
    for fc, rows in rec["fcs"].items():
        first = next(iter(rows.values()))
        parts.append(f"\nfc {fc} Hz (best paper combination under this servo: {rec['paper'][fc]['best']}; "
                     f"{first['box_unstable']} of the {first['box_models']} models' loops unstable, left out)")
        parts.append(table(head, [[k, fmt(v["perfect_um"], 3), fmt(v["nominal_um"], 3), fmt(v["box_worst_um"], 3),
                                   fmt(v["p95_um"], 3), fmt(v["ratio_best_paper_nominal"], 3),
                                   fmt(v["ratio_best_paper_worst"], 3), fmt(v["max_torque_nm"], 4)]
                                  for k, v in rows.items()]))
    return "\n".join(parts)


def compute(preset="default", payloads=(6.0,), tf=0.43, out=None, verify=False, grid=None,
            config: StudyConfig = StudyConfig(), export_rate: float = CSV_RATE_HZ, closed_loop: dict | None = None) -> dict:
    """Run the study (``optimize_design`` with ``config``) and return its JSON record; with ``out``
    also write the checkpoint (resumable), ``trajectory.csv`` and ``controller.json``
    (``jaxflex.export``, at ``export_rate`` [Hz]), the figures and ``optimize.json`` there. With
    ``closed_loop`` (fc, rate, rotor_inertia, feedforward, steps, samples, fcs, corners, scenarios, training,
    power, rounds, learning_rate, objective) the design
    is then refined and compared under the servo (``optimize.closed_loop.closed_loop_study``, the
    record's "closed_loop"; the first payload), and the export is the refined design's for that
    servo."""
    started = time.time()
    if closed_loop is not None:          # before the perfect controller's study: a bad count fails now
        extra = sorted(set(closed_loop) - {"fc", "rate", "rotor_inertia", "feedforward", "steps", "samples", "fcs",
                                           "corners", "scenarios", "training", "power", "rounds", "learning_rate",
                                           "objective"})
        if extra:
            raise ValueError(f"the closed-loop study sets up its controller by the default gain rule from fc, the "
                             f"rate, the rotor inertia and the feedforward kind; it does not take {', '.join(extra)} "
                             "(from the robot file's [servo] table): remove them, or use jaxflex sweep")
        for name in ("steps", "samples", "scenarios", "rounds"):
            if name in closed_loop:
                checks.count(f"servo {name}", closed_loop[name], minimum=int(name == "rounds"))
        for name in ("power", "learning_rate"):
            if name in closed_loop:
                checks.positive(f"servo {name.replace('_', ' ')}", closed_loop[name])
        if closed_loop.get("training", "fixed") not in SERVO_TRAININGS:
            raise ValueError(f"servo training must be one of {', '.join(SERVO_TRAININGS)}, "
                             f"got {closed_loop['training']!r}")
        if closed_loop.get("objective", "dwell") not in SERVO_OBJECTIVES:
            raise ValueError(f"servo objective must be one of {', '.join(SERVO_OBJECTIVES)}, "
                             f"got {closed_loop['objective']!r}")
    robot, cycle = robot_and_cycle(preset)
    ckpt = None
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        ckpt = Path(out) / "checkpoint.npz"
    config = config.with_optimizer(checkpoint=ckpt)
    study = optimize_design(Problem(robot, cycle, tuple(payloads), Timing(tf, 0.1, grid)), config)
    accuracy = nominal_accuracy(study.evaluators["nominal"], study.candidates, study.evaluations["nominal"], robot,
                                progress=config.train.optimizer.progress)
    missed = {name: a for name, a in accuracy.items() if not a.met}
    if missed:
        name, a = max(missed.items(), key=lambda kv: float(np.max(kv[1].errors["dwell_residual_mm"] / kv[1].tolerance_mm)))
        k = int(np.argmax(a.errors["dwell_residual_mm"] / a.tolerance_mm))
        warnings.warn(f"the study's grid misses the accuracy asked for: the estimated error of {name}'s nominal dwell "
                      f"residual is {1e3 * float(a.errors['dwell_residual_mm'][k]):.3g} um at {payloads[k]:g} kg, above "
                      f"its tolerance {1e3 * float(a.tolerance_mm[k]):.3g} um (the larger of 0.5 % of it and 1 nm, "
                      "docs/conventions.md#accuracy)", StepWarning, stacklevel=2)
    figures = 2 + ("box" in study.sets)
    bar = stage("study record and outputs", total=1 + (1 + figures if out else 0), unit="part")
    rec = {"payloads": list(study.payloads), "tf": tf, "blend": study.blend, "best_paper": study.best_paper,
           "train": study.train, "design": design_record(study),
           "laws": summary(study, accuracy), "accuracy": accuracy_summary(accuracy),
           "torque_bound_nm": study.torque_bound.tolist(),
           "ruckig_limits": study.ruckig_limits, "first_mode_hz": list(study.first_mode_hz),
           "model_sets": {k: [i.label for i in v] for k, v in study.sets.items()},
           "history": [list(h) for h in study.result.history], "steps_run": study.result.steps_run,
           "stopped": study.result.stopped, "optimize_s": study.result.wall_s,
           "step_times_s": list(study.result.times), "milestones": milestones(study),
           "grid": study.grid._asdict(),
           "provenance": provenance({"preset": setup_record(preset), "payloads": list(payloads), "tf": tf,
                                     **config.record()}, started)}
    bar.update(note="record")
    export_path, export_law, export_servo = study.paths["optimized"], study.candidates["optimized"].law, None
    if closed_loop is not None:
        rec["closed_loop"], (export_path, export_law, export_servo) = closed_loop_section(
            study, robot, cycle, payloads[0], tf, closed_loop, config)
    if out:
        out = Path(out)
        write_controller_files(out, robot.replace(payload=payloads[0]), export_path, export_law, tf,
                               servo=export_servo, rate=export_rate, grid=study.grid)
        bar.update(note="trajectory.csv, controller.json")
        figure(study, out)
        bar.update(note="design figure")
        error_figure(study, out / "error_series.png")
        bar.update(note="error_series.png")
        if "box" in study.sets:
            box_figure(study, robot, out / "box_residuals.png")
            bar.update(note="box_residuals.png")
    bar.close("done")
    if verify:
        from jaxflex.runtime.compiled import release_compiled

        release_compiled()          # the study's programs are done with (memory mappings, jaxflex.runtime.compiled)
        rec["verification"] = verification(rec, preset)
    if out:
        write_json(out / "optimize.json", rec)
    return rec


def trajectories_of(rec: dict, cycle) -> dict:
    """The best paper combination's trajectory and the optimized one of a study record (``compute``),
    rebuilt from the record's numbers (the same arrays as the study's: JSON keeps float64 exactly):
    name -> (Path, Profile)."""
    from jaxflex.designs import design, design_path
    from jaxflex.path import make_path
    from jaxflex.profiles import make_profile, shaped

    law, p = rec["design"], rec["design"]["path"]
    paper = make_path(cycle, rec["blend"], 0.025)
    if p["free"]:
        (c1, c2) = p["corners"]
        x = design(c1["d_m"], c1["e_m"], c1["n"], np.asarray(law["coef"], dtype=float), d2=c2["d_m"], e2=c2["e_m"],
                   n2=c2["n"])
        path = design_path(cycle, x, p["blend"])
    else:
        path = paper
    optimized = shaped(jnp.asarray(law["coef"], dtype=jnp.float64), law["order"], name="optimized")
    return {f"{rec['blend']}/{rec['best_paper']} (best paper)": (paper, make_profile(rec["best_paper"])),
            "optimized": (path, optimized)}


def verification(rec: dict, preset: str = "default") -> dict:
    """The study's independent check (``jaxflex.optimize.verification.verify``) of a study record: the best
    paper combination and the optimized trajectory re-simulated at a quarter step and with the full
    nonlinear model, per payload: "<payload> kg" -> trajectory -> method -> dwell residual [mm]."""
    robot, cycle = robot_and_cycle(preset)
    trajectories = trajectories_of(rec, cycle)
    return {f"{m:g} kg": verify_trajectories(Problem(robot, cycle, (m,), Timing(rec["tf"])), trajectories)
            for m in rec["payloads"]}


def verifications(records: list, preset: str = "default") -> list:
    """``verification`` of several study records in one process: the full model's and the fast
    model's programs compile (or load from the compilation cache) once for all of them."""
    return [verification(rec, preset) for rec in records]


def run(preset="default", payloads=(6.0,), tf=0.43, out=None, json_path=None, verify=False,
        config: StudyConfig = StudyConfig(), export_rate: float = CSV_RATE_HZ, closed_loop: dict | None = None) -> dict:
    """``jaxflex optimize``: ``compute`` with the CLI's arguments (payloads [kg], tf [s], the study's
    configuration, the export's rate [Hz], the closed-loop options), print the text and write the JSON."""
    rec = compute(preset, payloads, tf, out, verify, config=config, export_rate=export_rate, closed_loop=closed_loop)
    body = text(rec) + ("\n\n" + closed_loop_text(rec["closed_loop"]) if "closed_loop" in rec else "")
    print(body)
    if json_path:
        write_json(json_path, rec)
    if out:
        write_text(Path(out) / "REPORT.md", report_text(rec, body, Path(out)))
    return rec


def report_text(rec: dict, body: str, out: Path) -> str:
    """``DIR/REPORT.md`` of ``jaxflex optimize --out DIR``: the robot and the move, the comparison
    printed on the terminal, and the figures and files written beside it."""
    setup = rec["provenance"]["parameters"]["preset"] if "provenance" in rec else "default"
    lines = ["# Trajectory optimization", ""]
    if isinstance(setup, dict):
        r, c = setup["robot"], setup["cycle"]
        lines += [f"Robot `{setup['name']}`: links l1 {r['l1']:g} m, l2 {r['l2']:g} m, section {r['diameter']:g} m, "
                  f"E {r['young']:.4g} Pa, rho {r['rho']:g} kg/m^3, motors at +-{r['a']:g} m, rotor "
                  f"{r['rotor_inertia']:g} kg m^2. Move: pick ({c['pick'][0]:g}, {c['pick'][1]:g}) m to place "
                  f"({c['place'][0]:g}, {c['place'][1]:g}) m, lift {c['h']:g} m.", ""]
    else:
        lines += [f"Robot and move: the `{setup}` preset (docs/conventions.md#frames-and-geometry).", ""]
    lines += [body, "", "## Files", ""]
    figures = [(n, d) for n, d in (("optimized_law.png", "the optimized motion law against the paper's"),
                                   ("error_series.png", "end-effector error during the motion and the dwell"),
                                   ("box_residuals.png", "dwell residual over the uncertainty box"))
               if (out / n).exists()]
    lines += [f"![{d}]({n})" + "\n" for n, d in figures]
    lines += ["`trajectory.csv` with `controller.json`: the design as a controller is given it; `optimize.json`: "
              "every number above (docs/conventions.md#file-formats)."]
    return "\n".join(lines) + "\n"


def cycle_time_record(st) -> dict:
    """JSON record of a ``CycleTimeStudy``."""
    return {"payload": st.payload, "tf_ref": st.tf_ref, "train": st.train, "target_mm": st.target,
            "target_perturbed_worst_mm": st.target_perturbed, "torque_bound_nm": st.torque_bound,
            "tf_min": st.tf_min, "reduction": st.reduction, "tf_min_robust": st.tf_min_robust,
            "reduction_robust": st.reduction_robust, "wall_s": st.wall_s,
            "rows": [{"tf": float(t), "paper_best": pb, "paper_best_mm": float(pr), "optimized_mm": float(o),
                      "optimized_perturbed_worst_mm": float(w), "optimized_torque_nm": float(tq),
                      "corners": _corners(x), "coef": np.asarray(x.coef).tolist()}
                     for t, pb, pr, o, w, tq, x in zip(st.tfs, st.paper_best, st.paper_residual,
                                                       st.optimized_residual, st.optimized_perturbed_worst,
                                                       st.optimized_torque, st.designs)]}


def cycle_time_text(rec: dict) -> str:
    """The cycle-time record as text: target, one row per tf [s] (residuals [mm], torque [N m]), verdicts."""
    bound = rec["torque_bound_nm"]
    rows = [[fmt(r["tf"], 4), r["paper_best"], fmt(r["paper_best_mm"], 4), fmt(r["optimized_mm"], 4),
             fmt(r["optimized_perturbed_worst_mm"], 4), fmt(r["optimized_torque_nm"], 4),
             " / ".join(f"{1e3 * c['e_m']:.0f}" for c in r["corners"]),
             "yes" if r["optimized_mm"] <= rec["target_mm"] else "no",
             "yes" if r["optimized_torque_nm"] <= TORQUE_TOL * bound else "NO"] for r in rec["rows"]]
    shortest = min(r["tf"] for r in rec["rows"])
    verdict = lambda tf_min, red: ("no tf in the list reaches it" if tf_min is None else
                                   f"shortest tf {tf_min:g} s, {100 * red:.1f} % shorter than {rec['tf_ref']:g} s"
                                   + (" (the shortest tf tried: a lower bound on the reduction)"
                                      if tf_min <= shortest else ""))
    return (f"Cycle-time study, {rec['payload']:g} kg: optimized design (blends and motion law, trained on "
            f"the {rec['train']} models) at each tf; target: the best paper combination at tf = {rec['tf_ref']:g} s, "
            f"dwell residual {rec['target_mm']:.4g} mm (nominal; worst over the 9 perturbed models "
            f"{rec['target_perturbed_worst_mm']:.4g} mm); peak torque bound {bound:.4g} N m at every tf "
            f"(poly7-Lamé at {rec['tf_ref']:g} s: the same motors)\n\n"
            + table(["tf [s]", "best paper", "best paper [mm]", "optimized [mm]", "optimized perturbed worst [mm]",
                     "torque [N m]", "e pick / place [mm]", "<= target", "torque <= bound"], rows)
            + f"\n\nequal nominal residual: {verdict(rec['tf_min'], rec['reduction'])}; equal worst perturbed "
              f"residual: {verdict(rec['tf_min_robust'], rec['reduction_robust'])} (study {rec['wall_s']:.0f} s)")


def cycle_time_figure(rec: dict, out_path: Path):
    """Pareto figure: dwell residual [mm] against tf [s], best paper vs optimized, target line; saved to
    ``out_path``."""
    import matplotlib.pyplot as plt

    from jaxflex.plotting import COLUMN_WIDTH, legend_below

    tf = [r["tf"] for r in rec["rows"]]
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 4.2), layout="constrained")
    ax.semilogy(tf, [r["paper_best_mm"] for r in rec["rows"]], "o-", label="best of the 12 paper combinations")
    ax.semilogy(tf, [r["optimized_mm"] for r in rec["rows"]], "s-", label="optimized design")
    ax.semilogy(tf, [r["optimized_perturbed_worst_mm"] for r in rec["rows"]], "s:", color="C1", lw=0.8,
                markerfacecolor="none", label="optimized, worst of 9 perturbed models")
    ax.axhline(rec["target_perturbed_worst_mm"], color="C0", ls=":", lw=0.8,
               label=f"best paper at {rec['tf_ref']:g} s, worst perturbed")
    ax.axhline(rec["target_mm"], color="k", ls="--", lw=0.8, label=f"best paper at tf = {rec['tf_ref']:g} s")
    ax.set(xlabel="motion time tf [s]", ylabel="dwell residual [mm]")
    ax.set_title(f"Residual vibration vs cycle time, {rec['payload']:g} kg", fontsize=10)
    ax.grid(alpha=0.3)
    legend_below(fig, ncol=1)
    save_figure(fig, out_path)


def run_cycle_time(preset="default", payload=6.0, tf_ref=0.43, tfs=(0.43, 0.40, 0.37, 0.34, 0.31), out=None,
                   json_path=None, config: StudyConfig = StudyConfig()) -> dict:
    """``jaxflex optimize --cycle-time``: a design optimized at each tf in ``tfs`` [s] for ``payload`` [kg]
    against the best paper combination at ``tf_ref``; prints, writes JSON/figure, returns the record.
    ``config``: the study's configuration."""
    from jaxflex.optimize.cycle_time import cycle_time_study

    started = time.time()
    robot, cycle = robot_and_cycle(preset)
    st = cycle_time_study(Problem(robot, cycle, (payload,), Timing(tf_ref)), tfs, config)
    rec = cycle_time_record(st)
    rec["provenance"] = provenance({"preset": setup_record(preset), "payload": payload, "tf_ref": tf_ref, "tfs": list(tfs),
                                    **config.record()}, started)
    print(cycle_time_text(rec))
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        cycle_time_figure(rec, Path(out) / "cycle_time.png")
        write_json(Path(out) / "cycle_time.json", rec)
    if json_path:
        write_json(json_path, rec)
    return rec
