"""Trajectories = path x motion law x duration (paper Section 3): task and joint space samples.

X(t) = P(s(t)) with s(t) = L S(t / tf) (arc-length parametrization, docs/conventions.md#adept-cycle-and-blends), so
    X' = T s',  X'' = K s'^2 + T s'',  X''' = K' s'^3 + 3 K s' s'' + T s''',
with T, K, K' the arc-length derivatives of the path. Joint motion from the rigid IGM by
forward-mode autodiff. ``combinations`` stacks the 12 paper combinations (or any blends x
profiles), vmapped over profiles and time.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.path import Path, make_path, path_frame
from jaxflex.profiles import Profile, make_profile, profile_eval, time_scaled
from jaxflex.robot import Robot, check_cycle_reachable, joint_motion


class Trajectory(NamedTuple):
    """Samples of a trajectory on a time grid (leading batch axes allowed).

    t (T,) [s]; s, ds, dds (T,) arc length [m] and its time derivatives; x, xd, xdd, xddd (T, 2)
    task position [m], velocity [m/s], acceleration [m/s^2], jerk [m/s^3]; q, qd, qdd (T, 2) motor
    angles [rad], rates [rad/s], accelerations [rad/s^2] from the rigid IGM.
    """

    t: jax.Array
    s: jax.Array
    ds: jax.Array
    dds: jax.Array
    x: jax.Array
    xd: jax.Array
    xdd: jax.Array
    xddd: jax.Array
    q: jax.Array
    qd: jax.Array
    qdd: jax.Array


def check_tf(tf) -> None:
    """Eager check of a motion time."""
    if isinstance(tf, jax.core.Tracer):
        return
    v = np.asarray(tf, dtype=float)
    if v.ndim != 0:
        raise ValueError(f"motion time tf must be a scalar, got shape {v.shape}")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"motion time tf must be finite and > 0 s, got {tf}")


def time_grid(tf: float, steps: int) -> jax.Array:
    """Uniform grid of ``steps`` + 1 instants over [0, tf] [s]."""
    check_tf(tf)
    if not (np.ndim(steps) == 0 and np.isfinite(float(steps)) and float(steps) == int(steps) >= 1):
        raise ValueError(f"number of time steps must be >= 1 (an integer), got {steps}")
    return jnp.linspace(0.0, tf, int(steps) + 1)


def arc_motion(path: Path, profile: Profile, tf, t):
    """Arc length s(t) = L S(t/tf) and its first three time derivatives, each shaped like t."""
    check_tf(tf)
    law = time_scaled(profile_eval(profile, t / tf), tf)
    length = path.length
    return law.s * length, law.ds * length, law.dds * length, law.ddds * length


def task_from_arc(path: Path, s, ds, dds, ddds):
    """Task position, velocity, acceleration, jerk (..., 2) from arc-length motion samples (...,)."""
    flat = lambda a: jnp.reshape(a, (-1,))
    f = jax.vmap(path_frame, in_axes=(None, 0))(path, flat(s))
    ds, dds, ddds = flat(ds)[:, None], flat(dds)[:, None], flat(ddds)[:, None]
    x = f.pos
    xd = f.tangent * ds
    xdd = f.curv * ds**2 + f.tangent * dds
    xddd = f.dcurv * ds**3 + 3.0 * f.curv * ds * dds + f.tangent * ddds
    shape = jnp.shape(s) + (2,)
    return tuple(jnp.reshape(a, shape) for a in (x, xd, xdd, xddd))


def trajectory(robot: Robot, path: Path, profile: Profile, tf, t) -> Trajectory:
    """Sample one trajectory at the instants t (T,) [s] of a motion lasting tf [s].

    Concrete inputs are validated first (tf > 0, the cycle reachable without singularity), so a bad
    input raises a ValueError instead of returning NaN; traced inputs (under jit/vmap) are not."""
    check_tf(tf)
    leaves = jax.tree_util.tree_leaves((robot, path.cycle))
    if not any(isinstance(v, jax.core.Tracer) for v in leaves):
        with jax.ensure_compile_time_eval():     # concrete even inside a jit that closes over them
            check_cycle_reachable(robot, path.cycle)
    s, ds, dds, ddds = arc_motion(path, profile, tf, t)
    x, xd, xdd, xddd = task_from_arc(path, s, ds, dds, ddds)
    q, qd, qdd = jax.vmap(joint_motion, in_axes=(None, 0, 0, 0))(robot, x, xd, xdd)
    return Trajectory(t, s, ds, dds, x, xd, xdd, xddd, q, qd, qdd)


def combinations(robot, cycle, tf, t, d, e, n, blends, profiles) -> Trajectory:
    """Every blend x profile (static tuples of names; blend-major order) on the time grid t [s]:
    a ``Trajectory`` with a leading axis len(blends) * len(profiles). Traceable; on concrete values
    ``jaxflex.combinations.sample_combinations`` validates the inputs and runs it compiled."""
    out = []
    for blend in blends:
        path = make_path(cycle, blend, d, e, n)
        arcs = [arc_motion(path, make_profile(p), tf, t) for p in profiles]
        s, ds, dds, ddds = (jnp.stack(a) for a in zip(*arcs))          # (P, T) each
        x, xd, xdd, xddd = task_from_arc(path, s, ds, dds, ddds)
        joints = jax.vmap(jax.vmap(joint_motion, in_axes=(None, 0, 0, 0)),
                          in_axes=(None, 0, 0, 0))(robot, x, xd, xdd)
        tt = jnp.broadcast_to(t, s.shape)
        out.append(Trajectory(tt, s, ds, dds, x, xd, xdd, xddd, *joints))
    return jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *out)
