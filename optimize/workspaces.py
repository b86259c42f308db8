"""The training models' workspace tables, kept on disk for the studies that train on them again.

``jaxflex reproduce`` runs its studies each in a process of its own, and several train on the same
models (the 6 kg box in the 6 kg, both-payload and cycle-time studies). ``remembered_workspaces``
keeps each model's tables (``jaxflex.tables.build_workspaces``) in a memo directory, named by a
digest of the model, the cycle and the code, and loads them there instead of building them again.
Each model's tables are those of a stacked build (the same program per robot and chunk of poses),
so the result is the same, bit for bit, whichever models were loaded.
"""
from __future__ import annotations

import hashlib
import os
import pathlib
import zipfile

import jax
import numpy as np

from jaxflex import trees
from jaxflex.model_sets import ModelSet
from jaxflex.path import Cycle
from jaxflex.progress import Progress
from jaxflex.robot import Robot
from jaxflex.tables import build_workspaces
from jaxflex.workspace import Workspace, workspace_shapes

from .loop import code_digest

WORKSPACE_MEMO = "workspaces"       # the subdirectory of a study memo that holds the models' workspaces


def training_workspaces(models: ModelSet, cycle: Cycle, progress: bool, memo=None) -> Workspace:
    """The training models' workspace tables (``jaxflex.workspace``), with progress on stderr; with a
    ``memo`` directory each model's tables are kept there and loaded by later studies
    (``remembered_workspaces``)."""
    bar = Progress(f"workspace tables of {len(models.ids)} model(s)", enabled=progress)
    if memo is None:
        with bar.waiting("building (the blends' design space around both corners)", key="workspace tables"):
            return jax.block_until_ready(build_workspaces(models.robots, cycle))
    with bar.waiting("building or loading (the blends' design space around both corners)",
                     key="workspace tables (memo)"):
        return remembered_workspaces(models.robots, cycle, memo)


def remembered_workspaces(robots: Robot, cycle: Cycle, memo) -> Workspace:
    """``tables.build_workspaces(robots, cycle)`` for a stack of K robots, each model's tables kept in
    ``memo``/workspaces as a file named by a digest of the model, the cycle and the code
    (``loop.fingerprint``'s code digest). Models whose file is there are loaded, the others built
    (as one stack) and written: the studies of ``jaxflex reproduce`` train on the same models (the
    6 kg box in the 6 kg, both-payload and cycle-time studies), each in a process of its own, and
    building one model's tables runs the coefficient program on thousands of poses. Each model's
    tables are those of a stacked build (the same program per robot and chunk of poses), so the
    result is the same, bit for bit, whichever models were loaded."""
    folder = pathlib.Path(memo) / WORKSPACE_MEMO
    singles = trees.unstack(robots)
    code = code_digest().encode()
    files = [folder / f"{hashlib.sha1(code + trees.content_key(r, cycle)).hexdigest()}.npz" for r in singles]
    shapes = workspace_shapes(singles[0], cycle)
    tables = [_load_workspace(f, shapes) for f in files]
    missing = [k for k, t in enumerate(tables) if t is None]
    if missing:
        built = build_workspaces(trees.stack([singles[k] for k in missing]), cycle)
        folder.mkdir(parents=True, exist_ok=True)
        for j, k in enumerate(missing):
            _save_workspace(files[k], jax.tree_util.tree_map(lambda a: a[j], built))
        if len(missing) == len(tables):
            return jax.block_until_ready(built)      # every model built here: the stack as built, no copy
        for j, k in enumerate(missing):
            tables[k] = jax.tree_util.tree_map(lambda a: np.asarray(a[j]), built)
        del built
    return jax.block_until_ready(trees.stack(tables))


def _save_workspace(file: pathlib.Path, ws: Workspace) -> None:
    tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, *[np.asarray(a) for a in jax.tree_util.tree_leaves(ws)])
    os.replace(tmp, file)                   # atomic: a reader sees the whole file or none


def _load_workspace(file: pathlib.Path, shapes: Workspace) -> Workspace | None:
    """The workspace in ``file`` if it is there and has the structure of ``shapes``, else None."""
    leaves, treedef = jax.tree_util.tree_flatten(shapes)
    try:
        with np.load(file) as z:
            arrays = [z[f"arr_{i}"] for i in range(len(z.files))]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):     # missing or damaged
        return None
    if len(arrays) != len(leaves) or any(a.shape != tuple(s.shape) or a.dtype != s.dtype
                                         for a, s in zip(arrays, leaves)):
        return None
    return jax.tree_util.tree_unflatten(treedef, arrays)
