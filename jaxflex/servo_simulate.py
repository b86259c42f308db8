"""The fast model under a servo loop: the motors free, driven by a sampled, held torque.

With the motors' deviation d = q_a - q_ref (``jaxflex.servo_linearized``) the linearized equations
in z = [d, q_e] (n = 2 + ne) are M z'' + C z' + K z = F + [u; 0], integrated as the prescribed model
is (``jaxflex.simulate``): coefficients frozen per coarse interval, every fine step propagated
exactly, a second pass with continuous coefficients and the full model's second-order remainder
along the first. The servo's torque u is computed at its samples t_k = k T and held; a sample
falls anywhere inside a fine step (at a fraction theta of it: the rate is a traced value, its
instants need not meet the grid), at most one per step (``check_schedule``). The step's end is then

    x+ = Phi x + (forcing) + G(h) u_old + G((1 - theta) h) (u_new - u_old),

G(t) = int_0^t e^{A s} ds B S the response to a held unit torque, and the controller reads d, d' at
the sample from the maps over [0, theta h]. Those sub-step maps are tabulated per coarse interval at
theta = i / P (P = ``NODES``) by exact recurrences from the matrix functions of the small step h / P,
and interpolated in theta by local Lagrange polynomials of degree ``DEGREE``. Their error grows as
(omega_max h / P)^(DEGREE + 1) for the stiffest mode omega_max: at P = 32 (omega_max h / P about 0.34
on the paper's robot) the interpolated rows are within 2e-7 of the exact ones (in the stiffest
mode, which the motion barely excites) and the closed loop's results within 2e-11 of P = 128's, at
under half the tables' cost of P = 64. The full-step maps come from the same small-step functions
by doubling; velocities are scaled by the stiffness scale so that every argument stays of the order
of omega h.

The motors' stiffness block of K holds only gravity and motion terms (no servo stiffness: the loop
is sampled), so K may be singular: unlike ``simulate``, the forcing integrals are phi functions, never
A^-1.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import linalg
from jaxflex.expm import phi_series
from jaxflex.linearized import FastCoeffs, SlowCoeffs, Tables, interpolate
from jaxflex.rigid import rigid_torques
from jaxflex.robot import Robot
from jaxflex.servo import Servo, static_torque
from jaxflex.servo_linearized import ServoCoeffs, servo_remainder
from jaxflex.simulate import (Grid, MotionSamples, Series, jump_nodes, per_interval, remainder_stencil,
                              low_mode_acceleration)

NODES = 32          # sub-step nodes per fine step (a power of 2: the full step by doubling)
DEGREE = 7          # the local interpolant's degree in theta
TAYLOR = 20         # terms of the small step's phi_2 series (|A h / NODES| about 0.8 at most: 1e-20)


class Schedule(NamedTuple):
    """Per fine step of the motion (N) then of the dwell (Nd): ``has`` whether a sample falls in it
    (1.0 or 0.0) and ``theta`` its fraction of the step in [0, 1)."""

    has: jax.Array
    theta: jax.Array


def sample_positions(t0, h, count, period):
    """(has, theta) (count,) of the steps [t0 + j h, t0 + (j + 1) h): whether a sample k T falls in
    the step, and at which fraction of it (each sample in exactly one step; T > h required)."""
    t = t0 + jnp.arange(count, dtype=float) * h
    eps = 1e-9
    k = jnp.ceil(t / period - eps)
    ts = k * period
    has = ts < t + h - eps * period
    theta = jnp.clip((ts - t) / h, 0.0, 1.0 - 1e-12)
    return has.astype(float), jnp.where(has, theta, 0.0)


def servo_schedule(tf, dwell, grid: Grid, period) -> Schedule:
    """The ``Schedule`` of a motion over [0, tf] [s] on the grid's steps, then its dwell [s] steps:
    samples every ``period`` [s] from t = 0."""
    n, nd = grid.steps, grid.dwell_steps
    has_m, th_m = sample_positions(0.0, tf / n, n, period)
    has_d, th_d = sample_positions(tf, dwell / nd, nd, period)
    return Schedule(jnp.concatenate([has_m, has_d]), jnp.concatenate([th_m, th_d]))


def rigid_feedforward(controller: Robot, tables: Tables, samples: MotionSamples) -> tuple:
    """The rigid feedforward [N m]: (N + 1, 2) at the grid's motion nodes, (2,) at rest at the place:
    the inverse dynamics of the rigid robot ``controller`` (the controller's model, rotor
    included, ``rigid.rigid_torques``) along the motor motion of the tables' path and law, then at
    rest at the place."""
    s = jnp.concatenate([samples.start[0], samples.end[0][-1:]])
    ds = jnp.concatenate([samples.start[1], samples.end[1][-1:]])
    dds = jnp.concatenate([samples.start[2], samples.end[2][-1:]])
    fast = jax.vmap(lambda x: interpolate(tables.fast(), x))(s)
    qd = fast.qa1 * ds[:, None]
    qdd = fast.qa2 * ds[:, None] ** 2 + fast.qa1 * dds[:, None]
    motion = jax.vmap(lambda q, v, a: rigid_torques(controller, q, v, a))(fast.qa, qd, qdd)
    zero = jnp.zeros(2)
    rest = rigid_torques(controller, interpolate(tables.fast(), tables.breaks[-1]).qa, zero, zero)
    return motion, rest


def flexible_feedforward(controller: Robot, series: Series, place_qa, advance=0.0) -> tuple:
    """The flexible feedforward [N m]: (N + 1, 2) at the motion's nodes, (2,) at rest at the place.
    Over the motion, the controller's model's perfect-controller torque ``series.tau`` at the node
    times advanced by ``advance`` [s] (``servo.feedforward_advance``; linear between nodes, held at
    its value at tf beyond); at rest, the torque that holds that model at the place motor angles
    place_qa (2,) [rad] (``servo.static_torque``): the controller is not told the dwell's vibration."""
    t = series.t
    at = jnp.clip(t + advance, t[0], t[-1])
    motion = jnp.stack([jnp.interp(at, t, series.tau[:, i]) for i in range(2)], axis=1)
    return motion, static_torque(controller, place_qa)


def feedforward_torques(kind: str, controller: Robot, tables: Tables, samples: MotionSamples, grid: Grid,
                        series: Series | None = None, advance=0.0) -> jax.Array:
    """The feedforward (N + 1 + Nd + 1, 2) [N m] at the grid's motion nodes then its dwell nodes, of
    the kind ``kind`` (``servo.FEEDFORWARDS``): "none" zeros; "rigid" the inverse dynamics of the
    rigid robot ``controller`` (``rigid_feedforward``); "flexible" from the perfect controller's
    rollout ``series`` of the controller's model (``flexible_feedforward``, advanced by ``advance``
    [s]). In the dwell every kind holds the torque that holds its model at rest at the place. The
    closed loop reads it at its samples by linear interpolation in the step."""
    if kind == "none":
        return jnp.zeros((grid.steps + grid.dwell_steps + 2, 2))
    if kind == "rigid":
        motion, rest = rigid_feedforward(controller, tables, samples)
    elif kind == "flexible":
        if series is None:
            raise ValueError("the flexible feedforward needs the prescribed rollout's series")
        motion, rest = flexible_feedforward(controller, series, interpolate(tables.fast(), tables.breaks[-1]).qa,
                                            advance)
    else:
        raise ValueError(f"unknown feedforward {kind!r}")
    return jnp.concatenate([motion, jnp.broadcast_to(rest, (grid.dwell_steps + 1, 2))])


def check_schedule(grid: Grid, tf: float, dwell: float, rate: float) -> None:
    """ValueError unless every step of the grid is shorter than the sample period (at most one
    sample per step)."""
    period = 1.0 / float(rate)
    for name, step in (("motion", float(tf) / grid.steps), ("dwell", float(dwell) / grid.dwell_steps)):
        if step >= period:
            raise ValueError(f"the {name} step {step * 1e6:.4g} us is not below the servo period "
                             f"{period * 1e6:.4g} us: refine the grid (servo_grid)")


def servo_grid(grid: Grid, tf: float, dwell: float, rate: float) -> Grid:
    """The grid with fine and dwell steps refined (if needed) to 90 % of the sample period at most."""
    period = 0.9 / float(rate)
    fine = max(grid.fine, int(np.ceil(float(tf) / grid.coarse / period)))
    dwell_steps = max(grid.dwell_steps, int(np.ceil(float(dwell) / period)))
    return grid._replace(fine=fine, dwell_steps=dwell_steps)


class _Maps(NamedTuple):
    """One frozen interval's maps (x = [z, z'], 2 n): ``phi`` (2n, 2n), ``p1`` (2n, n) the response to
    a constant force over the step, ``p2`` (2n, n) to a ramp 0 -> 1; ``minv``, ``k``, ``c`` (n, n);
    and the sub-step node tables (P + 1 nodes): ``ru`` (P+1, 4, 2n) the rows [d, d'] of e^{A t},
    ``rv1``, ``rv2`` (P+1, 4, n) of the constant and ramp forcing's responses over [0, t], t = theta h,
    ``gs`` (P+1, 2n, 2) the held torque's response over the step's last (1 - theta) h."""

    phi: jax.Array
    p1: jax.Array
    p2: jax.Array
    minv: jax.Array
    k: jax.Array
    c: jax.Array
    ru: jax.Array
    rv1: jax.Array
    rv2: jax.Array
    gs: jax.Array


def _full_matrices(slow: SlowCoeffs, sc: ServoCoeffs, ds, dds):
    """M, K, C (n, n) of the free-motor system at path speed ds and acceleration dds."""
    k_e, c_e = slow.stiffness_damping(ds, dds)
    tq, tv = slow.torque_maps(ds, dds)
    k_a, c_a = sc.stiffness_damping(ds, dds)
    mass = jnp.block([[sc.m_aa, slow.m_ae], [slow.m_ae.T, slow.mass]])
    k = jnp.concatenate([k_a, jnp.concatenate([tq, k_e])], axis=1)
    c = jnp.concatenate([c_a, jnp.concatenate([tv, c_e])], axis=1)
    return mass, k, c


def _maps(mass, k, c, h) -> _Maps:
    """The frozen interval's maps over a step h (``_Maps``), from the matrix functions of h / NODES
    (Taylor series) in velocity-scaled coordinates y = [z, z' / w]."""
    n = mass.shape[0]
    minv = linalg.inv(mass)
    w = jnp.sqrt(jnp.maximum(jnp.max(jnp.abs(jnp.diag(minv @ k))), 1.0))
    eye, zero = jnp.eye(n), jnp.zeros((n, n))
    a = jnp.block([[zero, w * eye], [-minv @ k / w, -minv @ c]])
    b = jnp.concatenate([zero, minv / w])                                   # force -> y'
    delta = h / NODES
    # E = e^X, F1 = phi1(X), F2 = phi2(X) by Taylor (``expm.phi_series``); U, V1, V2 over delta:
    # e^{A d}, int_0^d e^{A s} ds, int_0^d e^{A (d - s)} s ds
    e_sum, f1, f2 = phi_series(a * delta, TAYLOR)
    u_d, v1_d, v2_d = e_sum, delta * f1, delta**2 * f2
    # only the forcing's responses V1 B, V2 B (2n, n) are used, never V1, V2 themselves: carry them
    # (the recurrences below are linear in V1, V2, so they hold for V1 B, V2 B; half the products)
    v1b_d, v2b_d = v1_d @ b, v2_d @ b
    # the node tables by recurrence over t = i delta for the rows R = [d, d' / w] of y:
    # U(t + d) = U(t) U(d), V1(t + d) = V1(t) + U(t) V1(d), V2(t + d) = V2(t) + d V1(t) + U(t) V2(d)
    # (a scan, not a Python loop: one small body compiled instead of NODES copies of it)
    rows = jnp.zeros((4, 2 * n)).at[0, 0].set(1.0).at[1, 1].set(1.0).at[2, n].set(1.0).at[3, n + 1].set(1.0)
    first = (rows, jnp.zeros((4, n)), jnp.zeros((4, n)))

    def node(c, _):
        ru, rv1, rv2 = c
        nxt = (ru @ u_d, rv1 + ru @ v1b_d, rv2 + delta * rv1 + ru @ v2b_d)
        return nxt, nxt

    _, later = jax.lax.scan(node, first, None, length=NODES)
    ru_n, rv1_n, rv2_n = (jnp.concatenate([a[None], b_]) for a, b_ in zip(first, later))
    # the held torque's response over the last (1 - theta) h: G(t) = V1(t) B S at t = (P - i) delta,
    # G(t + d) = V1(d) B S + U(d) G(t)
    g0 = jnp.zeros((2 * n, 2))
    v1bs_d = v1b_d[:, :2]

    def held(g, _):
        g = v1bs_d + u_d @ g
        return g, g

    _, g = jax.lax.scan(held, g0, None, length=NODES)
    gs_n = jnp.concatenate([g0[None], g])[::-1]
    # the full step by doubling: (U, V1 B, V2 B)(2 t) = (U^2, V1 B + U V1 B, U V2 B + t V1 B + V2 B)
    u_h, v1_h, v2_h, t = u_d, v1b_d, v2b_d, delta
    for _ in range(int(np.log2(NODES))):
        u_h, v1_h, v2_h = u_h @ u_h, v1_h + u_h @ v1_h, u_h @ v2_h + t * v1_h + v2_h
        t = 2 * t
    # back to x = T y, T = diag(I, w I): phi = T U T^-1, responses T V B, rows scaled alike
    tvec = jnp.concatenate([jnp.ones(n), jnp.full(n, w)])
    phi = u_h * tvec[:, None] / tvec[None, :]
    p1 = tvec[:, None] * v1_h
    p2 = tvec[:, None] * v2_h / h
    rscale = jnp.asarray([1.0, 1.0, 0.0, 0.0]) + w * jnp.asarray([0.0, 0.0, 1.0, 1.0])
    ru_x = ru_n * rscale[None, :, None] / tvec[None, None, :]
    rv1_x = rscale[None, :, None] * rv1_n
    rv2_x = rscale[None, :, None] * rv2_n / h
    gs_x = tvec[None, :, None] * gs_n
    return _Maps(phi, p1, p2, minv, k, c, ru_x, rv1_x, rv2_x, gs_x)


def _lagrange(theta):
    """(start node, weights (DEGREE + 1,)) of the local Lagrange interpolant at theta in [0, 1) on
    the nodes i / NODES: the DEGREE + 1 nodes around it."""
    pos = theta * NODES
    start = jnp.clip(jnp.floor(pos).astype(int) - (DEGREE - 1) // 2, 0, NODES - DEGREE)
    u = pos - start.astype(float)
    k = jnp.arange(DEGREE + 1, dtype=float)
    diff = u - k
    # w_k = prod_{j != k} (u - j) / (k - j)
    num = jnp.prod(jnp.where(jnp.eye(DEGREE + 1, dtype=bool), 1.0, diff[None, :]), axis=1)
    den = jnp.asarray([np.prod([k_ - j for j in range(DEGREE + 1) if j != k_]) for k_ in range(DEGREE + 1)],
                      dtype=float)
    return start, num / den


class _Steps(NamedTuple):
    """Per fine step: the external forcing's response over the step ``b`` (2n,), the forcing at the
    step's start ``f0`` (n,) and its change over the step ``df`` (n,), whether a sample falls in it
    ``has``, its interpolation ``start`` and ``weights``, and the feedforward there ``ff`` (2,)."""

    b: jax.Array
    f0: jax.Array
    df: jax.Array
    has: jax.Array
    start: jax.Array
    weights: jax.Array
    ff: jax.Array


class Carry(NamedTuple):
    """The loop's state between steps: x = [z, z'] (2n,), the applied torque ``u`` (2,) [N m], the
    torque computed but not yet applied ``pending`` (one-sample delay) and the ``integral`` of the
    angle error [rad s]."""

    x: jax.Array
    u: jax.Array
    pending: jax.Array
    integral: jax.Array


MARCH_UNROLL = 1    # the closed loop's step is not unrolled (``_march``)


def _march(carry: Carry, maps: _Maps, steps: _Steps, servo: Servo):
    """The fine steps of every interval (leaves of ``maps`` (Nc, ...), of ``steps`` (Nc, m, ...)):
    returns the final carry and, per step, the state and the applied torque at its start.

    Unlike the prescribed passes' small step (``Grid.unroll``), the closed loop's step holds the
    sample's interpolation, the control law and the held torque's response: unrolling it
    lengthened the compile of every program that contains it, by a fifth to a third, with no
    gain in run time (docs/performance.md), so it runs ``MARCH_UNROLL`` steps per loop iteration."""
    period = 1.0 / servo.rate
    nc, p1 = maps.ru.shape[:2]
    n2 = maps.ru.shape[-1]
    # per node, the rows [d, d'] of the maps on [x, force, force change] side by side, then the held
    # torque's response: one slice and one weighted sum per step give both
    rows = jnp.concatenate([maps.ru, maps.rv1, maps.rv2], axis=3)
    width = rows.shape[3]
    nodes = jnp.concatenate([rows.reshape(nc, p1, -1), maps.gs.reshape(nc, p1, -1)], axis=2)
    split = 4 * width
    step_map = jnp.concatenate([maps.phi, maps.p1[:, :, :2]], axis=2)          # [Phi | P1 S] on [x, u]

    def interval(c, inp):
        big, st, tab = inp

        def step(c, s):
            flat = s.weights @ jax.lax.dynamic_slice_in_dim(tab, s.start, DEGREE + 1)
            r, gs = flat[:split].reshape(4, width), flat[split:].reshape(n2, 2)
            at = r @ jnp.concatenate([c.x, s.f0.at[:2].add(c.u), s.df])      # [d, d'] at the sample
            new = s.ff - servo.kp * at[:2] - servo.kd * at[2:] + servo.ki * c.integral
            new = jnp.clip(new, -servo.torque_limit, servo.torque_limit)
            applied = c.pending if servo.delay else new
            has = s.has > 0
            applied = jnp.where(has, applied, c.u)
            x_next = big @ jnp.concatenate([c.x, c.u]) + s.b + gs @ (applied - c.u)
            nxt = Carry(x_next, applied, jnp.where(has, new, c.pending),
                        jnp.where(has, c.integral - period * at[:2], c.integral))
            return nxt, (c.x, c.u)

        return jax.lax.scan(step, c, st, unroll=MARCH_UNROLL)

    return jax.lax.scan(interval, carry, (step_map, steps, nodes))


def _node_coeffs(tables: Tables, servo_tables: Tables, s):
    """Fast and servo coefficients at the arc lengths s (N,)."""
    fast = jax.vmap(lambda x: interpolate(tables.fast(), x))(s)
    sc = jax.vmap(lambda x: interpolate(servo_tables, x))(s)
    return fast, sc


def _forcing(fast: FastCoeffs, ds, dds):
    """F = [-tau_r; f] (N, n) at the nodes and the rigid torque tau_r (N, 2)."""
    f, tr = jax.vmap(FastCoeffs.forcing)(fast, ds, dds)
    return jnp.concatenate([-tr, f], axis=1), tr


def _rest(tables: Tables, servo_tables: Tables, s):
    """M, K, C (n, n), F (n,) and the node coefficients at rest at arc length s."""
    c = interpolate(tables, s)
    sc = interpolate(servo_tables, s)
    zero = jnp.zeros(())
    mass, k, damp = _full_matrices(c.slow(), sc, zero, zero)
    f, tr = c.fast().forcing(zero, zero)
    return mass, k, damp, jnp.concatenate([-tr, f]), c, sc


def _equilibrium(k, force, servo: Servo, ff):
    """The closed loop's static equilibrium z* (n,) at rest: K z = F + [ff - Kp d; 0]."""
    k_cl = k.at[jnp.arange(2), jnp.arange(2)].add(servo.kp)
    return linalg.solve(k_cl, force.at[:2].add(ff)), k_cl


def _outputs(z, zd, zdd, fast: FastCoeffs, sc: ServoCoeffs, ds, dds, u):
    """e, e', e'', tau (N, 4, 2) at the nodes from z, z', z'' (N, n), the node coefficients, the path
    speed and acceleration (N,) and the applied torque u (N, 2)."""
    node = lambda a, v: jnp.einsum("nij,nj->ni", a, v)
    d, q, dd, qd, ddd, qdd = z[:, :2], z[:, 2:], zd[:, :2], zd[:, 2:], zdd[:, :2], zdd[:, 2:]
    e = node(sc.jxa, d) + node(fast.jx, q)
    ed = node(sc.jxa, dd) + ds[:, None] * node(sc.jxa1, d) + node(fast.jx, qd) + ds[:, None] * node(fast.jx1, q)
    s2, s1 = ds[:, None, None] ** 2, dds[:, None, None]
    edd = (node(sc.jxa, ddd) + 2.0 * ds[:, None] * node(sc.jxa1, dd) + node(s2 * sc.jxa2 + s1 * sc.jxa1, d)
           + node(fast.jx, qdd) + 2.0 * ds[:, None] * node(fast.jx1, qd) + node(s2 * fast.jx2 + s1 * fast.jx1, q))
    return jnp.stack([e, ed, edd, u], axis=1)


def _steps(maps: _Maps, f_start, f_end, schedule_part, ff, nc):
    """The per-step inputs of ``_march`` (leaves (Nc, m, ...))."""
    b = per_interval(maps.p1, f_start) + per_interval(maps.p2, f_end - f_start)
    start, weights = jax.vmap(_lagrange)(schedule_part[1])
    st = _Steps(b, f_start, f_end - f_start, schedule_part[0], start, weights, ff)
    return jax.tree_util.tree_map(lambda a: a.reshape((nc, -1) + a.shape[1:]), st)


def closed_loop(tables: Tables, servo_tables: Tables, samples: MotionSamples, schedule: Schedule, feedforward,
                tf, dwell, grid: Grid, servo: Servo, robot=None) -> Series:
    """One rollout under the servo (module docstring): motion over [0, tf] [s], then a dwell [s] with
    the reference at the place pose. ``tables``, ``servo_tables``: the path's coefficient tables
    (``linearized``, ``servo_linearized``) of the robot with the servo's rotor; ``schedule``: the
    samples' positions (``servo_schedule``); ``feedforward`` (N + 1 + Nd + 1, 2) [N m]: the
    feedforward torque at the motion's and the dwell's nodes (``feedforward_torques``); with ``robot``, the full
    model's second-order remainder along the first pass. ``tau`` of the series is the motors'
    applied torque; ``e_static`` the static error at the closed loop's equilibrium at the place."""
    nc, m, n_steps, nd = grid.coarse, grid.fine, grid.steps, grid.dwell_steps
    h, hd = tf / n_steps, dwell / nd
    s_mid, ds_mid, dds_mid = samples.mid
    slow = jax.vmap(lambda x: interpolate(tables.slow(), x))(s_mid)
    sc_mid = jax.vmap(lambda x: interpolate(servo_tables, x))(s_mid)
    mass, k, damp = jax.vmap(_full_matrices)(slow, sc_mid, ds_mid, dds_mid)
    maps = jax.vmap(lambda a, b, c: _maps(a, b, c, h))(mass, k, damp)
    fast, sc = _node_coeffs(tables, servo_tables, jnp.concatenate([samples.start[0], samples.end[0][-1:]]))
    fast_start, fast_end = (jax.tree_util.tree_map(lambda a: a[sl], fast) for sl in (slice(None, -1), slice(1, None)))
    sc_start, sc_end = (jax.tree_util.tree_map(lambda a: a[sl], sc) for sl in (slice(None, -1), slice(1, None)))
    f_start, _ = _forcing(fast_start, *samples.start[1:])
    f_end, _ = _forcing(fast_end, *samples.end[1:])
    # the feedforward at the samples: linear in the step between its nodes
    ff_nodes_m, ff_nodes_d = feedforward[:n_steps + 1], feedforward[n_steps + 1:]
    at_samples = lambda f, th: f[:-1] * (1.0 - th)[:, None] + f[1:] * th[:, None]
    ff_m = at_samples(ff_nodes_m, schedule.theta[:n_steps])
    ff_d = at_samples(ff_nodes_d, schedule.theta[n_steps:])
    sched_m = (schedule.has[:n_steps], schedule.theta[:n_steps])
    sched_d = (schedule.has[n_steps:], schedule.theta[n_steps:])
    # start: the closed loop's equilibrium at the pick pose, with the feedforward of the first sample
    m0, k0, c0, force0, _, _ = _rest(tables, servo_tables, tables.breaks[0])
    z0, _ = _equilibrium(k0, force0, servo, ff_nodes_m[0])
    n = z0.shape[0]
    u0 = jnp.clip(ff_nodes_m[0] - servo.kp * z0[:2], -servo.torque_limit, servo.torque_limit)
    start = Carry(jnp.concatenate([z0, jnp.zeros(n)]), u0, u0, jnp.zeros(2))

    def accelerations(xs, us, forces):
        z, zd = xs[:, :n], xs[:, n:]
        return per_interval(maps.minv, forces.at[:, :2].add(us) - per_interval(maps.c, zd) - per_interval(maps.k, z))

    def march(f_s, f_e):
        st = _steps(maps, f_s, f_e, sched_m, ff_m, nc)
        end, (xs, us) = _march(start, maps, st, servo)
        return end, xs.reshape(n_steps, -1), us.reshape(n_steps, 2)

    # ---- first pass, and the corrections of the second along it
    end1, x1, u1 = march(f_start, f_end)
    x1_end = jnp.concatenate([x1[1:], end1.x[None]])
    u1_end = jnp.concatenate([u1[1:], end1.u[None]])
    zdd_start = accelerations(x1, u1, f_start)
    zdd_end = accelerations(x1_end, u1_end, f_end)
    first = lambda a: a.reshape((nc, m) + a.shape[1:])[:, 0]
    last = lambda a: a.reshape((nc, m) + a.shape[1:])[:, m - 1]
    s_b = jnp.concatenate([first(samples.start[0]), samples.end[0][-1:]])
    slow_b = jax.vmap(lambda x: interpolate(tables.slow(), x))(s_b)
    sc_b = jax.vmap(lambda x: interpolate(servo_tables, x))(s_b)
    at_b = lambda tree, lo, hi: jax.tree_util.tree_map(lambda a: a[lo:hi], tree)
    m0_, k0_, c0_ = jax.vmap(_full_matrices)(at_b(slow_b, 0, nc), at_b(sc_b, 0, nc), first(samples.start[1]),
                                             first(samples.start[2]))
    m1_, k1_, c1_ = jax.vmap(_full_matrices)(at_b(slow_b, 1, nc + 1), at_b(sc_b, 1, nc + 1), last(samples.end[1]),
                                             last(samples.end[2]))
    frac = np.arange(m + 1) / m

    def corr(tt, x, zdd):
        w = jnp.tile(jnp.asarray(tt), nc)[:, None]
        out = 0.0
        for a0, a1, af, v in ((m0_, m1_, mass, zdd), (k0_, k1_, k, x[:, :n]), (c0_, c1_, damp, x[:, n:])):
            out = out + per_interval(a0 - af, v) + w * per_interval(a1 - a0, v)
        return out

    if grid.continuous:
        f_start = f_start - corr(frac[:-1], x1, zdd_start)
        f_end = f_end - corr(frac[1:], x1_end, zdd_end)
    if robot is not None:
        right, ((lo_s, hi_s, w_s), (lo_e, hi_e, w_e)) = remainder_stencil(grid)
        before = jump_nodes(grid) - 1
        cat = lambda a, b: jnp.concatenate([a[right], b[before]])
        sites = (cat(fast_start.qa, fast_end.qa), cat(fast_start.qa1, fast_end.qa1), cat(fast_start.qa2, fast_end.qa2),
                 cat(samples.start[1], samples.end[1]), cat(samples.start[2], samples.end[2]), cat(x1, x1_end),
                 cat(zdd_start, zdd_end))
        rem = jax.vmap(lambda *a: servo_remainder(robot, *a))(*sites)
        lin = lambda lo, hi, w: rem[lo] * (1.0 - w)[:, None] + rem[hi] * w[:, None]
        f_start = f_start - lin(lo_s, hi_s, w_s)
        f_end = f_end - lin(lo_e, hi_e, w_e)

    # ---- the last pass
    end2, x2, u2 = march(f_start, f_end)
    zdd2 = accelerations(x2, u2, f_start)
    ys = _outputs(x2[:, :n], x2[:, n:], zdd2, fast_start, sc_start, samples.start[1], samples.start[2], u2)
    x_tf = end2.x
    final = lambda tree: jax.tree_util.tree_map(lambda a: a[-1:], tree)
    minv_l, k_l, c_l = maps.minv[-1], maps.k[-1], maps.c[-1]
    zdd_tf = minv_l @ (f_end[-1].at[:2].add(u2[-1]) - c_l @ x_tf[n:] - k_l @ x_tf[:n])
    y_tf = _outputs(x_tf[None, :n], x_tf[None, n:], zdd_tf[None], final(fast_end), final(sc_end),
                    samples.end[1][-1:], samples.end[2][-1:], u2[-1:])
    ys = jnp.concatenate([ys, y_tf], axis=0)

    # ---- the dwell: the reference holds the place pose, coefficients at rest there
    m_p, k_p, c_p, force_p, rest_c, rest_sc = _rest(tables, servo_tables, tables.breaks[-1])
    maps_d = jax.tree_util.tree_map(lambda a: a[None], _maps(m_p, k_p, c_p, hd))
    f_d = jnp.broadcast_to(force_p, (nd, n))
    st_d = _steps(maps_d, f_d, f_d, sched_d, ff_d, 1)
    end_d, (xd, ud) = _march(end2, maps_d, st_d, servo)
    xd = jnp.concatenate([xd.reshape(nd, -1), end_d.x[None]])
    ud = jnp.concatenate([ud.reshape(nd, 2), end_d.u[None]])
    # one elimination for every dwell node's right-hand side (M z'' = F + [u; 0] - C z' - K z)
    held = force_p[None, :] + jnp.concatenate([ud, jnp.zeros((nd + 1, n - 2))], axis=1)
    zddd = linalg.solve(m_p, (held - xd[:, n:] @ c_p.T - xd[:, :n] @ k_p.T).T).T
    over = lambda tree: jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (nd + 1,) + a.shape), tree)
    zero = jnp.zeros(nd + 1)
    yd = _outputs(xd[:, :n], xd[:, n:], zddd, over(rest_c.fast()), over(rest_sc), zero, zero, ud)

    # ---- the closed loop's equilibrium at the place, the energy about it, the static error
    z_star, k_cl = _equilibrium(k_p, force_p, servo, ff_nodes_d[-1])
    e_static = rest_sc.jxa @ z_star[:2] + rest_c.jx @ z_star[2:]
    ksym = 0.5 * (k_cl + k_cl.T)

    def energy(x):
        dz = x[:n] - z_star
        return 0.5 * x[n:] @ m_p @ x[n:] + 0.5 * dz @ ksym @ dz

    elastic_tf = jnp.concatenate([x_tf[2:n], x_tf[n + 2:]])
    low = low_mode_acceleration(rest_c.mass, rest_c.k0, rest_c.c0, rest_c.jx, z_star[2:], elastic_tf)
    t = jnp.arange(n_steps + 1, dtype=float) * h
    td = tf + jnp.arange(nd + 1, dtype=float) * hd
    return Series(t=t, e=ys[:, 0], ed=ys[:, 1], edd=ys[:, 2], tau=ys[:, 3], t_dwell=td, e_dwell=yd[:, 0],
                  ed_dwell=yd[:, 1], edd_dwell=yd[:, 2], tau_dwell=yd[:, 3], e_static=e_static,
                  energy_tf=energy(x_tf), energy_dwell=jax.vmap(energy)(xd), state_tf=x_tf, dt=h, dt_dwell=hd,
                  edd_tf_low=low)
