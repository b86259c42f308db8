"""The fast rollout (linearized tables + exponential integrator + second-order correction) against
physics it must reproduce, each computed independently of the code under test:

- the start is the static equilibrium under gravity of the full model at the pick pose;
- a slow motion follows the quasi-static deflection of the full model under the inertial loads;
- the residual vibration decays at the rate the Rayleigh damping gives the first mode;
- the whole run (error, torques, dwell, metrics) equals the full nonlinear model integrated by RK4;
- the metrics are what their definitions (docs/conventions.md#metrics) say, on series with known answers.

All rollouts use the product's own default grid and the same compiled program (one law on one
model, ``LawEvaluator``), so the file pays one compilation of the fast model: its tests run on one
xdist worker (one group), and as a group of several tests xdist schedules it among the first work
units, so that the full-model run (the suite's longest single setup, about a minute) starts early
instead of being the last thing a worker does while the other one idles. The full-model test
comes first in the file (the group runs in file order).
"""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex.linearized import path_pose
from jaxflex.metrics import METRICS, metrics
from jaxflex.engine import LawEvaluator
from jaxflex.model_sets import ModelSet
from jaxflex.uncertainty import ModelId
from jaxflex.optimize.objective import stack_robots
from jaxflex.path import make_path
from jaxflex.profiles import make_profile, profile_eval
from jaxflex.rigid import rigid_torques
from jaxflex.robot import cycle_preset, joint_motion, robot_preset
from jaxflex.simulate import Series
from jaxflex.sweep import default_grid
from jaxflex.trajectory import task_from_arc

TF, DWELL = 0.43, 0.1
pytestmark = pytest.mark.xdist_group("rollout-physics")


@pytest.fixture(scope="module")
def setup():
    robot, cycle = robot_preset("default", payload=6.0), cycle_preset()
    path = make_path(cycle, "lame", 0.025)
    return robot, cycle, path, default_grid(robot, [TF], DWELL)


def _series(robot, path, grid, law, tf=TF, dwell=DWELL):
    """One rollout (the default second-order fast model) as numpy arrays."""
    ev = LawEvaluator(ModelSet(stack_robots([robot]), (ModelId(float(robot.payload)),)), path, TF, dwell, grid)
    s = ev.series(make_profile(law) if isinstance(law, str) else law, tf=tf)
    return jax.tree_util.tree_map(lambda a: np.asarray(a[0]), s)


def _motors(robot, path, law, tf, t):
    """Motor angles, rates, accelerations (T, 2) at the times t from the rigid IGM of the path."""
    return _motors_jit(robot, path, make_profile(law), jnp.asarray(tf), jnp.asarray(t))


@jax.jit
def _motors_jit(robot, path, profile, tf, t):
    v = profile_eval(profile, t / tf)
    L = path.length
    x, xd, xdd, _ = task_from_arc(path, v.s * L, v.ds * L / tf, v.dds * L / tf**2, jnp.zeros(len(t)))
    return jax.vmap(lambda a, b, c: joint_motion(robot, a, b, c))(x, xd, xdd)


# ---------------------------------------------------------------------------- the full nonlinear model


@pytest.fixture(scope="module")
def fast_and_full(setup):
    """A faster Adept move than the paper's 6 kg case (tf = 0.3 s: twice its accelerations, deflections
    up to 1.4 mm, so the second-order terms are larger) with a smooth law and a jerk-discontinuous one,
    simulated by the fast model (default grid) and by the full nonlinear model: its exponential
    integrator at 4e-5 s, twice its default step (2e-5 s, which agrees with RK4 at 1e-6 s within 2e-4
    relative on the paper cases' metrics: ``tests/test_reference.py``). On these two runs the
    metrics at 4e-5 s differ from those at 2e-5 s by at most 3e-5 relative (measured), a hundredth
    of the tolerances below, and the run costs half the steps."""
    from jaxflex.reference import reference_rollout

    robot, _, path, grid = setup
    tf, dwell, laws = 0.3, 0.03, ("poly7", "trap_1_8")
    # the reference first: it needs none of the fast model's programs, which meanwhile the other xdist
    # worker (the CLI tests' sweep) compiles into the session's shared compilation cache
    ref = reference_rollout(robot, path, [make_profile(p) for p in laws], tf, dwell, dt=4e-5)
    fast = [_series(robot, path, grid, law, tf=tf, dwell=dwell) for law in laws]
    full = [jax.tree_util.tree_map(lambda a: np.asarray(a[i]), ref) for i in range(len(laws))]
    return robot, path, tf, laws, fast, full


def _at(t_new, t, y):
    return np.stack([np.interp(t_new, t, y[:, j]) for j in range(y.shape[1])], -1)


def test_fast_rollout_matches_the_full_nonlinear_model(fast_and_full):
    """Against the full model: the end-effector error during the motion and over the dwell, the
    elastic part of the motor torques (tau minus the rigid robot's, from the independent
    Newton-Euler model) and the metrics. Measured: e within 0.10-0.15 % of its peak (the fast
    model's output map e = J q_e is linear: its error grows like the deflection over the link
    length, 1.4 mm / 0.38 m), the dwell within 0.03-0.12 % of its amplitude. A 5 % error in a
    force, mass, stiffness or torque term of the linearization or the rollout moves these by
    several percent."""
    robot, path, tf, laws, fast, full = fast_and_full
    for law, f, r in zip(laws, fast, full):
        e_ref = _at(f.t, r.t, r.e)
        assert np.abs(f.e - e_ref).max() < 5e-3 * np.abs(r.e).max(), (law, np.abs(f.e - e_ref).max())
        amp = r.e_dwell - r.e_static[None]
        d_ref = _at(f.t_dwell, r.t_dwell, amp)
        assert np.abs(f.e_dwell - f.e_static[None] - d_ref).max() < 1e-2 * np.abs(amp).max(), law
        qa, qad, qadd = _motors(robot, path, law, tf, jnp.asarray(f.t))
        tau_rigid = np.asarray(jax.jit(jax.vmap(lambda a, b, c: rigid_torques(robot, a, b, c)))(qa, qad, qadd))
        el_fast, el_full = f.tau - tau_rigid, _at(f.t, r.t, r.tau) - tau_rigid
        assert np.abs(el_full).max() > 1e-3 * np.abs(tau_rigid).max()        # the elastic part is there
        assert np.abs(el_fast - el_full).max() < 2e-2 * np.abs(el_full).max(), (law, np.abs(el_fast - el_full).max())
        mf, mr = metrics(f), metrics(r)
        for k in ("max_torque_nm", "max_deflection_mm", "residual_pos_mm", "residual_vel", "residual_acc_low",
                  "dwell_residual_mm", "residual_energy"):
            assert abs(float(mf[k]) / float(mr[k]) - 1) < 5e-3, (law, k, float(mf[k]), float(mr[k]))


# ---------------------------------------------------------------------------------------------- metrics


def _synthetic_series():
    """A series whose every metric is known in closed form (distinct magnitudes per field, so that a
    metric reading the wrong field or missing a term shows)."""
    n, nd = 200, 100
    t = np.linspace(0.0, 0.4, n + 1)
    w = 2 * np.pi * 5.0
    e = np.stack([3e-5 * np.cos(w * t), -7e-5 * np.sin(w * t) ** 2], -1)
    e[-1] = [-5e-5, 8e-5]                                                        # the peak |e| is the last sample
    edd = 2.5 * np.stack([np.cos(w * t), np.sin(w * t)], -1)                    # |e''| = 2.5 everywhere
    edd[: n // 2] *= 2.0                                                         # first half 5.0
    tau = np.stack([40.0 * np.sin(w * t), -60.0 * np.cos(0.125 * w * t)], -1)   # peak |tau| = 60 at t = 0, negative
    td = 0.4 + np.linspace(0.0, 0.1, nd + 1)
    e_static = np.array([1e-6, 4e-5])
    amp = np.stack([2e-6 * np.cos(w * td), 1e-6 * np.sin(w * td)], -1)
    e_dwell = e_static + amp
    e_dwell[0] = e_static + np.array([6e-6, -8e-6])                             # |e(tf) - e_static| = 1e-5
    ed_dwell = np.zeros((nd + 1, 2))
    ed_dwell[0] = [3e-3, 4e-3]                                                   # |e'(tf)| = 5e-3
    edd_dwell = np.zeros((nd + 1, 2))
    edd_dwell[0] = [-0.6, 0.8]                                                   # |e''(tf)| = 1
    arrays = dict(t=t, e=e, ed=np.zeros_like(e), edd=edd, tau=tau, t_dwell=td, e_dwell=e_dwell,
                  ed_dwell=ed_dwell, edd_dwell=edd_dwell, tau_dwell=np.zeros((nd + 1, 2)), e_static=e_static,
                  energy_tf=1.25e-4, energy_dwell=np.full(nd + 1, 1.25e-4), state_tf=np.zeros(24),
                  dt=0.4 / n, dt_dwell=0.1 / nd, edd_tf_low=np.array([0.3, 0.4]))
    return Series(**{k: jnp.asarray(v) for k, v in arrays.items()}), arrays


def test_metrics_on_a_series_with_known_answers():
    """Each metric from its definition (docs/conventions.md#metrics): peak |tau| over both motors (a
    negative peak counts), RMS of |e''| over the motion samples, max |e| in mm, |e|, |e'|, |e''| at tf
    (the dwell's first sample: the state the dwell starts from, e itself, not e - e_static), the
    low-mode part given by the rollout, the dwell amplitude max |e - e_static| in mm, and the vibration
    energy at tf."""
    series, a = _synthetic_series()
    got = {k: float(v) for k, v in jax.jit(metrics)(series).items()}
    assert set(got) == set(METRICS)
    n = len(a["t"])
    expected = {
        "max_torque_nm": 60.0,
        "rms_acc_error": np.sqrt(((n // 2) * 25.0 + (n - n // 2) * 6.25) / n),
        "max_deflection_mm": 1e3 * np.hypot(5e-5, 8e-5),
        "residual_pos_mm": 1e3 * np.hypot(1e-6 + 6e-6, 4e-5 - 8e-6),
        "residual_vel": 5e-3,
        "residual_acc": 1.0,
        "residual_acc_low": 0.5,
        "dwell_residual_mm": 1e3 * 1e-5,
        "residual_energy": 1.25e-4,
    }
    for k, v in expected.items():
        assert got[k] == pytest.approx(v, rel=1e-12), (k, got[k], v)


def test_the_objectives_dwell_terms_are_the_mean_square_and_a_smooth_maximum_below_the_maximum():
    """``metrics.terms`` on a known dwell: |e - e_static| = a exp(-t / T) |sin(w t + phi)| sampled
    every ms (a 50 Hz oscillation decaying over 50 ms; squares of order 1e-12 m^2, so every
    comparison is relative, with no absolute floor). The mean square is the samples' mean; the smooth maximum (power mean
    of order 16 of the squares) equals its definition, lies between the mean square and the
    squared dwell residual, tends to the maximum as its order grows, and its gradient equals central
    differences (relative 1e-6: their truncation at a step of 1e-4 of a sample's square)."""
    from jaxflex.metrics import DWELL_PEAK_POWER, dwell_peak, terms

    series, _ = _synthetic_series()
    n = series.e_dwell.shape[0]
    t = np.arange(n) * 1e-3
    amp = 2e-6 * np.exp(-t / 0.05) * np.sin(2 * np.pi * 50 * t + 0.3)
    d = np.stack([0.6 * amp, 0.8 * amp], -1)
    s = series._replace(e_dwell=jnp.asarray(d) + series.e_static[None])
    tm = jax.jit(terms)(s)
    sq = amp**2
    assert float(tm.dwell_ms) == pytest.approx(np.mean(sq), rel=1e-12, abs=0)
    p = DWELL_PEAK_POWER
    assert float(tm.dwell_peak) == pytest.approx(np.mean(sq**p) ** (1 / p), rel=1e-12, abs=0)
    top = (1e-3 * float(tm.metrics["dwell_residual_mm"])) ** 2
    assert top == pytest.approx(sq.max(), rel=1e-12, abs=0)
    assert np.mean(sq) < float(tm.dwell_peak) < top
    assert float(dwell_peak(jnp.asarray(sq), 4 * p)) > float(tm.dwell_peak)
    assert float(dwell_peak(jnp.asarray(sq), 1000)) == pytest.approx(top, rel=0.01, abs=0)
    at_rest = jnp.zeros(n)
    assert float(dwell_peak(at_rest)) == 0.0 and np.all(np.asarray(jax.grad(dwell_peak)(at_rest)) == 0.0)
    g = np.asarray(jax.grad(dwell_peak)(jnp.asarray(sq)))
    for i in (int(np.argmax(sq)), 3, n - 2):
        h = 1e-4 * sq[i]
        up, down = sq.copy(), sq.copy()
        up[i] += h
        down[i] -= h
        fd = (float(dwell_peak(jnp.asarray(up))) - float(dwell_peak(jnp.asarray(down)))) / (2 * h)
        assert g[i] == pytest.approx(fd, rel=1e-6, abs=1e-9 * np.max(np.abs(g))), i


def test_metrics_scale_and_shift_as_their_definitions():
    """Invariances: doubling the error doubles every length metric; a constant offset of the whole
    dwell together with e_static (a different sag) changes no dwell amplitude; torques enter only
    max_torque_nm."""
    series, _ = _synthetic_series()
    base = {k: float(v) for k, v in metrics(series).items()}
    twice = series._replace(e=2 * series.e, e_dwell=2 * series.e_dwell, e_static=2 * series.e_static)
    m2 = {k: float(v) for k, v in metrics(twice).items()}
    for k in ("max_deflection_mm", "residual_pos_mm", "dwell_residual_mm"):
        assert m2[k] == pytest.approx(2 * base[k], rel=1e-12), k
    shift = jnp.asarray([5e-4, -2e-4])
    moved = series._replace(e_dwell=series.e_dwell + shift[None], e_static=series.e_static + shift)
    assert float(metrics(moved)["dwell_residual_mm"]) == pytest.approx(base["dwell_residual_mm"], rel=1e-9)
    m3 = {k: float(v) for k, v in metrics(series._replace(tau=3 * series.tau)).items()}
    assert m3["max_torque_nm"] == pytest.approx(3 * base["max_torque_nm"], rel=1e-12)
    assert all(m3[k] == base[k] for k in METRICS if k != "max_torque_nm")


# -------------------------------------------------------------------------------------- statics


def test_rollout_starts_and_ends_in_the_full_models_static_equilibrium(setup):
    """At t = 0 the robot rests in the static equilibrium of the full nonlinear model at the pick pose
    (Newton on the model, not the tables): the error is the gravity sag, its rate zero, and the motor
    torques hold the weight; the dwell's reference e_static is the sag at the place pose. The fast
    model maps the elastic coordinates to the end effector linearly (e = J q_e), which leaves
    ~1e-4 of the sag (its quadratic term, q_e / l ~ 1e-4): 1e-3 here, against 5e-2 for a gravity,
    stiffness or payload term 5 % off."""
    robot, cycle, path, grid = setup
    s = _series(robot, path, grid, "poly7")
    qa0, qa1 = (np.asarray(path_pose(robot, path, x)[0]) for x in (0.0, float(path.length)))
    sag0, sag1 = (np.asarray(jax.jit(mdl.static_deflection)(robot, jnp.asarray(q))) for q in (qa0, qa1))
    np.testing.assert_allclose(s.e[0], sag0, rtol=1e-3, atol=1e-3 * np.abs(sag0).max())
    np.testing.assert_allclose(s.e_static, sag1, rtol=1e-3, atol=1e-3 * np.abs(sag1).max())
    assert np.abs(s.ed[0]).max() < 1e-9                              # at rest (m/s)
    qe0 = jax.jit(mdl.static_equilibrium)(robot, jnp.asarray(qa0))
    _, tau0 = jax.jit(mdl.inverse_dynamics)(robot, jnp.asarray(qa0), qe0, jnp.zeros(2), jnp.zeros(12), jnp.zeros(2))
    np.testing.assert_allclose(s.tau[0], np.asarray(tau0), rtol=1e-3, atol=1e-3 * float(jnp.abs(tau0).max()))
    assert np.abs(tau0).max() > 1.0                                   # gravity torques are really there


def _quasi_static_error(robot, path, law, tf, t):
    """Quasi-static end-effector error from the full model: the elastic rows of the reduced equations
    with q_e' = q_e'' = 0 solved by Newton at each time t, then X(q_a, q_e) - X(q_a, 0)."""
    qa, qad, qadd = _motors(robot, path, law, tf, jnp.asarray(t))

    def one(qa, qad, qadd):
        def resid(qe):
            red = mdl.reduced(robot, qa, qe, qad, jnp.zeros_like(qe))
            return red.mass[2:, :2] @ qadd + red.force[2:]

        def newton(_, qe):      # the residual and its Jacobian from one evaluation of the model
            jac, r = jax.jacfwd(lambda z: (lambda v: (v, v))(resid(z)), has_aux=True)(qe)
            return qe - jnp.linalg.solve(jac, r)

        qe = jax.lax.fori_loop(0, 3, newton, jnp.zeros(12))
        return mdl.ee_position(robot, qa, qe) - mdl.ee_position(robot, qa, jnp.zeros(12))

    return np.asarray(jax.jit(jax.vmap(one))(qa, qad, qadd))


def test_slow_motion_follows_the_quasi_static_deflection(setup):
    """Gravity off, tf = 16 s (the inertial loads vary at ~0.1 Hz, far below the 58 Hz first mode):
    e(t) equals the static deflection of the full model under the inertial loads. What remains is
    the free vibration excited by the jerk jumps at the G2 blend joins, which falls like 1/tf (1.4 %
    of the peak at 8 s, 0.7 % at 16 s): 1.5 % here, while a 5 % error in any inertial force, mass or
    stiffness moves e by ~5 %."""
    robot, _, path, grid = setup
    robot = robot.replace(gravity=jnp.zeros(2))
    tf = 16.0
    s = _series(robot, path, grid, "poly7", tf=tf)
    idx = np.linspace(0, len(s.t) - 1, 33).astype(int)
    ref = _quasi_static_error(robot, path, "poly7", tf, s.t[idx])
    scale = np.abs(ref).max()
    assert scale > 1e-8                                          # ~tens of nm: the inertial deflection
    assert np.abs(s.e[idx] - ref).max() < 0.015 * scale, np.abs(s.e[idx] - ref).max() / scale


# ------------------------------------------------------------------------------------------ damping


def test_residual_vibration_decays_at_the_damping_ratio_of_the_first_mode(setup):
    """Stiffness-proportional damping beta = 2 zeta / omega_1 gives the first locked mode at the place
    pose the damping ratio zeta (here 2 %); the higher modes die out faster (zeta_k = beta omega_k / 2).
    Over a 0.6 s dwell the peaks of |e - e_static| fall like exp(-zeta omega_1 t): the fitted zeta must
    be within 2 % of the requested one (a 5 % error in the damping force moves it by 5 %)."""
    robot, cycle, path, grid = setup
    zeta = 0.02
    qa_place = path_pose(robot, path, float(path.length))[0]
    w1 = 2 * np.pi * float(jax.jit(mdl.locked_modes)(robot, qa_place)[0][0])
    damped = robot.replace(damping=jnp.asarray([0.0, 2 * zeta / w1]))
    s = _series(damped, path, grid, "trap_1_8", dwell=0.6)
    amp = np.linalg.norm(s.e_dwell - s.e_static[None], axis=-1)
    t = s.t_dwell - s.t_dwell[0]
    peaks = np.flatnonzero((amp[1:-1] > amp[:-2]) & (amp[1:-1] >= amp[2:])) + 1
    peaks = peaks[t[peaks] > 0.15]                                # after the higher modes have died out
    assert len(peaks) > 40                                        # two peaks of |e| per period, ~25 periods
    slope = np.polyfit(t[peaks], np.log(amp[peaks]), 1)[0]
    zeta_fit = -slope / w1
    assert abs(zeta_fit / zeta - 1) < 0.02, zeta_fit
