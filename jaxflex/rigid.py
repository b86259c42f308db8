"""Rigid five-bar inverse dynamics by virtual power (Newton-Euler per body), independent of the
elastic assembly in ``jaxflex.model``.

Bodies: proximal rods (mass rho A l1, centroidal inertia m l1^2 / 12), distal rods (mass rho A l2),
payload point mass at the end effector, motor rotors. With the motor angles q as the only coordinates,

    tau = sum_b J_b^T m_b (a_b - g) + J_theta_b^T I_b alpha_b + J_r q'',

where a_b, alpha_b are the centre-of-mass and angular accelerations from the rigid DGM. Used as the
reference of the rigid limit and to split torques into rigid and elastic parts.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxflex.robot import Robot, dgm, elbows


def _bodies(robot: Robot, q):
    """Centre-of-mass positions (4, 2) and angles (4,) of the links, and the end effector (2,)."""
    x = dgm(robot, q)
    e = elbows(robot, q)
    base = robot.bases
    com = jnp.stack([0.5 * (base[0] + e[0]), 0.5 * (e[0] + x), 0.5 * (base[1] + e[1]), 0.5 * (e[1] + x)])
    d1, d2 = x - e[0], x - e[1]
    ang = jnp.stack([q[0], jnp.arctan2(d1[1], d1[0]), q[1], jnp.arctan2(d2[1], d2[0])])
    return com, ang, x


def rigid_torques(robot: Robot, q, qd, qdd) -> jax.Array:
    """Motor torques (2,) [N m] of the rigid robot moving with q, q', q'' (each (2,))."""
    f = lambda qq: _bodies(robot, qq)
    pos, vel = jax.jvp(f, (q,), (qd,))
    dvel = lambda qq: jax.jvp(f, (qq,), (qd,))[1]
    acc_vv = jax.jvp(dvel, (q,), (qd,))[1]
    acc_a = jax.jvp(f, (q,), (qdd,))[1]
    com_acc, ang_acc, x_acc = (a + b for a, b in zip(acc_vv, acc_a))
    jac_com, jac_ang, jac_x = jax.jacfwd(f)(q)         # (4, 2, 2), (4, 2), (2, 2)
    m1 = robot.rho * robot.area * robot.l1
    m2 = robot.rho * robot.area * robot.l2
    masses = jnp.stack([m1, m2, m1, m2])
    inertia = masses * jnp.stack([robot.l1, robot.l2, robot.l1, robot.l2]) ** 2 / 12.0
    g = robot.gravity
    lin = jnp.einsum("bij,bi->j", jac_com, masses[:, None] * (com_acc - g[None]))
    rot = jac_ang.T @ (inertia * ang_acc)
    pay = jac_x.T @ (robot.payload * (x_acc - g))
    return lin + rot + pay + robot.rotor_inertia * qdd
