"""The linearization along the path with the motors free: what the servo loop adds to
``jaxflex.linearized``.

Under a servo the motor angles leave the reference, q_a = q_ref(s) + d, so the equations are
linearized in z = [d, q_e] (n = 2 + ne) about the rigid motion:

    M z'' + C z' + K z = F + [u; 0],
    M = [[M_aa, M_ae], [M_ae^T, M_ee]],   K = [K_a, K_e],   C = [C_a, C_e],   F = [-tau_r; f],

with u the motors' torque. ``linearized.Coeffs`` holds the q_e columns (K_e = [T_q; K], C_e =
[T_v; C]), M_ee, M_ae, the forcing and the rigid torque; ``ServoCoeffs`` the rest: M_aa, the q_a
columns of the stiffness (K_a = ka0 + ka2 s'^2 + ka1 s'', every row) and of the damping (C_a = ca1 s',
the motion term's Jacobian by q_a'; the damping acts on q_e' only), and the end effector's motion
with the motors, e = jxa d + jx q_e (jxa1, jxa2 its path derivatives, as jx1, jx2). Each is one
term of the model's residual (``model.residual_term``) differentiated by q_a or q_a', exact in
(s', s'') as in ``linearized``. ``servo_remainder`` is the full model's second-order remainder with
the motors' deviation included.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxflex import model as mdl
from jaxflex.linearized import REMAINDER_T, Tables, table_poses
from jaxflex.path import Path
from jaxflex.robot import Robot


class ServoCoeffs(NamedTuple):
    """The coefficients a servo loop adds at one pose (module docstring); n = 2 + ne."""

    m_aa: jax.Array   # (2, 2) the motors' block of the reduced mass [kg m^2]
    ka0: jax.Array    # (n, 2) d residual / d q_a at rest
    ka1: jax.Array    # (n, 2) ... per unit s''
    ka2: jax.Array    # (n, 2) ... per unit s'^2
    ca1: jax.Array    # (n, 2) d residual / d q_a', per unit s'
    jxa: jax.Array    # (2, 2) dX/dq_a at q_e = 0 [m/rad]
    jxa1: jax.Array   # (2, 2) its derivative along the path (times q_a,s)
    jxa2: jax.Array   # (2, 2) its second derivative along the path

    def stiffness_damping(self, ds, dds):
        """K_a and C_a (n, 2) at path speed ds [m/s] and acceleration dds [m/s^2]."""
        return self.ka0 + self.ka2 * ds**2 + self.ka1 * dds, self.ca1 * ds


def servo_pose_coeffs(robot: Robot, qa, qa1, qa2) -> ServoCoeffs:
    """``ServoCoeffs`` at motor angles qa (2,) with path derivatives qa1 = dq_a/ds, qa2 = d2q_a/ds2."""
    ne = mdl.layout(robot).ne
    zero_e, zero2 = jnp.zeros(ne), jnp.zeros(2)
    by_qa = lambda name, qad, qadd: jax.jacfwd(lambda q: mdl.residual_term(robot, q, zero_e, name, qad, zero_e,
                                                                            qadd))(qa)
    ka0 = by_qa("potential", zero2, zero2)
    ka1 = by_qa("inertia", zero2, qa1)
    ka2 = by_qa("motion", qa1, qa2)
    ca1 = jax.jacfwd(lambda v: mdl.residual_term(robot, qa, zero_e, "motion", qa1 + v, zero_e, qa2))(zero2)
    m = mdl.reduced_mass(robot, qa, zero_e)

    def jxa_of(qq):
        return jax.jacfwd(lambda q: mdl.ee_position(robot, q, zero_e))(qq)

    jxa, jxa1 = jax.jvp(jxa_of, (qa,), (qa1,))
    d_jxa1 = lambda qq: jax.jvp(jxa_of, (qq,), (qa1,))[1]
    jxa2 = jax.jvp(d_jxa1, (qa,), (qa1,))[1] + jax.jvp(jxa_of, (qa,), (qa2,))[1]
    return ServoCoeffs(m_aa=m[:2, :2], ka0=ka0, ka1=ka1, ka2=ka2, ca1=ca1, jxa=jxa, jxa1=jxa1, jxa2=jxa2)


def servo_coeffs_at(robot: Robot, qa, qa1, qa2) -> ServoCoeffs:
    """``servo_pose_coeffs`` at a batch of poses (K, 2) each."""
    return jax.vmap(lambda a, b, c: servo_pose_coeffs(robot, a, b, c))(qa, qa1, qa2)


def build_servo_tables(robot: Robot, path: Path) -> Tables:
    """The servo coefficients tabulated at the nodes of the path's tables (``linearized.Tables`` with
    ``ServoCoeffs`` values); traceable."""
    return Tables(values=servo_coeffs_at(robot, *table_poses(robot, path)), breaks=path.breaks)


def servo_remainder(robot: Robot, qa, qa1, qa2, ds, dds, x, zdd):
    """The full model's second-order remainder (n,) along the path with the motors free: at the
    reference pose qa (2,) moving at path speed ds, acceleration dds, and the deviation
    x = [z, z'] (2 n,), z = [d, q_e], with acceleration zdd (n,), R(w) - R(0) - R'(0) w for
    w = [z, z', z''] (as ``linearized.remainder``, every row: the motors' and the elastic ones)."""
    n = zdd.shape[0]
    qad = qa1 * ds
    qadd = qa2 * ds**2 + qa1 * dds

    def full(w):
        z, zd, za = w[:n], w[n:2 * n], w[2 * n:]
        return mdl.residual(robot, qa + z[:2], z[2:], qad + zd[:2], zd[2:], qadd + za[:2], za[2:])

    w = jnp.concatenate([x, zdd])
    r0, r1, r1m = jax.vmap(lambda t: full(t * w))(jnp.asarray(REMAINDER_T))     # the even part, as there
    return 0.5 * (r1 + r1m) - r0
