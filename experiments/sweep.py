"""``jaxflex sweep``: the 12 path-profile combinations simulated for one payload and motion time."""
from __future__ import annotations

import time

from jaxflex.metrics import METRICS, UNITS
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import Case, SweepConfig, results_table, run_sweep

from .io import fmt, provenance, table, write_json

SHORT = {"max_torque_nm": "torque", "rms_acc_error": "rms e''", "max_deflection_mm": "max |e|",
         "residual_pos_mm": "|e(tf)|", "residual_vel": "|e'(tf)|", "residual_acc": "|e''(tf)|",
         "residual_acc_low": "|e''(tf)| < 1 kHz", "dwell_residual_mm": "dwell", "residual_energy": "energy"}


def compute(preset: str = "default", payload: float = 6.0, tf: float = 0.43, dt: float | None = None,
            dwell: float = 0.1, repeats: int = 3) -> dict:
    """Simulate every combination; returns the sweep record (docs/conventions.md#file-formats)."""
    started = time.time()
    robot, cycle = robot_preset(preset), cycle_preset(preset)
    res = run_sweep(robot, cycle, [Case(payload, tf)],
                    SweepConfig(dwell=dwell, dt=dt, repeats=repeats, progress=True))
    grid = res.grid
    return {"payload": payload, "tf": tf, "dt": tf / grid.steps, "dwell": dwell, "preset": preset,
            "results": results_table(res, 0),
            "timing": {"compile_s": res.compile_s, "run_s": res.run_s},
            "grid": grid._asdict(), "provenance": provenance(
                {"preset": preset, "payload": payload, "tf": tf, "dt": dt, "dwell": dwell}, started)}


def text(rec: dict) -> str:
    """The sweep record as a table (every metric of docs/conventions.md#metrics per blend and profile,
    with units) plus timing."""
    head = ["blend", "profile"] + [f"{SHORT.get(m, m)} [{UNITS[m]}]" for m in METRICS]
    rows = [[r["blend"], r["profile"]] + [fmt(r[m], 4) for m in METRICS] for r in rec["results"]]
    t = rec["timing"]
    return (f"Sweep: payload {rec['payload']:g} kg, tf {rec['tf']:g} s, dt {rec['dt']:.3g} s, dwell "
            f"{rec['dwell']:g} s ({rec['preset']} preset)\n\n" + table(head, rows)
            + f"\n\ncompile {t['compile_s']:.1f} s, run {t['run_s'] * 1e3:.0f} ms (median)")


def run(preset="default", payload=6.0, tf=0.43, dt=None, dwell=0.1, json_path=None) -> dict:
    """``jaxflex sweep``: the 12 combinations for ``payload`` [kg], ``tf`` [s], optional ``dt`` [s] and
    ``dwell`` [s]; prints the table and writes the JSON."""
    rec = compute(preset, payload, tf, dt, dwell)
    if json_path:                  # the record first: a display problem must not lose the results
        write_json(json_path, rec)
    print(text(rec))
    return rec
