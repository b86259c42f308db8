"""Reference simulation: the full nonlinear model integrated by classical RK4 (the second method).

Independent of the fast formulation (``jaxflex.linearized`` + ``jaxflex.simulate``): no
linearization, no tables, no exponential integrator. The state is the independent elastic state
[q_e, q_e'] with the motors prescribed by the rigid IGM of the desired trajectory; each RK4 stage calls
the nonlinear inverse dynamic model ``jaxflex.model.inverse_dynamics`` (passive coordinates solved
from the constraints in closed form, so the loop closes to round-off). The end-effector error uses
the nonlinear forward map, e = X(q_a, q_e) - X(q_a, 0), its derivatives by forward-mode autodiff.

RK4 is conditionally stable (|lambda h| < 2.78): the highest assumed mode of the default robot is
about 18.6 kHz, so h must stay below about 2.4e-5 s, and its numerical damping of that mode is small
only for h of a few microseconds (the default, 2e-6 s). It costs four nonlinear model evaluations per
step: this is the accurate, slow path used to check the fast one, not for sweeps.

Stage times t_k, t_k + h/2, t_k + h use right limits at t_k and left limits at t_k + h, so that with
a step count that is a multiple of 8 the trapezoids' acceleration jumps (at multiples of tf/8) fall
on step boundaries and are integrated exactly to the method's order.
"""
from __future__ import annotations

import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import model as mdl
from jaxflex import trees
from jaxflex.path import Path
from jaxflex.profiles import Profile, profile_eval
from jaxflex.robot import Robot, joint_motion
from jaxflex.simulate import Series, low_mode_acceleration
from jaxflex.trajectory import task_from_arc


@functools.partial(jax.jit, static_argnames="side")
def _joint_samples(robot: Robot, path: Path, profile: Profile, tf, eta, side):
    """Motor angles, rates, accelerations (T, 2) each at normalized times eta (T,) (one program per
    path family, law kind and sample count)."""
    v = profile_eval(profile, jnp.asarray(eta), side)
    s, ds, dds = v.s * path.length, v.ds * path.length / tf, v.dds * path.length / tf**2
    x, xd, xdd, _ = task_from_arc(path, s, ds, dds, jnp.zeros_like(s))
    return jax.vmap(lambda a, b, c: joint_motion(robot, a, b, c))(x, xd, xdd)


def _error(robot: Robot, qa, qe, qad, qed, qadd, qedd):
    """e, e', e'' (2,) each: X(q_a, q_e) - X(q_a, 0) and its time derivatives."""
    x = lambda a, b: mdl.ee_position(robot, a, b) - mdl.ee_position(robot, a, jnp.zeros_like(b))
    vel = lambda a, b: jax.jvp(x, (a, b), (qad, qed))[1]
    e, ed = jax.jvp(x, (qa, qe), (qad, qed))
    edd = jax.jvp(vel, (qa, qe), (qad, qed))[1] + jax.jvp(x, (qa, qe), (qadd, qedd))[1]
    return e, ed, edd


# classical RK4 as a loop over its four stages (one trace of the model instead of four): stage s
# evaluates the model at x + A[s] h k_{s-1} with the motor state MOTOR[s] (start, middle, end of the
# step) and adds B[s] h k_s
_RK4_A = (0.0, 0.5, 0.5, 1.0)
_RK4_B = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)
_RK4_MOTOR = (0, 1, 1, 2)


def _rk4(robot, h, x, stages):
    """One RK4 step of the elastic state x = [q_e, q_e'] with motor motion ``stages`` (3, 3, 2):
    (q_a, q_a', q_a'') at the start, middle and end of the step.

    Returns the new state and (q_e'', tau) at the start of the step (the first stage)."""
    ne = x.shape[0] // 2
    motor = stages[np.asarray(_RK4_MOTOR)]

    def stage(carry, inp):
        k_prev, acc = carry
        a, b, (qa, qad, qadd) = inp
        xx = x + a * h * k_prev
        qedd, tau = mdl.inverse_dynamics(robot, qa, xx[:ne], qad, xx[ne:], qadd)
        k = jnp.concatenate([xx[ne:], qedd])
        return (k, acc + b * k), (qedd, tau)

    zero = jnp.zeros_like(x)
    (_, acc), (qedd, tau) = jax.lax.scan(stage, (zero, zero), (jnp.asarray(_RK4_A), jnp.asarray(_RK4_B), motor))
    return x + h * acc, (qedd[0], tau[0])


def _outputs(robot, qa, qad, qadd, x, qedd, tau):
    ne = x.shape[0] // 2
    e, ed, edd = _error(robot, qa, x[:ne], qad, x[ne:], qadd, qedd)
    return jnp.stack([e, ed, edd, tau])


def reference_rollout(robot: Robot, path: Path | Sequence[Path], profile: Profile | Sequence[Profile], tf: float,
                      dwell: float = 0.1, dt: float = 1e-5, dwell_dt: float | None = None) -> Series:
    """Full nonlinear simulation of trajectories (motion over [0, tf] [s] then a dwell [s]) by RK4.

    ``profile`` is one motion law or a sequence of them, along ``path`` or along the matching
    element of a sequence of paths (one per law; they must share the pick and place points, as
    every path of one cycle does); ``robot.payload`` may be a 1-D array of
    payloads [kg]. The runs are vmapped (batching amortizes the per-operation overhead of the
    nonlinear model, which dominates a single sequential run). dt [s] is rounded down so that the
    motion has a multiple of 8 steps; the dwell uses dwell_dt (default dt). Returns a ``Series`` like
    ``jaxflex.simulate.rollout`` with outputs at every step and leading axes (profile, payload) for
    the batched inputs that were given, so ``jaxflex.metrics.metrics`` applies (vmapped).
    Each call compiles its program afresh (a slow, occasional cross-check; not cached).
    """
    tf, dwell, dt = float(tf), float(dwell), float(dt)
    if not (tf > 0 and dwell > 0 and dt > 0):
        raise ValueError(f"tf, dwell and dt must be > 0 s, got {tf}, {dwell}, {dt}")
    if dt > 2e-5:
        raise ValueError(f"RK4 reference step dt={dt} s is above its stability limit (~2.4e-5 s for "
                         "the 18.6 kHz axial mode of the default robot); use dt <= 2e-5 s")
    n = 8 * max(1, int(np.ceil(tf / dt / 8)))
    nd = max(1, int(np.ceil(dwell / (dwell_dt or dt))))
    single = isinstance(profile, Profile)
    profiles = [profile] if single else list(profile)
    paths = [path] * len(profiles) if isinstance(path, Path) else list(path)
    if len(paths) != len(profiles):
        raise ValueError(f"{len(paths)} paths for {len(profiles)} motion laws: give one path or one per law")
    tfa = jnp.asarray(tf)
    k = np.arange(n)
    samples = [tuple(_joint_samples(robot, pth, p, tfa, jnp.asarray(eta), side=side)
                     for eta, side in ((k / n, 1), ((k + 0.5) / n, 1), ((k + 1) / n, -1)))
               for pth, p in zip(paths, profiles)]
    samples = trees.stack(samples)
    payload = jnp.asarray(robot.payload, dtype=float)
    run = lambda m, smp: _reference(robot.replace(payload=m), smp, tfa, jnp.asarray(dwell), n, nd)
    if payload.ndim == 0:
        out = _batched(run, payload, samples, False)
    else:
        out = _batched(run, payload, samples, True)
    return jax.tree_util.tree_map(lambda a: a[0], out) if single else out


def _batched(run, payload, samples, over_payload):
    per_profile = jax.vmap(run, in_axes=(None, 0))
    if over_payload:
        return jax.jit(jax.vmap(per_profile, in_axes=(0, None), out_axes=1))(payload, samples)
    return jax.jit(per_profile)(payload, samples)


def _reference(robot, samples, tf, dwell, n, nd):
    """Motion (n steps) and dwell (nd steps) in one scan: one trace of the RK4 step."""
    h, hd = tf / n, dwell / nd
    starts, mids, ends = samples
    end = tuple(a[-1] for a in ends)
    qa_pick, qa_place, zero = starts[0][0], end[0], jnp.zeros(2)
    qe0, q_star = jax.vmap(lambda qa: mdl.static_equilibrium(robot, qa))(jnp.stack([qa_pick, qa_place]))
    x0 = jnp.concatenate([qe0, jnp.zeros_like(qe0)])
    ne = qe0.shape[0]
    hold = jnp.broadcast_to(jnp.stack([qa_place, zero, zero]), (nd, 3, 3, 2))    # motors hold the place
    motion = jnp.stack([jnp.stack(v, axis=1) for v in (starts, mids, ends)], axis=1)       # (n, 3, 3, 2)
    steps = jnp.concatenate([jnp.full(n, h), jnp.full(nd, hd)])

    def step(x, inp):
        hk, st = inp
        x_new, (qedd, tau) = _rk4(robot, hk, x, st)
        return x_new, (x, _outputs(robot, *st[0], x, qedd, tau))

    x_end, (states, ys) = jax.lax.scan(step, x0, (steps, jnp.concatenate([motion, hold])))
    x_tf = states[n]

    def outputs_at(motor, x):
        qedd, tau = mdl.inverse_dynamics(robot, motor[0], x[:ne], motor[1], x[ne:], motor[2])
        return _outputs(robot, *motor, x, qedd, tau)

    # the left limit at tf (motors still decelerating) and the end of the dwell
    y_tf, y_end = jax.vmap(outputs_at)(jnp.stack([jnp.stack(end), jnp.stack([qa_place, zero, zero])]),
                                       jnp.stack([x_tf, x_end]))
    ys_motion = jnp.concatenate([ys[:n], y_tf[None]])
    yd = jnp.concatenate([ys[n:], y_end[None]])

    e_static = mdl.ee_position(robot, qa_place, q_star) - mdl.ee_position(robot, qa_place, jnp.zeros(ne))
    v = lambda qe: mdl.potential(robot, mdl.full_coordinates(robot, qa_place, qe))

    def energy(x):
        m_ee = mdl.reduced(robot, qa_place, x[:ne], zero, x[ne:]).mass[2:, 2:]
        return 0.5 * x[ne:] @ m_ee @ x[ne:] + v(x[:ne]) - v(q_star)

    e_tf_end = jax.vmap(energy)(jnp.stack([x_tf, x_end]))
    return Series(t=jnp.arange(n + 1, dtype=float) * h, e=ys_motion[:, 0], ed=ys_motion[:, 1], edd=ys_motion[:, 2],
                  tau=ys_motion[:, 3], t_dwell=tf + jnp.arange(nd + 1, dtype=float) * hd, e_dwell=yd[:, 0],
                  ed_dwell=yd[:, 1], edd_dwell=yd[:, 2], tau_dwell=yd[:, 3], e_static=e_static,
                  energy_tf=e_tf_end[0], energy_dwell=e_tf_end, state_tf=x_tf, dt=h, dt_dwell=hd,
                  edd_tf_low=_low_modes(robot, qa_place, q_star, x_tf))


def _low_modes(robot, qa_place, q_star, x_tf):
    """Low-mode residual acceleration from the full model's linearization at the place pose (motors
    at rest, about q_e = 0, as ``linearized.pose_coeffs`` at zero path speed)."""
    ne = q_star.shape[0]
    zero2, zero_e = jnp.zeros(2), jnp.zeros(ne)
    jac = jax.jacfwd(lambda z: mdl.reduced(robot, qa_place, z[:ne], zero2, z[ne:]).force[2:])(jnp.zeros(2 * ne))
    mass = mdl.reduced(robot, qa_place, zero_e, zero2, zero_e).mass[2:, 2:]
    jx = jax.jacfwd(lambda x: mdl.ee_position(robot, qa_place, x))(zero_e)
    return low_mode_acceleration(mass, jac[:, :ne], jac[:, ne:], jx, q_star, x_tf)
