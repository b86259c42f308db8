"""Many processes as one JAX runtime: ``jax.distributed`` and global arrays sharded over every device.

A batch (models of an uncertainty box, designs) is laid along one mesh axis over ``jax.devices()``,
every device of every process. Each process builds only the rows its own devices hold
(``rows_array``); the compiled program runs on every process at once (single program, multiple
data: every process calls it with the same arguments, in the same order); its results are
gathered so that every process holds all of them (``gather``). With one process this is plain
sharding over the local devices (on CPU ``XLA_FLAGS=--xla_force_host_platform_device_count=N``
gives N). The partition is the mesh's, so there is no scheduler: a batch is cut into equal
shares, one per device.

Launch: every process runs the same script and calls ``initialize`` first; on a cluster that
JAX detects (SLURM, Open MPI, Kubernetes, cloud TPU) it needs no arguments, otherwise the
coordinator's address, the process count and this process's index, or the environment variables
``JAXFLEX_COORDINATOR``, ``JAXFLEX_NUM_PROCESSES`` and ``JAXFLEX_PROCESS_ID`` (README, "Running on
a cluster or a GPU").
"""
from __future__ import annotations

import os
from typing import Callable

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

_ENV = ("JAXFLEX_COORDINATOR", "JAXFLEX_NUM_PROCESSES", "JAXFLEX_PROCESS_ID")


def initialize(coordinator_address: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, **kwargs) -> None:
    """Join the multi-process runtime (``jax.distributed.initialize``; before any other JAX call).

    Arguments not given are read from ``JAXFLEX_COORDINATOR`` ("host:port"),
    ``JAXFLEX_NUM_PROCESSES`` and ``JAXFLEX_PROCESS_ID``, and where those are unset JAX detects
    them from the cluster. On CPU, cross-process collectives use gloo (JAX's default).
    ``kwargs`` go to ``jax.distributed.initialize``."""
    env = [os.environ.get(k) for k in _ENV]
    coordinator_address = coordinator_address or env[0]
    num_processes = num_processes if num_processes is not None else (int(env[1]) if env[1] else None)
    process_id = process_id if process_id is not None else (int(env[2]) if env[2] else None)
    jax.distributed.initialize(coordinator_address=coordinator_address, num_processes=num_processes,
                               process_id=process_id, **kwargs)


def batch_sharding(axis: str, devices=None) -> NamedSharding:
    """Rows of a batch along a one-dimensional mesh ``axis`` over ``devices`` (default every device
    of every process, ``jax.devices()``)."""
    devices = jax.devices() if devices is None else list(devices)
    return NamedSharding(Mesh(np.asarray(devices), (axis,)), PartitionSpec(axis))


def rows_array(rows: Callable[[int, int], np.ndarray], size: int, sharding: NamedSharding) -> jax.Array:
    """A global array of ``size`` rows sharded by ``sharding``, each process calling ``rows(lo, hi)``
    (rows lo..hi-1 as a numpy array, leading axis hi - lo) only for the shards its devices hold."""
    probe = np.asarray(rows(0, 1))
    shape = (size,) + probe.shape[1:]

    def shard(index):
        sl = index[0]
        lo, hi = sl.start or 0, size if sl.stop is None else sl.stop
        return np.asarray(rows(lo, hi), dtype=probe.dtype)

    return jax.make_array_from_callback(shape, sharding, shard)


def gather(tree):
    """Every leaf as a numpy array holding all of its rows on every process (an all-gather across
    processes when the leaf is not fully addressable here; a copy to the host otherwise)."""
    def one(a):
        if isinstance(a, jax.Array) and not a.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(a, tiled=True))
        return np.asarray(a)
    return jax.tree_util.tree_map(one, tree)


def is_leader() -> bool:
    """True on process 0 (the one that reports and writes files)."""
    return jax.process_index() == 0
