"""The evaluation engine: every rollout of the library through one set of compiled programs.

The engine interprets the stages of ``jaxflex.rollout`` from a trajectory's tables and samples to
its series as compiled programs (``programs``): for the second-order model one program per stage,
run one after the other; for the linearized model one program. They are compiled once per grid,
model order and mode counts (the remainder, a map over the first pass's sites, once for every grid:
``ROWS``), and that one set serves every caller: the paper sweep, the
optimization studies' paper combinations, baselines and evaluations, the cycle-time study, the
benchmarks. Batches are run one trajectory at a time, so no batch size ever costs a new
compilation, from a few threads at once (``jaxflex.runtime.threads``); the metrics come from a small
program of their own (``batch_metrics``), vmapped over the runs.

The rollout programs are hot programs: they compile with ``jaxflex.runtime.options.HOT_LOOP`` whatever
XLA_FLAGS say.

``run`` validates nothing: callers check their inputs before building tables
(docs/conventions.md#bad-input).
"""
from __future__ import annotations

import dataclasses
import functools
from concurrent.futures import Future
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import rollout as rl
from jaxflex import trees
from jaxflex.runtime import compiled
from jaxflex.runtime.options import HOT_LOOP
from jaxflex.linearized import SEGMENT_NODES, Tables, coeff_shapes
from jaxflex.metrics import metrics
from jaxflex.model_sets import ModelSet
from jaxflex.runtime.threads import host_map
from jaxflex.path import Path
from jaxflex.profiles import Profile
from jaxflex.robot import Robot
from jaxflex.rollout import RolloutModel, RolloutState
from jaxflex.servo import check_stable, feedforward_advance, with_rotor
from jaxflex.servo_simulate import Schedule, feedforward_torques, servo_grid, servo_schedule
from jaxflex.simulate import Grid, MotionSamples, Series, motion_samples
from jaxflex.tables import path_tables, servo_path_tables


def _stage(model: RolloutModel, inputs: RolloutState, stage: rl.Stage) -> RolloutState:
    """One program of the engine: a stage (or stages composed, ``rollout.compose``) on the state
    fields it reads, returning the fields it writes."""
    return rl.restrict(stage.fn(model, inputs), stage.writes)


_program = jax.jit(_stage, static_argnames=("stage",), compiler_options=HOT_LOOP)

# Rows per call of a stage that maps a field row by row (``rollout.Stage.over``: the second-order
# remainder at the first pass's sites). Its program then does not depend on the grid: the sweep's
# grid, its error estimate's coarser grid and a refined grid share one compilation. Each call has a
# fixed cost whatever its rows (the program's many small kernels), so the pieces are large: the
# default grid's 392 sites in one call, a coarser grid's padded to them, a finer grid's in two or
# more (the measurements are in docs/performance.md).
ROWS = 392

_CANONICAL_GRID = Grid()


def _by_rows(model: RolloutModel, inputs: RolloutState, stage: rl.Stage) -> RolloutState:
    """``stage`` (with ``stage.over``) on ``inputs`` through one program of ``ROWS`` rows, called
    on consecutive pieces of the mapped field (the last one padded with copies of the first row);
    the written rows are joined on the host and cut to the field's length. The model's grid is
    replaced by one fixed grid, which such a stage does not read, so that every grid shares the
    program."""
    model = dataclasses.replace(model, grid=_CANONICAL_GRID)
    leaves, tree = jax.tree_util.tree_flatten(getattr(inputs, stage.over))
    n = leaves[0].shape[0]
    if n == ROWS:                                   # one whole piece: no copies
        return _call(model, inputs, stage)
    rows = [np.asarray(a) for a in leaves]
    pad = -n % ROWS
    rows = [np.concatenate([a, np.repeat(a[:1], pad, axis=0)]) for a in rows]
    (written,) = stage.writes
    parts = [getattr(_call(model, inputs._replace(**{stage.over: tree.unflatten([a[i:i + ROWS] for a in rows])}),
                           stage), written)
             for i in range(0, n + pad, ROWS)]
    return rl.RolloutState(**{written: np.concatenate([np.asarray(p) for p in parts])[:n]})


def programs(second_order: bool, servo: bool = False) -> tuple[rl.Stage, ...]:
    """The engine's programs over the stages of a rollout from its tables and samples to its series
    (``rollout.between("first pass", "servo loop")`` as the controller selects them): with the
    perfect controller, the second-order model as one program per stage, because inside one program
    the remainder's thousand-odd small operations cost much more than their own time
    (docs/performance.md), the linearized model, which has no remainder, as one program; under a
    servo (``servo``) the feedforward and the closed loop, one program each."""
    stages = tuple(s for s in rl.between("first pass", "servo loop") if s.runs_with(servo))
    return stages if second_order or servo else (rl.compose(stages),)


def cache_size() -> int:
    """Executables compiled by the engine's rollout programs in this process (every shape and grid)."""
    return _program._cache_size() + compiled.registered(_program)


class ServoJob(NamedTuple):
    """What a rollout under a servo adds (``run``): the ``servo``, the path's ``servo_tables``
    (``servo_linearized``), the sample ``schedule`` (``sample_schedule``), and either the
    ``feedforward`` (N + 1 + Nd + 1, 2) [N m] at the nodes or None (computed for ``controller``, the
    controller's model; None: the robot simulated)."""

    servo: object
    servo_tables: Tables
    schedule: Schedule
    feedforward: jax.Array | None = None
    controller: Robot | None = None


def _call(model: RolloutModel, inputs: RolloutState, stage: rl.Stage) -> RolloutState:
    """One program of the engine on its inputs: the one ``compile_ahead`` compiled for these shapes,
    else compiled here and registered with them (``runtime.compiled.call``), so that the engine's
    programs are compiled once whichever comes first."""
    return compiled.call(_program, (model, inputs), {"stage": stage}, register=True)


def _ahead_chain(model: RolloutModel, state: RolloutState, stages) -> None:
    """Lower each program of ``stages`` from the output shapes of the ones before and compile them
    in the background (``runtime.compiled.lower_ahead``), as ``run`` will call them."""
    for stage in stages:
        inputs = rl.restrict(state, stage.reads)
        if stage.over is None:
            out, _ = compiled.lower_ahead(_program, (model, inputs), {"stage": stage})
        else:
            rows = getattr(inputs, stage.over)
            n = jax.tree_util.tree_leaves(rows)[0].shape[0]
            piece = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct((ROWS,) + a.shape[1:], a.dtype), rows)
            out, _ = compiled.lower_ahead(_program, (dataclasses.replace(model, grid=_CANONICAL_GRID),
                                                     inputs._replace(**{stage.over: piece})), {"stage": stage})
            out = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct((n,) + a.shape[1:], a.dtype), out)
        state = rl.merge(state, out, stage.writes)


def compile_ahead(robot: Robot, grid: Grid, second_order: bool = True) -> Future:
    """Start compiling, in the background, the engine's programs of a prescribed rollout (perfect
    controller) of models shaped like ``robot`` on ``grid``, from shapes alone (the robot's mode
    counts and the grid): a caller that builds its tables first (``sweep.run_sweep``) has the
    rollout compiled meanwhile, on the other core, and ``run`` then waits for these programs instead
    of compiling its own. Compiling them twice starts one compilation. Returns the Future of the
    lowering chain (done once every program is lowered; their compilations may go on)."""
    f64 = lambda shape: jax.ShapeDtypeStruct(shape, jnp.float64)
    nodes = sum(SEGMENT_NODES)
    tables = Tables(values=jax.tree_util.tree_map(lambda a: f64((nodes,) + a.shape), coeff_shapes(robot)),
                    breaks=f64((len(SEGMENT_NODES) + 1,)))
    n, nc = grid.steps, grid.coarse
    samples = MotionSamples(start=(f64((n,)),) * 3, end=(f64((n,)),) * 3, mid=(f64((nc,)),) * 3)
    model = RolloutModel(robot=robot, tf=f64(()), dwell=f64(()), grid=grid, second_order=second_order)
    key = ("engine", grid, second_order, jax.tree_util.tree_structure(robot),
           tuple(jax.typeof(a) for a in jax.tree_util.tree_leaves(robot)))
    return compiled.submit_chain(key, _ahead_chain, model, RolloutState(tables=tables, samples=samples),
                                 programs(second_order))


def run(tables: Tables, samples: MotionSamples, tf, dwell, robot: Robot, grid: Grid,
        second_order: bool = True, servo: ServoJob | None = None) -> Series:
    """One rollout (motion over [0, tf] [s], dwell [s]) of the model ``robot`` whose path tables are
    ``tables``, through the shared compiled programs (``programs``). ``second_order`` (default): the
    full model's second-order remainder is added; False: the linearized model. ``servo``: the motors
    driven by a servo loop (``ServoJob``; the robot with the servo's rotor); None: prescribed."""
    f = lambda v: jnp.asarray(v, dtype=float)
    model = RolloutModel(robot=robot, tf=f(tf), dwell=f(dwell), grid=grid, second_order=second_order,
                         servo=None if servo is None else servo.servo,
                         controller=None if servo is None else servo.controller)
    state = RolloutState(tables=tables, samples=samples)
    if servo is not None:
        state = state._replace(servo_tables=servo.servo_tables, schedule=servo.schedule, feedforward=servo.feedforward)
    for stage in rl.remaining(state, programs(second_order, servo is not None)):
        program = _call if stage.over is None else _by_rows
        state = rl.merge(state, program(model, rl.restrict(state, stage.reads), stage=stage), stage.writes)
    return state.series


class Job(NamedTuple):
    """One rollout for ``run_many``: the path ``tables`` of the model ``robot``, the motion
    ``samples``, the motion time ``tf`` [s], the ``dwell`` [s], and under a servo its ``ServoJob``."""

    tables: Tables
    samples: MotionSamples
    tf: float
    dwell: float
    robot: Robot
    servo: ServoJob | None = None


def run_many(jobs: Sequence[Job], grid: Grid, second_order: bool = True) -> Series:
    """Rollouts of the jobs (``Job``), stacked along a leading axis (run side by side on the host's
    cores, ``jaxflex.runtime.threads``)."""
    return trees.stack(host_map(lambda job: run(*job[:5], grid=grid, second_order=second_order, servo=job.servo),
                                jobs))


@jax.jit
def batch_metrics(series) -> dict:
    """``metrics`` of a batch of runs: every leaf of ``series`` with the same leading batch axes
    (those of ``series.t`` but its last) -> dict name -> array of that batch shape. A small program of
    its own, so the rollouts compile once whether or not their metrics are wanted."""
    lead = series.t.shape[:-1]
    flat = jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[len(lead):]), series)
    return {k: v.reshape(lead) for k, v in jax.vmap(metrics)(flat).items()}


def metrics_of(series: Series) -> dict:
    """Metrics (``jaxflex.metrics``) of a batch of runs as numpy arrays of the batch shape."""
    return {k: np.asarray(v) for k, v in batch_metrics(series).items()}


@functools.partial(jax.jit, static_argnames=("grid",))
def _motion_samples(length, profile, tf, grid):
    return motion_samples(length, profile, tf, grid)


def sample_motion(length, profile: Profile, tf, grid: Grid) -> MotionSamples:
    """``simulate.motion_samples`` on concrete values through one compiled program per kind of law
    (its display name does not matter): eager evaluation would dispatch (and compile) every small
    operation of the law on its own."""
    return _motion_samples(jnp.asarray(length, dtype=float), dataclasses.replace(profile, name=""),
                           jnp.asarray(tf, dtype=float), grid)


_schedule = jax.jit(servo_schedule, static_argnames=("grid",))


def sample_schedule(tf, dwell, grid: Grid, rate) -> Schedule:
    """``servo_simulate.servo_schedule`` on concrete values (one compiled program per grid): where
    the servo's samples at ``rate`` [Hz] fall in the grid's steps."""
    f = lambda v: jnp.asarray(v, dtype=float)
    return _schedule(f(tf), f(dwell), grid, 1.0 / f(rate))


REMEMBERED_MODELS = 16      # LawEvaluators of at most this many models keep their tables in the memo
STREAM_MODELS = 16          # models per group of an evaluator that does not keep its tables


class LawEvaluator:
    """Metrics of any motion law along one path on a set of models (second-order fast model).

    The tables are built once per model; every law (paper, shaped, input-shaped, Ruckig samples) on
    every model runs through the evaluation engine's compiled programs (``jaxflex.engine``), one
    model at a time, so evaluators of any model set share them. ``keep=False``: the tables are not
    kept but built again at every call, in groups of ``STREAM_MODELS`` models used for every law of
    the call (``metrics_many``) and dropped (for a large set: the memory of a few models' tables
    instead of all of them).

    ``servo``: the motors driven by a servo loop (``jaxflex.servo.Servo``, or one per model; None:
    the perfect controller). Each model then gets its servo's rotor, the grid is refined to the
    fastest servo's period (``servo_simulate.servo_grid``), and every loop is checked for stability
    along the path first (``servo.check_stable``; ``checked=True``: the caller has checked them over
    tf + dwell already, e.g. to leave the unstable ones out). The feedforward is computed for ``controller``
    (the controller's model, e.g. the nominal robot of a box; None: each model its own): the rigid
    inverse dynamics, or the flexible one from the controller's perfect-controller rollout, advanced
    by ``advance`` [s] (None: ``servo.feedforward_advance`` of the first model's servo; give the
    nominal controller's when the models' rates differ)."""

    def __init__(self, models: ModelSet, path: Path, tf: float, dwell: float, grid: Grid, *, keep: bool = True,
                 servo=None, controller: Robot | None = None, advance: float | None = None, checked: bool = False):
        k = len(models.labels)
        self._robots = models.singles()
        self._servos = None
        if servo is not None:
            servos = list(servo) if isinstance(servo, (list, tuple)) else [servo] * k
            if len(servos) != k:
                raise ValueError(f"{len(servos)} servos for {k} models")
            self._servos = [sv.checked() for sv in servos]
            self._robots = [with_rotor(r, sv) for r, sv in zip(self._robots, self._servos)]
            for r, sv in zip(self._robots, self._servos) if not checked else ():
                check_stable(r, sv, path, float(tf) + float(dwell))
            grid = servo_grid(grid, tf, dwell, max(float(sv.rate) for sv in self._servos))
        self.models, self.path, self.tf, self.dwell, self.grid = models, path, tf, dwell, grid
        self.controller = controller
        self.advance = advance if advance is not None or self._servos is None else float(
            feedforward_advance(self._servos[0]))
        # the tables built and kept per model (the rollouts take them one model at a time), in one
        # copy (they add up over a large set such as the studies' evaluation models, docs/performance.md);
        # the same coefficient program on the same chunks of poses as a stacked build, so the same values.
        # Without ``keep`` every call builds them again (in groups of models, see ``metrics_many``):
        # a few models' tables in memory at a time, the same values.
        self._remember = k <= REMEMBERED_MODELS     # small sets come again (``tables.coeffs_many``)
        self._tables = host_map(self._build, self._robots) if keep else None

    @property
    def servos(self) -> list | None:
        """The servo of each model (None: the perfect controller)."""
        return self._servos

    def _build(self, robot: Robot):
        """The path's tables of one model (with its servo tables under a servo)."""
        tables = path_tables(robot, self.path, remember=self._remember)
        return tables if self._servos is None else (tables, servo_path_tables(robot, self.path))

    @property
    def tables(self) -> Tables:
        """The tables of every model, stacked along a leading axis K (a new copy at each access)."""
        built = self._tables if self._tables is not None else host_map(self._build, self._robots)
        return trees.stack([b if self._servos is None else b[0] for b in built])

    def with_grid(self, grid: Grid) -> "LawEvaluator":
        """The same path and models on another grid, sharing the tables (they do not depend on it)."""
        other = object.__new__(LawEvaluator)
        if self._servos is not None:
            grid = servo_grid(grid, self.tf, self.dwell, max(float(sv.rate) for sv in self._servos))
        other.__dict__.update(self.__dict__, grid=grid)
        return other

    def samples(self, profile: Profile, tf: float | None = None) -> MotionSamples:
        return sample_motion(self.path.length, profile, self.tf if tf is None else tf, self.grid)

    def _feedforward(self, samples: MotionSamples, tf: float):
        """The controller's flexible feedforward at the nodes (None: computed per model)."""
        if self._servos is None or self.controller is None or self._servos[0].feedforward != "flexible":
            return None
        if any(sv.feedforward != "flexible" for sv in self._servos):
            raise ValueError("one feedforward kind for every model of an evaluator")
        tables = path_tables(self.controller, self.path)
        series = run(tables, samples, tf, self.dwell, self.controller, self.grid)
        return feedforward_torques("flexible", self.controller, tables, samples, self.grid, series, self.advance)

    def _jobs(self, built: list, indices, samples: MotionSamples, tf: float, feedforward) -> list[Job]:
        if self._servos is None:
            return [Job(built[j], samples, tf, self.dwell, self._robots[i]) for j, i in enumerate(indices)]
        jobs = []
        for j, i in enumerate(indices):
            servo = self._servos[i]
            extra = ServoJob(servo, built[j][1], sample_schedule(tf, self.dwell, self.grid, servo.rate), feedforward,
                             None if feedforward is not None else self.controller)
            jobs.append(Job(built[j][0], samples, tf, self.dwell, self._robots[i], extra))
        return jobs

    def series(self, law, tf: float | None = None):
        """The simulation ``Series`` of a law on every model (leading axis K)."""
        tf = self.tf if tf is None else tf
        samples = law if isinstance(law, MotionSamples) else self.samples(law, tf)
        ff = self._feedforward(samples, tf)
        if self._tables is None:
            def one(i):
                job = self._jobs([self._build(self._robots[i])], [i], samples, tf, ff)[0]
                return run(*job[:5], grid=self.grid, servo=job.servo)
            return trees.stack(host_map(one, range(len(self._robots))))
        return run_many(self._jobs(self._tables, range(len(self._robots)), samples, tf, ff), self.grid)

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
            ffs = [self._feedforward(smp, tf) for smp in samples]
            parts = [[] for _ in laws]
            for i in range(0, len(self._robots), STREAM_MODELS):
                indices = range(i, min(i + STREAM_MODELS, len(self._robots)))
                built = host_map(self._build, [self._robots[j] for j in indices])
                for part, smp, ff in zip(parts, samples, ffs):
                    part.append(metrics_of(run_many(self._jobs(built, indices, smp, tf, ff), self.grid)))
                del built
            out = [{k: np.concatenate([p[k] for p in part]) for k in part[0]} for part in parts]
        for law, mets in zip(laws, out):
            bad = [k for k, v in mets.items() if not np.all(np.isfinite(v))]
            if bad:
                raise FloatingPointError(f"non-finite {bad} for law {getattr(law, 'name', 'samples')}")
        return out
