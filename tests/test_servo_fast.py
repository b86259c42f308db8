"""The fast model under the servo (``jaxflex.servo_simulate``): its sub-step maps against the matrix
functions by eigendecomposition, its agreement with the full nonlinear model under the same servo
(``jaxflex.reference_servo``), and the continuous limit (a fast sampled PD of growing bandwidth tends
to the prescribed motion)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex import servo as sv
from jaxflex.engine import LawEvaluator, sample_motion, sample_schedule
from jaxflex.metrics import metrics
from jaxflex.model_sets import model_set
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.robot import cycle_preset, igm, robot_preset
from jaxflex.servo_simulate import NODES, Carry, _Steps, _equilibrium, _lagrange, _march, _maps, _rest, closed_loop, feedforward_torques, servo_grid
from jaxflex.simulate import Grid
from jaxflex.sweep import default_grid
from jaxflex.tables import path_tables, servo_path_tables

CYCLE = cycle_preset()
PATH = make_path(CYCLE, "lame", 0.025)


@jax.jit
def _full_model_at_rest(robot, qa, kp):
    """The full model at rest at the motor reference qa under a PD of stiffness kp with the rigid
    feedforward: (feedforward, the motors' offset d solved by Newton on the full model's static
    torque, the torque balance left, the links' sag there, the linearization about the sag)."""
    from jaxflex.rigid import rigid_torques

    ff = rigid_torques(robot, qa, jnp.zeros(2), jnp.zeros(2))
    gap = lambda d: sv.static_torque(robot, qa + d) - ff + kp * d
    d = jax.lax.fori_loop(0, 3, lambda _, d: d - jnp.linalg.solve(jax.jacfwd(gap)(d), gap(d)), jnp.zeros(2))
    return ff, d, gap(d), mdl.static_equilibrium(robot, qa + d), sv.rest_linearization(robot, qa)


@pytest.mark.xdist_group("servo-rest")      # both payloads on one worker: one compile of the full model's side
@pytest.mark.parametrize("payload", [0.1, 6.0])
def test_the_closed_loop_at_rest_at_the_place_is_the_full_models(payload):
    """At the place, where every rollout ends and the dwell residual is measured, fc 15 Hz, rigid
    feedforward, the fast closed loop (the path tables and the servo tables at the path's end)
    against the full model:

    - its matrices against ``servo.rest_linearization`` (the full model's reduced equations
      differentiated with the motors free, about the static equilibrium under gravity; the tables
      linearize about the undeflected links, so the two differ by the sag's share: measured 1e-5
      (0.1 kg) and 7e-5 (6 kg) of the mass matrix, 3e-4 of the motors' block of the stiffness);
    - its static equilibrium (the dwell residual's reference): the motors sit off their reference
      by d where the full model's static torque at qa + d equals the feedforward minus Kp d,
      solved here by Newton's method, d agreeing to 1e-5 (0.1 kg) and 6e-5 (6 kg) of itself, and
      the links at that sag.

    A motor inertia, stiffness, gain or static force a few percent off misses by percents."""
    robot = robot_preset("default", payload=payload)
    s = sv.servo_from_bandwidth(robot, PATH, 15.0, rate=8000.0)
    r = sv.with_rotor(robot, s)
    qa = igm(r, jnp.asarray(CYCLE.place, dtype=float))
    m, k, c, force, *_ = jax.jit(_rest)(path_tables(r, PATH), servo_path_tables(r, PATH), PATH.length)
    ff, d, left, sag, (mass, damp, stiff) = _full_model_at_rest(r, qa, s.kp)
    mass, damp, stiff, m, k, c = (np.asarray(a) for a in (mass, damp, stiff, m, k, c))
    np.testing.assert_allclose(m, mass, rtol=0, atol=1e-3 * np.max(np.abs(mass)))
    np.testing.assert_allclose(m[:2, :2], mass[:2, :2], rtol=0, atol=1e-3 * np.max(np.abs(mass[:2, :2])))
    np.testing.assert_allclose(k, stiff, rtol=0, atol=1e-9 * np.max(np.abs(stiff)))
    np.testing.assert_allclose(k[:, :2], stiff[:, :2], rtol=0, atol=1e-3 * np.max(np.abs(stiff[:, :2])))
    np.testing.assert_allclose(c, damp, rtol=0, atol=1e-9 * np.max(np.abs(stiff)))
    z, _ = _equilibrium(jnp.asarray(k), force, s, ff)
    assert float(jnp.max(jnp.abs(left))) < 1e-9 * float(jnp.max(jnp.abs(ff)))
    np.testing.assert_allclose(np.asarray(z[:2]), np.asarray(d), rtol=0, atol=1e-3 * float(jnp.max(jnp.abs(d))))
    np.testing.assert_allclose(np.asarray(z[2:]), np.asarray(sag), rtol=0, atol=1e-3 * float(jnp.max(jnp.abs(sag))))


def test_the_fast_loops_free_response_at_rest_is_the_sampled_loops():
    """At rest at the place (6 kg, fc 15 Hz, 8 kHz), the fast closed loop's steps (``_march``: the
    PD law, the hold and the sub-step maps, one step per sample period) released from a motor
    offset, against ``servo.sampled_loop``'s transition matrix (the stability check's model: the
    plant's matrix exponential over the hold with u = -Kp z_a - Kd z_a', built from the full model's
    linearization): the same motion over 400 samples, measured to 3e-13 of the offset. A gain, a
    hold or a map a few percent off misses by percents."""
    robot = robot_preset("default", payload=6.0)
    s = sv.servo_from_bandwidth(robot, PATH, 15.0, rate=8000.0)
    r = sv.with_rotor(robot, s)
    qa = igm(r, jnp.asarray(CYCLE.place, dtype=float))
    count = 400

    @jax.jit
    def both(r, s, qa):
        mass, damp, stiff = sv.rest_linearization(r, qa)
        n = mass.shape[0]
        maps = jax.tree_util.tree_map(lambda a: a[None], _maps(mass, stiff, damp, 1.0 / s.rate))
        start, weights = _lagrange(jnp.zeros(()))              # the sample at each step's start
        zeros = lambda *shape: jnp.zeros((1, count) + shape)
        steps = _Steps(b=zeros(2 * n), f0=zeros(n), df=zeros(n), has=jnp.ones((1, count)),
                       start=jnp.broadcast_to(start, (1, count)),
                       weights=jnp.broadcast_to(weights, (1, count) + weights.shape), ff=zeros(2))
        x0 = jnp.zeros(2 * n).at[0].set(1e-4).at[1].set(-5e-5)
        _, (xs, _) = _march(Carry(x0, jnp.zeros(2), jnp.zeros(2), jnp.zeros(2)), maps, steps, s)
        loop = sv.sampled_loop(r, s, qa)                     # on [z, z' / w]: z's rows are the same
        ys = jax.lax.scan(lambda y, _: (loop @ y, y), x0, None, length=count)[1]
        return xs.reshape(count, -1)[:, :n], ys[:, :n]

    fast, sampled = (np.asarray(a) for a in both(r, s, qa))
    assert np.max(np.abs(sampled[:, 0])) == 1e-4 and np.min(sampled[:, 0]) < 0      # it swings back
    np.testing.assert_allclose(fast, sampled, rtol=0, atol=1e-9 * 1e-4)


def test_the_sub_step_maps_are_the_matrix_functions_of_the_free_motor_system():
    """Phi = e^{A h}, the constant and ramp forcing's responses, their rows [d, d'] at every node
    theta h and the held torque's response over (1 - theta) h, against the same functions by
    eigendecomposition of A (a non-symmetric K with a nearly free motor direction, a little damping):
    1e-11 relative (the eigenvectors' conditioning, 4e5, bounds the reference's accuracy)."""
    robot = robot_preset("default", payload=6.0, rotor_inertia=0.01)
    mass, damping, stiffness = (np.asarray(a) for a in sv.rest_linearization(robot, sv.igm(robot, CYCLE.place)))
    damping = damping + 1e-6 * stiffness
    stiffness = stiffness.copy()
    stiffness[0, 2] += 5.0
    n, h = mass.shape[0], 0.43 / 4416
    mp = jax.jit(_maps)(jnp.asarray(mass), jnp.asarray(stiffness), jnp.asarray(damping), h)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(mass, stiffness), -np.linalg.solve(mass, damping)]])
    b = np.concatenate([np.zeros((n, n)), np.linalg.inv(mass)])
    lam, vec = np.linalg.eig(a)
    inv = np.linalg.inv(vec)

    def funcs(t):
        z = lam * t
        f1 = np.where(abs(z) > 1e-8, (np.exp(z) - 1) / np.where(z == 0, 1, z), 1 + z / 2) * t
        f2 = np.where(abs(z) > 1e-5, (np.exp(z) - 1 - z) / np.where(z == 0, 1, z) ** 2, 0.5 + z / 6) * t * t
        return [((vec * d) @ inv).real for d in (np.exp(z), f1, f2)]

    rel = lambda x, y: float(np.max(np.abs(np.asarray(x) - y)) / np.max(np.abs(y)))
    u, v1, v2 = funcs(h)
    assert rel(mp.phi, u) < 1e-11 and rel(mp.p1, v1 @ b) < 1e-11 and rel(mp.p2, v2 @ b / h) < 1e-9
    rows = np.array([0, 1, n, n + 1])
    for i in (1, 5, NODES // 2, NODES - 1):
        ut, v1t, v2t = funcs(i / NODES * h)
        assert rel(mp.ru[i], ut[rows]) < 1e-11 and rel(mp.rv1[i], (v1t @ b)[rows]) < 1e-11
        assert rel(mp.rv2[i], (v2t @ b)[rows] / h) < 1e-8
        assert rel(mp.gs[i], funcs((1 - i / NODES) * h)[1] @ b[:, :2]) < 1e-11
    # between the nodes, the local interpolant the loop reads the sample from: the stiffest mode's
    # omega h / NODES is 0.34 here, its error (0.34)^8-like, measured 1.3e-7 at the stencil's edge
    # (16 nodes: 5e-4)
    for theta in (0.03, 0.37, 0.5 + 1 / 64, 0.91):
        start, weights = _lagrange(jnp.asarray(theta))
        pick = lambda table: np.tensordot(np.asarray(weights), np.asarray(table)[int(start):int(start) + len(weights)], 1)
        assert rel(pick(mp.ru), funcs(theta * h)[0][rows]) < 1e-6, theta
        assert rel(pick(mp.gs), funcs((1 - theta) * h)[1] @ b[:, :2]) < 1e-6, theta


@pytest.mark.slow      # a full nonlinear run under the servo (77 s); figures in docs/conventions.md#servo
def test_the_fast_model_under_the_servo_agrees_with_the_full_model():
    """The same servo (fc 30 Hz, 8 kHz, rigid feedforward, 0.01 kg m^2 rotor) on a small robot (one
    mode per link, 2 kg) along a short move: the fast model's closed-loop metrics against the full
    nonlinear model's (exponential integrator, 125/7 us substeps): the dwell residual, the deflection,
    the torque and the residual energy within 0.5 %."""
    from jaxflex.reference_servo import closed_loop_rollout

    robot = robot_preset("default", payload=2.0, n_bending=1, n_axial=1)
    tf, dwell = 0.1, 0.01
    s = sv.servo_from_bandwidth(robot, PATH, 30.0)
    r = sv.with_rotor(robot, s)
    law = make_profile("poly7")
    full = {k: float(v) for k, v in metrics(closed_loop_rollout(robot, PATH, law, tf, dwell, s, progress=False)).items()}
    fast = LawEvaluator(model_set(robot, [2.0]), PATH, tf, dwell, default_grid(r, [tf], dwell), servo=s)(law)
    fast = {k: v[0] for k, v in fast.items()}
    for k in ("dwell_residual_mm", "max_deflection_mm", "max_torque_nm", "residual_energy", "residual_pos_mm"):
        assert abs(float(fast[k]) / full[k] - 1) < 5e-3, (k, float(fast[k]), full[k])


def test_a_fast_sampled_pd_of_growing_bandwidth_tends_to_the_prescribed_motion():
    """The continuous limit: at 200 kHz and a bandwidth of 400, 800, 1600 Hz (rigid feedforward),
    the closed loop's end-effector error over the motion and the dwell approaches the perfect
    controller's (the same fast model with the motors prescribed). Once fc is well above the
    structure's modes the motors' tracking error, the flexible reaction over Kp, goes as 1/fc^2: the
    largest difference shrinks about fourfold per doubling (measured 3.4x, then 3.9x), to 5.3 % of the
    error itself at 1600 Hz. (Below a few hundred hertz the difference is as large as the error: the
    servo's stiffness shifts the modes' phases, and that is the servo's effect, not a defect.)"""
    robot = robot_preset("default", payload=2.0)      # the default modes: the suite's table programs
    tf, dwell, rate = 0.1, 0.01, 2e5
    law = make_profile("poly7")
    grid = servo_grid(Grid(coarse=16, fine=4, dwell_steps=10, squarings=8, unroll=1), tf, dwell, rate)
    r = robot.replace(rotor_inertia=0.01)
    prescribed = LawEvaluator(model_set(r, [2.0]), PATH, tf, dwell, grid).series(law)
    e_ref = np.concatenate([np.asarray(prescribed.e[0]), np.asarray(prescribed.e_dwell[0])])
    tables, servo_tables = path_tables(r, PATH), servo_path_tables(r, PATH)
    samples = sample_motion(PATH.length, law, tf, grid)
    schedule = sample_schedule(tf, dwell, grid, rate)
    feedforward = jax.jit(lambda r: feedforward_torques("rigid", r, tables, samples, grid))(r)

    @jax.jit
    def error(s):
        series = closed_loop(tables, servo_tables, samples, schedule, feedforward, tf, dwell, grid, s,
                             sv.with_rotor(robot, s))
        return jnp.concatenate([series.e, series.e_dwell]), series

    gaps = []
    for fc in (400.0, 800.0, 1600.0):
        s = sv.servo_from_bandwidth(robot, PATH, fc, rate=rate)
        e, series = error(s)
        gaps.append(float(np.max(np.abs(np.asarray(e) - e_ref))))
    scale = float(np.max(np.abs(e_ref)))
    assert gaps[0] > gaps[1] > gaps[2], gaps
    assert 2.5 < gaps[0] / gaps[1] < 6 and 3 < gaps[1] / gaps[2] < 5, gaps
    assert gaps[2] < 0.08 * scale, (gaps, scale)
    # the dwell's accelerations (solved from the equations of motion at every node) are its
    # velocities' rate: central differences over the 5 us steps agree to 0.5 % of the largest
    # (measured at 1600 Hz; the differences' own error, (omega h)^2 / 6 for the kHz modes, and the
    # held torque's steps at the samples); accelerations 3 % off miss by 2.5 % or more
    ed, edd = np.asarray(series.ed_dwell), np.asarray(series.edd_dwell)
    rate_of = (ed[2:] - ed[:-2]) / (2 * float(series.dt_dwell))
    assert np.max(np.abs(rate_of - edd[1:-1])) < 0.015 * np.max(np.abs(edd))
