"""Metrics of one design on many models: a Monte Carlo set or the uncertainty box, sharded over every
device of every process.

``sweep_models`` runs one design (``jaxflex.designs.Design``, its path and shaped law) on a set of
models (``jaxflex.uncertainty.ModelId``, built from a nominal robot by ``model_sets.build_model``)
in fixed-size chunks of one compiled program: each model's path tables and rollout, every stage of
``jaxflex.rollout`` as one traced function, vmapped over the chunk's models. A chunk is laid over
the devices of every process along a mesh axis ``"model"`` (``jaxflex.runtime.distributed``): each
process builds only its own devices' models and the results are gathered on every process. Run it
in one process (every local device), or in several joined by ``runtime.distributed.initialize``,
every process calling it with the same arguments: the results are the same.
"""
from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxflex import checks, trees
from jaxflex.blends import ALL_BLENDS
from jaxflex.design_sweep import metrics_batch
from jaxflex.designs import Design, design_path
from jaxflex.model_sets import build_model
from jaxflex.path import Cycle
from jaxflex.problem import Timing
from jaxflex.profiles import shaped
from jaxflex.progress import Progress
from jaxflex.robot import Robot
from jaxflex.runtime import distributed
from jaxflex.sweep import default_grid
from jaxflex.uncertainty import ModelId


class ModelSweep(NamedTuple):
    """Metrics dict name -> (K,) arrays over the K models (the same on every process), the devices
    and processes the chunks were laid over, the chunk size, and timing [s]: ``compile_s``, ``run_s``
    (every chunk), ``models_per_s`` per process (K / run_s / processes)."""

    metrics: dict
    devices: int
    processes: int
    chunk: int
    compile_s: float
    run_s: float
    models_per_s: float


@dataclasses.dataclass(frozen=True)
class ModelSweepConfig:
    """How ``sweep_models`` simulates: the ``timing`` (tf [s], dwell [s], grid; None: the default grid
    for tf), the design's ``blend`` family, the shaped law's end-factor ``order``, the model order
    (``second_order``), the models per device per compiled call (``per_device``), the ``devices``
    (default every device of every process) and ``progress`` on stderr (process 0)."""

    timing: Timing = Timing()
    blend: str = "lame"
    order: int = 3
    second_order: bool = True
    per_device: int = 4
    devices: tuple | None = None
    progress: bool = False


def sweep_models(nominal: Robot, cycle: Cycle, x: Design, models: Sequence[ModelId],
                 config: ModelSweepConfig = ModelSweepConfig()) -> ModelSweep:
    """Metrics of the design ``x`` on every model of ``models`` (built from ``nominal``), as
    ``config`` says (``ModelSweepConfig``). The models are cut into chunks of ``per_device`` x the
    device count (the last one padded with its final model, the padding dropped); one compilation
    serves every chunk. Raises ValueError on a bad input (before anything compiles) and
    FloatingPointError naming the first model with a non-finite metric."""
    if not isinstance(config, ModelSweepConfig):
        raise TypeError(f"config must be a ModelSweepConfig, got {type(config).__name__}")
    models = tuple(models)
    if not models or not all(isinstance(m, ModelId) for m in models):
        raise ValueError("models must be a non-empty sequence of jaxflex.uncertainty.ModelId")
    tf, dwell, grid = config.timing.checked()
    blend = checks.one_of("blend", config.blend, ALL_BLENDS)
    per_device = checks.count("per_device", config.per_device)
    design_path(cycle, jax.tree_util.tree_map(np.asarray, x), blend)       # a valid path before compiling
    shaped(np.asarray(x.coef), config.order)
    grid = grid if grid is not None else default_grid(nominal, [tf], dwell)
    sharding = distributed.batch_sharding("model", config.devices)
    n_dev = sharding.mesh.devices.size
    chunk = per_device * n_dev
    size = len(models)
    padded = models + (models[-1],) * (-size % chunk)
    host = lambda v: np.asarray(v, dtype=float)

    def robots(lo, hi):                          # the models of rows lo..hi-1, stacked (built here only)
        return trees.stack([build_model(m, nominal, cycle) for m in padded[lo:hi]], dtype=float)

    def chunk_robots(start):
        example = robots(start, start + 1)
        leaves, treedef = jax.tree_util.tree_flatten(example)
        built = {}

        def rows_of(k):
            def rows(lo, hi):
                if (lo, hi) not in built:
                    built[(lo, hi)] = jax.tree_util.tree_flatten(robots(start + lo, start + hi))[0]
                return np.asarray(built[(lo, hi)][k])
            return rows
        return jax.tree_util.tree_unflatten(
            treedef, [distributed.rows_array(rows_of(k), chunk, sharding) for k in range(len(leaves))])

    scalars = (host(tf), host(dwell))
    leader = distributed.is_leader()
    bar = Progress(f"model sweep ({size} models)", total=size, unit="model", enabled=config.progress and leader)
    t0 = time.perf_counter()
    first = chunk_robots(0)
    with bar.waiting("compiling the batched rollout", key=f"compile model sweep {chunk} {grid}"):
        compiled = metrics_batch.lower(first, cycle, x, *scalars, grid=grid, blend=blend, order=config.order,
                                       second_order=config.second_order, over="robot").compile()
    compile_s = time.perf_counter() - t0
    out, t0 = [], time.perf_counter()
    for start in range(0, len(padded), chunk):
        rs = first if start == 0 else chunk_robots(start)
        out.append(distributed.gather(compiled(rs, cycle, x, *scalars)))
        bar.update(min(start + chunk, size))
    bar.close()
    run_s = time.perf_counter() - t0
    mets = {k: np.concatenate([o[k] for o in out])[:size] for k in out[0]}
    for name, v in mets.items():
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise FloatingPointError(f"non-finite {name} for model {models[int(bad[0])].label}")
    processes = jax.process_count()
    return ModelSweep(mets, n_dev, processes, chunk, compile_s, run_s, size / run_s / processes)
