"""Run by tests/test_sharding.py in a subprocess with two forced host devices (XLA_FLAGS must be set
before JAX starts, hence the separate process). Prints one JSON line."""
import dataclasses
import json

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxflex.design_sweep import DesignSweepConfig, sweep_designs  # noqa: E402
from jaxflex.designs import Design  # noqa: E402
from jaxflex.problem import Timing  # noqa: E402
from jaxflex.robot import cycle_preset, robot_preset  # noqa: E402
from jaxflex.simulate import Grid  # noqa: E402

robot = robot_preset("default", payload=6.0, n_bending=1, n_axial=1)   # small model: quick compile
cycle = cycle_preset()
grid = Grid(coarse=16, fine=4, dwell_steps=40, squarings=10)
rng = np.random.default_rng(0)
size = 5                                                 # not a multiple of the chunk: tests padding
corners = lambda v: jnp.stack([v, v[::-1]], axis=1)    # (size, 2): corner 1, corner 2
xs = Design(d=jnp.full((size, 2), 0.025), e=corners(jnp.linspace(0.02, 0.03, size)), n=jnp.full((size, 2), 3.0),
            coef=jnp.asarray(1.0 + 0.3 * rng.random((size, 4))))
config = DesignSweepConfig(Timing(tf=0.43, dwell=0.02, grid=grid), chunk=2)
two = sweep_designs(robot, cycle, xs, config)
one = sweep_designs(robot, cycle, xs, dataclasses.replace(config, devices=tuple(jax.local_devices()[:1])))
print(json.dumps({"device_count": jax.device_count(), "devices_used": [two.devices, one.devices],
                  "sharded": {k: v.tolist() for k, v in two.metrics.items()},
                  "single": {k: v.tolist() for k, v in one.metrics.items()}}))
