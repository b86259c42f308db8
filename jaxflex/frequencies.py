"""Locked-motor natural frequencies at a pose, on concrete values: the pose checked before anything
compiles, then one compiled program (``model.frequencies_at_point``,
``jaxflex.runtime.options.BUILD``) shared by every caller with the same mode counts
(docs/conventions.md#natural-frequencies)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.model import frequencies_at_point
from jaxflex.robot import Robot, check_reachable
from jaxflex.runtime.options import BUILD

_frequencies = jax.jit(frequencies_at_point, compiler_options=BUILD)


def modes_at_point(robot: Robot, x):
    """Locked-motor natural frequencies [Hz] (ne,) at end-effector position x (2,) [m] (the rigid IGM
    pose). A concrete (non-traced) x is first checked for reachability and singularity (ValueError),
    then evaluated by one compiled program; traced inputs are evaluated in the caller's trace."""
    if any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves((robot, x))):
        return frequencies_at_point(robot, x)
    check_reachable(robot, np.asarray(x)[None], "pose")
    return _frequencies(robot, jnp.asarray(x, dtype=float))
