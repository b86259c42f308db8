"""Paper Section 3 reproduced: Table 2 (blend lengths), Table 5 (max task acceleration), Table 6 (max
joint acceleration), Fig. 6 (blends), Fig. 7 (motion laws), Figs. 8, 10, 11 (PSD of joint
accelerations). Thin script over the library; ``jaxflex kinematics`` calls ``run``."""
from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks, plotting
from jaxflex.blends import BLENDS, blend_frame, make_blend
from jaxflex.profiles import PROFILES, make_profile, profile_eval
from jaxflex.robot import check_motion_loads
from jaxflex.spectral import welch
from jaxflex.combinations import sample_combinations
from jaxflex.trajectory import time_grid

from . import paper_data
from .io import fmt, pct, provenance, rel_diff, robot_and_cycle, save_figure, setup_name, setup_record, table, write_json

D = 0.025                 # blend size of the paper's 12 combinations [m]
EXTENDED_E = {"lame_extended": 0.0445, "clothoid_extended": 0.044}   # docs/conventions.md#adept-cycle-and-blends
LAME_E_TEXT = 0.125       # the paper's text for the extended Lamé curve [m]
FD_STEP = 1e-3            # sampling step of the paper-style finite-difference joint acceleration [s]
PSD_FS = 10_000.0         # sampling rate for spectra [Hz]
PSD_NPERSEG = 1024


def blend_lengths_mm() -> dict:
    """Table 2: blend lengths [mm] (d = e = 25 mm; extended curves d = 25 mm, e per
    docs/conventions.md#adept-cycle-and-blends)."""
    out = {b: float(make_blend(b, D, D).length) * 1e3 for b in BLENDS}
    for key, e in EXTENDED_E.items():
        out[key] = float(make_blend(key.split("_")[0], D, e).length) * 1e3
    out["lame_extended_e125"] = float(make_blend("lame", D, LAME_E_TEXT).length) * 1e3
    return out


def _samples_at_rate(robot, cycle, tf: float, rate: float, **kw):
    """Every combination sampled at ``rate`` [Hz] from t = 0 to tf (the last sample at or before
    tf) on a grid of ceil(tf rate) + 1 instants beyond which the motion has stopped: one compiled
    program per sample count serves every tf up to it (the figures' three motion times, the
    1 ms second differences and the spectra)."""
    n = int(np.floor(tf * rate + 1e-9))
    t = jnp.asarray(np.arange(int(np.ceil(max(tf, 1.0) * rate)) + 1) / rate)
    traj, labels = sample_combinations(robot, cycle, tf, t, **kw)
    return jax.tree_util.tree_map(lambda a: a[:, : n + 1], traj), labels


def accelerations(preset, tf: float, steps: int) -> dict:
    """Tables 5 and 6: max |X''| [m/s^2] and max |q''| [rad/s^2] over the motion, exact (analytic
    derivatives on a fine grid) and as a second difference of q sampled every FD_STEP. ``preset``: a
    preset's name or a ``jaxflex.robot_files.Setup`` (``io.robot_and_cycle``)."""
    robot, cycle = robot_and_cycle(preset)
    t = time_grid(tf, steps)
    traj, labels = sample_combinations(robot, cycle, tf, t, d=D)
    task = np.max(np.linalg.norm(np.asarray(traj.xdd), axis=-1), axis=1)
    joint = np.max(np.abs(np.asarray(traj.qdd)), axis=(1, 2))
    traj_10k, _ = _samples_at_rate(robot, cycle, tf, PSD_FS, d=D)        # shared with the spectra
    stride = int(round(FD_STEP * PSD_FS))
    q = np.asarray(traj_10k.q)[:, ::stride]
    fd = np.max(np.abs(q[:, 2:] - 2 * q[:, 1:-1] + q[:, :-2]) / FD_STEP**2, axis=(1, 2))
    nest = lambda v: {b: {p: float(v[i]) for i, (bb, p) in enumerate(labels) if bb == b} for b in BLENDS}
    return {"task_acc_max": nest(task), "joint_acc_max": nest(joint), "joint_acc_max_fd_1ms": nest(fd)}


def joint_acc_psd(preset, tf: float, d: float = D, profiles=PROFILES, blends=BLENDS):
    """PSD of both joint accelerations for blends x profiles at tf (sampled at PSD_FS)."""
    robot, cycle = robot_and_cycle(preset)
    traj, labels = _samples_at_rate(robot, cycle, tf, PSD_FS, d=d, blends=blends, profiles=profiles)
    qdd = jnp.swapaxes(traj.qdd[:, :-1], 1, 2)               # (C, 2, T): samples at t < tf
    freqs, psd = welch(qdd, PSD_FS, min(PSD_NPERSEG, qdd.shape[-1]))
    return np.asarray(freqs), {f"{b}-{p}": np.asarray(psd[i]) for i, (b, p) in enumerate(labels)}


@jax.jit
def _blend_points(blend, u):
    """Blend positions at arc-length fractions u (one program per blend family)."""
    return jax.vmap(lambda x: blend_frame(blend, x * blend.length).pos)(u)


def figures(preset, out: Path) -> dict:
    """Figs. 6, 7, 8, 10, 11 as PNG files in ``out``; returns name -> path."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    eta = jnp.linspace(0.0, 1.0, 1001)
    laws = {p: profile_eval(make_profile(p), eta) for p in PROFILES}
    paths["fig7_motion_laws"] = out / "fig7_motion_laws.png"
    save_figure(plotting.motion_laws(np.asarray(eta), laws), paths["fig7_motion_laws"])

    curves = {}
    for b in BLENDS:
        blend = make_blend(b, D, D)
        curves[b] = np.asarray(_blend_points(blend, jnp.linspace(0.0, 1.0, 301)))
    paths["fig6_blends"] = out / "fig6_blends.png"
    save_figure(plotting.blends_overlay(curves), paths["fig6_blends"])

    freqs, psd = joint_acc_psd(preset, 1.0)
    panels = {b: [f"{b}-{p}" for p in PROFILES] for b in BLENDS}
    paths["fig8_psd_combinations"] = out / "fig8_psd_combinations.png"
    save_figure(plotting.psd_panels(freqs, psd, "PSD of joint-1 acceleration, tf = 1 s (Fig. 8)",
                                    panels=panels, fmax=2000), paths["fig8_psd_combinations"])

    series = {}
    for tf in (1.0, 0.5, 0.25):
        f, p = joint_acc_psd(preset, tf, blends=("lame",), profiles=("poly7",))
        series[f"tf = {tf:g} s"] = np.interp(freqs, f, p["lame-poly7"][0])[None]
    paths["fig10_psd_cycle_time"] = out / "fig10_psd_cycle_time.png"
    save_figure(plotting.psd_panels(freqs, series, "Lamé, 7th-degree polynomial, joint 1: cycle time (Fig. 10)",
                                    fmax=2000), paths["fig10_psd_cycle_time"])

    series = {}
    for d in (0.025, 0.0125, 0.00625):
        _, p = joint_acc_psd(preset, 1.0, d=d, blends=("lame",), profiles=("poly7",))
        series[f"d = e = {d * 1e3:g} mm"] = p["lame-poly7"][:1]
    paths["fig11_psd_blend_size"] = out / "fig11_psd_blend_size.png"
    save_figure(plotting.psd_panels(freqs, series, "Lamé, 7th-degree polynomial, joint 1: blend size (Fig. 11)",
                                    fmax=2000), paths["fig11_psd_blend_size"])
    return {k: str(v) for k, v in paths.items()}


def compute(preset="default", tf: float = 1.0, steps: int = 20000) -> dict:
    """All kinematic tables as the JSON structure of docs/conventions.md#file-formats (plus provenance,
    and the paper's values for a preset). ``preset``: a preset's name, or a
    ``jaxflex.robot_files.Setup`` (a robot and move from files: its tables have no paper column, the
    paper's robot and move being another)."""
    started = time.time()
    tf, steps = checks.positive("tf", tf, "s"), checks.count("steps", steps, 2)
    check_motion_loads(*robot_and_cycle(preset), tf)     # e.g. tf = 1e-300: nothing to sample
    result = {"preset": setup_record(preset), "tf": tf, "blend_length_mm": blend_lengths_mm()}
    result.update(accelerations(preset, tf, steps))
    if isinstance(preset, str):
        result["paper"] = {"blend_length_mm": paper_data.TABLE2_BLEND_LENGTH_MM,
                           "task_acc_max": paper_data.TABLE5_TASK_ACC,
                           "joint_acc_max": paper_data.TABLE6_JOINT_ACC}
    result["notes"] = {
        "extended_e_mm": {k: v * 1e3 for k, v in EXTENDED_E.items()},
        "joint_acc_max_fd_1ms": "second difference of the IGM joint angles sampled every 1 ms; the "
                                "exact maximum is joint_acc_max",
    }
    result["provenance"] = provenance({"preset": setup_record(preset), "tf": tf, "steps": steps}, started)
    return result


def tables_markdown(res: dict) -> str:
    """Tables 2, 5, 6: ours beside the paper's with relative differences; ours alone for a robot or
    move from files (no paper values: ``compute``)."""
    pap = res.get("paper")
    cols = ("ours", "paper", "diff") if pap else ("ours",)

    def cells(ours, ref):
        return [fmt(ours), fmt(ref), pct(rel_diff(ours, ref))] if pap else [fmt(ours)]

    rows = [[k, fmt(v, 6)] + (cells(v, pap["blend_length_mm"].get(k))[1:] if pap else [])
            for k, v in res["blend_length_mm"].items()]
    out = ["### Table 2: blend lengths [mm]", "", table(["curve", *cols], rows), ""]
    tf_note = "" if res["tf"] == 1.0 or not pap else f" (ours at tf = {res['tf']:g} s; the paper's at 1 s)"
    for key, title, unit in (("task_acc_max", "Table 5: max task acceleration", "m/s^2"),
                             ("joint_acc_max", "Table 6: max joint acceleration", "rad/s^2")):
        rows = []
        for p in PROFILES:
            row = [p]
            for b in BLENDS:
                row += cells(res[key][b][p], pap[key][b][p] if pap else None)
            if key == "joint_acc_max":
                fd = res["joint_acc_max_fd_1ms"]["lame"][p]
                row += [fmt(fd)] + ([pct(rel_diff(fd, pap[key]["lame"][p]))] if pap else [])
            rows.append(row)
        headers = ["profile"] + ([f"{b} {c}" for b in BLENDS for c in cols] if pap else list(BLENDS))
        if key == "joint_acc_max":
            headers += ["lame ours (1 ms diff.)", "diff"] if pap else ["lame (1 ms diff.)"]
        where = f"preset `{res['preset']}`" if isinstance(res["preset"], str) else f"`{setup_name(res['preset'])}`"
        out += [f"### {title} [{unit}], {where}{tf_note}", "", table(headers, rows), ""]
    return "\n".join(out)


def run(preset="default", tf: float = 1.0, out: str | None = None, json_path: str | None = None,
        steps: int = 20000, make_figures: bool = True) -> dict:
    """Compute, print the tables, write JSON and figures."""
    res = compute(preset, tf, steps)
    print(tables_markdown(res))
    if json_path:
        write_json(json_path, res)
    if out and make_figures:
        res["figures"] = figures(preset, Path(out))
        for name, p in res["figures"].items():
            print(f"figure {name}: {p}")
    return res
