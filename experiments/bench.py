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

from jaxflex.linearized import build_tables
from jaxflex.optimize.loop import value_and_grad_fwd
from jaxflex.path import make_path
from jaxflex.profiles import shaped
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.simulate import motion_samples, rollout
from jaxflex.sweep import PAPER_CASES, default_grid, run_sweep

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


def gradient_bench(repeats: int = 5, payload: float = 6.0, tf: float = 0.43, dwell: float = 0.1) -> dict:
    """Forward and gradient of the residual objective (vibration energy at tf plus the squared dwell
    amplitude) w.r.t. the 6 coefficients of a shaped motion law, 6 kg Lamé path, tables fixed,
    second-order fast model (as the optimizer uses it); gradient by reverse mode (as the optimizer)
    and, for comparison, by forward mode."""
    robot, cycle = robot_preset("default", payload=payload), cycle_preset()
    path = make_path(cycle, "lame", 0.025)
    grid = default_grid(robot, [tf], dwell)
    tables = jax.jit(build_tables)(robot, path)

    def objective(coef):
        series = rollout(tables, motion_samples(path.length, shaped(coef), tf, grid), tf, dwell, grid, robot)
        amp = series.e_dwell - series.e_static[None]
        return series.energy_tf + jnp.mean(jnp.sum(amp**2, axis=-1)) * 1e3

    coef = jnp.asarray([1.0, 1.2, 0.9, 1.0, 1.1, 0.95])
    fwd = jax.jit(objective)
    grad = jax.jit(jax.value_and_grad(objective))
    grad_fwd_mode = jax.jit(value_and_grad_fwd(lambda c: (objective(c), None)))
    t0 = time.perf_counter()
    jax.block_until_ready(fwd(coef))
    c_fwd = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(grad(coef))
    c_grad = time.perf_counter() - t0
    r_fwd = _median_time(fwd, coef, repeats=repeats)
    r_grad = _median_time(grad, coef, repeats=repeats)
    r_grad_fwd = _median_time(grad_fwd_mode, coef, repeats=repeats)
    return {"parameters": int(coef.shape[0]), "forward_compile_s": c_fwd, "forward_run_s": r_fwd,
            "grad_compile_s": c_grad, "grad_run_s": r_grad, "grad_over_forward": r_grad / r_fwd,
            "forward_mode_grad_run_s": r_grad_fwd, "steps": grid.steps + grid.dwell_steps}


def compute(repeats: int = 5) -> dict:
    started = time.time()
    robot, cycle = robot_preset("default"), cycle_preset()
    print("sweep: 12 combinations x 2 cases (6 kg/0.43 s, 0.1 kg/0.3 s), motion + 0.1 s dwell ...",
          flush=True)
    res = run_sweep(robot, cycle, PAPER_CASES, repeats=repeats)
    g = res.grid
    steps = 24 * (g.steps + g.dwell_steps)
    sweep = {"rollouts": 24, "tables_s": res.tables_s, "compile_s": res.compile_s, "run_s": res.run_s,
             "per_rollout_ms": 1e3 * res.run_s / 24, "steps_per_rollout": g.steps + g.dwell_steps,
             "steps_per_s": steps / res.run_s, "grid": g._asdict()}
    print(f"  tables (3 blends x 2 payloads, compile included) {res.tables_s:.1f} s")
    print(f"  rollout program: compile {res.compile_s:.1f} s, run {res.run_s * 1e3:.0f} ms "
          f"({sweep['per_rollout_ms']:.1f} ms per rollout, {sweep['steps_per_s']:.3g} steps/s)", flush=True)
    print("gradient of the residual objective (6 motion-law coefficients, 6 kg, reverse mode) ...", flush=True)
    grad = gradient_bench(repeats)
    print(f"  forward {grad['forward_run_s'] * 1e3:.1f} ms, gradient {grad['grad_run_s'] * 1e3:.1f} ms "
          f"(x{grad['grad_over_forward']:.2f}; forward mode {grad['forward_mode_grad_run_s'] * 1e3:.1f} ms); "
          f"compile {grad['grad_compile_s']:.1f} s", flush=True)
    rec = {"sweep": sweep, "gradient": grad, "peak_rss_mb": _peak_rss_mb(),
           "devices": [str(d) for d in jax.devices()], "provenance": provenance({"repeats": repeats}, started)}
    print(f"peak memory {rec['peak_rss_mb']:.0f} MB")
    return rec


def run(repeats: int = 5, json_path=None) -> dict:
    rec = compute(repeats)
    if json_path:
        write_json(json_path, rec)
    return rec
