"""Paper Section 4: Tables 7-11 and Fig. 12 (inverse elastodynamic simulation, perfect controller).

Case 1: 6 kg, tf = 0.43 s (Tables 7, 8, Fig. 12); case 2: 0.1 kg, tf = 0.3 s (Tables 9, 10); extended
blends (Table 11). Each case: motion over [0, tf] then a 0.1 s dwell at the place pose.
"""
from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from jaxflex import spectral
from jaxflex.metrics import METRICS, UNITS
from jaxflex.frequencies import modes_at_point
from jaxflex.profiles import PROFILES
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import PAPER_CASES, SweepConfig, accuracy_record, run_sweep

from . import paper_data
from .io import fmt, pct, rel_diff, table

EXTENDED = {"lame_extended": ("lame", 0.0445), "clothoid_extended": ("clothoid", 0.044),
            "lame_e125": ("lame", 0.125)}
NAMES = {"max_torque_nm": "Torque [N m]", "rms_acc_error": "RMS acceleration error [m/s^2]",
         "max_deflection_mm": "Max deflection [mm]", "residual_pos_mm": "Position [mm]",
         "residual_vel": "Velocity [m/s]", "residual_acc": "Acceleration [m/s^2]",
         "residual_acc_low": "Acceleration of the modes below 1 kHz [m/s^2] (ours only)",
         "dwell_residual_mm": "Dwell residual amplitude [mm]", "residual_energy": "Residual energy [J]"}


def _by_blend(res, metric, case, values=None):
    values = res.metrics if values is None else values
    return {b: {p: float(values[metric][i, j, case]) for j, p in enumerate(res.profiles)}
            for i, b in enumerate(res.blends)}


def place_modes(robot, cycle, payload):
    """Locked-motor natural frequencies [Hz] at the place pose (what the residual vibration should
    ring at)."""
    return np.asarray(modes_at_point(robot.replace(payload=payload), jnp.asarray(cycle.place)))


def dwell_spectrum(series, top: int = 3):
    """Dominant frequencies [Hz] of e - e_static over the dwell."""
    amp = np.asarray(series.e_dwell - series.e_static[None])
    fs = 1.0 / float(series.dt_dwell)
    f, p = spectral.welch(jnp.asarray(amp.T), fs, nperseg=amp.shape[0])
    return np.asarray(spectral.dominant_frequencies(f, np.asarray(p).sum(axis=0), top, fmin=5.0))


def compute(quick: bool = False) -> dict:
    """The paper's vibration study (Tables 7-11, Fig. 12 data, dwell spectra) for both paper cases, on
    the default (converged) grid; ``quick`` skips the timed rerun of the sweep (the timing row then
    holds the first sweep, compilation included, and run_s is None); the results are the same."""
    started = time.time()
    robot, cycle = robot_preset("default"), cycle_preset()
    print("  12 combinations x 2 cases ...", flush=True)
    res = run_sweep(robot, cycle, PAPER_CASES, SweepConfig(with_series=True, timed=not quick, progress=True))
    out = {"cases": [c._asdict() for c in res.cases], "grid": res.grid._asdict(),
           "timing": {"compile_s": res.compile_s, "run_s": None if quick else res.run_s}}
    for k, case in enumerate(res.cases):
        out[f"case{k}"] = {m: _by_blend(res, m, k) for m in METRICS}
    out["accuracy"] = accuracy_record(res.accuracy)           # each run's error estimate (docs/conventions.md#accuracy)
    if res.accuracy is not None:
        for k, case in enumerate(res.cases):
            out[f"case{k}_error_estimate"] = {m: _by_blend(res, m, k, res.accuracy.errors) for m in METRICS}
    ext = {}
    for label, (blend, e) in EXTENDED.items():
        print(f"  extended blend {label} (d = 25 mm, e = {e * 1e3:g} mm) ...", flush=True)
        r = run_sweep(robot, cycle, PAPER_CASES, SweepConfig(d=0.025, e=e, blends=(blend,), timed=False))
        ext[label] = {str(k): {m: {p: float(r.metrics[m][0, j, k]) for j, p in enumerate(r.profiles)}
                          for m in METRICS} for k in range(len(PAPER_CASES))}
    out["extended"] = ext
    # Fig. 12 series (6 kg case) and dwell spectra
    s = res.series
    out["fig12"] = {"t": np.asarray(s.t[0, 0, 0]), "t_dwell": np.asarray(s.t_dwell[0, 0, 0]),
                    "e_norm_mm": {f"{b}/{p}": np.linalg.norm(np.asarray(s.e[i, j, 0]), axis=-1) * 1e3
                                  for i, b in enumerate(res.blends) for j, p in enumerate(res.profiles)},
                    "e_dwell_mm": {f"{b}/{p}": np.linalg.norm(np.asarray(s.e_dwell[i, j, 0])
                                                         - np.asarray(s.e_static[i, j, 0]), axis=-1) * 1e3
                                   for i, b in enumerate(res.blends) for j, p in enumerate(res.profiles)}}
    spectra = {}
    import jax

    for k, case in enumerate(res.cases):
        modes = place_modes(robot, cycle, case.payload)
        for i, b in enumerate(res.blends):
            for j, p in enumerate(res.profiles):
                one = jax.tree_util.tree_map(lambda a: a[i, j, k], s)
                peaks = dwell_spectrum(one)
                spectra[f"{case.payload:g}kg/{b}/{p}"] = {"peaks_hz": peaks, "locked_modes_hz": modes[:4]}
    out["dwell_spectra"] = spectra
    from jaxflex.combinations import sample_combinations
    from jaxflex.trajectory import time_grid

    tf0 = res.cases[0].tf
    tr, _ = sample_combinations(robot, cycle, tf0, time_grid(tf0, 4000), d=0.025, blends=("lame",),
                                profiles=("poly7",))           # jitted: one small program, not op by op
    out["task_acc_max_6kg_lame_poly7"] = float(np.max(np.linalg.norm(np.asarray(tr.xdd[0]), axis=-1)))
    out["wall_s"] = time.time() - started
    return out


def compare(ours: dict, paper: dict, metric: str, blends=("lame", "clothoid", "polar")) -> str:
    """Ours beside the paper's for one metric (rows: profiles; columns: blend ours/paper/diff %) as Markdown."""
    head = ["profile"] + [f"{b} {w}" for b in blends for w in ("ours", "paper", "diff")]
    rows = []
    for p in PROFILES:
        row = [p]
        for b in blends:
            o, r = ours[b][p], paper[b][p]
            row += [fmt(o, 4), fmt(r, 4), pct(rel_diff(o, r))]
        rows.append(row)
    return f"**{NAMES[metric]}**\n\n" + table(head, rows)


def ours_only(ours: dict, metric: str, blends=("lame", "clothoid", "polar")) -> str:
    """A metric the paper does not report: blends as columns, profiles as rows."""
    rows = [[p] + [fmt(ours[b][p], 4) for b in blends] for p in PROFILES]
    return f"**{NAMES[metric]}**\n\n" + table(["profile", *blends], rows)


def table11(ext: dict, case0: dict, case_index: int) -> str:
    """Table 11 (short vs extended blends, residuals at tf) ours beside the paper's, as Markdown."""
    cols = paper_data.TABLE11_COLUMNS
    out = []
    for m in ("residual_pos_mm", "residual_vel", "residual_acc"):
        head = ["profile"] + [f"{c} {w}" for c in cols for w in ("ours", "paper")] + ["lame_e125 ours"]
        rows = []
        for i, p in enumerate(PROFILES):
            row = [p]
            for k, c in enumerate(cols):
                o = case0[m][c][p] if c in ("lame", "clothoid") else ext[c][str(case_index)][m][p]
                row += [fmt(o, 4), fmt(paper_data.TABLE11[m][p][k], 4)]
            row.append(fmt(ext["lame_e125"][str(case_index)][m][p], 4))
            rows.append(row)
        out.append(f"**{NAMES[m]}**\n\n" + table(head, rows))
    return "\n\n".join(out)


def duplicated_cells() -> list[str]:
    """Values that occur in more than one cell of the paper's Tables 8 and 10 (copied rows)."""
    seen = {}
    for tname, tab in (("8", paper_data.TABLE8), ("10", paper_data.TABLE10)):
        for m, by_blend in tab.items():
            for b, by_prof in by_blend.items():
                for p, v in by_prof.items():
                    seen.setdefault(v, []).append(f"T{tname} {NAMES[m].split(' [')[0].lower()} {b}/{p}")
    return [f"{v:g}: " + ", ".join(c) for v, c in sorted(seen.items()) if len(c) > 1]


def unit(metric):
    """The unit of a metric (docs/conventions.md#metrics; ``jaxflex.metrics.UNITS``)."""
    return UNITS[metric]
