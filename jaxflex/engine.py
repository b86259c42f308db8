"""The evaluation engine: every rollout of the library through one compiled program.

A rollout (``simulate.rollout``) of one trajectory on one model is compiled once per grid, model
order (first or second) and mode counts, and that single program serves every caller: the paper
sweep, the optimization studies' paper combinations, baselines and evaluations, the cycle-time
study, the benchmarks. Batches are run one trajectory at a time (on a 2-core CPU a vmapped batch
is no faster: 24 rollouts take ~1.0 s either way), so no batch size ever costs a new compilation;
the metrics come from a small program of their own (``metrics.batch_metrics``).

``run`` validates nothing: callers check their inputs before building tables (SPEC 8).
"""
from __future__ import annotations

import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex.linearized import Tables
from jaxflex.metrics import batch_metrics
from jaxflex.robot import Robot
from jaxflex.simulate import Grid, MotionSamples, Series, rollout


@functools.partial(jax.jit, static_argnames=("grid", "second_order"))
def _run(tables: Tables, samples: MotionSamples, tf, dwell, robot: Robot, grid: Grid, second_order: bool):
    return rollout(tables, samples, tf, dwell, grid, robot if second_order else None)


def run(tables: Tables, samples: MotionSamples, tf, dwell, robot: Robot, grid: Grid,
        second_order: bool = True) -> Series:
    """One rollout (motion over [0, tf] [s], dwell [s]) of the model ``robot`` whose path tables are
    ``tables``, through the shared compiled program. ``second_order`` (default): the full model's
    second-order remainder is added (``simulate.rollout``); False: the linearized model."""
    return _run(tables, samples, jnp.asarray(tf, dtype=float), jnp.asarray(dwell, dtype=float), robot, grid,
                bool(second_order))


def run_many(jobs: Sequence[tuple], grid: Grid, second_order: bool = True) -> Series:
    """Rollouts of the jobs (tables, samples, tf, dwell, robot), stacked along a leading axis."""
    return trees.stack([run(*job, grid=grid, second_order=second_order) for job in jobs])


def metrics_of(series: Series) -> dict:
    """Metrics (``jaxflex.metrics``) of a batch of runs as numpy arrays of the batch shape."""
    return {k: np.asarray(v) for k, v in batch_metrics(series).items()}
