"""Linearization coefficients over the cycle's workspace: cheap, differentiable tables for any path.

Every coefficient of ``linearized.pose_coeffs`` is a polynomial in the path derivatives of the motor
angles, qa1 = dq_a/ds = (a, b) and qa2 = d2q_a/ds2 = (c, d), whose coefficients depend on the pose
only (the equations of motion are quadratic in velocities and linear in accelerations):

    C(pose, qa1, qa2) = B_1 + a B_a + b B_b + a^2 B_aa + a b B_ab + b^2 B_bb + c B_c + d B_d,

where the pose-only fields (mass, k0, ...) have B_1 alone, the fields per unit s'' and the gyroscopic
ones (f1, k1, c1, ...) B_a and B_b, and the fields per unit s'^2 (f2, k2, ..., jx2) the other five.
``build_workspace`` tabulates these pose functions once per robot on a uniform grid of end-effector
positions covering the cycle's rectangle (traverse x lift, where every blended path of the cycle
lies) from five exact evaluations of ``pose_coeffs`` per grid point. ``workspace_tables`` then
gives the path tables of ``linearized.build_tables`` for any path of the cycle by local bicubic
interpolation of the B's at the path's nodes and the exact polynomial in (qa1, qa2): no model
evaluation, so a gradient with respect to the path (blend parameters) costs little to compile and
to run. The optimizer differentiates through it; final evaluations use the exact tables.
Interpolation error: about 1e-7 of each field's range with the default 5 mm grid
(tests/test_workspace.py).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from jaxflex import trees
from jaxflex.linearized import Coeffs, Tables, coeff_shapes, cubic_weights, pose_coeffs, segment_nodes
from jaxflex.path import Cycle, Path, path_frame
from jaxflex.robot import Robot, joint_motion
from jaxflex.servo_linearized import ServoCoeffs

ORDER0 = ("mass", "m_ae", "f0", "k0", "c0", "t0", "tq0", "tv0", "jx")       # pose only
ORDER1 = ("f1", "k1", "c1", "t1", "tq1", "tv1", "jx1")                     # linear in qa1
ORDER2 = ("f2", "k2", "t2", "tq2", "jx2")                                  # quadratic in qa1, linear in qa2
FIELDS = ORDER0 + ORDER1 + ORDER2                                          # every field of the workspace
# the servo coefficients (``servo_linearized.ServoCoeffs``), tabulated with ``servo=True`` only: the
# same classes (d/dq_a of the residual's terms, and the end effector's motion with the motors)
SERVO_ORDER0 = ("m_aa", "ka0", "jxa")
SERVO_ORDER1 = ("ka1", "ca1", "jxa1")
SERVO_ORDER2 = ("ka2", "jxa2")
SERVO_FIELDS = SERVO_ORDER0 + SERVO_ORDER1 + SERVO_ORDER2
MONOMIALS = {0: (0,), 1: (1, 2), 2: (3, 4, 5, 6, 7)}   # indices into [1, a, b, a^2, ab, b^2, c, d]
# the (qa1, qa2) at which pose_coeffs is evaluated: e1, e2, e1 + e2 (qa1); e1, e2 (qa2). Each field
# is a polynomial with only its class's monomials (``MONOMIALS``: exact, the model being quadratic in
# velocities and linear in accelerations; tests/test_workspace.py checks it with more probes), so
# five evaluations determine every coefficient: at qa1 = e1 an order-1 field is B_a and an order-2
# field B_aa, at e1 + e2 an order-2 field is B_aa + B_ab + B_bb, at qa2 = e1 it is B_c; an order-0
# field is B_1 at any probe.
PROBES = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def monomial_order(field: str) -> int:
    return 0 if field in ORDER0 + SERVO_ORDER0 else 1 if field in ORDER1 + SERVO_ORDER1 else 2


def has_servo(ws: "Workspace") -> bool:
    """Whether the workspace also tabulates the servo coefficients (``build_workspace(servo=True)``)."""
    return all(k in ws.values for k in SERVO_FIELDS)


def restricted(ws: "Workspace", fields) -> "Workspace":
    """The workspace with only the pose functions of ``fields``."""
    return ws._replace(values={k: ws.values[k] for k in fields})


class Workspace(NamedTuple):
    """Pose functions B of the coefficient polynomial on a grid of end-effector positions.

    ``values``: field -> (nu, nv, k, ...) array, k the field's monomials (``MONOMIALS``); the grid
    point (i, j) is at origin + axes @ (i step_u, j step_v) [m]; ``axes`` (2, 2) has the traverse and
    lift directions as columns; ``step`` (2,) [m]. A pytree of arrays: vmap over robots stacks it."""

    values: dict
    origin: jax.Array
    axes: jax.Array
    step: jax.Array


def grid_shape(cycle: Cycle, spacing: float = 0.005) -> tuple[int, int]:
    """Grid points (along the traverse, along the lift) for a target spacing [m] (at least 4 each)."""
    l, h = float(cycle.l), float(cycle.h)
    return max(4, math.ceil(l / spacing) + 1), max(4, math.ceil(h / spacing) + 1)


def combine_probes(ev: dict) -> dict:
    """The monomial coefficients B of every field (field -> (k, ...)) from ``pose_coeffs`` (or
    ``servo_pose_coeffs``) at the five probes ``PROBES`` (field -> (5, ...), workspace fields only)."""
    out = {}
    for name in ev:
        e = ev[name]
        order = monomial_order(name)
        if order == 0:
            out[name] = e[:1]
        elif order == 1:
            out[name] = e[:2]                                                   # B_a, B_b
        else:
            out[name] = jnp.stack([e[0], e[2] - e[0] - e[1], e[1], e[3], e[4]])   # B_aa, B_ab, B_bb, B_c, B_d
    return out


def _basis_at(robot: Robot, qa):
    """The monomial coefficients B of every field (field -> (k, ...)) at motor angles qa (2,)."""
    return combine_probes(_basis_full(robot, qa))


def _basis_full(robot: Robot, qa):
    """``pose_coeffs`` at the probes ``PROBES`` (field -> (5, ...)), from which ``_basis_at`` forms
    the monomial coefficients."""
    probes = jnp.asarray(PROBES)
    ev = jax.vmap(lambda p: pose_coeffs(robot, qa, p[:2], p[2:]))(probes)._asdict()
    return {k: v for k, v in ev.items() if k in FIELDS}


def grid_points(cycle: Cycle, shape: tuple[int, int]):
    """World positions (nu, nv, 2) [m] of the grid points over the cycle's rectangle."""
    nu, nv = shape
    u = jnp.linspace(0.0, 1.0, nu) * cycle.l
    v = jnp.linspace(0.0, 1.0, nv) * cycle.h
    local = jnp.stack(jnp.meshgrid(u, v, indexing="ij"), axis=-1)          # (nu, nv, 2)
    return cycle.pick[None, None, :] + local @ cycle.basis.T


def workspace_shapes(robot: Robot, cycle: Cycle, spacing: float = 0.005, models: int | None = None) -> Workspace:
    """The shapes and dtypes of ``tables.build_workspace(robot, cycle, spacing)`` (a Workspace of
    ``jax.ShapeDtypeStruct``), or with ``models`` = K of ``tables.build_workspaces`` for a stack of K
    robots like ``robot``, without building it, so that a program taking the workspace can start
    compiling (``jaxflex.runtime.compiled.compile_ahead``) while the tables are built: from the
    coefficients' shapes (``linearized.coeff_shapes``, no trace of the model, which is slow and would
    delay everything), through a trace of ``combine_probes`` only."""
    nu, nv = grid_shape(cycle, spacing)
    lead = () if models is None else (int(models),)
    probes = len(PROBES)
    shapes = coeff_shapes(robot)._asdict()
    full = {k: jax.ShapeDtypeStruct((probes,) + v.shape, v.dtype) for k, v in shapes.items() if k in FIELDS}
    basis = jax.eval_shape(combine_probes, full)
    struct = lambda shape: jax.ShapeDtypeStruct(lead + shape, jnp.float64)
    return Workspace(values={k: struct((nu, nv) + v.shape) for k, v in basis.items()},
                     origin=struct((2,)), axes=struct((2, 2)), step=struct((2,)))


@jax.custom_jvp
def _bicubic(block, tu, tv):
    """sum_ij w_i(tu) w_j(tv) block[i, j, ...] for a (4, 4, ...) block of grid values."""
    return jnp.tensordot(cubic_weights(tu)[:, None] * cubic_weights(tv)[None, :], block, axes=2)


def _bicubic_jvp(primals, tangents):
    """The interpolant's tangent from its two slopes (d/dtu, d/dtv), so that reverse mode keeps these
    two (field-sized) slopes per node rather than the 16 grid values of the stencil (much less memory
    in the design gradient, whose tables are interpolated at every node of every model)."""
    block, tu, tv = primals
    dblock, dtu, dtv = tangents
    (wu, su), (wv, sv) = (jax.jvp(cubic_weights, (t,), (jnp.ones_like(t),)) for t in (tu, tv))
    out = jnp.tensordot(wu[:, None] * wv[None, :], block, axes=2)
    tangent = 0.0
    if not isinstance(dtu, SymbolicZero):
        tangent = tangent + jnp.tensordot(su[:, None] * wv[None, :], block, axes=2) * dtu
    if not isinstance(dtv, SymbolicZero):
        tangent = tangent + jnp.tensordot(wu[:, None] * sv[None, :], block, axes=2) * dtv
    if not isinstance(dblock, SymbolicZero):
        tangent = tangent + jnp.tensordot(wu[:, None] * wv[None, :], dblock, axes=2)
    return out, jnp.zeros_like(out) + tangent


_bicubic.defjvp(_bicubic_jvp, symbolic_zeros=True)


def _stencil_at(ws: Workspace, packed, x):
    """The bicubic interpolant of the packed grid values (nu, nv, F) at the end-effector position x
    (2,) [m]: the 4 x 4 stencil around x (clamped to the grid) as one slice."""
    local = ws.axes.T @ (x - ws.origin) / ws.step
    starts, ts = [], []
    for k in range(2):
        i0 = jnp.clip(jnp.floor(local[k]).astype(int) - 1, 0, packed.shape[k] - 4)
        starts.append(i0)
        ts.append(local[k] - i0.astype(float))
    block = jax.lax.dynamic_slice(packed, (starts[0], starts[1], 0), (4, 4, packed.shape[-1]))
    return _bicubic(block, *ts)


def interpolate_basis(ws: Workspace, x) -> dict:
    """Pose functions at the end-effector position x (2,) [m] by local bicubic interpolation
    (differentiable in x and in the grid values)."""
    return trees.map_packed(lambda v: _stencil_at(ws, v, x), ws.values, lead=2)


NODE_BATCH = 4      # nodes per step of ``interpolate_nodes``


def interpolate_nodes(ws: Workspace, xs) -> dict:
    """``interpolate_basis`` at the positions xs (N, 2) [m]: leaves with a leading axis N.

    The nodes go ``NODE_BATCH`` at a time (``lax.map``), not all as one batch: a batch of every node
    gathers all the stencils first (16 x 2320 values per node on the default model) and reads them
    back from memory, while a few nodes' stencils stay in cache, so the design gradient's path stage
    runs faster (docs/performance.md). Each step is the same batched interpolant, so the values and
    their derivatives equal the one-batch form's bit for bit."""
    return trees.map_packed(lambda v: jax.lax.map(lambda x: _stencil_at(ws, v, x), xs, batch_size=NODE_BATCH),
                            ws.values, lead=2)


def _monomials(qa1, qa2):
    a, b = qa1[0], qa1[1]
    return jnp.stack([jnp.ones_like(a), a, b, a * a, a * b, b * b, qa2[0], qa2[1]])


def _polynomials(basis: dict, names, qa1, qa2) -> dict:
    mono = _monomials(qa1, qa2)
    return {k: jnp.tensordot(mono[np.asarray(MONOMIALS[monomial_order(k)])], basis[k], axes=1) for k in names}


def coeffs_from_basis(basis: dict, qa, qa1, qa2) -> Coeffs:
    """``pose_coeffs`` from the pose functions at the pose qa (2,) and the path derivatives qa1, qa2."""
    return Coeffs(**_polynomials(basis, FIELDS, qa1, qa2), qa=qa, qa1=qa1, qa2=qa2)


def servo_from_basis(basis: dict, qa1, qa2) -> ServoCoeffs:
    """``servo_pose_coeffs`` from the servo pose functions at a pose and the path derivatives qa1, qa2."""
    return ServoCoeffs(**_polynomials(basis, SERVO_FIELDS, qa1, qa2))


def path_nodes(robot: Robot, path: Path):
    """Table nodes of a path (``linearized.SEGMENT_NODES``): end-effector positions (K, 2) [m] and the
    motor angles with their arc-length derivatives, (K, 2) each."""
    s = segment_nodes(path.breaks)

    def one(si):
        f = path_frame(path, si)
        return (f.pos,) + joint_motion(robot, f.pos, f.tangent, f.curv)

    return jax.vmap(one)(s)


def workspace_tables(ws: Workspace, robot: Robot, path: Path) -> Tables:
    """The path's linearization tables (as ``linearized.build_tables``) from the workspace tables of
    the same robot and cycle; differentiable in the path parameters."""
    x, qa, qa1, qa2 = path_nodes(robot, path)
    values = jax.vmap(coeffs_from_basis)(interpolate_nodes(restricted(ws, FIELDS), x), qa, qa1, qa2)
    return Tables(values=values, breaks=path.breaks)


def workspace_servo_tables(ws: Workspace, robot: Robot, path: Path) -> Tables:
    """The path's servo tables (as ``servo_linearized.build_servo_tables``) from a workspace that
    tabulates them (``has_servo``) of the same robot (rotor included) and cycle; differentiable in
    the path parameters, and much cheaper to differentiate and to compile than the model's."""
    x, _, qa1, qa2 = path_nodes(robot, path)
    values = jax.vmap(servo_from_basis)(interpolate_nodes(restricted(ws, SERVO_FIELDS), x), qa1, qa2)
    return Tables(values=values, breaks=path.breaks)
