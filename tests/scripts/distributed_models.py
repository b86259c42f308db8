"""Run by tests/test_distributed.py: one process of a model sweep (``jaxflex.model_sweep``), alone or
as one of several joined by ``jax.distributed``. Arguments: process id, process count, coordinator
port, output JSON path. Writes the metrics this process holds and how the sweep was laid out."""
import json
import sys

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from jaxflex.runtime import distributed  # noqa: E402

pid, count, port, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
if count > 1:
    distributed.initialize(f"localhost:{port}", count, pid)

from jaxflex.designs import design  # noqa: E402
from jaxflex.model_sweep import ModelSweepConfig, sweep_models  # noqa: E402
from jaxflex.problem import Timing  # noqa: E402
from jaxflex.robot import cycle_preset, robot_preset  # noqa: E402
from jaxflex.simulate import Grid  # noqa: E402
from jaxflex.uncertainty import Box  # noqa: E402

robot = robot_preset("default", n_bending=1, n_axial=1)          # small model: a quick compile
cycle = cycle_preset()
models = Box().random([6.0], n=5, seed=3)                         # 5: not a multiple of the chunk (padding)
x = design(0.025, coef=[1.1, 0.9, 1.0, 1.05])
config = ModelSweepConfig(Timing(tf=0.43, dwell=0.02, grid=Grid(coarse=16, fine=4, dwell_steps=40, squarings=10)),
                          per_device=2, second_order=False)
res = sweep_models(robot, cycle, x, models, config)
json.dump({"process": jax.process_index(), "processes": res.processes, "devices": res.devices, "chunk": res.chunk,
           "metrics": {k: np.asarray(v).tolist() for k, v in res.metrics.items()}}, open(out, "w"))
