"""The assembled model against an independent continuum description of the same robot.

The model (``jaxflex.model``) assembles closed-form mass matrices (Eqs. 7, 9), stiffness blocks
(Eqs. 11, 13), gravity (Eqs. 14-16), Rayleigh damping and the loop closure (Eq. 18) from modal
integrals. Here the same energies are computed the long way, from the mode shapes alone: every
point xi of every beam is placed in the plane, its velocity taken by autodiff, and the kinetic,
elastic, gravity and dissipation energies integrated by an independent Gauss-Legendre rule. The mass
matrix is the Hessian of that kinetic energy in the velocities, the generalized gravity and elastic
forces the gradient of that potential. Then the reduced equations of motion must satisfy the power
balance Q . q_i' = dE/dt + q'^T D q' for any state and any accelerations (Lagrange's equations), which
ties the Coriolis/centrifugal terms, the constraint acceleration term and the velocity map to the
energies. Together these catch a wrong mass, stiffness, gravity, damping or inertial term anywhere in
the model, and an asymmetry between the two arms (mirror test). Every check runs on the paper's model
and on the richer validation model (``model.richer``: every link in bending and tension), whose
continuum description here simply places both displacement fields on every beam. Everything here is exact to
round-off, so the tolerances are 1e-9 or tighter: a 5 % error in any term is far outside them.
"""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex.beams import mode_shapes
from jaxflex.robot import igm, robot_preset

_X, _W = np.polynomial.legendre.leggauss(48)     # independent of jaxflex.quadrature
XI, W = 0.5 * (_X + 1.0), 0.5 * _W


def _rot(th, v):
    c, s = jnp.cos(th), jnp.sin(th)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def _split(robot, q):
    lay = mdl.layout(robot)
    return (q[lay.a], tuple(q[i] for i in lay.e_beam), q[lay.base12], q[lay.base22], q[lay.ee])


def _fields(robot, beams, xi, deriv=0):
    """Displacement fields (u_x, u_y) (or their deriv-th xi-derivatives), each (m,), of the beams
    11, 12, 21, 22 in their frames: proximal links bend (then stretch, richer model), distal links
    stretch (then bend); a missing field is zero."""
    nb, na, nap, nbd = robot.n_bending, robot.n_axial, robot.n_axial_proximal, robot.n_bending_distal
    shape = lambda kind, n: (jnp.asarray(mode_shapes(kind, n, xi, deriv)) if n
                             else jnp.zeros((len(np.atleast_1d(xi)), 0)))
    pb, pa, pap, pbd = shape("bending", nb), shape("axial", na), shape("axial", nap), shape("bending", nbd)
    prox = lambda e: (pap @ e[nb:], pb @ e[:nb])
    dist = lambda e: (pa @ e[:na], pbd @ e[na:])
    e11, e12, e21, e22 = beams
    return prox(e11), dist(e12), prox(e21), dist(e22)


def _points(robot, q, xi):
    """Positions (4, m, 2) of the points xi (m,) of the beams 11, 12, 21, 22 in the plane, from the
    beam kinematics of the paper (Eq. 5): base + R(theta) [l xi + u_x, u_y]."""
    qa, beams, b12, b22, _ = _split(robot, q)
    (x11, y11), (x12, y12), (x21, y21), (x22, y22) = _fields(robot, beams, xi)
    bases = robot.bases
    p11 = bases[0][None] + _rot(qa[0], jnp.stack([robot.l1 * xi + x11, y11], -1))
    p21 = bases[1][None] + _rot(qa[1], jnp.stack([robot.l1 * xi + x21, y21], -1))
    p12 = b12[None, :2] + _rot(b12[2], jnp.stack([robot.l2 * xi + x12, y12], -1))
    p22 = b22[None, :2] + _rot(b22[2], jnp.stack([robot.l2 * xi + x22, y22], -1))
    return jnp.stack([p11, p12, p21, p22])


def _link_masses(robot):
    area = np.pi * robot.diameter**2 / 4
    m1, m2 = robot.rho * area * robot.l1, robot.rho * area * robot.l2
    return jnp.stack([m1, m2, m1, m2])


def kinetic_energy(robot, q, qd):
    """T = sum over beams of 1/2 int rho A |v|^2 dx + payload + rotors [J], by quadrature."""
    _, vel = jax.jvp(lambda x: _points(robot, x, XI), (q,), (qd,))
    beams = 0.5 * _link_masses(robot) @ (jnp.sum(vel**2, -1) @ W)
    lay = mdl.layout(robot)
    xd, qad = qd[lay.ee], qd[lay.a]
    return beams + 0.5 * robot.payload * xd @ xd + 0.5 * robot.rotor_inertia * qad @ qad


def elastic_energy(robot, qe_beams):
    """Sum over the beams of 1/2 int EI u_y''^2 dx + 1/2 int EA u_x'^2 dx [J] (the paper's model:
    bending of the proximal, tension of the distal links)."""
    area = np.pi * robot.diameter**2 / 4
    inertia = np.pi * robot.diameter**4 / 64
    first, second = _fields(robot, qe_beams, XI, 1), _fields(robot, qe_beams, XI, 2)
    lengths = (robot.l1, robot.l2, robot.l1, robot.l2)
    out = 0.0
    for (ux1, _), (_, uy2), l in zip(first, second, lengths):
        out = out + robot.young * inertia / l**3 * 0.5 * W @ uy2**2 + robot.young * area / l * 0.5 * W @ ux1**2
    return out


def potential_energy(robot, q):
    """Elastic energy plus the gravity energy -int rho A g.r dx - m_payload g.x [J]."""
    _, beams, _, _, x = _split(robot, q)
    pts = _points(robot, q, XI)
    grav = -_link_masses(robot) @ ((pts @ robot.gravity) @ W) - robot.payload * robot.gravity @ x
    return elastic_energy(robot, beams) + grav


def dissipation(robot, qd):
    """Rayleigh dissipation function alpha T_el(q_e') + beta V_el(q_e'), T_el the kinetic energy of the
    deformation rates in the beam frames [W]."""
    _, beams, _, _, _ = _split(robot, qd)
    m = _link_masses(robot)
    t_el = sum(0.5 * mk * W @ (ux**2 + uy**2) for mk, (ux, uy) in zip(m, _fields(robot, beams, XI)))
    return robot.damping[0] * t_el + robot.damping[1] * elastic_energy(robot, beams)


def tip_constraints(robot, q):
    """Loop closure from the beam tips (xi = 1): distal tips at the end effector, distal bases at the
    proximal tips (8,) [m]."""
    _, _, b12, b22, x = _split(robot, q)
    tips = _points(robot, q, jnp.ones(1))[:, 0]
    return jnp.concatenate([x - tips[1], x - tips[3], b12[:2] - tips[0], b22[:2] - tips[2]])


@pytest.fixture(scope="module", params=["paper", "richer"])
def robot(request):
    # non-default values everywhere (rotor inertia, damping, a tilted gravity) so that every term is on
    r = robot_preset("default", payload=6.0, rotor_inertia=3e-4, damping=(3.0, 2e-5), gravity=(1.5, 9.81))
    return r if request.param == "paper" else mdl.richer(r, 2)


def _random_state(robot, seed, scale_e=1e-2):
    """Full coordinates and velocities with large elastic parts (the formulas are exact in q_e)."""
    rng = np.random.default_rng(seed)
    lay = mdl.layout(robot)
    q = rng.normal(size=lay.n)
    q[lay.e] *= scale_e
    qd = rng.normal(size=lay.n)
    return jnp.asarray(q), jnp.asarray(qd)


def test_mass_matrix_is_the_hessian_of_the_kinetic_energy_by_quadrature(robot):
    """M(q) entry by entry (beams, payload, rotors; the q_e-dependent terms included) equals the
    Hessian in q' of the kinetic energy integrated over the beams: relative to the largest entry of
    its row and column, 1e-12."""
    for seed in (0, 1):
        q, _ = _random_state(robot, seed)
        m = np.asarray(jax.jit(mdl.mass_matrix)(robot, q))
        ref = np.asarray(jax.jit(jax.hessian(lambda v: kinetic_energy(robot, q, v)))(jnp.zeros_like(q)))
        scale = np.sqrt(np.outer(np.abs(np.diag(ref)), np.abs(np.diag(ref))))
        assert np.all(np.abs(m - ref) <= 1e-12 * scale + 1e-300), np.argwhere(np.abs(m - ref) > 1e-12 * scale)


def test_potential_and_generalized_forces_equal_the_integrated_energies(robot):
    """Elastic + gravity energy and its gradient (the generalized stiffness and gravity forces) equal
    the quadrature of 1/2 EI u''^2, 1/2 EA u'^2 and -rho A g.r over the beams plus the payload's weight."""
    for seed in (2, 3):
        q, _ = _random_state(robot, seed, scale_e=1e-3)
        v_model, g_model = jax.jit(jax.value_and_grad(lambda x: mdl.potential(robot, x)))(q)
        v_ref, g_ref = jax.jit(jax.value_and_grad(lambda x: potential_energy(robot, x)))(q)
        np.testing.assert_allclose(float(v_model), float(v_ref), rtol=1e-12)
        # each generalized force against its own size (elastic rows are stiffness x q_e, others gravity)
        np.testing.assert_allclose(np.asarray(g_model), np.asarray(g_ref), rtol=1e-10,
                                   atol=1e-12 * float(jnp.max(jnp.abs(g_ref))))
    # the elastic energy alone (gravity off) pins the stiffness blocks exactly
    r0 = robot.replace(gravity=jnp.zeros(2))
    q, _ = _random_state(robot, 4, scale_e=1e-3)
    lay = mdl.layout(robot)
    k_model = jax.jit(jax.hessian(lambda x: mdl.potential(r0, x)))(q)[np.ix_(lay.e, lay.e)]
    k_ref = jax.jit(jax.hessian(lambda x: potential_energy(r0, x)))(q)[np.ix_(lay.e, lay.e)]
    np.testing.assert_allclose(np.asarray(k_model), np.asarray(k_ref), rtol=1e-11,
                               atol=1e-12 * float(jnp.max(jnp.abs(k_ref))))


def test_damping_forces_derive_from_the_rayleigh_dissipation_function(robot):
    _, qd = _random_state(robot, 5)
    ref = jax.jit(jax.grad(lambda v: dissipation(robot, v)))(qd)
    got = jax.jit(mdl.damping_forces)(robot, qd)
    np.testing.assert_allclose(np.asarray(got), np.asarray(ref), rtol=1e-11, atol=1e-12 * float(jnp.max(jnp.abs(ref))))
    assert float(jnp.max(jnp.abs(ref))) > 0


def test_loop_closure_constraints_from_the_beam_tips(robot):
    for seed in (6, 7):
        q, _ = _random_state(robot, seed, scale_e=1e-3)
        np.testing.assert_allclose(np.asarray(mdl.constraints(robot, q)), np.asarray(tip_constraints(robot, q)),
                                   rtol=0, atol=1e-15)


def _power_terms(robot, qa, qe, qad, qed, qadd, qedd):
    """(Q . q_i', dE/dt, q'^T D q') for the reduced equations Q = M_r q_i'' + F at the given state."""
    red = mdl.reduced(robot, qa, qe, qad, qed)
    qid = jnp.concatenate([qad, qed])
    q_force = red.mass @ jnp.concatenate([qadd, qedd]) + red.force

    def energy(qi, qid_):
        q = mdl.full_coordinates(robot, qi[:2], qi[2:])
        qd = mdl.velocity_map(robot, q) @ qid_
        return kinetic_energy(robot, q, qd) + potential_energy(robot, q)

    qi = jnp.concatenate([qa, qe])
    _, de_dt = jax.jvp(energy, (qi, qid), (qid, jnp.concatenate([qadd, qedd])))
    return q_force @ qid, de_dt, red.qd @ mdl.damping_forces(robot, red.qd)


def test_reduced_equations_satisfy_the_power_balance(robot):
    """Lagrange's equations: the power of the generalized forces Q = [tau; Q_e] of the reduced
    model equals the rate of change of the (independently integrated) kinetic + potential energy
    plus the Rayleigh dissipation, for any state and any accelerations. A wrong Coriolis or
    centrifugal term, constraint acceleration or velocity map breaks it. Checked with the motors
    moving fast and an elastic state far larger than any real deflection (terms in q_e visible)."""
    rng = np.random.default_rng(8)
    qa = igm(robot, jnp.array([0.06, 0.29]))
    power = jax.jit(lambda *a: _power_terms(robot, *a))
    ne = mdl.layout(robot).ne
    for scale in (1e-3, 1e-6):
        qe, qed = jnp.asarray(rng.normal(size=ne) * scale), jnp.asarray(rng.normal(size=ne) * 1e3 * scale)
        qad, qadd = jnp.asarray(rng.normal(size=2) * 5.0), jnp.asarray(rng.normal(size=2) * 50.0)
        qedd = jnp.asarray(rng.normal(size=ne) * 1e5 * scale)
        p, de, diss = (float(v) for v in power(qa, qe, qad, qed, qadd, qedd))
        # each side is a sum of terms up to |tau . qa'| ~ 1e3 W: round-off ~1e-12 of them
        size = max(abs(p), abs(de), abs(diss), 1.0)
        assert abs(p - (de + diss)) < 1e-9 * size, (scale, p, de, diss)
        assert abs(diss) > 1e-6 * size                      # damping on: the test sees it


def test_inertial_coupling_alone_satisfies_the_power_balance_with_gravity_off():
    """The same balance with gravity and damping off, the payload light and the rotors heavy: the
    inertial terms alone (a different mix of the mass matrix blocks than above)."""
    robot = robot_preset("default", payload=0.1, rotor_inertia=1e-2, gravity=(0.0, 0.0))
    rng = np.random.default_rng(9)
    qa = igm(robot, jnp.array([-0.12, 0.25]))
    qe, qed = jnp.asarray(rng.normal(size=12) * 1e-3), jnp.asarray(rng.normal(size=12))
    qad, qadd = jnp.asarray([3.0, -4.0]), jnp.asarray([-60.0, 20.0])
    p, de, diss = (float(v) for v in jax.jit(lambda *a: _power_terms(robot, *a))(qa, qe, qad, qed, qadd,
                                                                               jnp.asarray(rng.normal(size=12) * 1e2)))
    assert diss == 0.0
    assert abs(p - de) < 1e-9 * max(abs(p), abs(de))


def _mirror(x):
    return jnp.asarray([-x[0], x[1]])


def test_mirror_symmetry_of_the_symmetric_robot():
    """The default robot is symmetric about x = 0 (motors at -a, +a; working modes (+1, -1)): at
    mirrored poses the locked natural frequencies are equal, the gravity sag is mirrored, and the
    torques of mirrored rigid motions are swapped with opposite signs (including the static elastic
    correction). A term applied to one arm only breaks this."""
    robot = robot_preset("default", payload=6.0, rotor_inertia=2e-4)
    x = jnp.array([-0.11, 0.275])
    qa, qb = igm(robot, x), igm(robot, _mirror(x))
    np.testing.assert_allclose(np.asarray(qb), np.pi - np.asarray(qa)[::-1], atol=1e-13)
    fa, fb = (np.asarray(jax.jit(mdl.locked_modes)(robot, q)[0]) for q in (qa, qb))
    np.testing.assert_allclose(fa, fb, rtol=1e-9)
    sa, sb = (np.asarray(jax.jit(mdl.static_deflection)(robot, q)) for q in (qa, qb))
    np.testing.assert_allclose(sb, [-sa[0], sa[1]], rtol=1e-9, atol=1e-12 * np.abs(sa).max())
    # a rigid motion and its mirror image: q_b(t) = pi - swap(q_a(t))
    qad, qadd = jnp.asarray([1.3, -0.4]), jnp.asarray([-20.0, 35.0])
    inv = jax.jit(mdl.inverse_dynamics)
    qe_a = jax.jit(mdl.static_equilibrium)(robot, qa)
    qe_b = jax.jit(mdl.static_equilibrium)(robot, qb)
    _, ta = inv(robot, qa, qe_a, qad, jnp.zeros(12), qadd)
    _, tb = inv(robot, qb, qe_b, -qad[::-1], jnp.zeros(12), -qadd[::-1])
    np.testing.assert_allclose(np.asarray(tb), -np.asarray(ta)[::-1], rtol=1e-9, atol=1e-9 * float(jnp.max(jnp.abs(ta))))
