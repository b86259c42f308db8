"""Linearized elastodynamics about the rigid motion, tabulated along the path (the fast model of
docs/conventions.md#fast-model).

With the motors following the rigid IGM of a path P(s), q_a = q_a(s), and
    q_a' = q_a,s s',   q_a'' = q_a,ss s'^2 + q_a,s s''.
Linearizing the inverse dynamic model ``jaxflex.model`` about q_e = q_e' = 0 gives

    M(s) q_e'' + C q_e' + K q_e = f,              tau = tau_r + T_q q_e + T_v q_e' + M_ae q_e'',
    f = f0 + f2 s'^2 + f1 s'',   K = K0 + K2 s'^2 + K1 s'',   C = C0 + C1 s',
    tau_r = t0 + t2 s'^2 + t1 s'' (the rigid torque), T_q, T_v alike,

and the end-effector error e = X(q_a, q_e) - X(q_a, 0) = J(s) q_e + O(q_e^2), so
    e' = J q_e' + J1 s' q_e,   e'' = J q_e'' + 2 J1 s' q_e' + (J2 s'^2 + J1 s'') q_e.

Every coefficient is a function of the pose only. The polynomial dependence on (s', s'') is exact
(the equations are quadratic in velocities and linear in accelerations), so each coefficient is one
term of the nonlinear model's residual (``model.residual_term``: the potential at rest, the inertia
per unit s'', the motion per unit s'^2) or its forward-mode Jacobian w.r.t. q_e or q_e'; the
damping C0 is the Rayleigh damping matrix, and T_v has no term at rest. The coefficients are
tabulated on per-segment uniform grids of the path (line, blend, traverse, blend, line) and
interpolated with local cubics, which keeps their one-sided smoothness at the G2 joins. The tables
do not depend on the motion law or tf.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from jaxflex import model as mdl
from jaxflex import trees
from jaxflex.path import Path, path_frame
from jaxflex.robot import Robot, joint_motion

# nodes per path segment (line, blend, traverse, blend, line). The blends need the most: with half as
# many nodes on each blend, long blends with a small dwell residual (such as the optimized smoothstep
# design) read it noticeably low, and doubling these counts no longer changes it appreciably. The
# straight segments need few: doubling their nodes leaves the paper sweep's residuals practically
# unchanged. The node study is in docs/performance.md.
SEGMENT_NODES = (6, 96, 48, 96, 6)


class SlowCoeffs(NamedTuple):
    """The coefficients the rollout freezes over each coarse interval: mass, stiffness, damping and
    the torque maps of the elastic state (leaves as in ``Coeffs``)."""

    mass: jax.Array   # (ne, ne) M
    m_ae: jax.Array   # (2, ne) coupling of q_e'' into the torques
    k0: jax.Array     # (ne, ne)
    k1: jax.Array
    k2: jax.Array
    c0: jax.Array     # (ne, ne) damping
    c1: jax.Array     # (ne, ne) gyroscopic, per unit s'
    tq0: jax.Array    # (2, ne)
    tq1: jax.Array
    tq2: jax.Array
    tv0: jax.Array    # (2, ne)
    tv1: jax.Array

    def stiffness_damping(self, ds, dds):
        """K and C (ne, ne) at path speed ds [m/s] and acceleration dds [m/s^2]."""
        return self.k0 + self.k2 * ds**2 + self.k1 * dds, self.c0 + self.c1 * ds

    def torque_maps(self, ds, dds):
        """T_q and T_v (2, ne): torques per unit elastic displacement and velocity."""
        return self.tq0 + self.tq2 * ds**2 + self.tq1 * dds, self.tv0 + self.tv1 * ds


class FastCoeffs(NamedTuple):
    """The coefficients the rollout takes at every fine node: forcing, rigid torque, the output
    maps and the pose (leaves as in ``Coeffs``)."""

    f0: jax.Array     # (ne,) forcing at rest (gravity)
    f1: jax.Array     # (ne,) forcing per unit s''
    f2: jax.Array     # (ne,) forcing per unit s'^2
    t0: jax.Array     # (2,) rigid torque at rest
    t1: jax.Array
    t2: jax.Array
    jx: jax.Array     # (2, ne) J = dX/dq_e
    jx1: jax.Array    # (2, ne) dJ/dq_a . q_a,s
    jx2: jax.Array    # (2, ne) d2J/dq_a2 [q_a,s, q_a,s] + dJ/dq_a . q_a,ss
    qa: jax.Array     # (2,) the pose: motor angles [rad]
    qa1: jax.Array    # (2,) dq_a/ds [rad/m]
    qa2: jax.Array    # (2,) d2q_a/ds2 [rad/m^2]

    def forcing(self, ds, dds):
        """Elastic forcing f (ne,) [N] and rigid torque tau_r (2,) [N m] at path speed ds [m/s] and
        acceleration dds [m/s^2]."""
        return self.f0 + self.f2 * ds**2 + self.f1 * dds, self.t0 + self.t2 * ds**2 + self.t1 * dds


class Coeffs(NamedTuple):
    """Linearization coefficients at one pose (ne elastic coordinates); see module docstring. The
    rollout uses them in two groups, ``slow()`` and ``fast()``."""

    mass: jax.Array   # (ne, ne) M
    m_ae: jax.Array   # (2, ne) coupling of q_e'' into the torques
    f0: jax.Array     # (ne,) forcing at rest (gravity)
    f1: jax.Array     # (ne,) forcing per unit s''
    f2: jax.Array     # (ne,) forcing per unit s'^2
    k0: jax.Array     # (ne, ne)
    k1: jax.Array
    k2: jax.Array
    c0: jax.Array     # (ne, ne) damping
    c1: jax.Array     # (ne, ne) gyroscopic, per unit s'
    t0: jax.Array     # (2,) rigid torque at rest
    t1: jax.Array
    t2: jax.Array
    tq0: jax.Array    # (2, ne)
    tq1: jax.Array
    tq2: jax.Array
    tv0: jax.Array    # (2, ne)
    tv1: jax.Array
    jx: jax.Array     # (2, ne) J = dX/dq_e
    jx1: jax.Array    # (2, ne) dJ/dq_a . q_a,s
    jx2: jax.Array    # (2, ne) d2J/dq_a2 [q_a,s, q_a,s] + dJ/dq_a . q_a,ss
    qa: jax.Array     # (2,) the pose: motor angles [rad]
    qa1: jax.Array    # (2,) dq_a/ds [rad/m]
    qa2: jax.Array    # (2,) d2q_a/ds2 [rad/m^2]

    def slow(self) -> SlowCoeffs:
        return SlowCoeffs(*(getattr(self, k) for k in SlowCoeffs._fields))

    def fast(self) -> FastCoeffs:
        return FastCoeffs(*(getattr(self, k) for k in FastCoeffs._fields))


def coeff_shapes(robot: Robot) -> Coeffs:
    """The shapes and dtypes of ``pose_coeffs(robot, ...)`` (``jax.ShapeDtypeStruct`` leaves, float64)
    from the robot's mode counts alone: no trace of the model (tracing it is slow, and
    ``workspace.workspace_shapes`` would spend that time before anything can start compiling)."""
    ne = mdl.layout(robot).ne
    square, row, vec, pair = (ne, ne), (2, ne), (ne,), (2,)
    shapes = dict(mass=square, m_ae=row, f0=vec, f1=vec, f2=vec, k0=square, k1=square, k2=square, c0=square,
                  c1=square, t0=pair, t1=pair, t2=pair, tq0=row, tq1=row, tq2=row, tv0=row, tv1=row, jx=row,
                  jx1=row, jx2=row, qa=pair, qa1=pair, qa2=pair)
    return Coeffs(**{k: jax.ShapeDtypeStruct(v, jnp.float64) for k, v in shapes.items()})


def pose_coeffs(robot: Robot, qa, qa1, qa2) -> Coeffs:
    """Coefficients at motor angles qa (2,) with path derivatives qa1 = dq_a/ds, qa2 = d2q_a/ds2."""
    ne = mdl.layout(robot).ne
    zero_e, zero2 = jnp.zeros(ne), jnp.zeros(2)

    def term(name, qad, qadd):
        """A term of the residual (``model.residual_term``) and its Jacobian by q_e, at q_e = 0, from
        one trace of the term: the value is the Jacobian's primal (``jax.jacfwd``'s ``has_aux``),
        not a second trace of the model."""
        def value_twice(qe):
            y = mdl.residual_term(robot, qa, qe, name, qad, zero_e, qadd)
            return y, y
        jac, value = jax.jacfwd(value_twice, has_aux=True)(zero_e)
        return value, jac

    # the residual at (s', s'') is potential + s'' inertia(q_a,s) + motion(s' q_a,s, s'^2 q_a,ss) +
    # damping, and the motion term is quadratic in s': so at rest, per unit s'' and per unit s'^2
    r0, j0 = term("potential", zero2, zero2)
    r1, j1 = term("inertia", zero2, qa1)
    r2, j2 = term("motion", qa1, qa2)
    # by q_e': the damping matrix (the residual's only term linear in q_e' at rest: the motion term is
    # quadratic in the velocities), and the motion term's (gyroscopic) Jacobian per unit s'
    jv = jax.jacfwd(lambda qed: mdl.residual_term(robot, qa, zero_e, "motion", qa1, qed, qa2))(zero_e)
    m = mdl.reduced_mass(robot, qa, zero_e)
    e, a = slice(2, None), slice(0, 2)

    def jx_of(qq):
        return jax.jacfwd(lambda x: mdl.ee_position(robot, qq, x))(zero_e)

    jx, jx1 = jax.jvp(jx_of, (qa,), (qa1,))
    d_jx1 = lambda qq: jax.jvp(jx_of, (qq,), (qa1,))[1]
    jx2 = jax.jvp(d_jx1, (qa,), (qa1,))[1] + jax.jvp(jx_of, (qa,), (qa2,))[1]
    return Coeffs(
        mass=m[e, e], m_ae=m[a, e],
        f0=-r0[e], f1=-r1[e], f2=-r2[e],
        k0=j0[e], k1=j1[e], k2=j2[e],
        c0=mdl.damping_matrix(robot), c1=jv[e],
        t0=r0[a], t1=r1[a], t2=r2[a],
        tq0=j0[a], tq1=j1[a], tq2=j2[a],
        tv0=jnp.zeros((2, ne)), tv1=jv[a],
        jx=jx, jx1=jx1, jx2=jx2, qa=qa, qa1=qa1, qa2=qa2,
    )


def remainder(robot: Robot, qa, qa1, qa2, ds, dds, x, qedd):
    """Second-order remainder (2 + ne,) of the full reduced equations along the path.

    With the motors at q_a (2,) [rad] moving at path speed ds [m/s] and acceleration dds [m/s^2]
    (q_a,s = qa1, q_a,ss = qa2) and the elastic state x = [q_e, q_e'] (2 ne,) with acceleration
    qedd (ne,), the full equations read R(z) = M(q) [q_a''; q_e''] + F(q, q') = [tau; 0] with
    z = [q_e, q_e', q_e'']. The linearized model keeps R(0) + R'(0) z; this returns the rest,
    R(z) - R(0) - R'(0) z = O(|z|^2), to second order (its even part; the cubic term, O(|z|^3) as
    what the second-order model leaves out, is not included): rows [:2] add to the motor torques
    [N m], rows [2:] (with a minus sign) to the elastic forcing f. Used by the second-order rollout
    (``simulate.rollout``)."""
    ne = x.shape[0] // 2
    qad = qa1 * ds
    qadd = qa2 * ds**2 + qa1 * dds

    def full(z):
        return mdl.residual(robot, qa, z[:ne], qad, z[ne:2 * ne], qadd, z[2 * ne:])

    z = jnp.concatenate([x, qedd])
    # R(tz) at t = 0, 1, -1 (one vmapped trace of the model): the even part (R(z) + R(-z)) / 2 - R(0)
    # = R''(0)[z, z] / 2 + O(|z|^4) is the remainder but for its cubic term R'''(0)[z, z, z] / 6, of the
    # order of |z| / (link length) ~ 1e-3 of it: the same order, O(|z|^3), as what the second-order
    # model leaves out anyway. It keeps the model's own derivatives out of the compiled rollout and
    # its gradient (a JVP nested in them would make both several times larger), and costs three
    # evaluations of the model per site (docs/performance.md: the effect on the metrics)
    r0, r1, r1m = jax.vmap(lambda t: full(t * z))(jnp.asarray(REMAINDER_T))
    return 0.5 * (r1 + r1m) - r0


REMAINDER_T = (0.0, 1.0, -1.0)


def path_pose(robot: Robot, path: Path, s):
    """Motor angles and their first two arc-length derivatives at arc length s (scalar)."""
    f = path_frame(path, s)
    return joint_motion(robot, f.pos, f.tangent, f.curv)


class Tables(NamedTuple):
    """Coefficients tabulated along a path: ``values`` leaves have a leading node axis (sum of
    SEGMENT_NODES); ``breaks`` (6,) are the path's segment boundaries [m]."""

    values: Coeffs
    breaks: jax.Array

    def slow(self) -> "Tables":
        """The tables of the slow group only (``SlowCoeffs``)."""
        return Tables(values=self.values.slow(), breaks=self.breaks)

    def fast(self) -> "Tables":
        """The tables of the fast group only (``FastCoeffs``)."""
        return Tables(values=self.values.fast(), breaks=self.breaks)


def segment_nodes(breaks):
    """Arc lengths (sum(SEGMENT_NODES),) [m] of the table nodes: uniform per segment of the path,
    its ends included, between the segment boundaries ``breaks`` (6,)."""
    pieces = []
    for k, n in enumerate(SEGMENT_NODES):
        pieces.append(breaks[k] + (breaks[k + 1] - breaks[k]) * jnp.linspace(0.0, 1.0, n))
    return jnp.concatenate(pieces)


def table_poses(robot: Robot, path: Path):
    """Table nodes: motor angles and their arc-length derivatives, each (K, 2), at the nodes of the
    path (K = sum(SEGMENT_NODES)). Cheap; depends on the blend family (static)."""
    s = segment_nodes(path.breaks)
    return jax.vmap(lambda si: path_pose(robot, path, si))(s)


def coeffs_at(robot: Robot, qa, qa1, qa2) -> Coeffs:
    """Linearization coefficients at a batch of poses (K, 2) each. Independent of the path family,
    so one compiled function serves every blend (the expensive part of the tables)."""
    return jax.vmap(lambda a, b, c: pose_coeffs(robot, a, b, c))(qa, qa1, qa2)


def build_tables(robot: Robot, path: Path) -> Tables:
    """Tabulate the linearization coefficients along the path (vmapped over the nodes); traceable
    (differentiable in the path parameters). On concrete values ``jaxflex.tables.path_tables`` builds
    the same tables through one shared compiled program."""
    return Tables(values=coeffs_at(robot, *table_poses(robot, path)), breaks=path.breaks)


def cubic_weights(t):
    """Cubic Lagrange weights (4,) at t in [0, 3] for nodes 0..3 (the path tables' and the workspace's
    local interpolants)."""
    return jnp.stack([-(t - 1) * (t - 2) * (t - 3) / 6, t * (t - 2) * (t - 3) / 2,
                      -t * (t - 1) * (t - 3) / 2, t * (t - 1) * (t - 2) / 6])


def interpolate(tables: Tables, s) -> Coeffs:
    """Coefficients at arc length s (scalar) by local cubic interpolation within its segment."""
    br = tables.breaks
    counts = np.array(SEGMENT_NODES)
    offsets = jnp.asarray(np.concatenate([[0], np.cumsum(counts)[:-1]]))
    s = jnp.clip(s, br[0], br[-1])
    seg = jnp.clip(jnp.sum(s >= br[1:5]), 0, 4)
    a, b = br[seg], br[seg + 1]
    n = jnp.asarray(counts)[seg]
    width = b - a
    u = jnp.where(width > 0, (s - a) / jnp.where(width > 0, width, 1.0), 0.0) * (n - 1).astype(float)
    i0 = jnp.clip(jnp.floor(u).astype(int) - 1, 0, n - 4)
    t = u - i0.astype(float)
    return trees.map_packed(lambda v: _window_sum(v, offsets[seg] + i0, t), tables.values, lead=1)


@jax.custom_jvp
def _window_sum(v, start, t):
    """sum_k w_k(t) v[start + k] (F,): the cubic interpolant of the rows v (K, F) at t in [0, 3]
    on the nodes start .. start + 3 (``start`` an integer; w = ``cubic_weights``).

    The value is a gather; so is its tangent in v, whose transpose in reverse mode is a
    scatter-add. Its derivative is a custom JVP for the tangent in t (the arc length's): the
    interpolant's slope sum_k w_k'(t) v[start + k] (F,) times dt, so reverse mode stores one
    slope per sample where the chain rule through the weights would store the window (4, F).

    The tangent in v is a gather rather than a dense row of K weights times dv: the dense form's
    transpose is a matrix product, faster in wall time for one program alone because it runs on
    several cores, but it costs more CPU time, and the design gradient runs two models side by
    side, so CPU time is what counts (docs/performance.md)."""
    return jnp.tensordot(cubic_weights(t), v[start + jnp.arange(4)], axes=1)


def _window_sum_jvp(primals, tangents):
    v, start, t = primals
    dv, _, dt = tangents
    idx = start + jnp.arange(4)
    window = v[idx]
    w, w_t = jax.jvp(cubic_weights, (t,), (jnp.ones_like(t),))
    out = jnp.tensordot(w, window, axes=1)          # the value, as ``_window_sum``
    tangent = jnp.zeros_like(out)
    if not isinstance(dv, SymbolicZero):         # tables that do not depend on the inputs: no gather
        tangent = tangent + jnp.tensordot(w, dv[idx], axes=1)
    if not isinstance(dt, SymbolicZero):
        tangent = tangent + dt * jnp.tensordot(w_t, window, axes=1)
    return out, tangent


_window_sum.defjvp(_window_sum_jvp, symbolic_zeros=True)


def evaluate(c: Coeffs, ds, dds):
    """Mass, stiffness, damping, forcing and torque maps at path speed ds [m/s], acceleration dds."""
    slow, fast = c.slow(), c.fast()
    k, cc = slow.stiffness_damping(ds, dds)
    tq, tv = slow.torque_maps(ds, dds)
    f, tr = fast.forcing(ds, dds)
    return c.mass, k, cc, f, tq, tv, tr
