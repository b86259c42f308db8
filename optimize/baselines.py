"""Baselines for the optimized designs (docs/conventions.md#optimization), evaluated on the same model and path.

- the paper's laws (``jaxflex.profiles.make_profile``) and their input-shaped versions (ZV, ZVD tuned to
  the first locked-motor mode at the place pose, equal total motion time: ``shaper_profiles``);
- a jerk-limited, time-optimal (double-S) profile along the path computed by Ruckig (optional
  dependency, ``pip install ruckig``), with limits scaled so that its duration is exactly tf
  (``ruckig_samples``).

Every law is turned into ``MotionSamples`` (arc length and its derivatives on the rollout grid), so all
of them go through the same compiled rollout (``jaxflex.engine.LawEvaluator``).
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxflex.profiles import Profile, zv, zvd
from jaxflex.simulate import Grid, MotionSamples

# Ruckig limit shape (units of L / tf^k): velocity and acceleration of a trapezoid with ta = tf/4,
# jerk time half the acceleration time. The limits are then scaled in time so the duration is tf.
RUCKIG_SHAPE = (4.0 / 3.0, 16.0 / 3.0, 16.0 / 3.0 / 0.125)


def shaper_profiles(base: str, freq_hz: float, tf: float) -> list[Profile]:
    """ZV and ZVD versions of the paper law ``base`` for a mode at freq_hz [Hz], total time tf [s]."""
    return [zv(base, freq_hz, tf), zvd(base, freq_hz, tf)]


def _ruckig_trajectory(length: float, limits):
    try:
        from ruckig import InputParameter, Result, Ruckig, Trajectory
    except ImportError as err:  # pragma: no cover - depends on the optional extra
        raise ImportError("the Ruckig baseline needs the optional dependency: pip install ruckig") from err
    inp = InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [float(length)], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = ([float(v)] for v in limits)
    traj = Trajectory(1)
    result = Ruckig(1).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise RuntimeError(f"Ruckig failed: {result}")
    return traj


def ruckig_limits(length: float, tf: float, shape=RUCKIG_SHAPE) -> tuple:
    """Velocity [m/s], acceleration [m/s^2] and jerk [m/s^3] limits of the given shape whose
    time-optimal jerk-limited profile over ``length`` [m] lasts exactly tf [s] (time scaling:
    limits (c v, c^2 a, c^3 j) shorten the duration by the factor c)."""
    base = [k * length / tf ** (i + 1) for i, k in enumerate(shape)]
    c = _ruckig_trajectory(length, base).duration / tf
    return tuple(b * c ** (i + 1) for i, b in enumerate(base))


def ruckig_samples(length: float, tf: float, grid: Grid, shape=RUCKIG_SHAPE) -> tuple[MotionSamples, tuple]:
    """Motion samples of the Ruckig profile on the rollout grid (s, s', s'' continuous: one-sided
    limits coincide), and the limits used."""
    limits = ruckig_limits(length, tf, shape)
    traj = _ruckig_trajectory(length, limits)
    if abs(traj.duration - tf) > 1e-9 * tf:
        raise RuntimeError(f"Ruckig duration {traj.duration} s != tf {tf} s")
    n, nc = grid.steps, grid.coarse

    def at(eta):
        vals = np.array([[v[0] for v in traj.at_time(float(e) * tf)[:3]] for e in eta])
        s = np.clip(vals[:, 0], 0.0, length)
        return jnp.asarray(s), jnp.asarray(vals[:, 1]), jnp.asarray(vals[:, 2])

    k = np.arange(n)
    return MotionSamples(start=at(k / n), end=at((k + 1) / n), mid=at((np.arange(nc) + 0.5) / nc)), limits
