"""Pure-jnp small linear algebra (jaxflex.linalg) against numpy's LAPACK: the package uses it instead
of jnp.linalg solves (a jaxlib CPU deadlock), so it must agree to round-off."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import linalg


@pytest.mark.parametrize("n", [1, 3, 12, 14])
def test_solvers_match_numpy(n):
    rng = np.random.default_rng(n)
    a, b, bm = rng.normal(size=(n, n)) + 0.1 * np.eye(n), rng.normal(size=n), rng.normal(size=(n, 3))
    spd = a @ a.T + n * np.eye(n)
    tol = 1e-12
    np.testing.assert_allclose(linalg.solve(a, b), np.linalg.solve(a, b), atol=tol * np.linalg.cond(a))
    np.testing.assert_allclose(linalg.solve(a, bm), np.linalg.solve(a, bm), atol=tol * np.linalg.cond(a))
    np.testing.assert_allclose(linalg.spd_solve(spd, b), np.linalg.solve(spd, b), atol=tol)
    np.testing.assert_allclose(linalg.spd_solve(spd, bm), np.linalg.solve(spd, bm), atol=tol)
    low = linalg.cholesky(spd)
    np.testing.assert_allclose(low, np.linalg.cholesky(spd), atol=tol * n)
    np.testing.assert_allclose(linalg.lower_inverse(low) @ low, np.eye(n), atol=tol)


def test_solve_pivots_on_a_zero_diagonal_and_differentiates_like_lapack():
    np.testing.assert_allclose(linalg.solve(jnp.array([[0.0, 1.0], [1.0, 0.0]]), jnp.array([1.0, 2.0])),
                               [2.0, 1.0], atol=0)
    a = jnp.asarray(np.random.default_rng(5).normal(size=(5, 5)) + 3 * np.eye(5))
    b = jnp.arange(5.0)
    g_ours = jax.grad(lambda m: linalg.solve(m, b).sum())(a)
    g_ref = jax.grad(lambda m: jnp.linalg.solve(m, b).sum())(a)
    np.testing.assert_allclose(g_ours, g_ref, atol=1e-12)


def test_shape_mismatch_is_rejected():
    with pytest.raises(ValueError, match="do not match"):
        linalg.spd_solve(jnp.eye(3), jnp.ones(4))
    with pytest.raises(ValueError, match="do not match"):
        linalg.solve(jnp.eye(3), jnp.ones(2))


def test_custom_derivatives_match_lapack_reference():
    """The custom JVPs (matrix identities) against jnp.linalg's own derivatives, forward and reverse,
    with symmetric tangents for the SPD routines (they read the lower triangle only)."""
    rng = np.random.default_rng(7)
    n = 6
    a = jnp.asarray(rng.normal(size=(n, n)) + 3 * np.eye(n))
    spd = a @ a.T
    da = jnp.asarray(rng.normal(size=(n, n)))
    ds = da + da.T
    b, db = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n))
    pairs = [
        (lambda m, v: linalg.solve(m, v), lambda m, v: jnp.linalg.solve(m, v), a, da),
        (lambda m, v: linalg.inv(m) @ v, lambda m, v: jnp.linalg.inv(m) @ v, a, da),
        (lambda m, v: linalg.spd_solve(m, v), lambda m, v: jnp.linalg.solve(m, v), spd, ds),
        (lambda m, v: linalg.cholesky(m) @ v, lambda m, v: jnp.linalg.cholesky(m) @ v, spd, ds),
        (lambda m, v: linalg.lower_inverse(jnp.tril(m)) @ v,
         lambda m, v: jnp.linalg.inv(jnp.tril(m)) @ v, a, da),
    ]
    for ours, ref, m, dm in pairs:
        t_ours = jax.jvp(ours, (m, b), (dm, db))[1]
        t_ref = jax.jvp(ref, (m, b), (dm, db))[1]
        np.testing.assert_allclose(t_ours, t_ref, rtol=1e-10, atol=1e-12)
        g_ours = jax.grad(lambda v: jnp.sum(ours(m, v) ** 2))(b)
        g_ref = jax.grad(lambda v: jnp.sum(ref(m, v) ** 2))(b)
        np.testing.assert_allclose(g_ours, g_ref, rtol=1e-10, atol=1e-12)
    # reverse mode w.r.t. the matrix: the VJP of the (transposed) custom JVP, checked on a symmetric direction
    f = lambda m: jnp.sum(linalg.cholesky(m) @ b)
    g = jax.grad(f)(spd)
    fd = (f(spd + 1e-6 * ds) - f(spd - 1e-6 * ds)) / 2e-6
    np.testing.assert_allclose(jnp.sum(g * ds), fd, rtol=1e-7)
