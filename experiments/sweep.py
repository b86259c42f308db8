"""``jaxflex sweep``: the 12 path-profile combinations simulated for one payload and motion time."""
from __future__ import annotations

import math
import sys
import time
import warnings

from jaxflex import checks
from jaxflex.metrics import METRICS, UNITS
from jaxflex.servo import cycle_servo, record
from jaxflex.sweep import Case, StepWarning, SweepConfig, accuracy_record, results_table, run_sweep

from .io import fmt, provenance, robot_and_cycle, setup_name, setup_record, table, write_json

SHORT = {"max_torque_nm": "torque", "rms_acc_error": "rms e''", "max_deflection_mm": "max |e|",
         "residual_pos_mm": "|e(tf)|", "residual_vel": "|e'(tf)|", "residual_acc": "|e''(tf)|",
         "residual_acc_low": "|e''(tf)| < 1 kHz", "dwell_residual_mm": "dwell", "residual_energy": "energy"}


def compute(preset: str = "default", payload: float = 6.0, tf: float = 0.43, dt: float | None = None,
            dwell: float = 0.1, repeats: int = 3, servo: dict | None = None) -> dict:
    """Simulate every combination; returns the sweep record (docs/conventions.md#file-formats).
    ``servo``: the motors driven by a servo loop, keyword arguments of ``jaxflex.servo.cycle_servo``
    (fc [Hz], rate [Hz], rotor_inertia [kg m^2], feedforward) for the payload's robot; None: the
    perfect controller. ``repeats``: sweeps timed after the first (0: none; the record's run time is then null)."""
    started = time.time()
    repeats = checks.count("repeats", repeats, minimum=0)
    robot, cycle = robot_and_cycle(preset)
    controller = None
    if servo is not None:
        options = dict(servo)
        controller = cycle_servo(robot.replace(payload=payload), cycle, options.pop("fc"), **options)
    said = []

    def say(message, category, *_args, **_kwargs):     # at once, before the long run, and in the record
        said.append(str(message))
        print(f"jaxflex sweep: warning: {message}", file=sys.stderr, flush=True)

    with warnings.catch_warnings():
        warnings.simplefilter("always", StepWarning)
        warnings.showwarning = say
        res = run_sweep(robot, cycle, [Case(payload, tf)],
                        SweepConfig(dwell=dwell, dt=dt, repeats=max(repeats, 1), timed=repeats > 0,
                                    progress=True, servo=controller))
    grid = res.grid
    return {"payload": payload, "tf": tf, "dt": tf / grid.steps, "dwell": dwell, "preset": setup_record(preset),
            "servo": None if controller is None else record(controller),
            "results": results_table(res, 0),
            "timing": {"compile_s": res.compile_s,
                       "run_s": res.run_s if math.isfinite(res.run_s) else None},   # None: not timed
            "grid": grid._asdict(), "accuracy": accuracy_record(res.accuracy), "warnings": said, "provenance": provenance(
                {"preset": setup_record(preset), "payload": payload, "tf": tf, "dt": dt, "dwell": dwell, "servo": servo,
                 "repeats": repeats}, started)}


def text(rec: dict) -> str:
    """The sweep record as a table (every metric of docs/conventions.md#metrics per blend and profile,
    with units) plus timing."""
    head = ["blend", "profile"] + [f"{SHORT.get(m, m)} [{UNITS[m]}]" for m in METRICS]
    est = lambda r, m: f" ± {fmt(r['error_estimate'][m], 2)}" if m == "dwell_residual_mm" and "error_estimate" in r else ""
    rows = [[r["blend"], r["profile"]] + [fmt(r[m], 4) + est(r, m) for m in METRICS] for r in rec["results"]]
    t = rec["timing"]
    sv = rec.get("servo")
    control = "perfect controller (motor angles prescribed)" if sv is None else (
        f"servo fc {sv['fc']:g} Hz at {sv['rate']:g} Hz, rotor {sv['rotor_inertia']:g} kg m^2, "
        f"{sv['feedforward']} feedforward, Kp {sv['kp'][0]:.4g} N m/rad, Kd {sv['kd'][0]:.4g} N m s/rad")
    acc = rec.get("accuracy")
    accuracy = "" if acc is None else (
        "\n\nDwell residual ± its estimated discretization error (" + (
            f"step doubling against a grid {acc['ratio']:.2g}x coarser" if acc["ratio"] > 1 else
            "against the same runs with every step halved") + ", docs/conventions.md#accuracy); "
        f"tolerance {100 * acc['rtol']:g} % of it or {1e6 * acc['atol_mm']:g} nm: "
        + ("met" if acc["met"] else "MISSED") + " (largest estimate "
        f"{acc['max_estimate_over_tolerance']:.2g} x its tolerance" + (
            f"; the grid refined {acc['refinements']} time(s) to meet it" if acc["refinements"] else "") + ")")
    return (f"Sweep: payload {rec['payload']:g} kg, tf {rec['tf']:g} s, dt {rec['dt']:.3g} s, dwell "
            f"{rec['dwell']:g} s ({setup_name(rec['preset'])}), {control}\n\n" + table(head, rows) + accuracy
            + (f"\n\ncompile {t['compile_s']:.1f} s, run {t['run_s'] * 1e3:.0f} ms (median)"
               if t["run_s"] is not None else f"\n\ncompile and first run {t['compile_s']:.1f} s (not timed)"))


def run(preset="default", payload=6.0, tf=0.43, dt=None, dwell=0.1, json_path=None, servo=None,
        repeats: int = 3) -> dict:
    """``jaxflex sweep``: the 12 combinations for ``payload`` [kg], ``tf`` [s], optional ``dt`` [s] and
    ``dwell`` [s], under the perfect controller or the ``servo`` (see ``compute``); prints the table
    and writes the JSON; ``repeats`` timed sweeps after the first."""
    rec = compute(preset, payload, tf, dt, dwell, repeats, servo=servo)
    if json_path:                  # the record first: a display problem must not lose the results
        write_json(json_path, rec)
    print(text(rec))
    return rec
