"""Stacking pytrees of concrete arrays on the host.

An eager ``jnp.stack`` or ``jnp.concatenate`` compiles a small XLA program for every new number and
shape of its operands; batches of robots, tables and series come in many sizes, so joining them on
the host (numpy, then one transfer per leaf) avoids a trickle of small compilations. For concrete
values only (inside a traced function use ``jnp`` directly).
"""
from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np


def stack(trees: Sequence, dtype=None):
    """Pytrees with equal structure -> one pytree whose leaves gain a leading axis (len(trees),)."""
    return jax.tree_util.tree_map(lambda *a: jnp.asarray(np.stack([np.asarray(v, dtype=dtype) for v in a])), *trees)


def concatenate(trees: Sequence, length: int | None = None):
    """Pytrees with equal structure -> one pytree whose leaves are joined along their leading axis
    (and cut to its first ``length`` entries if given)."""
    return jax.tree_util.tree_map(lambda *a: jnp.asarray(np.concatenate([np.asarray(v) for v in a])[:length]),
                                  *trees)
