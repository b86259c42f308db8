"""The servo loop (``jaxflex.servo``) and the full nonlinear model under it
(``jaxflex.reference_servo``): the default gain rule, the sampled loop's stability and its
continuous limit, and the closed-loop simulation's energy balance with the controller's work."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex import servo as sv
from jaxflex.path import make_path
from jaxflex.profiles import make_profile
from jaxflex.robot import cycle_preset, igm, robot_preset

CYCLE = cycle_preset()
PATH = make_path(CYCLE, "lame", 0.025)


def test_the_default_gains_follow_the_bandwidth_rule_with_the_rigid_inertia_at_the_midpoint():
    """Kp = J (2 pi fc)^2 and Kd = 2 * 0.7 * J (2 pi fc), J the mean of the diagonal of the rigid
    joint-space inertia (rotor included) at the path's arc-length midpoint. J is checked against the
    elastic model's reduced mass matrix at zero deflection (the rigid robot, by another route: the
    assumed-modes assembly instead of the rigid Newton-Euler model), to 1e-9."""
    robot = robot_preset("default", payload=6.0)
    s = sv.servo_from_bandwidth(robot, PATH, 15.0, rotor_inertia=0.01)
    r = sv.with_rotor(robot, s)
    qa = sv.midpoint_pose(r, PATH)
    ne = mdl.layout(r).ne
    m_rigid = np.asarray(mdl.reduced_mass(r, qa, jnp.zeros(ne)))[:2, :2]
    np.testing.assert_allclose(np.asarray(sv.rigid_inertia(r, qa)), m_rigid, rtol=1e-9)
    j = np.mean(np.diag(m_rigid))
    w = 2 * np.pi * 15.0
    np.testing.assert_allclose(np.asarray(s.kp), [j * w**2] * 2, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(s.kd), [2 * 0.7 * j * w] * 2, rtol=1e-9)
    # the midpoint by arc length: the IGM of the path's point at half its length
    x_mid = np.asarray(jax.jit(lambda: sv.path_frame(PATH, 0.5 * PATH.length).pos)())
    np.testing.assert_allclose(np.asarray(qa), np.asarray(igm(r, x_mid)), rtol=1e-12)
    # the rotor counts in J: a heavier rotor, larger gains by exactly its inertia
    s2 = sv.servo_from_bandwidth(robot, PATH, 15.0, rotor_inertia=0.02)
    np.testing.assert_allclose(float(s2.kp[0]) - float(s.kp[0]), 0.01 * w**2, rtol=1e-9)


@pytest.mark.parametrize("payload", [0.1, 6.0])
def test_the_static_torque_is_the_rigid_robots_gravity_torque_plus_a_compliance_term(payload):
    """The flexible feedforward's dwell torque (``static_torque``, the elastic model at its static
    equilibrium) against the rigid Newton-Euler model at rest (``rigid.rigid_torques`` with zero
    rates, gravity only; another model of the same bodies): the links' static sag moves the bodies
    by O(load / stiffness), so the two differ by a term that goes as 1/E. Measured at the place
    pose: 3.2e-5 (0.1 kg) and 1.6e-4 (6 kg) of the torque, and exactly 100 times less with E x 100.
    A gravity, mass or stiffness a few percent off moves the first figure by orders of magnitude or
    breaks the 1/E scaling."""
    from jaxflex.rigid import rigid_torques

    robot = robot_preset("default", payload=payload)
    qa = igm(robot, jnp.asarray(CYCLE.place, dtype=float))
    zero = jnp.zeros(2)
    rigid = np.asarray(rigid_torques(robot, qa, zero, zero))
    gap = [np.max(np.abs(np.asarray(sv.static_torque(robot.replace(young=robot.young * k), qa)) - rigid))
           / np.max(np.abs(rigid)) for k in (1.0, 100.0)]
    assert 1e-6 < gap[0] < 1e-3, gap            # small deflections: the sag is far below the links' size
    assert gap[0] / gap[1] == pytest.approx(100.0, rel=0.01), gap    # the compliance term goes as 1/E


@pytest.mark.parametrize("delay", [False, True])
def test_the_advanced_feedforward_holds_each_periods_mean_torque(delay):
    """The flexible feedforward is held over each sample period (with ``delay``, over the next one).
    Advanced by ``feedforward_advance``, the value held is the model torque's mean over the period
    it acts in, to O(T^2) (the midpoint rule: T^2 tau''/24), so the hold delivers the model's
    impulse and adds no lag. Checked on a torque known in closed form (10 Hz sines, 8 kHz
    sampling): within 1.5 times the midpoint rule's bound plus the nodes' interpolation error. An
    advance 5 % off leaves an O(T) error (0.025 T tau', here 50 times that bound)."""
    from jaxflex.servo_simulate import flexible_feedforward

    robot = robot_preset("default", payload=0.1)
    servo = dataclasses.replace(sv.servo_from_bandwidth(robot, PATH, 15.0, rate=8000.0), delay=delay)
    period = 1.0 / 8000.0
    w = 2 * np.pi * 10.0
    nodes = np.linspace(0.0, 0.2, 16001)                   # node spacing period / 10
    amp = np.array([3.0, -2.0])
    tau = lambda t: amp * np.sin(w * t[:, None]) + 0.5 * np.cos(2 * w * t[:, None])
    area = lambda t: -amp * np.cos(w * t[:, None]) / w + 0.5 * np.sin(2 * w * t[:, None]) / (2 * w)
    series = type("Series", (), {"t": jnp.asarray(nodes), "tau": jnp.asarray(tau(nodes))})()
    qa = igm(robot, jnp.asarray(CYCLE.place, dtype=float))
    held, _ = flexible_feedforward(robot, series, qa, sv.feedforward_advance(servo))
    k = np.arange(1, 1400)
    t_k = k * period                                       # the sample instants (the nodes hold them)
    u = np.stack([np.interp(t_k, nodes, np.asarray(held)[:, i]) for i in range(2)], 1)
    start = t_k + (period if delay else 0.0)               # the period the value acts in
    mean = (area(start + period) - area(start)) / period
    d2 = np.max(np.abs(amp)) * w**2 + 0.5 * (2 * w) ** 2  # a bound on |tau''|
    bound = 1.5 * period**2 * d2 / 24 + (period / 10) ** 2 * d2 / 8
    assert np.max(np.abs(u - mean)) < bound, (np.max(np.abs(u - mean)), bound)


def test_an_unstable_sampled_loop_is_refused_before_anything_is_simulated():
    """At 6 kg, 8 kHz and a 0.01 kg m^2 rotor the sampled loop (the plant linearized at rest,
    integrated exactly over the sample-and-hold) turns strongly unstable between 45 and 50 Hz:
    fc 60 Hz is refused with an error naming fc, the rate and the radius; 15 and 40 Hz pass (their
    radius exceeds 1 by under 1e-3: kHz modes of the undamped structure that grow a few-fold over
    the run), and with the literal criterion (``strict``) they are refused too. With 0.5 % damping at
    the first mode the loop at 40 Hz is stable outright."""
    robot = robot_preset("default", payload=6.0)
    ok = {fc: sv.check_stable(robot, sv.servo_from_bandwidth(robot, PATH, fc), PATH, duration=0.53, points=2)
          for fc in (15.0, 40.0)}
    assert all(1.0 < r < 1.001 for r in ok.values()), ok
    with pytest.raises(ValueError, match=r"servo unstable: fc 60 Hz at 8000 Hz .* radius 1\.4"):
        sv.check_stable(robot, sv.servo_from_bandwidth(robot, PATH, 60.0), PATH, duration=0.53, points=2)
    with pytest.raises(ValueError, match="servo unstable"):
        sv.check_stable(robot, sv.servo_from_bandwidth(robot, PATH, 15.0), PATH, duration=0.53, points=2,
                        strict=True)
    damped = robot.replace(damping=jnp.asarray([0.0, 2 * 0.005 / (2 * np.pi * 59.8)]))
    radius = sv.check_stable(damped, sv.servo_from_bandwidth(robot, PATH, 40.0), PATH, strict=True, points=2)
    assert radius < 1.0


def test_the_sampled_loop_tends_to_the_continuous_loop_as_the_rate_grows():
    """Continuous PD limit: at a very high rate the sampled loop's eigenvalues are those of the
    continuous closed loop, exp(lambda T): at 1 MHz the spectral radius is exp(T max Re lambda)
    (the continuous loop is stable: every Re lambda < 0) to 1e-9."""
    robot = robot_preset("default", payload=6.0)
    s = sv.servo_from_bandwidth(robot, PATH, 40.0)
    r = sv.with_rotor(robot, s)
    qa = sv.igm(r, CYCLE.place)
    mass, damping, stiffness = (np.asarray(a) for a in sv.rest_linearization(r, qa))
    n = mass.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(mass, stiffness), -np.linalg.solve(mass, damping)]])
    b = np.concatenate([np.zeros((n, 2)), np.linalg.solve(mass, np.eye(n)[:, :2])])
    g = np.zeros((2, 2 * n))
    g[:, :2], g[:, n:n + 2] = np.diag(np.asarray(s.kp)), np.diag(np.asarray(s.kd))
    lam = np.linalg.eigvals(a - b @ g)
    assert np.max(lam.real) < 0
    fast = dataclasses.replace(s, rate=jnp.asarray(1e6))
    assert abs(sv.sampled_radius(r, fast, qa) - np.exp(np.max(lam.real) / 1e6)) < 1e-9


def test_a_servo_with_bad_settings_is_refused():
    robot = robot_preset("default", payload=6.0)
    for kw, match in ((dict(fc=-1.0), "fc"), (dict(fc=15.0, rate=0.0), "rate"),
                      (dict(fc=15.0, feedforward="ideal"), "feedforward"), (dict(fc=15.0, rotor_inertia=-0.1), "rotor"),
                      (dict(fc=15.0, torque_limit=0.0), "torque_limit")):
        fc = kw.pop("fc")
        with pytest.raises(ValueError, match=match):
            sv.servo_from_bandwidth(robot, PATH, fc, **kw)


@pytest.mark.slow      # a full nonlinear run under the servo (50 s); the default suite keeps test_servo_fast's
def test_the_full_model_under_the_servo_balances_energy_with_the_controllers_work():
    """With no damping, the change of the mechanical energy (kinetic + gravity + strain) over every
    sample period equals the work of the held motor torques, u_k . (q_a(t_k+1) - q_a(t_k)), exactly in
    the model; the exponential integrator keeps the balance to 1e-6 of the total work done (a small
    robot, one mode per link, a short move)."""
    from jaxflex import reference_servo as rs

    robot = robot_preset("default", payload=2.0, n_bending=1, n_axial=1)
    path = make_path(CYCLE, "lame", 0.025)
    s = sv.servo_from_bandwidth(robot, path, 30.0, rate=8000.0)
    r = sv.with_rotor(robot, s)
    series_states = []
    orig = rs._advance

    def spy(*args, **kw):
        out = orig(*args, **kw)
        series_states.append(out)
        return out

    rs._advance = spy
    try:
        rs.closed_loop_rollout(robot, path, make_profile("poly7"), 0.1, 0.01, s, progress=False)
    finally:
        rs._advance = orig
    xs = np.concatenate([np.asarray(o[1][0]) for o in series_states])      # (K, m, 2n) states per substep
    us = np.concatenate([np.asarray(o[1][1]) for o in series_states])[:, 0]  # (K, 2) the torque of each period
    keep = (0.1 + 0.01) * 8000
    xs, us = xs[:int(keep)], us[:int(keep)]
    n = xs.shape[-1] // 2
    starts = xs[:, 0]
    energy = jax.jit(jax.vmap(lambda x: 0.5 * x[n:] @ mdl.reduced_mass(r, x[:2], x[2:n]) @ x[n:]
                              + mdl.potential(r, mdl.full_coordinates(r, x[:2], x[2:n]))))(jnp.asarray(starts))
    energy = np.asarray(energy)
    work = np.sum(us[:-1] * (starts[1:, :2] - starts[:-1, :2]), axis=1)
    de = np.diff(energy)
    total = np.sum(np.abs(work))
    assert total > 0.1                                                    # joules: the move does work
    assert np.max(np.abs(np.cumsum(de - work))) <= 1e-6 * total, np.max(np.abs(np.cumsum(de - work)))
