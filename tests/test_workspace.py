"""Workspace tables: the coefficient polynomial in the path derivatives, interpolation accuracy and
derivatives with respect to the blend parameters (what the design optimizer differentiates)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex.path import make_path
from jaxflex.robot import cycle_preset, igm, robot_preset
from jaxflex.tables import build_workspace, coeffs_many, path_tables
from jaxflex.workspace import (MONOMIALS, ORDER0, ORDER1, ORDER2, PROBES, coeffs_from_basis, combine_probes,
                               monomial_order, workspace_shapes, workspace_tables)


@pytest.fixture(scope="module")
def setup():
    robot, cycle = robot_preset("default", payload=6.0), cycle_preset()
    return robot, cycle, build_workspace(robot, cycle)


def test_workspace_shapes_are_those_of_the_built_workspace(setup):
    """``workspace_shapes`` (what the design gradient compiles against while the tables are built)
    gives every leaf's shape and dtype of ``build_workspace``, for one robot and, with the leading
    model axis, for a stack of robots."""
    from jaxflex.optimize.objective import stack_robots

    robot, cycle, ws = setup
    shapes = workspace_shapes(robot, cycle)
    assert jax.tree_util.tree_structure(shapes) == jax.tree_util.tree_structure(ws)
    for s, a in zip(jax.tree_util.tree_leaves(shapes), jax.tree_util.tree_leaves(ws)):
        assert (s.shape, s.dtype) == (a.shape, a.dtype)
    two = workspace_shapes(stack_robots([robot, robot.replace(payload=0.1)]), cycle, models=2)
    assert jax.tree_util.tree_structure(two) == jax.tree_util.tree_structure(ws)
    for s, a in zip(jax.tree_util.tree_leaves(two), jax.tree_util.tree_leaves(ws)):
        assert (s.shape, s.dtype) == ((2,) + a.shape, a.dtype)


# (qa1, qa2) probes of the structure check: 0, +-e1, +-e2, e1 + e2 (qa1); e1, e2 (qa2), from which every
# monomial of [1, a, b, a^2, ab, b^2, c, d] follows (central differences separate odd and even parts)
_CHECK_PROBES = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [0, -1, 0, 0], [1, 1, 0, 0],
                          [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def test_coefficients_are_exact_polynomials_in_the_path_derivatives():
    """Every field's monomials outside its class (``MONOMIALS``) vanish (eight probes, more than the
    workspace's five, so that the check does not assume the structure the workspace relies on), and
    the polynomial the workspace rebuilds from its five probes equals ``pose_coeffs`` at arbitrary
    (qa1, qa2) to round-off (the model is quadratic in velocities and linear in accelerations, so
    the claim is exact). Tolerance 1e-12 of each field's range: pose_coeffs takes every field from one
    term of the residual (``model.residual_term``), so none is a difference against the ~5e9 N/m
    elastic stiffness (measured 4e-16 for the structure and 1e-15 for the rebuilt polynomial; 1e-8
    when the s'' and s'^2 fields were such differences)."""
    robot = robot_preset("default", payload=6.0)
    qa = np.asarray(igm(robot, jnp.asarray([0.05, 0.27])))

    def at(probes):      # pose_coeffs at the probes, through the library's shared coefficient program
        full = coeffs_many(robot, np.repeat(qa[None], len(probes), 0), probes[:, :2], probes[:, 2:])._asdict()
        return {k: np.asarray(v) for k, v in full.items() if k in ORDER0 + ORDER1 + ORDER2}

    e = at(_CHECK_PROBES)
    b = {k: np.stack([e[k][0], 0.5 * (e[k][1] - e[k][2]), 0.5 * (e[k][3] - e[k][4]),
                      0.5 * (e[k][1] + e[k][2]) - e[k][0], np.zeros_like(e[k][0]), 0.5 * (e[k][3] + e[k][4]) - e[k][0],
                      e[k][6] - e[k][0], e[k][7] - e[k][0]]) for k in e}
    for k in b:
        b[k][4] = e[k][5] - b[k][0] - b[k][1] - b[k][2] - b[k][3] - b[k][5]
        scale = np.max(np.abs(b[k])) + 1e-300
        dropped = np.delete(b[k], MONOMIALS[monomial_order(k)], axis=0)
        assert np.max(np.abs(dropped)) <= 1e-12 * scale, k
    assert set(ORDER0 + ORDER1 + ORDER2) == set(e)
    probed = at(np.asarray(PROBES))
    basis = jax.tree_util.tree_map(lambda v: v[0], jax.vmap(combine_probes)({k: jnp.asarray(v)[None] for k, v in probed.items()}))
    for k in b:           # the same monomials as the eight-probe check's
        np.testing.assert_allclose(basis[k], b[k][np.asarray(MONOMIALS[monomial_order(k)])], rtol=0,
                                   atol=1e-12 * (np.max(np.abs(b[k])) + 1e-300), err_msg=k)
    rng = np.random.default_rng(0)
    qa1s, qa2s = rng.normal(0, 4, (3, 2)), rng.normal(0, 300, (3, 2))             # rad/m, rad/m^2
    refs = coeffs_many(robot, np.repeat(qa[None], 3, 0), qa1s, qa2s)._asdict()
    for i in range(3):
        ours = coeffs_from_basis(basis, jnp.asarray(qa), jnp.asarray(qa1s[i]), jnp.asarray(qa2s[i]))._asdict()
        for k in refs:
            ref = np.asarray(refs[k][i])
            np.testing.assert_allclose(ours[k], ref, rtol=0, atol=1e-12 * (np.max(np.abs(ref)) + 1e-300), err_msg=k)


def _tables(cycle, d, e, fn):
    return fn(make_path(cycle, "lame", d, e, 3.5, 0.02, 0.04, 2.5)).values._asdict()


def test_workspace_tables_and_their_blend_derivatives_match_the_exact_tables(setup):
    """An asymmetric Lamé design (corners d, e, n = 15/60/3.5 and 20/40/2.5 mm): every field within
    1e-5 of its range (bicubic interpolation on the 5 mm grid: measured 5e-7); the derivatives w.r.t.
    the first corner's d and e (forward mode through the interpolation) against central differences
    of the exact tables (h = 1e-6 m: truncation ~1e-12) within 2e-3 of each derivative's largest
    value (the interpolant's derivative error is O(grid^3): measured 6e-4, on k0, whose derivative
    is small because K0 hardly depends on the pose)."""
    robot, cycle, ws = setup
    exact = lambda d, e: _tables(cycle, d, e, lambda p: path_tables(robot, p))      # the shared program
    interp = lambda d, e: _tables(cycle, d, e, lambda p: workspace_tables(ws, robot, p))
    d0, e0 = 0.015, 0.06
    ex, ap = exact(d0, e0), jax.jit(interp)(d0, e0)
    for k in ex:
        assert float(jnp.max(jnp.abs(ap[k] - ex[k]))) <= 1e-5 * float(jnp.max(jnp.abs(ex[k]))) + 1e-300, k
    h = 1e-6
    for t in ((1.0, 0.0), (0.0, 1.0)):
        plus, minus = exact(d0 + h * t[0], e0 + h * t[1]), exact(d0 - h * t[0], e0 - h * t[1])
        _, jv = jax.jit(lambda: jax.jvp(interp, (d0, e0), t))()
        for k in ex:
            fd = (plus[k] - minus[k]) / (2 * h)
            scale = float(jnp.max(jnp.abs(fd)))
            if scale > 0:
                assert float(jnp.max(jnp.abs(jv[k] - fd))) <= 2e-3 * scale, (t, k)


def test_workspace_rejects_a_cycle_outside_the_reach():
    robot = robot_preset("default")
    from jaxflex.path import make_cycle
    far = make_cycle((-0.3, 0.55), (0.3, 0.55))
    with pytest.raises(ValueError, match="workspace grid point"):
        build_workspace(robot, far)


def test_bicubic_derivative_rule_equals_autodiff_of_the_interpolant():
    """The interpolant's hand-written JVP (``workspace._bicubic``: two slopes, so that reverse mode keeps
    2 field-sized values per node instead of the stencil's 16) against autodiff of the plain weighted
    sum: forward and reverse derivatives in the cell coordinates and in the grid values, second
    derivatives in a coordinate, and under vmap with only the coordinates differentiated (how the
    design gradient uses it), each to 1e-13 of its scale."""
    from jaxflex.linearized import cubic_weights
    from jaxflex.workspace import _bicubic

    plain = lambda b, tu, tv: jnp.tensordot(cubic_weights(tu)[:, None] * cubic_weights(tv)[None, :], b, axes=2)
    rng = np.random.default_rng(5)
    block, tu, tv = jnp.asarray(rng.normal(size=(4, 4, 3, 2))), 1.3, 1.7
    np.testing.assert_allclose(_bicubic(block, tu, tv), plain(block, tu, tv), rtol=0, atol=1e-14)
    both = lambda d: jax.jit(lambda *a: (d(_bicubic)(*a), d(plain)(*a)))(block, tu, tv)   # (ours, autodiff)
    for derivative in (lambda f: jax.jacfwd(f, argnums=(0, 1, 2)), lambda f: jax.jacrev(f, argnums=(0, 1, 2)),
                       lambda f: lambda *a: (jax.hessian(f, argnums=1)(*a),)):
        for ours, ref in zip(*both(derivative)):
            np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-13)
    blocks, ts = jnp.asarray(rng.normal(size=(6, 4, 4, 3))), jnp.asarray(rng.uniform(0.0, 3.0, size=6))
    loss = lambda f: lambda t: jnp.sum(jnp.sin(jax.vmap(f)(blocks, t, 3.0 - 0.5 * t)))
    g, g_ref = jax.jit(lambda t: (jax.grad(loss(_bicubic))(t), jax.grad(loss(plain))(t)))(ts)
    assert float(jnp.max(jnp.abs(g_ref))) > 0.1
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-13)


def test_nodes_interpolated_in_steps_equal_each_node_alone():
    """``interpolate_nodes`` (the path's nodes ``NODE_BATCH`` at a time, the last step short) gives
    ``interpolate_basis`` at every node, inside the grid and clamped beyond its edges, with the same
    reverse-mode derivative in the positions (what the design gradient takes), to 1e-14 of the
    scale: a synthetic workspace of two fields on a rotated 9 x 7 grid, no model needed."""
    from jaxflex.workspace import NODE_BATCH, Workspace, interpolate_basis, interpolate_nodes

    rng = np.random.default_rng(7)
    angle = 0.3
    axes = jnp.asarray([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    ws = Workspace(values={"a": jnp.asarray(rng.normal(size=(9, 7, 2, 3))), "b": jnp.asarray(rng.normal(size=(9, 7, 5)))},
                   origin=jnp.asarray([0.1, 0.2]), axes=axes, step=jnp.asarray([0.01, 0.02]))
    n = 2 * NODE_BATCH + 3
    local = np.column_stack([rng.uniform(-0.5, 8.5, n), rng.uniform(-0.5, 6.5, n)]) * np.asarray(ws.step)
    xs = jnp.asarray(np.asarray(ws.origin)[None, :] + local @ np.asarray(axes).T)
    ours = interpolate_nodes(ws, xs)
    alone = jax.vmap(lambda x: interpolate_basis(ws, x))(xs)
    for k in ws.values:
        assert ours[k].shape == (n,) + ws.values[k].shape[2:]
        np.testing.assert_allclose(ours[k], alone[k], rtol=0, atol=1e-14 * float(jnp.max(jnp.abs(alone[k]))))
    loss = lambda f: lambda x: sum(jnp.sum(jnp.sin(v)) for v in jax.tree_util.tree_leaves(f(x)))
    g = jax.grad(loss(lambda x: interpolate_nodes(ws, x)))(xs)
    g_ref = jax.grad(loss(lambda x: jax.vmap(lambda p: interpolate_basis(ws, p))(x)))(xs)
    assert float(jnp.max(jnp.abs(g_ref))) > 1.0
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-14 * float(jnp.max(jnp.abs(g_ref))))


def test_the_servo_coefficients_are_exact_polynomials_and_their_workspace_tables_match_the_models():
    """The servo loop's coefficients (``servo_linearized.ServoCoeffs``: d/dq_a of the residual's
    terms, the end effector's motion with the motors) have the same polynomial structure in the path
    derivatives as the perfect controller's: rebuilt from the five probes they equal
    ``servo_pose_coeffs`` at arbitrary (qa1, qa2) to 1e-12 of each field's range (exact, the model
    being quadratic in velocities and linear in accelerations). The workspace with ``servo=True``
    (6 kg, a 0.01 kg m^2 rotor) then gives the servo tables of an asymmetric Lamé design within 1e-5
    of each field's range of the model's tables (bicubic interpolation on the 5 mm grid, as the
    perfect controller's tables: measured 7e-8 to 5e-7), and a workspace without them is not taken for one that has them."""
    from jaxflex.tables import _servo_many, servo_path_tables
    from jaxflex.workspace import SERVO_FIELDS, has_servo, servo_from_basis, workspace_servo_tables

    robot, cycle = robot_preset("default", payload=6.0).replace(rotor_inertia=0.01), cycle_preset()
    qa = np.asarray(igm(robot, jnp.asarray([0.05, 0.27])))
    # servo_pose_coeffs through the one compiled program the library's servo tables share
    at = lambda p: _servo_many(robot, np.repeat(qa[None], len(p), 0), p[:, :2], p[:, 2:])
    probed = at(np.asarray(PROBES))
    basis = jax.tree_util.tree_map(lambda v: v[0], jax.vmap(combine_probes)({k: v[None] for k, v in probed.items()}))
    rng = np.random.default_rng(1)
    qa1s, qa2s = rng.normal(0, 4, (3, 2)), rng.normal(0, 300, (3, 2))             # rad/m, rad/m^2
    refs = at(np.concatenate([qa1s, qa2s], axis=1))
    for i in range(3):
        ours = servo_from_basis(basis, jnp.asarray(qa1s[i]), jnp.asarray(qa2s[i]))._asdict()
        for k in SERVO_FIELDS:
            ref = np.asarray(refs[k][i])
            np.testing.assert_allclose(ours[k], ref, rtol=0, atol=1e-12 * (np.max(np.abs(ref)) + 1e-300), err_msg=k)

    ws = build_workspace(robot, cycle, servo=True)
    assert has_servo(ws) and not has_servo(build_workspace(robot, cycle))
    path = make_path(cycle, "lame", 0.015, 0.06, 3.5, 0.02, 0.04, 2.5)
    exact = servo_path_tables(robot, path).values._asdict()
    interp = jax.jit(workspace_servo_tables)(ws, robot, path).values._asdict()
    for k in SERVO_FIELDS:
        scale = float(jnp.max(jnp.abs(exact[k])))
        assert float(jnp.max(jnp.abs(interp[k] - exact[k]))) <= 1e-5 * scale + 1e-300, k
