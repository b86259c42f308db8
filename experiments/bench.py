"""``jaxflex bench``: compile and run times of the batched sweep and of one gradient.

Timing is wall clock on this machine (``jax.block_until_ready``); run times are medians of repeats
after compilation; peak memory is the process's maximum resident set size.
"""
from __future__ import annotations

import resource
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.path import make_path
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import PAPER_CASES, SweepConfig, default_grid, run_sweep
from jaxflex.tables import build_workspaces

from .io import provenance, write_json


def _median_time(f, *args, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _peak_rss_mb() -> float:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def _time_first_and_median(f, *args, repeats: int):
    """(first call [s] (compilation included), median of ``repeats`` further calls [s], last result)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(f(*args))
    first = time.perf_counter() - t0
    return first, _median_time(f, *args, repeats=repeats), out


def _scales(k: int, weights):
    """Fixed reference values for k models (energy 1e-3 J, dwell 1e-10 m^2, torque bound 90 N m): the
    bench times the objective, it does not compare designs."""
    from jaxflex.optimize.objective import Scales

    return Scales(jnp.full(k, 1e-3), jnp.full(k, 1e-10), jnp.full(k, 90.0), weights)


def gradient_bench(repeats: int = 5, payload: float = 6.0, tf: float = 0.43, dwell: float = 0.1,
                   quick: bool = False) -> dict:
    """The optimizer's own programs on one 6 kg model, tf = 0.43 s (what ``jaxflex optimize --train
    nominal`` runs at every step; second-order fast model, reverse mode):

    - ``design``: value and gradient of the design objective w.r.t. the 6 blend parameters (d, e, n
      of both corners) and the 6 law coefficients, the linearization tables rebuilt inside the
      differentiated function from the workspace tables (their build, once per model, is timed
      apart, compilation included), the objective alone (forward) for the ratio, and the time of
      each of the gradient's programs run alone (``stages_s``, ``optimize.staged.Staged.stage_times``);
    - ``law`` (not with ``quick``): the same for the 6 coefficients of a shaped law on the Lamé path
      (tables fixed);
    - ``design_box`` (not with ``quick``): the design gradient of the studies, over the 9 models of
      the perturbation box (``--train box``), with its XLA temporary memory: the largest buffer set
      of a study.
    Compile times are those of the programs alone (the strategy's ``compile_ahead``)."""
    from jaxflex.designs import design
    from jaxflex.engine import LawEvaluator
    from jaxflex.optimize.gradient import OneProgram
    from jaxflex.optimize.objective import encode
    from jaxflex.optimize.staged import Staged
    from jaxflex.optimize.config import StudyConfig
    from jaxflex.optimize.training import (Training, design_objective, law_objective, training_models,
                                           training_weights)
    from jaxflex.problem import Timing

    robot, cycle = robot_preset("default"), cycle_preset()
    grid = default_grid(robot, [tf], dwell)
    models = training_models(robot, [payload], "nominal")
    # the study's defaults, weights and pytrees: the optimizer's own compiled program (one process
    # that ran ``jaxflex optimize --train nominal`` on this grid reuses it)
    c = StudyConfig()
    scales = _scales(1, jnp.asarray(training_weights("nominal", 1)))
    coef = jnp.asarray([1.0, 1.2, 0.9, 1.0, 1.1, 0.95])
    t0 = time.perf_counter()
    ws = jax.block_until_ready(build_workspaces(models.robots, cycle))
    ws_s = time.perf_counter() - t0
    timing = Timing(tf, dwell, grid)
    f = design_objective(Training(models, cycle, timing, scales, ws), c.train.with_optimizer(label="bench"))
    params = encode(cycle, design(0.0245, 0.03, 3.2, coef, e2=0.035, n2=3.4))
    build = "quick" if quick else "fast"
    staged = Staged(build=build)
    out = {"design": _time_value_and_grad(f, params, staged, repeats, not quick),
           "steps": grid.steps + grid.dwell_steps}
    out["design"]["workspace_build_s"] = ws_s
    out["design"]["stages_s"] = staged.stage_times(f, params, repeats=repeats)
    if not quick:
        path = make_path(cycle, "lame", 0.025)
        f_law = law_objective(LawEvaluator(models, path, tf, dwell, grid), scales,
                              c.train.with_optimizer(label="bench"))
        out["law"] = _time_value_and_grad(f_law, coef, OneProgram(build="fast"), repeats, True)
        box = training_models(robot, [payload], "box")
        k = len(box.ids)
        f_box = design_objective(Training(box, cycle, timing, _scales(k, None), build_workspaces(box.robots, cycle)),
                                 c.train.with_optimizer(label="bench"))
        out["design_box"] = _time_value_and_grad(f_box, params, Staged(build="fast"), repeats, False)
        out["design_box"]["models"] = k
    return out


def _time_value_and_grad(f, params, gradient, repeats: int, forward: bool) -> dict:
    """Compile and run times of the optimizer's value and gradient as the strategy ``gradient``
    computes it (its build "fast": what a long optimization runs; "quick": a smoke run's)."""
    t0 = time.perf_counter()
    program = gradient.compile_ahead(f, params).result()
    compile_s = time.perf_counter() - t0
    run = _median_time(lambda p: gradient.value_and_grad(f, p), params, repeats=repeats)
    # the staged design gradient is several programs (``optimize.staged``): the largest one's memory
    mems = [p.memory_analysis() for p in (program if isinstance(program, list) else [program])]
    temps = [m.temp_size_in_bytes for m in mems if m is not None]
    rec = {"parameters": int(sum(np.size(v) for v in jax.tree_util.tree_leaves(params))),
           "grad_compile_s": compile_s, "grad_run_s": run,
           "grad_temp_gib": max(temps) / 2**30 if temps else None}
    if forward:
        fwd = jax.jit(lambda p: f(p)[0])
        first, run_f, _ = _time_first_and_median(fwd, params, repeats=repeats)
        rec.update(forward_compile_s=max(first - run_f, 0.0), forward_run_s=run_f, grad_over_forward=run / run_f)
    return rec


def servo_sweep_bench(robot, cycle, fc: float, repeats: int) -> dict:
    """The 24 paper rollouts under a servo of bandwidth ``fc`` [Hz] (8 kHz, 0.01 kg m^2 rotor, rigid
    feedforward, each payload's default gains, ``jaxflex.servo.cycle_servo``): one sweep per paper
    case (a servo's gains belong to its payload), the error estimate off as in the perfect
    controller's timing. Returns the summed times [s] and the per-case grids."""
    from jaxflex.servo import cycle_servo

    out = {"fc": fc, "rollouts": 0, "tables_s": 0.0, "compile_s": 0.0, "run_s": 0.0, "grids": []}
    for case in PAPER_CASES:
        servo = cycle_servo(robot.replace(payload=case.payload), cycle, fc)
        res = run_sweep(robot, cycle, [case], SweepConfig(repeats=repeats, estimate=False, servo=servo))
        out["rollouts"] += 12
        for key in ("tables_s", "compile_s", "run_s"):
            out[key] += getattr(res, key)
        out["grids"].append(res.grid._asdict())
    out["per_rollout_ms"] = 1e3 * out["run_s"] / out["rollouts"]
    return out


def compute(repeats: int = 5, quick: bool = False, servo: float | None = None) -> dict:
    """Time the 24-rollout sweep and the optimizer's gradients (median of ``repeats``); the JSON
    record. ``quick``: the design gradient only, without the forward-only and law timings.
    ``servo`` [Hz]: also the 24 rollouts under a servo of that bandwidth (``servo_sweep_bench``)."""
    started = time.time()
    repeats = checks.count("repeats", repeats)
    robot, cycle = robot_preset("default"), cycle_preset()
    print("sweep: 12 combinations x 2 cases (6 kg/0.43 s, 0.1 kg/0.3 s), motion + 0.1 s dwell ...",
          flush=True)
    res = run_sweep(robot, cycle, PAPER_CASES, SweepConfig(repeats=repeats, estimate=False))
    g = res.grid
    steps = 24 * (g.steps + g.dwell_steps)
    sweep = {"rollouts": 24, "tables_s": res.tables_s, "compile_s": res.compile_s, "run_s": res.run_s,
             "per_rollout_ms": 1e3 * res.run_s / 24, "steps_per_rollout": g.steps + g.dwell_steps,
             "steps_per_s": steps / res.run_s, "grid": g._asdict()}
    print(f"  tables (3 blends x 2 payloads, compile included, the rollout's compiling beside) {res.tables_s:.1f} s")
    print(f"  rollout programs: compile (what remains after the tables) {res.compile_s:.1f} s, "
          f"run {res.run_s * 1e3:.0f} ms "
          f"({sweep['per_rollout_ms']:.1f} ms per rollout, {sweep['steps_per_s']:.3g} steps/s)", flush=True)
    servo_rec = None
    if servo is not None:
        print(f"the same 24 rollouts under a servo, fc {servo:g} Hz at 8 kHz (one sweep per case) ...", flush=True)
        servo_rec = servo_sweep_bench(robot, cycle, servo, repeats)
        print(f"  tables {servo_rec['tables_s']:.1f} s; rollout programs: compile {servo_rec['compile_s']:.1f} s, "
              f"run {servo_rec['run_s'] * 1e3:.0f} ms ({servo_rec['per_rollout_ms']:.1f} ms per rollout)", flush=True)
    print("the optimizer's value and gradient (6 kg, tf 0.43 s, one model, reverse mode) ...", flush=True)
    grad = gradient_bench(repeats, quick=quick)
    for key, what in (("design", "6 blend parameters + 6 law coefficients, tables rebuilt from the workspace"),
                      ("law", "6 law coefficients, tables fixed"),
                      ("design_box", "the design gradient over the 9 box models")):
        if key not in grad:
            continue
        g = grad[key]
        fwd = (f"forward {g['forward_run_s'] * 1e3:.1f} ms (compile {g['forward_compile_s']:.0f} s), "
               f"gradient x{g['grad_over_forward']:.2f}; " if "forward_run_s" in g else "")
        temp = f", XLA temp {g['grad_temp_gib']:.2f} GiB" if g["grad_temp_gib"] is not None else ""
        print(f"  {what}: value and gradient {g['grad_run_s'] * 1e3:.1f} ms (compile {g['grad_compile_s']:.0f} s"
              f"{temp}); " + fwd, flush=True)
        if "stages_s" in g:
            print("    its programs on one model, one at a time: " + ", ".join(
                f"{name} {t * 1e3:.1f} ms" for name, t in g["stages_s"].items()), flush=True)
    rec = {"sweep": sweep, "servo_sweep": servo_rec, "gradient": grad, "peak_rss_mb": _peak_rss_mb(), "quick": quick,
           "devices": [str(d) for d in jax.devices()],
           "provenance": provenance({"repeats": repeats, "quick": quick, "servo": servo}, started)}
    print(f"peak memory {rec['peak_rss_mb']:.0f} MB")
    return rec


def run(repeats: int = 5, json_path=None, quick: bool = False, servo: float | None = None) -> dict:
    """``jaxflex bench``: ``compute`` and, with ``json_path``, write its record there."""
    rec = compute(repeats, quick, servo)
    if json_path:
        write_json(json_path, rec)
    return rec
