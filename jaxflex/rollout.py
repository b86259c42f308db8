"""One rollout as one ordered list of stages over a typed state.

A rollout simulates one trajectory on one model: the motion over [0, tf], then the dwell at the
place pose. It is written once, as the stages of ``STAGES``, each a pure function
``stage(model, state) -> state`` of the constant ``RolloutModel`` (the robot, the times, the grid)
and the ``RolloutState`` that the stages fill in turn:

    path and tables   design                               -> tables, samples
    servo tables      design                               -> servo_tables, schedule         (servo)
    first pass        tables, samples                      -> prep, sites               (prescribed)
    remainder         sites                                -> remainders                (prescribed)
    last pass         tables, samples, prep, remainders    -> series                    (prescribed)
    feedforward       tables, samples                      -> feedforward                    (servo)
    servo loop        tables, servo_tables, samples,
                      schedule, feedforward                -> series                         (servo)
    metrics           series                               -> terms

(``jaxflex.simulate`` holds the integrator these stages call: the frozen-coefficient passes, the
continuous-coefficient correction and the second-order remainder; ``jaxflex.servo_simulate`` the
same integrator with the motors driven by a servo.) With the perfect controller (``model.servo``
None, the paper's) the motor angles are prescribed and the three passes run; with a servo
(``jaxflex.servo.Servo``) the motors are states of the closed loop, driven by the feedforward and
the sampled feedback, and the servo stages run instead (``active``). A state may start anywhere in
the list: given its tables and samples, a rollout starts at the first pass (``remaining``); a field
given in the state (the feedforward of a nominal model, for instance) is not computed again.

Every way the library runs a rollout reads this list, so a stage added here reaches all of them:

- ``run`` (here): the stages composed into one traced function, for ``jax.jit``, ``jax.vmap`` and
  ``jax.grad`` at the caller (the design sweep, the one-program objectives);
- ``jaxflex.engine``: one compiled program per stage, run in turn (the metrics batched over runs);
- ``jaxflex.optimize.staged``: each stage's forward pass and backward pass as programs of their
  own, model by model, and the ahead-of-time compilation of that chain.

Each ``Stage`` declares the state fields it reads and writes, so that an interpreter passes a
program only what it uses and keeps only what it returns.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import jax

from jaxflex.designs import Design, design_path
from jaxflex.linearized import Tables, build_tables
from jaxflex.metrics import Terms, terms
from jaxflex.path import Cycle
from jaxflex.profiles import shaped
from jaxflex.robot import Robot
from jaxflex.servo import Servo, feedforward_advance
from jaxflex.servo_linearized import build_servo_tables
from jaxflex.servo_simulate import Schedule, closed_loop, feedforward_torques, servo_schedule
from jaxflex.simulate import (Grid, MotionSamples, Prepared, Series, Sites, add_remainders, first_pass,
                              motion_samples, prepare, remainders, second_pass)
from jaxflex.workspace import Workspace, has_servo, workspace_servo_tables, workspace_tables

_static = dict(metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RolloutModel:
    """What stays constant during a rollout.

    robot: the model simulated (its tables come from it); tf [s] the motion time; dwell [s] the time
    simulated after it; cycle and workspace: where the path stage builds a design's path and its
    tables (workspace None: the tables from the model, ``linearized.build_tables``; else
    interpolated from the robot's workspace tables, ``jaxflex.workspace``, and so are the servo
    tables if it holds them); only the path and servo-tables stages read them. ``servo``: the servo
    loop driving the motors (None: the perfect controller, the motor angles prescribed); ``robot``
    then carries the servo's rotor (``servo.with_rotor``). Static (part
    of the compiled program's identity): the ``grid``; ``second_order`` (the full model's
    second-order remainder is added; False: the linearized model); the design's ``blend`` family and
    the shaped law's end-factor ``order`` (path stage)."""

    robot: Robot
    tf: jax.Array
    dwell: jax.Array
    cycle: Cycle | None = None
    workspace: Workspace | None = None
    servo: Servo | None = None
    controller: Robot | None = None
    grid: Grid = dataclasses.field(default=Grid(), **_static)
    second_order: bool = dataclasses.field(default=True, **_static)
    blend: str = dataclasses.field(default="lame", **_static)
    order: int = dataclasses.field(default=3, **_static)


class RolloutState(NamedTuple):
    """What the stages compute, field by field (None: not computed, or not given).

    design: the blend parameters and law coefficients (``jaxflex.designs.Design``); tables: the
    path's coefficient tables; samples: the motion law on the grid; prep: the frozen maps, node
    coefficients and forcing of the passes (the first pass's corrections included); sites: where the
    second-order remainder is sampled; remainders (S, 2 + ne): its values there; servo_tables: the
    path's tables of the motors' coefficients (``servo_linearized``); schedule: where the servo's
    samples fall in the grid's steps (``servo_simulate.Schedule``); feedforward (N + 1 + Nd + 1, 2)
    [N m]: the servo's feedforward torque at the motion's and the dwell's nodes; series: the outputs
    at every node (``simulate.Series``), of the closed loop under a servo; terms: the metrics and the
    residual terms (``metrics.Terms``)."""

    design: Design | None = None
    tables: Tables | None = None
    samples: MotionSamples | None = None
    servo_tables: Tables | None = None
    schedule: Schedule | None = None
    feedforward: jax.Array | None = None
    prep: Prepared | None = None
    sites: Sites | None = None
    remainders: jax.Array | None = None
    series: Series | None = None
    terms: Terms | None = None


def path_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The design's path (``designs.design_path``), its coefficient tables and its shaped motion law
    sampled on the grid."""
    path = design_path(model.cycle, state.design, model.blend)
    if model.workspace is None:
        tables = build_tables(model.robot, path)
    else:
        tables = workspace_tables(model.workspace, model.robot, path)
    samples = motion_samples(path.length, shaped(state.design.coef, model.order), model.tf, model.grid)
    return state._replace(tables=tables, samples=samples)


def servo_tables_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The design path's servo tables and the servo's sample schedule on the grid
    (``servo_simulate.servo_schedule``). The tables are interpolated from the model's workspace when
    it tabulates them (``workspace.has_servo``: cheap to differentiate and to compile, within the
    workspace's interpolation error), else built from the model
    (``servo_linearized.build_servo_tables``)."""
    path = design_path(model.cycle, state.design, model.blend)
    if model.workspace is not None and has_servo(model.workspace):
        servo_tables = workspace_servo_tables(model.workspace, model.robot, path)
    else:
        servo_tables = build_servo_tables(model.robot, path)
    return state._replace(servo_tables=servo_tables,
                          schedule=servo_schedule(model.tf, model.dwell, model.grid, model.servo.period))


def first_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The coefficients of the passes (``simulate.prepare``) and, for the second-order model or
    continuous coefficients, the first pass: its corrections of the forcing and the remainder's
    sites (``simulate.first_pass``)."""
    prep = prepare(state.tables, state.samples, model.tf, model.grid)
    sites = None
    if model.second_order or model.grid.continuous:
        forcing, sites = first_pass(state.tables, prep, state.samples, model.grid)
        prep = prep._replace(forcing=forcing)
    return state._replace(prep=prep, sites=sites)


def remainder_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The full model's second-order remainder at the first pass's sites (second-order model only)."""
    return state._replace(remainders=remainders(model.robot, state.sites) if model.second_order else None)


def last_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The last pass with the remainders added to the forcing, then the dwell
    (``simulate.second_pass``)."""
    prep = state.prep
    if state.remainders is not None:
        prep = prep._replace(forcing=add_remainders(prep.forcing, state.remainders, model.grid))
    return state._replace(series=second_pass(state.tables, prep, state.samples, model.tf, model.dwell, model.grid))


def feedforward_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The servo's feedforward at the nodes (``servo_simulate.feedforward_torques``) of its kind:
    "rigid" the rigid inverse dynamics of ``model.controller`` (default the robot); "flexible" the
    torque of the robot's perfect-controller rollout (the three passes; for another model's, give
    the field in the state), advanced by ``servo.feedforward_advance``."""
    kind = model.servo.feedforward
    series = None
    if kind == "flexible":
        if model.controller is not None:
            raise ValueError("a flexible feedforward of another model than the one simulated is given in the state")
        prescribed = dataclasses.replace(model, servo=None)
        series = run(prescribed, restrict(state, ("tables", "samples")), between("first pass", "last pass")).series
    controller = model.robot if model.controller is None else model.controller
    return state._replace(feedforward=feedforward_torques(kind, controller, state.tables, state.samples, model.grid,
                                                          series, feedforward_advance(model.servo)))


def servo_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The closed loop under the servo (``servo_simulate.closed_loop``), with the full model's
    second-order remainder for the second-order model."""
    robot = model.robot if model.second_order else None
    return state._replace(series=closed_loop(state.tables, state.servo_tables, state.samples, state.schedule,
                                             state.feedforward, model.tf, model.dwell, model.grid, model.servo,
                                             robot))


def metrics_stage(model: RolloutModel, state: RolloutState) -> RolloutState:
    """The metrics and the residual terms of the series (``metrics.terms``)."""
    return state._replace(terms=terms(state.series))


class Stage(NamedTuple):
    """A named stage: ``fn(model, state) -> state`` reads the state fields ``reads`` and writes
    ``writes``; it runs ``when`` "always", under the perfect controller ("prescribed") or under a
    servo ("servo"). ``over``: the one field it reads (a pytree of arrays with a common leading axis)
    if it maps that field row by row into its one written array, rows in the same order, and reads
    nothing of the model but the robot and the model order (not the grid, the times or the design):
    an interpreter may then run it on pieces of the rows (``jaxflex.engine``). Hashable (a static
    argument of the interpreters' compiled programs)."""

    name: str
    fn: Callable
    reads: tuple
    writes: tuple
    when: str = "always"
    over: str | None = None

    def runs_with(self, servo: bool) -> bool:
        """Whether the stage runs under a servo (``servo``) or under the perfect controller."""
        return self.when == "always" or (self.when == "servo") == servo

    def active(self, model: RolloutModel) -> bool:
        """Whether the stage runs in a rollout of ``model``."""
        return self.runs_with(model.servo is not None)


STAGES = (
    Stage("path and tables", path_stage, ("design",), ("tables", "samples")),
    Stage("servo tables", servo_tables_stage, ("design",), ("servo_tables", "schedule"), "servo"),
    Stage("first pass", first_stage, ("tables", "samples"), ("prep", "sites"), "prescribed"),
    Stage("remainder", remainder_stage, ("sites",), ("remainders",), "prescribed", over="sites"),
    Stage("last pass", last_stage, ("tables", "samples", "prep", "remainders"), ("series",), "prescribed"),
    Stage("feedforward", feedforward_stage, ("tables", "samples"), ("feedforward",), "servo"),
    Stage("servo loop", servo_stage, ("tables", "servo_tables", "samples", "schedule", "feedforward"), ("series",),
          "servo"),
    Stage("metrics", metrics_stage, ("series",), ("terms",)),
)


def active(model: RolloutModel, stages=None) -> tuple[Stage, ...]:
    """The ``stages`` (default ``STAGES``) that run in a rollout of ``model`` (``Stage.active``)."""
    return tuple(s for s in (STAGES if stages is None else stages) if s.active(model))


def between(first: str | None = None, last: str | None = None) -> tuple[Stage, ...]:
    """The stages of ``STAGES`` from the one named ``first`` to the one named ``last`` (inclusive;
    None: from the start, to the end)."""
    names = [s.name for s in STAGES]
    i = 0 if first is None else names.index(first)
    j = len(STAGES) if last is None else names.index(last) + 1
    return STAGES[i:j]


def remaining(state: RolloutState, stages=None) -> tuple[Stage, ...]:
    """The stages still to run on ``state`` (of ``stages``, default ``STAGES``): from the first one
    with an output not yet in it, but those after it whose outputs are all given."""
    stages = STAGES if stages is None else stages
    missing = lambda stage: any(getattr(state, name) is None for name in stage.writes)
    for i, stage in enumerate(stages):
        if missing(stage):
            return (stage,) + tuple(s for s in stages[i + 1:] if missing(s))
    return ()


def restrict(state: RolloutState, fields) -> RolloutState:
    """The state with only ``fields`` kept (the others None)."""
    return RolloutState(**{name: getattr(state, name) for name in fields})


def merge(state: RolloutState, update: RolloutState, fields) -> RolloutState:
    """``state`` with the ``fields`` of ``update``."""
    return state._replace(**{name: getattr(update, name) for name in fields})


class _Composed(NamedTuple):
    """Stages run one after the other as one function (equal, and hashing equal, for equal stages)."""

    stages: tuple

    def __call__(self, model: RolloutModel, state: RolloutState) -> RolloutState:
        for stage in self.stages:
            state = stage.fn(model, state)
        return state


def compose(stages) -> Stage:
    """Consecutive stages as one: it reads what they read and the earlier ones do not write, and
    writes everything they write."""
    stages = tuple(stages)
    reads, writes = [], []
    for stage in stages:
        reads += [f for f in stage.reads if f not in writes and f not in reads]
        writes += [f for f in stage.writes if f not in writes]
    return Stage(" + ".join(s.name for s in stages), _Composed(stages), tuple(reads), tuple(writes))


def run(model: RolloutModel, state: RolloutState, stages=None) -> RolloutState:
    """The plain rollout: the ``stages`` (default: every stage of the model still to run on
    ``state``, ``remaining(state, active(model))``) applied in order, as one traced function."""
    for stage in remaining(state, active(model)) if stages is None else stages:
        state = stage.fn(model, state)
    return state


def rollout(tables: Tables, samples: MotionSamples, tf, dwell, grid: Grid, robot: Robot | None = None) -> Series:
    """Simulate one trajectory from its path tables and motion samples: motion over [0, tf] [s],
    then a dwell [s] at the place pose.

    A first pass with coefficients frozen per coarse interval gives z1 = [q_e, q_e', q_e'']; a second
    pass adds, as forcing, the variation of the coefficients within each interval along z1 (with
    ``grid.continuous``, the default) and, with ``robot`` (the robot the tables were built for), the
    full model's remainder R(z1) - R(0) - R'(0) z1 (``linearized.remainder``; extra forcing and
    torque): one defect correction, so the run is second-order accurate in the elastic coordinates
    (error O(q_e^3) instead of O(q_e^2)). Without robot and with ``continuous=False`` it is a single
    pass of the plain linearized model. The dwell keeps the linear equations."""
    model = RolloutModel(robot=robot, tf=tf, dwell=dwell, grid=grid, second_order=robot is not None)
    state = RolloutState(tables=tables, samples=samples)
    return run(model, state, remaining(state, active(model, between(last="last pass")))).series


def design_rollout(robot: Robot, cycle: Cycle, x: Design, tf, dwell, grid: Grid, *, blend: str = "lame",
                   order: int = 3, second_order: bool = True, workspace: Workspace | None = None) -> RolloutState:
    """Every stage of one design's rollout (motion over [0, tf] [s], then a dwell [s]): the state
    with its tables, samples, series and terms. Differentiable in x, robot (payload, stiffness, ...)
    and tf. ``second_order`` selects the second-order fast model. The path's tables are built from
    the model (``linearized.build_tables``) or, given the robot's ``workspace``
    (``jaxflex.workspace``), interpolated from it: much cheaper to differentiate and to compile,
    within ~1e-6 of the exact tables. Validate concrete inputs with ``designs.design_path`` before
    tracing."""
    model = RolloutModel(robot=robot, tf=tf, dwell=dwell, cycle=cycle, workspace=workspace, grid=grid,
                         second_order=second_order, blend=blend, order=order)
    return run(model, RolloutState(design=x))
