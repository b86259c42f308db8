"""The paper's path x motion-law combinations sampled on a time grid, on concrete values: inputs
validated before anything compiles, then one compiled program (``trajectory.combinations``,
``jaxflex.runtime.options.BUILD``) per set of blends and laws."""
from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp

from jaxflex.blends import BLENDS
from jaxflex.path import Cycle, check_path_args
from jaxflex.profiles import PROFILES, make_profile
from jaxflex.robot import Robot, check_cycle_reachable
from jaxflex.runtime.options import BUILD
from jaxflex.trajectory import Trajectory, check_tf, combinations

_combinations = jax.jit(combinations, static_argnames=("blends", "profiles"), compiler_options=BUILD)


def sample_combinations(robot: Robot, cycle: Cycle, tf, t, *, d=0.025, e=None, n=3.0,
                        blends: Sequence[str] = BLENDS,
                        profiles: Sequence[str] = PROFILES) -> tuple[Trajectory, list]:
    """All blend x profile combinations (blend-major order) on the grid t [s] at motion time tf [s],
    corner blends d, e [m] and Lamé order n, in one compiled call.

    Returns the stacked Trajectory (leading axis len(blends) * len(profiles)) and the list of
    (blend, profile) labels. Inputs are validated eagerly, before any compilation.
    """
    e = d if e is None else e
    blends, profiles = tuple(blends), tuple(profiles)
    for p in profiles:
        make_profile(p)
    for b in blends:
        check_path_args(cycle, b, d, e, n, d, e, n)
    check_tf(tf)
    check_cycle_reachable(robot, cycle)
    traj = _combinations(robot, cycle, jnp.asarray(tf, dtype=float), jnp.asarray(t, dtype=float),
                         jnp.asarray(d, dtype=float), jnp.asarray(e, dtype=float),
                         jnp.asarray(n, dtype=float), blends, profiles)
    labels = [(b, p) for b in blends for p in profiles]
    return traj, labels


def cache_size() -> int:
    """Executables the combinations program compiled in this process (every set of names and shapes)."""
    return _combinations._cache_size()
