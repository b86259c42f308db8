"""Reference simulation: the full nonlinear model (the second method).

Independent of the fast formulation (``jaxflex.linearized`` + ``jaxflex.simulate``): no
linearization, no tables. The state is the independent elastic state [q_e, q_e'] with the motors
prescribed by the rigid IGM of the desired trajectory; every evaluation of the field calls the
nonlinear inverse dynamic model ``jaxflex.model.inverse_dynamics`` (passive coordinates solved from
the constraints in closed form, so the loop closes to round-off). The end-effector error uses the
nonlinear forward map, e = X(q_a, q_e) - X(q_a, 0), its derivatives by forward-mode autodiff.

Two integrators:
- ``exprb3`` (the default): a third-order exponential integrator about the field's Jacobian
  (``_exprb3``). The elastic modes up to the 18.6 kHz axial ones are stiff for explicit methods; it
  integrates them exactly through matrix functions and treats only the slowly varying remainder
  explicitly, so its step follows the motion, not the highest mode: at 20 us (4 steps per period of
  that mode) it agrees with RK4 at 1 us within 2e-4 relative on every metric (docs/conventions.md#metrics)
  of the two paper cases, at a small fraction of RK4's cost (``tests/test_reference.py``).
- ``rk4``: classical RK4, conditionally stable (|lambda h| < 2.78, so h below about 2.4e-5 s), and
  its numerical damping of the highest mode is small only for h of a few microseconds. It costs four
  model evaluations per step: the slow ground truth that the exponential integrator is checked against.

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

from jaxflex import checks
from jaxflex.runtime import options
from jaxflex import model as mdl
from jaxflex import trees
from jaxflex.expm import phi_times, squarings_for
from jaxflex.path import Path
from jaxflex.profiles import Profile, profile_eval
from jaxflex.progress import Progress
from jaxflex.robot import Robot, joint_motion
from jaxflex.simulate import Series, low_mode_acceleration
from jaxflex.trajectory import task_from_arc


def joint_samples(robot: Robot, path: Path, profile: Profile, tf, eta, side):
    """``_joint_samples`` at the normalized times eta (T,) (numpy), evaluated CHUNK samples per call
    (the last call padded with the last time): one program per path family, law kind and side for
    every run length (tf / dt), instead of one per sample count."""
    n = len(eta)
    padded = np.concatenate([eta, np.full(-n % CHUNK, eta[-1])])
    parts = [_joint_samples(robot, path, profile, tf, jnp.asarray(padded[i:i + CHUNK]), side=side)
             for i in range(0, len(padded), CHUNK)]
    return trees.concatenate(parts, length=n)


@functools.partial(jax.jit, static_argnames="side", compiler_options=options.BUILD)
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
    motor = stages[np.asarray(_RK4_MOTOR)]

    def stage(carry, inp):
        k_prev, acc = carry
        a, b, mot = inp
        k, out = _field(robot, mot, x + a * h * k_prev)
        return (k, acc + b * k), out

    zero = jnp.zeros_like(x)
    (_, acc), (qedd, tau) = jax.lax.scan(stage, (zero, zero), (jnp.asarray(_RK4_A), jnp.asarray(_RK4_B), motor))
    return x + h * acc, (qedd[0], tau[0])


def _field(robot, motor, u):
    """The elastic state's field F = [q_e', q_e''] (2 ne,) at the state u = [q_e, q_e'] with the motor
    motion ``motor`` (3, 2) = (q_a, q_a', q_a''), and (q_e'', tau) (the nonlinear inverse dynamics)."""
    ne = u.shape[0] // 2
    qedd, tau = mdl.inverse_dynamics(robot, motor[0], u[:ne], motor[1], u[ne:], motor[2])
    return jnp.concatenate([u[ne:], qedd]), (qedd, tau)


def _field_jacobian(robot, motor, u):
    """dF/du (2 ne, 2 ne) of ``_field`` by forward-mode autodiff."""
    return jax.jacfwd(lambda v: _field(robot, motor, v)[0])(u)


def velocity_scaling(jac, omega):
    """The state scaling s = [1 .. 1, 1/omega .. 1/omega] (2 ne,) and diag(s) J diag(s)^-1: with
    omega [rad/s] the scale of the elastic frequencies, the Jacobian's blocks are all about omega."""
    ne = jac.shape[0] // 2
    s = jnp.concatenate([jnp.ones(ne), jnp.full(ne, 1.0 / omega)])
    return s, jac * s[:, None] / s[None, :]


def _exprb3(robot, h, x, stages, omega, squarings, jac):
    """One step of a third-order exponential integrator of the elastic state x = [q_e, q_e'] (the
    motor motion ``stages`` as in ``_rk4``), about the linear part ``jac`` (2 ne, 2 ne): the field's
    Jacobian (``_field_jacobian``) at the start of this step or of a few steps before.

    The field F(t, u) is split into J u and the remainder N(t, u) = F(t, u) - J u, which varies
    slowly: the stiff elastic modes sit in J and are integrated exactly by matrix functions, whatever
    their frequency. Stages at h/2 and h interpolate N quadratically in time, so the motor
    acceleration's variation (the forcing) is integrated exactly up to its second derivative:

        u_a = x + h/2 phi1(hJ/2) F0
        u_b = x + h [phi1(hJ) F0 + 2 phi2(hJ) (N_a - N0)]
        x+  = x + h [phi1(hJ) F0 + phi2(hJ) (-3 N0 + 4 N_a - N_b) + 4 phi3(hJ) (N0 - 2 N_a + N_b)]

    (the variation-of-constants formula with N replaced by its interpolant, as in exponential
    Rosenbrock methods; N's dependence on u is weak, as J is the Jacobian near x). Velocities are
    scaled by 1/omega [rad/s] (the scale of the elastic frequencies) inside the matrix functions, so
    that ||hJ|| is about h omega and not h omega^2; ``squarings`` is chosen for that norm. Returns the new
    state and (q_e'', tau) at the start of the step."""
    s, scaled = velocity_scaling(jac, omega)
    a = h * scaled
    phi = lambda *v: phi_times(a, [h * s * vi for vi in v], squarings) / s

    # the three field evaluations as a loop over the stages (one trace of the model instead of
    # three, as in ``_rk4``): stage k evaluates N at its state and motor motion, then forms the
    # next stage's state (u_a, u_b, then the new state)
    def stage(carry, inp):
        u, f0, n0, na = carry
        k, motor = inp
        f, out = _field(robot, motor, u)
        n = f - jac @ u
        f0, n0 = jax.lax.cond(k == 0, lambda: (f, n), lambda: (f0, n0))
        na = jax.lax.cond(k == 1, lambda: n, lambda: na)
        u_next = jax.lax.switch(k, [
            lambda: x + phi_times(0.5 * a, [0.5 * h * s * f0], max(squarings - 1, 0)) / s,
            lambda: x + phi(f0, 2.0 * (na - n0)),
            lambda: x + phi(f0, -3.0 * n0 + 4.0 * na - n, 4.0 * (n0 - 2.0 * na + n))])
        return (u_next, f0, n0, na), out

    zero = jnp.zeros_like(x)
    (x_new, *_), (qedd, tau) = jax.lax.scan(stage, (x, zero, zero, zero), (jnp.arange(3), stages))
    return x_new, (qedd[0], tau[0])


def _outputs(robot, qa, qad, qadd, x, qedd, tau):
    ne = x.shape[0] // 2
    e, ed, edd = _error(robot, qa, x[:ne], qad, x[ne:], qadd, qedd)
    return jnp.stack([e, ed, edd, tau])


METHODS = ("exprb3", "rk4")
DEFAULT_DT = {"exprb3": 2e-5, "rk4": 1e-5}    # [s]
METHOD_NAMES = {"exprb3": "exponential integrator, order 3", "rk4": "RK4"}
CHUNK = 1024     # steps per call of the stepping program: one program for every run length (progress, ETA)
WINDOW = 32      # exprb3: steps per Jacobian of the field (a multiple of it divides CHUNK)
MIN_SQUARINGS = 5   # exprb3: the matrix functions' least squarings (20 us steps need 4-5; each costs a small product)
RUN_BLOCK = 2    # runs per batch of the programs: more runs go in batches of this many, fewer are padded (the
                 # first run repeated, then dropped). Every call then shares one set of programs (each
                 # batch size compiles its own, which is slow): the studies' checks of 2 trajectories
                 # and the paper cases' of 4 laws. A batch of 4 would pad the studies' 2 runs and take
                 # markedly longer than a batch of 2 (docs/performance.md).


def reference_rollout(robot: Robot, path: Path | Sequence[Path], profile: Profile | Sequence[Profile], tf: float,
                      dwell: float = 0.1, dt: float | None = None, dwell_dt: float | None = None, *,
                      method: str = "exprb3", progress: bool = True) -> Series:
    """Full nonlinear simulation of trajectories (motion over [0, tf] [s] then a dwell [s]).

    ``method``: ``"exprb3"`` (default), the third-order exponential integrator ``_exprb3`` with the
    field's Jacobian refreshed every ``WINDOW`` steps, which integrates the stiff elastic modes
    exactly and so takes steps far above their period (default dt 2e-5 s; against RK4 at 1e-6 s it
    agrees within 2e-4 relative on every metric of the paper cases, docs/conventions.md#metrics and
    ``tests/test_reference.py``);
    or ``"rk4"``, classical RK4, conditionally stable (dt <= 2e-5 s for the default robot), accurate
    for the kHz axial modes only at dt of a few microseconds (default 1e-5 s), the slow ground truth.

    ``profile`` is one motion law or a sequence of them, along ``path`` or along the matching
    element of a sequence of paths (one per law; they must share the pick and place points, as
    every path of one cycle does); ``robot.payload`` may be a 1-D array of
    payloads [kg]. The runs are vmapped in batches of ``RUN_BLOCK`` (batching amortizes the
    per-operation overhead of the nonlinear model, which dominates a single sequential run; a short
    last batch is padded, so every call runs the same programs). dt [s] is rounded down so that the
    motion has a multiple of 8 steps; the dwell uses dwell_dt (default dt). Returns a ``Series`` like
    ``jaxflex.simulate.rollout`` with outputs at every step and leading axes (profile, payload) for
    the batched inputs that were given, so ``jaxflex.metrics.metrics`` applies (vmapped).
    The steps run in calls of ``CHUNK`` steps, with ``progress`` on stderr (elapsed time, ETA); the
    programs depend on the number of runs and the robot's structure, not on tf, dt or the
    trajectories, so later calls in a process reuse them.
    """
    checks.one_of("full-model method", method, METHODS)
    tf, dwell = checks.positive("tf", tf, "s"), checks.positive("dwell", dwell, "s")
    dt = checks.positive("dt", DEFAULT_DT[method] if dt is None else dt, "s")
    dwell_dt = dt if dwell_dt is None else checks.positive("dwell_dt", dwell_dt, "s")
    if method == "rk4" and dt > 2e-5:
        raise ValueError(f"RK4 reference step dt={dt} s is above its stability limit (~2.4e-5 s for "
                         "the 18.6 kHz axial mode of the default robot); use dt <= 2e-5 s or method='exprb3'")
    n = 8 * max(1, int(np.ceil(tf / dt / 8)))
    nd = max(1, int(np.ceil(dwell / dwell_dt)))
    single = isinstance(profile, Profile)
    profiles = [profile] if single else list(profile)
    paths = [path] * len(profiles) if isinstance(path, Path) else list(path)
    if len(paths) != len(profiles):
        raise ValueError(f"{len(paths)} paths for {len(profiles)} motion laws: give one path or one per law")
    payload = np.asarray(robot.payload, dtype=float)
    bar = Progress(f"full model ({METHOD_NAMES[method]}, h = {tf / n * 1e6:.3g} us, "
                   f"{len(profiles) * payload.size} runs)",
                   total=-(-(n + nd) // CHUNK) * -(-len(profiles) * payload.size // RUN_BLOCK), unit="chunk",
                   enabled=progress)
    with bar:
        with bar.waiting("the motors' motion at every step"):
            tfa, k = jnp.asarray(tf), np.arange(n)
            samples = [tuple(joint_samples(robot, pth, p, tfa, eta, side)
                             for eta, side in ((k / n, 1), ((k + 0.5) / n, 1), ((k + 1) / n, -1)))
                       for pth, p in zip(paths, profiles)]
        # one flat batch of runs (law-major, then payload), every input repeated per run
        runs = [(float(m), smp) for smp in samples for m in np.atleast_1d(payload)]
        count = len(runs)
        runs += runs[:1] * (-count % RUN_BLOCK)                   # filler runs, dropped below
        batches = [(jnp.asarray([m for m, _ in block]), trees.stack([smp for _, smp in block]))
                   for block in (runs[i:i + RUN_BLOCK] for i in range(0, len(runs), RUN_BLOCK))]
        with bar.waiting("the start: static equilibria at the pick and place poses"):
            begun = [_begin(robot, masses, smp, tf, dwell, n, nd, method) for masses, smp in batches]
            # for twice the largest start norm of the call's runs (the pose and the deflection change
            # ||h J|| by far less), and at least MIN_SQUARINGS, so that most calls share one program
            norm = max(float(jnp.max(b[-1])) for b in begun)
            squarings = max(MIN_SQUARINGS, squarings_for(2.0 * norm)) if method == "exprb3" else 0
        out = trees.concatenate([_integrate(robot, masses, smp, tf, dwell, n, nd, method, squarings, start, bar,
                                             first=j == 0)
                                 for j, ((masses, smp), start) in enumerate(zip(batches, begun))], length=count)
    shape = (len(profiles),) + payload.shape
    out = jax.tree_util.tree_map(lambda a: a.reshape(shape + a.shape[1:]), out)
    return jax.tree_util.tree_map(lambda a: a[0], out) if single else out


def _begin(robot, masses, samples, tf, dwell, n, nd, method):
    """The start of a batch of runs (leading axis B of ``masses`` [kg] and ``samples``; ``_start``):
    (state, q_e*, static error, omega, norm)."""
    h, hd = tf / n, dwell / nd
    starts, _, ends = samples
    return _start(robot, masses, starts[0][:, 0], ends[0][:, -1], max(h, hd), exponential=method == "exprb3")


def _integrate(robot, masses, samples, tf, dwell, n, nd, method, squarings, start, bar, first: bool = True):
    """The batch of runs (leading axis B of ``masses`` [kg] and ``samples``) from its ``start``
    (``_begin``): the steps of ``method`` in calls of CHUNK steps (on the progress ``bar``, one unit
    per call), the outputs at the ends. ``first``: the first batch of the call (whose first chunk
    compiles the step)."""
    h, hd = tf / n, dwell / nd
    chunks = -(-(n + nd) // CHUNK)
    total = chunks * CHUNK
    starts, mids, ends = samples
    # motor motion (B, total, 3, 3, 2) of every step (start, middle, end; q_a, q_a', q_a''): the
    # motion's n steps, then the motors hold the place pose (the dwell's nd steps, then steps of
    # size zero, the identity, up to whole chunks)
    motion = jnp.stack([jnp.stack(v, axis=2) for v in (starts, mids, ends)], axis=2)
    qa_place = ends[0][:, -1]
    hold = jnp.stack([qa_place, jnp.zeros_like(qa_place), jnp.zeros_like(qa_place)], axis=1)
    motor = jnp.concatenate([motion, jnp.broadcast_to(hold[:, None, None], (len(masses), total - n, 3, 3, 2))],
                            axis=1)
    steps = jnp.asarray(np.concatenate([np.full(n, h), np.full(nd, hd), np.zeros(total - n - nd)]))
    x, q_star, e_static, omega, _ = start
    x_tf, ys = None, []
    for c in range(chunks):
        part = slice(c * CHUNK, (c + 1) * CHUNK)
        with bar.waiting("the first chunk (compiles the step)") if c == 0 and first else contextlib.nullcontext():
            x_next, (states, y) = jax.block_until_ready(
                _advance(robot, masses, omega, x, steps[part], motor[:, part], method=method,
                         squarings=squarings))
        if c * CHUNK <= n < (c + 1) * CHUNK:
            x_tf = states[:, n - c * CHUNK]
        x = x_next
        ys.append(y)
        bar.update()
    with bar.waiting("outputs at tf and at the end of the dwell"):
        end = jnp.stack([a[:, -1] for a in ends], axis=1)
        y_ends, energy, low = jax.block_until_ready(_ends(robot, masses, end, q_star, x_tf, x))
    ys = jnp.concatenate(ys, axis=1)
    ys_motion = jnp.concatenate([ys[:, :n], y_ends[:, :1]], axis=1)
    yd = jnp.concatenate([ys[:, n:n + nd], y_ends[:, 1:]], axis=1)
    batch = lambda a: jnp.broadcast_to(jnp.asarray(a), (len(masses),) + jnp.shape(a))
    return Series(t=batch(jnp.arange(n + 1, dtype=float) * h), e=ys_motion[:, :, 0], ed=ys_motion[:, :, 1],
                  edd=ys_motion[:, :, 2], tau=ys_motion[:, :, 3],
                  t_dwell=batch(tf + jnp.arange(nd + 1, dtype=float) * hd),
                  e_dwell=yd[:, :, 0], ed_dwell=yd[:, :, 1], edd_dwell=yd[:, :, 2], tau_dwell=yd[:, :, 3],
                  e_static=e_static, energy_tf=energy[:, 0], energy_dwell=energy, state_tf=x_tf, dt=batch(h),
                  dt_dwell=batch(hd), edd_tf_low=low)


@functools.partial(jax.jit, static_argnames="exponential", compiler_options=options.ONCE)
def _start(robot, masses, qa_pick, qa_place, h, exponential):
    """Per run, from the motor angles at the pick and place poses (B, 2): the initial state
    (B, 2 ne), static equilibrium at rest; the static equilibrium q_e* (B, ne) and the static error
    (B, 2) [m] at the place pose; and for the exponential method a frequency scale omega [rad/s] of
    the elastic modes at the pick pose and the 1-norm of h J there with velocities scaled by
    1/omega (J the field's Jacobian), else zeros (B,)."""
    def one(m, qa_pick, qa_place):
        r, zero = robot.replace(payload=m), jnp.zeros(2)
        # both poses in one trace of the model
        qe0, q_star = jax.vmap(lambda qa: mdl.static_equilibrium(r, qa))(jnp.stack([qa_pick, qa_place]))
        ne = qe0.shape[0]
        x0 = jnp.concatenate([qe0, jnp.zeros(ne)])
        ends = jax.vmap(lambda qe: mdl.ee_position(r, qa_place, qe))(jnp.stack([q_star, jnp.zeros(ne)]))
        e_static = ends[0] - ends[1]
        if not exponential:
            return x0, q_star, e_static, jnp.zeros(()), jnp.zeros(())
        jac = _field_jacobian(r, jnp.stack([qa_pick, zero, zero]), x0)
        # the frequency scale sqrt(||dq_e''/dq_e||_1), at least the highest elastic frequency: it
        # balances the blocks h omega and h ||dq_e''/dq_e|| / omega of the scaled Jacobian
        omega = jnp.sqrt(jnp.max(jnp.sum(jnp.abs(jac[ne:, :ne]), axis=0)))
        return x0, q_star, e_static, omega, h * jnp.max(jnp.sum(jnp.abs(velocity_scaling(jac, omega)[1]), axis=0))
    return jax.vmap(one)(masses, qa_pick, qa_place)


@functools.partial(jax.jit, static_argnames=("method", "squarings"), compiler_options=options.BUILD)
def _advance(robot, masses, omega, x, steps, motor, *, method, squarings):
    """Steps of size ``steps`` (T,) [s] from the states x (B, 2 ne), motor motion (B, T, 3, 3, 2):
    the states after them and, per step, the state at its start and the outputs (e, e', e'', tau)
    there. exprb3 computes the field's Jacobian once per WINDOW steps, at the first of them."""
    def run(m, w, x, motor):
        r = robot.replace(payload=m)

        def step(jac):
            def one(x, inp):
                hk, st = inp
                if method == "rk4":
                    x_new, (qedd, tau) = _rk4(r, hk, x, st)
                else:
                    x_new, (qedd, tau) = _exprb3(r, hk, x, st, w, squarings, jac)
                return x_new, (x, _outputs(r, *st[0], x, qedd, tau))
            return one

        if method == "rk4":
            return jax.lax.scan(step(None), x, (steps, motor))

        def window(x, inp):
            hw, mw = inp
            return jax.lax.scan(step(_field_jacobian(r, mw[0, 0], x)), x, (hw, mw))

        windows = (steps.reshape(-1, WINDOW), motor.reshape((-1, WINDOW) + motor.shape[1:]))
        x, (states, y) = jax.lax.scan(window, x, windows)
        return x, (states.reshape((-1,) + states.shape[2:]), y.reshape((-1,) + y.shape[2:]))

    return jax.vmap(run)(masses, omega, x, motor)


@functools.partial(jax.jit, compiler_options=options.ONCE)
def _ends(robot, masses, end, q_star, x_tf, x_end):
    """Per run, from the motor motion at the left limit at tf ``end`` (B, 3, 2), the static
    equilibrium q_e* (B, ne) at the place pose and the states at tf and at the end of the dwell
    (B, 2 ne): the outputs there (B, 2, 4, 2), the vibration energy at both (B, 2) [J] and the
    low-mode residual acceleration at tf (B, 2)."""
    def one(m, end, q_star, x_tf, x_end):
        r = robot.replace(payload=m)
        qa_place, zero = end[0], jnp.zeros(2)
        ne = q_star.shape[0]

        def outputs_at(motor, x):
            return _outputs(r, *motor, x, *_field(r, motor, x)[1])

        # the left limit at tf (motors still decelerating) and the end of the dwell
        y = jax.vmap(outputs_at)(jnp.stack([end, jnp.stack([qa_place, zero, zero])]), jnp.stack([x_tf, x_end]))
        v = lambda qe: mdl.potential(r, mdl.full_coordinates(r, qa_place, qe))

        def energy(x):
            m_ee = mdl.reduced_mass(r, qa_place, x[:ne])[2:, 2:]
            return 0.5 * x[ne:] @ m_ee @ x[ne:] + v(x[:ne]) - v(q_star)

        return y, jax.vmap(energy)(jnp.stack([x_tf, x_end])), _low_modes(r, qa_place, q_star, x_tf)

    return jax.vmap(one)(masses, end, q_star, x_tf, x_end)


def _low_modes(robot, qa_place, q_star, x_tf):
    """Low-mode residual acceleration from the full model's linearization at the place pose (motors
    at rest, about q_e = 0, as ``linearized.pose_coeffs`` at zero path speed)."""
    ne = q_star.shape[0]
    zero2, zero_e = jnp.zeros(2), jnp.zeros(ne)
    def force(z):       # the force and (as aux, at z = 0) the mass: one trace of the model
        red = mdl.reduced(robot, qa_place, z[:ne], zero2, z[ne:])
        return red.force[2:], red.mass[2:, 2:]

    jac, mass = jax.jacfwd(force, has_aux=True)(jnp.zeros(2 * ne))
    jx = jax.jacfwd(lambda x: mdl.ee_position(robot, qa_place, x))(zero_e)
    return low_mode_acceleration(mass, jac[:, :ne], jac[:, ne:], jx, q_star, x_tf)
