"""Inverse elastodynamic simulation with a perfect controller (paper Section 4), fast formulation.

The motors follow the rigid IGM of the desired trajectory over [0, tf], then hold the place pose for a
dwell. The elastic coordinates obey the linearized equations of ``jaxflex.linearized``

    M q_e'' + C q_e' + K q_e = f(t),

integrated by an exponential integrator: the coefficients are frozen at the midpoint of each of
``coarse`` intervals (aligned with the acceleration jumps of the paper's profiles, which fall on
multiples of tf/8), and within an interval every one of the ``fine`` steps h is propagated exactly
for that frozen system, with the forcing linear over the step (first-order hold on its one-sided
end values). The propagator exp(A h) is unconditionally stable and has no numerical damping or
dispersion: the kHz axial modes keep their exact frequency and amplitude at any h. Outputs (end-
effector error, its derivatives, motor torques) are evaluated at every fine node. The run starts
from the static equilibrium at the pick pose.

A second pass (``first_pass``, ``add_remainders``, on by default) corrects the first along its solution:
(1) the frozen coefficients jump at every interval boundary and each jump kicks the undamped kHz
modes, an artefact that does not shrink with the interval and dominated |e''| at one instant; the
second pass adds the force of the coefficients' variation (linear in time between the boundary
values), so the effective coefficients are continuous (``Grid.continuous``); (2) given the robot,
the full model's second-order remainder along the first pass (``Grid.remainder_points`` samples per
interval), which brings every metric close to the full nonlinear model (within the tolerance of
docs/conventions.md#fast-model; tests/test_reference.py).

All functions are pure, for one trajectory; ``jaxflex.rollout`` composes them into the stages of a
rollout.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import linalg
from jaxflex.expm import expm_fixed
from jaxflex.linearized import FastCoeffs, SlowCoeffs, Tables, interpolate, remainder
from jaxflex.profiles import Profile, profile_eval


class Grid(NamedTuple):
    """Static discretization. ``coarse`` intervals over [0, tf] (a multiple of 8, so that tf/8, tf/4
    and tf/2 are interval boundaries), ``fine`` steps per interval, ``dwell_steps`` over the dwell,
    ``squarings`` of the matrix exponential (see ``squarings_for_robot``), the ``unroll`` of the
    passes' scans (steps per loop iteration; the servo loop's larger step is not unrolled,
    ``servo_simulate.MARCH_UNROLL``);
    ``remainder_points`` samples of the second-order remainder per coarse interval and
    ``continuous``: correct the frozen coefficients to continuous ones in the second pass (see the
    module docstring; False reproduces the plain frozen-coefficient integrator)."""

    coarse: int = 96
    fine: int = 48
    dwell_steps: int = 1000
    squarings: int = 8
    unroll: int = 8
    remainder_points: int = 2
    continuous: bool = True

    @property
    def steps(self) -> int:
        return self.coarse * self.fine


def check_grid(grid: Grid) -> None:
    """Raise ValueError unless ``grid`` is usable (coarse a positive multiple of 8, steps >= 1)."""
    if grid.coarse < 8 or grid.coarse % 8:
        raise ValueError(f"grid.coarse must be a positive multiple of 8, got {grid.coarse}")
    if grid.fine < 1 or grid.dwell_steps < 1:
        raise ValueError("grid.fine and grid.dwell_steps must be >= 1")


class MotionSamples(NamedTuple):
    """Arc-length motion s [m], s' [m/s], s'' [m/s^2] at the start (right limit) and end (left limit)
    of every fine step (N,), and at the midpoints of the coarse intervals (Nc,)."""

    start: tuple
    end: tuple
    mid: tuple


def motion_samples(length, profile: Profile, tf, grid: Grid) -> MotionSamples:
    """Sample s(t) = L S(t / tf) on the grid (normalized times are exact fractions k / N)."""
    n, nc = grid.steps, grid.coarse
    k = np.arange(n)

    def at(eta, side):
        v = profile_eval(profile, jnp.asarray(eta), side)
        return v.s * length, v.ds * length / tf, v.dds * length / tf**2

    return MotionSamples(start=at(k / n, 1), end=at((k + 1) / n, -1), mid=at((np.arange(nc) + 0.5) / nc, 1))


class Series(NamedTuple):
    """Simulation output of one run.

    motion: (N + 1,) samples at t_k = k tf / N (right limits; the last is the left limit at tf);
    dwell: (Nd + 1,) samples at tf + j dwell / Nd (the first is the right limit at tf). Each has
    e, ed, edd (T, 2) end-effector error X - X_desired [m], its rate [m/s] and acceleration [m/s^2],
    and tau (T, 2) motor torques [N m]. e_static (2,) is the static error (gravity sag) at the place
    pose; energy_tf [J] the vibration energy at tf relative to the static equilibrium at the place
    pose and energy_dwell (Nd + 1,) [J] the same over the dwell; state_tf (2 ne,) the elastic state
    [q_e, q_e'] at tf; edd_tf_low (2,) [m/s^2] the part of e''(tf) carried by the locked modes of the
    place pose below ``LOW_MODES_HZ`` (``low_mode_acceleration``); dt and dt_dwell the sample steps [s].
    """

    t: jax.Array
    e: jax.Array
    ed: jax.Array
    edd: jax.Array
    tau: jax.Array
    t_dwell: jax.Array
    e_dwell: jax.Array
    ed_dwell: jax.Array
    edd_dwell: jax.Array
    tau_dwell: jax.Array
    e_static: jax.Array
    energy_tf: jax.Array
    energy_dwell: jax.Array
    state_tf: jax.Array
    dt: jax.Array
    dt_dwell: jax.Array
    edd_tf_low: jax.Array


LOW_MODES_HZ = 1000.0   # cut-off of the low-mode residual acceleration (below the axial kHz modes)


def low_mode_acceleration(mass, k, c, jx, q_star, x, cutoff_hz=LOW_MODES_HZ):
    """End-effector acceleration [m/s^2] (2,) carried by the locked modes below ``cutoff_hz`` [Hz].

    The elastic state x = [q_e, q_e'] (2 ne,) is expanded in the undamped modes of (mass, k) (ne, ne)
    about the static equilibrium q_star (ne,); each mode's acceleration -w_i^2 y_i - (V^T C V y')_i is
    kept when w_i < 2 pi cutoff and mapped to the end effector by jx (2, ne). This is the residual
    acceleration a sensor with a 1 kHz bandwidth would see; unlike |e''(tf)| it does not depend on the
    phase of the ~18 kHz axial modes at one instant, so it converges in dt. The modal basis is held
    constant under differentiation (``stop_gradient``; eigenvector derivatives are ill-conditioned
    for the nearly equal axial modes of the two distal links)."""
    ne = mass.shape[0]
    mass, k, c = (jax.lax.stop_gradient(a) for a in (mass, k, c))
    lower = linalg.cholesky(mass)
    li = linalg.lower_inverse(lower)
    w2, vec = jnp.linalg.eigh(li @ (0.5 * (k + k.T)) @ li.T)
    to_modal = vec.T @ lower.T                          # y = V^T L^T q
    y = to_modal @ (x[:ne] - q_star)
    yd = to_modal @ x[ne:]
    ydd = -w2 * y - (vec.T @ li @ c @ li.T @ vec) @ yd
    keep = w2 < (2.0 * jnp.pi * cutoff_hz) ** 2
    return jx @ (li.T @ vec @ jnp.where(keep, ydd, 0.0))


def _interp(tables: Tables, s):
    """Coefficients at the arc lengths s (N,): leaves with a leading axis N."""
    return jax.vmap(lambda x: interpolate(tables, x))(s)


class _Frozen(NamedTuple):
    phi: jax.Array      # (2ne, 2ne) state transition over one fine step
    g0: jax.Array       # (2ne, ne) response to a constant unit force over the step
    g1: jax.Array       # (2ne, ne) response to a unit force ramp (0 -> 1) over the step
    mass: jax.Array     # (ne, ne)
    minv: jax.Array
    k: jax.Array
    c: jax.Array
    tq: jax.Array
    tv: jax.Array
    m_ae: jax.Array


def _propagator(m, k, c, h, squarings):
    """Exact one-step maps of M q'' + C q' + K q = f0 + (f1 - f0) t/h, t in [0, h], for frozen M, K, C.

    Returns (Phi, G0, G1, M^-1) with x(h) = Phi x(0) + G0 f0 + G1 (f1 - f0), x = [q, q'], and the
    inverse mass from the Cholesky factor already at hand (L^-T L^-1). Works in
    mass-normalized coordinates z = L^T q (M = L L^T) with the velocity scaled by
    w = sqrt(trace(L^-1 K L^-T) / ne) so that ||A h|| is of the order of omega_max h; the forcing
    integrals follow from A^-1: G0 = A^-1 (Phi - I) B, G1 = A^-1 (G0 - h B) / h.
    """
    ne = m.shape[0]
    lower = linalg.cholesky(m)
    li = linalg.lower_inverse(lower)   # L^-1
    ks = li @ k @ li.T
    cs = li @ c @ li.T
    w = jnp.sqrt(jnp.maximum(jnp.trace(ks), 1e-30) / ne)
    eye, zero = jnp.eye(ne), jnp.zeros((ne, ne))
    a = jnp.block([[zero, w * eye], [-ks / w, -cs]])
    phi_y = expm_fixed(a * h, squarings)
    ks_inv = linalg.inv(ks)
    a_inv = jnp.block([[-ks_inv @ cs, -w * ks_inv], [eye / w, zero]])
    b = jnp.concatenate([zero, eye / w], axis=0)                  # mass-normalized force -> y'
    g0_y = a_inv @ ((phi_y - jnp.eye(2 * ne)) @ b)
    g1_y = a_inv @ (g0_y - h * b) / h
    # back to physical coordinates x = [q, q'] = T y, y = [z, z'/w], T = blockdiag(L^-T, w L^-T)
    lt = li.T
    t_mat = jnp.block([[lt, zero], [zero, w * lt]])
    t_inv = jnp.block([[lower.T, zero], [zero, lower.T / w]])
    return t_mat @ phi_y @ t_inv, t_mat @ g0_y @ li, t_mat @ g1_y @ li, lt @ li


def _frozen(c: SlowCoeffs, ds, dds, h, squarings) -> _Frozen:
    k, cc = c.stiffness_damping(ds, dds)
    tq, tv = c.torque_maps(ds, dds)
    phi, g0, g1, minv = _propagator(c.mass, k, cc, h, squarings)
    return _Frozen(phi, g0, g1, c.mass, minv, k, cc, tq, tv, c.m_ae)


def _recurrence(phi, x0, b, unroll, keep: bool = True):
    """x_{j+1} = phi x_j + b_j for the rows of b: returns (x_m, states x_0 .. x_{m-1}), or only x_m
    without ``keep``."""
    def step(x, bj):
        return phi @ x + bj, (x if keep else None)

    x_m, states = jax.lax.scan(step, x0, b, unroll=unroll)
    return (x_m, states) if keep else x_m


def per_interval(a, v):
    """a (Nc, i, j) applied to the rows of v (Nc m, j) interval by interval -> (Nc m, i)."""
    nc = a.shape[0]
    return jnp.einsum("cij,cmj->cmi", a, v.reshape((nc, -1) + v.shape[1:])).reshape(v.shape[:1] + a.shape[1:2])


def _outputs(fz: _Frozen, c: FastCoeffs, ds, dds, x, f, tr):
    """e, e', e'', tau (N, 4, 2) at N nodes from the elastic states x = [q_e, q_e'] (N, 2 ne), with
    the node coefficients c (leaves (N, ...)), ds, dds (N,), forcing f (N, ne) and rigid torque tr
    (N, 2); the frozen maps fz (leaves (Nc, ...)) hold over Nc equal runs of N / Nc nodes (batched
    products over all nodes: a few operations, not a few per coarse interval)."""
    ne = fz.k.shape[1]
    q, qd = x[:, :ne], x[:, ne:]
    mv = per_interval
    qdd = mv(fz.minv, f - mv(fz.c, qd) - mv(fz.k, q))
    node = lambda a, v: jnp.einsum("nij,nj->ni", a, v)
    e = node(c.jx, q)
    ed = node(c.jx, qd) + ds[:, None] * node(c.jx1, q)
    edd = (node(c.jx, qdd) + 2.0 * ds[:, None] * node(c.jx1, qd)
           + node(ds[:, None, None] ** 2 * c.jx2 + dds[:, None, None] * c.jx1, q))
    tau = tr + mv(fz.tq, q) + mv(fz.tv, qd) + mv(fz.m_ae, qdd)
    return jnp.stack([e, ed, edd, tau], axis=1)


def _motion(x0, frozen, f_start, f_end, tr_start, fast_start, ds, dds, grid: Grid, states: bool = False):
    """March the elastic state over [0, tf]: every coarse interval frozen, every fine step exact.

    Returns x(tf) and either the outputs [e, e', e'', tau] (N, 4, 2) at every fine node or, with
    ``states``, the state x (N, 2 ne) at the start of every fine step. Only the recurrence itself
    runs in the loop; the forcing increments before it and the outputs after it are batched over
    all the nodes (the loop's per-iteration work, not the arithmetic, dominates a rollout's time)."""
    nc, m = grid.coarse, grid.fine
    b = per_interval(frozen.g0, f_start) + per_interval(frozen.g1, f_end - f_start)   # (N, 2 ne)

    def coarse_step(x, inp):
        phi, bc = inp
        return _recurrence(phi, x, bc, grid.unroll)

    x_tf, xs = jax.lax.scan(coarse_step, x0, (frozen.phi, b.reshape(nc, m, -1)))
    xs = xs.reshape(nc * m, -1)
    if states:
        return x_tf, xs
    return x_tf, _outputs(frozen, fast_start, ds, dds, xs, f_start, tr_start)


def jump_nodes(grid: Grid) -> np.ndarray:
    """Fine-node indices of tf/8, 2 tf/8, ..., tf: where the paper laws' s'' may jump."""
    return np.arange(1, 9) * (grid.coarse // 8) * grid.fine


def remainder_stencil(grid: Grid):
    """Static sampling and interpolation plan of the second-order remainder.

    The remainder is sampled (right limits) at ``grid.remainder_points`` fine nodes per coarse
    interval (offsets round(k m / r)) and, as a left limit, at every jump node (``jump_nodes``;
    the last is tf). Between consecutive samples of one jump-free segment it is linear in time.
    Returns the right-limit sample nodes (S,), and for the start and the end of every fine step
    (N,) the indices of the two bracketing samples in [right samples, left samples] and the weight
    of the second. A static plan (numpy), computed when ``first_pass`` and ``add_remainders`` are
    traced."""
    nc, m, r = grid.coarse, grid.fine, max(1, min(grid.remainder_points, grid.fine))
    offsets = np.unique(np.round(np.arange(r) * m / r).astype(int))
    right = (np.arange(nc)[:, None] * m + offsets[None, :]).ravel()
    jumps = jump_nodes(grid)
    n = nc * m
    seg_of_step = np.searchsorted(jumps, np.arange(n), side="right")       # segment of every step
    plans = []
    for node in (np.arange(n), np.arange(n) + 1):                          # start / end of step j
        lo = np.empty(n, int)
        hi = np.empty(n, int)
        w = np.empty(n)
        for k in range(len(jumps)):
            sel = seg_of_step == k
            seg_start = 0 if k == 0 else jumps[k - 1]
            inside = np.flatnonzero((right >= seg_start) & (right < jumps[k]))
            pos = np.concatenate([right[inside], [jumps[k]]])
            ids = np.concatenate([inside, [len(right) + k]])
            p = node[sel]
            i = np.clip(np.searchsorted(pos, p, side="right") - 1, 0, len(pos) - 2)
            lo[sel], hi[sel] = ids[i], ids[i + 1]
            w[sel] = (p - pos[i]) / (pos[i + 1] - pos[i])
        plans.append((lo, hi, w))
    return right, plans


class Sites(NamedTuple):
    """Where the second-order remainder is sampled (S sites: the right-limit nodes of
    ``remainder_stencil``, then the left limits at the jump nodes): the pose qa (S, 2) [rad] with its
    arc-length derivatives qa1 [rad/m] and qa2 [rad/m^2], the path speed ds [m/s] and acceleration
    dds [m/s^2], the first pass's elastic state x = [q_e, q_e'] (S, 2 ne) and acceleration qdd (S, ne)."""

    qa: jax.Array
    qa1: jax.Array
    qa2: jax.Array
    ds: jax.Array
    dds: jax.Array
    x: jax.Array
    qdd: jax.Array


class Forcing(NamedTuple):
    """Elastic forcing f [N] (N, ne) and motor torques tau_r [N m] (N, 2) at the start (right limit)
    and end (left limit) of every fine step."""

    f_start: jax.Array
    f_end: jax.Array
    tr_start: jax.Array
    tr_end: jax.Array


class Prepared(NamedTuple):
    """What both passes of a rollout share: the frozen maps per coarse interval, the fast
    coefficients at the fine nodes (start and end of every step), the forcing and the initial state."""

    frozen: _Frozen
    fast_start: FastCoeffs
    fast_end: FastCoeffs
    forcing: Forcing
    x0: jax.Array


def prepare(tables: Tables, samples: MotionSamples, tf, grid: Grid) -> Prepared:
    """The coefficients of the passes over [0, tf]: frozen per coarse interval, forcing and output
    maps per fine node, and the static equilibrium at the pick pose (s = 0, at rest)."""
    h = tf / grid.steps
    s_mid, ds_mid, dds_mid = samples.mid
    slow = _interp(tables.slow(), s_mid)
    frozen = jax.vmap(lambda c, a, b: _frozen(c, a, b, h, grid.squarings))(slow, ds_mid, dds_mid)
    # the arc length is continuous: the end of step j is the start of step j + 1 (s from the other
    # side's formula differs by round-off at most), so the N + 1 fine nodes are interpolated once
    fast_nodes = _interp(tables.fast(), jnp.concatenate([samples.start[0], samples.end[0][-1:]]))
    fast_start = jax.tree_util.tree_map(lambda a: a[:-1], fast_nodes)
    fast_end = jax.tree_util.tree_map(lambda a: a[1:], fast_nodes)
    f_start, tr_start = jax.vmap(FastCoeffs.forcing)(fast_start, *samples.start[1:])
    f_end, tr_end = jax.vmap(FastCoeffs.forcing)(fast_end, *samples.end[1:])
    rest0 = interpolate(tables, tables.breaks[0])
    q0 = linalg.solve(rest0.k0, rest0.f0)
    x0 = jnp.concatenate([q0, jnp.zeros_like(q0)])
    return Prepared(frozen, fast_start, fast_end, Forcing(f_start, f_end, tr_start, tr_end), x0)


def first_pass(tables: Tables, prep: Prepared, samples: MotionSamples, grid: Grid):
    """The first pass of a rollout and the corrections of the second that follow from it.

    Returns (forcing, sites): ``prep.forcing`` with, if ``grid.continuous``, the variation of the
    coefficients within each coarse interval along the first-pass solution (1. below), and the
    inputs of ``remainders`` at the nodes of ``remainder_stencil`` (2.).

    1. Continuous coefficients: the first pass freezes M, C, K over each coarse interval, so they
       jump at its ends; every jump kicks the undamped kHz modes (an artefact that does not
       vanish as the interval shrinks and dominates |e''| at one instant). The second pass adds
       the force -(dM q'' + dC q' + dK q), with dX = X_lin(t) - X_frozen and X_lin linear in time
       between the coarse boundary values (right limit at the start, left limit at the end of every
       interval), evaluated along the first-pass solution at every fine node: the effective
       coefficients are then continuous and accurate to O(H^2).
    2. The full model's second-order remainder R(z1) - R(0) - R'(0) z1 along the first-pass
       solution z1 = [q_e, q_e', q_e''] is sampled at the nodes of ``remainder_stencil``
       (``remainders``) and enters, linear in time in between, as forcing and torque
       (``add_remainders``)."""
    nc, m = grid.coarse, grid.fine
    frozen, fast_start, fast_end, forcing, x0 = prep
    f_start, f_end = forcing.f_start, forcing.f_end
    ne = x0.shape[0] // 2
    x1_tf, x1 = _motion(x0, frozen, f_start, f_end, forcing.tr_start, fast_start, samples.start[1],
                        samples.start[2], grid, states=True)
    mv = per_interval
    x1_end = jnp.concatenate([x1[1:], x1_tf[None]])                   # state at the end of every step
    acc = lambda f, x: mv(frozen.minv, f - mv(frozen.c, x[:, ne:]) - mv(frozen.k, x[:, :ne]))
    qdd1_start = acc(f_start, x1)
    qdd1_end = acc(f_end, x1_end)                                    # left limits (same interval)

    # ---- 1. coefficients linear in time between the coarse boundaries (the first and last fine
    # step of every interval as strided slices: static index gathers would turn into scatter loops
    # in the gradient)
    first = lambda a: a.reshape(nc, m)[:, 0]
    last = lambda a: a.reshape(nc, m)[:, m - 1]
    s_b = jnp.concatenate([first(samples.start[0]), samples.end[0][-1:]])
    cb = _interp(tables.slow(), s_b)

    def mkc(c: SlowCoeffs, ds, dds):
        return (c.mass,) + c.stiffness_damping(ds, dds)
    at_b = lambda lo, hi: jax.tree_util.tree_map(lambda a: a[lo:hi], cb)
    m0, k0, c0 = jax.vmap(mkc)(at_b(0, nc), first(samples.start[1]), first(samples.start[2]))
    m1, k1, c1 = jax.vmap(mkc)(at_b(1, nc + 1), last(samples.end[1]), last(samples.end[2]))
    tau = np.arange(m + 1) / m

    def corr(tt, x, qdd):     # dM q'' + dC q' + dK q at the fractions tt (m,) of every interval -> (N, ne)
        w = jnp.tile(jnp.asarray(tt), nc)[:, None]
        out = 0.0
        for a0, a1, af, v in ((m0, m1, frozen.mass, qdd), (k0, k1, frozen.k, x[:, :ne]), (c0, c1, frozen.c, x[:, ne:])):
            out = out + mv(a0 - af, v) + w * mv(a1 - a0, v)
        return out

    if grid.continuous:
        forcing = forcing._replace(f_start=f_start - corr(tau[:-1], x1, qdd1_start),
                                   f_end=f_end - corr(tau[1:], x1_end, qdd1_end))

    # ---- 2. where the second-order remainder is sampled: right limits at the stencil's nodes and
    # left limits at the jump nodes (one model evaluation site each)
    right, _ = remainder_stencil(grid)
    before = jump_nodes(grid) - 1                         # last fine step before each jump node
    cat = lambda a, b: jnp.concatenate([a[right], b[before]])
    sites = Sites(cat(fast_start.qa, fast_end.qa), cat(fast_start.qa1, fast_end.qa1), cat(fast_start.qa2, fast_end.qa2),
                  cat(samples.start[1], samples.end[1]), cat(samples.start[2], samples.end[2]),
                  jnp.concatenate([x1[right], x1_end[before]]), jnp.concatenate([qdd1_start[right], qdd1_end[before]]))
    return forcing, sites


def remainders(robot, sites: Sites) -> jax.Array:
    """The full model's second-order remainder (``linearized.remainder``) at the sites of
    ``first_pass``: (S, 2 + ne), rows [:, :2] motor torques [N m], [:, 2:] elastic forces [N]."""
    return jax.vmap(lambda qa, q1, q2, ds, dds, x, qdd: remainder(robot, qa, q1, q2, ds, dds, x, qdd))(*sites)


def add_remainders(forcing: Forcing, r_all, grid: Grid) -> Forcing:
    """``forcing`` with the remainders at the sites (``remainders``), linear in time between the
    samples of one jump-free segment (``remainder_stencil``)."""
    _, ((lo_s, hi_s, w_s), (lo_e, hi_e, w_e)) = remainder_stencil(grid)
    lin = lambda lo, hi, w: r_all[lo] * (1.0 - w)[:, None] + r_all[hi] * w[:, None]
    at_start, at_end = lin(lo_s, hi_s, w_s), lin(lo_e, hi_e, w_e)
    return Forcing(forcing.f_start - at_start[:, 2:], forcing.f_end - at_end[:, 2:],
                   forcing.tr_start + at_start[:, :2], forcing.tr_end + at_end[:, :2])


def second_pass(tables: Tables, prep: Prepared, samples: MotionSamples, tf, dwell, grid: Grid) -> Series:
    """The last pass of a rollout with the forcing of ``prep`` (corrected by ``first_pass`` and
    ``add_remainders``), then the dwell; the outputs at every node as a ``Series``."""
    n = grid.steps
    h = tf / n
    hd = dwell / grid.dwell_steps
    frozen, fast_start, fast_end, forcing, x0 = prep
    ne = x0.shape[0] // 2
    x_tf, ys = _motion(x0, frozen, forcing.f_start, forcing.f_end, forcing.tr_start, fast_start, samples.start[1],
                       samples.start[2], grid)
    final = lambda a: a[-1:]                   # the left limit at tf: the last interval's maps
    y_end = _outputs(jax.tree_util.tree_map(final, frozen), jax.tree_util.tree_map(final, fast_end),
                     final(samples.end[1]), final(samples.end[2]), x_tf[None], final(forcing.f_end),
                     final(forcing.tr_end))
    ys = jnp.concatenate([ys, y_end], axis=0)

    # ---- dwell: motors hold the place pose, constant coefficients
    rest = interpolate(tables, tables.breaks[-1])
    zero = jnp.zeros(())
    fz_d = _frozen(rest.slow(), zero, zero, hd, grid.squarings)
    f_d, tr_d = rest.fast().forcing(zero, zero)
    q_star = linalg.solve(rest.k0, rest.f0)
    e_static = rest.jx @ q_star

    b_d = jnp.broadcast_to(fz_d.g0 @ f_d, (grid.dwell_steps, x_tf.shape[0]))
    x_end, xd_states = _recurrence(fz_d.phi, x_tf, b_d, grid.unroll)
    xd_states = jnp.concatenate([xd_states, x_end[None]], axis=0)
    nd = xd_states.shape[0]
    over_dwell = lambda a: jnp.broadcast_to(a, (nd,) + a.shape)
    yd = _outputs(jax.tree_util.tree_map(lambda a: a[None], fz_d), jax.tree_util.tree_map(over_dwell, rest.fast()),
                  jnp.zeros(nd), jnp.zeros(nd), xd_states, over_dwell(f_d), over_dwell(tr_d))

    ksym = 0.5 * (rest.k0 + rest.k0.T)

    def energy(x):
        dq = x[:ne] - q_star
        return 0.5 * x[ne:] @ rest.mass @ x[ne:] + 0.5 * dq @ ksym @ dq

    t = jnp.arange(n + 1, dtype=float) * h
    td = tf + jnp.arange(grid.dwell_steps + 1, dtype=float) * hd
    return Series(t=t, e=ys[:, 0], ed=ys[:, 1], edd=ys[:, 2], tau=ys[:, 3],
                  t_dwell=td, e_dwell=yd[:, 0], ed_dwell=yd[:, 1], edd_dwell=yd[:, 2], tau_dwell=yd[:, 3],
                  e_static=e_static, energy_tf=energy(x_tf),
                  energy_dwell=jax.vmap(energy)(xd_states), state_tf=x_tf, dt=h, dt_dwell=hd,
                  edd_tf_low=low_mode_acceleration(rest.mass, rest.k0, rest.c0, rest.jx, q_star,
                                                   x_tf))
