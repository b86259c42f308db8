"""Metrics of many designs on one robot: fixed-size chunks of one compiled program, sharded over devices.

``sweep_designs`` evaluates thousands of designs (``jaxflex.designs.Design``) in fixed-size chunks
(one compilation, bounded memory) and shards each chunk over every device of every process with
``jax.sharding`` (``jaxflex.runtime.distributed``: in several processes joined by
``jax.distributed``, every process calls it with the same arguments and gets every result); on
CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` exposes two devices to one process.
Each design runs every stage of ``jaxflex.rollout`` as one traced function.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex.blends import ALL_BLENDS
from jaxflex.designs import Design
from jaxflex.path import Cycle, check_path_args
from jaxflex.problem import Timing
from jaxflex.profiles import shaped
from jaxflex.progress import Progress
from jaxflex.robot import Robot
from jaxflex.runtime import distributed
from jaxflex.rollout import design_rollout
from jaxflex.sweep import default_grid


@functools.partial(jax.jit, static_argnames=("grid", "blend", "order", "second_order", "over"))
def metrics_batch(robot, cycle, x, tf, dwell, grid, blend, order, second_order, over="design"):
    """Every stage of a design's rollout as one traced function, vmapped over a leading batch axis of
    the designs ``x`` (``over="design"``) or of the models ``robot`` (``over="robot"``, e.g.
    ``jaxflex.model_sweep``) -> metrics dict name -> (batch,) arrays."""
    one = lambda r, xi: design_rollout(r, cycle, xi, tf, dwell, grid, blend=blend, order=order,
                                       second_order=second_order).terms.metrics
    return jax.vmap(one, in_axes=(None, 0) if over == "design" else (0, None))(robot, x)


class DesignSweep(NamedTuple):
    """Metrics dict name -> (D,) arrays, the number of devices used, chunk size and timing [s]."""

    metrics: dict
    devices: int
    chunk: int
    compile_s: float
    run_s: float


@dataclasses.dataclass(frozen=True)
class DesignSweepConfig:
    """How ``sweep_designs`` simulates: the ``timing`` (tf [s], dwell [s], grid; None: the default
    grid for tf, ``jaxflex.sweep.default_grid``), the designs' ``blend`` family, the shaped law's
    end-factor ``order``, the model order (``second_order``, ``simulate.rollout``), the ``chunk``
    of designs per compiled call (default 4 per device) and the ``devices`` it is sharded over
    (default: every device of every process); ``progress`` on stderr (process 0)."""

    timing: Timing = Timing()
    blend: str = "lame"
    order: int = 3
    second_order: bool = True
    chunk: int | None = None
    devices: tuple | None = None
    progress: bool = False


def sweep_designs(robot: Robot, cycle: Cycle, xs: Design,
                  config: DesignSweepConfig = DesignSweepConfig()) -> DesignSweep:
    """Metrics of a batch of D designs (leaves with a leading axis D) on ``robot`` as ``config``
    says (``DesignSweepConfig``).

    The batch is cut into chunks of ``config.chunk`` designs (the last chunk is padded by repeating
    its final design and the padding dropped), each chunk sharded over the devices along a
    one-dimensional mesh axis ``"design"``. One compilation serves every chunk. Raises ValueError on
    inconsistent shapes and FloatingPointError naming the first design with a non-finite metric."""
    if not isinstance(config, DesignSweepConfig):
        raise TypeError(f"config must be a DesignSweepConfig, got {type(config).__name__}")
    tf, dwell, grid = config.timing.checked()
    blend, order, second_order, chunk, devices = (config.blend, config.order, config.second_order, config.chunk,
                                                  config.devices)
    blend = checks.one_of("blend", blend, ALL_BLENDS)
    if chunk is not None:
        chunk = checks.count("chunk", chunk)
    leaves = [jnp.asarray(v, dtype=float) for v in xs]
    size = leaves[0].shape[0] if leaves[0].ndim == 2 else 0
    if size == 0 or any(v.shape[:1] != (size,) for v in leaves) or any(v.shape != (size, 2) for v in leaves[:3]):
        raise ValueError("designs need a common leading batch axis D and a corner axis (D, 2) for d, e, n; "
                         f"got shapes {[v.shape for v in leaves]}")
    if leaves[3].ndim != 2:
        raise ValueError(f"design coefficients must have shape (D, m + 1), got {leaves[3].shape}")
    host = [np.asarray(v) for v in leaves]
    for i in range(size):                    # every design valid before anything compiles
        try:
            check_path_args(cycle, blend, *(float(host[k][i, c]) for c in range(2) for k in range(3)))
            shaped(host[3][i], order)
        except ValueError as err:
            raise ValueError(f"design {i}: {err}") from None
    grid = grid if grid is not None else default_grid(robot, [tf], dwell)
    shard = distributed.batch_sharding("design", devices)
    devices = list(shard.mesh.devices.flat)
    chunk = chunk or 4 * len(devices)
    if chunk % len(devices):
        raise ValueError(f"chunk {chunk} is not a multiple of the {len(devices)} devices")
    pad = -size % chunk
    padded = [np.concatenate([v, np.repeat(v[-1:], pad, axis=0)]) for v in host]
    scalars = (np.asarray(tf, dtype=float), np.asarray(dwell, dtype=float))
    part = lambda i: Design(*(distributed.rows_array(lambda lo, hi, v=v: v[i + lo:i + hi], chunk, shard)
                              for v in padded))
    bar = Progress(f"design sweep ({size} designs)", total=size, unit="design",
                   enabled=config.progress and distributed.is_leader())
    t0 = time.perf_counter()
    with bar.waiting("compiling the batched rollout", key=f"compile design sweep {chunk} {grid}"):
        compiled = metrics_batch.lower(robot, cycle, part(0), *scalars, grid=grid,
                                        blend=blend, order=order, second_order=second_order).compile()
    compile_s = time.perf_counter() - t0
    out, t0 = [], time.perf_counter()
    for i in range(0, size + pad, chunk):
        out.append(distributed.gather(compiled(robot, cycle, part(i), *scalars)))
        bar.update(min(i + chunk, size))
    bar.close()
    run_s = time.perf_counter() - t0
    mets = {k: np.concatenate([o[k] for o in out])[:size] for k in out[0]}
    for name, v in mets.items():
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            i = int(bad[0])
            raise FloatingPointError(f"non-finite {name} for design {i}: d={np.asarray(leaves[0][i]).tolist()} m, "
                                     f"e={np.asarray(leaves[1][i]).tolist()} m, n={np.asarray(leaves[2][i]).tolist()}, "
                                     f"coef={np.asarray(leaves[3][i]).tolist()}")
    return DesignSweep(mets, len(devices), chunk, compile_s, run_s)
