"""A Monte Carlo robustness evaluation of a design: its metrics on N random models of the uncertainty
box, sharded over every device of every process (``jaxflex.model_sweep``).

One process: ``python -m jaxflex.experiments.monte_carlo --design DIR/optimize.json --models 1000``.
Several (on one machine or a cluster): start the same command in every process with
``--coordinator HOST:PORT --processes P --process-id I`` (or the ``JAXFLEX_*`` variables of
``jaxflex.runtime.distributed``; on a cluster JAX detects them, README "Running on a cluster or a
GPU"). Every process evaluates its share and holds every result; process 0 prints the summary and
writes the JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m jaxflex.experiments.monte_carlo", description=__doc__.split("\n\n")[0])
    p.add_argument("--design", required=True, help="a design: jaxflex optimize's optimize.json (its 'design')")
    p.add_argument("--models", type=int, default=1000, help="random models of the box (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random models (default 0)")
    p.add_argument("--per-device", type=int, default=4, help="models per device per compiled call (default 4)")
    p.add_argument("--coordinator", help="HOST:PORT of process 0 (several processes)")
    p.add_argument("--processes", type=int, help="number of processes")
    p.add_argument("--process-id", type=int, help="this process's index")
    p.add_argument("--json", help="write the record here (process 0)")
    a = p.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from jaxflex.runtime import distributed

    if a.coordinator or a.processes:
        distributed.initialize(a.coordinator, a.processes, a.process_id)
    import numpy as np

    from jaxflex.experiments.io import design_of_record
    from jaxflex.model_sweep import ModelSweepConfig, sweep_models
    from jaxflex.problem import Timing
    from jaxflex.robot import cycle_preset, robot_preset
    from jaxflex.uncertainty import Box

    started = time.time()
    rec = json.load(open(a.design))
    (payload,), tf = rec["payloads"][:1], rec["tf"]
    x, blend, order = design_of_record(rec["design"])
    robot, cycle = robot_preset("default"), cycle_preset()
    models = Box().random([payload], n=a.models, seed=a.seed)
    res = sweep_models(robot, cycle, x, models, ModelSweepConfig(Timing(tf=tf, dwell=0.1), blend=blend, order=order,
                                                                 per_device=a.per_device,
                                                                 progress=True))
    if not distributed.is_leader():
        return 0
    dw = 1e3 * res.metrics["dwell_residual_mm"]
    out = {"design": a.design, "payload": payload, "tf": tf, "models": a.models, "seed": a.seed,
           "processes": res.processes, "devices": res.devices, "chunk": res.chunk, "compile_s": res.compile_s,
           "run_s": res.run_s, "models_per_s_per_process": res.models_per_s,
           "dwell_residual_um": {"max": float(dw.max()), "p95": float(np.percentile(dw, 95)),
                                 "median": float(np.median(dw)), "min": float(dw.min())},
           "max_torque_nm": float(res.metrics["max_torque_nm"].max()), "wall_s": time.time() - started}
    print(f"{a.models} models of the box at {payload:g} kg, tf {tf:g} s, on {res.processes} process(es), "
          f"{res.devices} device(s): compile {res.compile_s:.1f} s, run {res.run_s:.1f} s, "
          f"{res.models_per_s:.2f} models/s per process; dwell residual [um] max {dw.max():.4g}, "
          f"p95 {np.percentile(dw, 95):.4g}, median {np.median(dw):.4g}")
    if a.json:
        json.dump(out, open(a.json, "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
