"""Coefficient tables on concrete values: every table build through one shared compiled program.

The linearization coefficients (``linearized.pose_coeffs``) are the costly part of a rollout to
compile. Here they are evaluated on the host's concrete poses through one compiled program of
fixed shape (``COEFF_CHUNK`` poses per call, ``jaxflex.runtime.options.BUILD``), shared by every
table builder: the path tables of the engine's evaluators (``path_tables``), the paper sweep's
stacked tables and the workspace tables of the design gradient (``build_workspace``). The chunks
run side by side on the host's cores (``jaxflex.runtime.threads.host_map``); every chunk is the
same program on its own inputs, so the result does not depend on the threads. Recent results are
remembered by the content of their inputs (``jaxflex.runtime.memo.ContentMemo``).

Functions taking ``robot`` take one robot; those taking ``robots`` a stack of K robots (leaves with
a leading axis K, ``optimize.objective.stack_robots`` or ``model_sets.ModelSet.robots``).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex import trees
from jaxflex.linearized import SEGMENT_NODES, Coeffs, Tables, coeffs_at, table_poses
from jaxflex.path import Cycle, Path
from jaxflex.robot import Robot, check_reachable, igm
from jaxflex.runtime import compiled
from jaxflex.runtime.memo import ContentMemo
from jaxflex.runtime.options import BUILD
from jaxflex.runtime.threads import host_map
from jaxflex.servo_linearized import servo_coeffs_at
from jaxflex.workspace import PROBES, FIELDS, SERVO_FIELDS, Workspace, combine_probes, grid_points, grid_shape

COEFF_CHUNK = sum(SEGMENT_NODES)   # poses per call of the shared coefficient program: one path table
                                   # is one call, larger sets (sweeps, workspaces) a few (padding costs)
MEMO_BYTES = 256 * 2**20           # the remembered results' total size: the oldest go first beyond it

_coeffs_chunk = jax.jit(coeffs_at, compiler_options=BUILD)
_table_poses = jax.jit(table_poses, compiler_options=BUILD)        # one program per blend family
_grid_angles = jax.jit(lambda robot, points: jax.vmap(lambda x: igm(robot, x))(points))
_combine_all = jax.jit(jax.vmap(combine_probes))
_MEMO = ContentMemo(MEMO_BYTES)


def clear_memo() -> None:
    """Forget the remembered coefficients (they only cost memory: at most ``MEMO_BYTES``)."""
    _MEMO.clear()


def _coeffs(robots: list, poses: list) -> list:
    """The coefficients of each robot (a list) at its poses (qa, qa1, qa2: (N, 2) each), every chunk
    of every robot in one ``host_map``."""
    n = poses[0][0].shape[0]
    pad = -n % COEFF_CHUNK
    jobs = []
    for r, qs in zip(robots, poses):
        qs = [np.concatenate([q, np.repeat(q[:1], pad, axis=0)]) for q in qs]    # valid filler poses
        r = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype=float), r)
        jobs += [(r, *(q[i:i + COEFF_CHUNK] for q in qs)) for i in range(0, n + pad, COEFF_CHUNK)]
    parts = host_map(lambda job: compiled.call(_coeffs_chunk, job, register=True), jobs)
    per = (n + pad) // COEFF_CHUNK
    return [trees.concatenate(parts[k * per:(k + 1) * per], length=n) for k in range(len(robots))]


def compile_ahead(robot: Robot) -> None:
    """Start compiling the shared coefficient program for robots shaped like ``robot`` (its mode
    counts) in the background (``runtime.compiled.compile_ahead``), so that a caller compiles it
    while it computes the table poses; the table builds then run that program."""
    r = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(np.shape(a), jnp.float64), robot)
    poses = jax.ShapeDtypeStruct((COEFF_CHUNK, 2), jnp.float64)
    compiled.compile_ahead(_coeffs_chunk, (r, poses, poses, poses))


def coeffs_many(robot: Robot, qa, qa1, qa2, *, remember: bool = True) -> Coeffs:
    """``linearized.coeffs_at`` for one robot at any number N of poses (qa, qa1, qa2: (N, 2) each)
    through the shared coefficient program. Not traceable (concrete arrays). Recent results are
    remembered by the content of the inputs (``trees.content_key``): the same robot and poses again
    (a study's tables rebuilt by the next study) return the same arrays without running the program;
    ``remember=False`` neither looks them up nor keeps the result (large one-off sets)."""
    def build(robot, qa, qa1, qa2):
        return _coeffs([robot], [[np.asarray(a, dtype=float) for a in (qa, qa1, qa2)]])[0]
    return _MEMO(build, robot, qa, qa1, qa2) if remember else build(robot, qa, qa1, qa2)


def coeffs_stacked(robots: Robot, qa, qa1, qa2, *, remember: bool = True) -> Coeffs:
    """``coeffs_many`` for a stack of K robots: poses (K, N, 2) (each robot its own) or (N, 2)
    (shared); every leaf of the result has a leading axis K."""
    def build(robots, qa, qa1, qa2):
        singles = trees.unstack(robots)
        poses = [np.asarray(a, dtype=float) for a in (qa, qa1, qa2)]
        per_robot = [[p[k] if p.ndim == 3 else p for p in poses] for k in range(len(singles))]
        return trees.stack(_coeffs(singles, per_robot))
    return _MEMO(build, robots, qa, qa1, qa2) if remember else build(robots, qa, qa1, qa2)


def robot_table_poses(robot: Robot, path: Path):
    """``linearized.table_poses`` of one robot on concrete values through the shared compiled
    program (one per blend family)."""
    return _table_poses(robot, path)


def path_tables(robot: Robot, path: Path, *, remember: bool = True) -> Tables:
    """``linearized.build_tables`` on concrete arrays through the shared coefficient program
    (``coeffs_many``, which remembers recent results unless ``remember`` is False): no new
    compilation of the model per caller."""
    return Tables(values=coeffs_many(robot, *robot_table_poses(robot, path), remember=remember), breaks=path.breaks)


def _workspaces(robot: Robot, singles: list, cycle: Cycle, spacing: float, stacked: bool,
                servo: bool = False) -> Workspace:
    """The workspace tables of ``robot`` (one, or a stack of them with ``stacked``), whose single
    robots are ``singles``; with ``servo`` the servo coefficients' too."""
    shape = grid_shape(cycle, spacing)
    nu, nv = shape
    pts = np.asarray(grid_points(cycle, shape)).reshape(-1, 2)
    check_reachable(singles[0], pts, "workspace grid point")
    qa = np.stack([np.asarray(_grid_angles(r, jnp.asarray(pts))) for r in singles])      # (K, N, 2)
    n, p = pts.shape[0], len(PROBES)
    probes = np.tile(PROBES, (n, 1))                                                     # (N * 5, 4)
    if stacked:
        ev = coeffs_stacked(robot, np.repeat(qa, p, axis=1), probes[:, :2], probes[:, 2:])
    else:
        ev = coeffs_many(singles[0], np.repeat(qa[0], p, axis=0), probes[:, :2], probes[:, 2:])
    lead = (len(singles),) if stacked else ()
    ev = {k: v.reshape((-1, p) + v.shape[len(lead) + 1:]) for k, v in ev._asdict().items() if k in FIELDS}
    values = {k: v.reshape(lead + (nu, nv) + v.shape[1:]) for k, v in _combine_all(ev).items()}
    if servo:
        per = [_servo_many(r, np.repeat(q, p, axis=0), probes[:, :2], probes[:, 2:]) for r, q in zip(singles, qa)]
        sv = {k: np.stack([np.asarray(d[k]) for d in per]) for k in SERVO_FIELDS}          # (K, N * 5, ...)
        sv = {k: v.reshape((-1, p) + v.shape[2:]) for k, v in sv.items()}
        combined = {k: v.reshape((len(singles), nu, nv) + v.shape[1:]) for k, v in _combine_all(sv).items()}
        values.update({k: v if stacked else v[0] for k, v in combined.items()})
    step = jnp.stack([cycle.l / (nu - 1), cycle.h / (nv - 1)])
    ws = Workspace(values=values, origin=jnp.asarray(cycle.pick, dtype=float), axes=jnp.asarray(cycle.basis), step=step)
    if not stacked:
        return ws
    k = len(singles)
    return ws._replace(origin=jnp.broadcast_to(ws.origin, (k, 2)), axes=jnp.broadcast_to(ws.axes, (k, 2, 2)),
                       step=jnp.broadcast_to(ws.step, (k, 2)))


def build_workspace(robot: Robot, cycle: Cycle, spacing: float = 0.005, servo: bool = False) -> Workspace:
    """The workspace tables of one robot (``jaxflex.workspace``): the pose functions tabulated over
    the cycle's rectangle with about ``spacing`` [m] between grid points; with ``servo`` those of
    the servo coefficients too (``servo_linearized.ServoCoeffs``, of the robot with its rotor: for
    the servo loop's tables, ``workspace.workspace_servo_tables``). Raises ValueError when a grid
    point is unreachable or singular (before any compilation)."""
    return _workspaces(robot, [robot], cycle, spacing, stacked=False, servo=servo)


def build_workspaces(robots: Robot, cycle: Cycle, spacing: float = 0.005, servo: bool = False) -> Workspace:
    """``build_workspace`` for a stack of K robots: a Workspace whose leaves have a leading axis K."""
    return _workspaces(robots, trees.unstack(robots), cycle, spacing, stacked=True, servo=servo)


_servo_coeffs = jax.jit(servo_coeffs_at, compiler_options=BUILD)


def _servo_many(robot: Robot, qa, qa1, qa2) -> dict:
    """``servo_coeffs_at`` of one robot at N concrete poses (N, 2) each, ``COEFF_CHUNK`` poses per call
    (the program ``servo_path_tables`` compiles), the chunks side by side on the host's cores."""
    n = qa.shape[0]
    pad = -n % COEFF_CHUNK
    qs = [np.concatenate([q, np.repeat(q[:1], pad, axis=0)]) for q in (qa, qa1, qa2)]
    r = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype=float), robot)
    parts = host_map(lambda i: _servo_coeffs(r, *(q[i:i + COEFF_CHUNK] for q in qs)), range(0, n + pad, COEFF_CHUNK))
    return trees.concatenate(parts, length=n)._asdict()


def servo_path_tables(robot: Robot, path: Path) -> Tables:
    """The servo coefficients (``servo_linearized.ServoCoeffs``) tabulated along the path
    (``servo_linearized.build_servo_tables``) on concrete values: the poses through the program of
    the blend family (``robot_table_poses``, cheap), the coefficients through one compiled program
    that every blend family shares (the costly part to compile)."""
    return Tables(values=_servo_coeffs(robot, *robot_table_poses(robot, path)), breaks=path.breaks)
