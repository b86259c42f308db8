"""Optimization: gradients through the rollout vs finite differences, design decoding, the loop."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex.designs import design
from jaxflex.optimize.gradient import value_and_grad_fwd
from jaxflex.optimize.loop import OptimizerConfig, minimize
from jaxflex.optimize.objective import DesignObjective, Params, Scales, decode, encode, stack_robots
from jaxflex.path import make_path
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import default_grid

TF, DWELL = 0.43, 0.1


def _central(f, x, i, h):
    e = jnp.zeros_like(x).at[i].set(h)
    return (f(x + e) - f(x - e)) / (2 * h)


def test_models_one_at_a_time_give_the_vmapped_values_and_gradients(monkeypatch):
    """``objective.over_models`` runs more than ``VMAP_MODELS`` models one at a time (lax.map) with the
    per-model function rematerialized in the backward pass. That is a memory layout, not a change of
    the objective: on a per-model function with a recurrence (a scan, like the rollout), a closed-over
    differentiated input (like the law's samples) and a None argument (the first-order model), the
    value and the reverse-mode gradient equal the vmapped ones to round-off (1e-12 relative)."""
    from jaxflex.optimize import objective as obj

    rng = np.random.default_rng(3)
    tables, k = jnp.asarray(rng.normal(size=(5, 7, 3))), 5

    def total(theta):
        drive = jnp.sin(theta[1] * jnp.arange(1.0, 8.0))        # closed over, like the motion samples

        def one(tab, robot):
            assert robot is None
            def step(x, row):
                x = 0.9 * x + jnp.tanh(row * theta[:3]) * drive[0] + row * x * x
                return x, jnp.sum(x * x)
            x, e = jax.lax.scan(step, jnp.zeros(3), tab * drive[:, None])
            return {"energy": jnp.sum(e), "end": x}
        t = obj.over_models(one, tables, None)
        assert t["energy"].shape == (k,) and t["end"].shape == (k, 3)
        w = jnp.arange(1.0, k + 1.0)                               # the models' order matters
        return jnp.log(jnp.sum(w * t["energy"])) + jnp.sum(w[:, None] * t["end"] ** 2)

    theta = jnp.asarray([0.3, -0.2, 0.5])
    assert k > obj.VMAP_MODELS                                  # the default runs them one at a time
    one_by_one = jax.value_and_grad(total)(theta)
    monkeypatch.setattr(obj, "VMAP_MODELS", k)
    vmapped = jax.value_and_grad(total)(theta)
    np.testing.assert_allclose(one_by_one[0], vmapped[0], rtol=1e-12)
    np.testing.assert_allclose(one_by_one[1], vmapped[1], rtol=1e-12)
    assert float(jnp.max(jnp.abs(vmapped[1]))) > 1e-3           # a gradient that could differ


@pytest.mark.xdist_group("commands")
def test_law_gradient_matches_central_differences_full_6kg_rollout():
    """The law optimizer's own gradient (``loop.value_and_grad`` on the law objective as ``train_law``
    builds it: reverse mode, second-order model, tables fixed) w.r.t. the motion-law coefficients
    through a full 6 kg rollout (motion + dwell, default grid, torque penalty active) vs central
    differences: relative error < 1e-5 (float64; FD step 1e-5 on O(1) coefficients: the tables are
    local cubics in the arc length, C0 at their nodes, and the samples s(t) move across them with
    the law, so a 1e-4 step can straddle a kink (errors up to 5e-5); at 1e-5 the measured errors are
    <= 6e-7). The program is the one ``jaxflex optimize --law-only --train nominal`` compiles."""
    from jaxflex.optimize.loop import value_and_grad
    from jaxflex.engine import LawEvaluator
    from jaxflex.optimize.config import StudyConfig
    from jaxflex.optimize.training import law_objective, training_models

    robot, cycle = robot_preset("default"), cycle_preset()
    models = training_models(robot, [6.0], "nominal")
    config = StudyConfig().train.with_optimizer(label="law")    # the command's objective
    path = make_path(cycle, "lame", 0.025)
    grid = default_grid(robot, [TF], DWELL)
    coef = jnp.asarray([1.0, 1.3, 0.8, 1.1, 0.9, 1.2])
    scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), jnp.full(1, jnp.inf), jnp.ones(1))
    evaluator = LawEvaluator(models, path, TF, DWELL, grid)
    f = law_objective(evaluator, scales, config)
    torque = float(value_and_grad(f, coef)[0][1].torque[0])
    # a bound 1 % below the peak torque: the penalty term is on, and its size comparable to the rest
    scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), jnp.full(1, 0.99 * torque), jnp.ones(1))
    f = law_objective(evaluator, scales, config)
    (value, aux), grad = value_and_grad(f, coef)
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
    # the objective's rollout (``rollout.run``, one traced function inside the gradient) and the
    # evaluation engine's (the same stages as three programs: first pass, remainder, last pass) give
    # the same metrics: measured within 6e-14, while between the engine's programs the continuity
    # correction lost or the remainder added twice moves them by 3e-2, the remainder 5 % off by 1.5e-3
    from jaxflex.profiles import shaped
    ev = evaluator(shaped(coef, config.order))
    for k, v in aux.metrics.items():
        assert float(v[0]) == pytest.approx(float(ev[k][0]), rel=1e-9), (k, float(v[0]), float(ev[k][0]))
    value_of = lambda c: float(value_and_grad(f, c)[0][0])
    for i in range(coef.shape[0]):
        fd = float(_central(value_of, coef, i, 1e-5))
        assert abs(float(grad[i]) - fd) <= 1e-5 * max(abs(fd), 1e-2 * float(jnp.abs(grad).max())), \
            (i, float(grad[i]), fd)


def test_forward_mode_gradient_equals_reverse_mode():
    """``value_and_grad_fwd`` (the optimizer's ``OneProgram(mode="forward")``) gives reverse mode's value and
    gradient on a pytree of parameters, with the aux output passed through."""
    def f(p):
        x, y = p["x"], p["y"]
        v = jnp.sum(jnp.sin(x) * jnp.exp(0.3 * y)) + jnp.sum(x**3) * y[0]
        return v, {"v2": 2 * v}

    p = {"x": jnp.asarray([0.3, -1.2, 0.7]), "y": jnp.asarray([0.5, 2.0, -0.4])}
    (v_f, aux_f), g_f = jax.jit(value_and_grad_fwd(f))(p)
    (v_r, aux_r), g_r = jax.jit(jax.value_and_grad(f, has_aux=True))(p)
    np.testing.assert_allclose(float(v_f), float(v_r), rtol=1e-15)
    np.testing.assert_allclose(float(aux_f["v2"]), float(aux_r["v2"]), rtol=1e-15)
    for k in p:
        np.testing.assert_allclose(np.asarray(g_f[k]), np.asarray(g_r[k]), rtol=1e-13)


def test_decode_keeps_blends_within_the_legs_and_encode_inverts_it():
    cycle = cycle_preset()
    x = design(d=0.02, e=0.05, n=4.0, coef=[1.0, 2.0], d2=0.01, e2=0.12, n2=2.5)   # asymmetric corners
    back = decode(cycle, encode(cycle, x))
    for a, b in zip(back, x):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    far = decode(cycle, Params(blend=jnp.asarray([30.0, 30.0, -30.0, -30.0, 30.0, 30.0]), coef=jnp.ones(2)))
    assert far.d.shape == far.e.shape == far.n.shape == (2,)
    assert np.all((0 < far.d) & (far.d <= cycle.h)) and np.all((0 < far.e) & (far.e <= 0.5 * cycle.l))
    assert np.all((2.0 <= far.n) & (far.n <= 8.0))
    make_path(cycle, "lame", *(float(v[i]) for i in range(2) for v in (far.d, far.e, far.n)))   # a valid path


def test_combine_is_zero_for_the_reference_and_log_scaled():
    """J = 0 when every model equals its reference; 100x less energy and mean-square amplitude (10x
    less amplitude) gives log(1/100); the torque penalty starts at the bound."""
    from jaxflex.metrics import Terms
    from jaxflex.optimize.objective import combine

    scales = Scales(jnp.asarray([2.0, 3.0]), jnp.asarray([5.0, 7.0]), jnp.asarray(10.0))
    terms = Terms(energy=scales.energy, dwell_ms=scales.dwell_ms, torque=jnp.asarray([9.0, 10.0]), metrics={})
    assert abs(float(combine(terms, scales))) < 1e-15
    small = terms._replace(energy=scales.energy / 100, dwell_ms=scales.dwell_ms / 100)
    np.testing.assert_allclose(float(combine(small, scales)), np.log(0.01), rtol=1e-14)
    over = terms._replace(torque=jnp.asarray([11.0, 10.0]))              # 10 % above the bound
    np.testing.assert_allclose(float(combine(over, scales, torque_weight=1e3)), 1e3 * 0.1**2, rtol=1e-12)


def test_minimize_is_deterministic_and_resumes_from_a_checkpoint(tmp_path):
    """20 steps in one run equal 10 steps, a checkpoint, and 10 more in a new call."""
    target = jnp.asarray([1.0, -2.0, 0.5])
    f = lambda p: (jnp.sum((p["x"] - target) ** 2) + 0.1 * jnp.sum(p["x"] ** 4), {"x": p["x"]})
    p0 = {"x": jnp.zeros(3)}
    full = minimize(f, p0, config=OptimizerConfig(steps=20, learning_rate=0.1, progress=False, patience=100))
    ck = tmp_path / "ck.npz"
    minimize(f, p0, config=OptimizerConfig(steps=10, learning_rate=0.1, progress=False, checkpoint=ck, patience=100))
    resumed = minimize(f, p0, config=OptimizerConfig(steps=20, learning_rate=0.1, progress=False, checkpoint=ck,
                                                     patience=100))
    np.testing.assert_array_equal(resumed.params["x"], full.params["x"])
    assert [h for h in resumed.history] == [h for h in full.history]
    assert full.value < float(f(p0)[0])


@dataclasses.dataclass(frozen=True)
class _Quartic:
    """A small objective described by its fields (what a memo of optimizations needs)."""

    weight: float = 0.1

    def __call__(self, p, target):
        return jnp.sum((p - target) ** 2) + self.weight * jnp.sum(p**4), {"p": p}


def test_minimize_memo_loads_a_finished_run_with_the_same_inputs_only(tmp_path):
    """A run whose objective, start, arguments and schedule were all seen before is loaded from the
    memo (its recorded wall times come back, no step runs); a new argument value, objective field or
    step count runs and is stored apart; a plain function cannot be memoized."""
    memo, target = tmp_path / "memo", jnp.asarray([1.0, -2.0, 0.5])
    cfg = OptimizerConfig(steps=15, learning_rate=0.1, progress=False, patience=100, decay=True, memo=memo)
    first = minimize(_Quartic(), jnp.zeros(3), args=(target,), config=cfg)
    again = minimize(_Quartic(), jnp.zeros(3), args=(target,), config=cfg)
    assert again.times == first.times and again.history == first.history      # loaded, not run again
    np.testing.assert_array_equal(again.params, first.params)
    assert again.value == first.value and again.steps_run == 15 and again.stopped == "steps"
    assert len(list(memo.glob("*.npz"))) == 1
    other = minimize(_Quartic(), jnp.zeros(3), args=(target + 1e-12,), config=cfg)
    assert other.times != first.times and len(list(memo.glob("*.npz"))) == 2
    minimize(_Quartic(0.2), jnp.zeros(3), args=(target,), config=cfg)
    minimize(_Quartic(), jnp.zeros(3), args=(target,), config=dataclasses.replace(cfg, steps=14))
    assert len(list(memo.glob("*.npz"))) == 4
    with pytest.raises(ValueError, match="frozen dataclass"):
        minimize(lambda p, t: _Quartic()(p, t), jnp.zeros(3), args=(target,), config=cfg)


def test_minimize_reuses_its_compilation_for_new_argument_values():
    """The same objective with new traced ``args`` (e.g. another tf or payload set) compiles once,
    and each run converges to its own minimum."""
    from jaxflex.optimize import gradient

    def f(p, target):
        return jnp.sum((p - target) ** 2), {}

    before = gradient.cache_size()
    cfg = OptimizerConfig(steps=300, learning_rate=0.1, progress=False, patience=300)
    a = minimize(f, jnp.zeros(2), args=(jnp.asarray([1.0, 2.0]),), config=cfg)
    b = minimize(f, jnp.zeros(2), args=(jnp.asarray([-1.0, 0.5]),), config=cfg)
    # the schedule (warm-up, then cosine decay) and another rate and length: still the same program
    minimize(f, jnp.zeros(2), args=(jnp.asarray([0.0, 0.0]),),
             config=OptimizerConfig(steps=30, learning_rate=0.02, progress=False, patience=300, decay=True))
    assert gradient.cache_size() == before + 1
    np.testing.assert_allclose(a.params, [1.0, 2.0], atol=1e-2)     # Adam at lr 0.1: within 1e-2
    np.testing.assert_allclose(b.params, [-1.0, 0.5], atol=1e-2)


def test_learning_rate_schedule_warms_up_then_decays_to_the_floor():
    """The optax schedule: linear warm-up over the first 10 % of the steps from rate/warm to the
    rate, cosine decay reaching DECAY_FLOOR x rate one past the last step; constant without decay."""
    from jaxflex.optimize.loop import DECAY_FLOOR, learning_rate_at

    lr, steps = 0.05, 100
    rates = np.array([learning_rate_at(k, steps, lr, True) for k in range(steps + 1)])
    np.testing.assert_allclose(rates[:10], lr * np.arange(1, 11) / 10, rtol=1e-12)     # warm-up
    np.testing.assert_allclose(rates[10], lr, rtol=1e-12)
    assert np.all(np.diff(rates[10:]) < 0)                                             # decays
    np.testing.assert_allclose(rates[55], lr * (DECAY_FLOOR + (1 - DECAY_FLOOR) / 2), rtol=1e-12)  # half-way
    np.testing.assert_allclose(rates[steps], DECAY_FLOOR * lr, rtol=1e-12)
    assert learning_rate_at(37, steps, lr, False) == lr


def test_minimize_does_not_stop_early_on_negative_objectives():
    """Log-scale objectives cross zero: the plateau test must still see progress below zero."""
    f = lambda p: (jnp.log(1e-6 + jnp.sum((p - 3.0) ** 2)), {})
    r = minimize(f, jnp.zeros(2), config=OptimizerConfig(steps=400, learning_rate=0.05, progress=False, patience=20))
    assert r.value < -5.0, (r.value, r.steps_run, r.stopped)        # |p - 3| < 0.06


@pytest.mark.xdist_group("commands")
def test_the_optimizers_own_gradient_matches_central_differences():
    """The gradient the optimizer steps with (``staged.Staged`` on the design objective exactly as
    ``train_design`` builds it: reverse mode through the staged programs;
    second-order model, tables rebuilt from the workspace, default grid, the default smoothstep
    blends, the studies' power mean of order 8) over two models, the nominal 0.1 kg and 6 kg ones,
    with the torque penalty active on the 6 kg model alone, w.r.t. every design parameter - the six
    blend parameters (d, e of both corners, asymmetric, through the smoothstep's warp solve; n, which
    that family ignores, has a zero gradient) and the six law coefficients - against central
    differences of the same objective (``Staged.value``: the same forward programs). FD step 1e-5
    on O(1) parameters (the workspace tables are local bicubics, C0 across their 5 mm cells: a 1e-4
    step can straddle a cell boundary of some path node and errs by up to 5e-5, while at 1e-5 the
    rounding noise of the rollout, ~1e-9 of the objective, reaches 5e-5 on the smallest
    components): relative error < 1e-4, or 1e-3 of the largest component for the near-zero ones. A
    wrong derivative rule anywhere in the chain (custom JVPs, the remainder, the table rebuild, the
    staged backward passes and their combination over the models, the torque penalty's row) shows as
    errors of percent. The staged programs do not depend on the number of models: one model reuses
    them. The programs are the ones ``jaxflex optimize --train nominal`` compiles, so the command and
    this check share them."""
    from jaxflex.optimize import staged
    from jaxflex.optimize.config import StudyConfig
    from jaxflex.optimize.training import Training, design_objective, training_models
    from jaxflex.problem import Timing

    gradient = staged.Staged()
    robot, cycle = robot_preset("default"), cycle_preset()
    models = training_models(robot, [0.1, 6.0], "nominal")
    config = StudyConfig().train                               # the command's objective
    grid = default_grid(robot, [TF], DWELL)
    timing = Timing(TF, DWELL, grid)
    p0 = encode(cycle, design(d=0.02, e=0.03, n=3.5, coef=[1.0, 1.2, 0.9, 1.1, 0.8, 1.05], d2=0.022, e2=0.04,
                              n2=3.2))
    refs = dict(energy=jnp.asarray([1e-4, 1e-3]), dwell_ms=jnp.asarray([1e-11, 1e-10]))
    training = Training(models, cycle, timing, Scales(**refs, torque_bound=jnp.full(2, jnp.inf)))
    f = design_objective(training, config)
    torque = np.asarray(gradient.value(f, p0)[1].torque)
    # a bound 1 % below the 6 kg model's peak torque: its penalty term is on, and its size comparable to
    # the rest; the 0.1 kg model stays within its bound
    bound = jnp.asarray([1.01 * torque[0], 0.99 * torque[1]])
    f = design_objective(training._replace(scales=Scales(**refs, torque_bound=bound), workspaces=f.workspaces),
                         config)
    (value, aux), grad = gradient.value_and_grad(f, p0)
    programs = staged.cache_size()
    np.testing.assert_allclose(np.asarray(aux.torque), torque, rtol=1e-12)
    value_of = lambda p: float(gradient.value(f, p)[0])
    assert abs(value_of(p0) - float(value)) <= 1e-12 * abs(float(value))
    for field in ("blend", "coef"):
        x = getattr(p0, field)
        for i in range(x.shape[0]):
            h = 1e-5
            e = jnp.zeros_like(x).at[i].set(h)
            fd = (value_of(p0._replace(**{field: x + e})) - value_of(p0._replace(**{field: x - e}))) / (2 * h)
            g = float(getattr(grad, field)[i])
            assert abs(g - fd) <= 1e-4 * max(abs(fd), 1e-3 * float(jnp.abs(getattr(grad, field)).max())), \
                (field, i, g, fd)
    one = training_models(robot, [6.0], "nominal")
    one_scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), bound[1:])
    f1 = design_objective(Training(one, cycle, timing, one_scales), config)
    (value1, aux1), _ = gradient.value_and_grad(f1, p0)
    np.testing.assert_allclose(np.asarray(aux1.torque), torque[1:], rtol=1e-12)
    assert staged.cache_size() == programs + 1, "a new number of models compiled more than its combination"


@pytest.mark.slow
def test_the_staged_design_gradient_equals_the_one_program_gradient():
    """The staged value and gradient (``optimize.staged``) against ``jax.value_and_grad`` of the whole
    design objective as one program (``gradient.OneProgram``), on three models of
    the uncertainty box with the power mean of order 8 and the torque bound active on one of them:
    the same numbers up to the round-off of two different programs (the rollout's ~1e-12, amplified
    by the log and the power mean): value and terms to 1e-9 relative, gradient to 1e-9 of its
    largest component. About a minute (the one-program gradient's compile)."""
    from jaxflex.optimize.gradient import OneProgram
    from jaxflex.optimize.staged import Staged
    from jaxflex.optimize.config import StudyConfig
    from jaxflex.optimize.training import Training, design_objective, subset, training_models
    from jaxflex.problem import Timing

    robot, cycle = robot_preset("default"), cycle_preset()
    models = subset(training_models(robot, [6.0], "box"), [0, 4, 8])
    config = StudyConfig().train
    grid = default_grid(robot, [TF], DWELL)
    p0 = encode(cycle, design(d=0.02, e=0.03, n=3.5, coef=[1.0, 1.2, 0.9, 1.1, 0.8, 1.05], d2=0.022, e2=0.04,
                              n2=3.2))
    scales = Scales(jnp.full(3, 1e-3), jnp.full(3, 1e-10), jnp.full(3, jnp.inf))
    training = Training(models, cycle, Timing(TF, DWELL, grid), scales)
    f = design_objective(training, config)
    torque = np.asarray(Staged().value_and_grad(f, p0)[0][1].torque)
    bound = jnp.asarray(torque * np.array([1.01, 0.99, 1.01]))
    f = design_objective(training._replace(scales=scales._replace(torque_bound=bound), workspaces=f.workspaces),
                         config)
    (v, aux), g = Staged().value_and_grad(f, p0)
    (v1, aux1), g1 = OneProgram().value_and_grad(f, p0)
    assert abs(float(v) - float(v1)) <= 1e-9 * abs(float(v1))
    for a, b in zip(jax.tree_util.tree_leaves(aux), jax.tree_util.tree_leaves(aux1)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-300)
    flat = lambda t: np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(t)])
    assert np.max(np.abs(flat(g) - flat(g1))) <= 1e-9 * np.max(np.abs(flat(g1)))


@pytest.mark.slow
@pytest.mark.parametrize("tables", ["workspace", "exact"])
def test_design_gradient_wrt_blend_parameters_matches_central_differences(tables):
    """Gradient w.r.t. the blend parameters (u_d, u_e, u_n of both corners) through the table rebuild
    and the rollout vs central differences of the same objective, relative error < 1e-5: with the
    workspace tables (what the optimizer differentiates, ~2 min) and with the exact tables built
    from the model (~5 min to compile)."""
    from jaxflex.tables import build_workspaces

    robot, cycle = robot_preset("default"), cycle_preset()
    robots = stack_robots([robot.replace(payload=6.0)])
    ws = build_workspaces(robots, cycle) if tables == "workspace" else None
    grid = default_grid(robot, [TF], DWELL)
    scales = Scales(jnp.full(1, 1e-3), jnp.full(1, 1e-10), jnp.asarray(jnp.inf))
    p0 = encode(cycle, design(d=0.02, e=0.03, n=3.5, coef=[1.0, 1.2, 0.9, 1.0], d2=0.022, e2=0.04, n2=3.2))
    f = jax.jit(lambda p: DesignObjective(robots, cycle, jnp.asarray(TF), jnp.asarray(DWELL), scales, ws, grid=grid,
                                          blend="lame")(p))
    (_, _), grad = jax.jit(jax.value_and_grad(f, has_aux=True))(p0)
    for i in range(6):
        fd = float(_central(lambda u: f(Params(u, p0.coef))[0], p0.blend, i, 1e-4))
        assert abs(float(grad.blend[i]) - fd) <= 1e-5 * abs(fd), (i, float(grad.blend[i]), fd)


# with the commands: the default model on the default grid, whose coefficient and rollout programs
# the sweep and optimize commands compile in that process (nothing new to compile here)
@pytest.mark.xdist_group("commands")
def test_paper_sweep_on_training_models_matches_run_sweep_and_chunks_do_not_change_metrics(monkeypatch):
    """The study's paper sweep (``paper_sweep``: one evaluator per blend on the training models)
    gives the nominal model the metrics of ``run_sweep`` (same model, different callers of the
    engine: equal to rounding), and an evaluator that simulates its models in padded batches
    (``chunk``: the nine perturbed models as 5 + 4 and one padding copy) returns, for the five
    models it shares with the training set, the training evaluator's metrics; an evaluator that
    does not keep its tables (``keep=False``, models in groups) returns the same metrics for
    several laws, bit for bit. The default 6 kg
    model, grid and 0.43 s motion of ``jaxflex optimize``."""
    from jaxflex import engine
    from jaxflex.engine import LawEvaluator
    from jaxflex.model_sets import model_set
    from jaxflex.optimize.evaluation import paper_sweep
    from jaxflex.optimize.training import PERTURB_E, PERTURB_PAYLOAD, nominal_indices, training_models
    from jaxflex.profiles import make_profile
    from jaxflex.sweep import Case, SweepConfig, run_sweep

    robot, cycle = robot_preset("default"), cycle_preset()
    grid = default_grid(robot, [TF], DWELL)
    blends, laws = ("lame",), ("poly7", "trap_1_4")
    models = training_models(robot, [6.0], "spanning")
    sweep = paper_sweep(models, cycle, TF, SweepConfig(blends=blends, profiles=laws, dwell=DWELL, grid=grid))
    res = run_sweep(robot, cycle, [Case(6.0, TF)], SweepConfig(blends=blends, profiles=laws, grid=grid, timed=False,
                                                      estimate=False))
    assert np.isnan(res.run_s) and res.compile_s > 0          # untimed: one sweep, no timed rerun
    i = int(nominal_indices(models, [6.0])[0])
    for name in ("dwell_residual_mm", "max_torque_nm", "residual_energy", "max_deflection_mm"):
        assert sweep.metrics[name].shape == (1, 2, 5)
        np.testing.assert_allclose(sweep.metrics[name][..., i], res.metrics[name][..., 0], rtol=1e-9, err_msg=name)
    # the perturbation corners differ from the nominal model (the sweep really ran on each model)
    dw = sweep.metrics["dwell_residual_mm"]
    assert np.all(np.abs(dw[..., 1:] / dw[..., :1] - 1) > 1e-3)
    perturbed = model_set(robot, [6.0], stiffness=PERTURB_E, payload_scale=PERTURB_PAYLOAD)
    chunked = LawEvaluator(perturbed, sweep.evaluators["lame"].path, TF, DWELL, grid)(make_profile("poly7"))
    same = [4, 0, 2, 6, 8]      # the spanning models' places in the perturbed set (E outer, payload inner)
    assert [perturbed.labels[k] for k in same] == list(models.labels)
    for name, v in chunked.items():
        assert v.shape == (9,)
        np.testing.assert_allclose(v[same], sweep.metrics[name][0, 0], rtol=1e-12, atol=0, err_msg=name)
    # an evaluator that does not keep its tables builds the same ones at every call: the same metrics
    streamed = LawEvaluator(perturbed, sweep.evaluators["lame"].path, TF, DWELL, grid, keep=False)
    kept = LawEvaluator(perturbed, sweep.evaluators["lame"].path, TF, DWELL, grid)
    monkeypatch.setattr(engine, "STREAM_MODELS", 4)          # groups of 4 + 4 + 1 models
    laws = [make_profile("poly7"), make_profile("trap_1_8")]
    for got, want in zip(streamed.metrics_many(laws), [chunked, kept(laws[1])]):
        for name, v in got.items():
            np.testing.assert_array_equal(v, want[name], err_msg=name)
    assert streamed.tables.values.mass.shape[0] == 9
    with pytest.raises(TypeError, match="chunk"):         # no option that does nothing
        LawEvaluator(perturbed, sweep.evaluators["lame"].path, TF, DWELL, grid, chunk=5)


def test_power_mean_objective_tends_to_the_worst_model_and_scales_are_absolute():
    """p = 1 is the weighted mean; a large power tends to the worst model (within w_min^(-1/p));
    the study's scales divide every model of a payload case by the same nominal reference."""
    from jaxflex.model_sets import model_set
    from jaxflex.metrics import Terms
    from jaxflex.optimize.objective import combine
    from jaxflex.optimize.training import scales_from_metrics

    scales = Scales(jnp.ones(3), jnp.ones(3), jnp.asarray(1e9), jnp.asarray([0.5, 0.25, 0.25]))
    r = jnp.asarray([1.0, 4.0, 2.0])                                   # per-model (E + A) / 2 = r
    terms = Terms(r, r, jnp.zeros(3), {})
    np.testing.assert_allclose(float(combine(terms, scales)), np.log(0.5 * 1 + 0.25 * 4 + 0.25 * 2), rtol=1e-14)
    np.testing.assert_allclose(float(combine(terms, scales, power=2.0)),
                               0.5 * np.log(0.5 * 1 + 0.25 * 16 + 0.25 * 4), rtol=1e-13)
    worst = float(combine(terms, scales, power=64.0))
    assert np.log(4.0) + np.log(0.25) / 64 - 1e-12 <= worst <= np.log(4.0) + 1e-12
    robot = robot_preset("default", n_bending=1, n_axial=1)
    ms = model_set(robot, [0.1, 6.0], stiffness=(0.95, 1.0), payload_scale=(1.0,))   # payload outer, then E
    ref = {"residual_energy": np.array([1.0, 2.0, 3.0, 4.0]), "dwell_residual_mm": np.array([0.1, 0.2, 0.3, 0.4])}
    s = scales_from_metrics(ref, 1.0, None, ms)
    # each model takes its payload's nominal model (E x1): 0.1 kg -> index 1, 6 kg -> index 3
    assert [i.payload for i in ms.ids] == [0.1, 0.1, 6.0, 6.0] and [i.stiffness_scale for i in ms.ids] == [0.95, 1.0] * 2
    np.testing.assert_allclose(np.asarray(s.energy), [2.0, 2.0, 4.0, 4.0])
    np.testing.assert_allclose(np.asarray(s.dwell_ms), np.array([0.2, 0.2, 0.4, 0.4]) ** 2 * 1e-6 / 2)


def test_a_study_record_rebuilds_the_studys_trajectories_bit_for_bit(tmp_path):
    """``jaxflex reproduce`` verifies the studies after them, in one process, from their JSON records
    (``experiments.optimize.trajectories_of``): the optimized path and law and the best paper path
    rebuilt from the record (``design_record``, through a JSON round trip) must be the study's own
    arrays, bit for bit, or the verification would check another trajectory. The workspace memo of
    the studies (``workspaces.remembered_workspaces``) is checked by the same principle in
    ``test_workspace.py``."""
    import json
    from types import SimpleNamespace

    from jaxflex.designs import Design, design_path
    from jaxflex.experiments.optimize import design_record, trajectories_of
    from jaxflex.profiles import profile_eval, shaped

    cycle = cycle_preset()
    x = Design(np.array([0.0215, 0.0231]), np.array([0.0302, 0.0357]), np.array([3.21, 3.43]),
               np.array([1.0, 1.17, 0.93, 1.0, 1.08]))
    paths = {"paper": make_path(cycle, "lame", 0.025), "optimized": design_path(cycle, x, "smoothstep")}
    law = shaped(jnp.asarray(x.coef), 3, name="optimized")
    study = SimpleNamespace(design=x, coef=x.coef, blend="lame", paths=paths,
                            candidates={"optimized": SimpleNamespace(law=law)})
    rec = json.loads(json.dumps({"blend": "lame", "best_paper": "trap_1_4", "design": design_record(study)}))
    (paper, _), (path, rebuilt) = trajectories_of(rec, cycle).values()
    for a, b in ((paths["paper"], paper), (paths["optimized"], path)):
        assert type(a) is type(b)
        for u, v in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))
    eta = jnp.linspace(0.0, 1.0, 101)
    for side in (1, -1):
        for u, v in zip(profile_eval(law, eta, side), profile_eval(rebuilt, eta, side)):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))


def test_remembered_workspaces_load_the_models_built_before_and_rebuild_the_others(tmp_path, monkeypatch):
    """The studies' workspace memo (``workspaces.remembered_workspaces``): a model whose tables a study
    built before is loaded, the others are built (as one stack) and kept; the result is the stack
    in the models' order, whichever were loaded; a damaged file is built again. The builder is
    replaced by a cheap one whose tables encode the payload, so the test checks which model's
    tables land where (that a stacked build gives each model the tables of a build alone, bit for
    bit, was measured separately: the 18 models of both payloads against two stacks of 9)."""
    from jaxflex.optimize import workspaces as study
    from jaxflex.workspace import workspace_shapes

    robot, cycle = robot_preset("default"), cycle_preset()
    built = []

    def fake_build(robots, cyc):
        payloads = np.atleast_1d(np.asarray(robots.payload, dtype=float))
        built.append(payloads.tolist())
        return jax.tree_util.tree_map(
            lambda s: jnp.asarray(np.stack([m * (1.0 + np.arange(np.prod(s.shape[1:])).reshape(s.shape[1:]))
                                            for m in payloads]).astype(s.dtype)),
            workspace_shapes(robots, cyc, models=len(payloads)))

    monkeypatch.setattr(study, "build_workspaces", fake_build)
    stack = lambda ms: stack_robots([robot.replace(payload=m) for m in ms])
    same = lambda a, b: all(np.array_equal(np.asarray(u), np.asarray(v))
                            for u, v in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))

    first = study.remembered_workspaces(stack([6.0, 0.1]), cycle, tmp_path)
    assert built == [[6.0, 0.1]] and same(first, fake_build(stack([6.0, 0.1]), cycle))
    built.clear()
    second = study.remembered_workspaces(stack([0.1, 2.0, 6.0]), cycle, tmp_path)
    assert built == [[2.0]], "only the model not built before is built"
    assert same(second, fake_build(stack([0.1, 2.0, 6.0]), cycle))
    files = sorted((tmp_path / study.WORKSPACE_MEMO).glob("*.npz"))
    assert len(files) == 3
    files[0].write_bytes(files[0].read_bytes()[:len(files[0].read_bytes()) // 2])      # cut short
    for f in files[1:]:
        f.write_bytes(b"damaged")
    built.clear()
    third = study.remembered_workspaces(stack([2.0, 0.1, 6.0]), cycle, tmp_path)
    assert built == [[2.0, 0.1, 6.0]] and same(third, fake_build(stack([2.0, 0.1, 6.0]), cycle))
