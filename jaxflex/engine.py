"""The evaluation engine: every rollout of the library through one set of compiled programs.

A rollout (``simulate.rollout``) of one trajectory on one model is compiled once per grid, model
order (first or second) and mode counts (the second-order model as three programs run one after
the other: first pass, remainder, second pass; see ``_first``), and that one set serves every caller: the paper
sweep, the optimization studies' paper combinations, baselines and evaluations, the cycle-time
study, the benchmarks. Batches are run one trajectory at a time (on a 2-core CPU a vmapped batch
was no faster: 24 rollouts took ~1.0 s either way, measured with the single-program rollout), so no batch size ever costs a new compilation,
from a few threads at once (``jaxflex.parallel``: ~0.7x the time on 2 cores);
the metrics come from a small program of their own (``metrics.batch_metrics``).

The rollout programs are hot programs: they compile with ``jaxflex.compiled.HOT_LOOP`` whatever
XLA_FLAGS say (LLVM level 1 runs it as fast as level 3 and compiles it sooner).

``run`` validates nothing: callers check their inputs before building tables (SPEC 8).
"""
from __future__ import annotations

import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex.compiled import HOT_LOOP
from jaxflex.linearized import Tables, _robot_list, path_tables
from jaxflex.metrics import batch_metrics
from jaxflex.model_sets import ModelSet
from jaxflex.parallel import host_map
from jaxflex.path import Path
from jaxflex.profiles import Profile
from jaxflex.robot import Robot
from jaxflex.simulate import (Grid, MotionSamples, Prepared, Series, add_remainders, first_pass, prepare,
                              remainders, rollout, sample_motion, second_pass)


@functools.partial(jax.jit, static_argnames=("grid",), compiler_options=HOT_LOOP)
def _linear(tables: Tables, samples: MotionSamples, tf, dwell, grid: Grid):
    return rollout(tables, samples, tf, dwell, grid)


# The second-order rollout runs as three programs: the first pass, the full model's remainder at
# its sites, the second pass. The same operations as ``simulate.rollout`` (the gradients go through
# that one function), but inside one program the remainder's thousand-odd small operations cost
# about twice their own time (a rollout of the default grid, minimum of 40 runs on 2 cores: 36.6 ms
# of wall time and 54 ms of CPU as one program, 20.7 ms and 29 ms as these three; the same e(t) to
# 5e-15 relative).
def first_stage(tables: Tables, samples: MotionSamples, tf, grid: Grid) -> tuple[Prepared, object]:
    """The second-order rollout's first part: the prepared pass with the first pass's forcing, and
    the sites (the first pass's states) where the full model's remainder is evaluated."""
    prep = prepare(tables, samples, tf, grid)
    forcing, sites = first_pass(tables, prep, samples, grid)
    return prep._replace(forcing=forcing), sites


def second_stage(tables: Tables, prep: Prepared, r_all, samples: MotionSamples, tf, dwell, grid: Grid) -> Series:
    """The second-order rollout's last part: the second pass with the remainders ``r_all``
    (``simulate.remainders`` at the sites of ``first_stage``) added to the forcing, then the dwell."""
    return second_pass(tables, prep._replace(forcing=add_remainders(prep.forcing, r_all, grid)), samples, tf,
                       dwell, grid)


_first = jax.jit(first_stage, static_argnames=("grid",), compiler_options=HOT_LOOP)
_remainders = jax.jit(remainders, compiler_options=HOT_LOOP)
_second = jax.jit(second_stage, static_argnames=("grid",), compiler_options=HOT_LOOP)


def cache_size() -> int:
    """Executables compiled by the engine's rollout programs in this process (every shape and grid)."""
    return sum(p._cache_size() for p in (_linear, _first, _remainders, _second))


def run(tables: Tables, samples: MotionSamples, tf, dwell, robot: Robot, grid: Grid,
        second_order: bool = True) -> Series:
    """One rollout (motion over [0, tf] [s], dwell [s]) of the model ``robot`` whose path tables are
    ``tables``, through the shared compiled programs. ``second_order`` (default): the full model's
    second-order remainder is added (``simulate.rollout``); False: the linearized model."""
    tf, dwell = jnp.asarray(tf, dtype=float), jnp.asarray(dwell, dtype=float)
    if not second_order:
        return _linear(tables, samples, tf, dwell, grid)
    prep, sites = _first(tables, samples, tf, grid)
    return _second(tables, prep, _remainders(robot, sites), samples, tf, dwell, grid)


def run_many(jobs: Sequence[tuple], grid: Grid, second_order: bool = True) -> Series:
    """Rollouts of the jobs (tables, samples, tf, dwell, robot), stacked along a leading axis (run
    side by side on the host's cores, ``jaxflex.parallel``)."""
    return trees.stack(host_map(lambda job: run(*job, grid=grid, second_order=second_order), jobs))


def metrics_of(series: Series) -> dict:
    """Metrics (``jaxflex.metrics``) of a batch of runs as numpy arrays of the batch shape."""
    return {k: np.asarray(v) for k, v in batch_metrics(series).items()}


REMEMBERED_MODELS = 16      # LawEvaluators of at most this many models keep their tables in the memo
STREAM_MODELS = 16          # models per group of an evaluator that does not keep its tables


class LawEvaluator:
    """Metrics of any motion law along one path on a set of models (second-order fast model).

    The tables are built once per model; every law (paper, shaped, input-shaped, Ruckig samples) on
    every model runs through the evaluation engine's compiled programs (``jaxflex.engine``), one
    model at a time, so evaluators of any model set share them. ``keep=False``: the tables are not
    kept but built again at every call, in groups of ``STREAM_MODELS`` models used for every law of
    the call (``metrics_many``) and dropped (for a large set: the memory of a few models' tables
    instead of all of them). ``chunk`` is accepted for compatibility (it used to set the batch size
    of a vmapped program) and must be >= 1."""

    def __init__(self, models: ModelSet, path: Path, tf: float, dwell: float, grid: Grid, *,
                 chunk: int | None = None, keep: bool = True):
        k = len(models.labels)
        chunk = k if chunk is None else int(chunk)
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.models, self.path, self.tf, self.dwell, self.grid, self.chunk = models, path, tf, dwell, grid, chunk
        # the tables built and kept per model (the rollouts take them one model at a time), in one
        # copy: 2.3 MB per model on the default path, 0.5 GB for the studies' 212 evaluation models;
        # the same coefficient program on the same chunks of poses as a stacked build, so the same values.
        # Without ``keep`` every call builds them again (in groups of models, see ``metrics_many``):
        # a few models' tables in memory at a time, the same values.
        self._robots = _robot_list(models.robots)
        self._remember = k <= REMEMBERED_MODELS     # small sets come again (``linearized.coeffs_many``)
        self._tables = host_map(self._build, self._robots) if keep else None

    def _build(self, robot: Robot) -> Tables:
        return path_tables(robot, self.path, remember=self._remember)

    @property
    def tables(self) -> Tables:
        """The tables of every model, stacked along a leading axis K (a new copy at each access)."""
        return trees.stack(self._tables if self._tables is not None else host_map(self._build, self._robots))

    def with_grid(self, grid: Grid) -> "LawEvaluator":
        """The same path and models on another grid, sharing the tables (they do not depend on it)."""
        other = object.__new__(LawEvaluator)
        other.__dict__.update(self.__dict__, grid=grid)
        return other

    def samples(self, profile: Profile, tf: float | None = None) -> MotionSamples:
        return sample_motion(self.path.length, profile, self.tf if tf is None else tf, self.grid)

    def series(self, law, tf: float | None = None):
        """The simulation ``Series`` of a law on every model (leading axis K)."""
        tf = self.tf if tf is None else tf
        samples = law if isinstance(law, MotionSamples) else self.samples(law, tf)
        if self._tables is None:
            return trees.stack(host_map(lambda robot: run(self._build(robot), samples, tf, self.dwell, robot,
                                                          self.grid), self._robots))
        return run_many([(tables, samples, tf, self.dwell, robot) for tables, robot in zip(self._tables, self._robots)],
                        self.grid)

    def __call__(self, law, tf: float | None = None) -> dict:
        """law: a Profile or MotionSamples -> metrics dict name -> (K,) numpy arrays. ``tf`` [s]
        overrides the motion time (same grid, no recompilation; MotionSamples must match it)."""
        return self.metrics_many([law], tf)[0]

    def metrics_many(self, laws: Sequence, tf: float | None = None) -> list[dict]:
        """The metrics (as ``__call__``) of several laws, one dict per law. Without kept tables the
        models go in groups of ``STREAM_MODELS``: each group's tables are built, every law is run on
        them and they are dropped, so each model's tables are built once for all the laws."""
        tf = self.tf if tf is None else tf
        samples = [law if isinstance(law, MotionSamples) else self.samples(law, tf) for law in laws]
        if self._tables is not None:
            out = [metrics_of(self.series(smp, tf)) for smp in samples]
        else:
            parts = [[] for _ in laws]
            for i in range(0, len(self._robots), STREAM_MODELS):
                robots = self._robots[i:i + STREAM_MODELS]
                tables = host_map(self._build, robots)
                for part, smp in zip(parts, samples):
                    part.append(metrics_of(run_many([(t, smp, tf, self.dwell, r) for t, r in zip(tables, robots)],
                                                    self.grid)))
                del tables
            out = [{k: np.concatenate([p[k] for p in part]) for k in part[0]} for part in parts]
        for law, metrics in zip(laws, out):
            bad = [k for k, v in metrics.items() if not np.all(np.isfinite(v))]
            if bad:
                raise FloatingPointError(f"non-finite {bad} for law {getattr(law, 'name', 'samples')}")
        return out
