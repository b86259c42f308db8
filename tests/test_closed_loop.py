"""Trajectories judged under the servo (``jaxflex.optimize.closed_loop``): the controller's box, the
stability filter, and the design objective with the servo in the loop against the evaluation engine
and against finite differences."""

import numpy as np
import pytest

from jaxflex import servo as sv
from jaxflex.designs import design, design_path
from jaxflex.optimize import closed_loop as cl
from jaxflex.path import make_path
from jaxflex.profiles import shaped
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.sweep import default_grid
from jaxflex.uncertainty import Box, ModelId

CYCLE = cycle_preset()


def test_the_box_models_scale_the_gains_for_the_achieved_bandwidth_and_the_rotor():
    """Kp scales with the bandwidth factor squared and Kd with the factor (Kp = J w^2, Kd = 2 zeta J w);
    the rotor with the model's factor; the rate is the model's. The random set starts with the
    nominal model, is reproducible and stays inside both boxes."""
    robot = robot_preset("default", payload=6.0)
    nominal = sv.cycle_servo(robot, CYCLE, 15.0)
    s = cl.servo_of(nominal, cl.ServoModel(ModelId(6.0, rotor_scale=1.1), 0.8, 4000.0))
    np.testing.assert_allclose(s.kp, nominal.kp * 0.64, rtol=1e-14)
    np.testing.assert_allclose(s.kd, nominal.kd * 0.8, rtol=1e-14)
    assert float(s.rotor_inertia) == pytest.approx(0.011, rel=1e-14) and float(s.rate) == 4000.0
    which = cl.random_models(6.0, Box(), cl.ServoBox(), 50, seed=3)
    assert which[0] == cl.ServoModel(ModelId(6.0)) and len(which) == 51
    assert which == cl.random_models(6.0, Box(), cl.ServoBox(), 50, seed=3)
    assert all(0.8 <= w.fc_scale <= 1.2 and 4000 <= w.rate <= 16000 for w in which[1:])
    assert len(set(cl.corner_models(6.0, Box(), cl.ServoBox()))) == 32


def test_the_training_set_pairs_payload_and_rotor_and_the_scenarios_are_the_worst_stable_models():
    """The nine training models: the nominal one and eight corners with the rotor on the payload's
    side (a heavier payload with a heavier rotor: the feedforward's largest inertia error). The
    refinement's scenarios: the k largest residuals, largest first, unstable loops (NaN) and
    models already trained on left out."""
    train = cl.train_models(0.1, Box(), cl.ServoBox())
    assert train[0] == cl.ServoModel(ModelId(0.1)) and len(set(train)) == 9
    for w in train[1:]:
        assert np.sign(w.model.rotor_scale - 1) == np.sign(w.model.payload_scale - 1) != 0, w
        assert abs(w.model.rotor_scale - 1) == pytest.approx(Box().rotor, rel=1e-12)
    which = cl.random_models(0.1, Box(), cl.ServoBox(), 5, seed=2)
    r = np.array([1.0, np.nan, 3.0, 2.0, 5.0, 4.0])
    assert cl.worst_models(r, which, 3) == (which[4], which[5], which[2])
    assert cl.worst_models(r, which, 3, exclude=(which[5],)) == (which[4], which[2], which[3])
    assert cl.worst_models(r, which, 9) == tuple(which[i] for i in (4, 5, 2, 3, 0))     # never the NaN
    with pytest.raises(ValueError, match="residuals"):
        cl.worst_models(r[:3], which, 1)


def test_unstable_loops_of_the_box_are_found_and_left_out():
    """At 6 kg the sampled loop at 4 kHz is unstable from fc 18 Hz on (spectral radius 1.08: a mode
    growing by 10^71 over the run), while 15 Hz at 8 kHz is stable enough to simulate. ``stable``
    marks each model, and ``evaluate`` fills the unstable ones with NaN instead of refusing the set."""
    robot = robot_preset("default")
    nominal = sv.cycle_servo(robot.replace(payload=6.0), CYCLE, 15.0)
    which = (cl.ServoModel(ModelId(6.0)), cl.ServoModel(ModelId(6.0), 1.2, 4000.0),
             cl.ServoModel(ModelId(6.0), 1.2, 16000.0))
    models, servos = cl.model_robots(robot.replace(payload=6.0), CYCLE, nominal, which)
    path = make_path(CYCLE, "lame", 0.025)
    np.testing.assert_array_equal(cl.stable(models, servos, path, 0.53), [True, False, True])
    with pytest.raises(ValueError, match="unstable"):
        sv.check_stable(models.singles()[1], servos[1], path, 0.53)


@pytest.fixture(scope="module")
def small():
    """A 2 kg robot with one mode of each kind per link and a 0.1 s move: the closed-loop objective's
    programs compile in minutes instead of the 6 kg robot's longer ones."""
    robot = robot_preset("default", payload=2.0, n_bending=1, n_axial=1)
    tf, dwell = 0.1, 0.01
    x0 = design(0.02, 0.05, 3.0, np.ones(6), d2=0.02, e2=0.05, n2=3.0)
    which = (cl.ServoModel(ModelId(2.0)), cl.ServoModel(ModelId(2.0, 1.1, 0.95), 0.8, 16000.0))
    return robot, tf, dwell, default_grid(robot, [tf], dwell), x0, which


def test_the_closed_loop_objective_weighs_the_dwell_amplitude_alone_or_with_the_energy():
    """``closed_loop_scales``: with "dwell" the objective is the log of the power mean of A_k / A_ref
    (A the mean square dwell amplitude, A_ref = a^2 / 2 for the reference's residual a), 0 for the
    reference's own residual, and neither it nor its gradient depends on the energy at tf; with
    "energy+dwell" it is the perfect controller's residual (E_k / E_ref + A_k / A_ref) / 2; with
    "peak" the log of the power mean of P_k / a^2 (P the dwell's smooth maximum). To 1e-14
    relative: the same arithmetic in another order."""
    import jax
    import jax.numpy as jnp
    from jaxflex.metrics import Terms
    from jaxflex.optimize.objective import combine

    ref = {"residual_energy": np.array([2e-8]), "dwell_residual_mm": np.array([1e-3])}
    a_ref, e_ref = (1e-6) ** 2 / 2, 2e-8
    dwell_ms = jnp.asarray([a_ref, 0.01 * a_ref, 4 * a_ref])
    energy = jnp.asarray([5e-8, 1e-9, 3e-7])
    terms = Terms(energy=energy, dwell_ms=dwell_ms, torque=jnp.full(3, 10.0), metrics={})
    p = 8.0
    mean = lambda r: np.mean(np.asarray(r) ** p) ** (1 / p)
    dwell = cl.closed_loop_scales(ref, 3, 20.0, "dwell")
    np.testing.assert_allclose(float(combine(terms, dwell, power=p)), np.log(mean(dwell_ms / a_ref)), rtol=1e-14)
    alike = Terms(energy=energy, dwell_ms=jnp.full(3, a_ref), torque=jnp.full(3, 10.0), metrics={})
    assert abs(float(combine(alike, dwell, power=p))) < 1e-14
    g = jax.grad(lambda t: combine(t, dwell, power=p))(terms)
    assert np.all(np.asarray(g.energy) == 0.0) and np.all(np.asarray(g.dwell_ms) > 0)
    both = cl.closed_loop_scales(ref, 3, 20.0, "energy+dwell")
    np.testing.assert_allclose(float(combine(terms, both, power=p)),
                               np.log(mean((energy / e_ref + dwell_ms / a_ref) / 2)), rtol=1e-14)
    # "peak": the log of the power mean of P_k / a^2 (P the dwell's smooth maximum), neither the
    # energy nor the mean square in it or its gradient
    peak = jnp.asarray([0.5, 0.02, 3.0]) * (1e-6) ** 2
    with_peak = terms._replace(dwell_peak=peak)
    smooth = cl.closed_loop_scales(ref, 3, 20.0, "peak")
    np.testing.assert_allclose(float(combine(with_peak, smooth, power=p)), np.log(mean(peak / (1e-6) ** 2)),
                               rtol=1e-14)
    g = jax.grad(lambda t: combine(t, smooth, power=p))(with_peak)
    assert np.all(np.asarray(g.energy) == 0.0) and np.all(np.asarray(g.dwell_ms) == 0.0)
    assert np.all(np.asarray(g.dwell_peak) > 0)
    with pytest.raises(ValueError, match="objective must be one of"):
        cl.closed_loop_scales(ref, 3, 20.0, "energy")


@pytest.mark.slow
def test_the_closed_loop_objective_is_the_engines_closed_loop_and_its_gradient_the_finite_differences(small):
    """The design objective with the servo in the loop (flexible feedforward of the nominal model,
    each model its own servo) gives the evaluation engine's closed-loop dwell residual on every
    model to 1e-6 (the workspace tables' interpolation against the model's own), and its reverse-mode
    gradient matches central differences to 1e-5 relative (blend size, blend shape and a law
    coefficient) or 1e-6 absolute. The absolute part is the differences' own scatter: the objective
    (about 6.8) carries round-off of about 1e-13 through its rollouts, and steps of 3e-7 to 3e-5 give
    central differences that scatter by up to 1.2e-6 about the gradient (3.5e-7 at 1e-5, the step
    used; a gradient of 0.1 is then only 1e-5 relative)."""
    import jax
    from jaxflex.optimize.gradient import OneProgram
    from jaxflex.optimize.objective import decode

    robot, tf, dwell, grid, x0, which = small
    ref = {"residual_energy": np.array([1e-3]), "dwell_residual_mm": np.array([0.1])}
    obj, p0, kept = cl.closed_loop_objective(x0, robot, CYCLE, tf, dwell, grid, 30.0, which, ref, 1e4)
    assert kept == which
    run = jax.jit(lambda p: obj(p))                 # one compiled objective for the value and the differences
    value, terms = run(p0)
    path = design_path(CYCLE, decode(CYCLE, p0), "smoothstep")
    out = cl.evaluate({"x": cl.Trajectory(path, shaped(p0.coef, 3), "flexible")}, robot, CYCLE, tf, dwell, grid, 30.0,
                      which)
    np.testing.assert_allclose(np.asarray(terms.metrics["dwell_residual_mm"]), out["x"]["dwell_residual_mm"],
                               rtol=1e-6)
    (v2, _), g = OneProgram().value_and_grad(obj, p0)
    assert float(v2) == pytest.approx(float(value), rel=1e-12)
    eps, f = 1e-5, lambda p: run(p)[0]
    for field, i in (("blend", 0), ("blend", 1), ("coef", 2)):
        bump = lambda d: p0._replace(**{field: getattr(p0, field).at[i].add(d)})
        fd = (float(f(bump(eps))) - float(f(bump(-eps)))) / (2 * eps)
        assert float(getattr(g, field)[i]) == pytest.approx(fd, rel=1e-5, abs=1e-6)


def test_the_closed_loop_report_and_figure_render_a_study_record(tmp_path):
    """The reproduce section's text and figure from a closed-loop record (the keys
    ``closed_loop_study`` writes): every trajectory's row with its ratios, the unstable count, and a
    figure with one line per trajectory."""
    from jaxflex.experiments import closed_loop as exp
    from jaxflex.experiments.report import closed_loop_section

    row = lambda nominal, worst: {"nominal_um": nominal, "worst_um": worst, "p95_um": worst, "median_um": nominal,
                                  "max_torque_nm": 70.0, "unstable": 1, "box_worst_um": worst, "box_unstable": 2,
                                  "box_models": 5, "perfect_um": 3 * nominal, "perfect_max_torque_nm": 70.0,
                                  "feedforward": "rigid", "ratio_best_paper_nominal": 1.0, "ratio_best_paper_worst": 1.0}
    study = {"controller": {"fc": 40.0, "rate": 8000.0, "rotor": 0.01, "feedforward": "flexible"}, "samples": 2,
             "corners": True, "paper": {"40": {"best": "polar/poly7", "dwell_residual_um": {}}},
             "refined": {"history": [[0, 1.0], [1, -1.0]], "steps_run": 2},
             "fcs": {"40": {"optimized": row(0.25, 0.46), "polar/poly7 (best paper)": row(1.08, 1.74)}}}
    sweep = {"fcs": [15.0, 40.0], "dwell_residual_um": {"optimized": [1.3, 0.25], "polar/poly7": [9.5, 1.08],
                                                        "optimized, rigid feedforward": [2.0, 0.2]}}
    text = closed_loop_section({"cases": [{"dir": "closed_loop_6kg", "payload": 6.0, "tf": 0.43,
                                           "studies": {"40": study}, "sweep": sweep}]})
    assert "2 of the 5 models' loops unstable" in text and "objective (energy+dwell) 1.000 -> -1.000" in text
    assert "| optimized " in text and "closed_loop_6kg/residual_vs_fc.png" in text
    # the figure's caption says what the sweep measured: 9.5 / 1.3 and 1.08 / 0.25 below the paper's
    # best with the design's own (flexible) feedforward, 9.5 / 2 and 1.08 / 0.2 with the rigid one,
    # which does better at 40 Hz only
    assert ("from 15 to 40 Hz, the optimized design of the first table leaves 4.32x to 7.31x less than the better "
            "paper combination shown with the flexible feedforward it was refined with, and 4.75x to 5.4x less "
            "with the rigid one; the rigid one does better than its own at 40 Hz.*") in text
    assert "no advantage" not in text
    fig = exp.figure(sweep, study, "6 kg, 0.43 s")
    assert len(fig.axes[0].get_lines()) == 5          # three trajectories, two with a perfect-controller line
    fig.savefig(tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 1000


def test_the_refinements_training_sets_and_its_rounds_chain_the_designs(monkeypatch):
    """``training``: "fixed" is the nine models of ``train_models``, "corners" the nominal model and
    all 32 corners; anything else is refused before any rollout. ``rounds``: each refinement starts
    from the design the last one returned, with the settings given, and the record keeps every
    round (the study's rollouts are replaced here by stand-ins: what is checked is the chaining)."""
    fixed = cl.training_models(6.0, Box(), cl.ServoBox(), "fixed")
    assert fixed == cl.train_models(6.0, Box(), cl.ServoBox())
    every = cl.training_models(6.0, Box(), cl.ServoBox(), "corners")
    assert every[0] == cl.ServoModel(ModelId(6.0)) and len(set(every)) == 33
    assert set(every[1:]) == set(cl.corner_models(6.0, Box(), cl.ServoBox())) >= set(fixed[1:])
    with pytest.raises(ValueError, match="training must be one of fixed, corners"):
        cl.training_models(6.0, Box(), cl.ServoBox(), "all")

    robot = robot_preset("default")
    blends, profiles = ["lame", "polar"], ["poly7"]
    metrics = {"dwell_residual_mm": np.array([[2e-3], [1e-3]]), "residual_energy": np.ones((2, 1)),
               "max_torque_nm": np.array([[80.0], [70.0]])}
    monkeypatch.setattr(cl, "paper_under_servo", lambda *a, **k: (metrics, blends, profiles, ("polar", "poly7")))
    calls = []

    def fake_refine(x, *a, **k):
        calls.append((np.asarray(x.coef).copy(), k["training"], k["power"], k["learning_rate"]))
        x2 = x._replace(coef=np.asarray(x.coef) + 1.0)
        return x2, type("R", (), {"history": [(0, 1.0), (1, 0.5)], "steps_run": 1})(), fixed[:2]

    monkeypatch.setattr(cl, "refine", fake_refine)
    flat = {"dwell_residual_mm": np.array([1e-3]), "max_torque_nm": np.array([70.0])}
    monkeypatch.setattr(cl, "evaluate", lambda trs, *a, **k: {name: flat for name in trs})
    monkeypatch.setattr(cl, "_perfect", lambda *a, **k: flat)
    x0 = design(0.02, 0.05, 3.0, np.ones(6), d2=0.02, e2=0.05, n2=3.0)
    law = shaped(np.ones(6), 3)
    rec = cl.closed_loop_study(robot, CYCLE, 6.0, 0.43, 0.1, default_grid(robot, [0.43], 0.1), x0, law,
                               cl.Controller(15.0), fcs=(), steps=1, samples=0, corners=False, ruckig=False,
                               training="corners", power=16.0, learning_rate=0.02, rounds=3)
    assert [c[0][0] for c in calls] == [1.0, 2.0, 3.0]           # each round from the last one's design
    assert all(c[1:] == ("corners", 16.0, 0.02) for c in calls)
    assert len(rec["refined"]["rounds"]) == 3 and rec["refined"]["design"]["coef"][0] == 4.0
    assert rec["refined"]["training"] == "corners" and rec["refined"]["power"] == 16.0
    for bad, match in (({"rounds": 0}, "rounds"), ({"power": 0.0}, "power"), ({"training": "box"}, "training")):
        with pytest.raises(ValueError, match=match):
            cl.closed_loop_study(robot, CYCLE, 6.0, 0.43, 0.1, default_grid(robot, [0.43], 0.1), x0, law,
                                 cl.Controller(15.0), fcs=(), steps=1, **bad)
