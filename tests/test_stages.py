"""The rollout is one list of stages (``jaxflex.rollout.STAGES``) that every interpreter reads: the
plain rollout (one traced function), the evaluation engine (one compiled program per stage), the
staged gradient (a forward and a backward program per stage, model by model) and its ahead-of-time
compile chain. Adding a stage is one edit there: a stage inserted into the list reaches all four.

A small model (one mode per link) on a coarse grid keeps the compilations short; the checks are
about the composition, which does not depend on the model's size."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import engine
from jaxflex import rollout as rl
from jaxflex.designs import design
from jaxflex.engine import sample_motion
from jaxflex.model_sets import model_set
from jaxflex.optimize import staged
from jaxflex.optimize.objective import Scales, encode
from jaxflex.optimize.training import Training, design_objective
from jaxflex.path import make_path
from jaxflex.problem import Timing
from jaxflex.profiles import make_profile
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.simulate import Grid
from jaxflex.tables import path_tables

TF, DWELL = 0.43, 0.02
GRID = Grid(coarse=16, fine=4, dwell_steps=40, squarings=8, unroll=1)


def _double(model, state):
    """A stage that changes the physics visibly: the second-order remainder counted twice."""
    return state._replace(remainders=2.0 * state.remainders)


EXTRA = rl.Stage("doubled remainder", _double, ("remainders",), ("remainders",))


def _with_extra(monkeypatch):
    stages = list(rl.STAGES)
    stages.insert([s.name for s in stages].index("remainder") + 1, EXTRA)
    monkeypatch.setattr(rl, "STAGES", tuple(stages))      # the one edit


@pytest.fixture(scope="module")
def small():
    robot = robot_preset("default", payload=6.0, n_bending=1, n_axial=1)
    cycle = cycle_preset()
    path = make_path(cycle, "lame", 0.025)
    return robot, cycle, path_tables(robot, path), sample_motion(path.length, make_profile("poly7"), TF, GRID)


def _dwell(series) -> np.ndarray:
    return np.asarray(series.e_dwell)


def test_a_stage_added_to_the_list_reaches_the_plain_rollout_and_the_engine(small, monkeypatch):
    """The plain rollout and the engine agree with each other with or without the extra stage (the
    same stages, one traced function against one program per stage: round-off, 1e-12 of the
    response), and the extra stage moves both by far more than that."""
    robot, _, tables, samples = small
    plain = lambda: jax.jit(lambda t, s: rl.rollout(t, s, TF, DWELL, GRID, robot))(tables, samples)
    before = (_dwell(plain()), _dwell(engine.run(tables, samples, TF, DWELL, robot, GRID)))
    _with_extra(monkeypatch)
    assert EXTRA in engine.programs(True)
    after = (_dwell(plain()), _dwell(engine.run(tables, samples, TF, DWELL, robot, GRID)))
    scale = np.max(np.abs(before[0]))
    for a, b in (before, after):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * scale)
    assert np.max(np.abs(after[0] - before[0])) > 1e-6 * scale           # the stage changed the physics


def test_the_engine_runs_the_remainder_in_pieces_that_every_grid_shares(small, monkeypatch):
    """The engine runs a stage that maps the sites row by row (the remainder, ``Stage.over``) through
    one program of ``engine.ROWS`` sites, whatever the grid (here 56 rows): a grid twice as fine as
    ``GRID`` (72 sites: two pieces, the last padded) compiles its two passes but not the remainder
    again, and its rollout equals the one with all 72 sites in one piece (round-off, 1e-12 of the
    response; the engine against the plain rollout is the test above)."""
    robot, cycle, tables, samples = small
    monkeypatch.setattr(engine, "ROWS", 56)
    engine.run(tables, samples, TF, DWELL, robot, GRID)
    grid = GRID._replace(coarse=2 * GRID.coarse)
    fine = sample_motion(make_path(cycle, "lame", 0.025).length, make_profile("poly7"), TF, grid)
    before = engine.cache_size()
    pieces = _dwell(engine.run(tables, fine, TF, DWELL, robot, grid))
    assert engine.cache_size() == before + 2, "the remainder's program was compiled again for a new grid"
    monkeypatch.setattr(engine, "ROWS", 72)
    whole = _dwell(engine.run(tables, fine, TF, DWELL, robot, grid))
    np.testing.assert_allclose(pieces, whole, rtol=0, atol=1e-12 * np.max(np.abs(whole)))


def test_the_engine_compiles_a_grid_ahead_from_shapes_alone(small):
    """``engine.compile_ahead`` builds the programs of a grid from the robot and the grid alone (the
    tables' and samples' shapes made by hand): a rollout on that grid then compiles nothing of its
    own (a shape made wrongly would leave the rollout to compile its own programs)."""
    robot, cycle, tables, _ = small
    grid = GRID._replace(dwell_steps=2 * GRID.dwell_steps)
    samples = sample_motion(make_path(cycle, "lame", 0.025).length, make_profile("poly7"), TF, grid)
    engine.compile_ahead(robot, grid).result()
    before = engine.cache_size()
    series = engine.run(tables, samples, TF, DWELL, robot, grid)
    assert engine.cache_size() == before, "a program of the rollout was not among those compiled ahead"
    assert np.all(np.isfinite(_dwell(series))) and np.max(np.abs(_dwell(series))) > 0


def test_a_stage_added_to_the_list_reaches_the_staged_gradient_and_its_compile_chain(small, monkeypatch):
    """With the extra stage (which the previous test shows changes the physics), the staged forward
    programs give the one-traced-function objective's value, the staged backward pass (whose cotangents now flow through the extra stage, which reads
    and rewrites a field another stage wrote) matches central differences of the staged value, and
    compiling the chain ahead of time compiles every program the step then runs (none is compiled
    again on first use)."""
    robot, cycle, _, _ = small
    models = model_set(robot, [6.0])
    scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), jnp.full(1, jnp.inf))
    f = design_objective(Training(models, cycle, Timing(TF, DWELL, GRID), scales))
    p0 = encode(cycle, design(d=0.02, e=0.03, n=3.5, coef=[1.0, 1.2, 0.9, 1.1]))
    gradient = staged.Staged()
    _with_extra(monkeypatch)
    assert EXTRA in staged.groups()
    gradient.compile_ahead(f, p0).result()
    programs = staged.cache_size(stages_only=True)
    (value, _), grad = gradient.value_and_grad(f, p0)
    assert staged.cache_size(stages_only=True) == programs, "a program of the step was not in the ahead-of-time chain"
    plain = float(jax.jit(lambda p: f(p)[0])(p0))
    assert abs(float(value) - plain) <= 1e-10 * abs(plain)       # the one traced function has the stage too
    value_of = lambda p: float(gradient.value(f, p)[0])
    for i in range(p0.coef.shape[0]):
        h = 1e-5
        e = jnp.zeros_like(p0.coef).at[i].set(h)
        fd = (value_of(p0._replace(coef=p0.coef + e)) - value_of(p0._replace(coef=p0.coef - e))) / (2 * h)
        g = float(grad.coef[i])
        assert abs(g - fd) <= 1e-5 * max(abs(fd), 1e-2 * float(jnp.abs(grad.coef).max())), (i, g, fd)
