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
from jaxflex.linearized import path_tables
from jaxflex.optimize.loop import value_and_grad_fwd
from jaxflex.path import make_path
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import PAPER_CASES, default_grid, run_sweep
from jaxflex.workspace import build_workspace

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


def _time_gradient(objective, x, repeats: int) -> dict:
    """Compile and median run times of a scalar objective (value, aux) and of its reverse-mode
    value and gradient (as the optimizer computes it) and forward-mode gradient."""
    fwd = jax.jit(lambda p: objective(p)[0])
    grad = jax.jit(jax.value_and_grad(objective, has_aux=True))
    grad_fwd_mode = jax.jit(value_and_grad_fwd(objective))
    t0 = time.perf_counter()
    jax.block_until_ready(fwd(x))
    c_fwd = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(grad(x))
    c_grad = time.perf_counter() - t0
    r_fwd = _median_time(fwd, x, repeats=repeats)
    r_grad = _median_time(grad, x, repeats=repeats)
    r_grad_fwd = _median_time(grad_fwd_mode, x, repeats=repeats)
    n = int(sum(np.size(v) for v in jax.tree_util.tree_leaves(x)))
    return {"parameters": n, "forward_compile_s": c_fwd, "forward_run_s": r_fwd, "grad_compile_s": c_grad,
            "grad_run_s": r_grad, "grad_over_forward": r_grad / r_fwd, "forward_mode_grad_run_s": r_grad_fwd}


def gradient_bench(repeats: int = 5, payload: float = 6.0, tf: float = 0.43, dwell: float = 0.1) -> dict:
    """Forward and gradient of the optimizer's residual objective (``jaxflex.optimize.objective``:
    vibration energy at tf and mean-square dwell amplitude, log scale, torque penalty), second-order
    fast model, one 6 kg model, tf = 0.43 s:

    - ``law``: w.r.t. the 6 coefficients of a shaped motion law on the Lamé path (tables fixed);
    - ``design``: w.r.t. the 6 blend parameters (d, e, n of both corners) and the 6 law coefficients,
      the linearization tables rebuilt from the path inside the differentiated function by
      interpolation of the workspace tables (what ``jaxflex optimize`` differentiates; the
      workspace build, once per model, is timed apart, compilation included).
    """
    from jaxflex.designs import design
    from jaxflex.optimize.objective import Scales, encode, law_objective, objective, stack_robots

    robot, cycle = robot_preset("default", payload=payload), cycle_preset()
    path = make_path(cycle, "lame", 0.025)
    grid = default_grid(robot, [tf], dwell)
    robots = stack_robots([robot])
    tables = path_tables(robots, path)
    scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), jnp.full(1, 90.0))
    coef = jnp.asarray([1.0, 1.2, 0.9, 1.0, 1.1, 0.95])
    law = _time_gradient(lambda c: law_objective(c, tables, path.length, tf, dwell, grid, scales, robots=robots),
                         coef, repeats)
    params = encode(cycle, design(0.0245, 0.03, 3.2, coef, e2=0.035, n2=3.4))
    t0 = time.perf_counter()
    ws = jax.block_until_ready(build_workspace(robots, cycle))
    ws_s = time.perf_counter() - t0
    full = _time_gradient(lambda p: objective(p, robots, cycle, tf, dwell, grid, scales, workspaces=ws), params,
                          repeats)
    full["workspace_build_s"] = ws_s
    return {"law": law, "design": full, "steps": grid.steps + grid.dwell_steps}


def compute(repeats: int = 5) -> dict:
    """Time the 24-rollout sweep and the law/design gradients (median of ``repeats``); the JSON record."""
    started = time.time()
    repeats = checks.count("repeats", repeats)
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
    print("gradient of the residual objective (6 kg, tf 0.43 s, one model, reverse mode as the optimizer) ...",
          flush=True)
    grad = gradient_bench(repeats)
    for key, what in (("law", "6 law coefficients, tables fixed"),
                      ("design", "6 blend parameters + 6 law coefficients, tables rebuilt from the workspace")):
        g = grad[key]
        print(f"  {what}: forward {g['forward_run_s'] * 1e3:.1f} ms, gradient {g['grad_run_s'] * 1e3:.1f} ms "
              f"(x{g['grad_over_forward']:.2f}; forward mode {g['forward_mode_grad_run_s'] * 1e3:.1f} ms); "
              f"compile {g['forward_compile_s']:.0f} s forward, {g['grad_compile_s']:.0f} s gradient", flush=True)
    rec = {"sweep": sweep, "gradient": grad, "peak_rss_mb": _peak_rss_mb(),
           "devices": [str(d) for d in jax.devices()], "provenance": provenance({"repeats": repeats}, started)}
    print(f"peak memory {rec['peak_rss_mb']:.0f} MB")
    return rec


def run(repeats: int = 5, json_path=None) -> dict:
    """``jaxflex bench``: ``compute`` and, with ``json_path``, write its record there."""
    rec = compute(repeats)
    if json_path:
        write_json(json_path, rec)
    return rec
