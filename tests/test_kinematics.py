"""Rigid kinematics, trajectories and the paper's kinematic tables (docs/conventions.md#adept-cycle-and-blends)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.robot import (check_cycle_reachable, check_reachable, cycle_preset, dgm, igm, jacobian, jacobian_dot,
                           make_robot, robot_preset)
from jaxflex.combinations import sample_combinations
from jaxflex.trajectory import time_grid, trajectory


@pytest.fixture(scope="module", params=["default", "table6"])
def preset(request):
    return robot_preset(request.param), cycle_preset(request.param)


def test_igm_dgm_roundtrip(preset):
    robot, cycle = preset
    rng = np.random.default_rng(0)
    pts = np.asarray(cycle.pick) + rng.uniform([0, -0.03], [0.35, 0.03], size=(50, 2))
    q = jax.vmap(lambda x: igm(robot, x))(jnp.asarray(pts))
    back = jax.vmap(lambda qq: dgm(robot, qq))(q)
    np.testing.assert_allclose(back, pts, atol=1e-13)


def test_jacobian_and_its_derivative_match_finite_differences(preset):
    robot, cycle = preset
    q = igm(robot, cycle.pick + jnp.array([0.1, 0.01]))
    jac = np.asarray(jacobian(robot, q))
    h = 1e-6
    fd = np.stack([(dgm(robot, q + h * e) - dgm(robot, q - h * e)) / (2 * h) for e in jnp.eye(2)], 1)
    np.testing.assert_allclose(jac, fd, rtol=1e-8, atol=1e-10)      # O(h^2) truncation
    qd = jnp.array([0.7, -1.3])
    jd = np.asarray(jacobian_dot(robot, q, qd))
    fd = (jacobian(robot, q + h * qd) - jacobian(robot, q - h * qd)) / (2 * h)
    np.testing.assert_allclose(jd, fd, rtol=1e-7, atol=1e-9)


def test_trajectory_derivatives_are_consistent(preset):
    """Task velocity/acceleration and joint rates/accelerations equal differences of the samples."""
    robot, cycle = preset
    path = make_path(cycle, "polar", 0.02, 0.03)
    tf = 0.4
    dt = 1e-6
    t = jnp.linspace(0.01, tf - 0.01, 41)
    f = jax.jit(lambda tt: trajectory(robot, path, make_profile("poly7"), tf, tt))
    a, b, c = f(t - dt), f(t), f(t + dt)
    np.testing.assert_allclose((c.x - a.x) / (2 * dt), b.xd, atol=1e-7)
    np.testing.assert_allclose((c.xd - a.xd) / (2 * dt), b.xdd, atol=1e-4)
    np.testing.assert_allclose((c.xdd - a.xdd) / (2 * dt), b.xddd, rtol=1e-5, atol=5e-2)
    np.testing.assert_allclose((c.q - a.q) / (2 * dt), b.qd, atol=1e-7)
    np.testing.assert_allclose((c.qd - a.qd) / (2 * dt), b.qdd, atol=1e-4)
    # the motors' rigid DGM reproduces the desired path
    np.testing.assert_allclose(jax.vmap(lambda q: dgm(robot, q))(b.q), b.x, atol=1e-13)


def test_batched_combinations_equal_single_calls():
    robot, cycle = robot_preset(), cycle_preset()
    t = time_grid(0.43, 200)
    batch, labels = sample_combinations(robot, cycle, 0.43, t)
    assert len(labels) == 12 and batch.q.shape == (12, 201, 2)
    single_fn = jax.jit(trajectory)
    for k in (0, 5, 11):
        blend, prof = labels[k]
        single = single_fn(robot, make_path(cycle, blend, 0.025), make_profile(prof), 0.43, t)
        np.testing.assert_allclose(batch.qdd[k], single.qdd, rtol=1e-12, atol=1e-10)


# paper Table 5 reference values (tf = 1 s, d = e = 25 mm); tolerance 0.5 % for Lamé and polar
TABLE5_TASK_ACC = {
    "lame": (7.78, 5.17, 6.89, 11.81),
    "polar": (7.04, 4.47, 5.96, None),   # trap_1_8 polar: 10.05-10.15 (max at a jump)
    "clothoid": (7.48, 5.06, 6.75, 11.57),
}


@pytest.fixture(scope="module")
def table5():
    t = time_grid(1.0, 20000)
    traj, labels = sample_combinations(robot_preset(), cycle_preset(), 1.0, t)
    acc = np.max(np.linalg.norm(np.asarray(traj.xdd), axis=-1), axis=1)
    return {lab: a for lab, a in zip(labels, acc)}


@pytest.mark.parametrize("blend", ["lame", "polar", "clothoid"])
def test_table5_task_accelerations(table5, blend):
    for prof, ref in zip(("poly7", "bang_bang", "trap_1_4", "trap_1_8"), TABLE5_TASK_ACC[blend]):
        val = table5[(blend, prof)]
        if ref is None:
            # reference range 10.05-10.15, quoted to 2 decimals (the sampled grid hits the right limit
            # at the acceleration jump, where the supremum 10.1507 sits)
            assert 10.045 <= val < 10.155, val
        else:
            # references rounded to 2 decimals: 0.5 % (Lamé/polar) and rounding for the clothoid
            assert abs(val / ref - 1) < 0.005, (blend, prof, val, ref)


def test_table6_joint_accelerations_with_table6_preset():
    """Paper Table 6, Lamé column: 25.0858, 16.4343, 21.8879, 37.432 rad/s^2 (used only as the
    comparison reference of this acceptance test). The paper's values match a 1 ms second
    difference of the joint angles within 1 %; the exact maximum differs by up to 1.8 % (trap_1_8,
    where the maximum sits at the acceleration jump)."""
    robot, cycle = robot_preset("table6"), cycle_preset("table6")
    paper = np.array([25.0858, 16.4343, 21.8879, 37.432])
    profiles = ("poly7", "bang_bang", "trap_1_4", "trap_1_8")
    t = jnp.arange(0.0, 1.0005, 1e-3)
    traj, _ = sample_combinations(robot, cycle, 1.0, t, blends=("lame",), profiles=profiles)
    q = np.asarray(traj.q)
    fd = np.max(np.abs(q[:, 2:] - 2 * q[:, 1:-1] + q[:, :-2]) / 1e-6, axis=(1, 2))
    np.testing.assert_allclose(fd, paper, rtol=0.01)
    exact, _ = sample_combinations(robot, cycle, 1.0, time_grid(1.0, 20000), blends=("lame",),
                                   profiles=profiles)
    np.testing.assert_allclose(np.max(np.abs(np.asarray(exact.qdd)), axis=(1, 2)), paper, rtol=0.018)


def test_reachability_errors_name_point_and_arm():
    robot = robot_preset()
    far = cycle_preset().__class__(pick=jnp.array([-0.5, 0.6]), place=jnp.array([0.5, 0.6]),
                                   h=jnp.asarray(0.025), lift=jnp.array([0.0, 1.0]))
    with pytest.raises(ValueError, match=r"pick point \(-0.5000, 0.6000\) m is unreachable by arm 1"):
        check_cycle_reachable(robot, far)
    # a = 0.5 m: with both distal links horizontal (elbows at x = -/+ l2, same height as the end
    # effector) the distal links are collinear: a parallel (type II) singularity
    robot2 = make_robot(a=0.5, modes=(1, -1), assembly=1)
    y = np.sqrt(0.24**2 - (0.5 - 0.38079) ** 2)
    with pytest.raises(ValueError, match="parallel singularity"):
        check_reachable(robot2, np.array([[0.0, y]]))
    check_reachable(robot2, np.array([[0.0, y + 0.02]]))     # away from it: fine
