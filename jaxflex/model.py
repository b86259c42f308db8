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

The richer model (``richer``; it validates designs and never trains them,
docs/conventions.md#elastodynamic-model) gives every link both kinds of modes: the proximal links also
stretch (``n_axial_proximal`` fixed-free bar modes after their bending ones) and the distal links
also bend (``n_bending_distal`` clamped-free modes in the frame of the link, after their axial ones).
A link with both has the exact kinetic energy of Eq. 4 with u = (l xi + u_x, u_y) in its frame, which
couples the two sets through the frame rotation (``beams.cross_mass``); its tip moves by
(u_x(1), u_y(1)) in the loop closure.

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
from jaxflex.beams import beam_modes, cross_mass
from jaxflex.robot import Robot, circle_intersection, igm


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
    """Coordinate layout for the robot's mode counts (each beam: its primary modes, bending for the
    proximal and axial for the distal links, then the richer model's secondary ones)."""
    n1 = robot.n_bending + robot.n_axial_proximal
    n2 = robot.n_axial + robot.n_bending_distal
    ne = 2 * n1 + 2 * n2
    starts = np.cumsum([2, n1, n2, n1])
    sizes = (n1, n2, n1, n2)
    e_beam = tuple(np.arange(s, s + k) for s, k in zip(starts, sizes))
    p0 = 2 + ne
    return Layout(n=p0 + 8, ne=ne, a=np.arange(2), e=np.arange(2, p0), p=np.arange(p0, p0 + 8),
                  e_beam=e_beam, base12=np.arange(p0, p0 + 3), base22=np.arange(p0 + 3, p0 + 6),
                  ee=np.arange(p0 + 6, p0 + 8))


def _assemble(lay: Layout, a, e, p) -> jax.Array:
    """The full-coordinate vector (N,) from its actuated (2,), elastic (ne,) and passive (8,) parts.

    The layout is contiguous in that order (``layout``), so this is a concatenation: an indexed
    update (``.at[idx].set``) would compile to a scatter, which XLA:CPU runs as a loop over its
    indices (inside the batched remainder and, as the derivative of a gather, in its gradient)."""
    assert lay.p[-1] == lay.n - 1 and lay.e[0] == lay.a[-1] + 1 and lay.p[0] == lay.e[-1] + 1
    assert list(lay.ee) == list(lay.p[6:8])
    return jnp.concatenate([a, e, p])


def _part(x, idx) -> jax.Array:
    """x[idx] for a contiguous static index run (a slice, not a gather: a gather's derivative is a
    scatter, see ``_assemble``)."""
    idx = np.asarray(idx)
    if idx.size == 0 or np.any(np.diff(idx) != 1):
        raise ValueError("_part: the indices must be a non-empty run of consecutive integers")
    return x[int(idx[0]):int(idx[-1]) + 1]


def _embed_blocks(n: int, blocks) -> jax.Array:
    """The (n, n) matrix with the square ``blocks`` [(matrix (k, k), full-coordinate indices (k,))]
    at their indices and zeros elsewhere; the index sets must be disjoint.

    Built from static slices and concatenations over the runs of consecutive coordinates that
    belong to one block in order (the same values as adding the blocks into zeros with ``.at``,
    without a scatter: see ``_assemble``)."""
    owner, local = np.full(n, -1), np.zeros(n, int)
    for b, (_, idx) in enumerate(blocks):
        if np.any(owner[idx] >= 0):
            raise ValueError("_embed_blocks: the blocks' index sets overlap")
        owner[idx], local[idx] = b, np.arange(len(idx))
    runs, i = [], 0                           # (start, stop, owning block or -1, its first local index)
    while i < n:
        j = i + 1
        while j < n and owner[j] == owner[i] and (owner[i] < 0 or local[j] == local[j - 1] + 1):
            j += 1
        runs.append((i, j, owner[i], local[i]))
        i = j
    rows = []
    for r0, r1, rb, rl in runs:
        rows.append(jnp.concatenate([
            blocks[rb][0][rl:rl + r1 - r0, cl:cl + c1 - c0] if rb >= 0 and rb == cb else jnp.zeros((r1 - r0, c1 - c0))
            for c0, c1, cb, cl in runs], axis=1))
    return jnp.concatenate(rows, axis=0)


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


def richer(robot: Robot, n: int = 3) -> Robot:
    """The richer validation model of ``robot`` (docs/conventions.md#elastodynamic-model): every link
    flexible in bending and in tension-compression, ``n`` modes of each kind it lacks (axial on the
    proximal, bending on the distal links) added to its own."""
    return robot.replace(n_axial_proximal=int(n), n_bending_distal=int(n))


def _secondary(robot: Robot):
    """The richer model's extra mode data: (proximal axial modes, distal bending modes, proximal
    cross integrals, distal cross integrals, K_proximal_axial, K_distal_bending); None parts if absent."""
    nap, nbd = robot.n_axial_proximal, robot.n_bending_distal
    pa = beam_modes("axial", nap) if nap else None
    db = beam_modes("bending", nbd) if nbd else None
    cp = jnp.asarray(cross_mass(nap, robot.n_bending)) if nap else None
    cd = jnp.asarray(cross_mass(robot.n_axial, nbd)) if nbd else None
    kpa = robot.young * robot.area / robot.l1 * jnp.asarray(pa.stiffness) if nap else None
    kdb = robot.young * robot.second_moment / robot.l2**3 * jnp.asarray(db.stiffness) if nbd else None
    return pa, db, cp, cd, kpa, kdb


def _beam_parts(robot: Robot, qe_beams):
    """Each beam's elastic coordinates split into (bending, axial) parts (None where absent)."""
    nb, na = robot.n_bending, robot.n_axial
    e11, e12, e21, e22 = qe_beams
    prox = lambda e: (e[:nb], e[nb:] if robot.n_axial_proximal else None)
    dist = lambda e: (e[na:] if robot.n_bending_distal else None, e[:na])
    return prox(e11), dist(e12), prox(e21), dist(e22)


def _two_set_beam_mass(m, l, bend, ax, cross, th, qb, qx, axial_first: bool):
    """Mass matrix (3 + nb + na) of a beam with bending (qb) and axial (qx) modes, coordinates
    [x_A, y_A, theta, first set, second set] (axial first if ``axial_first``): the exact integral of
    Eq. 4 with the position A + R(theta) (l xi + phi_x . qx, phi_b . qb); ``cross`` (na, nb) =
    int phi_x phi_b^T."""
    r = _rot(th)
    pb, px = jnp.asarray(bend.phi_int), jnp.asarray(ax.phi_int)
    mb, mx = jnp.asarray(bend.mass), jnp.asarray(ax.mass)
    nb, nx = pb.shape[0], px.shape[0]
    m_at = m * r @ jnp.stack([-pb @ qb, 0.5 * l + px @ qx])
    m_ab = m * r @ jnp.stack([jnp.zeros(nb), pb])
    m_ax = m * r @ jnp.stack([px, jnp.zeros(nx)])
    m_tt = m * (l * l / 3.0 + 2.0 * l * jnp.asarray(ax.xi_phi_int) @ qx + qx @ mx @ qx + qb @ mb @ qb)
    m_tb = m * (l * jnp.asarray(bend.xi_phi_int) + cross.T @ qx)          # int (l xi + u_x) phi_b
    m_tx = -m * (cross @ qb)                                                # int (-u_y) phi_x
    zbx = jnp.zeros((nb, nx))
    if axial_first:
        m_aq, m_tq = jnp.concatenate([m_ax, m_ab], axis=1), jnp.concatenate([m_tx, m_tb])
        m_qq = jnp.block([[m * mx, zbx.T], [zbx, m * mb]])
    else:
        m_aq, m_tq = jnp.concatenate([m_ab, m_ax], axis=1), jnp.concatenate([m_tb, m_tx])
        m_qq = jnp.block([[m * mb, zbx], [zbx.T, m * mx]])
    top = jnp.concatenate([m * jnp.eye(2), m_at[:, None], m_aq], axis=1)
    mid = jnp.concatenate([m_at, m_tt[None], m_tq])[None]
    bot = jnp.concatenate([m_aq.T, m_tq[:, None], m_qq], axis=1)
    return jnp.concatenate([top, mid, bot], axis=0)


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
    e11, e12, e21, e22 = (_part(q, i) for i in lay.e_beam)
    return lay, _part(q, lay.a), (e11, e12, e21, e22), _part(q, lay.base12), _part(q, lay.base22), _part(q, lay.ee)


def mass_matrix(robot: Robot, q) -> jax.Array:
    """Full (N, N) mass matrix M(q) [kg, kg m, kg m^2] of beams, payload and rotors."""
    lay, qa, (e11, e12, e21, e22), b12, b22, _ = _split(robot, q)
    m1, m2 = _masses(robot)
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    pa, db, cp, cd, _, _ = _secondary(robot)
    p11, p12, p21, p22 = _beam_parts(robot, (e11, e12, e21, e22))
    prox = lambda th, e, parts: (_bending_beam_mass(m1, robot.l1, bend, th, e) if pa is None else
                                 _two_set_beam_mass(m1, robot.l1, bend, pa, cp, th, *parts, axial_first=False))
    dist = lambda th, e, parts: (_axial_beam_mass(m2, robot.l2, ax, th, e) if db is None else
                                 _two_set_beam_mass(m2, robot.l2, db, ax, cd, th, *parts, axial_first=True))
    blocks = [
        # (beam mass matrix, full-coordinate indices of its [theta, q_e] or [x, y, theta, q_e])
        (prox(qa[0], e11, p11)[2:, 2:], np.r_[lay.a[0], lay.e_beam[0]]),
        (dist(b12[2], e12, p12), np.r_[lay.base12, lay.e_beam[1]]),
        (prox(qa[1], e21, p21)[2:, 2:], np.r_[lay.a[1], lay.e_beam[2]]),
        (dist(b22[2], e22, p22), np.r_[lay.base22, lay.e_beam[3]]),
    ]
    # rotor inertia on the motors' diagonal, the payload on the end effector's (the last two passive
    # coordinates, ``layout``)
    diag = _assemble(lay, jnp.broadcast_to(robot.rotor_inertia, (2,)), jnp.zeros(lay.ne),
                     jnp.concatenate([jnp.zeros(6), jnp.broadcast_to(robot.payload, (2,))]))
    return _embed_blocks(lay.n, blocks) + jnp.diag(diag)


def potential(robot: Robot, q) -> jax.Array:
    """Elastic (Eq. 10-13) plus gravitational (Eq. 14-16) potential energy [J]; gravity force = m g."""
    lay, qa, (e11, e12, e21, e22), b12, b22, x = _split(robot, q)
    kb, ka = stiffness_blocks(robot)
    sa, sb, _, _, kpa, kdb = _secondary(robot)
    p11, p12, p21, p22 = _beam_parts(robot, (e11, e12, e21, e22))
    if sa is None and sb is None:
        elastic = 0.5 * (e11 @ kb @ e11 + e21 @ kb @ e21 + e12 @ ka @ e12 + e22 @ ka @ e22)
    else:
        elastic = 0.5 * (p11[0] @ kb @ p11[0] + p21[0] @ kb @ p21[0] + p12[1] @ ka @ p12[1] + p22[1] @ ka @ p22[1])
        if sa is not None:
            elastic = elastic + 0.5 * (p11[1] @ kpa @ p11[1] + p21[1] @ kpa @ p21[1])
        if sb is not None:
            elastic = elastic + 0.5 * (p12[0] @ kdb @ p12[0] + p22[0] @ kdb @ p22[0])
    m1, m2 = _masses(robot)
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    pb, pa = jnp.asarray(bend.phi_int), jnp.asarray(ax.phi_int)
    # mean position of each beam: base + R(theta) * mean of [l xi + u_x, u_y]
    stretch = lambda parts: 0.0 if sa is None else jnp.asarray(sa.phi_int) @ parts[1]
    sway = lambda parts: 0.0 if sb is None else jnp.asarray(sb.phi_int) @ parts[0]
    c1 = robot.bases[0] + _rot(qa[0]) @ jnp.stack([0.5 * robot.l1 + stretch(p11), pb @ p11[0]])
    c2 = b12[:2] + _rot(b12[2]) @ jnp.stack([0.5 * robot.l2 + pa @ p12[1], sway(p12)])
    c3 = robot.bases[1] + _rot(qa[1]) @ jnp.stack([0.5 * robot.l1 + stretch(p21), pb @ p21[0]])
    c4 = b22[:2] + _rot(b22[2]) @ jnp.stack([0.5 * robot.l2 + pa @ p22[1], sway(p22)])
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
    mp, md = m1 * jnp.asarray(bend.mass), m2 * jnp.asarray(ax.mass)
    sa, sb, _, _, kpa, kdb = _secondary(robot)
    if sa is not None:                       # block-diagonal: the two sets are orthogonal in the frame
        mp, kb = jax.scipy.linalg.block_diag(mp, m1 * jnp.asarray(sa.mass)), jax.scipy.linalg.block_diag(kb, kpa)
    if sb is not None:
        md, ka = jax.scipy.linalg.block_diag(md, m2 * jnp.asarray(sb.mass)), jax.scipy.linalg.block_diag(ka, kdb)
    forces = [(alpha * jnp.asarray(mm) + beta * k) @ _part(qd, idx)          # the beams in order
              for idx, k, mm in zip(lay.e_beam, (kb, ka, kb, ka), (mp, md, mp, md))]
    return _assemble(lay, jnp.zeros(2), jnp.concatenate(forces), jnp.zeros(8))


def tip_deflections(robot: Robot, qe):
    """Deflections at xi = 1: (u_y11, u_x12, u_y21, u_x22) [m] from the elastic coordinates (ne,)
    (the primary modes of each link; ``secondary_tips`` gives the richer model's others)."""
    lay = layout(robot)
    off = lay.e[0]
    bend, ax = beam_modes("bending", robot.n_bending), beam_modes("axial", robot.n_axial)
    tips = (bend.tip, ax.tip, bend.tip, ax.tip)
    sizes = (robot.n_bending, robot.n_axial, robot.n_bending, robot.n_axial)
    return tuple(jnp.asarray(t) @ _part(qe, idx[:n] - off) for t, idx, n in zip(tips, lay.e_beam, sizes))


def secondary_tips(robot: Robot, qe):
    """The richer model's tip deflections (u_x11, u_y12, u_x21, u_y22) [m] (axial stretch of the
    proximal and transverse deflection of the distal links at xi = 1), None for the paper's model."""
    sa, sb, *_ = _secondary(robot)
    if sa is None and sb is None:
        return None
    lay = layout(robot)
    off = lay.e[0]
    nb, na = robot.n_bending, robot.n_axial
    prox = lambda idx: 0.0 if sa is None else jnp.asarray(sa.tip) @ _part(qe, idx[nb:] - off)
    dist = lambda idx: 0.0 if sb is None else jnp.asarray(sb.tip) @ _part(qe, idx[na:] - off)
    e11, e12, e21, e22 = lay.e_beam
    return prox(e11), dist(e12), prox(e21), dist(e22)


def constraints(robot: Robot, q) -> jax.Array:
    """Loop-closure constraints f1..f8 of Eq. 18 (8,) [m]."""
    lay, qa, (e11, e12, e21, e22), b12, b22, x = _split(robot, q)
    u11, u12, u21, u22 = tip_deflections(robot, _part(q, lay.e))
    s11, s12, s21, s22 = secondary_tips(robot, _part(q, lay.e)) or (0.0, 0.0, 0.0, 0.0)
    f12 = x - b12[:2] - robot.l2 * jnp.stack([jnp.cos(b12[2]), jnp.sin(b12[2])]) \
        - _rot(b12[2]) @ jnp.stack([u12, s12])
    f34 = x - b22[:2] - robot.l2 * jnp.stack([jnp.cos(b22[2]), jnp.sin(b22[2])]) \
        - _rot(b22[2]) @ jnp.stack([u22, s22])
    f56 = b12[:2] - robot.bases[0] - robot.l1 * jnp.stack([jnp.cos(qa[0]), jnp.sin(qa[0])]) \
        - _rot(qa[0]) @ jnp.stack([s11, u11])
    f78 = b22[:2] - robot.bases[1] - robot.l1 * jnp.stack([jnp.cos(qa[1]), jnp.sin(qa[1])]) \
        - _rot(qa[1]) @ jnp.stack([s21, u21])
    return jnp.concatenate([f12, f34, f56, f78])


def constraint_jacobians(robot: Robot, q):
    """A = df/dq_p (8, 8), B = df/dq_e (8, ne), C = df/dq_a (8, 2) (Eq. 19, autodiff)."""
    lay = layout(robot)
    jac = jax.jacfwd(lambda qq: constraints(robot, qq))(q)
    return jac[:, lay.p], jac[:, lay.e], jac[:, lay.a]


def passive(robot: Robot, qa, qe) -> jax.Array:
    """Passive coordinates q_p (8,) solving f(q) = 0 in closed form for given q_a (2,), q_e (ne,)."""
    u11, u12, u21, u22 = tip_deflections(robot, qe)
    sec = secondary_tips(robot, qe)
    if sec is None:
        a12 = robot.bases[0] + _rot(qa[0]) @ jnp.stack([robot.l1, u11])
        a22 = robot.bases[1] + _rot(qa[1]) @ jnp.stack([robot.l1, u21])
        x = circle_intersection(a12, robot.l2 + u12, a22, robot.l2 + u22, robot.assembly)
        d1, d2 = x - a12, x - a22
        t12, t22 = jnp.arctan2(d1[1], d1[0]), jnp.arctan2(d2[1], d2[0])
        return jnp.concatenate([a12, t12[None], a22, t22[None], x])
    # richer model: the distal tip sits at (l2 + u_x, u_y) in the link frame, at the distance
    # rho = |(l2 + u_x, u_y)| from the elbow and the angle atan2(u_y, l2 + u_x) off the frame's axis
    s11, s12, s21, s22 = sec
    a12 = robot.bases[0] + _rot(qa[0]) @ jnp.stack([robot.l1 + s11, u11])
    a22 = robot.bases[1] + _rot(qa[1]) @ jnp.stack([robot.l1 + s21, u21])
    r1, r2 = robot.l2 + u12, robot.l2 + u22
    x = circle_intersection(a12, jnp.sqrt(r1**2 + s12**2), a22, jnp.sqrt(r2**2 + s22**2), robot.assembly)
    d1, d2 = x - a12, x - a22
    t12 = jnp.arctan2(d1[1], d1[0]) - jnp.arctan2(s12, r1)
    t22 = jnp.arctan2(d2[1], d2[0]) - jnp.arctan2(s22, r2)
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
    return _velocity_map(robot, _part(q, np.r_[lay.a, lay.e]))


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


def _mass_terms(robot: Robot, q, qd):
    """M(q) (N, N), M'q' = (dM/dq q') q' (N,) and dT/dq = 1/2 q'^T (dM/dq) q' (N,) at the full
    coordinates and velocities (q, q'), from one trace of the mass matrix: its linearization at q,
    applied to q' and transposed (the Lagrangian's Coriolis and centrifugal terms)."""
    mq, tangent = jax.linearize(lambda qq: mass_matrix(robot, qq), q)
    (dtdq,) = jax.linear_transpose(tangent, q)(0.5 * jnp.outer(qd, qd))
    return mq, tangent(qd) @ qd, dtdq


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
    w_acc = _assemble(lay, jnp.zeros(2), jnp.zeros(lay.ne), jax.jvp(pdot, (qi,), (qid,))[1])
    mq, mdot_qd, dtdq = _mass_terms(robot, q, qd)
    h = mdot_qd - dtdq
    dv = jax.grad(lambda qq: potential(robot, qq))(q)
    gen = mq @ w_acc + h + dv + damping_forces(robot, qd)
    return Reduced(mass=wm.T @ mq @ wm, force=wm.T @ gen, q=q, qd=qd, w_map=wm, w_acc=w_acc)


def reduced_mass(robot: Robot, qa, qe) -> jax.Array:
    """The reduced mass matrix W^T M(q) W (2 + ne, 2 + ne) at (q_a, q_e): ``reduced(...).mass``
    (which does not depend on the velocities) without tracing the forces."""
    wm = _velocity_map(robot, jnp.concatenate([qa, qe]))
    return wm.T @ mass_matrix(robot, full_coordinates(robot, qa, qe)) @ wm


def _moving_state(robot: Robot, qa, qe, qad, qed, qadd, qedd):
    """(layout, q, q', q'', project) at the state (q_a, q_e, q_a', q_e') and accelerations (q_a'',
    q_e''): the full coordinates, velocities and accelerations from the closed-form loop closure's
    directional derivatives (W v = [v; dq_p/dq_i v], q_p'' = W_p q_i'' + w_p), and ``project``, the
    VJP g_p -> (W_p^T g_p,) of the closure (W^T g = g_i + W_p^T g_p)."""
    lay = layout(robot)
    qi = jnp.concatenate([qa, qe])
    qid = jnp.concatenate([qad, qed])
    pas = _passive_of(robot)
    rate = lambda x: jax.jvp(pas, (x,), (qid,))
    (qp, qpd), (_, w_p) = jax.jvp(rate, (qi,), (qid,))      # q_p, q_p' = W_p q_i', w_p = q_p''|q_i''=0
    _, project = jax.vjp(pas, qi)                             # g_p -> W_p^T g_p
    qpdd = jax.jvp(pas, (qi,), (jnp.concatenate([qadd, qedd]),))[1] + w_p
    return lay, _assemble(lay, qa, qe, qp), _assemble(lay, qad, qed, qpd), _assemble(lay, qadd, qedd, qpdd), project


def _projected(lay: Layout, gen, project) -> jax.Array:
    """W^T g (2 + ne,) of a generalized force g (N,) on the full coordinates."""
    return _part(gen, np.r_[lay.a, lay.e]) + project(_part(gen, lay.p))[0]


def residual(robot: Robot, qa, qe, qad, qed, qadd, qedd) -> jax.Array:
    """M_r [q_a''; q_e''] + F (2 + ne,) at the state (q_a, q_e, q_a', q_e') and accelerations
    (q_a'', q_e''): the reduced equations' left-hand side (``reduced``), [N m; N].

    The same quantity as ``reduced(...).mass @ acc + reduced(...).force`` to round-off, without
    forming W or M_r: W v = [v; dq_p/dq_i v] and W^T g = g_i + (dq_p/dq_i)^T g_p are directional
    derivatives of the closed-form loop closure (two JVPs and one VJP instead of its (8, 2 + ne)
    Jacobian and the (N, N) x (N, 2 + ne) products), so it costs less than ``reduced``. The
    second-order remainder (``linearized.remainder``) evaluates it; its terms one by one are
    ``residual_term``."""
    lay, q, qd, qdd, project = _moving_state(robot, qa, qe, qad, qed, qadd, qedd)
    mq, mdot_qd, dtdq = _mass_terms(robot, q, qd)
    dv = jax.grad(lambda qq: potential(robot, qq))(q)
    gen = mq @ qdd + mdot_qd - dtdq + dv + damping_forces(robot, qd)
    return _projected(lay, gen, project)


RESIDUAL_TERMS = ("potential", "inertia", "motion")


def residual_term(robot: Robot, qa, qe, term: str, qad=None, qed=None, qadd=None) -> jax.Array:
    """One term (2 + ne,) of ``residual`` [N m; N], with q_e'' = 0; ``term`` (static):

    - ``"potential"``: W^T dV/dq, the residual at rest (q' = q'' = 0; the damping is then zero);
    - ``"inertia"``: W^T M(q) q'' with the motors accelerating at q_a'' = ``qadd`` from rest (q' = 0,
      so q_p'' = W_p q_i''): the residual's increase from rest that is linear in q_a'';
    - ``"motion"``: W^T (M(q) q'' + M' q' - dT/dq) at the velocities (``qad``, ``qed``) and q_a'' =
      ``qadd``: everything but the potential and the damping.

    So residual = potential + motion + damping forces, and at q' = 0 the motion term is the inertia
    term. Evaluating a term alone skips the others' arithmetic, and their derivatives: the
    linearization coefficients (``linearized.pose_coeffs``) take each one's Jacobian by q_e where a
    difference of whole residuals' would cost several times as much (and lose the small
    s'' and s'^2 stiffness terms to round-off against the large elastic stiffness)."""
    if term not in RESIDUAL_TERMS:
        raise ValueError(f"term must be one of {RESIDUAL_TERMS}, got {term!r}")
    needs = {"potential": (), "inertia": ("qadd",), "motion": ("qad", "qed", "qadd")}[term]
    missing = [name for name, v in zip(("qad", "qed", "qadd"), (qad, qed, qadd)) if name in needs and v is None]
    if missing:
        raise ValueError(f"the {term} term needs {', '.join(missing)}")
    if term == "motion":
        lay, q, qd, qdd, project = _moving_state(robot, qa, qe, qad, qed, qadd, jnp.zeros_like(qe))
        mq, mdot_qd, dtdq = _mass_terms(robot, q, qd)
        return _projected(lay, mq @ qdd + mdot_qd - dtdq, project)
    lay = layout(robot)
    qi = jnp.concatenate([qa, qe])
    qp, project = jax.vjp(_passive_of(robot), qi)
    q = _assemble(lay, qa, qe, qp)
    if term == "potential":
        return _projected(lay, jax.grad(lambda qq: potential(robot, qq))(q), project)
    qpdd = jax.jvp(_passive_of(robot), (qi,), (jnp.concatenate([qadd, jnp.zeros_like(qe)]),))[1]
    return _projected(lay, mass_matrix(robot, q) @ _assemble(lay, qadd, jnp.zeros_like(qe), qpdd), project)


def damping_matrix(robot: Robot) -> jax.Array:
    """D (ne, ne): the Rayleigh damping forces on the elastic coordinates are D q_e' (``damping_forces``;
    they do not depend on the pose, and act on no other coordinate)."""
    lay = layout(robot)
    force = lambda qed: _part(damping_forces(robot, _assemble(lay, jnp.zeros(2), qed, jnp.zeros(8))), lay.e)
    return jax.jacfwd(force)(jnp.zeros(lay.ne))


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
        gen = gen - _assemble(lay, jnp.zeros(2), jnp.zeros(lay.ne), jnp.concatenate([jnp.zeros(6), external]))
    return (wm.T @ gen)[2:]


def static_equilibrium(robot: Robot, qa, external=None, iterations: int = 8) -> jax.Array:
    """Elastic coordinates q_e (ne,) in static equilibrium with the motors locked at q_a (2,), under
    gravity and an optional end-effector force (2,) [N] (Newton on the reduced potential gradient)."""
    lay = layout(robot)

    def step(qe, _):
        force = lambda x: (elastic_force(robot, qa, x, external),) * 2
        k, r = jax.jacfwd(force, has_aux=True)(qe)       # the force traced once, with its tangents
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
    m = reduced_mass(robot, qa, qe)[2:, 2:]
    inv = linalg.lower_inverse(linalg.cholesky(m))
    lam, vec = jnp.linalg.eigh(inv @ k @ inv.T)
    shapes = inv.T @ vec
    return jnp.sqrt(jnp.maximum(lam, 0.0)) / (2.0 * jnp.pi), shapes


def static_deflection(robot: Robot, qa, external=None) -> jax.Array:
    """End-effector deflection (2,) [m] of the static equilibrium at the motor angles q_a w.r.t. the
    rigid pose (gravity and an optional end-effector force [N])."""
    qe = static_equilibrium(robot, qa, external)
    return ee_position(robot, qa, qe) - ee_position(robot, qa, jnp.zeros_like(qe))


def frequencies_at_point(robot: Robot, x):
    """Locked-motor natural frequencies [Hz] (ne,) at end-effector position x (2,) [m] (the rigid
    IGM pose). Traceable; on concrete values ``jaxflex.frequencies.modes_at_point`` checks the pose
    and runs it compiled."""
    return locked_modes(robot, igm(robot, x))[0]
