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

import contextlib
import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import model as mdl
from jaxflex import trees
from jaxflex.path import Path
from jaxflex.profiles import Profile, profile_eval
from jaxflex.progress import Progress
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
                      dwell: float = 0.1, dt: float = 1e-5, dwell_dt: float | None = None, *,
                      progress: bool = True) -> Series:
    """Full nonlinear simulation of trajectories (motion over [0, tf] [s] then a dwell [s]) by RK4.

    ``profile`` is one motion law or a sequence of them, along ``path`` or along the matching
    element of a sequence of paths (one per law; they must share the pick and place points, as
    every path of one cycle does); ``robot.payload`` may be a 1-D array of
    payloads [kg]. The runs are vmapped (batching amortizes the per-operation overhead of the
    nonlinear model, which dominates a single sequential run). dt [s] is rounded down so that the
    motion has a multiple of 8 steps; the dwell uses dwell_dt (default dt). Returns a ``Series`` like
    ``jaxflex.simulate.rollout`` with outputs at every step and leading axes (profile, payload) for
    the batched inputs that were given, so ``jaxflex.metrics.metrics`` applies (vmapped).
    Each call compiles its programs afresh (a slow, occasional cross-check; not cached); the steps
    run in ``CHUNKS`` calls, with ``progress`` shown on stderr (elapsed time, ETA).
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
    payload = np.asarray(robot.payload, dtype=float)
    # one flat batch of runs (law-major, then payload), every input repeated per run
    runs = [(float(m), smp) for smp in samples for m in np.atleast_1d(payload)]
    masses = jnp.asarray([m for m, _ in runs])
    samples = trees.stack([smp for _, smp in runs])
    out = _integrate(robot, masses, samples, tfa, jnp.asarray(dwell), n, nd, progress)
    shape = (len(profiles),) + payload.shape
    out = jax.tree_util.tree_map(lambda a: a.reshape(shape + a.shape[1:]), out)
    return jax.tree_util.tree_map(lambda a: a[0], out) if single else out


CHUNKS = 40      # the RK4 scan runs in this many calls of one compiled program (progress, ETA)


def _integrate(robot, masses, samples, tf, dwell, n, nd, progress):
    """The batch of runs (leading axis B of ``masses`` [kg] and ``samples``): start, the RK4 steps
    in CHUNKS calls of one program (progress on stderr with an ETA), the outputs at the ends."""
    size = -(-(n + nd) // CHUNKS)
    total = size * CHUNKS
    with_robot = lambda m: robot.replace(payload=m)
    plan = jax.jit(jax.vmap(lambda m, smp: _plan(with_robot(m), smp, tf, dwell, n, nd, total)))
    advance = jax.jit(jax.vmap(lambda m, x, h, motor, i: _advance(with_robot(m), x, h, motor, i, size),
                               in_axes=(0, 0, 0, 0, None)))
    finish = jax.jit(jax.vmap(lambda m, smp, x_tf, x_end, ys: _finish(with_robot(m), smp, tf, dwell, n, nd,
                                                                      x_tf, x_end, ys)))
    bar = Progress(f"full model (RK4, h = {float(tf) / n * 1e6:.3g} us, {masses.shape[0]} runs)", total=CHUNKS,
                   unit="chunk", enabled=progress)
    with bar:
        with bar.waiting("compiling the model's programs and starting"):
            x, h, motor = jax.block_until_ready(plan(masses, samples))
        x_tf, ys = None, []
        for c in range(CHUNKS):
            with bar.waiting("compiling the RK4 step, first chunk") if c == 0 else contextlib.nullcontext():
                x_next, (states, y) = jax.block_until_ready(advance(masses, x, h, motor, jnp.asarray(c * size)))
            if c * size <= n < (c + 1) * size:
                x_tf = states[:, n - c * size]
            x = x_next
            ys.append(y)
            bar.update(c + 1)
        with bar.waiting("outputs at tf and at the end of the dwell"):
            return jax.block_until_ready(finish(masses, samples, x_tf, x, jnp.concatenate(ys, axis=1)[:, :n + nd]))


def _plan(robot, samples, tf, dwell, n, nd, total):
    """Initial state (static equilibrium at the pick pose), step sizes (total,) (motion n steps,
    dwell nd steps, then zero steps: the identity, padding to whole chunks) and motor motion
    (total, 3, 3, 2) of every step."""
    h, hd = tf / n, dwell / nd
    starts, mids, ends = samples
    qa_pick, qa_place, zero = starts[0][0], ends[0][-1], jnp.zeros(2)
    qe0 = mdl.static_equilibrium(robot, qa_pick)
    x0 = jnp.concatenate([qe0, jnp.zeros_like(qe0)])
    hold = jnp.broadcast_to(jnp.stack([qa_place, zero, zero]), (total - n, 3, 3, 2))   # motors hold the place
    motion = jnp.stack([jnp.stack(v, axis=1) for v in (starts, mids, ends)], axis=1)      # (n, 3, 3, 2)
    steps = jnp.concatenate([jnp.full(n, h), jnp.full(nd, hd), jnp.zeros(total - n - nd)])
    return x0, steps, jnp.concatenate([motion, hold])


def _advance(robot, x, steps, motor, start, size):
    """``size`` RK4 steps from step ``start``: the state after them and, per step, the state at its
    start and the outputs (e, e', e'', tau) there."""
    h = jax.lax.dynamic_slice_in_dim(steps, start, size)
    m = jax.lax.dynamic_slice_in_dim(motor, start, size)

    def step(x, inp):
        hk, st = inp
        x_new, (qedd, tau) = _rk4(robot, hk, x, st)
        return x_new, (x, _outputs(robot, *st[0], x, qedd, tau))

    return jax.lax.scan(step, x, (h, m))


def _finish(robot, samples, tf, dwell, n, nd, x_tf, x_end, ys):
    """The ``Series`` from the per-step outputs ys (n + nd, 4, 2) and the states at tf and at the
    end of the dwell."""
    h, hd = tf / n, dwell / nd
    starts, mids, ends = samples
    end = tuple(a[-1] for a in ends)
    qa_place, zero = end[0], jnp.zeros(2)
    q_star = mdl.static_equilibrium(robot, qa_place)
    ne = q_star.shape[0]

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
