"""Baselines and outputs of the optimization study that need no rollout: Ruckig timing, model sets,
the controller trajectory export."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex.experiments.optimize import trajectory_rows
from jaxflex.model_sets import model_set, place_first_mode_hz
from jaxflex.optimize.baselines import ruckig_limits, ruckig_samples
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.robot import cycle_preset, dgm, robot_preset
from jaxflex.simulate import Grid


def test_ruckig_profile_lasts_tf_and_respects_its_limits():
    pytest.importorskip("ruckig")
    length, tf = 0.384, 0.43
    v, a, j = ruckig_limits(length, tf)
    grid = Grid(coarse=64, fine=10, dwell_steps=10)
    smp, limits = ruckig_samples(length, tf, grid)
    s, ds, dds = (np.asarray(x) for x in smp.start)
    # starts at rest, ends at the target (left limit of the last step), monotone, within the limits
    assert s[0] == 0 and ds[0] == 0 and dds[0] == 0
    np.testing.assert_allclose(np.asarray(smp.end[0])[-1], length, atol=1e-12)
    np.testing.assert_allclose(np.asarray(smp.end[1])[-1], 0.0, atol=1e-9)
    assert np.all(np.diff(s) >= 0)
    assert ds.max() <= v * (1 + 1e-9) and np.abs(dds).max() <= a * (1 + 1e-9)
    # time scaling: limits scale as (c, c^2, c^3) with 1 / duration
    v2, a2, j2 = ruckig_limits(length, tf / 2)
    np.testing.assert_allclose([v2 / v, a2 / a, j2 / j], [2, 4, 8], rtol=1e-9)


def test_model_set_damping_ratio_at_first_mode():
    # one assumed mode per link: the same code path, a smaller program to compile
    robot, cycle = robot_preset("default", n_bending=1, n_axial=1), cycle_preset()
    ms = model_set(robot, [6.0], damping_ratio=0.01, cycle=cycle)
    beta = float(ms.robots.damping[0, 1])
    f1 = place_first_mode_hz(robot.replace(payload=6.0), cycle)
    np.testing.assert_allclose(beta * 2 * np.pi * f1 / 2, 0.01, rtol=1e-12)   # zeta = beta omega / 2
    ms = model_set(robot, [0.1, 6.0], stiffness=(0.95, 1.05), payload_scale=(0.9, 1.1))
    assert len(ms.labels) == 8
    np.testing.assert_allclose(np.asarray(ms.robots.payload), [0.09, 0.11, 0.09, 0.11, 5.4, 6.6, 5.4, 6.6])


def test_trajectory_csv_rows_follow_the_path_at_10khz():
    robot, cycle = robot_preset("default", payload=6.0), cycle_preset()
    path = make_path(cycle, "lame", 0.025)
    rows = trajectory_rows(robot, path, make_profile("poly7"), 0.43)
    assert rows.shape == (4301, 5)
    np.testing.assert_allclose(np.diff(rows[:, 0]), 1e-4, atol=1e-12)
    np.testing.assert_allclose(rows[0, 1:3], np.asarray(cycle.pick), atol=1e-12)
    np.testing.assert_allclose(rows[-1, 1:3], np.asarray(cycle.place), atol=1e-12)
    # joint angles are the rigid IGM of the positions (the forward model maps them back)
    for k in (0, 1234, 4300):
        np.testing.assert_allclose(np.asarray(dgm(robot, jnp.asarray(rows[k, 3:5]))), rows[k, 1:3], atol=1e-12)


def test_spanning_training_set_brackets_the_first_frequency_of_the_perturbed_models():
    """The spanning set (nominal and the four corners of the perturbation box) contains the models
    with the lowest and the highest first locked frequency of the nine perturbed models (E x
    0.95/1/1.05, payload x 0.9/1/1.1): training on it covers their range."""
    from jaxflex.optimize.training import training_models

    robot, cycle = robot_preset("default", n_bending=1, n_axial=1), cycle_preset()
    span = training_models(robot, [6.0], "spanning")
    assert len(span.labels) == 5 and span.labels[0] == "6 kg x1, E x1"
    np.testing.assert_allclose(np.asarray(span.robots.payload), [6.0, 5.4, 6.6, 5.4, 6.6])
    np.testing.assert_allclose(np.asarray(span.robots.young) / float(robot.young), [1.0, 0.95, 0.95, 1.05, 1.05])
    pert = training_models(robot, [6.0], "perturbed")
    f = lambda ms, k: place_first_mode_hz(jax.tree_util.tree_map(lambda a: a[k], ms.robots), cycle)
    span_f = [f(span, k) for k in range(5)]
    pert_f = [f(pert, k) for k in range(9)]
    assert min(span_f) == pytest.approx(min(pert_f), rel=1e-12) and max(span_f) == pytest.approx(max(pert_f), rel=1e-12)
    assert min(span_f) < span_f[0] < max(span_f)
    assert len(training_models(robot, [0.1, 6.0], "spanning").labels) == 10
    with pytest.raises(ValueError, match="training set"):
        training_models(robot, [6.0], "robust")


def test_nominal_indices_find_each_payloads_nominal_model_in_every_training_set():
    """The study reads the paper combinations' metrics of the nominal models out of the sweep on
    the training models: the index must be the model with the robot's stiffness and that payload."""
    from jaxflex.optimize.training import nominal_indices, training_models

    robot = robot_preset("default", n_bending=1, n_axial=1)
    for kind, expected in (("nominal", [0, 1]), ("spanning", [0, 5]), ("perturbed", [4, 13])):
        ms = training_models(robot, [0.1, 6.0], kind)
        idx = nominal_indices(ms, [0.1, 6.0])
        assert idx.tolist() == expected, kind
        assert [ms.labels[i] for i in idx] == ["0.1 kg x1, E x1", "6 kg x1, E x1"]
    with pytest.raises(ValueError, match="no nominal 3 kg model"):
        nominal_indices(training_models(robot, [6.0], "spanning"), [3.0])
