"""Elastodynamic model of the five-bar (paper Section 2): assumed modes, Lagrangian, closed loop.

Generalized coordinates (paper Eq. 17-19), full vector q of size N = 10 + ne:

    q = [q_a (2) | q_e (ne) | q_p (8)]
    q_a = [theta_11, theta_21]                       actuated (motor) angles [rad]
    q_e = [q_e11 (nb), q_e12 (na), q_e21 (nb), q_e22 (na)]  elastic coordinates (modal amplitudes, m)
    q_p = [x_12, y_12, theta_12, x_22, y_22, theta_22, x, y] passive coordinates (m, rad)

Beam j has coordinates [x_A, y_A, theta, q_e] (the proximal beams' bases are the fixed motors).
The kinetic energy of each beam is the exact integral of Eq. 4 with the position of Eq. 5 (the
paper's Eqs. 7 and 9 are the same matrices written in the beam frame), the elastic energy is Eq. 10-13
and the gravity energy Eq. 14-16 with the gravity vector of the robot. The payload is a point mass at
the end effector (x, y); an optional rotor inertia acts on q_a.

The loop closure f(q) = 0 (Eq. 18, deflections taken at the distal end xi = 1) is solved for q_p in
closed form (tip of each proximal beam, then intersection of two circles whose radii are the
stretched distal links), so the constraints hold to round-off at every evaluation. The Jacobians
A = df/dq_p, B = df/dq_e, C = df/dq_a (Eq. 19) come from autodiff and give the velocity map
q' = W q_i' (q_i = [q_a, q_e] the independent coordinates) and the acceleration term w (q'' = W q_i'' + w).
Lagrange's equations projected on the independent coordinates,

    W^T [M(q) q'' + h(q, q') + dV/dq + D q'] = [tau; 0],

give the reduced mass matrix M_r = W^T M W and the force vector F = W^T (M w + h + dV/dq + D q'):
M_r q_i'' + F = [tau; 0]. h = M' q' - dT/dq holds the Coriolis and centrifugal terms (autodiff).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import linalg
from jaxflex.beams import beam_modes
from jaxflex.robot import Robot, check_reachable, circle_intersection, igm


class Layout(NamedTuple):
    """Index sets of the full coordinate vector (static numpy int arrays)."""

    n: int
    ne: int
    a: np.ndarray          # actuated
    e: np.ndarray          # elastic
    p: np.ndarray          # passive
    e_beam: tuple          # (e11, e12, e21, e22)
    base12: np.ndarray     # x12, y12, theta12
    base22: np.ndarray     # x22, y22, theta22
    ee: np.ndarray         # x, y


def layout(robot: Robot) -> Layout:
    """Coordinate layout for the robot's mode counts."""
    nb, na = robot.n_bending, robot.n_axial
    ne = 2 * nb + 2 * na
    starts = np.cumsum([2, nb, na, nb])
    sizes = (nb, na, nb, na)
    e_beam = tuple(np.arange(s, s + k) for s, k in zip(starts, sizes))
    p0 = 2 + ne
    return Layout(n=p0 + 8, ne=ne, a=np.arange(2), e=np.arange(2, p0), p=np.arange(p0, p0 + 8),
                  e_beam=e_beam, base12=np.arange(p0, p0 + 3), base22=np.arange(p0 + 3, p0 + 6),
                  ee=np.arange(p0 + 6, p0 + 8))


def _rot(th):
    c, s = jnp.cos(th), jnp.sin(th)
    return jnp.array([[c, -s], [s, c]])


def _masses(robot: Robot):
    """Link masses rho A l [kg] of the proximal and distal links."""
    return robot.rho * robot.area * robot.l1, robot.rho * robot.area * robot.l2


def stiffness_blocks(robot: Robot):
    """Elastic stiffness matrices (K_proximal (nb, nb) [N/m], K_distal (na, na) [N/m]), Eqs. 11, 13."""
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    kb = robot.young * robot.second_moment / robot.l1**3 * jnp.asarray(bend.stiffness)
    ka = robot.young * robot.area / robot.l2 * jnp.asarray(ax.stiffness)
    return kb, ka


def _bending_beam_mass(m, l, modes, th, qe):
    """Mass matrix (3 + n) of a beam in bending, coordinates [x_A, y_A, theta, q_e] (Eq. 7, exact)."""
    r = _rot(th)
    phi = jnp.asarray(modes.phi_int)
    mphi = jnp.asarray(modes.mass)
    n = phi.shape[0]
    m_at = m * r @ jnp.stack([-phi @ qe, 0.5 * l])
    m_aq = m * r @ jnp.stack([jnp.zeros(n), phi])
    m_tt = m * (l * l / 3.0 + qe @ mphi @ qe)
    m_tq = m * l * jnp.asarray(modes.xi_phi_int)
    top = jnp.concatenate([m * jnp.eye(2), m_at[:, None], m_aq], axis=1)
    mid = jnp.concatenate([m_at, m_tt[None], m_tq])[None]
    bot = jnp.concatenate([m_aq.T, m_tq[:, None], m * mphi], axis=1)
    return jnp.concatenate([top, mid, bot], axis=0)


def _axial_beam_mass(m, l, modes, th, qe):
    """Mass matrix (3 + n) of a beam in tension-compression, coordinates [x_A, y_A, theta, q_e] (Eq. 9)."""
    r = _rot(th)
    phi = jnp.asarray(modes.phi_int)
    mphi = jnp.asarray(modes.mass)
    n = phi.shape[0]
    m_at = m * r @ jnp.stack([0.0, 0.5 * l + phi @ qe])
    m_aq = m * r @ jnp.stack([phi, jnp.zeros(n)])
    m_tt = m * (l * l / 3.0 + 2.0 * l * jnp.asarray(modes.xi_phi_int) @ qe + qe @ mphi @ qe)
    top = jnp.concatenate([m * jnp.eye(2), m_at[:, None], m_aq], axis=1)
    mid = jnp.concatenate([m_at, m_tt[None], jnp.zeros(n)])[None]
    bot = jnp.concatenate([m_aq.T, jnp.zeros((n, 1)), m * mphi], axis=1)
    return jnp.concatenate([top, mid, bot], axis=0)


def _split(robot: Robot, q):
    lay = layout(robot)
    e11, e12, e21, e22 = (q[i] for i in lay.e_beam)
    return lay, q[lay.a], (e11, e12, e21, e22), q[lay.base12], q[lay.base22], q[lay.ee]


def mass_matrix(robot: Robot, q) -> jax.Array:
    """Full (N, N) mass matrix M(q) [kg, kg m, kg m^2] of beams, payload and rotors."""
    lay, qa, (e11, e12, e21, e22), b12, b22, _ = _split(robot, q)
    m1, m2 = _masses(robot)
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    out = jnp.zeros((lay.n, lay.n))
    blocks = [
        # (beam mass matrix, full-coordinate indices of its [theta, q_e] or [x, y, theta, q_e])
        (_bending_beam_mass(m1, robot.l1, bend, qa[0], e11)[2:, 2:], np.r_[lay.a[0], lay.e_beam[0]]),
        (_axial_beam_mass(m2, robot.l2, ax, b12[2], e12), np.r_[lay.base12, lay.e_beam[1]]),
        (_bending_beam_mass(m1, robot.l1, bend, qa[1], e21)[2:, 2:], np.r_[lay.a[1], lay.e_beam[2]]),
        (_axial_beam_mass(m2, robot.l2, ax, b22[2], e22), np.r_[lay.base22, lay.e_beam[3]]),
    ]
    for block, idx in blocks:
        out = out.at[np.ix_(idx, idx)].add(block)
    out = out.at[lay.ee, lay.ee].add(robot.payload)
    out = out.at[lay.a, lay.a].add(robot.rotor_inertia)
    return out


def potential(robot: Robot, q) -> jax.Array:
    """Elastic (Eq. 10-13) plus gravitational (Eq. 14-16) potential energy [J]; gravity force = m g."""
    lay, qa, (e11, e12, e21, e22), b12, b22, x = _split(robot, q)
    kb, ka = stiffness_blocks(robot)
    elastic = 0.5 * (e11 @ kb @ e11 + e21 @ kb @ e21 + e12 @ ka @ e12 + e22 @ ka @ e22)
    m1, m2 = _masses(robot)
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    pb, pa = jnp.asarray(bend.phi_int), jnp.asarray(ax.phi_int)
    # mean position of each beam: base + R(theta) * mean of [l xi + u_x, u_y]
    c1 = robot.bases[0] + _rot(qa[0]) @ jnp.stack([0.5 * robot.l1, pb @ e11])
    c2 = b12[:2] + _rot(b12[2]) @ jnp.stack([0.5 * robot.l2 + pa @ e12, 0.0])
    c3 = robot.bases[1] + _rot(qa[1]) @ jnp.stack([0.5 * robot.l1, pb @ e21])
    c4 = b22[:2] + _rot(b22[2]) @ jnp.stack([0.5 * robot.l2 + pa @ e22, 0.0])
    g = robot.gravity
    grav = -(m1 * g @ (c1 + c3) + m2 * g @ (c2 + c4) + robot.payload * g @ x)
    return elastic + grav


def damping_forces(robot: Robot, qd) -> jax.Array:
    """Rayleigh damping forces D q' on the elastic coordinates (D = alpha M_e + beta K_e), (N,)."""
    lay = layout(robot)
    kb, ka = stiffness_blocks(robot)
    m1, m2 = _masses(robot)
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    alpha, beta = robot.damping[0], robot.damping[1]
    out = jnp.zeros(lay.n)
    for idx, k, mm in zip(lay.e_beam, (kb, ka, kb, ka),
                          (m1 * bend.mass, m2 * ax.mass, m1 * bend.mass, m2 * ax.mass)):
        out = out.at[idx].set((alpha * jnp.asarray(mm) + beta * k) @ qd[idx])
    return out


def tip_deflections(robot: Robot, qe):
    """Deflections at xi = 1: (u_y11, u_x12, u_y21, u_x22) [m] from the elastic coordinates (ne,)."""
    lay = layout(robot)
    off = lay.e[0]
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    tips = (bend.tip, ax.tip, bend.tip, ax.tip)
    return tuple(jnp.asarray(t) @ qe[idx - off] for t, idx in zip(tips, lay.e_beam))


def constraints(robot: Robot, q) -> jax.Array:
    """Loop-closure constraints f1..f8 of Eq. 18 (8,) [m]."""
    lay, qa, (e11, e12, e21, e22), b12, b22, x = _split(robot, q)
    u11, u12, u21, u22 = tip_deflections(robot, q[lay.e])
    f12 = x - b12[:2] - robot.l2 * jnp.stack([jnp.cos(b12[2]), jnp.sin(b12[2])]) \
        - _rot(b12[2]) @ jnp.stack([u12, 0.0])
    f34 = x - b22[:2] - robot.l2 * jnp.stack([jnp.cos(b22[2]), jnp.sin(b22[2])]) \
        - _rot(b22[2]) @ jnp.stack([u22, 0.0])
    f56 = b12[:2] - robot.bases[0] - robot.l1 * jnp.stack([jnp.cos(qa[0]), jnp.sin(qa[0])]) \
        - _rot(qa[0]) @ jnp.stack([0.0, u11])
    f78 = b22[:2] - robot.bases[1] - robot.l1 * jnp.stack([jnp.cos(qa[1]), jnp.sin(qa[1])]) \
        - _rot(qa[1]) @ jnp.stack([0.0, u21])
    return jnp.concatenate([f12, f34, f56, f78])


def constraint_jacobians(robot: Robot, q):
    """A = df/dq_p (8, 8), B = df/dq_e (8, ne), C = df/dq_a (8, 2) (Eq. 19, autodiff)."""
    lay = layout(robot)
    jac = jax.jacfwd(lambda qq: constraints(robot, qq))(q)
    return jac[:, lay.p], jac[:, lay.e], jac[:, lay.a]


def passive(robot: Robot, qa, qe) -> jax.Array:
    """Passive coordinates q_p (8,) solving f(q) = 0 in closed form for given q_a (2,), q_e (ne,)."""
    u11, u12, u21, u22 = tip_deflections(robot, qe)
    a12 = robot.bases[0] + _rot(qa[0]) @ jnp.stack([robot.l1, u11])
    a22 = robot.bases[1] + _rot(qa[1]) @ jnp.stack([robot.l1, u21])
    x = circle_intersection(a12, robot.l2 + u12, a22, robot.l2 + u22, robot.assembly)
    d1, d2 = x - a12, x - a22
    t12, t22 = jnp.arctan2(d1[1], d1[0]), jnp.arctan2(d2[1], d2[0])
    return jnp.concatenate([a12, t12[None], a22, t22[None], x])


def full_coordinates(robot: Robot, qa, qe) -> jax.Array:
    """Full coordinate vector q (N,) from the independent coordinates."""
    return jnp.concatenate([qa, qe, passive(robot, qa, qe)])


def ee_position(robot: Robot, qa, qe) -> jax.Array:
    """End-effector position (2,) [m] of the deformed robot."""
    return passive(robot, qa, qe)[6:8]


def velocity_map(robot: Robot, q) -> jax.Array:
    """W (N, 2 + ne): q' = W [q_a', q_e'] at the full coordinates q (N,).

    The passive rows are the Jacobian of the closed-form loop closure ``passive``, which equals
    -A^-1 [C B] of Eq. 19 (implicit function theorem) without a linear solve."""
    lay = layout(robot)
    return _velocity_map(robot, jnp.concatenate([q[lay.a], q[lay.e]]))


def _passive_of(robot):
    return lambda qi: passive(robot, qi[:2], qi[2:])


def _velocity_map(robot, qi):
    wp = jax.jacfwd(_passive_of(robot))(qi)
    return jnp.concatenate([jnp.eye(qi.shape[0]), wp], axis=0)


class Reduced(NamedTuple):
    """Equations of motion in the independent coordinates: M_r q_i'' + F = [tau; 0].

    mass (2 + ne, 2 + ne); force (2 + ne,); q (N,) full coordinates; qd (N,) full velocities;
    w_map (N, 2 + ne) velocity map W; w_acc (N,) the acceleration term w.
    """

    mass: jax.Array
    force: jax.Array
    q: jax.Array
    qd: jax.Array
    w_map: jax.Array
    w_acc: jax.Array


def reduced(robot: Robot, qa, qe, qad, qed) -> Reduced:
    """Reduced mass matrix and force vector at the state (q_a, q_e, q_a', q_e')."""
    lay = layout(robot)
    q = full_coordinates(robot, qa, qe)
    qi = jnp.concatenate([qa, qe])
    qid = jnp.concatenate([qad, qed])
    wm = _velocity_map(robot, qi)
    qd = wm @ qid
    # acceleration term: q_p'' = W_p q_i'' + w_p with w_p the second directional derivative of the
    # closed-form q_p(q_i) along q_i' (equals -A^-1 gamma, gamma = f_qq[q', q'], without a solve)
    pas = _passive_of(robot)
    pdot = lambda x: jax.jvp(pas, (x,), (qid,))[1]
    w_acc = jnp.zeros(lay.n).at[lay.p].set(jax.jvp(pdot, (qi,), (qid,))[1])
    mq = mass_matrix(robot, q)
    mdot_qd = jax.jvp(lambda qq: mass_matrix(robot, qq) @ qd, (q,), (qd,))[1]
    dtdq = jax.grad(lambda qq: 0.5 * qd @ mass_matrix(robot, qq) @ qd)(q)
    h = mdot_qd - dtdq
    dv = jax.grad(lambda qq: potential(robot, qq))(q)
    gen = mq @ w_acc + h + dv + damping_forces(robot, qd)
    return Reduced(mass=wm.T @ mq @ wm, force=wm.T @ gen, q=q, qd=qd, w_map=wm, w_acc=w_acc)


def direct_dynamics(robot: Robot, qa, qe, qad, qed, tau):
    """Direct dynamic model: motor torques tau (2,) [N m] -> (q_a'' (2,), q_e'' (ne,))."""
    red = reduced(robot, qa, qe, qad, qed)
    rhs = jnp.concatenate([tau, jnp.zeros_like(qe)]) - red.force
    acc = linalg.spd_solve(red.mass, rhs)
    return acc[:2], acc[2:]


def inverse_dynamics(robot: Robot, qa, qe, qad, qed, qadd):
    """Inverse dynamic model (perfect controller): prescribed q_a'' (2,) -> (q_e'' (ne,), tau (2,))."""
    red = reduced(robot, qa, qe, qad, qed)
    m, f = red.mass, red.force
    qedd = linalg.spd_solve(m[2:, 2:], -f[2:] - m[2:, :2] @ qadd)
    tau = m[:2, :2] @ qadd + m[:2, 2:] @ qedd + f[:2]
    return qedd, tau


def elastic_force(robot: Robot, qa, qe, external=None):
    """Static generalized force on the elastic coordinates, W_e^T (dV/dq - Q_ext) (ne,), motors at q_a.

    ``external`` is an optional end-effector force (2,) [N]."""
    lay = layout(robot)
    q = full_coordinates(robot, qa, qe)
    wm = velocity_map(robot, q)
    gen = jax.grad(lambda qq: potential(robot, qq))(q)
    if external is not None:
        gen = gen.at[lay.ee].add(-external)
    return (wm.T @ gen)[2:]


def static_equilibrium(robot: Robot, qa, external=None, iterations: int = 8) -> jax.Array:
    """Elastic coordinates q_e (ne,) in static equilibrium with the motors locked at q_a (2,), under
    gravity and an optional end-effector force (2,) [N] (Newton on the reduced potential gradient)."""
    lay = layout(robot)

    def step(qe, _):
        r = elastic_force(robot, qa, qe, external)
        k = jax.jacfwd(lambda x: elastic_force(robot, qa, x, external))(qe)
        return qe - linalg.solve(k, r), None

    qe, _ = jax.lax.scan(step, jnp.zeros(lay.ne), None, length=iterations)
    return qe


def locked_stiffness(robot: Robot, qa, qe) -> jax.Array:
    """Tangent stiffness d(elastic_force)/dq_e (ne, ne) with the motors locked (symmetric)."""
    k = jax.jacfwd(lambda x: elastic_force(robot, qa, x))(qe)
    return 0.5 * (k + k.T)


def locked_modes(robot: Robot, qa):
    """Natural frequencies [Hz] (ne,) ascending and mode shapes (ne, ne) (columns, mass-normalized)
    with the motors locked at q_a, linearized about the static equilibrium under gravity."""
    qe = static_equilibrium(robot, qa)
    k = locked_stiffness(robot, qa, qe)
    m = reduced(robot, qa, qe, jnp.zeros(2), jnp.zeros_like(qe)).mass[2:, 2:]
    inv = linalg.lower_inverse(linalg.cholesky(m))
    lam, vec = jnp.linalg.eigh(inv @ k @ inv.T)
    shapes = inv.T @ vec
    return jnp.sqrt(jnp.maximum(lam, 0.0)) / (2.0 * jnp.pi), shapes


def static_deflection(robot: Robot, qa, external=None) -> jax.Array:
    """End-effector deflection (2,) [m] of the static equilibrium at the motor angles q_a w.r.t. the
    rigid pose (gravity and an optional end-effector force [N])."""
    qe = static_equilibrium(robot, qa, external)
    return ee_position(robot, qa, qe) - ee_position(robot, qa, jnp.zeros_like(qe))


def _frequencies_at_point(robot: Robot, x):
    return locked_modes(robot, igm(robot, x))[0]


_frequencies_at_point_jit = jax.jit(_frequencies_at_point)


def modes_at_point(robot: Robot, x):
    """Locked-motor natural frequencies [Hz] (ne,) at end-effector position x (2,) (rigid IGM pose).

    A concrete (non-traced) x is first checked for reachability and singularity (ValueError), then
    evaluated by one compiled program (shared by every caller with the same mode counts)."""
    if any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves((robot, x))):
        return _frequencies_at_point(robot, x)
    check_reachable(robot, np.asarray(x)[None], "pose")
    return _frequencies_at_point_jit(robot, jnp.asarray(x, dtype=float))
