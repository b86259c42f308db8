"""Baselines for the optimized designs (SPEC 6), evaluated on the same model and path.

- the paper's laws (``jaxflex.profiles.make_profile``) and their input-shaped versions (ZV, ZVD tuned to
  the first locked-motor mode at the place pose, equal total motion time: ``shaper_profiles``);
- a jerk-limited, time-optimal (double-S) profile along the path computed by Ruckig (optional
  dependency, ``pip install ruckig``), with limits scaled so that its duration is exactly tf
  (``ruckig_samples``).

Every law is turned into ``MotionSamples`` (arc length and its derivatives on the rollout grid), so all
of them go through the same compiled rollout (``LawEvaluator``).
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex import engine
from jaxflex import model as mdl
from jaxflex.linearized import path_tables
from jaxflex.path import Cycle, Path
from jaxflex.profiles import Profile, zv, zvd
from jaxflex.robot import Robot
from jaxflex.simulate import Grid, MotionSamples, sample_motion

# Ruckig limit shape (units of L / tf^k): velocity and acceleration of a trapezoid with ta = tf/4,
# jerk time half the acceleration time. The limits are then scaled in time so the duration is tf.
RUCKIG_SHAPE = (4.0 / 3.0, 16.0 / 3.0, 16.0 / 3.0 / 0.125)


def place_first_mode_hz(robot: Robot, cycle: Cycle) -> float:
    """First locked-motor natural frequency [Hz] at the place pose (payload included)."""
    return float(mdl.modes_at_point(robot, np.asarray(cycle.place))[0])


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


class ModelId(NamedTuple):
    """Which model of a set: the payload case [kg] and the factors applied to the nominal robot
    (payload, Young's modulus) and the damping ratio at the first mode (0: the robot's own)."""

    payload: float
    payload_scale: float = 1.0
    stiffness_scale: float = 1.0
    damping_ratio: float = 0.0

    @property
    def nominal(self) -> bool:
        """The nominal robot with this payload (no perturbation, no added damping)."""
        return self.payload_scale == 1.0 and self.stiffness_scale == 1.0 and self.damping_ratio == 0.0

    @property
    def label(self) -> str:
        """Readable name, e.g. '6 kg x1.1, E x0.95' (JSON, tables, figures)."""
        zeta = f", zeta {self.damping_ratio:g}" if self.damping_ratio else ""
        return f"{self.payload:g} kg x{self.payload_scale:g}, E x{self.stiffness_scale:g}{zeta}"


class ModelSet(NamedTuple):
    """K robots stacked (leading axis) and the identity (``ModelId``) of each."""

    robots: Robot
    ids: tuple

    @property
    def labels(self) -> tuple:
        return tuple(i.label for i in self.ids)

    def index(self, model: ModelId) -> int:
        """Position of a model in the set (ValueError if absent)."""
        if model not in self.ids:
            raise ValueError(f"no model {model.label!r} among {list(self.labels)}")
        return self.ids.index(model)


def model_set(robot: Robot, payloads: Sequence[float], *, stiffness=(1.0,), payload_scale=(1.0,),
              damping_ratio: float = 0.0, cycle: Cycle | None = None) -> ModelSet:
    """Every payload [kg] x Young's modulus factor x payload factor; with ``damping_ratio`` > 0 a
    stiffness-proportional (Rayleigh beta) damping giving that ratio at the first mode of the place
    pose (``cycle`` needed)."""
    robots, ids = [], []
    for m in payloads:
        for k in stiffness:
            for ps in payload_scale:
                r = robot.replace(payload=m * ps, young=robot.young * k)
                if damping_ratio > 0:
                    w1 = 2 * np.pi * place_first_mode_hz(r, cycle)
                    r = r.replace(damping=jnp.asarray([0.0, 2 * damping_ratio / w1]))
                robots.append(r)
                ids.append(ModelId(float(m), float(ps), float(k), float(damping_ratio)))
    stacked = trees.stack(robots, dtype=float)
    return ModelSet(stacked, tuple(ids))


class LawEvaluator:
    """Metrics of any motion law along one path on a set of models (second-order fast model).

    The tables are built once per model; every law (paper, shaped, input-shaped, Ruckig samples) on
    every model runs through the evaluation engine's one compiled program (``jaxflex.engine``), one
    model at a time, so evaluators of any model set share it. ``chunk`` is accepted for
    compatibility (it used to set the batch size of a vmapped program) and must be >= 1."""

    def __init__(self, models: ModelSet, path: Path, tf: float, dwell: float, grid: Grid, *,
                 chunk: int | None = None):
        k = len(models.labels)
        chunk = k if chunk is None else int(chunk)
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.models, self.path, self.tf, self.dwell, self.grid, self.chunk = models, path, tf, dwell, grid, chunk
        self.tables = path_tables(models.robots, path)
        self._per_model = [(jax.tree_util.tree_map(lambda v: v[i], self.tables),
                            jax.tree_util.tree_map(lambda v: v[i], models.robots)) for i in range(k)]

    def with_grid(self, grid: Grid) -> "LawEvaluator":
        """The same path and models on another grid, sharing the tables (they do not depend on it)."""
        other = object.__new__(LawEvaluator)
        other.__dict__.update(self.__dict__, grid=grid)
        return other

    def samples(self, profile: Profile, tf: float | None = None) -> MotionSamples:
        return sample_motion(self.path.length, profile, self.tf if tf is None else tf, self.grid)

    def series(self, law, tf: float | None = None):
        """The simulation ``Series`` of a law on every model (leading axis K)."""
        tf = self.tf if tf is None else tf
        samples = law if isinstance(law, MotionSamples) else self.samples(law, tf)
        return engine.run_many([(tables, samples, tf, self.dwell, robot) for tables, robot in self._per_model],
                               self.grid)

    def __call__(self, law, tf: float | None = None) -> dict:
        """law: a Profile or MotionSamples -> metrics dict name -> (K,) numpy arrays. ``tf`` [s]
        overrides the motion time (same grid, no recompilation; MotionSamples must match it)."""
        out = engine.metrics_of(self.series(law, tf))
        bad = [k for k, v in out.items() if not np.all(np.isfinite(v))]
        if bad:
            raise FloatingPointError(f"non-finite {bad} for law {getattr(law, 'name', 'samples')}")
        return out
