"""Pytrees of arrays: stacking concrete ones on the host, mapping traced ones at once.

An eager ``jnp.stack`` or ``jnp.concatenate`` compiles a small XLA program for every new number and
shape of its operands; batches of robots, tables and series come in many sizes, so joining them on
the host (numpy, then one transfer per leaf) avoids a trickle of small compilations. For concrete
values only (inside a traced function use ``jnp`` directly), except ``map_packed``, which is for
traced code: one operation on all leaves of a pytree at once.
"""
from __future__ import annotations

import hashlib
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np


def stack(trees: Sequence, dtype=None):
    """Pytrees with equal structure -> one pytree whose leaves gain a leading axis (len(trees),)."""
    return jax.tree_util.tree_map(lambda *a: jnp.asarray(np.stack([np.asarray(v, dtype=dtype) for v in a])), *trees)


def unstack(tree) -> list:
    """A pytree whose leaves share a leading axis K -> the list of its K slices (``stack``'s
    inverse)."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    k = np.shape(leaves[0])[0]
    return [jax.tree_util.tree_unflatten(treedef, [a[i] for a in leaves]) for i in range(k)]


def concatenate(trees: Sequence, length: int | None = None):
    """Pytrees with equal structure -> one pytree whose leaves are joined along their leading axis
    (and cut to its first ``length`` entries if given)."""
    return jax.tree_util.tree_map(lambda *a: jnp.asarray(np.concatenate([np.asarray(v) for v in a])[:length]),
                                  *trees)


def content_key(*trees) -> bytes:
    """A digest of pytrees of concrete arrays: their structure, every leaf's dtype, shape and bytes.
    Equal keys mean equal inputs (to the hash's collision odds, 2^-160), so a deterministic function
    of them can return a remembered result."""
    h = hashlib.blake2b(digest_size=20)
    for tree in trees:
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        h.update(str(treedef).encode())
        for leaf in leaves:
            a = np.ascontiguousarray(np.asarray(leaf))
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
    return h.digest()


def map_packed(fn, tree, lead: int):
    """``fn`` applied once to all leaves of ``tree`` at once (traced): every leaf's first ``lead``
    axes are kept and its trailing axes are flattened and joined into one last axis, ``fn`` maps
    that (lead..., F) array to an array (..., F), and the result is split back into leaves of shape
    (...,) + the leaf's trailing shape. For a linear map that acts on the leading axes alone (an
    interpolant), this equals mapping every leaf on its own, with one operation instead of one per
    leaf: a smaller program to trace, compile and differentiate."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    tails = [leaf.shape[lead:] for leaf in leaves]
    sizes = [int(np.prod(t, dtype=int)) for t in tails]
    packed = jnp.concatenate([leaf.reshape(leaf.shape[:lead] + (-1,)) for leaf in leaves], axis=-1)
    out = fn(packed)
    cuts = np.cumsum(sizes)[:-1]
    parts = jnp.split(out, cuts, axis=-1)
    return jax.tree_util.tree_unflatten(treedef, [p.reshape(p.shape[:-1] + t) for p, t in zip(parts, tails)])
