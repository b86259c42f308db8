"""The linearization tables and their use in the rollout, term by term, against the full model.

``linearized.pose_coeffs`` takes the coefficients of the linearized equations from the model's
residual term by term (``model.residual_term``: at rest, per unit s'', per unit s'^2); the rollout
(``simulate``) evaluates them and propagates the frozen system exactly over each step. Here every
piece is checked against an independent computation:

- at arbitrary path speed and acceleration, the linear model built from the coefficients
  (``linearized.evaluate``) equals the full model's equations and their Jacobians in (q_e, q_e',
  q_e'') computed directly by autodiff (no probes): forcing, rigid torque, mass, damping, stiffness,
  the torque maps and the end-effector maps J, J' and J'';
- the tables interpolate the coefficients between their nodes to the accuracy of local cubics;
- the rollout's frozen system (stiffness, damping, torque maps, forcing) is the same polynomial;
- the one-step propagator equals the matrix exponential of the augmented first-order system
  (Van Loan), computed with ``jax.scipy.linalg.expm``.
A 5 % error in any coefficient, in its use or in the propagator is far outside these tolerances.
"""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import model as mdl
from jaxflex import tables
from jaxflex.linearized import evaluate, interpolate, path_pose
from jaxflex.tables import coeffs_many, path_tables
from jaxflex.path import make_path
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.simulate import _frozen, _propagator


@pytest.fixture(scope="module")
def setup():
    robot = robot_preset("default", payload=6.0, damping=(2.0, 3e-5))     # damping on: C0 is not zero
    path = make_path(cycle_preset(), "lame", 0.025)
    return robot, path, path_tables(robot, path)


def _model_linearization(robot, qa, qa1, qa2, ds, dds):
    """R(0) and dR/d[q_e, q_e', q_e''] at z = 0 of the full reduced equations R(z) = M [q_a''; q_e'']
    + F with q_a' = q_a,s s', q_a'' = q_a,ss s'^2 + q_a,s s'' (direct autodiff, no probes)."""
    ne = 12
    qad, qadd = qa1 * ds, qa2 * ds**2 + qa1 * dds

    def resid(z):
        red = mdl.reduced(robot, qa, z[:ne], qad, z[ne:2 * ne])
        return red.mass @ jnp.concatenate([qadd, z[2 * ne:]]) + red.force

    z0 = jnp.zeros(3 * ne)
    return resid(z0), jax.jacfwd(resid)(z0)


def _end_effector_maps(robot, qa, qa1, qa2):
    """J = dX/dq_e, and its first and second derivatives along the path (d/ds, d2/ds2 at unit speed)."""
    jx_of = lambda q: jax.jacfwd(lambda x: mdl.ee_position(robot, q, x))(jnp.zeros(12))
    # J(q_a(s)): first derivative J_q[q_a,s]; second J_qq[q_a,s, q_a,s] + J_q[q_a,ss]
    jx, jx1 = jax.jvp(jx_of, (qa,), (qa1,))
    d1 = lambda q: jax.jvp(jx_of, (q,), (qa1,))[1]
    jx2 = jax.jvp(d1, (qa,), (qa1,))[1] + jax.jvp(jx_of, (qa,), (qa2,))[1]
    return jx, jx1, jx2


# one xdist group: the four nodes share one compiled full-model linearization (``_model_linearization``)
@pytest.mark.xdist_group("model-linearization")
@pytest.mark.parametrize("node", [3, 30, 80, 130])
def test_coefficients_are_the_full_models_linearization_at_any_speed(setup, node):
    """At table nodes on the first line, first blend, traverse and second blend, for a path speed
    and acceleration unlike the probes (s' = 2.3 m/s, s'' = -17 m/s^2), every term of the linear model
    equals the full model's. Tolerance: 1e-12 of each matrix's largest entry (the reference's
    Jacobian holds the ~5e9 N/m axial stiffness beside the s'' and s'^2 terms: its round-off is ~1e-6
    N/m, the tolerance 5e-3 N/m, while a 5 % error in the smallest of them, the centrifugal stiffness
    K2 s'^2 ~ 1e2..1e3 N/m, is ~10 N/m; 1e-9 when the coefficients were differences of such
    Jacobians)."""
    robot, path, tables = setup
    c = jax.tree_util.tree_map(lambda a: a[node], tables.values)
    ds, dds = 2.3, -17.0
    m, k, cc, f, tq, tv, tr = (np.asarray(v) for v in evaluate(c, ds, dds))
    r0, jac = (np.asarray(v) for v in jax.jit(_model_linearization)(robot, c.qa, c.qa1, c.qa2, ds, dds))
    e, a = slice(2, None), slice(0, 2)
    q, v, acc = slice(0, 12), slice(12, 24), slice(24, 36)
    pairs = {"forcing f": (f, -r0[e]), "rigid torque": (tr, r0[a]), "mass M": (m, jac[e, acc]),
             "stiffness K": (k, jac[e, q]), "damping C": (cc, jac[e, v]), "torque map T_q": (tq, jac[a, q]),
             "torque map T_v": (tv, jac[a, v]), "torque map M_ae": (np.asarray(c.m_ae), jac[a, acc])}
    for name, (ours, ref) in pairs.items():
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12 * np.abs(ref).max(), err_msg=name)
    for name, ours, ref in zip(("J", "J'", "J''"), (c.jx, c.jx1, c.jx2), _end_effector_maps(robot, c.qa, c.qa1, c.qa2)):
        np.testing.assert_allclose(np.asarray(ours), np.asarray(ref), rtol=0, atol=1e-10 * float(jnp.abs(ref).max()),
                                   err_msg=name)


def test_tables_interpolate_the_coefficients_between_nodes(setup):
    """Between the nodes (arc lengths not on the grid) the tables' local cubics give the exact
    coefficients within 2e-4 of each field's range (nodes every ~1 mm on the blends, ~6 mm on the
    traverse; measured <= 4e-5, on f2 near a blend join)."""
    robot, path, tables = setup
    rng = np.random.default_rng(4)
    s = np.sort(rng.uniform(0.0, float(path.length), 6))
    poses = jax.jit(jax.vmap(lambda x: path_pose(robot, path, x)))(jnp.asarray(s))
    exact = coeffs_many(robot, *poses)._asdict()       # pose_coeffs, through the library's shared program
    got = jax.jit(jax.vmap(lambda x: interpolate(tables, x)))(jnp.asarray(s))._asdict()
    for name in ("mass", "f0", "f1", "f2", "k0", "k2", "c1", "t1", "t2", "tq0", "jx", "jx1", "jx2"):
        scale = float(np.abs(np.asarray(tables.values._asdict()[name])).max())
        np.testing.assert_allclose(np.asarray(got[name]), np.asarray(exact[name]), rtol=0, atol=2e-4 * scale,
                                   err_msg=name)



def test_interpolating_all_fields_at_once_equals_field_by_field(setup):
    """``interpolate`` runs one gather and one cubic on all fields joined (``trees.map_packed``): the
    same values and arc-length derivative as interpolating every field on its own, to round-off
    (the sums are the same; 1e-13 allows a different summation order)."""
    from jaxflex import trees

    robot, path, tables = setup
    s = jnp.asarray(0.37 * float(path.length))
    idx, w = jnp.asarray([3, 4, 5, 6]), jnp.asarray([-0.0625, 0.5625, 0.5625, -0.0625])
    packed = jax.jacfwd(lambda x: trees.map_packed(lambda v: jnp.tensordot(w * x, v[idx], axes=1),
                                                   tables.values, lead=1))(s)
    each = jax.jacfwd(lambda x: jax.tree_util.tree_map(lambda v: jnp.tensordot(w * x, v[idx], axes=1),
                                                       tables.values))(s)
    assert jax.tree_util.tree_structure(packed) == jax.tree_util.tree_structure(each)
    for a, b in zip(jax.tree_util.tree_leaves(packed), jax.tree_util.tree_leaves(each)):
        assert a.shape == b.shape
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-300)
    got = jax.vmap(lambda x: interpolate(tables, x))(jnp.asarray([0.1, 0.5]) * path.length)
    for name, v in got._asdict().items():
        assert v.shape[1:] == tables.values._asdict()[name].shape[1:], name
def test_rollout_uses_the_same_polynomial_in_the_path_motion(setup):
    """The rollout's frozen system and forcing (``simulate``, from the slow and fast coefficient
    groups) are the coefficients' polynomial in (s', s'') of ``linearized.evaluate``."""
    _, _, tables = setup
    c = jax.tree_util.tree_map(lambda a: a[70], tables.values)
    for ds, dds in ((0.0, 0.0), (1.7, 9.0), (-0.4, -25.0)):
        m, k, cc, f, tq, tv, tr = evaluate(c, ds, dds)
        fz = _frozen(c.slow(), jnp.asarray(ds), jnp.asarray(dds), 1e-4, 8)
        f2, tr2 = c.fast().forcing(jnp.asarray(ds), jnp.asarray(dds))
        for name, ours, ref in (("K", fz.k, k), ("C", fz.c, cc), ("T_q", fz.tq, tq), ("T_v", fz.tv, tv),
                                ("M", fz.mass, m), ("M_ae", fz.m_ae, c.m_ae), ("f", f2, f), ("tau_r", tr2, tr)):
            np.testing.assert_allclose(np.asarray(ours), np.asarray(ref), rtol=1e-13,
                                       atol=1e-14 * float(jnp.abs(ref).max()), err_msg=name)


def test_propagator_is_the_exact_solution_of_the_frozen_system(setup):
    """x(h) = Phi x(0) + G0 f0 + G1 (f1 - f0) for M q'' + C q' + K q = f0 + (f1 - f0) t / h equals the
    exponential of the augmented system [x; u; w; v] (x' = A x + B (u + w), w' = v / h), i.e. the
    exact solution, computed with jax.scipy.linalg.expm (not jaxflex.expm). Step h = 1e-4 s with the
    real 18.6 kHz axial modes (omega h ~ 12)."""
    _, _, tables = setup
    c = jax.tree_util.tree_map(lambda a: a[70], tables.values)
    m, k, cc, *_ = evaluate(c, 1.2, 5.0)
    h = 1e-4
    phi, g0, g1, minv_ours = _propagator(m, k, cc, h, 10)
    n = 12
    minv = jnp.linalg.inv(m)
    # the inverse mass from the propagator's Cholesky factor equals LAPACK's inverse to round-off
    np.testing.assert_allclose(np.asarray(minv_ours), np.asarray(minv), rtol=0, atol=1e-12 * float(jnp.abs(minv).max()))
    # velocities scaled by w ~ omega_max (y = [q, q' / w]) so that the exponential is well scaled
    w = float(jnp.sqrt(jnp.max(jnp.abs(jnp.linalg.eigvals(minv @ k)))))
    a = jnp.block([[jnp.zeros((n, n)), w * jnp.eye(n)], [-minv @ k / w, -minv @ cc]])
    b = jnp.concatenate([jnp.zeros((n, n)), minv / w])
    aug = jnp.zeros((5 * n, 5 * n))
    aug = aug.at[:2 * n, :2 * n].set(a).at[:2 * n, 2 * n:3 * n].set(b).at[:2 * n, 3 * n:4 * n].set(b)
    aug = aug.at[3 * n:4 * n, 4 * n:].set(jnp.eye(n) / h)
    ex = jax.scipy.linalg.expm(aug * h)
    rng = np.random.default_rng(2)
    x0 = jnp.asarray(np.r_[rng.normal(size=n) * 1e-6, rng.normal(size=n) * 1e-3])
    f0, f1 = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n))
    y0 = jnp.concatenate([x0[:n], x0[n:] / w])
    ref = ex @ jnp.concatenate([y0, f0, jnp.zeros(n), f1 - f0])
    ref = jnp.concatenate([ref[:n], w * ref[n:2 * n]])
    ours = phi @ x0 + g0 @ f0 + g1 @ (f1 - f0)
    scale = np.abs(np.asarray(ref[:2 * n])).max(axis=None)
    np.testing.assert_allclose(np.asarray(ours[:n]), np.asarray(ref[:n]), rtol=0,
                               atol=1e-8 * float(jnp.abs(ref[:n]).max()))
    np.testing.assert_allclose(np.asarray(ours[n:]), np.asarray(ref[n:2 * n]), rtol=0,
                               atol=1e-8 * float(jnp.abs(ref[n:2 * n]).max()))
    assert scale > 0


def test_tables_are_fine_enough_for_long_blends_at_the_micrometre_level(monkeypatch):
    """Table resolution along the path: for a design of the kind the optimizer finds (long G4
    blends, smoothstep d = 24.8 mm, e = 102 mm, and a shaped law whose residual is about 1 um, the
    default 6 kg design after 50 steps, rounded), the dwell residual changes by less than 1 % when
    the nodes on the blends double. With 48 nodes per blend it read 7 % low (1.25 um against 1.34
    converged): an interpolation error that misleads the optimizer at the micrometre level while
    the paper's combinations (tens of um) hardly notice it (0.1 %)."""
    from jaxflex import engine, linearized, trees
    from jaxflex.profiles import shaped
    from jaxflex.engine import sample_motion
    from jaxflex.sweep import default_grid

    robot, cycle = robot_preset("default", payload=6.0), cycle_preset()
    path = make_path(cycle, "smoothstep", 0.0248, 0.102)
    law = shaped(jnp.array([1.116, 0.399, 1.101, 1.106, 0.438, 1.139]), 3)
    grid = default_grid(robot, [0.43], 0.1)
    samples = sample_motion(path.length, law, 0.43, grid)

    def residual(nodes):
        monkeypatch.setattr(linearized, "SEGMENT_NODES", nodes)
        poses = jax.jit(lambda r, p: linearized.table_poses(r, p))(robot, path)   # a new function: a fresh trace
        tab = linearized.Tables(values=tables.coeffs_many(robot, *poses), breaks=path.breaks)
        series = engine.run(tab, samples, 0.43, 0.1, robot, grid)   # new table shape: a new trace
        return float(engine.metrics_of(trees.stack([series]))["dwell_residual_mm"][0])

    default = linearized.SEGMENT_NODES
    finer = (default[0], 2 * default[1], default[2], 2 * default[3], default[4])
    r0, r1 = residual(default), residual(finer)
    assert 5e-4 < r1 < 5e-3, r1                                     # mm: a micrometre-level residual
    assert abs(r0 / r1 - 1.0) < 0.01, (r0, r1)


def test_coeffs_many_remembers_its_results_by_content(setup):
    """``coeffs_many`` remembers recent results by the content of its inputs: equal robots and poses
    (new arrays) give back the same result; any change of a model parameter or a pose computes
    afresh (a different result), and a cleared memo recomputes the same values bit for bit."""
    robot, path, _ = setup
    poses = [np.asarray(p) for p in tables.robot_table_poses(robot, path)]
    a = tables.coeffs_many(robot, *poses)
    assert tables.coeffs_many(robot, *[p.copy() for p in poses]) is a
    flat = lambda c: np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(c)])
    heavier = tables.coeffs_many(robot.replace(payload=6.06), *poses)
    assert heavier is not a and not np.allclose(flat(heavier), flat(a), rtol=1e-4, atol=0)
    moved = [p.copy() for p in poses]
    moved[0][3, 1] += 1e-6
    shifted = tables.coeffs_many(robot, *moved)
    assert shifted is not a and not np.array_equal(flat(shifted), flat(a))
    tables.clear_memo()
    again = tables.coeffs_many(robot, *poses)
    assert again is not a
    for x, y in zip(jax.tree_util.tree_leaves(again), jax.tree_util.tree_leaves(a)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.parametrize("richer", [False, True], ids=["paper", "richer"])
def test_coefficient_shapes_without_a_trace_equal_the_traced_ones(richer):
    """``coeff_shapes`` (the coefficients' shapes from the mode counts, which ``workspace_shapes``
    uses instead of tracing the model) equals ``jax.eval_shape`` of ``pose_coeffs`` field by field,
    for the paper model and the richer one (other mode counts)."""
    from jaxflex.linearized import coeff_shapes, pose_coeffs

    robot = robot_preset("default").replace(payload=6.0)
    robot = mdl.richer(robot, 2) if richer else robot
    pose = jax.ShapeDtypeStruct((2,), jnp.float64)
    traced = jax.eval_shape(pose_coeffs, robot, pose, pose, pose)
    declared = coeff_shapes(robot)
    assert traced._fields == declared._fields
    for name, t, d in zip(traced._fields, traced, declared):
        assert (t.shape, t.dtype) == (d.shape, d.dtype), name
