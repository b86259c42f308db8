"""The full nonlinear model under a servo loop: the reference for the closed-loop fast model.

The motors are no longer prescribed: the state is X = [q_a, q_e, q_a', q_e'] (2 (2 + ne)), driven by
the servo's torque (``jaxflex.servo``), computed at every sample t_k = k T from the state there and
held until the next one. Between samples the field X' = [X_v; M_r^-1 ([u; 0] - F)] (the nonlinear
direct dynamics, ``model.direct_dynamics``) is autonomous, so the exponential integrator of
``jaxflex.reference`` (third order, about the field's Jacobian at the sample) integrates each sample
period exactly to its order in ``substeps`` steps: the sample-and-hold needs no interpolation. The
reference motion enters only through the controller, at the samples.

The error is e = X(q_a, q_e) - X(q_ref, 0) (the desired position: the rigid forward model of the
reference angles), with its time derivatives. The run starts from the closed-loop static
equilibrium at the pick pose; the dwell residual is measured from the closed-loop static
equilibrium at the place pose (motors where the servo's torque balances gravity and the
deflection). Over [0, tf] the reference follows the trajectory, then holds the place pose.

tf and the dwell must hold a whole number of sample periods (integer-kHz rates with times in ms do).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import checks
from jaxflex import model as mdl
from jaxflex.expm import phi_times, squarings_for
from jaxflex.path import Path, path_frame
from jaxflex.profiles import Profile
from jaxflex.progress import Progress
from jaxflex.reference import joint_samples, velocity_scaling
from jaxflex.rigid import rigid_torques
from jaxflex.robot import Robot, igm
from jaxflex.runtime import options
from jaxflex.servo import Servo, feedforward_advance, static_torque, with_rotor
from jaxflex.simulate import Series, low_mode_acceleration

DEFAULT_DT = 2e-5      # [s] the largest substep (the period is cut into the fewest substeps below it)
CHUNK = 256            # samples per call of the stepping program


def _field(robot, x, u):
    """X' (2 n,) and the accelerations (n,) at the state x with the motor torques u (2,)."""
    n = x.shape[0] // 2
    qadd, qedd = mdl.direct_dynamics(robot, x[:2], x[2:n], x[n:n + 2], x[n + 2:], u)
    acc = jnp.concatenate([qadd, qedd])
    return jnp.concatenate([x[n:], acc]), acc


def _exprb3(robot, h, x, u, omega, squarings, jac):
    """One third-order exponential step of the autonomous field (``reference._exprb3`` with the
    motor torque u held): u_a at h/2, u_b at h, the remainder N = F - J x interpolated
    quadratically. Returns the new state and the accelerations at the step's start."""
    s, scaled = velocity_scaling(jac, omega)
    a = h * scaled
    phi = lambda *v: phi_times(a, [h * s * vi for vi in v], squarings) / s
    f0, acc0 = _field(robot, x, u)
    n0 = f0 - jac @ x
    xa = x + phi_times(0.5 * a, [0.5 * h * s * f0], max(squarings - 1, 0)) / s
    na = _field(robot, xa, u)[0] - jac @ xa
    xb = x + phi(f0, 2.0 * (na - n0))
    nb = _field(robot, xb, u)[0] - jac @ xb
    return x + phi(f0, -3.0 * n0 + 4.0 * na - nb, 4.0 * (n0 - 2.0 * na + nb)), acc0


def _torque(servo: Servo, x, ref, integral):
    """The servo's torque (2,) at a sample from the state x and the reference ref (3, 2) = (q_ref,
    q_ref', tau_ff), with the integral of the angle error [rad s]; clipped to the torque limit."""
    n = x.shape[0] // 2
    u = ref[2] + servo.kp * (ref[0] - x[:2]) + servo.kd * (ref[1] - x[n:n + 2]) + servo.ki * integral
    return jnp.clip(u, -servo.torque_limit, servo.torque_limit)


def _error(robot, x, acc, ref_motion):
    """e, e', e'' (2,) each: X(q_a, q_e) - X(q_ref, 0) with the reference motion ref_motion (3, 2)."""
    n = x.shape[0] // 2
    ee = lambda qa, qe: mdl.ee_position(robot, qa, qe)
    qe0 = jnp.zeros(n - 2)
    qa, qe, qad, qed, qadd, qedd = x[:2], x[2:n], x[n:n + 2], x[n + 2:], acc[:2], acc[2:]
    r, rd, rdd = ref_motion
    pos, vel = jax.jvp(ee, (qa, qe), (qad, qed))
    acc_ = jax.jvp(lambda a, b: jax.jvp(ee, (a, b), (qad, qed))[1], (qa, qe), (qad, qed))[1] + \
        jax.jvp(ee, (qa, qe), (qadd, qedd))[1]
    pr, vr = jax.jvp(lambda a: ee(a, qe0), (r,), (rd,))
    ar = jax.jvp(lambda a: jax.jvp(lambda b: ee(b, qe0), (a,), (rd,))[1], (r,), (rd,))[1] + \
        jax.jvp(lambda a: ee(a, qe0), (r,), (rdd,))[1]
    return jnp.stack([pos - pr, vel - vr, acc_ - ar])


def equilibrium(robot: Robot, servo: Servo, q_ref, tau_ff, iterations: int = 12):
    """The closed-loop static equilibrium (q_a, q_e) with the reference held at q_ref (2,) and the
    feedforward tau_ff (2,) [N m]: the static forces (gravity, elasticity) balance [u; 0] with
    u = tau_ff + Kp (q_ref - q_a) (Newton from q_a = q_ref and the locked equilibrium)."""
    qe0 = mdl.static_equilibrium(robot, q_ref)
    n = 2 + qe0.shape[0]
    zero = jnp.zeros(n)

    def residual(z):
        force = mdl.reduced(robot, z[:2], z[2:], zero[:2], zero[2:]).force
        return force - jnp.concatenate([tau_ff + servo.kp * (q_ref - z[:2]), zero[2:]])

    def step(z, _):
        jac, r = jax.jacfwd(lambda v: (residual(v),) * 2, has_aux=True)(z)
        return z - jnp.linalg.solve(jac, r), None

    z, _ = jax.lax.scan(step, jnp.concatenate([q_ref, qe0]), None, length=iterations)
    return z[:2], z[2:]


def _energy(robot, servo, x, q_ref, tau_ff, z_star):
    """Vibration energy [J] of the state x relative to the closed-loop equilibrium z_star (n,) with
    the reference held at q_ref and the feedforward tau_ff: kinetic + gravity and strain + the
    controller's spring (its static torque tau_ff + Kp (q_ref - q_a) derives from a potential)."""
    n = x.shape[0] // 2
    q, qd = x[:n], x[n:]

    def potential(z):
        v = mdl.potential(robot, mdl.full_coordinates(robot, z[:2], z[2:]))
        dq = q_ref - z[:2]
        return v + 0.5 * dq @ (servo.kp * dq) - tau_ff @ z[:2]

    mass = mdl.reduced_mass(robot, q[:2], q[2:])
    return 0.5 * qd @ mass @ qd + potential(q) - potential(z_star)


@functools.partial(jax.jit, static_argnames=("substeps", "squarings"), compiler_options=options.BUILD)
def _advance(robot, servo, omega, carry, refs, motions, h, *, substeps, squarings):
    """``len(refs)`` sample periods from ``carry`` = (X, held torque, pending torque, integral):
    per period the torque from the state at its start (applied now, or next period with a delay),
    then ``substeps`` exponential steps. refs (K, 3, 2): (q_ref, q_ref', tau_ff) at the samples;
    motions (K, substeps, 3, 2): the reference motion at every substep's start (for the error).
    Returns the carry and per substep the state, the applied torque and (e, e', e'')."""
    def period(c, inp):
        x, _, pending, integral = c
        ref, motion = inp
        new = _torque(servo, x, ref, integral)
        u = pending if servo.delay else new
        jac = jax.jacfwd(lambda v: _field(robot, v, u)[0])(x)

        def sub(x, mot):
            x_new, acc = _exprb3(robot, h, x, u, omega, squarings, jac)
            return x_new, (x, u, _error(robot, x, acc, mot))

        x_end, out = jax.lax.scan(sub, x, motion)
        integral = integral + (ref[0] - x[:2]) * (h * substeps)
        return (x_end, u, new, integral), out

    return jax.lax.scan(period, carry, (refs, motions))


@functools.partial(jax.jit, compiler_options=options.ONCE)
def _start(robot, servo, ref_pick, ref_place):
    """The closed-loop equilibria at the pick and place poses (refs (3, 2) = (q_ref, q_ref',
    tau_ff) at rest there), the static error at the place [m], and the elastic frequency scale
    omega [rad/s] with the 1-norm of the scaled Jacobian per second (to choose the squarings)."""
    qa0, qe0 = equilibrium(robot, servo, ref_pick[0], ref_pick[2])
    qa1, qe1 = equilibrium(robot, servo, ref_place[0], ref_place[2])
    n = 2 + qe0.shape[0]
    x0 = jnp.concatenate([qa0, qe0, jnp.zeros(n)])
    u0 = _torque(servo, x0, ref_pick, jnp.zeros(2))
    jac = jax.jacfwd(lambda v: _field(robot, v, u0)[0])(x0)
    omega = jnp.sqrt(jnp.max(jnp.sum(jnp.abs(jac[n:, :n]), axis=0)))
    norm = jnp.max(jnp.sum(jnp.abs(velocity_scaling(jac, omega)[1]), axis=0))
    e_static = mdl.ee_position(robot, qa1, qe1) - mdl.ee_position(robot, ref_place[0], jnp.zeros_like(qe1))
    return x0, u0, jnp.concatenate([qa1, qe1]), e_static, omega, norm


@functools.partial(jax.jit, compiler_options=options.ONCE)
def _ends(robot, servo, x_tf, u_tf, x_end, u_end, motion_tf, ref_place, z_star):
    """Outputs at tf (left limit: the torque u_tf held before it, the reference's left-limit motion
    motion_tf (3, 2)) and at the end of the dwell (torque u_end), the vibration energies there and
    the low-mode residual acceleration at tf."""
    acc_tf, acc_end = _field(robot, x_tf, u_tf)[1], _field(robot, x_end, u_end)[1]
    rest = jnp.stack([ref_place[0], jnp.zeros(2), jnp.zeros(2)])
    y = jnp.stack([_error(robot, x_tf, acc_tf, motion_tf), _error(robot, x_end, acc_end, rest)])
    energy = jax.vmap(lambda x: _energy(robot, servo, x, ref_place[0], ref_place[2], z_star))(jnp.stack([x_tf, x_end]))
    n = x_tf.shape[0] // 2
    qa, qe_star = ref_place[0], z_star[2:]
    zero2, zero_e = jnp.zeros(2), jnp.zeros(n - 2)

    def force(z):
        red = mdl.reduced(robot, qa, z[:n - 2], zero2, z[n - 2:])
        return red.force[2:], red.mass[2:, 2:]

    jac, mass = jax.jacfwd(force, has_aux=True)(jnp.zeros(2 * (n - 2)))
    jx = jax.jacfwd(lambda v: mdl.ee_position(robot, qa, v))(zero_e)
    elastic = jnp.concatenate([x_tf[2:n], x_tf[n + 2:]])
    low = low_mode_acceleration(mass, jac[:, :n - 2], jac[:, n - 2:], jx, qe_star, elastic)
    return y, energy, low


def _references(robot, path, profile, tf, rate, samples, substeps, feedforward, flexible_tau):
    """(refs (K, 3, 2), motions (K, substeps, 3, 2)) over the whole run: the reference motion at the
    samples and substeps (the trajectory over [0, tf], then the place pose at rest) and the
    feedforward at the samples."""
    h = 1.0 / rate / substeps
    t = np.arange(samples * substeps) * h
    eta = np.clip(t / tf, 0.0, 1.0)
    q, qd, qdd = (np.array(a) for a in joint_samples(robot, path, profile, jnp.asarray(tf), eta, 1))
    after = t >= tf - 0.5 * h
    qd[after], qdd[after] = 0.0, 0.0
    motion = np.stack([q, qd, qdd], axis=1)                    # (K m, 3, 2)
    at_samples = motion[::substeps]
    if feedforward == "none":
        tau = np.zeros((samples, 2))
    elif feedforward == "rigid":
        tau = np.asarray(jax.jit(jax.vmap(lambda a, b, c: rigid_torques(robot, a, b, c)))(
            *(jnp.asarray(at_samples[:, i]) for i in range(3))))
    else:
        tau = np.asarray(flexible_tau)
    refs = np.stack([at_samples[:, 0], at_samples[:, 1], tau], axis=1)
    return refs, motion.reshape(samples, substeps, 3, 2)


def _whole(name, seconds, rate):
    k = seconds * rate
    if abs(k - round(k)) > 1e-6 or round(k) < 1:
        raise ValueError(f"{name} = {seconds:g} s holds {k:g} sample periods at {rate:g} Hz; the closed-loop "
                         "reference needs a whole number (e.g. an integer-kHz rate with times in ms)")
    return int(round(k))


def closed_loop_rollout(robot: Robot, path: Path, profile: Profile, tf: float, dwell: float, servo: Servo,
                        dt: float = DEFAULT_DT, progress: bool = True) -> Series:
    """The full nonlinear model under the servo (module docstring): motion over [0, tf] [s], then a
    dwell [s] with the reference holding the place pose. The robot gets the servo's rotor; each
    sample period is cut into the fewest substeps of at most dt [s]. Returns a ``Series`` with
    outputs at every substep (``tau``: the applied torque), so ``jaxflex.metrics`` applies. A
    "flexible" feedforward is the perfect controller's torque of the same robot
    (``reference.reference_rollout`` at the same substep) over the motion, advanced by
    ``servo.feedforward_advance``, and the static torque at the place (``servo.static_torque``)
    through the dwell."""
    from jaxflex.reference import reference_rollout

    servo = servo.checked()
    tf, dwell = checks.positive("tf", tf, "s"), checks.positive("dwell", dwell, "s")
    rate = float(servo.rate)
    k_motion, k_dwell = _whole("tf", tf, rate), _whole("dwell", dwell, rate)
    substeps = max(1, int(np.ceil(1.0 / rate / checks.positive("dt", dt, "s") - 1e-9)))
    h = 1.0 / rate / substeps
    r = with_rotor(robot, servo)
    samples = k_motion + k_dwell
    flexible_tau = None
    if servo.feedforward == "flexible":
        ref = reference_rollout(r, path, profile, tf, dwell, dt=h, progress=progress)
        t_ref, tau_ref = np.asarray(ref.t), np.asarray(ref.tau)
        at = np.clip(np.arange(k_motion) / rate + float(feedforward_advance(servo)), 0.0, tf)
        motion = np.column_stack([np.interp(at, t_ref, tau_ref[:, i]) for i in range(2)])
        place = np.asarray(static_torque(r, igm(r, jnp.asarray(path_frame(path, path.length).pos))))
        flexible_tau = np.concatenate([motion, np.broadcast_to(place, (k_dwell, 2))])
        if flexible_tau.shape[0] != samples:
            raise ValueError("the flexible feedforward's samples do not match the servo's")
    refs, motions = _references(r, path, profile, tf, rate, samples, substeps, servo.feedforward, flexible_tau)
    motion_tf = np.stack([np.asarray(a)[0] for a in joint_samples(r, path, profile, jnp.asarray(tf), np.ones(1), -1)])
    place = np.concatenate([refs[-1, :1], np.zeros((1, 2)), refs[-1, 2:]])
    x0, u0, z_star, e_static, omega, norm = _start(r, servo, jnp.asarray(refs[0]), jnp.asarray(place))
    squarings = max(5, squarings_for(2.0 * float(norm) * h))
    carry = (x0, u0, u0, jnp.zeros(2))
    bar = Progress(f"full model under the servo (h = {h * 1e6:.3g} us, {samples} samples)",
                   total=-(-samples // CHUNK), unit="chunk", enabled=progress)
    states, torques, errors = [], [], []
    with bar:
        for i in range(0, samples, CHUNK):
            refs_c, motions_c = refs[i:i + CHUNK], motions[i:i + CHUNK]
            keep = len(refs_c)
            if keep < CHUNK:             # padded with the last sample (run past the end, not kept)
                refs_c = np.concatenate([refs_c, np.repeat(refs_c[-1:], CHUNK - keep, axis=0)])
                motions_c = np.concatenate([motions_c, np.repeat(motions_c[-1:], CHUNK - keep, axis=0)])
            carry, (xs, us, es) = jax.block_until_ready(_advance(
                r, servo, omega, carry, jnp.asarray(refs_c), jnp.asarray(motions_c), jnp.asarray(h),
                substeps=substeps, squarings=squarings))
            xs, us, es = np.asarray(xs), np.asarray(us), np.asarray(es)
            states.append(xs[:keep]), torques.append(us[:keep]), errors.append(es[:keep])
            # the state at the end of the run: the carry, or the first padded period's start
            x_end = np.asarray(carry[0]) if keep == CHUNK else xs[keep, 0]
            bar.update()
    xs = np.concatenate(states).reshape(-1, x0.shape[0])
    us = np.concatenate(torques).reshape(-1, 2)
    es = np.concatenate(errors).reshape(-1, 3, 2)
    n_m, nd = k_motion * substeps, k_dwell * substeps
    x_tf = xs[n_m]                   # the state at tf; its left limit takes the torque held before it
    y, energy, low = _ends(r, servo, jnp.asarray(x_tf), jnp.asarray(us[n_m - 1]), jnp.asarray(x_end),
                           jnp.asarray(us[-1]), jnp.asarray(motion_tf), jnp.asarray(place), z_star)
    y, energy = np.asarray(y), np.asarray(energy)
    motion_e = np.concatenate([es[:n_m], y[:1]])
    dwell_e = np.concatenate([es[n_m:], y[1:]])
    tau_m = np.concatenate([us[:n_m], us[n_m - 1:n_m]])
    tau_d = np.concatenate([us[n_m:], us[-1:]])
    f = jnp.asarray
    return Series(t=f(np.arange(n_m + 1) * h), e=f(motion_e[:, 0]), ed=f(motion_e[:, 1]), edd=f(motion_e[:, 2]),
                  tau=f(tau_m), t_dwell=f(tf + np.arange(nd + 1) * h), e_dwell=f(dwell_e[:, 0]),
                  ed_dwell=f(dwell_e[:, 1]), edd_dwell=f(dwell_e[:, 2]), tau_dwell=f(tau_d),
                  e_static=f(e_static), energy_tf=f(energy[0]), energy_dwell=f(energy), state_tf=f(x_tf),
                  dt=f(h), dt_dwell=f(h), edd_tf_low=low)
