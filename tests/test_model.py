"""Elastodynamic model (paper Section 2): beams, assembly, dynamics, statics, natural frequencies."""
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex.frequencies import modes_at_point
from jaxflex.beams import beam_modes, bending_coefficients, bending_roots
from jaxflex.rigid import rigid_torques
from jaxflex.robot import cycle_preset, elbows, igm, robot_preset

E, RHO, DIAM, L1, L2 = 70e9, 2710.0, 0.035, 0.24, 0.38079
AREA, INERTIA = np.pi * DIAM**2 / 4, np.pi * DIAM**4 / 64


# ---------------------------------------------------------------------------- single beams


def test_table1_modal_parameters():
    b = bending_roots(3)
    np.testing.assert_allclose(b, [1.8751, 4.6941, 7.8548], atol=5e-5)          # Table 1, 5 digits
    np.testing.assert_allclose(bending_coefficients(b), [-1.3622, -0.98186, -1.0008], atol=5e-5)
    np.testing.assert_allclose(np.cos(b) * np.cosh(b), -1.0, atol=1e-12)


@pytest.mark.parametrize("n", [3, 6])
def test_cantilever_frequencies(n):
    """Clamped-free beam: f_k = b_k^2 / (2 pi l^2) sqrt(EI / (rho A)) (1.8751^2, 4.6941^2, ...)."""
    modes = beam_modes("bending", n)
    m = RHO * AREA * L1 * modes.mass
    k = E * INERTIA / L1**3 * modes.stiffness
    freqs = np.sqrt(np.linalg.eigvalsh(np.linalg.solve(np.linalg.cholesky(m), k)
                                       @ np.linalg.inv(np.linalg.cholesky(m)).T)) / (2 * np.pi)
    exact = bending_roots(n) ** 2 / (2 * np.pi * L1**2) * np.sqrt(E * INERTIA / (RHO * AREA))
    np.testing.assert_allclose(np.sort(freqs), exact, rtol=1e-12)   # exact modes: round-off only
    assert abs(exact[0] - 1.8751**2 / (2 * np.pi * L1**2) * np.sqrt(E * INERTIA / (RHO * AREA))) < 0.1


def test_axial_bar_frequencies():
    """Fixed-free bar: f_k = (2k - 1) / (4 l) sqrt(E / rho)."""
    modes = beam_modes("axial", 4)
    lam = np.linalg.eigvals(np.linalg.solve(RHO * AREA * L2 * modes.mass, E * AREA / L2 * modes.stiffness))
    exact = (2 * np.arange(1, 5) - 1) / (4 * L2) * np.sqrt(E / RHO)
    np.testing.assert_allclose(np.sort(np.sqrt(lam.real)) / (2 * np.pi), exact, rtol=1e-12)


def test_modal_tip_compliance_converges_to_beam_theory():
    """Static tip compliance sum_k phi_k(1)^2 / K_k -> l^3/(3 EI) (bending) and l/(EA) (axial)."""
    def compliance(kind, n, scale):
        m = beam_modes(kind, n)
        return m.tip @ np.linalg.solve(scale * m.stiffness, m.tip)

    cb = [compliance("bending", n, E * INERTIA / L1**3) / (L1**3 / (3 * E * INERTIA)) for n in (3, 8)]
    ca = [compliance("axial", n, E * AREA / L2) / (L2 / (E * AREA)) for n in (3, 8, 60)]
    assert 0.99 < cb[0] < 1.0 and abs(cb[1] - 1) < 2e-4           # bending converges as n^-4
    np.testing.assert_allclose(ca[0], 8 / np.pi**2 * (1 + 1 / 9 + 1 / 25), rtol=1e-12)
    assert abs(ca[2] - 1) < 4e-3                                    # axial converges as 1/n


# ---------------------------------------------------------------------------- assembly


@pytest.fixture(scope="module")
def robot6():
    return robot_preset("default", payload=6.0)


@pytest.fixture(scope="module")
def pose(robot6):
    return igm(robot6, jnp.array([-0.1, 0.28]))


@jax.jit
def _closure_terms(robot, pose, qe, qad, qed):
    """Constraint residual and Jacobians, W, and the acceleration terms at one state (one program)."""
    q = mdl.full_coordinates(robot, pose, qe)
    red = mdl.reduced(robot, pose, qe, qad, qed)
    fdot = lambda qq: jax.jvp(lambda x: mdl.constraints(robot, x), (qq,), (red.qd,))[1]
    gamma = jax.jvp(fdot, (q,), (red.qd,))[1]
    return (mdl.constraints(robot, q), mdl.constraint_jacobians(robot, q), mdl.velocity_map(robot, q),
            red.w_acc, gamma)


def test_closed_form_passive_solves_constraints_and_w_matches_autodiff(robot6, pose):
    rng = np.random.default_rng(0)
    qe = jnp.asarray(rng.normal(scale=1e-4, size=12))
    qad, qed = jnp.array([0.7, -1.1]), jnp.asarray(rng.normal(scale=1e-2, size=12))
    res, (a, b, c), w, w_acc, gamma = _closure_terms(robot6, pose, qe, qad, qed)
    assert float(jnp.max(jnp.abs(res))) < 1e-15
    assert a.shape == (8, 8) and b.shape == (8, 12) and c.shape == (8, 2)
    # W and w come from derivatives of the closed-form q_p(q_i); check them against the constraint
    # Jacobians of Eq. 19 (an independent route): A W_p + [C B] = 0 and A w_p + f_qq[q', q'] = 0.
    np.testing.assert_allclose(a @ w[14:], -jnp.concatenate([c, b], axis=1), atol=1e-12)
    np.testing.assert_allclose(w[:14], np.eye(14), atol=0)
    np.testing.assert_allclose(a @ w_acc[14:], -gamma, atol=1e-12 * float(jnp.max(jnp.abs(gamma))))


_reduced = jax.jit(mdl.reduced)        # one program for the tests below (robot and state as arguments)


def test_mass_matrix_symmetric_positive(robot6, pose):
    q = mdl.full_coordinates(robot6, pose, jnp.full(12, 1e-4))
    m = jax.jit(mdl.mass_matrix)(robot6, q)
    np.testing.assert_allclose(m, m.T, atol=1e-15)
    red = _reduced(robot6, pose, jnp.full(12, 1e-4), jnp.zeros(2), jnp.zeros(12))
    assert float(jnp.min(jnp.linalg.eigvalsh(red.mass))) > 0


@pytest.mark.parametrize("richer", [False, True])
def test_matrix_free_residual_equals_reduced_equations(robot6, pose, richer):
    """``residual`` (W and M_r applied by directional derivatives of the loop closure) equals
    M_r [q_a''; q_e''] + F from ``reduced`` to round-off (1e-12 of the largest term: the sums are
    ordered differently), on the paper's model and the richer one (other layout, two mode sets)."""
    robot = mdl.richer(robot6) if richer else robot6
    ne = mdl.layout(robot).ne
    rng = np.random.default_rng(11)
    qe, qed = jnp.asarray(rng.normal(scale=1e-5, size=ne)), jnp.asarray(rng.normal(scale=1e-2, size=ne))
    qad, qadd, qedd = jnp.array([1.5, -2.0]), jnp.array([30.0, 12.0]), jnp.asarray(rng.normal(scale=1e2, size=ne))
    red = _reduced(robot, pose, qe, qad, qed)
    terms = jnp.abs(red.mass) @ jnp.abs(jnp.concatenate([qadd, qedd])) + jnp.abs(red.force)
    want = red.mass @ jnp.concatenate([qadd, qedd]) + red.force
    got = jax.jit(mdl.residual)(robot, pose, qe, qad, qed, qadd, qedd)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * float(jnp.max(terms)))
    assert float(jnp.max(jnp.abs(want))) > 1e-3 * float(jnp.max(terms))   # not a sum of cancelling terms only


@pytest.mark.parametrize("richer", [False, True])
def test_reduced_mass_alone_equals_the_reduced_equations_mass(robot6, pose, richer):
    """``reduced_mass`` (W^T M W without the forces, for the linearization coefficients, the locked
    modes and the full model's energy) equals ``reduced(...).mass`` at a moving state: the mass
    matrix does not depend on the velocities, and both take the same products (1e-14 relative: the
    same operations, compiled as different programs)."""
    robot = mdl.richer(robot6) if richer else robot6
    ne = mdl.layout(robot).ne
    rng = np.random.default_rng(12)
    qe, qed = jnp.asarray(rng.normal(scale=1e-4, size=ne)), jnp.asarray(rng.normal(scale=1e-1, size=ne))
    want = _reduced(robot, pose, qe, jnp.array([1.5, -2.0]), qed).mass
    got = jax.jit(mdl.reduced_mass)(robot, pose, qe)
    assert got.shape == (2 + ne, 2 + ne)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14 * float(jnp.max(jnp.abs(want))))


@jax.jit
def _terms_and_residual(robot, pose, qe, qad, qed, qadd):
    zero = jnp.zeros_like(qe)
    return (mdl.residual_term(robot, pose, qe, "potential"),
            mdl.residual_term(robot, pose, qe, "inertia", qadd=qadd),
            mdl.residual_term(robot, pose, qe, "motion", qad, qed, qadd),
            mdl.residual_term(robot, pose, qe, "motion", jnp.zeros(2), zero, qadd),
            mdl.residual(robot, pose, qe, qad, qed, qadd, zero),
            mdl.residual(robot, pose, qe, jnp.zeros(2), zero, qadd, zero),
            mdl.residual(robot, pose, qe, jnp.zeros(2), zero, jnp.zeros(2), zero),
            mdl.damping_forces(robot, mdl.reduced(robot, pose, qe, qad, qed).qd), mdl.damping_matrix(robot))


@pytest.mark.parametrize("richer", [False, True])
def test_residual_terms_add_up_to_the_residual(robot6, pose, richer):
    """The residual's terms (``residual_term``, from which the linearization coefficients are taken)
    against the whole residual at a deflected, moving state with damping on: at rest it is the
    potential term; accelerating from rest, potential + inertia; moving, potential + motion + the
    damping forces D q_e'; the motion term at zero velocity is the inertia term. Tolerance 1e-12 of
    the largest term (sums in another order); a term missing or 5 % off is far outside it."""
    robot = mdl.richer(robot6) if richer else robot6
    robot = robot.replace(damping=(2.0, 3e-5))
    ne = mdl.layout(robot).ne
    rng = np.random.default_rng(5)
    qe, qed = jnp.asarray(rng.normal(scale=1e-5, size=ne)), jnp.asarray(rng.normal(scale=1e-2, size=ne))
    qad, qadd = jnp.array([1.5, -2.0]), jnp.array([30.0, 12.0])
    pot, inertia, motion, motion_at_rest, full, accelerating, rest, damping, d = (
        np.asarray(v) for v in _terms_and_residual(robot, pose, qe, qad, qed, qadd))
    lay = mdl.layout(robot)
    damping_i = np.concatenate([damping[lay.a], damping[lay.e]])
    assert np.all(damping[lay.a] == 0) and np.all(damping[lay.p] == 0)          # on the elastic coordinates only
    np.testing.assert_allclose(damping[lay.e], d @ np.asarray(qed), rtol=1e-13)   # D q_e'
    scale = max(np.abs(v).max() for v in (pot, inertia, motion, damping_i))
    tol = dict(rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(rest, pot, **tol)
    np.testing.assert_allclose(accelerating, pot + inertia, **tol)
    np.testing.assert_allclose(full, pot + motion + damping_i, **tol)
    np.testing.assert_allclose(motion_at_rest, inertia, **tol)
    for v in (inertia, motion - inertia, damping_i):        # each term matters at this state
        assert np.abs(v).max() > 1e-6 * scale
    with pytest.raises(ValueError, match="term must be one of"):
        mdl.residual_term(robot, pose, qe, "gravity")
    with pytest.raises(ValueError, match="the motion term needs qed"):
        mdl.residual_term(robot, pose, qe, "motion", qad, qadd=qadd)


def test_inverse_then_direct_dynamics_roundtrip(robot6, pose):
    rng = np.random.default_rng(3)
    # elastic state of the size met along the paper's trajectories (tip deflections ~1e-5..1e-6 m)
    qe, qed = jnp.asarray(rng.normal(scale=1e-6, size=12)), jnp.asarray(rng.normal(scale=1e-4, size=12))
    qad, qadd = jnp.array([1.5, -2.0]), jnp.array([30.0, 12.0])
    qedd, tau = jax.jit(mdl.inverse_dynamics)(robot6, pose, qe, qad, qed, qadd)
    qadd2, qedd2 = jax.jit(mdl.direct_dynamics)(robot6, pose, qe, qad, qed, tau)
    # M_r mixes rigid (kg m^2) and axial-mode (kg) scales: cond(M_r) ~ 1e7 amplifies round-off
    cond = float(np.linalg.cond(np.asarray(_reduced(robot6, pose, qe, qad, qed).mass)))
    # norm-wise backward-stable bound: |error| <~ eps cond(M_r) max|q_i''| (q_e'' ~ 1e3 x q_a'')
    tol = 1e-15 * cond * float(jnp.max(jnp.abs(qedd)))
    assert tol < 1e-3 * 12.0
    np.testing.assert_allclose(qadd2, qadd, rtol=0, atol=tol)
    np.testing.assert_allclose(qedd2, qedd, rtol=0, atol=tol)


@pytest.mark.parametrize("payload, rotor", [(6.0, 0.0), (0.1, 2e-4)])
def test_rigid_part_equals_independent_newton_euler(payload, rotor):
    """At q_e = q_e' = q_e'' = 0 the assembled model is the rigid five-bar: its torques equal the
    independent virtual-power rigid model to round-off."""
    robot = robot_preset("default", payload=payload, rotor_inertia=rotor)
    q = igm(robot, jnp.array([0.05, 0.27]))
    qd, qdd = jnp.array([2.0, -1.0]), jnp.array([-25.0, 40.0])
    red = _reduced(robot, q, jnp.zeros(12), qd, jnp.zeros(12))
    tau_model = red.mass[:2, :2] @ qdd + red.force[:2]
    np.testing.assert_allclose(tau_model, jax.jit(rigid_torques)(robot, q, qd, qdd), rtol=1e-11)


def test_rigid_limit_of_quasi_static_elastic_torques():
    """With the elastic coordinates in quasi-static equilibrium under the inertial load, the torque
    error w.r.t. the rigid model falls like 1/E as the stiffness grows."""
    q = igm(robot_preset(), jnp.array([0.05, 0.27]))
    qd, qdd = jnp.array([2.0, -1.0]), jnp.array([-25.0, 40.0])

    @jax.jit
    def torque_error(robot):
        def resid(qe):
            red = mdl.reduced(robot, q, qe, qd, jnp.zeros(12))
            return red.force[2:] + red.mass[2:, :2] @ qdd

        def newton(_, qe):      # the residual and its Jacobian from one evaluation of the model
            jac, r = jax.jacfwd(lambda z: (lambda v: (v, v))(resid(z)), has_aux=True)(qe)
            return qe - jnp.linalg.solve(jac, r)

        qe = jax.lax.fori_loop(0, 4, newton, jnp.zeros(12))
        red = mdl.reduced(robot, q, qe, qd, jnp.zeros(12))
        tau = red.mass[:2, :2] @ qdd + red.force[:2]
        return jnp.linalg.norm(tau - rigid_torques(robot, q, qd, qdd))

    errs = [float(torque_error(robot_preset("default", payload=6.0, young=E * s))) for s in (1.0, 10.0, 100.0)]
    assert errs[0] > 0
    np.testing.assert_allclose(errs[1] / errs[0], 0.1, rtol=0.05)
    np.testing.assert_allclose(errs[2] / errs[1], 0.1, rtol=0.05)


# ---------------------------------------------------------------------------- statics


def _beam_theory_deflection(robot, q, force, elbow_forces=np.zeros((2, 2))):
    """Independent reference: end-effector deflection under an end-effector force (2,) and forces at
    the elbows (2, 2) [N]. Distal links are two-force members (axial compliance c_a), proximal links
    cantilevers loaded at the tip (compliance c_b), both with the model's modal truncation."""
    bend, ax = beam_modes("bending", 3), beam_modes("axial", 3)
    cb = bend.tip @ np.linalg.solve(E * INERTIA / L1**3 * bend.stiffness, bend.tip)
    ca = ax.tip @ np.linalg.solve(E * AREA / L2 * ax.stiffness, ax.tip)
    e = np.asarray(elbows(robot, q))
    x = np.asarray(mdl.ee_position(robot, q, jnp.zeros(12)))
    u = (x - e) / L2                                   # unit vectors elbow -> end effector
    n = np.stack([-np.sin(q), np.cos(q)], 1)           # normals of the proximal links
    tension = np.linalg.solve(u.T, force)              # F = N1 u1 + N2 u2
    d_elbow = [cb * (tension[i] * u[i] + elbow_forces[i]) @ n[i] * n[i] for i in range(2)]
    rhs = [tension[i] * ca + u[i] @ d_elbow[i] for i in range(2)]
    return np.linalg.solve(u, rhs)


def _beam_theory_ee_compliance(robot, q):
    return np.stack([_beam_theory_deflection(robot, q, f) for f in np.eye(2)], axis=1)


@jax.jit
def _ee_compliance(robot, q):
    """End-effector compliance J_e K^-1 J_e^T [m/N] of the assembled model with the motors locked."""
    k = mdl.locked_stiffness(robot, q, jnp.zeros(12))
    je = mdl.velocity_map(robot, mdl.full_coordinates(robot, q, jnp.zeros(12)))[-2:, 2:]
    return je @ jnp.linalg.solve(k, je.T)


def test_static_deflection_under_end_effector_force():
    robot = robot_preset("default", payload=6.0, gravity=(0.0, 0.0))
    q = igm(robot, jnp.array([0.08, 0.27]))
    x0 = mdl.ee_position(robot, q, jnp.zeros(12))
    eq = jax.jit(lambda f: mdl.ee_position(robot, q, mdl.static_equilibrium(robot, q, f)) - x0)
    compliance = _ee_compliance(robot, q)
    ref = _beam_theory_ee_compliance(robot, q)
    # the assembled stiffness matrix and the independent two-force-member analysis agree
    np.testing.assert_allclose(compliance, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    for f in (jnp.array([20.0, 0.0]), jnp.array([0.0, -20.0]), jnp.array([14.0, 14.0])):
        d_plus, d_minus = eq(f), eq(-f)
        lin = compliance @ f
        # geometric nonlinearity ~ deflection / link length ~ 1e-4
        np.testing.assert_allclose(d_plus, lin, rtol=1e-3, atol=1e-3 * float(jnp.linalg.norm(lin)))
        np.testing.assert_allclose(d_minus, -d_plus, rtol=1e-3, atol=1e-3 * float(jnp.linalg.norm(lin)))


def test_gravity_sag_matches_beam_theory(robot6):
    """Gravity along +y (the paper's convention) sags the end effector along +y. Reference: payload
    plus half of each distal link at the end effector, the other halves at the elbows, and each
    proximal link's own weight as the tip load with the same tip deflection (3/8 of it)."""
    q = igm(robot6, jnp.array([0.0, 0.27]))
    qe = mdl.static_equilibrium(robot6, q)
    sag = np.asarray(mdl.ee_position(robot6, q, qe) - mdl.ee_position(robot6, q, jnp.zeros(12)))
    m1, m2 = RHO * AREA * L1, RHO * AREA * L2
    g = np.array([0.0, 9.81])
    ref = _beam_theory_deflection(robot6, q, (6.0 + m2) * g, np.stack([(0.5 * m2 + 3 / 8 * m1) * g] * 2))
    assert sag[1] > 0 and abs(sag[0]) < 1e-3 * sag[1]          # symmetric pose: vertical sag
    # distributed loads are represented through 3 modes; axial self-weight of the distal links and
    # their rotation are neglected in the reference: 2 %
    np.testing.assert_allclose(sag, ref, rtol=0.02, atol=0.02 * abs(ref[1]))


# ---------------------------------------------------------------------------- dynamics invariants


@functools.partial(jax.jit, static_argnames=("dt", "steps"))
def _rk4_locked(robot, qa, qe0, qed0, dt, steps):
    """Classical RK4 of the full model with the motors locked at qa (one program for every robot and
    start). The four stages are a loop over one evaluation of the model (stage s evaluates it at
    x + A[s] dt k_{s-1} and adds B[s] dt k_s): a quarter of the code to compile of four inlined ones."""
    a_coef, b_coef = jnp.array([0.0, 0.5, 0.5, 1.0]), jnp.array([1.0, 2.0, 2.0, 1.0]) / 6.0

    def stage(x, carry, coef):
        k_prev, acc = carry
        a, b = coef
        xx = x + a * dt * k_prev
        ne = xx.shape[0] // 2
        qedd = mdl.inverse_dynamics(robot, qa, xx[:ne], jnp.zeros(2), xx[ne:], jnp.zeros(2))[0]
        k = jnp.concatenate([xx[ne:], qedd])
        return (k, acc + b * k), None

    def step(x, _):
        zero = jnp.zeros_like(x)
        (_, acc), _ = jax.lax.scan(lambda c, coef: stage(x, c, coef), (zero, zero), (a_coef, b_coef))
        new = x + dt * acc
        return new, new

    xs = jax.lax.scan(step, jnp.concatenate([qe0, qed0]), None, length=steps)[1]
    ne = qe0.shape[0]
    return xs[:, :ne], xs[:, ne:]


def test_energy_conserved_in_free_vibration_and_constraints_hold():
    robot = robot_preset("default", payload=6.0, gravity=(0.0, 0.0))
    qa = igm(robot, jnp.array([-0.1, 0.28]))
    qe0 = mdl.static_equilibrium(robot, qa, jnp.array([150.0, -80.0]))     # released from a load
    qed0 = jnp.asarray(np.random.default_rng(5).normal(scale=2e-3, size=12))
    qe, qed = _rk4_locked(robot, qa, qe0, qed0, dt=2e-6, steps=1500)

    def energy(qe_, qed_):
        red = mdl.reduced(robot, qa, qe_, jnp.zeros(2), qed_)
        return 0.5 * qed_ @ red.mass[2:, 2:] @ qed_ + mdl.potential(robot, red.q)

    e = jax.jit(jax.vmap(energy))(jnp.concatenate([qe0[None], qe[::250]]), jnp.concatenate([qed0[None], qed[::250]]))
    e0, e = e[0], e[1:]
    assert float(jnp.max(jnp.abs(e - e0))) < 1e-6 * float(e0)     # RK4 at dt = 2 us: ~1e-8 drift
    # constraints stay at round-off along the run (closed-form passive coordinates)
    res = jax.jit(jax.vmap(lambda x: mdl.constraints(robot, mdl.full_coordinates(robot, qa, x))))(qe[::125])
    assert float(jnp.max(jnp.abs(res))) < 1e-15
    # the run really vibrates: elastic energy oscillates by a large fraction
    assert float(jnp.max(jnp.abs(qe[:, :3] - qe0[None, :3]))) > 0.3 * float(jnp.max(jnp.abs(qe0[:3])))


def test_damping_dissipates_energy():
    robot = robot_preset("default", payload=6.0, gravity=(0.0, 0.0), damping=(0.0, 2e-5))
    qa = igm(robot, jnp.array([-0.1, 0.28]))
    qe0 = mdl.static_equilibrium(robot, qa, jnp.array([150.0, -80.0]))
    qe, qed = _rk4_locked(robot, qa, qe0, jnp.zeros(12), dt=2e-6, steps=1500)   # the program above
    e = jax.jit(lambda a, b: mdl.potential(robot, mdl.full_coordinates(robot, qa, a)) + 0.5 * b @ mdl.reduced(
        robot, qa, a, jnp.zeros(2), b).mass[2:, 2:] @ b)
    assert float(e(qe[-1], qed[-1])) < 0.999 * float(e(qe0, jnp.zeros(12)))


# ---------------------------------------------------------------------------- natural frequencies


@pytest.fixture(scope="module")
def path_points():
    c = cycle_preset("default")
    lift, pick, place = np.asarray(c.lift) * 0.025, np.asarray(c.pick), np.asarray(c.place)
    return jnp.asarray([pick, pick + lift, 0.5 * (pick + place) + lift, place + lift, place])


@pytest.mark.parametrize("payload, k, lo, hi", [
    (6.0, 0, 57.0, 60.0),          # paper 58 +- 1 Hz; FE reference 57-60 Hz
    (0.1, 0, 124.0, 129.0),        # paper 126 +- 2 Hz; FE 125-129 Hz
    (0.1, 2, 1860.0, 1940.0),      # paper 1912 +- 7.5 Hz; FE ~1890-1900 Hz (a few percent)
])
def test_natural_frequencies_along_path(path_points, payload, k, lo, hi):
    robot = robot_preset("default", payload=payload)
    freqs = np.stack([modes_at_point(robot, x) for x in path_points])     # the library's one program
    assert np.all(np.asarray(freqs[:, k]) > lo) and np.all(np.asarray(freqs[:, k]) < hi), freqs[:, k]


def test_locked_modes_are_mass_normalized(robot6, pose):
    freqs, shapes = jax.jit(mdl.locked_modes)(robot6, pose)
    m = _reduced(robot6, pose, jax.jit(mdl.static_equilibrium)(robot6, pose), jnp.zeros(2), jnp.zeros(12)).mass[2:, 2:]
    np.testing.assert_allclose(shapes.T @ m @ shapes, np.eye(12), atol=1e-9)
    assert np.all(np.diff(np.asarray(freqs)) >= 0)


def test_singular_or_unreachable_pose_is_rejected(robot6):
    with pytest.raises(ValueError, match="unreachable by arm 1"):
        modes_at_point(robot6, jnp.array([-0.7, 0.3]))
    reach = np.sqrt((L1 + L2) ** 2 - 0.0**2)
    with pytest.raises(ValueError, match="serial singularity of arm 1"):
        modes_at_point(robot6, jnp.array([-0.1, reach - 1e-7]))


def test_static_deflection_is_the_gravity_sag(robot6, pose):
    sag = mdl.static_deflection(robot6, pose)
    no_g = mdl.static_deflection(robot6.replace(gravity=jnp.zeros(2)), pose)
    assert float(jnp.linalg.norm(no_g)) < 1e-18
    assert 1e-5 < float(sag[1]) < 1e-4          # tens of micrometres under 6 kg


@pytest.mark.parametrize("richer", [False, True])
def test_block_assembly_equals_indexed_updates(richer):
    """The mass matrix is assembled from slices and concatenations (``model._embed_blocks``), not
    scattered with ``.at`` (XLA:CPU runs scatters as loops). With the model's own index sets and
    random blocks, the assembly equals the indexed updates exactly; overlapping index sets and
    non-contiguous slices are refused."""
    robot = robot_preset("default")
    robot = mdl.richer(robot) if richer else robot
    lay = mdl.layout(robot)
    idx = [np.r_[lay.a[0], lay.e_beam[0]], np.r_[lay.base12, lay.e_beam[1]],
           np.r_[lay.a[1], lay.e_beam[2]], np.r_[lay.base22, lay.e_beam[3]]]
    rng = np.random.default_rng(0)
    blocks = [(jnp.asarray(rng.normal(size=(len(i), len(i)))), i) for i in idx]
    expected = jnp.zeros((lay.n, lay.n))
    for b, i in blocks:
        expected = expected.at[np.ix_(i, i)].add(b)
    np.testing.assert_array_equal(np.asarray(mdl._embed_blocks(lay.n, blocks)), np.asarray(expected))
    with pytest.raises(ValueError, match="overlap"):
        mdl._embed_blocks(lay.n, blocks + [(jnp.eye(1), lay.a[:1])])
    q = jnp.arange(lay.n, dtype=float)
    np.testing.assert_array_equal(np.asarray(mdl._part(q, lay.e)), np.asarray(q[lay.e]))
    with pytest.raises(ValueError, match="consecutive"):
        mdl._part(q, np.r_[lay.a, lay.p])
